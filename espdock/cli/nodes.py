"""The commands that run the workspace's nodes: compose, run, shell."""

from __future__ import annotations

import os
import sys
from typing import Annotated

import typer

from espdock import bootstrap, nodes
from espdock.cli.core import WorkspaceOption, app, build_plan, command, ensure_images, load, notify, workspace_packages
from espdock.config import resolve_ca_bundle
from espdock.workspace import PackageKind


@app.command(context_settings={"allow_extra_args": True, "ignore_unknown_options": True, "help_option_names": []})
@command
def compose(ctx: typer.Context, workspace: WorkspaceOption = None) -> None:
    """Run `docker compose ARGS...` in the workspace with espdock's settings (CA bundle) in its environment."""
    ws, config = load(workspace)
    engine = bootstrap.ensure_engine(os.environ, notify)
    bootstrap.ensure_compose(os.environ, notify)
    env = dict(os.environ)
    ca_bundle = resolve_ca_bundle(config, os.environ)
    if ca_bundle is not None:
        env["ESPDOCK_CA_BUNDLE"] = str(ca_bundle)
    raise typer.Exit(engine.run_compose(ctx.args, ws.root, env))


@app.command(context_settings={"allow_interspersed_args": False, "ignore_unknown_options": True})
@command
def run(
    package: Annotated[str, typer.Argument(help="A ROS package of the workspace (built).")],
    executable: Annotated[str, typer.Argument(help="One of its executables (install/PKG/lib/PKG/).")],
    args: Annotated[list[str] | None, typer.Argument(help="Arguments for the node (--ros-args ...).")] = None,
    network: Annotated[
        str, typer.Option(help="Docker network: host (the host's DDS traffic), or a compose project's network.")
    ] = nodes.DEFAULT_NETWORK,
    workspace: WorkspaceOption = None,
) -> None:
    """Run EXECUTABLE of a built PACKAGE in the workspace's runtime image, like `ros2 run`
    (espdock's options go before PACKAGE; everything after EXECUTABLE goes to the node)."""
    ws, config = load(workspace)
    packages = workspace_packages(ws, config.ros_distro)
    path = nodes.find_executable(ws, packages, package, executable)
    # Only what runs must be served: another package's missing key does not stop this node.
    plan, step = nodes.runtime_plan(build_plan(ws, config, [], PackageKind.ROS, checked=(package,)))
    runner = ensure_images(ws, config, plan)
    image = runner.runtime_spec(ws, step).tag
    tty = bool(sys.stdin and sys.stdin.isatty()) and sys.stdout.isatty()
    spec = nodes.node_spec(ws, image, path, tuple(args or ()), runner.container_owner(), os.environ, network, tty)
    code, stopped_by = runner.engine.run_foreground(spec)
    raise typer.Exit(128 + stopped_by if stopped_by else code)


@app.command()
@command
def shell(workspace: WorkspaceOption = None) -> None:
    """Open a shell in the ROS build image with the workspace mounted and its install tree sourced."""
    ws, config = load(workspace)
    plan, image = nodes.build_image_plan(build_plan(ws, config, [], PackageKind.ROS, checked=()))
    runner = ensure_images(ws, config, plan)
    spec = nodes.shell_spec(
        ws, image, runner.container_owner(), os.environ, bool(sys.stdin and sys.stdin.isatty()) and sys.stdout.isatty()
    )
    code, stopped_by = runner.engine.run_foreground(spec)
    raise typer.Exit(128 + stopped_by if stopped_by else code)
