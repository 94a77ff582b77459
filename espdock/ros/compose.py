"""`espdock init --compose`: the starter compose file of a workspace's nodes and the micro-ROS agent;
and `espdock compose`: where in its arguments Compose's subcommand and options are, the env files
it reads, and what is wrong in the compose file for this workspace."""

from __future__ import annotations

import hashlib
import itertools
import os
import posixpath
import re
from collections.abc import Iterable, Mapping
from pathlib import Path

from espdock.errors import WorkspaceError
from espdock.ros.nodes import executables
from espdock.workspace import Package, PackageKind, Workspace

# REP 144: lower case letters, digits and underscores, starting with a letter, no "__".
COMPOSE_TEMPLATE = """\
# The workspace's nodes as services, written by `espdock init` from what install/ holds;
# `espdock init --compose` writes it again after a build (not once you have edited it).
#
#   espdock build                            builds the packages
#   espdock compose up                       makes the image below of install/, starts the nodes
#   (plain `docker compose up` runs that image as espdock last made it: `runtime_image = true`
#   in espdock.toml makes it with every `espdock build`)
#   espdock compose up talker                only some of them
#   espdock compose --profile hardware up    also the micro-ROS agent, for ESP32 boards
#   espdock compose --profile serial up      the agent for a board on USB/UART (MICROROS_SERIAL_DEVICE)
#   espdock compose --profile '*' down       stops and removes everything
#
# Settings (environment or .env): ROS_DOMAIN_ID (default 0), MICROROS_AGENT_PORT (default 8888).
# ESPDOCK_NAME names the project and the image: `espdock compose` sets it to this workspace's
# name, so a clone, a copy or a git worktree of it runs its own nodes, not this one's (for plain
# `docker compose` there, set ESPDOCK_NAME=<its name> in its environment or .env).
name: {project}

x-ros-node: &ros-node
  # The runtime image of install/ (no compilers) that `espdock compose up` and `espdock run`
  # make when a build changed install/; espdock/{name}:<key> names one of them for good.
  image: {image}
  # As you under `espdock compose`, which sets ESPDOCK_USER to your uid:gid (what a node writes
  # into a mounted directory is yours, as with `espdock run`); plain `docker compose`: the
  # image's own user, ros.
  user: ${{ESPDOCK_USER:-ros}}
  environment: &ros-env
    ROS_DOMAIN_ID: ${{ROS_DOMAIN_ID:-0}}
    # A home any user can write in (rcl's logs go to ~/.ros/log); ros's own.
    HOME: /tmp
    # Fast DDS's default shared-memory transport loses topics between containers, each
    # having its own /dev/shm: UDP only, discovery by multicast on the compose network.
    FASTDDS_BUILTIN_TRANSPORTS: UDPv4
    PYTHONUNBUFFERED: "1"
  # Not restarted: an executable may be a one-shot client or tool, which a restart policy would
  # start again forever. Give the long-running nodes `restart: unless-stopped`.
  restart: "no"

services:
{services}
  # Real boards reach ROS 2 through the micro-ROS agent on UDP port 8888 (the
  # address `espdock provision --agent` gives them is this host's).
  micro_ros_agent:
    image: {agent}
    profiles: [hardware]
    command: [udp4, --port, "8888"]
    environment:
      <<: *ros-env
    ports:
      - "${{MICROROS_AGENT_PORT:-8888}}:8888/udp"
    restart: unless-stopped

  # A board on a serial line (espdock new --transport serial): only its device goes in, as
  # /dev/microros. MICROROS_SERIAL_DEVICE (default /dev/ttyACM0) must exist when it starts.
  micro_ros_agent_serial:
    image: {agent}
    profiles: [serial]
    command: [serial, --dev, /dev/microros, -b, "${{MICROROS_SERIAL_BAUD:-115200}}"]
    devices:
      - "${{MICROROS_SERIAL_DEVICE:-/dev/ttyACM0}}:/dev/microros"
    # As on any other engine where one remaps users (dockerd --userns-remap): remapped, runc cannot
    # make /dev/microros (it bind-mounts the host's node at that path, which the host lacks), nor
    # would the port (root and dialout, 0660) let the remapped root in. A no-op elsewhere.
    userns_mode: host
    environment:
      <<: *ros-env
    restart: unless-stopped
"""
# What `espdock compose` sets to the workspace's name (espdock's own setting of it, ESPDOCK_NAME),
# which the file `espdock init` writes names its project and image by: the file is committed, and
# a clone or git worktree of another name ran the original's image, in the original's project.
NAME_VARIABLE = "ESPDOCK_NAME"
_NAMED = re.compile(r"(?<!\$)\$(?:\{ESPDOCK_NAME(?::?-[^}]*)?\}|ESPDOCK_NAME\b)")
# The first line of a compose file espdock wrote: the hash of the rest, so that a refresh
# (`espdock init --compose`) can tell an untouched file from one a user edited.
COMPOSE_MARK = "# espdock-generated sha256:"


