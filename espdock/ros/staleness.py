"""What the ROS side's last build left stale: which packages a build would build again (by the
packages' stamps, espdock.build.stamps), and what `espdock run` and `compose` say of an install
built on other sources than the workspace holds now. Read by the colcon build step, the plan's
preview and the commands that run nodes; nothing here writes."""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import NamedTuple

from espdock.build.stamps import StampFile, TreeState, declaring, listing_digest, package_stamps, tree_state
from espdock.layout import ROS_BUILD_BASE
from espdock.ros.cmake_inputs import file_digests, fold, outside_inputs
from espdock.ros.colcon import closure, symlink_installed
from espdock.ros.plan import PYTHON_BUILD_TYPES, ColconBuild
from espdock.workspace import Package, Workspace

# Under ws/build: what the ROS packages and the firmware were last built from (espdock.build.stamps).
ROS_STAMPS = ".espdock-colcon-stamps.json"
# Its records' format: 2 since they record where each package was built from and whether it was
# built on a dependency's old install, and the copies setuptools makes are forced (an older
# espdock's records are stale: its packages are built again, afresh).
ROS_STAMP_FORMAT = 2


def ros_stamp_file(workspace: Workspace) -> StampFile:
    """WORKSPACE's record of what its ROS packages were last built from."""
    return StampFile(workspace.ws_dir / "build" / ROS_STAMPS, ROS_STAMP_FORMAT)


class Rebuild(NamedTuple):
    """What colcon_rebuild found of a ColconBuild's packages."""

    stamp_file: StampFile
    stamps: dict[str, str]  # the stamps of the packages it builds, as they are now
    rebuild: tuple[str, ...]  # which of them colcon gets
    trees: dict[str, TreeState]  # each package's own sources
    # Each package's files outside its directory its last build read (espdock.ros.cmake_inputs),
    # with their digests now; and the packages an espdock before that list recorded, whose
    # build dirs say they read none (their records get an empty one: not looked for again).
    outside: dict[str, dict[str, str]]
    unlisted: tuple[str, ...]


def colcon_rebuild(workspace: Workspace, step: ColconBuild) -> Rebuild:
    """STEP's stamp file, the stamps of the packages it builds as they are now, which of them
    colcon gets (the changed ones and, their stamps being chained, what depends on them; all of
    them with --force; the rest are up to date in install/, where colcon finds them), and each
    package's own sources as tree_state had them: what a build of them records, and what tells
    sources put back with an older time."""
    stamp_file = ros_stamp_file(workspace)
    trees = {name: tree_state(workspace.ws_dir / rel) for name, rel in step.sources}
    recorded = stamp_file.read()
    outside, unlisted, known = {}, [], {}
    for name, rel in step.sources:
        entry = recorded.get(name)
        listed = entry.get("outside") if isinstance(entry, dict) else None
        if isinstance(listed, dict):
            paths = [path for path in listed if isinstance(path, str)]
        elif isinstance(entry, dict):
            # Built by an espdock before this list: what its build dir says the build read (an
            # edit since is unknown, so one found builds the package once).
            paths = read_outside(workspace, name, rel)
            unlisted += [] if paths else [name]
        else:
            paths = []
        outside[name] = file_digests(workspace.root, paths, known)
    sources = {name: fold(now.digest, outside[name]) for name, now in trees.items()}
    chained = package_stamps(sources, dict(step.depends), step.stamp_images(), dict(step.settings), dict(step.reads))
    stamps = {name: chained[name] for name in step.building}
    if step.force:
        return Rebuild(stamp_file, stamps, tuple(stamps), trees, outside, tuple(unlisted))
    installed = {name: listing_digest(workspace.ws_dir / "install" / name) for name in stamps}
    stale = stamp_file.stale(stamps, installed, dict(step.sources))
    # A CMake package an espdock built that recorded no digest of its CMake files (before the
    # rule below): what an install rule it had taken out left installed stayed, up to date by its
    # stamp. Installed afresh once, where an upgrade's first build would call it up to date.
    unrecorded = stamp_file.redeclared(
        {name: trees[name] for name in stamps if name not in step.python and name not in stale}, unrecorded=True
    )
    rebuild = tuple(name for name in stamps if name in stale or name in unrecorded)
    return Rebuild(stamp_file, stamps, rebuild, trees, outside, tuple(unlisted))


def read_outside(workspace: Workspace, name: str, rel: str) -> list[str]:
    """The files of the workspace outside package NAME's directory (REL, under the colcon root)
    that its build dir says its last build read (espdock.ros.cmake_inputs)."""
    build_dir = workspace.ws_dir / ROS_BUILD_BASE / name
    return outside_inputs(build_dir, workspace.root, workspace.ws_dir / rel, colcon_outputs(workspace))


def colcon_outputs(workspace: Workspace) -> list[Path]:
    """colcon's output dirs: no input of a package, wherever its build read them."""
    return [workspace.ws_dir / name for name in ("build", "install", "log")]


