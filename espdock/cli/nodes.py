"""The commands that run the workspace's nodes: compose, run, shell."""

from __future__ import annotations

import contextlib
import os
import pwd
import shlex
import sys
import uuid
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated

import typer
from rich.text import Text

from espdock import interrupts
from espdock.build.prepare import last_build_options, workspace_packages
from espdock.build.runner import Runner
from espdock.build.steps import LABEL_WORKSPACE, EnsureImage, Plan
from espdock.cli import complete
from espdock.cli.core import (
    NOTES,
    WorkspaceOption,
    app,
    build_plan,
    command,
    ensure_images,
    load,
    notify,
    say,
)
from espdock.cli.prune import record_images
from espdock.config import Config, invoking_user, resolve_ca_bundle
from espdock.errors import EspdockError, Interrupted, LockBehind, LockError, WorkspaceError
from espdock.images import bootstrap
from espdock.images.engine import ComposeStillStopping, Engine, in_background
from espdock.images.keyed import is_current
from espdock.images.specs import RunSpec
from espdock.ros import compose as compose_file
from espdock.ros import nodes, rmw
from espdock.ros.plan import ColconBuild, RuntimeImage, runtime_repository, runtime_step
from espdock.ros.runtime_tree import runtime_spec
from espdock.ros.staleness import built_on_older, edited_since_built, stale_installs
from espdock.workspace import Package, PackageKind, Workspace, build_running, current_dir


def caller_env(
    ws: Workspace, config: Config, runner: Runner, image: str, given: tuple[tuple[str, str], ...] = ()
) -> Mapping[str, str]:
    """This environment, for a node or shell in IMAGE: without an RMW_IMPLEMENTATION the image
    lacks (said), which ended every node; one GIVEN with --env is the user's choice, passed."""
    if any(name == "RMW_IMPLEMENTATION" for name, _ in given):
        return os.environ
    environ, said = rmw.for_image(runner.engine, image, config, os.environ, {LABEL_WORKSPACE: str(ws.root)})
    if said:
        notify(said)
    return environ


def user_name(uid: int) -> str | None:
    """UID's login name on this machine, None where it has none."""
    try:
        return pwd.getpwuid(uid).pw_name
    except KeyError:
        return None


def run_foreground(engine: Engine, spec: RunSpec) -> tuple[int, int | None]:
    """Engine.run_foreground of SPEC, after removing what a killed espdock's run (or shell) of the
    workspace left running, and saying so."""
    if swept := engine.sweep(dict(spec.labels)):
        notify(interrupts.swept(swept))
    return engine.run_foreground(spec)


def sweep_workspace(engine: Engine, ws: Workspace) -> None:
    """Remove the containers a dead espdock left in WS, and say so."""
    if swept := engine.sweep({LABEL_WORKSPACE: str(ws.root)}):
        notify(interrupts.swept(swept, where=" in this workspace"))


def runtime_image(ws: Workspace, config: Config, plan: Plan | None = None) -> tuple[Runner, str]:
    """Make sure the runtime image holds what install/ holds now (made again when a build changed
    it since); the runner that did, and the image's keyed tag (`:latest` names it too)."""
    plan, step = nodes.runtime_plan(plan or build_plan(ws, config, [], PackageKind.ROS))
    engine = bootstrap.ensure_engine(os.environ, notify)
    if (holder := build_running(ws)) is not None:
        # An image of what install/ holds now would be of a half rebuilt tree (the node's own
        # package may be whole, its dependencies not), and `:latest` would move to it: one made
        # before of the same files is the only one to run.
        tag = runtime_spec(ws, step).tag
        if engine.image(tag) is None:
            raise WorkspaceError(
                f"an espdock build is running in {ws.root}{holder}: install/ may be half rebuilt, and the runtime "
                "image would be made of it",
                "Wait for it to finish, then run again.",
            )
    else:
        # A build's container an espdock killed outright (kill -9) went on writing install/ while
        # the image was made of it.
        sweep_workspace(engine, ws)
        if unfinished := nodes.unfinished_builds(ws, step.packages):
            notify(
                f"warning: the last espdock build of {', '.join(unfinished)} did not finish (it failed or was "
                "interrupted): their install trees may be half written, and the runtime image is made of install/ "
                "as it is (`espdock build` first)"
            )
    spec = runtime_spec(ws, step)
    if is_current(spec, engine.image(spec.tag)):
        # The runtime image of install/ as it is now is there (a lab's `docker load` of it): its
        # base, and the base's base, are needed only to make it.
        plan = Plan(plan.workspace, (step,))
    runner = ensure_images(ws, config, plan, engine)
    # A runtime image `run` or `compose` made is the workspace's as much as a build's: prune may take it.
    record_images(ws, runner, step.repository)
    return runner, spec.tag


