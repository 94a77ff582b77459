"""`espdock run` and `espdock shell`: a workspace's nodes in its runtime image, a shell in its build image."""

from __future__ import annotations

import difflib
import itertools
import json
import os
import posixpath
import re
import shlex
from collections.abc import Iterable, Mapping
from pathlib import Path, PurePosixPath

from espdock.build.stamps import listing_digest
from espdock.build.steps import LABEL_WORKSPACE, EnsureBaseImage, EnsureImage, Plan, container_path
from espdock.errors import ConfigError, WorkspaceError
from espdock.images.containers import give_to, make_dirs_for
from espdock.images.specs import Mount, RunSpec
from espdock.images.visibility import links_out
from espdock.layout import ROS_BUILD_BASE, ROS_OFFICIAL_DOCKERFILE, WORKSPACE_MOUNT
from espdock.ros.colcon import egg_info_order_define
from espdock.ros.plan import RUNTIME_INSTALL, RuntimeImage
from espdock.ros.runtime_tree import resolve_installed
from espdock.ros.staleness import ros_stamp_file
from espdock.workspace import Package, PackageKind, Workspace, build_running, left_out, select_up_to

# What reaches a node from the caller's environment, as `ros2 run` would see it.
PASSED_ENV = (
    "ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE", "ROS_STATIC_PEERS", "ROS_LOCALHOST_ONLY",
    "RMW_IMPLEMENTATION", "FASTDDS_BUILTIN_TRANSPORTS", "FASTRTPS_DEFAULT_PROFILES_FILE",
    "FASTDDS_DEFAULT_PROFILES_FILE", "ROS_DISCOVERY_SERVER", "ROS_SUPER_CLIENT", "RCUTILS_COLORIZED_OUTPUT",
    "RCUTILS_CONSOLE_OUTPUT_FORMAT", "RCUTILS_LOGGING_BUFFERED_STREAM", "RCUTILS_LOGGING_USE_STDOUT",
    "PYTHONUNBUFFERED",
)  # fmt: skip
# Not passed whatever --env says: the image's own ROS (a host's sourced ROS_DISTRO would lie to
# the node), and where the container keeps its install tree.
IMAGE_ENV = (
    "ROS_DISTRO", "ROS_VERSION", "ROS_PYTHON_VERSION", "AMENT_PREFIX_PATH", "PYTHONPATH", "LD_LIBRARY_PATH", "PATH",
    "VIRTUAL_ENV",
)  # fmt: skip
# Fast DDS's XML profiles, by the file these name: a path on the host, which the container has
# only where espdock mounts it (Fast DDS only warns about a missing one, and runs on defaults).
PROFILE_VARIABLES = ("FASTRTPS_DEFAULT_PROFILES_FILE", "FASTDDS_DEFAULT_PROFILES_FILE")
PROFILES_DIR = "/opt/espdock/dds"
# Containers have their own /dev/shm, so Fast DDS's shared-memory transport loses topics
# between them (micro-ROS/docker#85): UDP only, unless the caller says otherwise.
DDS_DEFAULTS = (("FASTDDS_BUILTIN_TRANSPORTS", "UDPv4"),)
# The host network: nodes reach the host's and each other's DDS traffic. A compose network's
# name instead joins that project's services.
DEFAULT_NETWORK = "host"


def executables(install: Path, package: str, root: Path | None = None) -> list[str]:
    """The executables `ros2 run` would find for PACKAGE in the install tree INSTALL (ROOT: the
    workspace root, where the links of a symlink install lead)."""
    directory = install / package / "lib" / package
    found = []
    try:
        for entry in directory.iterdir():
            path = resolve_installed(entry, root if root is not None else install.parent)
            if path is not None and path.is_file() and os.access(path, os.X_OK):
                found.append(entry.name)
    except OSError:  # none, or another user's this one may not read (mode 0700): nothing to run here
        return []
    return sorted(found)


# Above this many packages with executables, a hint names the packages, not each one's executables.
LISTED = 8


