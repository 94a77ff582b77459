"""The workspace in a volume on the engine, for an engine that does not see this machine's files
(DOCKER_HOST=tcp://... or ssh://..., a docker:dind service without a shared path).

The build containers mount the volume where they would mount the workspace, so colcon's and
IDF's build dirs stay on the engine and rebuilds are incremental. Before a build, the sources
that changed since the last sync go into the build container as a tar stream (the engine API's
archive upload: no shared path) and the ones deleted since are removed; a manifest of what was
sent (paths, sizes, modification times, modes) lies under the colcon root's build/ on the host.
After it, what the host needs comes back the same way and is swapped in whole: install/ and
colcon's log, or a firmware package's build dir.
"""

from __future__ import annotations

import contextlib
import errno
import io
import json
import os
import posixpath
import re
import shutil
import stat
import tarfile
from collections.abc import Collection, Iterator
from dataclasses import dataclass, replace
from pathlib import Path, PurePosixPath

from espdock import durable, interrupts, scratch
from espdock.build.stamps import source_files
from espdock.build.steps import LABEL_WORKSPACE
from espdock.errors import EngineUnavailable, WorkspaceError
from espdock.images.engine import Engine
from espdock.images.specs import Mount
from espdock.layout import WORKSPACE_MOUNT
from espdock.workspace import Workspace, give_tree, root_key

LABEL_VOLUME = "io.espdock.volume"
# Under the colcon root's build/ on the host: what the volume holds of the sources.
SYNCED = ".espdock-volume-sync.json"
# What colcon writes, relative to the colcon root: never sent, and made writable for the build's user.
OUTPUT_DIRS = ("build", "install", "log")


def volume_name(workspace: Workspace) -> str:
    """The workspace's volume: its directory's name (for people) and a digest of its path (unique)."""
    digest = root_key(workspace.root)[:12]
    readable = re.sub(r"[^a-z0-9_.-]+", "-", workspace.root.name.lower()).strip("-.")[:40] or "workspace"
    return f"espdock-ws-{readable}-{digest}"


def volume_labels(workspace: Workspace) -> dict[str, str]:
    return {LABEL_WORKSPACE: str(workspace.root), LABEL_VOLUME: "workspace"}


def volume_mount(workspace: Workspace) -> Mount:
    """The volume where build containers mount the workspace (espdock.visibility.workspace_mount)."""
    return Mount(volume_name(workspace), WORKSPACE_MOUNT, volume=True)


def container_path(workspace: Workspace, path: Path) -> str:
    """Where PATH (inside the workspace) is in a container with the workspace or its volume mounted."""
    return posixpath.join(WORKSPACE_MOUNT, path.relative_to(workspace.root).as_posix())


@dataclass(frozen=True)
class Sync:
    """What a build container gets before it starts: the changed sources and the deleted ones."""

    volume: str
    # True when the volume was made for this sync: it holds nothing yet (no build dirs either).
    fresh: bool
    archive: bytes
    sent: int
    deleted: tuple[str, ...]  # container paths
    files: dict[str, list[int]]  # the manifest once the build container has them
    # The host's install/ (espdock.stamps.listing_digest) as the last copy back left it: when it
    # is another, install/ holds what the volume did not build, and the volume builds everything.
    installed: str | None


def prepare(engine: Engine, workspace: Workspace, owner: tuple[int, int]) -> Sync:
    """Make the workspace's volume if the engine lacks it, and the tar of what it lacks; OWNER
    (uid, gid): who owns what the tar makes, the build containers' user."""
    name = volume_name(workspace)
    fresh = engine.ensure_volume(name, volume_labels(workspace))
    manifest = workspace.ws_dir / "build" / SYNCED
    record = {"volume": name, "engine": engine.info().identity}
    before: dict[str, list[int]] = {}
    installed = None
    if not fresh:
        try:
            data = json.loads(manifest.read_text())
            if {k: data.get(k) for k in record} == record and isinstance(data.get("files"), dict):
                before, installed = data["files"], data.get("installed")
        except (OSError, ValueError, AttributeError):
            pass
    now: dict[str, Path] = {}
    for path in source_files(workspace.root, (workspace.root, workspace.ws_dir)):
        if not _output(workspace, path):
            now[path.relative_to(workspace.root).as_posix()] = path
    files: dict[str, list[int]] = {}
    buffer = io.BytesIO()
    sent = 0
    with tarfile.open(fileobj=buffer, mode="w", format=tarfile.PAX_FORMAT) as tar:
        dirs = {workspace.ws_dir.relative_to(workspace.root) / d for d in OUTPUT_DIRS}
        for directory in sorted({p for d in dirs for p in (d, *d.parents)} - {Path(".")}):
            tar.addfile(_owned(tarfile.TarInfo(directory.as_posix()), tarfile.DIRTYPE, 0o755, owner))
        made: set[str] = set()
        for rel, path in sorted(now.items()):
            info = path.lstat()
            # The change time as well, as git's index keeps it: an edit that keeps the size and
            # the modification time (`cp -p`, `rsync -a`, `touch -r`) was never sent, and the
            # volume built the old file. No one sets it but the kernel, on every write.
            files[rel] = [info.st_size, info.st_mtime_ns, info.st_mode, info.st_ctime_ns]
            if before.get(rel) == files[rel]:
                continue
            for parent in reversed(Path(rel).parents[:-1]):
                if parent.as_posix() not in made:
                    made.add(parent.as_posix())
                    tar.addfile(_owned(tarfile.TarInfo(parent.as_posix()), tarfile.DIRTYPE, 0o755, owner))
            entry = tar.gettarinfo(str(path), arcname=rel)
            entry.uid, entry.gid, entry.uname, entry.gname = *owner, "", ""
            if entry.isreg():
                with path.open("rb") as handle:
                    tar.addfile(entry, handle)
            else:
                tar.addfile(entry)
            sent += 1
    deleted = tuple(posixpath.join(WORKSPACE_MOUNT, rel) for rel in sorted(set(before) - set(now)))
    return Sync(name, fresh, buffer.getvalue(), sent, deleted, files, installed)


