"""Whether the engine's containers see the workspace where espdock mounts it.

An engine on another machine (DOCKER_HOST=tcp://... or ssh://..., a docker:dind service) mounts
the workspace's path from its own machine: another tree there, or nothing (the engine refuses a
bind of a missing path). Before the first build container, a container reads a nonce file espdock
wrote into the workspace; the answer is kept under the colcon root's build/ for that engine and
path.
"""

from __future__ import annotations

import json
import os
import posixpath
import re
import secrets
import stat
from collections.abc import Iterable
from pathlib import Path, PurePosixPath

from espdock.errors import MountSourceMissing, WorkspaceError, WorkspaceNotVisible
from espdock.images.engine import Engine
from espdock.images.specs import Mount, RunSpec
from espdock.layout import WORKSPACE_MOUNT
from espdock.workspace import Workspace, walk_following_links

CHECKED = ".espdock-engine-sees.json"
PROBE_PREFIX = ".espdock-probe-"


def workspace_mount(workspace: Workspace) -> Mount:
    """The workspace as every build container mounts it (the one place that is decided)."""
    return Mount(workspace.root, WORKSPACE_MOUNT)


# The mount point as a path of its own (not /workspaces, not a/workspace): at the start of a line
# or after a space, quote, bracket, = or :, and followed by / or the end of the path.
_MOUNTED = re.compile(rf"(?<![\w.~/-]){re.escape(WORKSPACE_MOUNT)}(?=/|$|[\s:'\")\],;])")


def host_paths(line: str, workspace: Workspace) -> str:
    """LINE (a tool's output in a build container) with the workspace's paths as the user's: a
    compiler's or CMake's error names /workspace/..., which no editor or terminal can open."""
    if WORKSPACE_MOUNT not in line:
        return line
    root = str(workspace.root)
    return _MOUNTED.sub(lambda _: root, line)


def linked_mounts(workspace: Workspace, paths: Iterable[Path]) -> tuple[Mount, ...]:
    """Mounts for the directories PATHS (under the workspace) that links lead out of it: each real
    directory at the path a build container, which has the workspace at its mount, follows the
    links to: for `ln -s ~/repos/driver src/` the same absolute path; for a relative link, where it
    points from the mount. colcon follows such links; without these mounts they lead nowhere."""
    mounts: dict[str, Mount] = {}
    for path in paths:
        inside = _followed(workspace.root, path, WORKSPACE_MOUNT)
        if inside is None or inside == WORKSPACE_MOUNT or inside.startswith(f"{WORKSPACE_MOUNT}/"):
            continue  # the workspace's own mount has it (or the links loop: colcon says so)
        real = path.resolve()
        if real.is_dir():
            mounts[inside] = Mount(real, inside)
    return tuple(mounts[target] for target in sorted(mounts))


def links_out(workspace: Workspace, roots: Iterable[Path]) -> tuple[Mount, ...]:
    """linked_mounts of the directories ROOTS (packages, firmware projects) and of the links to
    directories within them: what colcon, or IDF, follows there, which the workspace's mount lacks."""
    roots = list(roots)
    return linked_mounts(workspace, [*roots, *(link for root in roots for link in directory_links(root))])


def directory_links(root: Path) -> list[Path]:
    """The links to directories under ROOT, following them (each directory once): a package's
    `config -> ~/common/config`, whose files colcon installs, and linked_mounts must mount."""
    found: list[Path] = []
    for dirpath, dirnames, _ in walk_following_links(root):
        dirnames[:] = sorted(d for d in dirnames if not d.startswith(".") and d != "__pycache__")
        found += [Path(dirpath, d) for d in dirnames if os.path.islink(os.path.join(dirpath, d))]
    return found


def _followed(root: Path, path: Path, mount: str) -> str | None:
    """Where a container with ROOT at MOUNT finds ROOT/... PATH, following its links as the kernel
    would there (a path outside MOUNT is read at the same path here); None for a link loop."""
    pending = list(reversed(path.relative_to(root).parts))
    current, hops = mount, 0
    while pending:
        part = pending.pop()
        if part == "..":
            current = posixpath.dirname(current)
            continue
        candidate = posixpath.join(current, part)
        inside_mount = candidate.removeprefix(mount) if candidate.startswith(f"{mount}/") else None
        here = os.path.join(root, inside_mount.lstrip("/")) if inside_mount is not None else candidate
        if not os.path.islink(here):
            current = candidate
            continue
        hops += 1
        if hops > 40:  # the kernel's own limit
            return None
        target = PurePosixPath(os.readlink(here))
        if target.is_absolute():
            current = "/"
        pending.extend(reversed([p for p in target.parts if p not in ("/", ".")]))
    return current


def ensure_engine_sees(
    engine: Engine, workspace: Workspace, image: str, user: str, labels: tuple[tuple[str, str], ...]
) -> None:
    """Raise unless a container of IMAGE, run as USER, reads the workspace at its mount path."""
    if not engine_sees(engine, workspace, image, user, labels):
        raise not_visible(engine, workspace)


