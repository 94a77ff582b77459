"""Locks among the espdock processes of this machine on one engine: one image build of a tag at a
time, one import of a base image. Their files are in /tmp, whatever TMPDIR says: a CI runner's
per-job TMPDIR, or libpam-tmpdir's per-user one, gave two builds of one tag a lock each, and the
same image was built twice, one copy left untagged where prune never sees it."""

from __future__ import annotations

import fcntl
import os
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

from espdock.workspace import holder_text, remove_holder, write_holder

LOCK_DIR = Path("/tmp")


@contextmanager
def machine_lock(name: str, waiting: Callable[[str], None]) -> Iterator[None]:
    """Hold the lock NAME (WAITING is called once, when another process holds it, with who that
    is: " (pid N: COMMAND)", or "" where it did not say).

    Its holder removes the lock file before it lets go, so /tmp does not keep one per tag ever
    built; a waiter that then holds a removed file locks the path's new one instead. Where the
    file cannot be opened (another user's, in a directory that refuses it) the block runs
    unlocked, as it did before locks."""
    path = _lock_path(name)
    holder = path.with_suffix(".holder")
    fd = _hold_lock(path, lambda: waiting(holder_text(holder)))
    if fd is None:
        yield
        return
    write_holder(holder)
    try:
        yield
    finally:
        remove_holder(holder)
        with suppress(OSError):
            path.unlink()
        os.close(fd)


def lock_holder(name: str) -> str | None:
    """Who holds the lock NAME now (as WAITING of machine_lock is told it), or None when no other
    process does. It only looks: no lock file is made, and one found free is let go at once."""
    path = _lock_path(name)
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:  # none (nobody holds it), or another user's that this one cannot open
        return None
    try:  # shared: two that look do not see each other
        fcntl.flock(fd, fcntl.LOCK_SH | fcntl.LOCK_NB)
    except BlockingIOError:
        return holder_text(path.with_suffix(".holder"))
    finally:
        os.close(fd)  # lets go of a lock it took
    return None


def _lock_path(name: str) -> Path:
    return LOCK_DIR / f"espdock-{name}.lock"


def _hold_lock(path: Path, waiting: Callable[[], None]) -> int | None:
    """A descriptor holding the exclusive lock of the file PATH names (WAITING is called once, when
    another holds it); None where it cannot be opened. A holder removes the file before it lets
    go, so the file a waiter gets is checked against PATH, and PATH's new one is locked instead."""
    said = False
    while True:
        try:
            try:  # without O_CREAT first: protected_regular refuses it on another user's file in /tmp
                fd = os.open(path, os.O_RDONLY)
            except FileNotFoundError:
                fd = os.open(path, os.O_RDONLY | os.O_CREAT, 0o444)
                # Whatever the umask: under 077 another user's espdock could not open it, and went on
                # unlocked (two flashes of one board, two builds of one image).
                with suppress(OSError):  # another's, made in between: theirs to set
                    os.fchmod(fd, 0o444)
        except OSError:
            return None
        try:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                if not said:
                    waiting()
                    said = True
                fcntl.flock(fd, fcntl.LOCK_EX)
        except BaseException:  # Ctrl-C while waiting
            os.close(fd)
            raise
        if _names(path, fd):
            return fd
        os.close(fd)  # removed, or made again, by its last holder


def _names(path: Path, fd: int) -> bool:
    """Whether PATH is still the file open as FD."""
    try:
        named = path.stat()
    except FileNotFoundError:
        return False
    held = os.fstat(fd)
    return (named.st_dev, named.st_ino) == (held.st_dev, held.st_ino)