def record(workspace: Workspace, engine: Engine, sync: Sync, installed: str | None) -> None:
    """The volume holds SYNC's files now, and INSTALLED is the host's install/ as copied back from
    it: the next sync sends only what changes after this."""
    manifest = workspace.ws_dir / "build" / SYNCED
    data = {"volume": sync.volume, "engine": engine.info().identity, "files": sync.files, "installed": installed}
    durable.write_text(manifest, json.dumps(data, sort_keys=True) + "\n")


def file_archive(path: str, data: bytes) -> tuple[str, bytes]:
    """An archive for RunSpec.archives that makes the file PATH (absolute, in the container) of DATA:
    what a read-only bind mount of a host file is on an engine that cannot see the host."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w") as tar:
        directory = ""
        for part in posixpath.dirname(path).strip("/").split("/"):
            directory = posixpath.join(directory, part)
            tar.addfile(_owned(tarfile.TarInfo(directory), tarfile.DIRTYPE, 0o755, (0, 0)))
        entry = tarfile.TarInfo(path.lstrip("/"))
        entry.size, entry.mode = len(data), 0o644
        tar.addfile(entry, io.BytesIO(data))
    return "/", buffer.getvalue()


def files_archive(
    workspace: Workspace, directory: Path, names: tuple[str, ...], owner: tuple[int, int]
) -> tuple[str, bytes]:
    """An archive for RunSpec.archives of the files NAMES in DIRECTORY (a host dir of the
    workspace) that exist, owned by OWNER, where the workspace's volume is mounted."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w", format=tarfile.PAX_FORMAT) as tar:
        rel = directory.relative_to(workspace.root)
        for parent in (*reversed(rel.parents[:-1]), rel):
            tar.addfile(_owned(tarfile.TarInfo(parent.as_posix()), tarfile.DIRTYPE, 0o755, owner))
        for path in (directory / name for name in names):
            if path.is_file() and not path.is_symlink():
                entry = tar.gettarinfo(str(path), arcname=(rel / path.name).as_posix())
                entry.uid, entry.gid, entry.uname, entry.gname = *owner, "", ""
                with path.open("rb") as handle:
                    tar.addfile(entry, handle)
    return WORKSPACE_MOUNT, buffer.getvalue()


def unknown(sync: Sync) -> Sync:
    """SYNC with its files' states unknown: recorded so, the next sync sends every source again
    (over what a shell on the volume changed) and still removes what was deleted since."""
    return replace(sync, files={rel: [] for rel in sync.files})


def forget(workspace: Workspace) -> None:
    """The volume is gone: the next sync sends everything."""
    (workspace.ws_dir / "build" / SYNCED).unlink(missing_ok=True)


def _output(workspace: Workspace, path: Path) -> bool:
    """Whether PATH lies in what colcon writes (the colcon root's build/, install/, log/)."""
    return any(path.is_relative_to(workspace.ws_dir / d) for d in OUTPUT_DIRS)


def _owned(info: tarfile.TarInfo, kind: bytes, mode: int, owner: tuple[int, int]) -> tarfile.TarInfo:
    info.type, info.mode, (info.uid, info.gid) = kind, mode, owner
    return info


@contextlib.contextmanager
def fetched(*names: str) -> Iterator[dict[str, Path]]:
    """Temporary files (NAME -> path) for the tar streams a build container hands back."""
    with scratch.scratch_dir("espdock-volume-") as tmp:
        yield {name: tmp / f"{name}.tar" for name in names}


