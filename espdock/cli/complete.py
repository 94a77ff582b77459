"""Shell completion of the workspace's names (`espdock --install-completion`): its packages as a
build finds them, and a built package's executables as `ros2 run` would, so that
`espdock run <TAB>` offers what `ros2 run <TAB>` offers a native workspace. Completion never
fails: outside a workspace, or in one espdock cannot read, it offers nothing."""

from __future__ import annotations

import functools
import os
from collections.abc import Callable, Iterable
from pathlib import Path

import typer

from espdock.config import load_config
from espdock.errors import EspdockError
from espdock.ros.nodes import executables, installed_ros_packages
from espdock.workspace import Package, PackageKind, Workspace, discover_packages, find_workspace

Completer = Callable[[typer.Context, str], list[str]]


def _quiet(complete: Completer) -> Completer:
    """COMPLETE offering nothing where the workspace cannot be read: a traceback would land in
    the middle of the line the user is typing (an install dir of another user's, mode 0700)."""

    @functools.wraps(complete)
    def offered(ctx: typer.Context, incomplete: str) -> list[str]:
        try:
            return complete(ctx, incomplete)
        except (EspdockError, OSError, ValueError):
            return []

    return offered


def _workspace(ctx: typer.Context) -> tuple[Workspace, tuple[Package, ...]] | None:
    given = ctx.params.get("workspace")
    if given:
        # The word as typed: the shell expands `~` and `$HOME` only when the command runs.
        given = Path(os.path.expandvars(os.path.expanduser(given)))
        if not given.is_dir():  # looked for above it, the workspace found would be the one here
            return None
    ws = find_workspace(given or None)
    config = load_config(ws.root, os.environ)
    ws = ws.with_layout(config.package_paths, config.colcon_root)
    return ws, discover_packages(ws, config.ros_distro)


def _offer(names: Iterable[str], incomplete: str, given: Iterable[str] = ()) -> list[str]:
    taken = set(given)
    return sorted(n for n in set(names) if n.startswith(incomplete) and n not in taken)


def _packages_of(kind: PackageKind | None) -> Completer:
    @_quiet
    def complete(ctx: typer.Context, incomplete: str) -> list[str]:
        found = _workspace(ctx)
        if found is None:
            return []
        given = ctx.params.get("packages") or ()
        return _offer((p.name for p in found[1] if kind is None or p.kind is kind), incomplete, given)

    return complete


packages = _packages_of(None)
firmware_packages = _packages_of(PackageKind.FIRMWARE)


@_quiet
def runnable_packages(ctx: typer.Context, incomplete: str) -> list[str]:
    """The built ROS packages with an executable to run (not an interface package's)."""
    found = _workspace(ctx)
    if found is None:
        return []
    ws, install = found[0], found[0].ws_dir / "install"
    built = (name for name in installed_ros_packages(*found) if name.startswith(incomplete))
    return _offer((name for name in built if executables(install, name, ws.root)), incomplete)


@_quiet
def package_executables(ctx: typer.Context, incomplete: str) -> list[str]:
    found, package = _workspace(ctx), ctx.params.get("package")
    if found is None or package not in installed_ros_packages(*found):  # a firmware package runs nothing
        return []
    ws = found[0]
    return _offer(executables(ws.ws_dir / "install", package, ws.root), incomplete)