def find_executable(workspace: Workspace, packages: tuple[Package, ...], package: str, executable: str) -> str:
    """Where EXECUTABLE of PACKAGE is in the runtime image; a WorkspaceError listing what exists otherwise."""
    install = workspace.ws_dir / "install"
    ros = [p.name for p in packages if p.kind is PackageKind.ROS]
    runnable = {name: found for name in ros if (found := executables(install, name, workspace.root))}
    if len(runnable) > LISTED:  # each package's executables, in a workspace of dozens, made a hint of pages
        listing = f"{len(runnable)} packages: {', '.join(sorted(runnable))}"
    else:
        listing = "; ".join(f"{name}: {', '.join(found)}" for name, found in sorted(runnable.items())) or "none"
    if any(p.name == package and p.kind is PackageKind.FIRMWARE for p in packages):
        # Its `ros2 run` commands (flash, idf, monitor) run espdock on the host, not in a node's image.
        raise WorkspaceError(
            f"'{package}' is a firmware package: it runs on the board, not in the runtime image",
            f"`espdock flash {package} --port PORT` (or `ros2 run {package} flash --port PORT`) writes it to the "
            f"board, and `espdock monitor {package} --port PORT` shows its output.",
        )
    if package not in ros:
        # A package an ignore marker leaves out, a project colcon would build without a package.xml,
        # or one renamed or removed on this branch ("Did you mean" offered another package by its
        # letters): said as the build says it.
        why = f": {out.what}" if (out := left_out(workspace).get(package)) else ""
        # Among those it could run, or might once built: a renamed package's old name got an
        # (installed) interface package's.
        offered = [name for name in ros if name in runnable or not (install / name).is_dir()]
        close = difflib.get_close_matches(package, offered, n=1)
        raise WorkspaceError(
            f"no ROS package '{package}' in this workspace{why}",
            f"Did you mean '{close[0]}'? {close[0]}: "
            + (", ".join(runnable.get(close[0], [])) or f"not built yet (`espdock build {close[0]}`)")
            + "."
            if close and not why
            else f"Packages with executables (after `espdock build`): {listing}.",
        )
    built, found = (install / package).is_dir(), executable in runnable.get(package, [])
    if not (built and found) and (running := _running_build(workspace, package)):
        # A build rebuilding it afresh has moved its install aside, or is filling it in: it was
        # "not built yet", whose hint a build then refused.
        raise running
    if not (built and found) and unfinished_builds(workspace, [package]):
        # An interrupted first build installs an ament_python package's lib/ last: "has no
        # executable" blamed its setup.py.
        raise _unfinished(package)
    if not built:
        raise WorkspaceError(f"package '{package}' is not built yet", f"Run `espdock build {package}` first.")
    if not found:
        found = ", ".join(runnable.get(package, [])) or "none (it installs nothing into lib/" + package + ")"
        if executable.endswith(LAUNCH_SUFFIXES):
            # `ros2 launch PKG FILE` habits: espdock run is `ros2 run`.
            raise WorkspaceError(
                f"'{executable}' is a launch file, and `espdock run` runs a package's executables, as `ros2 run` "
                f"does (its executables: {found})",
                # ros2 launch finds a package's launch file by its name in its share/ directory.
                f"Launch it with `ros2 launch {package} {posixpath.basename(executable)}` in `espdock shell` on the "
                "official ROS image "
                '(ros_image = "official"), which has launch and the `ros2` command; the wheels image has neither.',
            )
        close = difflib.get_close_matches(executable, runnable.get(package, []), n=1)
        raise WorkspaceError(
            f"package '{package}' has no executable '{executable}'",
            f"Did you mean '{close[0]}'? {package}: {found}."
            if close
            else f"Its executables: {found}. All packages with executables: {listing}.",
        )
    check_built_by_espdock(workspace, package)
    check_dependencies_built_by_espdock(workspace, packages, package)
    return posixpath.join(RUNTIME_INSTALL, package, "lib", package, executable)


LAUNCH_SUFFIXES = (".launch.py", ".launch.xml", ".launch.yaml", "_launch.py", "_launch.xml", "_launch.yaml")


def check_built_by_espdock(workspace: Workspace, package: str) -> None:
    """Refuse PACKAGE's install tree when espdock's last build did not leave it so: a native
    `colcon build` rewrites it with the host's paths and interpreters, which the runtime image
    lacks (the node would die with exit 127). `espdock build` rebuilds exactly such packages."""
    if _left_by_espdock(ros_stamp_file(workspace).read().get(package), workspace.ws_dir / "install" / package):
        return
    if running := _running_build(workspace, package):
        raise running
    if unfinished_builds(workspace, [package]):
        raise _unfinished(package)
    raise WorkspaceError(
        f"install/{package} was not built by espdock, or changed since its last `espdock build` "
        "(a colcon build of your own, native or in `espdock shell`?): espdock runs only what its own builds "
        "installed (a native build's executables name the host's paths and Python, which the runtime image "
        "does not have)",
        f"Run `espdock build {package}` (it rebuilds what changed in install/), then run again.",
    )


