"""Which espdock process made a thing, and scratch directories named by it.

A process's identity (its boot, pid and start time) names the containers it labels and the
scratch directories it makes, so that the next espdock run removes what an espdock killed
outright (kill -9, the OOM killer) left behind: containers, staged image contexts, the workspace
volume's tar streams and the trees it unpacks beside install/, provisioning's NVS image. A live
espdock's are never touched."""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path


def _boot_id() -> str:
    try:
        return Path("/proc/sys/kernel/random/boot_id").read_text().strip()
    except OSError:
        return "unknown-boot"


def _start_time(pid: int) -> str | None:
    """PID's start time in clock ticks since boot (/proc/PID/stat field 22), None when it is gone."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return stat.rsplit(")", 1)[1].split()[19]


def _pid_namespace() -> str:
    """This process's PID namespace (its inode), '' where /proc does not say."""
    try:
        return os.readlink("/proc/self/ns/pid").partition("[")[2].rstrip("]")
    except OSError:
        return ""


def owner_identity() -> str:
    """This process as LABEL_OWNER names it: a pid is reused, a pid with its start time is not;
    and a pid means something only in its PID namespace (NAMESPACE.PID)."""
    return f"{_boot_id()}:{_pid_namespace()}.{os.getpid()}:{_start_time(os.getpid())}"


def owner_alive(owner: str) -> bool:
    """Whether the process OWNER (an owner_identity) still runs on this machine. One of another
    machine's (an engine over TCP) is not found here, so it counts as gone: only sweep what a
    workspace path of this machine labels. One of another PID namespace of this machine (a CI
    job's container beside this one, on the same engine and at the same checkout path) cannot be
    looked up, so it counts as running: a live build there is never taken for a killed one."""
    boot, _, rest = owner.partition(":")
    pid, _, started = rest.partition(":")
    namespace, dot, pid = pid.rpartition(".")
    if dot and boot == _boot_id() and namespace != _pid_namespace():
        return True
    return boot == _boot_id() and pid.isdigit() and _start_time(int(pid)) == started


def sweep(directory: Path, prefix: str, remove: Callable[[Path], None] = shutil.rmtree) -> None:
    """Remove (REMOVE) this user's PREFIX directories in DIRECTORY whose process is gone; root's,
    any user's: root's provisioning hands its directory to the container's user, and one killed
    outright left the Wi-Fi password there for good."""
    try:
        left = [entry for entry in directory.iterdir() if entry.name.startswith(prefix)]
    except OSError:  # a temp dir this user cannot list: nothing of theirs to sweep
        return
    for path in left:
        owner = path.name.removeprefix(prefix).rpartition("-")[0]
        if owner.count(":") != 2:  # not named by make(): another tool's, or an older espdock's
            continue
        with suppress(OSError):
            mine = os.geteuid() in (0, path.lstat().st_uid)
            if mine and path.is_dir() and not path.is_symlink() and not owner_alive(owner):
                remove(path)


def make(prefix: str, directory: Path | None = None, remove: Callable[[Path], None] = shutil.rmtree) -> Path:
    """A new private directory PREFIX<identity>-<random> in DIRECTORY (the temp dir by default),
    after sweeping (REMOVE) the ones of processes that are gone."""
    where = Path(directory or tempfile.gettempdir())
    sweep(where, prefix, remove)
    return Path(tempfile.mkdtemp(prefix=f"{prefix}{owner_identity()}-", dir=where))


@contextmanager
def scratch_dir(prefix: str, directory: Path | None = None) -> Iterator[Path]:
    """make()'s directory, removed with what it holds when the block ends."""
    path = make(prefix, directory)
    try:
        yield path
    finally:
        shutil.rmtree(path, ignore_errors=True)