def _check_record(engine: Engine, workspace: Workspace) -> dict[str, str]:
    """What engine_sees's answer for WORKSPACE is kept with: the engine and the mount."""
    mount = workspace_mount(workspace)
    return {"engine": engine.info().identity, "root": str(mount.source), "mount": mount.target}


def sees_as_checked(engine: Engine, workspace: Workspace) -> bool | None:
    """What engine_sees found the last time it asked ENGINE about WORKSPACE, or None: no container needed."""
    record = _check_record(engine, workspace)
    cached = _last_check(workspace)
    if cached is not None and {k: cached.get(k) for k in record} == record:
        return cached.get("sees", True) is True
    return None


def checked_unseen(workspace: Workspace) -> bool:
    """Whether the last engine asked about WORKSPACE could not see it (which engine that was,
    sees_as_checked tells, after a connection to the engine now chosen)."""
    cached = _last_check(workspace)
    return cached is not None and cached.get("sees", True) is False


def _last_check(workspace: Workspace) -> dict | None:
    """engine_sees's kept answer for WORKSPACE, as written; None where there is none to read."""
    try:
        cached = json.loads((workspace.ws_dir / "build" / CHECKED).read_text())
    except (OSError, ValueError):
        return None
    return cached if isinstance(cached, dict) else None


def engine_sees(
    engine: Engine, workspace: Workspace, image: str, user: str, labels: tuple[tuple[str, str], ...]
) -> bool:
    """Whether a container of IMAGE, run as USER, reads the workspace at its mount path; the
    answer, either way, is kept for the engine and path (workspace_mode auto asks it each build)."""
    mount = workspace_mount(workspace)
    if (known := sees_as_checked(engine, workspace)) is not None:
        return known
    nonce = secrets.token_hex(16)
    probe = mount.source / f"{PROBE_PREFIX}{os.getpid()}-{nonce[:8]}"
    output: list[str] = []
    try:
        try:
            probe.write_text(nonce)
            probe.chmod(0o644)
        except OSError as exc:  # a read-only checkout, or one of another user's
            raise WorkspaceError(
                f"espdock cannot write in the workspace {mount.source}: {exc.strerror or exc}",
                "espdock writes there: its build trees (build/, install/, log/), and the file it asks the engine "
                "to find. Let your user write the workspace (`chmod u+w`, or `sudo chown -R $(id -u):$(id -g)` "
                "on what another user owns), or work in a copy of your own.",
            ) from None
        spec = RunSpec(
            image=image,
            # Judged by the exit code: a short container's output can come back empty.
            argv=("sh", "-c", 'test "$(cat "$0")" = "$1"', f"{mount.target}/{probe.name}", nonce),
            workdir="/",
            user=user,
            mounts=(mount,),
            labels=(*labels, ("io.espdock.step", "mount-check")),
        )
        try:
            code = engine.run(spec, output.append)
        except MountSourceMissing as exc:
            if exc.path != str(mount.source):
                raise
            code = None  # Docker's engines refuse a bind of a path their machine lacks
    finally:
        probe.unlink(missing_ok=True)
    if code not in (0, None) and any("permission denied" in line.lower() for line in output):
        raise WorkspaceError(
            f"the build containers (user {user} on the {engine.info().name}) may not read the workspace: "
            f"{_described(mount.source)}",
            "Let that user read and enter it and its parent directories (e.g. `chmod o+rx` on them), "
            "or move the workspace somewhere it can.",
        )
    cache = workspace.ws_dir / "build" / CHECKED
    cache.parent.mkdir(parents=True, exist_ok=True)
    cache.write_text(json.dumps({**_check_record(engine, workspace), "sees": code == 0}) + "\n")
    return code == 0


def not_visible(engine: Engine, workspace: Workspace) -> WorkspaceNotVisible:
    """The error of workspace_mode mount on an engine that does not see the workspace."""
    mount = workspace_mount(workspace)
    return WorkspaceNotVisible(
        f"the {engine.info().name} does not see the workspace {mount.source}: a container does not find "
        f"the file espdock wrote into it (at {mount.target}), so the engine mounts a directory of its own "
        "machine, not this one",
        'Let espdock keep the workspace in a volume on that engine (workspace_mode = "auto" or "volume" in '
        "espdock.toml, or `espdock build --workspace-mode volume`), or build on an engine that shares this "
        "machine's files at the same path: a local engine (unset DOCKER_HOST), or share the path with the "
        "engine's machine. On GitLab with the docker:dind service, keep the workspace under the project's "
        "builds dir ($CI_PROJECT_DIR), which the runner mounts into the service at the same path (the Engines "
        "page of espdock's docs).",
    )


def _described(path: Path) -> str:
    """PATH with its owner and mode, e.g. `/home/ann/ws (owner uid 1000, mode 0700)`."""
    try:
        info = path.stat()
    except OSError:
        return str(path)
    return f"{path} (owner uid {info.st_uid}, mode {stat.S_IMODE(info.st_mode):04o})"