def stale_runtime_note(
    engine: Engine, ws: Workspace, config: Config, plan: Plan, packages: tuple[Package, ...]
) -> None:
    """After a build (PLAN) of the workspace's PACKAGES that changed install/ and made no runtime
    image: say when espdock/<name>:latest, which plain `docker compose up` runs, is no longer the
    image of install/ (a Compose user's robot ran the code before the build, without a word)."""
    image = next((s.spec for s in plan.steps if isinstance(s, EnsureImage) and s.spec.target == "build"), None)
    if image is None or (step := runtime_step(ws, config, image, packages)) is None:
        return
    if (latest := engine.image(step.stable_tag)) is None:
        return  # none yet: Compose says so itself
    try:
        current = engine.image(runtime_spec(ws, step).tag)
    except (EspdockError, OSError):
        return  # an install tree it cannot read: `espdock compose` will say what
    if current is None or current.id != latest.id:
        say(
            Text(
                f"note: {step.stable_tag} is older than install/ now: plain `docker compose up` runs it as it was; "
                "`espdock compose up` or `espdock run` make it afresh, as a build does with --runtime-image (or "
                "`runtime_image = true` in espdock.toml)",
                style="yellow",
            )
        )


# Options after Compose's subcommand are Compose's (`exec -w DIR`, `up -w`): espdock's go before it.
@app.command(
    context_settings={
        "allow_extra_args": True,
        "ignore_unknown_options": True,
        "allow_interspersed_args": False,
        "help_option_names": [],
    }
)
@command
def compose(ctx: typer.Context, workspace: WorkspaceOption = None) -> None:
    """Run `docker compose ARGS...` in the workspace with espdock's settings (CA bundle) in its
    environment; `up`, `run` and `create` first make the runtime image of what install/ holds."""
    # Among Compose's global options (`-p NAME --workspace DIR ps`), click leaves it to Compose.
    args, among = compose_file.own_workspace(list(ctx.args))
    ws, config = load(workspace or among, runtime_image=True)
    subcommand = compose_file.compose_subcommand(args)
    # Only what starts services reads the packages: `down`, `stop`, `ps` or `logs` must not wait for a
    # package.xml being edited to be valid again.
    packages = workspace_packages(ws, config.ros_distro) if subcommand in compose_file.COMPOSE_CREATING else ()
    installed = nodes.installed_ros_packages(ws, packages)
    if subcommand in compose_file.COMPOSE_CREATING and (holder := build_running(ws)) is not None:
        # Its runtime image would be made of a half rebuilt install/, and `:latest` moved to it. With
        # nothing installed too: a build that rebuilds every package afresh (--force, a first build) has
        # moved their install trees aside, and `up` started the last build's `:latest`, warning that
        # nothing was built yet.
        raise WorkspaceError(
            f"an espdock build is running in {ws.root}{holder}: install/ may be half rebuilt",
            "Wait for it to finish, then run again.",
        )
    repository = runtime_repository(config, ws)
    if subcommand in compose_file.COMPOSE_CREATING or subcommand in compose_file.COMPOSE_ENDING:
        # `up` and `create` start the file's services: what they run is checked against install/ too.
        found = compose_file.built_executables(ws, packages) if subcommand in ("up", "create") else None
        no_ros2 = config.ros_image == "wheels"
        starting = subcommand in compose_file.COMPOSE_CREATING
        for said in compose_file.check_compose_file(ws.root, repository, args, os.environ, found, no_ros2, starting):
            notify(said)
    env_files = compose_file.compose_env_files(args, ws.root, os.environ)
    if (
        compose_file.NAME_VARIABLE not in os.environ
        and (named := compose_file.env_file_value(env_files, compose_file.NAME_VARIABLE)) is not None
        and named != repository.removeprefix("espdock/")
    ):
        # Compose takes the environment's over the .env's: espdock's, and plain `docker compose` the .env's.
        notify(
            f"note: {compose_file.NAME_VARIABLE}={named} in the env file is not this workspace's name "
            f"({repository.removeprefix('espdock/')}), which `espdock compose` sets: plain `docker compose` runs "
            f"espdock/{named}:latest; espdock takes its name from espdock.toml's `name` or the environment"
        )
    engine = bootstrap.ensure_engine(os.environ, notify)
    bootstrap.ensure_compose(os.environ, notify)
    if subcommand in compose_file.COMPOSE_CREATING and installed:
        # What the services run must be served, as for `espdock run`; with the last build's options,
        # by which the packages are up to date or not.
        plan = build_plan(ws, config, [], PackageKind.ROS, colcon_args=last_build_options(ws), checked=tuple(installed))
        colcon = next((step for step in plan.steps if isinstance(step, ColconBuild)), None)
        if colcon is not None and (stale := stale_installs(ws, colcon, [p for p in packages if p.name in installed])):
            # `espdock run` warns of its node's; the services run what install/ holds of all of them
            # (a dependency rebuilt since: an interface's type hash).
            notify(
                f"warning: install/ is not what the sources build now: `espdock build` would build {', '.join(stale)} "
                "(since it, their sources or install/ changed, a copy made without `cp -a` too, or the image, the "
                "build's options or espdock's way of building them did, or they were built on other sources of what "
                "they depend on); the services run what the last build installed"
            )
        # A workspace's own ROS Dockerfile may have no runtime stage: its compose file names others.
        if any(isinstance(step, RuntimeImage) for step in plan.steps):
            runtime_image(ws, config, plan)
    env = dict(os.environ)
    # The starter compose file's nodes run as ESPDOCK_USER: the user espdock builds for, as its own
    # containers do; in a rootless engine root, the engine's own user outside (the user's uid there
    # is a subordinate one, whose files in a mounted directory the user could not even remove).
    # One the user set (the environment, the project's .env) is theirs: plain `docker compose`
    # reads it as well.
    if "ESPDOCK_USER" not in env and not compose_file.env_file_sets(
        compose_file.compose_env_files(args, ws.root, env), "ESPDOCK_USER"
    ):
        owner = (0, 0) if engine.info().rootless else invoking_user(os.environ, ws.root)
        env["ESPDOCK_USER"] = ":".join(str(n) for n in owner)
    # The project and image of the file `espdock init` writes: this workspace's, also in a clone or a
    # git worktree of the committed file (the same value as any ESPDOCK_NAME the user set).
    env[compose_file.NAME_VARIABLE] = repository.removeprefix("espdock/")
    ca_bundle = resolve_ca_bundle(config, os.environ)
    if ca_bundle is not None:
        env["ESPDOCK_CA_BUNDLE"] = str(ca_bundle)
    token = uuid.uuid4().hex
    if subcommand == "up":
        # With the caller's own -p, -f and --profile: a bare `down` left a profile's services running.
        # And the workspace where it was named: run from elsewhere, a bare `down` found none.
        named = ["--workspace", str(ws.root)] if (workspace or among) is not None else []
        given = shlex.join(["espdock", "compose", *named, *args[: compose_file.compose_subcommand_at(args)]])
        interrupts.leaving(
            f"services Compose started may still be running: `{given} ps` lists them, `{given} down` stops and "
            "removes them"
        )
    try:
        code = engine.run_compose(compose_file.labelled_run(args, token), ws.root, env)
    except KeyboardInterrupt as exc:
        # Without a terminal Compose ends and leaves the run's container running, --rm or not:
        # removed where --rm asked for it, else stopped and kept, as Compose keeps it at a terminal.
        keep = "--rm" not in args[(compose_file.compose_subcommand_at(args) or 0) :]
        if subcommand == "run" and engine.end_labelled(compose_file.LABEL_COMPOSE_RUN, token, remove=not keep):
            done = "stopped (kept: run without --rm)" if keep else "stopped and removed"
            raise Interrupted(f"interrupted; the container `compose run` started was {done}") from None
        if subcommand != "up":
            raise Interrupted("interrupted") from None
        if {"-d", "--detach"} & set(args):
            raise Interrupted(
                "interrupted; services Compose had started may be running",
                "`espdock compose ps -a` lists them, `espdock compose down` stops and removes them.",
            ) from None
        if isinstance(exc, ComposeStillStopping):
            raise Interrupted(
                "interrupted; Compose is still stopping the services (one that ignores SIGTERM is killed at the "
                "end of its stop_grace_period), and their containers remain, stopped",
                "`espdock compose down` removes them (`-t 0` stops them at once; the same -p/--profile options "
                "as `up`).",
            ) from None
        # Compose stops what `up` started on Ctrl-C, and keeps the containers (and networks).
        raise Interrupted(
            # A Ctrl-C while Compose was still creating them leaves the network and perhaps no container.
            "interrupted; Compose stopped the services; the project's network and the containers it had made "
            "remain (stopped)",
            "`espdock compose down` removes them (with the same -p/--profile options as `up`).",
        ) from None
    detached = {"-d", "--detach", "--wait"} & set(args)
    # Compose names the project only where something runs there (it costs a `compose config`).
    if (
        subcommand == "up"
        and not detached
        and engine.compose_services_running(ws.root)
        and (project := compose_project(engine, args, ws.root, env)) is not None
        and (running := engine.compose_services_running(ws.root, project))
    ):
        # A foreground `up` that returned with services left running: it failed on one service
        # (its port taken, say) after starting others, or the service it attached to (--attach)
        # stopped. Ctrl-C no longer reaches them.
        how = f"compose up failed (exit code {code})" if code else "compose up returned"
        notify(
            f"{how}, and these services are still running: {', '.join(running)}; "
            "`espdock compose down` stops them (with the same -p/--profile options as `up`)"
        )
    raise typer.Exit(code)