# Compose's global options that take a value (`docker compose --help`), so that the subcommand
# is found after them.
COMPOSE_VALUED_OPTIONS = frozenset(
    {"-f", "--file", "-p", "--project-name", "--profile", "--env-file", "--project-directory", "--ansi",
     "--progress", "--parallel"}
)  # fmt: skip
# espdock's own option among Compose's global ones (Compose has no global -w).
WORKSPACE_OPTIONS = ("--workspace", "-w")
# The subcommands that make containers of the images: the runtime image must be current first.
COMPOSE_CREATING = frozenset({"up", "run", "create", "scale", "watch"})
# Those that stop or remove the project's containers: in another workspace's project, its own.
COMPOSE_ENDING = frozenset({"down", "stop", "rm", "kill", "restart", "pause"})
# A label espdock gives the container of its `compose run`: the one to remove when it is interrupted.
LABEL_COMPOSE_RUN = "io.espdock.compose-run"


def compose_subcommand(args: list[str] | tuple[str, ...]) -> str | None:
    """The Compose subcommand in ARGS (`up` in `-p x --profile sim up -d`), or None."""
    at = compose_subcommand_at(args)
    return None if at is None else args[at]


def compose_subcommand_at(args: list[str] | tuple[str, ...]) -> int | None:
    """Where the Compose subcommand is in ARGS (after the global options), or None."""
    skip = False
    for at, arg in enumerate(args):
        if skip:
            skip = False
        elif arg in COMPOSE_VALUED_OPTIONS or arg in WORKSPACE_OPTIONS:
            skip = True
        elif not arg.startswith("-"):
            return at
    return None


def own_workspace(args: list[str]) -> tuple[list[str], Path | None]:
    """ARGS without espdock's `--workspace DIR` where it stands before Compose's subcommand, among
    Compose's global options (`-p NAME --workspace DIR ps`), and DIR (None: not given)."""
    at = compose_subcommand_at(args)
    before, after = list(args[:at] if at is not None else args), list(args[at:] if at is not None else [])
    kept, workspace = [], None
    pending = iter(before)
    for arg in pending:
        if arg in WORKSPACE_OPTIONS:
            workspace = next(pending, None)
        elif arg.startswith("--workspace="):
            workspace = arg.removeprefix("--workspace=")
        else:
            kept.append(arg)
    return kept + after, Path(workspace) if workspace else None


def global_values(args: list[str] | tuple[str, ...], option: str) -> list[str]:
    """The values of Compose's global OPTION (`--env-file`, `-f`) in ARGS, before its subcommand."""
    at = compose_subcommand_at(args)
    before = list(args[:at] if at is not None else args)
    values = [value for name, value in itertools.pairwise(before) if name == option]
    return values + [arg.removeprefix(f"{option}=") for arg in before if arg.startswith(f"{option}=")]


def compose_env_files(args: list[str] | tuple[str, ...], root: Path, env: Mapping[str, str]) -> list[Path]:
    """The env files a `compose ARGS` run in ROOT reads, as Compose finds them: each `--env-file`,
    else COMPOSE_ENV_FILES', else the project directory's `.env` (--project-directory, else the
    first compose file's directory, else ROOT)."""
    if given := global_values(args, "--env-file"):
        return [root / value for value in given]
    if listed := env.get("COMPOSE_ENV_FILES"):
        return [root / value for value in listed.split(",") if value]
    project = global_values(args, "--project-directory") or [
        posixpath.dirname(f) for f in (global_values(args, "-f") + global_values(args, "--file"))[:1]
    ]
    return [root / (project[0] if project else "") / ".env"]


