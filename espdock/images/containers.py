"""How a build's containers meet the workspace: whom they run as, how they are labelled, the
reproducible environment they get, and the check that the engine sees the workspace at all."""

from __future__ import annotations

import os
import pwd
import re
import shlex
import shutil
import subprocess
from collections.abc import Mapping
from dataclasses import replace
from pathlib import Path

from espdock.build.steps import LABEL_WORKSPACE
from espdock.config import Config
from espdock.errors import ConfigError, EspdockError, WorkspaceError, WorkspaceNotVisible
from espdock.events import Emit, StepNote
from espdock.images import volume
from espdock.images.engine import Engine
from espdock.images.specs import Mount, RunSpec
from espdock.images.visibility import CHECKED, engine_sees, ensure_engine_sees, sees_as_checked, workspace_mount
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


# SOURCE_DATE_EPOCH of a workspace with no git history: 1980-01-01, the earliest time a zip (a
# wheel, an egg) can hold.
NO_COMMIT_EPOCH = "315532800"


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
        # Per workspace root: whether its build containers use its volume (espdock.images.volume).
        self._volume: dict[Path, bool] = {}

    def source_date(self, workspace: Workspace) -> tuple[tuple[str, str], ...]:
        """SOURCE_DATE_EPOCH for the build containers: the caller's, else the workspace's last commit.

        Tools that stamp their output read it instead of the clock (Python's .pyc files switch
        to source hashes, GCC's __DATE__/__TIME__, ...), so two builds of a commit match."""
        if workspace.root not in self._commit_times:  # one git call per run, not one per container
            self._commit_times[workspace.root] = workspace_commit_time(workspace.root)
        # Without git history (`git archive`, a downloaded zip), a fixed time: unset, .pyc files
        # held the sources' modification times, which differ with every unpacking.
        epoch = self.env.get("SOURCE_DATE_EPOCH") or self._commit_times[workspace.root] or NO_COMMIT_EPOCH
        return (("SOURCE_DATE_EPOCH", epoch),)

    def reproducible_env(self, workspace: Workspace) -> tuple[tuple[str, str], ...]:
        """SOURCE_DATE_EPOCH, and a fixed PYTHONHASHSEED: rosidl's generators write some lists in
        set order (a service type description's includes), which the hash seed would shuffle.
        CMAKE_INSTALL_ALWAYS: CMake's install skips a file whose destination's time is within a
        second of its own, and rosidl_generator_c and rosidl_typesupport_introspection_c both
        install a detail/X__type_support.c of their own to one path, so which one stayed there
        was up to whether they were generated in the same second; installed always, the last one
        installed stays."""
        return (*self.source_date(workspace), ("PYTHONHASHSEED", "0"), ("CMAKE_INSTALL_ALWAYS", "1"))

    def check_mount(self, workspace: Workspace, image: str, user: str, labels: tuple[tuple[str, str], ...]) -> None:
        """Make sure the engine's containers see the workspace (espdock.images.visibility), once per engine and path."""
        make_dirs_for(workspace.ws_dir / "build", self.owner)
        ensure_engine_sees(self.engine, workspace, image, user, labels)
        if (workspace.ws_dir / "build" / CHECKED).exists():
            give_to(workspace.ws_dir / "build" / CHECKED, self.owner)

    def uses_volume(self, workspace: Workspace, image: str, user: str, labels: tuple[tuple[str, str], ...]) -> bool:
        """Whether WORKSPACE's build containers mount its volume (espdock.images.volume), not the workspace:
        workspace_mode volume, or auto on an engine whose containers do not see the workspace."""
        if workspace.root not in self._volume:
            mode = self.config.workspace_mode
            if mode == "auto":
                make_dirs_for(workspace.ws_dir / "build", self.owner)
                self._volume[workspace.root] = not engine_sees(self.engine, workspace, image, user, labels)
                give_to(workspace.ws_dir / "build" / CHECKED, self.owner)
            else:
                if mode == "mount":
                    self.check_mount(workspace, image, user, labels)
                self._volume[workspace.root] = mode == "volume"
        return self._volume[workspace.root]

    def sync(
        self,
        workspace: Workspace,
        step_name: str,
        image: str,
        user: str,
        labels: tuple[tuple[str, str], ...],
        emptied: tuple[Path, ...] = (),
    ) -> volume.Sync | None:
        """In volume mode, the sources the volume lacks (for the build container's archives), with
        the ones deleted since the last sync, and EMPTIED (host paths), removed from it; None in
        mount mode."""
        if not self.uses_volume(workspace, image, user, labels):
            return None
        make_dirs_for(workspace.ws_dir / "build", self.owner)
        sync = volume.prepare(self.engine, workspace, self.container_owner())
        sync = replace(sync, deleted=(*sync.deleted, *(volume.container_path(workspace, p) for p in emptied)))
        new = " (new)" if sync.fresh else ""
        sent = f"{sync.sent} file(s) sent, {len(sync.deleted)} removed"
        self.emit(StepNote(step_name, f"workspace volume {sync.volume}{new}: {sent}"))
        if sync.deleted:
            spec = RunSpec(
                image=image,
                argv=("rm", "-rf", "--", *sync.deleted),
                workdir="/",
                user=user,
                mounts=(volume.volume_mount(workspace),),
                labels=(*labels, ("io.espdock.step", "volume-sync")),
            )
            output: list[str] = []
            if self.engine.run(spec, output.append) != 0:
                raise EspdockError(
                    f"could not remove deleted sources from volume {sync.volume}: {first_line(chr(10).join(output))}",
                    "Remove the volume (`espdock prune --volume`) and build again: it is made afresh.",
                )
        return sync

    def known_to_need_this_machine(self, workspace: Workspace, what: str, firmware: bool = True) -> None:
        """Refuse WHAT as needs_this_machine does where the answer is known without a container
        (workspace_mode volume, or auto with the engine checked before): before any image work."""
        mode = self.config.workspace_mode
        if mode == "volume" or (mode == "auto" and sees_as_checked(self.engine, workspace) is False):
            raise volume_mode_refused(what, firmware)

    def needs_this_machine(self, workspace: Workspace, image: str, what: str, firmware: bool = True) -> None:
        """Refuse WHAT (a command that needs this machine's files or devices) in volume mode."""
        user, labels = self.container_identity(workspace, "mount-check", sweep=False)
        if self.uses_volume(workspace, image, user, labels):
            raise volume_mode_refused(what, firmware)

    def workspace_for(self, workspace: Workspace, image: str, step_label: str) -> Mount:
        """The workspace for an interactive container of IMAGE (espdock shell): the bind mount, or in
        volume mode the volume, with the sources synced first (and sent again by the next build)."""
        user, labels = self.container_identity(workspace, step_label, sweep=False)
        sync = self.sync(workspace, step_label, image, user, labels)
        if sync is None:
            return workspace_mount(workspace)
        mounts, archives = self.workspace_in(workspace, sync)
        spec = RunSpec(image=image, argv=("true",), workdir="/", user=user, mounts=tuple(mounts),
                       labels=(*labels, ("io.espdock.step", "volume-sync")), archives=tuple(archives))  # fmt: skip
        output: list[str] = []
        if self.engine.run(spec, output.append) != 0:
            said = first_line(chr(10).join(output))
            raise EspdockError(f"could not send the sources to volume {sync.volume}: {said}")
        # What the shell changes stays on the volume: recorded as unknown, the next build sends
        # every source again, and builds the host's, not the shell's edits.
        volume.record(workspace, self.engine, volume.unknown(sync), sync.installed)
        give_to(workspace.ws_dir / "build" / volume.SYNCED, self.owner)
        return mounts[0]

    def workspace_in(
        self, workspace: Workspace, sync: volume.Sync | None
    ) -> tuple[list[Mount], list[tuple[str, bytes]]]:
        """The mounts and archives that give a build container the workspace: the bind mount, or
        the volume and SYNC's changed sources."""
        if sync is None:
            check_trees_inside(workspace)
            return [workspace_mount(workspace)], []
        return [volume.volume_mount(workspace)], [(volume.WORKSPACE_MOUNT, sync.archive)]

    def container_identity(
        self, workspace: Workspace, step_label: str, sweep: bool
    ) -> tuple[str, tuple[tuple[str, str], ...]]:
        """The user a workspace container runs as, and its labels.

        With SWEEP, containers with the same labels are removed first: left by an espdock
        killed outright. Only a caller holding the workspace lock may sweep, since only
        then can none of them be live here; a live espdock's elsewhere (another PID namespace
        at the same path, which another lock holds) are left alone.
        """
        labels = {LABEL_WORKSPACE: str(workspace.root), "io.espdock.step": step_label}
        if sweep:
            self.engine.remove_containers(labels)
        return self.container_user(), tuple(labels.items())

    def container_user(self) -> str:
        uid, gid = self.container_owner()
        return f"{uid}:{gid}"

    def shared_group(self, workspace: Workspace) -> tuple[int, ...]:
        """The workspace's group, where the invoking user is in it but not by their primary group
        (a setgid directory a team shares): a container runs with the primary group alone, and
        was refused the group-writable trees a teammate's build left."""
        if self.engine.info().rootless:
            return ()
        uid, gid = self.owner
        try:
            group = workspace.root.stat().st_gid
            member = os.getgrouplist(pwd.getpwuid(uid).pw_name, gid) if uid != os.getuid() else os.getgroups()
        except (OSError, KeyError):
            return ()
        return (group,) if group != gid and group in member else ()

    def container_owner(self) -> tuple[int, int]:
        """Who a container writing into the workspace runs as, so its files are the invoking user's:
        that user's uid, gid, or in a rootless engine 0, 0, which is the engine's own user outside."""
        return (0, 0) if self.engine.info().rootless else self.owner