def compose_project(engine: Engine, args: list[str], cwd: Path, env: dict[str, str]) -> str | None:
    """The project a `compose ARGS` in CWD is about (Compose's options before its subcommand say)."""
    at = compose_file.compose_subcommand_at(args)
    return engine.compose_project(args[:at] if at is not None else args, cwd, env)


RUN_FILES = "the files and devices `espdock run` passes in (--volume, --device, FASTRTPS_DEFAULT_PROFILES_FILE)"


@app.command(context_settings={"allow_interspersed_args": False, "ignore_unknown_options": True})
@command
def run(
    package: Annotated[
        str, typer.Argument(help="A ROS package of the workspace (built).", autocompletion=complete.runnable_packages)
    ],
    executable: Annotated[
        str,
        typer.Argument(
            help="One of its executables (install/PKG/lib/PKG/).", autocompletion=complete.package_executables
        ),
    ],
    args: Annotated[list[str] | None, typer.Argument(help="Arguments for the node (--ros-args ...).")] = None,
    network: Annotated[
        str, typer.Option(help="Docker network: host (the host's DDS traffic), or a compose project's network.")
    ] = nodes.DEFAULT_NETWORK,
    volume: Annotated[
        list[str] | None,
        typer.Option(
            "--volume",
            "-v",
            help="HOST:CONTAINER[:ro]: a file or directory the node reads or writes, e.g. a --params-file "
            "(repeatable; HOST relative to here).",
        ),
    ] = None,
    device: Annotated[
        list[str] | None,
        typer.Option("--device", help="HOST[:CONTAINER]: a device the node opens, e.g. /dev/ttyUSB0 (repeatable)."),
    ] = None,
    env: Annotated[
        list[str] | None,
        typer.Option(
            "--env",
            "-e",
            help="NAME=VALUE, or NAME for its value here: a variable for the node (repeatable), as `docker run -e`.",
        ),
    ] = None,
    workspace: WorkspaceOption = None,
) -> None:
    """Run EXECUTABLE of a built PACKAGE in the workspace's runtime image, like `ros2 run`
    (espdock's options go before PACKAGE; everything after EXECUTABLE goes to the node).
    The runtime image is made of install/ first when a build changed it."""
    NOTES["stderr"] = True
    # Run from a directory since removed, with --workspace: relative paths are the workspace's.
    here = current_dir(workspace.resolve() if workspace is not None and workspace.is_absolute() else None)
    mounts = tuple(nodes.volume(text, here) for text in volume or ())
    devices = tuple(nodes.device(text) for text in device or ())
    variables = tuple(v for text in env or () if (v := nodes.variable(text, os.environ)) is not None)
    nodes.profile_mounts(os.environ, here)  # a missing profiles file: refused before any image is made
    ws, config = load(workspace, runtime_image=True)
    nodes.check_file_arguments(ws, args or (), mounts, here)
    packages = workspace_packages(ws, config.ros_distro)
    # With the last build's options: by another's, every package would seem out of date.
    last = last_build_options(ws)
    try:
        path = nodes.find_executable(ws, packages, package, executable)
    except WorkspaceError:
        # What an interrupted build left (a second Ctrl-C) goes now: its "exiting now" said the
        # next run would remove it, and a run refused here never came to that.
        if (engine := bootstrap.reachable_engine(os.environ)) is not None and build_running(ws) is None:
            sweep_workspace(engine, ws)
        if any(p.name == package for p in packages) and not (ws.ws_dir / "install" / package).is_dir():
            # "not built yet: run `espdock build PKG`", a build this image refuses: say why it does.
            # Not a missing or stale rosdep lock, which that build makes itself (--locked aside).
            with contextlib.suppress(LockError, LockBehind):
                build_plan(ws, config, [], PackageKind.ROS, colcon_args=last, checked=(package,))
        raise
    if runs := next((edited_since_built(ws, p) for p in packages if p.name == package), None):
        notify(
            f"warning: {package}'s sources changed since its last build: this runs {runs} "
            f"(`espdock build {package}` first to run them)"
        )
    # Only what runs must be served: another package's missing key does not stop this node.
    plan = build_plan(ws, config, [], PackageKind.ROS, colcon_args=last, checked=(package,))
    colcon = next((step for step in plan.steps if isinstance(step, ColconBuild)), None)
    if not runs and colcon is not None and (older := built_on_older(ws, colcon, package)) is not None:
        # `espdock build msgs` after a .msg edit: a node of a package built on the old msgs
        # aborted on the type hash assertion of rosidl's generated code.
        which = f" ({', '.join(older)} among them)" if older else ""
        notify(
            f"warning: {package} was built on other sources of the workspace packages it depends on{which}: "
            f"it may fail on what changed in them, an interface's type hash (`espdock build {package}` first)"
        )
    runner, image = runtime_image(ws, config, plan)
    if mounts or devices or nodes.profile_mounts(os.environ, here):
        # An engine that does not see this machine would mount its own machine's path, or none.
        runner.containers.needs_this_machine(ws, image, RUN_FILES, firmware=False)
    tty = bool(sys.stdin and sys.stdin.isatty()) and sys.stdout.isatty() and not in_background()
    environ = caller_env(ws, config, runner, image, variables)
    spec = nodes.node_spec(
        ws,
        image,
        path,
        tuple(args or ()),
        runner.containers.container_owner(),
        environ,
        network,
        tty,
        mounts,
        devices,
        variables,
        here,
    )
    code, stopped_by = run_foreground(runner.engine, spec)
    raise typer.Exit(128 + stopped_by if stopped_by else code)