def env_file_sets(paths: Iterable[Path], name: str) -> bool:
    """Whether one of the env files PATHS sets NAME (`NAME=...`, Compose's .env syntax)."""
    return env_file_value(paths, name) is not None


def env_file_value(paths: Iterable[Path], name: str) -> str | None:
    """What the env files PATHS set NAME to (the last one setting it), or None."""
    value = None
    for path in paths:
        try:
            lines = path.read_text(encoding="utf-8-sig", errors="replace").splitlines()
        except OSError:
            continue
        for line in lines:
            key, equals, given = line.strip().removeprefix("export ").partition("=")
            if equals and key.strip() == name:
                given = given.strip()
                value = given[1:-1] if len(given) > 1 and given[0] == given[-1] and given[0] in "\"'" else given
    return value


def labelled_run(args: list[str], token: str) -> list[str]:
    """ARGS of a `compose run` with its container labelled LABEL_COMPOSE_RUN=TOKEN (run's own
    `--label`), so that espdock removes that container and no other one-off of the project's."""
    at = compose_subcommand_at(args)
    if at is None or args[at] != "run":
        return list(args)
    return [*args[: at + 1], "--label", f"{LABEL_COMPOSE_RUN}={token}", *args[at + 1 :]]


def starter_compose(project: str, image: str, executables: dict[str, list[str]]) -> str:
    """The commented compose file `espdock init` writes: one service per executable (package ->
    its executables, as installed), on IMAGE, under a first line that marks it as espdock's."""
    from espdock.layout import MICRO_ROS_AGENT_IMAGE
    from espdock.ros.plan import RUNTIME_INSTALL

    taken = [exe for found in executables.values() for exe in found]
    blocks = []
    for package, found in sorted(executables.items()):
        for exe in found:
            service = exe if taken.count(exe) == 1 else f"{package}-{exe}"
            path = f"{RUNTIME_INSTALL}/{package}/lib/{package}/{exe}"
            blocks.append(f"  {service}:\n    <<: *ros-node\n    command: [{path}]\n")
    services = "\n".join(blocks) or (
        "  # No node was built yet: run `espdock build`, then `espdock init --compose`, or add one\n"
        f"  # service per node, e.g.\n  # talker:\n  #   <<: *ros-node\n"
        f"  #   command: [{RUNTIME_INSTALL}/<package>/lib/<package>/<executable>]\n"
    )
    name = image.split("/", 1)[-1].rsplit(":", 1)[0]
    body = COMPOSE_TEMPLATE.format(
        project=project, image=image, name=name, services=services, agent=MICRO_ROS_AGENT_IMAGE
    )
    return f"{COMPOSE_MARK}{hashlib.sha256(body.encode()).hexdigest()}\n{body}"


def foreign_runtime_images(data: object, own: str) -> tuple[list[str], str | None]:
    """The images DATA (a parsed compose file) runs that are another workspace's runtime images
    (espdock/<name>:latest where OWN, espdock/<this workspace's name>, is not), and, with those, its
    project name (`name:`): a copied or cloned workspace's compose file still naming the original,
    whose nodes it would run and, under the same project name, whose containers it would replace."""
    services = data.get("services") if isinstance(data, dict) else None
    images = sorted(
        {
            str(service["image"])
            for service in (services.values() if isinstance(services, dict) else ())
            if isinstance(service, dict) and isinstance(service.get("image"), str)
        }
    )
    foreign = [
        image
        for image in images
        if image.startswith("espdock/")
        and image.endswith(":latest")
        and "$" not in image
        and image.rpartition(":")[0] != own
        and not image.startswith(("espdock/ros-", "espdock/idf-"))  # keyed images, not a workspace's
    ]
    project = data.get("name") if isinstance(data, dict) else None
    return foreign, project if foreign and isinstance(project, str) and "$" not in project else None