def _unfinished(package: str) -> WorkspaceError:
    return WorkspaceError(
        f"the last espdock build of {package} did not finish (it failed or was interrupted): "
        f"install/{package} may be half written",
        f"Run `espdock build {package}`, then run again.",
    )


def check_dependencies_built_by_espdock(workspace: Workspace, packages: tuple[Package, ...], package: str) -> None:
    """Refuse, as check_built_by_espdock does PACKAGE's, the install tree of a workspace package
    PACKAGE depends on that a native `colcon build` rewrote: the runtime image was made of it
    without a word, and the node died importing it (its modules under the host's Python version,
    its scripts' and libraries' host paths). One a build did not finish is named where the image
    is made, as before."""
    recorded = ros_stamp_file(workspace).read()
    depended = [p.name for p in select_up_to(packages, [package]) if p.name != package and p.kind is PackageKind.ROS]
    unfinished = set(unfinished_builds(workspace, depended))
    for name in depended:
        install = workspace.ws_dir / "install" / name
        if name in unfinished or not install.is_dir() or _left_by_espdock(recorded.get(name), install):
            continue
        if running := _running_build(workspace, name):
            raise running
        raise WorkspaceError(
            f"install/{name}, which {package} depends on, was not built by espdock, or changed since its last "
            "`espdock build` (a colcon build of your own, native or in `espdock shell`?): the runtime image would "
            "hold it as it is, with the host's paths and interpreters",
            f"Run `espdock build {name}` (it rebuilds what changed in install/), then run again.",
        )


def _running_build(workspace: Workspace, package: str) -> WorkspaceError | None:
    """The error to give where an espdock build runs in WORKSPACE: PACKAGE's install may be half rebuilt."""
    if (holder := build_running(workspace)) is None:
        return None
    return WorkspaceError(
        f"an espdock build is running in {workspace.root}{holder}: install/{package} may be half rebuilt",
        "Wait for it to finish, then run again.",
    )


def _left_by_espdock(recorded: object, install: Path) -> bool:
    """Whether the install tree INSTALL is as the finished espdock build RECORDED (its entry in the
    stamp file) left it."""
    listing = listing_digest(install)
    return _finished(recorded) and listing is not None and recorded.get("installed") == listing


def _finished(recorded: object) -> bool:
    # A record without a stamp names only where a build that did not finish was building from.
    return isinstance(recorded, dict) and "stamp" in recorded


def unfinished_builds(workspace: Workspace, names: Iterable[str]) -> list[str]:
    """Of NAMES, the packages whose last espdock build did not finish (it failed, was interrupted,
    or its espdock was killed): espdock's colcon configured them (its own build base), and no
    build of them finished since, so their install trees may be half written."""
    recorded = ros_stamp_file(workspace).read()
    base = workspace.ws_dir / ROS_BUILD_BASE
    return [name for name in names if not _finished(recorded.get(name)) and (base / name).is_dir()]


def node_env(env: Mapping[str, str], mounted: bool = True) -> tuple[tuple[str, str], ...]:
    """The node's environment: DDS_DEFAULTS, then what PASSED_ENV names from ENV, a profiles file
    where profile_mounts mounts it (MOUNTED; else left out: its host path means nothing there)."""
    values = dict(DDS_DEFAULTS) | {name: env[name] for name in PASSED_ENV if name in env}
    for name in PROFILE_VARIABLES:
        if values.get(name):
            if mounted:
                values[name] = f"{PROFILES_DIR}/{name}.xml"
            else:
                del values[name]
    return tuple(sorted(values.items()))


