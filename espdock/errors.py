"""The errors espdock reports to users: what happened, then what to try.

Only the CLI entry point turns these into exit codes; nothing below it exits.
"""

from __future__ import annotations


class EspdockError(Exception):
    """Base of every error espdock expects and explains."""

    exit_code = 1

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


class RegistryError(EspdockError):
    """The cache registry refused the engine's credentials."""

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


class Interrupted(EspdockError):
    """The user interrupted espdock (Ctrl-C or SIGTERM); work in flight was cleaned up."""

    exit_code = 130


class EspdockBug(EspdockError):
    """An exception espdock did not expect: its own bug, reported with a traceback log."""

    exit_code = 70  # EX_SOFTWARE
