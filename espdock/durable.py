"""Writes a power cut cannot half-lose: a rename is durable only once the file's data and the
directory that names it are on disk (ext4's and XFS's delayed allocation may otherwise leave an
empty file under the new name)."""

from __future__ import annotations

import os
from pathlib import Path


def sync_file(path: Path) -> None:
    """Flush PATH's data to disk."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def sync_dir(path: Path) -> None:
    """Flush PATH's entries (names created, renamed or removed in it) to disk."""
    fd = os.open(path, os.O_RDONLY | os.O_DIRECTORY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def sync_tree(root: Path) -> None:
    """Flush every file and directory under ROOT (not following symlinks), ROOT last."""
    for dirpath, _, filenames in os.walk(root, topdown=False):
        for name in filenames:
            if not os.path.islink(os.path.join(dirpath, name)):
                sync_file(Path(dirpath, name))
        sync_dir(Path(dirpath))


def replace(source: Path, target: Path) -> None:
    """Rename SOURCE (written, not yet flushed) over TARGET, durably: data first, then the name."""
    if not source.is_symlink():
        sync_file(source)
    os.replace(source, target)
    sync_dir(target.parent)


def write_text(path: Path, text: str) -> None:
    """PATH holds TEXT, the old content or the new one whatever happens: a temporary file beside it,
    flushed, renamed over it, and the rename flushed."""
    # One of this process's own: two espdocks recording at once (two `espdock run`s) wrote and
    # renamed one shared temporary, and the second's rename found it gone.
    temporary = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        temporary.write_text(text)
        replace(temporary, path)
    except BaseException:
        temporary.unlink(missing_ok=True)
        raise