# The umask of the engine's containers (Docker's and Podman's): what they write is 0644, 0755.
CONTAINER_UMASK = 0o022


def with_host_umask(argv: tuple[str, ...]) -> tuple[str, ...]:
    """ARGV, run with the host's umask where it lets the group (or others) write what 022 does
    not: a workspace a group shares (umask 002, a setgid directory) gets build trees its members
    can rebuild, as colcon on the host makes them; the containers' 0755 log/ and build/ refused
    the teammate's build. A stricter umask (077) is not taken: what the containers write stays
    readable to the runtime image's user."""
    mask = os.umask(0)
    os.umask(mask)
    if mask == CONTAINER_UMASK or mask & ~CONTAINER_UMASK:
        return argv
    return ("sh", "-c", 'umask "$0" && exec "$@"', f"{mask:04o}", *argv)


def make_dirs_for(directory: Path, owner: tuple[int, int]) -> None:
    """mkdir -p DIRECTORY; as root, the directories it creates belong to OWNER."""
    missing = [d for d in (directory, *directory.parents) if not d.exists()]
    directory.mkdir(parents=True, exist_ok=True)
    for created in missing:
        give_to(created, owner)


def give_to(path: Path, owner: tuple[int, int]) -> None:
    if os.geteuid() == 0:
        os.chown(path, *owner)


