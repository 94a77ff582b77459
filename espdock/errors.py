"""The errors espdock reports to users: what happened, then what to try.

Only the CLI entry point turns these into exit codes; nothing below it exits.
"""

from __future__ import annotations

import os
import shutil


class EspdockError(Exception):
    """Base of every error espdock expects and explains."""

    exit_code = 1
    keys: tuple[str, ...] = ()  # the rosdep keys nothing answers, where that is what refused

    def __init__(self, message: str, hint: str | None = None) -> None:
        super().__init__(message)
        self.message = message
        self.hint = hint


class ConfigError(EspdockError):
    """espdock.toml, the environment or the command line asks for something invalid."""

    exit_code = 2


class WorkspaceError(EspdockError):
    """The workspace cannot be found, or its packages cannot be read or ordered."""

    exit_code = 2


class LockError(EspdockError):
    """A dependency lock is missing or stale against its source, or cannot be made."""

    exit_code = 2


class DependencyError(EspdockError):
    """A package depends on something the ROS image does not provide and rosdep cannot install."""

    exit_code = 2

    def __init__(self, message: str, hint: str | None = None, keys: tuple[str, ...] = ()) -> None:
        super().__init__(message, hint)
        self.keys = keys


class LockBehind(DependencyError):
    """The rosdep lock is missing, or older than the package.xml files: a key they name it has
    never seen, which refreshing the lock answers (`espdock build` does, out of CI)."""


class RegistryError(EspdockError):
    """The cache registry refused the engine's credentials, or --push-cache could not push."""

    exit_code = 2


class EngineUnavailable(EspdockError):
    """No container engine answers and espdock cannot start one."""

    exit_code = 3


class ImageBuildError(EspdockError):
    """An image build failed."""

    exit_code = 4


class BuildFailed(EspdockError):
    """A package failed to build; names the packages and where their logs are."""

    exit_code = 5


class WorkspaceNotVisible(EspdockError):
    """The engine's containers do not see the workspace at its mount path: the engine is on another
    machine (DOCKER_HOST=tcp://..., ssh://..., a docker:dind service) that does not share it."""

    exit_code = 8


class ContainerError(EspdockError):
    """The engine refused to create or start a container (the message names the engine)."""

    exit_code = 9


class MountSourceMissing(ContainerError):
    """The engine has no such path for a container's bind mount: it runs on another machine."""

    def __init__(self, message: str, hint: str | None, path: str) -> None:
        super().__init__(message, hint)
        self.path = path


class TestsFailed(EspdockError):
    """`espdock test`: a test failed or errored (or colcon test itself failed); the summary names them."""

    exit_code = 10


class DiskFull(EspdockError):
    """A disk a build writes to (the workspace's, or the engine's) has no space left."""

    exit_code = 7


def disk_full(path: str | os.PathLike[str], low: int = 64 << 20, known: bool = False) -> DiskFull | None:
    """A DiskFull naming the filesystem that holds PATH when it is nearly full (less than LOW bytes
    and under 5 % of it free: a small filesystem with most of it free is not full, and taking it
    for full hid a build's real error), or whatever it has free when it is KNOWN to be (ENOSPC);
    else None."""
    where = os.path.abspath(path)
    while not os.path.exists(where):
        where = os.path.dirname(where)
    try:
        usage = shutil.disk_usage(where)
    except OSError:
        return None
    if not known and (usage.free >= low or usage.free >= usage.total / 20):
        return None
    mount = where
    while not os.path.ismount(mount):
        mount = os.path.dirname(mount)
    return DiskFull(
        f"the disk holding {path} (the filesystem mounted at {mount}) is full: "
        f"{_size(usage.free)} free of {_size(usage.total)}",
        "Free space there, then build again: what this build did not finish is built again.",
    )


def _size(count: int) -> str:
    """COUNT bytes in MiB, or in KiB under one (a 300 KiB filesystem was "0 MiB free of 0 MiB")."""
    return f"{count >> 20} MiB" if count >= 1 << 20 else f"{count >> 10} KiB"


class Interrupted(EspdockError):
    """The user interrupted espdock (Ctrl-C or SIGTERM); work in flight was cleaned up."""

    exit_code = 130


class EspdockBug(EspdockError):
    """An exception espdock did not expect: its own bug, reported with a traceback log."""

    exit_code = 70  # EX_SOFTWARE
