"""The espdock command line: parses, calls the library, maps known errors to exit codes."""

from __future__ import annotations

import functools
import os
import signal
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, NoReturn, ParamSpec

import typer
from rich.console import Console
from rich.table import Table
from rich.text import Text

from espdock import __version__, bootstrap
from espdock.config import Config, load_config, resolve_ca_bundle
from espdock.errors import EspdockError, Interrupted, WorkspaceError
from espdock.plan import IMAGE_INPUT_DIR, ROS_DOCKERFILE, Plan, plan_build, ros_build_image
from espdock.runner import Runner
from espdock.ui import Reporter, render_plan
from espdock.workspace import (
    Workspace,
    discover_packages,
    find_workspace,
    order_packages,
    read_image_inputs,
    select_up_to,
)

app = typer.Typer(
    help="Build ESP-IDF firmware, micro-ROS and a ROS 2 workspace reproducibly, in containers.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
console = Console(soft_wrap=True)
err_console = Console(stderr=True, soft_wrap=True)
_state = {"debug": False}
P = ParamSpec("P")

WorkspaceOption = Annotated[
    Path | None, typer.Option("--workspace", "-w", help="Workspace root (default: search upward from here).")
]


def _command(function: Callable[P, None]) -> Callable[P, None]:
    """Make FUNCTION a command whose espdock errors and Ctrl-C end in a message and an exit code.

    Handled here, inside the command, because Typer would turn Ctrl-C into a bare exit code.
    """

    @functools.wraps(function)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> None:
        try:
            function(*args, **kwargs)
        except EspdockError as exc:
            _fail(exc)
        except KeyboardInterrupt:
            _fail(Interrupted("interrupted; containers started by this run were stopped and removed"))

    return wrapper


def _version(value: bool) -> None:
    if value:
        console.print(f"espdock {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    debug: Annotated[bool, typer.Option("--debug", help="Show tracebacks for errors.")] = False,
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")
    ] = False,
) -> None:
    _state["debug"] = debug


def _notify(text: str) -> None:
    console.print(Text(text, style="dim"))


def _load(workspace: Path | None, **overrides: object) -> tuple[Workspace, Config]:
    ws = find_workspace(workspace or Path.cwd())
    return ws, load_config(ws.root, os.environ, overrides)


def _build_plan(ws: Workspace, config: Config, names: list[str]) -> Plan:
    packages = order_packages(discover_packages(ws))
    selected = select_up_to(packages, names) if names else packages
    dockerfile = ws.root / ROS_DOCKERFILE
    if not dockerfile.is_file():
        raise WorkspaceError(f"{dockerfile} is missing", "The workspace root needs the Dockerfile for the ROS image.")
    ros_image = ros_build_image(config, dockerfile.read_text(), read_image_inputs(ws.root, IMAGE_INPUT_DIR))
    return plan_build(ws, config, selected, ros_image, tuple(names))


@app.command()
@_command
def build(
    packages: Annotated[
        list[str] | None, typer.Argument(help="Build only these packages and what they depend on.")
    ] = None,
    dry_run: Annotated[bool, typer.Option("--dry-run", help="Print the plan without running it.")] = False,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="Show image build logs in full.")] = False,
    target: Annotated[str | None, typer.Option(help="ESP32 chip target (overrides espdock.toml).")] = None,
    workspace: WorkspaceOption = None,
) -> None:
    """Build the images when their inputs changed, then every package of the workspace."""
    ws, config = _load(workspace, target=target)
    plan = _build_plan(ws, config, packages or [])
    if dry_run:
        render_plan(console, plan)
        return
    reporter = Reporter(console, verbose=verbose)
    engine = bootstrap.ensure_engine(os.environ, _notify)
    try:
        Runner(engine, config, os.environ, reporter).run(plan)
    finally:
        reporter.close()
        reporter.summary()


@app.command()
@_command
def setup() -> None:
    """Make this machine ready: a Docker engine (started or installed), Compose v2, the base image."""
    notify = _notify
    engine = bootstrap.ensure_engine(os.environ, notify)
    bootstrap.ensure_compose(os.environ, notify)
    try:
        ws, config = _load(None)
    except WorkspaceError:
        console.print("engine and compose ready (not in a workspace: no base image to prepare)")
        return
    from espdock.plan import dockerfile_args

    base = config.base_image or dockerfile_args((ws.root / ROS_DOCKERFILE).read_text()).get("BASE_IMAGE")
    if base:
        how = bootstrap.ensure_base_image(engine, base, config, notify)
        console.print(f"base image {base}: {how}")
    console.print("ready")


@app.command(context_settings={"allow_extra_args": True, "ignore_unknown_options": True, "help_option_names": []})
@_command
def compose(ctx: typer.Context, workspace: WorkspaceOption = None) -> None:
    """Run `docker compose ARGS...` in the workspace with espdock's settings (CA bundle) in its environment."""
    ws, config = _load(workspace)
    notify = _notify
    engine = bootstrap.ensure_engine(os.environ, notify)
    bootstrap.ensure_compose(os.environ, notify)
    env = dict(os.environ)
    ca_bundle = resolve_ca_bundle(config, os.environ)
    if ca_bundle is not None:
        env["ESPDOCK_CA_BUNDLE"] = str(ca_bundle)
    argv = [*engine.compose_command(), *ctx.args]
    raise typer.Exit(subprocess.call(argv, cwd=ws.root, env=env))


@app.command("list")
@_command
def list_packages(workspace: WorkspaceOption = None) -> None:
    """List the workspace's packages in build order."""
    ws, _ = _load(workspace)
    table = Table(title=str(ws.root), title_justify="left")
    for column in ("package", "kind", "build type", "depends on (in workspace)"):
        table.add_column(column)
    packages = order_packages(discover_packages(ws))
    names = {p.name for p in packages}
    for p in packages:
        table.add_row(p.name, p.kind.value, p.build_type, ", ".join(sorted(p.depends & names)))
    console.print(table)


def _on_sigterm(signum: int, frame: object) -> NoReturn:
    raise KeyboardInterrupt


def main() -> None:
    """Entry point: SIGTERM (CI timeouts, `docker stop`) cleans up like Ctrl-C."""
    signal.signal(signal.SIGTERM, _on_sigterm)
    app()


def _fail(exc: EspdockError) -> NoReturn:
    if _state["debug"]:
        import traceback

        traceback.print_exception(exc)
    err_console.print(Text.assemble(("error: ", "bold red"), exc.message))
    if exc.hint:
        err_console.print(Text.assemble(("hint: ", "yellow"), exc.hint))
    sys.exit(exc.exit_code)