def permission_error(
    exc: PermissionError, user: tuple[int, int] | None = None, within: Path | None = None
) -> WorkspaceError:
    """A path espdock may not write or read, named with its owner (a rootless engine's files, say).
    USER: the uid, gid the build that was refused writes as (`sudo espdock build` in another
    user's workspace builds as that user), else espdock's own. WITHIN (the colcon root): the
    hint's chown takes the topmost directory under it of the same other owner, so one command
    gives back all a `sudo colcon build` left, not one file per run."""
    path = Path(exc.filename) if exc.filename else None
    owner = ""
    top = denied = None
    owner_uid = None
    if path is not None:
        try:
            denied = path if path.exists() or path.is_symlink() else path.parent
            if denied != path and path.name.endswith(".tmp"):
                # A file espdock was about to write beside its own (durable's temporary): name the
                # directory, not a name the user never sees.
                path = denied
            info = denied.lstat()
            owner_uid = info.st_uid
            where = "" if denied == path else ", its directory"
            owner = f" (owner uid {info.st_uid}, mode {info.st_mode & 0o7777:04o}{where})"
            top = _topmost_of(denied, info.st_uid, within)
        except OSError:
            pass
    writer = os.geteuid() if user is None else user[0]
    if user is None:
        who, chown = f"espdock runs as uid {os.geteuid()}", "$(id -u):$(id -g)"
    else:
        who, chown = f"the build writes as uid {user[0]}", f"{user[0]}:{user[1]}"
    if owner_uid == writer:
        # Its own file, without the write bit (a `chmod -R a-w` tree): no owner to give it back to.
        return WorkspaceError(
            f"permission denied on {path}{owner}; {who}, its owner, but its mode does not let it write",
            f"Let its owner write it (`chmod u+w {shlex.quote(str(denied))}`), or build elsewhere.",
        )
    mine = top if top is not None else denied
    give_back = f"sudo chown -R {chown} {shlex.quote(str(mine)) if mine is not None else 'PATH'}"
    return WorkspaceError(
        f"permission denied on {path or 'a workspace file'}{owner}; {who}",
        f"Give it back (`{give_back}`), or work in a copy of your own. Where a container wrote it as another "
        "user, that is the engine's doing: see the Engines page of espdock's docs (rootless engines).",
    )