# The terminal types the images' terminfo knows (Debian's ncurses-base). Another (xterm-kitty,
# alacritty, foot, wezterm, ghostty) had `clear` and `less` say "unknown terminal type": those
# speak xterm's, as the engine's default had them.
IMAGE_TERMINALS = frozenset(
    "Eterm Eterm-color ansi cons25 cons25-debian cygwin dumb hurd linux mach mach-bold mach-color mach-gnu "
    "mach-gnu-color pcansi rxvt rxvt-basic rxvt-m rxvt-unicode rxvt-unicode-256color screen screen-256color "
    "screen-256color-bce screen-bce screen-s screen-w screen.xterm-256color sun tmux tmux-256color vt100 vt102 "
    "vt220 vt52 wsvt25 wsvt25m xterm xterm-256color xterm-color xterm-debian xterm-mono xterm-r5 xterm-r6 "
    "xterm-vt220 xterm-xfree86".split()
)


def terminal_env(env: Mapping[str, str], tty: bool) -> tuple[tuple[str, str], ...]:
    """The caller's TERM for a container at their terminal (TTY), where the images know it: the
    engine's default, xterm, gave Emacs' `M-x shell` (TERM=dumb) bash's bracketed-paste escapes
    and a colour prompt."""
    if not tty or not (term := env.get("TERM")):
        return ()
    return (("TERM", term if term in IMAGE_TERMINALS else "xterm-256color"),)


def profile_mounts(env: Mapping[str, str], cwd: Path) -> tuple[Mount, ...]:
    """The Fast DDS profiles files ENV names (relative to CWD), each mounted where node_env says;
    a ConfigError (exit 2) for one that is not a file, which Fast DDS would only warn about."""
    mounts = []
    for name in PROFILE_VARIABLES:
        if not (value := env.get(name)):
            continue
        path = cwd / Path(value).expanduser()
        if not path.is_file():
            raise ConfigError(
                f"{name}={value}: no such file ({path})",
                "Fast DDS would warn and run the node on its default settings: name the XML profiles file on "
                "this machine (espdock mounts it into the container), or unset the variable.",
            )
        mounts.append(Mount(path.resolve(), f"{PROFILES_DIR}/{name}.xml", read_only=True))
    return tuple(mounts)


def runtime_plan(plan: Plan) -> tuple[Plan, RuntimeImage]:
    """From a ROS build plan: the plan that only ensures the runtime image, and its step."""
    step = next((s for s in plan.steps if isinstance(s, RuntimeImage)), None)
    if step is None:
        if not any(isinstance(s, EnsureImage) for s in plan.steps):
            raise WorkspaceError("this workspace has no ROS packages to run", "Add one under its package paths.")
        raise WorkspaceError(
            "the workspace's ROS Dockerfile has no `runtime` stage, so there is no runtime image to run in",
            "Add a stage `FROM ... AS runtime` (espdock's default Dockerfile.ros has one).",
        )
    steps = [s for s in plan.steps if isinstance(s, EnsureBaseImage)]
    steps += [s for s in plan.steps if isinstance(s, EnsureImage) and s.spec.key == step.base.key]
    return Plan(plan.workspace, (*steps, step)), step


def build_image_plan(plan: Plan) -> tuple[Plan, str, str]:
    """From a ROS build plan: the plan that only ensures the build image, its tag and its Dockerfile."""
    steps = [s for s in plan.steps if isinstance(s, EnsureBaseImage)]
    images = [s for s in plan.steps if isinstance(s, EnsureImage) and s.spec.target == "build"]
    if not images:
        raise WorkspaceError("this workspace has no ROS packages, so no ROS build image", "Add one first.")
    return Plan(plan.workspace, (*steps, images[0])), images[0].spec.tag, images[0].spec.dockerfile


def installed_ros_packages(workspace: Workspace, packages: tuple[Package, ...]) -> list[str]:
    """The workspace's ROS packages that have an install tree (what a runtime image would hold)."""
    install = workspace.ws_dir / "install"
    return [p.name for p in packages if p.kind is PackageKind.ROS and (install / p.name).is_dir()]