def edited_since_built(
    workspace: Workspace, package: Package, recorded: Mapping[str, object] | None = None, now: TreeState | None = None
) -> str | None:
    """What `espdock run` runs of PACKAGE where its sources differ from those its last build
    recorded (a branch checked out, an edit), None where they do not or a symlink install runs
    them as they are (an ament_python package's modules). RECORDED (the stamp file's content) and
    NOW (the package's tree) where the caller has them already."""
    if recorded is None:
        recorded = ros_stamp_file(workspace).read()
    entry = recorded.get(package.name)
    tree = entry.get("tree") if isinstance(entry, dict) else None
    if not isinstance(tree, str):
        return None
    if tree == (now := now or tree_state(package.path)).digest:
        # A monorepo's shared header or CMake module (espdock.ros.cmake_inputs), compiled in.
        read = entry.get("outside") if isinstance(entry, dict) else None
        if isinstance(read, dict) and (changed := sorted(file_digests(workspace.root, read).items() - read.items())):
            return f"what that build made of {', '.join(path for path, _ in changed)} as it was then"
        if not isinstance(read, dict) and (
            paths := read_outside(workspace, package.name, os.path.relpath(package.path, workspace.ws_dir))
        ):
            # An older espdock's record keeps no digest of them: the next build builds it once (colcon_rebuild).
            return (
                f"what an older espdock's build made of {', '.join(paths)}, as they were then, which it did not record"
            )
        return None
    if not symlink_installed(workspace.ws_dir / ROS_BUILD_BASE, package.name):
        return "what that build installed"
    if package.build_type in PYTHON_BUILD_TYPES:
        if now.declares == entry.get("declares"):
            return None
        return "the entry points and data files of its setup.py as that build installed them"
    if (
        now.declares == entry.get("declares")
        and entry.get("paths") == list(now.paths)
        and not _makes(package.path, now)
    ):
        # A bringup package's params.yaml or launch file edited: the link installed is to it.
        return None
    return "what that build compiled or generated, beside the sources its --symlink-install links to"


# CMake commands that compile or generate what a package installs (the rest of a --symlink-install
# of it links to the sources): an edit of a file they read needs a build.
_MAKING = re.compile(
    r"^\s*(?:(?:add_executable|add_library|rosidl_generate_interfaces|configure_file|add_custom_command"
    r"|add_custom_target|ament_auto_add_\w+|generate_parameter_library|pybind11_add_module|\w*_generate_\w*)\s*\("
    r"|file\s*\(\s*(?:GENERATE|CONFIGURE|COPY|WRITE|APPEND)\b)",
    re.I | re.M,
)


def _makes(path: Path, tree: TreeState) -> bool:
    """Whether the CMake package at PATH (TREE its sources) compiles or generates anything."""
    for rel in tree.paths:
        if declaring(rel):
            try:
                if _MAKING.search((path / rel).read_text(errors="replace")):
                    return True
            except OSError:
                return True
    return False


def stale_installs(workspace: Workspace, step: ColconBuild, packages: Iterable[Package]) -> list[str]:
    """Those of PACKAGES whose install is not what their sources build now: their own sources edited
    (edited_since_built: a --symlink-install's modules are as they are), or up to date themselves but
    built on other sources of what they depend on (the build would build them again)."""
    found = colcon_rebuild(workspace, step)
    recorded = found.stamp_file.read()

    def own_tree_built(name: str) -> bool:
        entry = recorded.get(name)
        return isinstance(entry, dict) and name in found.trees and entry.get("tree") == found.trees[name].digest

    return [
        package.name
        for package in packages
        if edited_since_built(workspace, package, recorded, found.trees.get(package.name)) is not None
        or (package.name in found.rebuild and own_tree_built(package.name))
    ]


def built_on_older(workspace: Workspace, step: ColconBuild, package: str) -> list[str] | None:
    """Where PACKAGE's own sources are as its last build recorded, the workspace packages it depends
    on that were rebuilt or edited since (by the stamps its build recorded of them; a record of an
    older espdock: those of them STEP would build, [] where only PACKAGE would build); None where
    there are none, or its own sources changed (edited_since_built says that) but for a symlink
    install's Python modules, which run as they are."""
    found = colcon_rebuild(workspace, step)
    rebuild, trees = found.rebuild, found.trees
    recorded = found.stamp_file.read()
    entry = recorded.get(package)
    if not isinstance(entry, dict) or package not in trees:
        return None
    if entry.get("tree") != trees[package].digest and not (
        # Its module edited under --symlink-install beside a .msg edit: nothing was said, and the
        # node failed on the new field.
        package in step.python
        and trees[package].declares == entry.get("declares")
        and symlink_installed(workspace.ws_dir / ROS_BUILD_BASE, package)
    ):
        return None
    against = entry.get("against")

    def edited(dep: str) -> bool:
        now = recorded.get(dep)
        read = now.get("outside") if isinstance(now, dict) else None
        return dep in trees and (
            not isinstance(now, dict)
            or now.get("tree") != trees[dep].digest
            or (isinstance(read, dict) and read != found.outside.get(dep))
        )

    if isinstance(against, dict):
        # By the stamps it was built on: options given to one build or another (a selection's
        # --cmake-args) make no dependency older. What it only runs with (a Python package's
        # exec_depends) its build did not read: only an edit not built since is older there.
        def changed(dep: str, stamp: object) -> bool:
            # An `espdock test` build's record serves for the plain build of the same sources.
            now = recorded.get(dep)
            return not isinstance(now, dict) or stamp not in (now.get("stamp"), now.get("serves")) or edited(dep)

        runs_with = closure([package], dict(step.depends)) - step.build_reads(package) - {package}
        older = {dep for dep, stamp in against.items() if changed(dep, stamp)}
        return sorted(older | {dep for dep in runs_with if edited(dep)}) or None
    if package not in rebuild:
        return None
    return sorted(closure([package], dict(step.depends)) & set(rebuild))
