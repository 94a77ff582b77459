"""What the ROS side's last build left stale: which packages a build would build again (by the
packages' stamps, espdock.build.stamps), which of their build dirs and install prefixes it
removes first and why, and what `espdock run` and `compose` say of an install built on other
sources than the workspace holds now. Read by the colcon build step, the plan's preview and the
commands that run nodes; nothing here writes."""

from __future__ import annotations

import os
import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import NamedTuple

from espdock.build.stamps import StampFile, TreeState, declaring, listing_digest, package_stamps, tree_state
from espdock.layout import ROS_BUILD_BASE
from espdock.ros.cmake_inputs import file_digests, fold, outside_inputs
from espdock.ros.colcon import closure, left_out
from espdock.ros.plan import PYTHON_BUILD_TYPES, ColconBuild
from espdock.ros.trees import install_kind_switched, natively_linked, symlink_installed
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
    # Each package's install listing (listing_digest) as the stale check read it; none with --force.
    installed: dict[str, str | None]
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
        return Rebuild(stamp_file, stamps, tuple(stamps), trees, {}, outside, tuple(unlisted))
    installed = {name: listing_digest(workspace.ws_dir / "install" / name) for name in stamps}
    stale = stamp_file.stale(stamps, installed, dict(step.sources))
    # A CMake package an espdock built that recorded no digest of its CMake files (before the
    # rule below): what an install rule it had taken out left installed stayed, up to date by its
    # stamp. Installed afresh once, where an upgrade's first build would call it up to date.
    unrecorded = stamp_file.redeclared(
        {name: trees[name] for name in stamps if name not in step.python and name not in stale}, unrecorded=True
    )
    rebuild = tuple(name for name in stamps if name in stale or name in unrecorded)
    return Rebuild(stamp_file, stamps, rebuild, trees, installed, outside, tuple(unlisted))


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