def default_compose_file(root: Path, args: list[str] | tuple[str, ...], env: Mapping[str, str]) -> Path | None:
    """The compose file in ROOT that a `compose ARGS` reads, where the user chose none (-f,
    COMPOSE_FILE in ENV or the env file Compose reads): None where they did, or there is none."""
    from espdock.layout import COMPOSE_FILES

    if {"-f", "--file"} & set(args) or any(a.startswith(("-f=", "--file=")) for a in args):
        return None
    if env.get("COMPOSE_FILE") or env_file_sets(compose_env_files(args, root, env), "COMPOSE_FILE"):
        return None
    if any((root / name.replace(".y", ".override.y")).exists() for name in COMPOSE_FILES):
        # Compose merges an override into the file: the file alone says nothing sure of what runs.
        return None
    return next((root / name for name in COMPOSE_FILES if (root / name).is_file()), None)


def _project_named_elsewhere(root: Path, args: list[str] | tuple[str, ...], env: Mapping[str, str]) -> bool:
    """Whether the compose project's name comes from -p, COMPOSE_PROJECT_NAME or the env file,
    not from the file's `name:`."""
    if global_values(args, "-p") or global_values(args, "--project-name") or env.get("COMPOSE_PROJECT_NAME"):
        return True
    return env_file_sets(compose_env_files(args, root, env), "COMPOSE_PROJECT_NAME")


def _active_profiles(root: Path, args: list[str] | tuple[str, ...], env: Mapping[str, str]) -> set[str] | None:
    """The profiles a `compose ARGS` turns on (--profile, COMPOSE_PROFILES); None where the env file
    sets them (what they are, this does not read)."""
    if env_file_sets(compose_env_files(args, root, env), "COMPOSE_PROFILES") and "COMPOSE_PROFILES" not in env:
        return None
    return {*global_values(args, "--profile"), *filter(None, env.get("COMPOSE_PROFILES", "").split(","))}


def check_compose_file(
    root: Path,
    own: str,
    args: list[str] | tuple[str, ...],
    env: Mapping[str, str],
    found: dict[str, list[str]] | None = None,
    no_ros2: bool = False,
    starting: bool = True,
) -> list[str]:
    """What is wrong in ROOT's compose file (the one Compose reads when ARGS and ENV choose none)
    for this workspace's runtime image OWN (espdock/<name>): another workspace's runtime image it
    runs, and, given FOUND (built_executables: `up` and `create` start the services), where it lags
    that image, and (NO_ROS2: the wheels image's) the services it starts with a `ros2` command.
    A WorkspaceError where a service it starts (STARTING: `up`, `run`, `create`) mounts a path that
    is not there."""
    path = default_compose_file(root, args, env)
    if path is None:
        return []
    text = path.read_text(errors="replace")
    import yaml  # only for `espdock compose`: about 11 ms of every other command's start

    try:
        # As Compose reads it under `espdock compose`, which sets the name variable.
        data = yaml.safe_load(_NAMED.sub(own.removeprefix("espdock/"), text))
    except yaml.YAMLError:
        return []  # Compose says what is wrong with it
    active = _active_profiles(root, args, env)
    if starting and (missing := _missing_bind_sources(root, data, active, _named_services(args, data))):
        raise WorkspaceError(
            f"{path.name}: {', '.join(f'{service} mounts {source}' for service, source in missing)}, which is not "
            "there: Docker would make a directory owned by root in its place (in the sources, where a file was meant)",
            f"Create it (`mkdir -p` for a directory), or correct the path in {path.name}.",
        )
    ours = generated_unchanged(text)
    foreign, project = foreign_runtime_images(data, own)
    if project == own.removeprefix("espdock/") or (project is not None and _project_named_elsewhere(root, args, env)):
        project = None  # this workspace's own project name, or another one: nothing of another's is acted on
    if not starting and project is not None:
        # A clone of an older espdock's file: `down` there removed the original's running services.
        raise WorkspaceError(
            f"{path.name} names its project {project}, another workspace's (it runs {', '.join(foreign)}): "
            f"`{compose_subcommand(args)}` would act on that workspace's containers",
            f"`espdock build`, then `espdock init --compose`, writes the file for this workspace (or give the "
            f"project: `espdock compose -p {project} ...` acts on that one's)."
            if ours
            else f"Set name: ${{{NAME_VARIABLE}:-{project}}} and its images' names so in {path.name} (or give the "
            f"project: `espdock compose -p {project} ...` acts on that one's).",
        )
    said = [warning] if (warning := _foreign_warning(path.name, foreign, project, ours, own)) else []
    if found is not None:
        # A file espdock wrote for another workspace (a clone's, a copy's) runs none of this one's
        # services: the warning above says what to do, not that nothing was built.
        said += _lagging_warnings(path.name, data, ours and warning is None, own, found, active, no_ros2)
    return said