def _topmost_of(path: Path, uid: int, within: Path | None) -> Path | None:
    """The highest of PATH and its parents below WITHIN that UID owns, PATH's owner; None without WITHIN."""
    if within is None or not path.is_relative_to(within) or path == within:
        return None
    top = path
    while top.parent != within and top.parent.is_relative_to(within) and top.parent.lstat().st_uid == uid:
        top = top.parent
    return top


def prepare_output(path: Path, owner: tuple[int, int], option: str, directory: bool = False) -> None:
    """Make sure espdock can write an output it was asked for (`--report FILE`, `--results DIR`)
    before any work: the missing directories made (as root, OWNER's), anything in the way
    refused, so a CI job learns of it at once and not as a failure after its build."""
    where = path if directory else path.parent
    try:
        if directory and path.exists() and not path.is_dir():
            raise ConfigError(f"{option} {path}: that is a file, and {option} names a directory", "Name a directory.")
        if not directory and path.is_dir():
            raise ConfigError(f"{option} {path}: that is a directory, and {option} names a file", "Name a file.")
        try:
            make_dirs_for(where, owner)
        except (FileExistsError, NotADirectoryError):
            raise ConfigError(f"{option} {path}: a file is in the way of its directory", "Name another path.") from None
        writable = os.access(where, os.W_OK | os.X_OK) and (directory or not path.exists() or os.access(path, os.W_OK))
        if not writable:
            raise PermissionError(13, "Permission denied", str(path if path.exists() else where))
    except OSError as exc:
        if isinstance(exc, PermissionError) and _owner(exc.filename) not in (None, 0):
            raise permission_error(exc) from None  # a user's leftover (a `sudo` run's): chown it back
        # Root's directory (/root/x as a user: even asking whether it exists is refused), a
        # system one (/proc): no chown of the user's to give, another path to name.
        raise ConfigError(
            f"{option} {path}: espdock (uid {os.geteuid()}) cannot write there ({exc.strerror or exc})",
            "Name a path you can write, e.g. in the workspace.",
        ) from None


def _owner(path: str | None) -> int | None:
    try:
        return os.stat(path).st_uid if path else None
    except OSError:
        return None


def check_trees_inside(workspace: Workspace) -> None:
    """Refuse a build/, install/ or log/ of the colcon root that links out of the workspace: a
    build container sees only the workspace, where that link leads nowhere (colcon failed on
    FileNotFoundError: /workspace/build/espdock-ros, the hint blaming options never given)."""
    root = workspace.root.resolve()
    for name in ("build", "install", "log"):
        tree = workspace.ws_dir / name
        if tree.is_symlink() and not tree.resolve().is_relative_to(root):
            raise WorkspaceError(
                f"{tree} links to {tree.resolve()}, outside the workspace: the build containers see only the "
                f"workspace ({root}), where that link leads nowhere",
                f"Make {name}/ a directory of the workspace (or link it to one inside it); nothing was built.",
            )


def volume_mode_refused(what: str, firmware: bool = True) -> WorkspaceNotVisible:
    """The error of a command that needs this machine's files or devices (WHAT) in volume mode;
    FIRMWARE: one that would write firmware to a board, which any flasher can do instead."""
    elsewhere = (
        "; the firmware `espdock build` installed is in install/<package>/share/<package>/firmware for any flasher"
        if firmware
        else ""
    )
    return WorkspaceNotVisible(
        f"the build containers use the workspace's volume (workspace_mode: an engine that does not see this "
        f"machine, or volume chosen), and {what} must be on this machine",
        "Use an engine that sees this machine's files and devices for it (a local engine: unset DOCKER_HOST, "
        f"or ESPDOCK_WORKSPACE_MODE=mount with an engine sharing the path){elsewhere}.",
    )


# The Docker SDK's text of an engine's error answer, around the engine's own message.
_SDK_ERROR = re.compile(r'^\d{3} (?:Client|Server) Error for \S+: [^(]*\("(?P<said>.*)"\)\s*$', re.DOTALL)


def first_line(text: str) -> str:
    """TEXT's first line, cut at 200 characters: what a one-line message has room for. Of the Docker
    SDK's text, the engine's own message, which the 200 characters of the URL before it cut off."""
    if match := _SDK_ERROR.match(text.strip()):
        text = match.group("said")
    return (text.strip().splitlines() or ["no details"])[0][:200]