def build_afresh(
    workspace: Workspace,
    step: ColconBuild,
    rebuild: tuple[str, ...],
    stamp_file: StampFile,
    trees: Mapping[str, TreeState],
    installed: Mapping[str, str | None],
) -> list[tuple[tuple[Path, ...], str]]:
    """What colcon would build on wrongly among REBUILD's trees, each reason with the build dirs
    and install prefixes it removes and what to say of it: every build dir and install prefix with
    --force (but those the options after `--` leave out) or when --symlink-install was turned on
    or off; else the build dirs of interface packages whose interface dependencies changed
    (ColconBuild.stale_interfaces), the install prefixes a native symlink install linked to this
    machine's paths, and the build dirs and install prefixes of packages that moved (STAMP_FILE
    knows where they were), whose sources changed with no newer file, lost a file, or changed
    their setup.py (TREES: their tree_state now), whose install prefix changed outside espdock
    (INSTALLED: their install listings as colcon_rebuild read them), or that an older espdock built,
    each reason that holds."""
    base = workspace.ws_dir / ROS_BUILD_BASE
    install = workspace.ws_dir / "install"
    reasons: list[tuple[tuple[Path, ...], str]] = []

    def both(names: Iterable[str]) -> tuple[Path, ...]:
        """NAMES' build dirs and install prefixes."""
        return tuple(tree for name in names for tree in (base / name, install / name))

    # What the options after `--` leave out: colcon would not build or install it again.
    out = left_out(step.colcon_args, dict(step.depends), base)
    if switched := install_kind_switched(base, rebuild, step.effective_args, install):
        turned = "on" if "--symlink-install" in step.effective_args else "off"
        # What they leave out colcon does not build: it keeps its install, of the other kind.
        switching = [name for name in switched if name not in out]
        why = (
            f"--symlink-install {turned} since their last build: removed the build dirs and install prefixes "
            f"of {len(switching)} package(s), which colcon cannot switch in place"
        )
        if skipped := [name for name in switched if name in out]:
            why += f"; {', '.join(skipped)}, which the options after `--` leave out, keep theirs until built"
        reasons.append((both(switching), why))
        rebuild = tuple(name for name in rebuild if name not in switched)
    if step.force:
        # A rebuild by make and setuptools, which decide by time, kept what a source put back
        # with an older time (`cp -p`, a backup) had built: the old binary, --force or not.
        if afresh := [name for name in rebuild if name not in out]:
            why = f"--force: building {len(afresh)} package(s) afresh, in new build dirs and install prefixes"
            reasons.append((both(afresh), why))
    else:
        # Not what `--` leaves out: a package skipped lost its install, and what depends on it
        # failed to build.
        rebuild = tuple(name for name in rebuild if name not in out)
        # Only those built before (a build dir here, or a record of one in the workspace volume): a
        # first build has nothing to build afresh, and said it did.
        recorded = stamp_file.read()
        before = [name for name in step.stale_interfaces(rebuild) if name in recorded or (base / name).exists()]
        if stale := tuple(before):
            why = (
                f"building {', '.join(stale)} afresh: interface packages whose interface dependencies changed, "
                "whose type hashes rosidl's incremental build would keep"
            )
            reasons.append((tuple(base / name for name in stale), why))
        if native := natively_linked(install, rebuild, workspace.root):
            why = (
                f"removed the install prefixes of {', '.join(native)}: a native `colcon build "
                "--symlink-install` linked them to this machine's paths, which colcon in the container "
                "cannot replace"
            )
            reasons.append((tuple(install / name for name in native), why))
        if moved := stamp_file.moved({name: rel for name, rel in step.sources if name in rebuild}):
            # Their CMake caches and symlink installs hold the old directory.
            why = "building afresh what moved since the last build: " + ", ".join(
                f"{name} (from {old})" for name, old in moved.items()
            )
            reasons.append((both(moved), why))
        if put_back := [n for n in stamp_file.put_back({n: trees[n] for n in rebuild}) if n not in moved]:
            why = (
                f"building afresh what changed with no newer file: {', '.join(put_back)} (put back from a "
                "backup or an archive, a file renamed or removed, or a file's x bit changed), which make and "
                "setuptools, deciding by time, would not build again"
            )
            reasons.append((both(put_back), why))
        # What neither reason above builds afresh: whether it lost or gained files.
        others = {n: trees[n] for n in rebuild if n not in {*moved, *put_back}}
        lost = stamp_file.removed(others)
        if lost:
            why = "installing afresh what lost source files since its last build: " + "; ".join(
                f"{name} ({', '.join(gone[:3])}{', ...' if len(gone) > 3 else ''})" for name, gone in lost.items()
            )
            why += ", whose installed files colcon would leave in install/"
            # CMake installs every file of its rules again into an empty prefix, and its build
            # stays incremental; the build dirs of setuptools and ament_cmake_python keep the
            # removed modules, and rosidl's generated code of a removed interface failed the build.
            afresh = [
                name
                for name, gone in lost.items()
                if name in step.python or any(_lost_from_build_dir(path, base / name) for path in gone)
            ]
            why += f"; building {', '.join(afresh)} afresh as well" if afresh else ""
            trees_of = [install / name for name in lost] + [base / name for name in afresh]
            reasons.append((tuple(trees_of), why))
        else:
            afresh = []
        # A CMake package whose files changed configures again, its compile incremental: a file(GLOB)
        # kept the list it was configured with (a removed source failed every build, one back was left out).
        listed = {*lost, *stamp_file.gained(others)}
        if cmake := sorted(n for n in listed if n not in step.python and n not in afresh and (base / n).is_dir()):
            its = "its" if len(cmake) == 1 else "their"
            why = f"configuring {', '.join(cmake)} again: {its} source files are others than at {its} last build"
            reasons.append((tuple(base / name / "CMakeCache.txt" for name in cmake), why))
        # A `-D` option taken out of the options stays in CMake's cache: the package rebuilt, and
        # kept what the option had made (a Release build, after a build without it).
        settings = {
            n: d for n, d in step.settings if n in others and n not in step.python and n not in (*afresh, *cmake)
        }
        if options := [n for n in stamp_file.reconfigured(settings) if (base / n / "CMakeCache.txt").is_file()]:
            its = "its" if len(options) == 1 else "their"
            why = (
                f"configuring {', '.join(options)} afresh: {its} colcon options or settings files changed since "
                f"{its} last build (a CMake option taken out would stay in {its} cache)"
            )
            reasons.append((tuple(base / name / "CMakeCache.txt" for name in options), why))
        python = {n: now for n, now in others.items() if n in step.python and n not in lost}
        if redeclared := stamp_file.redeclared(python):
            why = (
                f"building afresh what changed its setup.py or setup.cfg: {', '.join(redeclared)} (an entry "
                "point or data file taken out of it would stay installed)"
            )
            reasons.append((both(redeclared), why))
        # CMake's install of an emptied prefix puts every file of its rules there again, the build incremental.
        cmake_trees = {n: now for n, now in others.items() if n not in step.python and n not in lost}
        if reinstalled := stamp_file.redeclared(cmake_trees, unrecorded=True):
            why = (
                f"installing afresh what changed its CMake files (or whose last build did not record them): "
                f"{', '.join(reinstalled)} (what a target renamed or an install rule taken out had installed "
                "would stay in install/)"
            )
            # An interface taken out of rosidl_generate_interfaces (its file kept) leaves its generated
            # code in the build dir, whose output directories ament installs whole: it stayed importable.
            # By its CMakeLists: in volume mode the build dirs are the engine's, not here.
            where = dict(step.sources)
            generated = [
                name
                for name in reinstalled
                if (base / name / "rosidl_generator_c").is_dir()
                or "rosidl_generate_interfaces" in text_or_empty(workspace.ws_dir / where[name] / "CMakeLists.txt")
            ]
            if generated:
                why += f"; building {', '.join(generated)} afresh as well (rosidl's generated code)"
            reasons.append((tuple(install / name for name in reinstalled) + tuple(base / n for n in generated), why))
        done = {*moved, *put_back, *lost, *redeclared, *reinstalled}
        # colcon installs over what it finds: a file put into an install prefix, or a native build's
        # (its modules under the host's Python version), stayed, and went into the manifest and the
        # runtime image as the build's own.
        listings = {n: installed.get(n) for n in others if n not in done and n not in native}
        if changed := stamp_file.install_changed(listings):
            why = (
                f"installing afresh what changed in install/ since its last build: {', '.join(changed)} (a file "
                "put or edited there, or a build of your own; colcon would install over it and keep what it did "
                "not make)"
            )
            reasons.append((tuple(install / name for name in changed), why))
            done |= set(changed)
        # An older espdock's records keep no list of files: whether one went is not known.
        unlisted = stamp_file.unlisted({n: now for n, now in others.items() if n not in done})
        if older := [name for name in (*stamp_file.foreign(rebuild), *unlisted) if name not in done]:
            newer = set(stamp_file.newer(older))
            # A teammate's or a CI job's espdock, upgraded before this one: not an older one.
            which = "an older espdock" if not newer else "a newer espdock" if newer == set(older) else "another espdock"
            why = (
                f"building afresh what {which} built: {', '.join(older)} (its records do not say "
                "where each package was built from, nor on what, as this one reads them)"
            )
            reasons.append((both(older), why))
    return reasons


def text_or_empty(path: Path) -> str:
    """PATH's text, or "" where it cannot be read."""
    try:
        return path.read_text(errors="replace")
    except OSError:
        return ""


def _lost_from_build_dir(path: str, build_dir: Path) -> bool:
    """Whether a lost source file at PATH leaves its package's BUILD_DIR wrong: an interface file
    (rosidl's generated code of it), or a Python module where ament_cmake_python copies the
    package's modules there (a launch file or script of a CMake package is not)."""
    return path.endswith((".msg", ".srv", ".action", ".idl")) or (
        path.endswith(".py") and (build_dir / "ament_cmake_python").is_dir()
    )