def _starts(service: object, active: set[str] | None) -> bool:
    """Whether SERVICE (a compose file's) starts with the ACTIVE profiles (None: unknown, only if it has none)."""
    if not isinstance(service, dict):
        return False
    profiles = service.get("profiles") or []
    return not profiles or (active is not None and bool({"*", *map(str, profiles)} & active))


def _named_services(args: list[str] | tuple[str, ...], data: object) -> set[str]:
    """The services of DATA (a parsed compose file) ARGS name after the subcommand (`up -d beacon`)."""
    services = data.get("services") if isinstance(data, dict) else None
    at = compose_subcommand_at(args)
    return (
        {word for word in args[at + 1 :] if word in services}
        if at is not None and isinstance(services, dict)
        else set()
    )


def _missing_bind_sources(root: Path, data: object, active: set[str] | None, named: set[str]) -> list[tuple[str, str]]:
    """(service, source) of the bind mounts in DATA (a parsed compose file in ROOT) whose source is
    not there, in the services NAMED, or where none is, that start with ACTIVE profiles (None:
    unknown, only those of none)."""
    services = data.get("services") if isinstance(data, dict) else None
    missing = []
    for name, service in services.items() if isinstance(services, dict) else ():
        if not (name in named if named else _starts(service, active)) or not isinstance(service, dict):
            continue
        for volume in service.get("volumes") or ():
            # Only the short syntax makes a missing source (the long one's bind is refused by
            # Compose); one with no colon is an anonymous volume.
            bind = isinstance(volume, str) and ":" in volume and "$" not in volume
            source = volume.split(":", 1)[0] if bind else ""
            if source.startswith((".", "/", "~")) and not os.path.lexists(root / os.path.expanduser(source)):
                missing.append((str(name), source))
    return missing


def _foreign_warning(name: str, foreign: list[str], project: str | None, ours: bool, own: str) -> str | None:
    """The warning for compose file NAME (OURS: as espdock wrote it) that runs FOREIGN, other
    workspaces' runtime images than OWN, under PROJECT, the name of one's project (None: not
    another's), or None where it runs none."""
    if not foreign:
        return None
    replaced = (
        f", and its project `name: {project}` is that workspace's too (its containers are this project's: `up` "
        "replaces them, `down` removes them)"
    )
    if ours:
        # As espdock wrote it: the command that wrote it writes this workspace's (a renamed or copied one's).
        # Its services are written of what install/ holds: before a build, none.
        fix = "`espdock build`, then `espdock init --compose`, writes it afresh for this workspace"
    else:
        # The file is committed: this workspace's name in it would be the original's problem. Its
        # own name as what ESPDOCK_NAME, which `espdock compose` sets, falls back to serves both.
        default = foreign[0].removeprefix("espdock/").rpartition(":")[0]
        rename = f" and name: ${{{NAME_VARIABLE}:-{project}}}"
        fix = (
            f"set image: espdock/${{{NAME_VARIABLE}:-{default}}}:latest{rename if project else ''} in {name} "
            f"(`espdock compose` sets {NAME_VARIABLE} to each workspace's name)"
        )
    return (
        f"warning: {name} runs {', '.join(foreign)}, another workspace's runtime image, not this one's "
        f"({own}:latest, of this install/){replaced if project else ''}; {fix} (a copied, cloned or renamed "
        "workspace keeps the original's)"
    )