def replace_tree(archive: Path, dest: Path, owner: tuple[int, int], only: Collection[str] | None = None) -> bool:
    """Swap DEST for the directory ARCHIVE holds (a container path's tar stream: one top-level
    directory), owned by OWNER when espdock runs as root; False (DEST left alone) when the
    container had no such path. DEST is never half-written: the tree is unpacked beside it first.
    With ONLY, of DEST's own entries just those named are the archive's: the others stay as they
    were (linked into the new tree), and the archive's that DEST lacks are added."""
    if not archive.is_file():
        return False
    staging = _unpacked(archive, dest.parent, owner)
    old: Path | None = None
    try:
        if only is not None and dest.is_dir():
            new = staging / _top(archive)
            for entry in dest.iterdir():
                if entry.name in only:
                    continue
                kept = new / entry.name
                if kept.is_dir() and not kept.is_symlink():
                    shutil.rmtree(kept)
                elif kept.exists() or kept.is_symlink():
                    kept.unlink()
                if entry.is_dir() and not entry.is_symlink():
                    shutil.copytree(entry, kept, symlinks=True, copy_function=os.link)
                    if os.geteuid() == 0:
                        # The files are the old ones (links); the directories are new, and root's
                        # kept the user from removing the old tree's files after a `sudo` build.
                        for directory, _, names in os.walk(kept):
                            was = (entry / os.path.relpath(directory, kept)).stat()
                            os.chown(directory, was.st_uid, was.st_gid)
                            for name in names:  # copytree makes its links anew, as root
                                if (link := Path(directory, name)).is_symlink():
                                    was = (entry / link.relative_to(kept)).lstat()
                                    os.chown(link, was.st_uid, was.st_gid, follow_symlinks=False)
                else:
                    os.link(entry, kept, follow_symlinks=False)
        old = scratch.make(".espdock-old-", dest.parent)  # DEST goes in it, to be removed with it
        with interrupts.held():  # the two renames as one: DEST is the old tree or the new one
            if dest.exists() or dest.is_symlink():
                try:
                    dest.rename(old / dest.name)
                except OSError as exc:
                    if exc.errno not in (errno.EXDEV, errno.EBUSY):
                        raise
                    # A mount point of its own (a bind mount, another disk): no rename moves it.
                    raise WorkspaceError(
                        f"{dest} is a mount point of its own: the workspace volume's {dest.name}/ comes back by "
                        f"renaming it into place, which cannot move it ({exc.strerror})",
                        f"Make {dest.name}/ a plain directory of the workspace, or build with "
                        "--workspace-mode mount where the engine sees the workspace. It was left as it was.",
                    ) from None
            (staging / _top(archive)).rename(dest)
        durable.sync_dir(dest.parent)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
        if old is not None:
            shutil.rmtree(old, ignore_errors=True)
    return True


def merge_logs(archive: Path, dest: Path, owner: tuple[int, int]) -> None:
    """Add the colcon runs ARCHIVE (the volume's log/) holds that DEST lacks; its latest* links win."""
    if not archive.is_file():
        return
    staging = _unpacked(archive, dest.parent, owner)
    try:
        dest.mkdir(exist_ok=True)
        _give(dest, owner)
        for entry in sorted((staging / _top(archive)).iterdir()):
            target = dest / entry.name
            if entry.is_symlink():
                os.replace(entry, target)
            elif not target.exists():
                entry.rename(target)
    finally:
        shutil.rmtree(staging, ignore_errors=True)


def _top(archive: Path) -> str:
    with tarfile.open(archive) as tar:
        first = tar.next()
    if first is None:
        raise _cut_short(archive, "it holds nothing")
    return first.name.split("/", 1)[0]


def _unpacked(archive: Path, beside: Path, owner: tuple[int, int]) -> Path:
    staging = scratch.make(".espdock-fetched-", beside)
    try:
        with tarfile.open(archive) as tar:
            _extract(tar, staging)
        if os.geteuid() == 0:
            give_tree(staging, owner)
    except (tarfile.ReadError, EOFError) as exc:
        shutil.rmtree(staging, ignore_errors=True)
        raise _cut_short(archive, str(exc)) from exc
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return staging


def _extract(tar: tarfile.TarFile, where: Path) -> None:
    """Extract TAR into WHERE through tarfile's "tar" filter: no absolute names or ones leading out,
    no setuid, setgid, sticky or group and other write bits; links may lead anywhere (a symlink
    install's point at the build dirs), as colcon made them. Python before 3.11.4 (Debian
    bookworm's 3.11.2) has no filters: the same checks, made here."""
    if hasattr(tarfile, "tar_filter"):
        tar.extractall(where, filter="tar")
        return
    members = tar.getmembers()
    for member in members:
        if member.name.startswith("/") or ".." in PurePosixPath(member.name).parts:
            raise ValueError(f"{member.name}: a name out of the directory a copy from the engine goes to")
        member.mode &= ~(stat.S_ISUID | stat.S_ISGID | stat.S_ISVTX | stat.S_IWGRP | stat.S_IWOTH)
    tar.extractall(where, members)


def _cut_short(archive: Path, why: str) -> EngineUnavailable:
    """The engine answered a copy out of a finished container with a broken stream (an engine
    that went away mid-copy): the engine's failure, and the host's tree is left as it was."""
    return EngineUnavailable(
        f"the engine's copy of the container's {archive.stem}/ came back broken ({why})",
        f"Nothing in {archive.stem}/ was replaced. Check the engine (`docker info`) and build again.",
    )


def _give(path: Path, owner: tuple[int, int]) -> None:
    if os.geteuid() == 0:
        os.lchown(path, *owner)