def volume(text: str, cwd: Path) -> Mount:
    """`--volume HOST:CONTAINER[:ro]` as a bind mount: HOST (relative to CWD) must exist, CONTAINER
    be absolute; a ConfigError (exit 2) naming the option otherwise."""
    parts = text.split(":")
    if len(parts) not in (2, 3) or not all(parts[:2]) or parts[2:] not in ([], ["ro"], ["rw"]):
        raise ConfigError(
            f"--volume {text}: expected HOST:CONTAINER or HOST:CONTAINER:ro",
            "For example: --volume ./joy.yaml:/params/joy.yaml:ro (a ':' in a path cannot be mounted this way).",
        )
    host = (cwd / Path(parts[0]).expanduser()).resolve()
    if not host.exists():
        raise ConfigError(f"--volume {text}: {host} does not exist", "Give a file or directory on this machine.")
    if not posixpath.isabs(parts[1]):
        raise ConfigError(f"--volume {text}: the container path must be absolute", "For example: /params/joy.yaml.")
    return Mount(host, posixpath.normpath(parts[1]), read_only=parts[2:] == ["ro"])


# Where a node starts (node_spec's workdir): a relative file argument is read there.
NODE_WORKDIR = "/tmp"


def check_file_arguments(workspace: Workspace, args: Iterable[str], mounts: Iterable[Mount], cwd: Path) -> None:
    """Refuse a `--params-file FILE` in a node's ARGS that names a file of this machine the node
    cannot see (no --volume among MOUNTS holds it): rcl's "Couldn't parse params file" said
    nothing of why. Only files of the workspace, here or of the home directory: another path may
    be the image's too. A file of the workspace's install/ is in the runtime image: its path there."""
    targets = [m.target for m in mounts]
    for option, value in itertools.pairwise(args):
        if option != "--params-file":
            continue
        inside = posixpath.normpath(posixpath.join(NODE_WORKDIR, value))
        if any(PurePosixPath(inside).is_relative_to(t) for t in (*targets, RUNTIME_INSTALL)):
            continue
        host = Path(os.path.abspath(cwd / Path(value).expanduser()))
        # A --symlink-install's file may be a link that leads nowhere here (to /workspace/...).
        if not os.path.lexists(host):
            continue  # a file of the image, or none: rcl says which
        home = os.environ.get("HOME")
        mine = (workspace.root, workspace.root.resolve(), cwd, *([Path(home)] if home else []))
        # As given and with its links resolved: a path through a link to the workspace is of it too.
        ways = (host, Path(os.path.realpath(host)))
        if not any(way.is_relative_to(place) for way in ways for place in mine):
            continue  # /opt/ros/... of a ROS on this machine is the official image's as well
        install = next(
            (
                (way, i)
                for way in ways
                for i in (workspace.ws_dir / "install", workspace.ws_dir.resolve() / "install")
                if way.is_relative_to(i)
            ),
            None,
        )
        if install is not None:
            there = posixpath.join(RUNTIME_INSTALL, install[0].relative_to(install[1]).as_posix())
            fix = f"The runtime image holds install/ at {RUNTIME_INSTALL}: pass `--params-file {there}`."
        else:
            mount, inside = shlex.quote(f"{value}:/params/{host.name}:ro"), shlex.quote(f"/params/{host.name}")
            fix = f"Mount it: `espdock run -v {mount} ... --params-file {inside}`."
        raise ConfigError(
            f"--params-file {value}: the node runs in a container, which has no {host} (it sees only the "
            "runtime image and what --volume mounts)",
            fix,
        )


def variable(text: str, env: Mapping[str, str]) -> tuple[str, str] | None:
    """`--env NAME=VALUE`, or `--env NAME` for ENV's value (None where ENV has none, as `docker
    run -e` leaves it out); a ConfigError (exit 2) naming the option for a malformed one or one of
    IMAGE_ENV."""
    name, given, value = text.partition("=")
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", name):
        raise ConfigError(f"--env {text}: expected NAME=VALUE or NAME", "For example: --env ROBOT_SITE=lab.")
    if name in IMAGE_ENV:
        raise ConfigError(
            f"--env {text}: {name} is the runtime image's own (its ROS and install tree)",
            "Give the node's settings as variables of its own, or as --ros-args parameters.",
        )
    if not given:
        return (name, env[name]) if name in env else None
    return name, value


def device(text: str) -> tuple[str, str]:
    """`--device HOST[:CONTAINER]`: HOST must be a device file, CONTAINER (default: the same path)
    absolute; a ConfigError (exit 2) naming the option otherwise."""
    host, _, inside = text.partition(":")
    inside = inside or host
    if not host.startswith("/") or not inside.startswith("/") or ":" in inside:
        raise ConfigError(f"--device {text}: expected HOST[:CONTAINER], absolute paths", "For example: /dev/ttyUSB0.")
    if not os.path.exists(host):
        raise ConfigError(f"--device {text}: {host} does not exist", "Is the board plugged in? See `ls /dev/tty*`.")
    if not (Path(host).is_char_device() or Path(host).is_block_device()):
        raise ConfigError(f"--device {text}: {host} is not a device", "Files and directories go with --volume.")
    return os.path.realpath(host), posixpath.normpath(inside)