def built_executables(workspace: Workspace, packages: tuple[Package, ...]) -> dict[str, list[str]]:
    """The executables WORKSPACE's ROS PACKAGES have installed (package -> names, none where it is
    not built or installs none): what its runtime image runs."""
    install = workspace.ws_dir / "install"
    return {p.name: executables(install, p.name, workspace.root) for p in packages if p.kind is PackageKind.ROS}


def _lagging_warnings(
    name: str,
    data: object,
    ours: bool,
    repository: str,
    found: dict[str, list[str]],
    active: set[str] | None,
    no_ros2: bool = False,
) -> list[str]:
    """What is wrong between compose file NAME (DATA parsed; OURS: as espdock wrote it) and the
    runtime image of REPOSITORY, whose install/ holds FOUND, in the services on that image that
    start with the ACTIVE profiles: one that runs an executable the image lacks (a package gone from the
    branch: the container died at start, "not found"), and, in a file as espdock wrote it, built
    executables it runs no service of (written before the first build, it had none: Compose said
    only "no service selected"); with NO_ROS2, one whose command is `ros2`."""
    from espdock.ros.plan import RUNTIME_INSTALL

    services = data.get("services") if isinstance(data, dict) else None
    built = {f"{RUNTIME_INSTALL}/{p}/lib/{p}/{exe}": exe for p, exes in found.items() for exe in exes}
    ran, lacking, ros2 = set(), [], []
    for service_name, service in services.items() if isinstance(services, dict) else ():
        image = service.get("image") if isinstance(service, dict) else None
        if image not in (repository, f"{repository}:latest"):
            # Another image: its own install tree; a tag of this workspace's pinned in the file
            # (espdock/<name>:<key>) holds what it was made of, which install/ need not hold now.
            continue
        if not _starts(service, active):
            continue  # a profile this run does not turn on
        command = service.get("command")
        words = command if isinstance(command, list) else str(command or "").split()
        run = str(words[0]) if words else ""
        if run == "ros2" and no_ros2:
            ros2.append(service_name)
        package, _, exe = run.removeprefix(f"{RUNTIME_INSTALL}/").partition("/lib/")
        if not (run.startswith(f"{RUNTIME_INSTALL}/") and exe.startswith(f"{package}/")):
            continue
        ran.add(run)
        if run not in built:
            lacking.append((package, f"{service_name} ({package} {exe.removeprefix(package + '/')})"))
    said = []
    if ros2:
        # The container ended at once: "exec: ros2: not found", exit 127, after `up` had said nothing.
        said.append(
            f"warning: {name}: {', '.join(ros2)} run `ros2`, which the runtime image lacks (PyPI's ROS 2 wheels "
            f"have no ros2 command, launch or rclcpp): run an executable by its path, {RUNTIME_INSTALL}/<package>/"
            'lib/<package>/<executable>, or build on the official image (ros_image = "official")'
        )
    if lacking and not built and all(package in found for package, _ in lacking):
        # A fresh clone or worktree: `espdock init --compose` now would write a file of no service.
        said.append(
            f"warning: {name}: nothing is built in this workspace yet, and its services run what a build "
            "installs: `espdock build` first"
        )
    elif lacking:
        fix = "`espdock init --compose` writes it afresh" if ours else f"edit or remove them in {name}"
        said.append(
            f"warning: {name}: {', '.join(what for _, what in lacking)} run what the runtime image lacks (not built, "
            f"or a package no longer in the workspace): their containers fail at start; {fix}"
        )
    elif ours and (unrun := sorted(exe for run, exe in built.items() if run not in ran)):
        said.append(
            f"note: {name} runs none of {', '.join(unrun)}, built since espdock wrote it: `espdock init "
            "--compose` writes the built executables as services"
        )
    elif ours and not built and not ran:
        said.append(
            f"note: {name} has no node to run yet (espdock wrote it before anything was built): `espdock "
            "build`, then `espdock init --compose` writes the built executables as services"
        )
    return said


def generated_unchanged(text: str) -> bool:
    """Whether TEXT is a compose file as espdock wrote it (its mark matches the rest)."""
    first, _, body = text.partition("\n")
    return first == COMPOSE_MARK + hashlib.sha256(body.encode()).hexdigest()