@app.command()
@command
def shell(workspace: WorkspaceOption = None) -> None:
    """Open a shell in the ROS build image with the workspace mounted and its install tree sourced."""
    NOTES["stderr"] = True
    ws, config = load(workspace)
    if (holder := build_running(ws)) is not None:
        notify(
            f"warning: an espdock build is running in {ws.root}{holder}: a colcon build in this shell "
            f"would build in its build dirs at the same time, and one of them fail"
        )
    plan, image, dockerfile = nodes.build_image_plan(build_plan(ws, config, [], PackageKind.ROS, checked=()))
    runner = ensure_images(ws, config, plan)
    tty = bool(sys.stdin and sys.stdin.isatty()) and sys.stdout.isatty()
    mount = runner.containers.workspace_for(ws, image, "shell")
    packages = workspace_packages(ws, config.ros_distro)
    owner = runner.containers.container_owner()
    if not mount.volume:
        # As espdock's builds on the wheels image: no ament_lint_auto for `if(BUILD_TESTING)` to find.
        nodes.make_shell_home(ws, runner.owner, tests_off=config.ros_image == "wheels")
    environ = caller_env(ws, config, runner, image)
    spec = nodes.shell_spec(
        ws,
        image,
        owner,
        environ,
        tty,
        dockerfile,
        mount,
        packages,
        current_dir(ws.root, logical=True),
        user_name(runner.owner[0]),
        runner.containers.reproducible_env(ws),
    )
    code, stopped_by = run_foreground(runner.engine, spec)
    raise typer.Exit(128 + stopped_by if stopped_by else code)