def _labels(workspace: Workspace, what: str) -> tuple[tuple[str, str], ...]:
    return ((LABEL_WORKSPACE, str(workspace.root)), ("io.espdock.step", what))


# Without a terminal espdock passes Ctrl-C on to the container's PID 1, tini (the images'
# entrypoint), which passes it to its child alone: a shell reading a script from stdin waited for
# the command it ran, which never got it, then ran the rest. tini -g's setting: to the child's
# process group, as a terminal sends it.
SIGNAL_GROUP = ("TINI_KILL_PROCESS_GROUP", "1")


def node_spec(
    workspace: Workspace,
    image: str,
    path: str,
    args: tuple[str, ...],
    owner: tuple[int, int],
    env: Mapping[str, str],
    network: str,
    tty: bool,
    mounts: tuple[Mount, ...] = (),
    devices: tuple[tuple[str, str], ...] = (),
    variables: tuple[tuple[str, str], ...] = (),
    cwd: Path | None = None,
) -> RunSpec:
    """A container of IMAGE running the node at PATH with ARGS, as OWNER, with MOUNTS and DEVICES
    (host, container) passed in; OWNER also gets the devices' groups (a serial port's dialout).
    VARIABLES (--env) come last: they win. CWD: what relative profile paths are relative to."""
    given = dict(variables)
    own = (("HOME", "/tmp"), SIGNAL_GROUP, *terminal_env(env, tty), *node_env(env))
    passed = [(name, value) for name, value in own if name not in given]
    return RunSpec(
        image=image,
        argv=(path, *args),
        workdir=NODE_WORKDIR,
        user=f"{owner[0]}:{owner[1]}",
        mounts=(*mounts, *profile_mounts(env, cwd or Path.cwd())),
        env=(*passed, *given.items()),
        labels=_labels(workspace, "run"),
        devices=tuple(f"{host}:{inside}" for host, inside in devices),
        group_add=tuple(sorted({os.stat(host).st_gid for host, _ in devices})),
        network=network,
        tty=tty,
    )


# The official image's build stage keeps its own entrypoint (/ros_entrypoint.sh, ROS only): the
# shell sources the install tree itself, which it names as an argument, not in the script.
SOURCE_AND_SHELL = 'if [ -f "$1/local_setup.bash" ]; then . "$1/local_setup.bash"; fi; exec bash'


# The shell's home, under the colcon root's build/: its history and ~/.ros outlive the container.
SHELL_HOME = "build/espdock-home"
# The containers' /etc/passwd has no line for the user: bash's prompt would say "I have no name!".
SHELL_BASHRC = """\
# espdock shell's ~/.bashrc (the home is build/espdock-home: history and ~/.ros stay between shells).
# The container's /etc/passwd does not know you, so the prompt names you from $USER.
if ! id -un >/dev/null 2>&1; then PS1='${USER:-me}@\\h:\\w\\$ '; fi
"""


# colcon run in the shell builds where `espdock build` does: one set of CMake caches, which
# neither takes for another build's (espdock retires caches configured at the container's
# default build/ as its own old ones).
SHELL_COLCON_DEFAULTS = """\
# espdock shell's colcon defaults (COLCON_DEFAULTS_FILE): colcon here builds where `espdock build`
# does, build/espdock-ros, so the two share CMake caches and never remove each other's.
build:
  build-base: build/espdock-ros
test:
  build-base: build/espdock-ros
"""


def shell_colcon_defaults(define: str, tests_off: bool = False) -> str:
    """SHELL_COLCON_DEFAULTS with the CMake arguments espdock's builds give (DEFINE:
    egg_info_order_define; TESTS_OFF: BUILD_TESTING=OFF, as on the wheels image, which has no
    ament_lint_auto for `ros2 pkg create`'s packages), for the build dirs a colcon build in the
    shell configures itself."""
    args = [define, *(["-DBUILD_TESTING=OFF"] if tests_off else [])]
    return SHELL_COLCON_DEFAULTS.replace(
        "build:\n  build-base: build/espdock-ros\n",
        f"build:\n  build-base: build/espdock-ros\n  cmake-args: [{', '.join(map(json.dumps, args))}]\n",
    )