def write_starter_compose(
    root: Path, text: str, owner: tuple[int, int] | None = None, refresh: bool = False, force: bool = False
) -> str | None:
    """Write TEXT as ROOT's compose file: where there is none ("wrote"); with REFRESH over one espdock
    wrote and nobody changed since ("refreshed"), or with FORCE over any, keeping the old one
    as <name>.orig ("replaced"). None when one is there and REFRESH is off; a WorkspaceError
    (exit 2) when a refresh meets an edited file without FORCE."""
    from espdock.layout import COMPOSE_FILES

    existing = next((root / name for name in COMPOSE_FILES if (root / name).exists()), None)
    path = existing or root / COMPOSE_FILES[0]
    try:
        if existing is None:
            with path.open("x") as out:  # never overwrites
                out.write(text)
            outcome = "wrote"
        elif not refresh:
            return None
        else:
            old = existing.read_text(errors="replace")
            if old == text:
                return "unchanged"
            if generated_unchanged(old):
                outcome = "refreshed"
            elif force:
                existing.replace(existing.with_name(existing.name + ".orig"))
                outcome = "replaced"
            else:
                raise WorkspaceError(
                    f"{existing.name} was edited since espdock wrote it (or espdock did not write it): left as it is",
                    f"`espdock init --compose --force` replaces it, keeping yours as {existing.name}.orig.",
                )
            staged = path.with_name(f".{path.name}.espdock-new")
            staged.write_text(text)
            staged.replace(path)  # whole or not at all
    except FileExistsError:
        return None
    except OSError as exc:
        raise WorkspaceError(f"cannot write {path}: {exc.strerror or exc}") from None
    if owner is not None:
        os.lchown(path, *owner)
    return outcome


def _default_name(root: Path) -> str | None:
    """The name ROOT's compose file falls back to without ESPDOCK_NAME (as espdock writes it): kept
    by a refresh, as the file is committed (a worktree's `espdock init --compose` wrote its own
    directory's name there, which plain `docker compose` in the original then ran)."""
    from espdock.layout import COMPOSE_FILES

    for name in COMPOSE_FILES:
        try:
            text = (root / name).read_text(errors="replace")
        except OSError:
            continue
        found = re.search(rf"^name: \$\{{{NAME_VARIABLE}:-([^}}\s]+)\}}$", text, flags=re.M)
        return found.group(1) if found else None
    return None


def plain_compose_note(root: Path, own: str, env: Mapping[str, str]) -> str | None:
    """Where plain `docker compose` in ROOT runs another name's runtime image than OWN
    (espdock/<name>): the name ROOT's compose file falls back to (a worktree or clone of the
    committed file), with ESPDOCK_NAME set neither in ENV nor in the .env."""
    fallback, name = _default_name(root), own.removeprefix("espdock/")
    if fallback in (None, name) or NAME_VARIABLE in env:
        return None
    if env_file_value(compose_env_files([], root, env), NAME_VARIABLE) is not None:
        return None  # what `espdock compose` says of it
    return (
        f"note: plain `docker compose` here runs espdock/{fallback}:latest, the name compose.yaml falls back to, "
        f"not this workspace's {own}:latest: `echo {NAME_VARIABLE}={name} >> .env` makes it this one's "
        f"(`espdock compose` sets {NAME_VARIABLE} itself)"
    )


def init_compose(
    workspace: Workspace,
    repository: str,
    packages: tuple[Package, ...],
    owner=None,
    refresh=False,
    force=False,
    by_setting: bool = False,
) -> str | None:
    """`espdock init`'s compose.yaml for WORKSPACE, whose runtime images are REPOSITORY: the
    executables its ROS PACKAGES have installed (see write_starter_compose for REFRESH, FORCE
    and what it returns). BY_SETTING: REPOSITORY's name is espdock.toml's `name`, which every worktree
    and clone shares, so the file falls back to it, not to the one it fell back to before."""
    own = repository.split("/", 1)[-1]
    named = f"${{{NAME_VARIABLE}:-{own if by_setting else _default_name(workspace.root) or own}}}"
    text = starter_compose(named, f"espdock/{named}:latest", built_executables(workspace, packages))
    return write_starter_compose(workspace.root, text, owner, refresh, force)
