"""How a build's containers meet the workspace: whom they run as, how they are labelled, the
reproducible environment they get, and the check that the engine sees the workspace at all."""

from __future__ import annotations

import os
import shutil
import subprocess
from collections.abc import Mapping
from pathlib import Path

from espdock.build.steps import LABEL_WORKSPACE
from espdock.config import Config
from espdock.errors import WorkspaceError
from espdock.events import Emit
from espdock.images.engine import Engine
from espdock.images.visibility import CHECKED, ensure_engine_sees
from espdock.workspace import Workspace


def workspace_commit_time(root: Path) -> str | None:
    """The committer time (Unix seconds) of ROOT's git HEAD, or None outside a repository."""
    if shutil.which("git") is None:
        return None
    # safe.directory: as root, reading a repository another user owns is what espdock does.
    argv = ["git", "-c", "safe.directory=*", "-C", str(root), "log", "-1", "--format=%ct"]
    result = subprocess.run(argv, capture_output=True, text=True, check=False, stdin=subprocess.DEVNULL)
    value = result.stdout.strip()
    return value if result.returncode == 0 and value.isdigit() else None


class Containers:
    """What every step's containers share in one run: the engine, the settings, where progress
    goes and who owns what they write."""

    def __init__(
        self, engine: Engine, config: Config, env: Mapping[str, str], emit: Emit, owner: tuple[int, int]
    ) -> None:
        """OWNER (uid, gid): who containers run as and who owns what a build writes (config.invoking_user)."""
        self.engine = engine
        self.config = config
        self.env = env
        self.emit = emit
        self.owner = owner
        self._commit_times: dict[Path, str | None] = {}

    def source_date(self, workspace: Workspace) -> tuple[tuple[str, str], ...]:
        """SOURCE_DATE_EPOCH for the build containers: the caller's, else the workspace's last commit.

        Tools that stamp their output read it instead of the clock (Python's .pyc files switch
        to source hashes, GCC's __DATE__/__TIME__, ...), so two builds of a commit match."""
        if workspace.root not in self._commit_times:  # one git call per run, not one per container
            self._commit_times[workspace.root] = workspace_commit_time(workspace.root)
        epoch = self.env.get("SOURCE_DATE_EPOCH") or self._commit_times[workspace.root]
        return (("SOURCE_DATE_EPOCH", epoch),) if epoch else ()

    def reproducible_env(self, workspace: Workspace) -> tuple[tuple[str, str], ...]:
        """SOURCE_DATE_EPOCH, and a fixed PYTHONHASHSEED: rosidl's generators write some lists in
        set order (a service type description's includes), which the hash seed would shuffle."""
        return (*self.source_date(workspace), ("PYTHONHASHSEED", "0"))

    def check_mount(self, workspace: Workspace, image: str, user: str, labels: tuple[tuple[str, str], ...]) -> None:
        """Make sure the engine's containers see the workspace (espdock.images.visibility), once per engine and path."""
        make_dirs_for(workspace.ws_dir / "build", self.owner)
        ensure_engine_sees(self.engine, workspace, image, user, labels)
        if (workspace.ws_dir / "build" / CHECKED).exists():
            give_to(workspace.ws_dir / "build" / CHECKED, self.owner)

    def container_identity(
        self, workspace: Workspace, step_label: str, sweep: bool
    ) -> tuple[str, tuple[tuple[str, str], ...]]:
        """The user a workspace container runs as, and its labels.

        With SWEEP, containers with the same labels are removed first: left by an espdock
        killed outright. Only a caller holding the workspace lock may sweep, since only
        then can none of them be live.
        """
        labels = {LABEL_WORKSPACE: str(workspace.root), "io.espdock.step": step_label}
        if sweep:
            self.engine.remove_containers(labels)
        return self.container_user(), tuple(labels.items())

    def container_user(self) -> str:
        uid, gid = self.container_owner()
        return f"{uid}:{gid}"

    def container_owner(self) -> tuple[int, int]:
        """Who a container writing into the workspace runs as, so its files are the invoking user's:
        that user's uid, gid, or in a rootless engine 0, 0, which is the engine's own user outside."""
        return (0, 0) if self.engine.info().rootless else self.owner


def make_dirs_for(directory: Path, owner: tuple[int, int]) -> None:
    """mkdir -p DIRECTORY; as root, the directories it creates belong to OWNER."""
    missing = [d for d in (directory, *directory.parents) if not d.exists()]
    directory.mkdir(parents=True, exist_ok=True)
    for created in missing:
        give_to(created, owner)


def give_to(path: Path, owner: tuple[int, int]) -> None:
    if os.geteuid() == 0:
        os.chown(path, *owner)


def permission_error(exc: PermissionError) -> WorkspaceError:
    """A path espdock may not write or read, named with its owner (a rootless engine's files, say)."""
    path = Path(exc.filename) if exc.filename else None
    owner = ""
    if path is not None:
        try:
            info = path.lstat() if path.exists() or path.is_symlink() else path.parent.lstat()
            where = "" if path.exists() else ", its directory"
            owner = f" (owner uid {info.st_uid}, mode {info.st_mode & 0o7777:04o}{where})"
        except OSError:
            pass
    return WorkspaceError(
        f"permission denied on {path or 'a workspace file'}{owner}; espdock runs as uid {os.geteuid()}",
        "Give that path back to you (e.g. `sudo chown -R $(id -u):$(id -g) PATH`); files a container wrote as "
        "another user are the engine's doing: see the Engines page of espdock's docs (rootless engines).",
    )