def make_shell_home(workspace: Workspace, owner: tuple[int, int], tests_off: bool = False) -> None:
    """The shell's home on the workspace (SHELL_HOME), with its .bashrc and colcon defaults
    written once (then the user's to edit; defaults as espdock writes them, unedited, follow
    espdock's and the image's: TESTS_OFF, shell_colcon_defaults), all OWNER's."""
    home = workspace.ws_dir / SHELL_HOME
    make_dirs_for(home, owner)
    define = egg_info_order_define(container_path(workspace.colcon_root))
    defaults = shell_colcon_defaults(define, tests_off)
    ours = {SHELL_COLCON_DEFAULTS, shell_colcon_defaults(define), shell_colcon_defaults(define, True)}
    for name, text, older in (
        (".bashrc", SHELL_BASHRC, set()),
        ("colcon-defaults.yaml", defaults, ours),
    ):
        written = home / name
        now = written.read_text() if written.exists() else None
        if now is None or (now in older and now != text):
            written.write_text(text)
            give_to(written, owner)


def shell_spec(
    workspace: Workspace,
    image: str,
    owner: tuple[int, int],
    env: Mapping[str, str],
    tty: bool,
    dockerfile: str = "",
    mount: Mount | None = None,
    packages: Iterable[Package] = (),
    cwd: Path | None = None,
    user_name: str | None = None,
    build_env: tuple[tuple[str, str], ...] = (),
) -> RunSpec:
    """A shell in the build IMAGE (made from DOCKERFILE) with the workspace mounted (MOUNT: its
    volume instead, espdock.volume), the directories the links to its ROS PACKAGES lead to (as a
    build has them) and its install tree sourced; in CWD where that is in the colcon root, else
    there; as USER_NAME (USER, LOGNAME), with SHELL_HOME as its home on the workspace's mount.
    BUILD_ENV: what espdock's build containers get for reproducible output (SOURCE_DATE_EPOCH, ...):
    a colcon build in the shell builds where theirs do."""
    root = container_path(workspace.colcon_root)
    official = dockerfile == ROS_OFFICIAL_DOCKERFILE
    mount = mount or Mount(workspace.root, WORKSPACE_MOUNT)
    ros = [p.path for p in packages if p.kind is PackageKind.ROS]
    workdir = root
    # As the shell reached it too: in a package of a src/ that links elsewhere, the resolved path is
    # outside the workspace (the container follows the link, mounted where it leads).
    bases = (workspace.ws_dir, workspace.ws_dir.resolve())
    ways = [(way, base) for way in ((cwd, cwd.resolve()) if cwd is not None else ()) for base in bases]
    if inside := next(((way, base) for way, base in ways if way.is_relative_to(base)), None):
        workdir = posixpath.join(root, inside[0].relative_to(inside[1]).as_posix())
    home = "/tmp" if mount.volume else posixpath.join(root, SHELL_HOME)
    named = (("USER", user_name), ("LOGNAME", user_name)) if user_name else ()
    colcon = () if mount.volume else (("COLCON_DEFAULTS_FILE", f"{home}/colcon-defaults.yaml"),)
    return RunSpec(
        image=image,
        argv=("bash", "-c", SOURCE_AND_SHELL, "bash", f"{root}/install") if official else ("bash",),
        workdir=posixpath.normpath(workdir),
        user=f"{owner[0]}:{owner[1]}",
        mounts=(mount,)
        if mount.volume
        else (mount, *links_out(workspace, ros), *profile_mounts(env, cwd or Path.cwd())),
        # The entrypoint sources this install tree when it exists (docker/ros-entrypoint.sh).
        env=(
            ("HOME", home),
            SIGNAL_GROUP,
            *named,
            *colcon,
            ("ESPDOCK_WS_INSTALL", f"{root}/install"),
            *terminal_env(env, tty),
            *node_env(env, mounted=not mount.volume),
            *build_env,
        ),
        labels=_labels(workspace, "shell"),
        network=DEFAULT_NETWORK,
        tty=tty,
    )
