"""The workspace model: where it is, which packages it holds, and their order."""

from __future__ import annotations

import difflib
import fcntl
import glob
import hashlib
import json
import os
import re
import sys
import tempfile
from collections.abc import Iterable, Iterator
from contextlib import contextmanager, suppress
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path
from typing import NamedTuple

from espdock.config import CHIP_TARGETS
from espdock.defaults import defaults_root
from espdock.errors import WorkspaceError
from espdock.layout import (
    CONFIG_FILE,
    IDF_DOCKERFILE,
    IDF_INPUT_DIR,
    IMAGE_INPUT_DIR,
    ROS_DOCKERFILE,
    ROS_OFFICIAL_DOCKERFILE,
    ROSDEP_LOCK,
    xdg_dir,
)

IGNORE_MARKERS = ("COLCON_IGNORE", "AMENT_IGNORE", "CATKIN_IGNORE")
# The ROS distribution package.xml conditions are evaluated for (espdock.toml's ros_distro).
DEFAULT_ROS_DISTRO = "jazzy"
FIRMWARE_BUILD_TYPE = "esp_idf"
# colcon's outputs, in the colcon root only: colcon marks them COLCON_IGNORE and searches any
# other directory of these names (a repository cloned as src/log), so espdock does too.
COLCON_OUTPUTS = ("build", "install", "log")
# IDF's component manager's downloads, wherever a project is: they hold micro-ROS's packages.
NOT_SOURCES = ("managed_components",)


class PackageKind(StrEnum):
    ROS = "ros"
    FIRMWARE = "firmware"


@dataclass(frozen=True)
class Package:
    """One package.xml: a ROS package under ws/src or a firmware package under firmware/."""

    name: str
    path: Path
    kind: PackageKind
    build_type: str
    # Every dependency named in the manifest (build, buildtool, exec, test, group), workspace or not.
    depends: frozenset[str]
    is_interface: bool = False
    # The dependencies named only as test_depend: not needed to build or run.
    test_only_depends: frozenset[str] = frozenset()
    # The dependencies its build reads (build, buildtool and their export kinds), not those it
    # only runs or tests with (exec_depend, test_depend); None: not told apart (all of DEPENDS).
    build_depends: frozenset[str] | None = None


# This repository's layout: ROS packages in ws/src, firmware in firmware/, colcon's build,
# install and log in ws/. A plain colcon workspace: everything under src/, outputs at the root.
CLASSIC_LAYOUT = (("ws/src", "firmware"), "ws")
COLCON_LAYOUT = (("src",), ".")


@dataclass(frozen=True)
class Workspace:
    """An espdock workspace: ROOT/espdock.toml; packages (ROS and firmware, told apart by their
    build type) anywhere under PACKAGE_PATHS; colcon's build/, install/ and log/ in COLCON_ROOT.
    Both paths are relative to ROOT."""

    root: Path
    package_paths: tuple[str, ...] = CLASSIC_LAYOUT[0]
    colcon_root: str = CLASSIC_LAYOUT[1]

    @property
    def ws_dir(self) -> Path:
        """The colcon workspace: where build/, install/ and log/ go."""
        return (self.root / self.colcon_root).resolve() if self.colcon_root != "." else self.root

    def with_layout(self, package_paths: tuple[str, ...] | None, colcon_root: str | None) -> Workspace:
        """This workspace with the configured layout; what is not configured is detected:
        ws/src present means this repository's layout, else a colcon workspace's."""
        detected = CLASSIC_LAYOUT if (self.root / "ws" / "src").is_dir() else COLCON_LAYOUT
        paths = tuple(package_paths) if package_paths else detected[0]
        root = colcon_root if colcon_root is not None else detected[1]
        for rel in (*paths, root):
            if Path(rel).is_absolute() or ".." in Path(rel).parts:
                raise WorkspaceError(
                    f"layout path '{rel}' must be relative to the workspace and inside it",
                    "Set package_paths and colcon_root in espdock.toml relative to its directory.",
                )
        return Workspace(self.root, paths, root)


def root_key(root: Path | str) -> str:
    """A short digest of the path ROOT: the name of what espdock keeps for a workspace outside it
    (its lock's holder file, its manifest cache, its rosdep database, its image record)."""
    return hashlib.sha256(str(root).encode(errors="surrogateescape")).hexdigest()[:16]


def workspace_gone(root: Path | str) -> bool:
    """Whether the workspace at ROOT was removed (a deleted clone, a CI job's checkout): no
    command will use what espdock keeps for it outside it again."""
    return not os.path.isdir(root)


def check_utf8_path(directory: Path) -> None:
    """Refuse a workspace at a path that is not UTF-8 (bytes Python holds as lone surrogates)."""
    try:
        str(directory).encode()
    except UnicodeEncodeError:
        raise WorkspaceError(
            f"the workspace's path is not UTF-8: {os.fsencode(directory)!r}",
            "Rename the directory (or one above it) with a UTF-8 name: the engine's API (JSON) and "
            "image labels carry the path as text.",
        ) from None


def ways_up(start: Path | None = None) -> tuple[list[Path], list[Path]]:
    """START (default: the current directory) and its parents as the filesystem has them (links
    resolved), and as the shell reached START (its $PWD, links kept), when that differs: a
    package linked into a workspace's src/ from a checkout elsewhere lies in the workspace only
    the second way. Raises FileNotFoundError when the current directory is gone."""
    if start is not None and start.is_absolute():
        here, logical = start.resolve(), Path(os.path.normpath(start))
    else:
        cwd = Path.cwd()
        here = (start or cwd).resolve()
        pwd = os.environ.get("PWD", "")
        try:
            shell = Path(pwd) if pwd.startswith("/") and os.path.samefile(pwd, cwd) else cwd
        except OSError:
            shell = cwd
        logical = Path(os.path.normpath(shell / (start or ".")))
    return [here, *here.parents], ([logical, *logical.parents] if logical != here else [])


def _cwd_gone() -> WorkspaceError:
    return WorkspaceError(
        "the current directory no longer exists (removed, or replaced by a new clone)",
        "cd into the workspace again (`cd $PWD`), then run again.",
    )


def current_dir(instead: Path | None = None, logical: bool = False) -> Path:
    """The current directory; where it no longer exists, INSTEAD (the workspace --workspace named,
    with which other commands run from there too), else a clear error, not a crash. LOGICAL: as the
    shell reached it ($PWD, links kept), where that is the same directory."""
    try:
        here = Path.cwd()
    except FileNotFoundError:
        if instead is not None:
            return instead
        raise _cwd_gone() from None
    pwd = os.environ.get("PWD", "")
    try:
        return Path(pwd) if logical and pwd.startswith("/") and os.path.samefile(pwd, here) else here
    except OSError:
        return here


def find_workspace(start: Path | None = None) -> Workspace:
    """The nearest directory at or above START (default: the current one) that holds espdock.toml,
    through links as they are, else as the shell took them (ways_up)."""
    try:
        resolved, logical = ways_up(start)
    except FileNotFoundError:
        raise _cwd_gone() from None
    start, looked, denied = resolved[0], [], []
    for directory in (*resolved, *logical):
        looked.append(directory)
        try:
            found = (directory / CONFIG_FILE).is_file()
        except PermissionError:  # one this user may not look into (`sudo -u builder` in /root)
            denied.append(directory)
            continue
        if found:
            check_utf8_path(directory.resolve())
            return Workspace(directory.resolve())
    looked = looked[: len(resolved)]
    shown = ", ".join(str(d) for d in looked[:4]) + (", ..." if len(looked) > 4 else "")
    barred = f"; you may not look into {', '.join(map(str, dict.fromkeys(denied)))}" if denied else ""
    raise WorkspaceError(
        f"not inside an espdock workspace: no {CONFIG_FILE} in {start} or any parent ({shown}){barred}",
        f"Run espdock from a workspace, or make this one: `espdock init` at its root (an existing colcon workspace "
        f"too) writes its {CONFIG_FILE}.",
    )


def discover_packages(
    workspace: Workspace, ros_distro: str = DEFAULT_ROS_DISTRO, unreadable: list[WorkspaceError] | None = None
) -> tuple[Package, ...]:
    """Every package under the workspace's package paths, by name; names must be unique.

    A package is firmware when its build type is esp_idf (as colcon tells packages apart), ROS
    otherwise, wherever it lives. Conditions in package.xml are evaluated for ROS 2 ROS_DISTRO.
    A package.xml that cannot be read is an error, or, given UNREADABLE, left out and its error
    added there (commands that use what is installed, not the sources).
    """
    found: dict[str, Package] = {}
    seen: set[Path] = set()
    cache = _ManifestCache.load(workspace, ros_distro)
    for rel in workspace.package_paths:
        for manifest in _manifests(workspace.root / rel, _outputs(workspace)):
            if manifest in seen:  # nested package paths
                continue
            seen.add(manifest)
            package = cache.get(manifest)
            if package is None:
                try:
                    package = _read_manifest(manifest, ros_distro)
                except WorkspaceError as exc:
                    if unreadable is None:
                        raise
                    unreadable.append(exc)
                    continue
                cache.put(manifest, package)
            if package.name in found:
                raise WorkspaceError(
                    f"two packages are named '{package.name}': {found[package.name].path} and {package.path}",
                    "Package names must be unique in a workspace (as colcon's): remove or COLCON_IGNORE one. To "
                    "override an underlay's package linked in whole, link its other packages one by one instead.",
                )
            found[package.name] = package
    cache.save(seen)
    return tuple(found[name] for name in sorted(found))


def _outputs(workspace: Workspace) -> frozenset[str]:
    return frozenset(os.path.join(workspace.ws_dir, d) for d in COLCON_OUTPUTS)


def _sources(dirpath: str, dirnames: list[str], outputs: frozenset[str]) -> list[str]:
    """The directories under DIRPATH that may hold packages: not hidden, not outputs."""
    kept = [d for d in dirnames if not d.startswith((".", "__")) and d not in NOT_SOURCES]
    return [d for d in kept if os.path.normpath(os.path.join(dirpath, d)) not in outputs]


def _searched(base: Path, outputs: frozenset[str] = frozenset()) -> Iterator[tuple[str, list[str]]]:
    """The directories under BASE a search for packages looks at, with their files, as colcon's
    crawl: not below a package or an ignore marker (nor the marker's own), hidden dirs or
    OUTPUTS. Links to directories are followed, as colcon follows them (`ln -s ~/repos/driver
    src/`), each real directory once."""
    for dirpath, dirnames, filenames in walk_following_links(base):
        if any(marker in filenames for marker in IGNORE_MARKERS):
            dirnames[:] = []
            continue
        dirnames[:] = [] if "package.xml" in filenames else sorted(_sources(dirpath, dirnames, outputs))
        yield dirpath, filenames


def _manifests(base: Path, outputs: frozenset[str] = frozenset()) -> Iterable[Path]:
    """package.xml files under BASE (see _searched)."""
    return (Path(dirpath) / "package.xml" for dirpath, files in _searched(base, outputs) if "package.xml" in files)


def walk_following_links(root: str | os.PathLike[str]) -> Iterator[tuple[str, list[str], list[str]]]:
    """os.walk of ROOT following links to directories, as colcon follows them, each real directory
    once: a link loop, or a second way to a directory, is not walked again. Prune dirnames as
    with os.walk."""
    visited: set[str] = set()
    for dirpath, dirnames, filenames in os.walk(root, followlinks=True):
        real = os.path.realpath(dirpath)
        if real in visited:
            dirnames[:] = []
            continue
        visited.add(real)
        yield dirpath, dirnames, filenames


@dataclass(frozen=True)
class LeftOut:
    """A package of the workspace that espdock does not build: WHERE (relative to the workspace
    root) is the ignore marker that leaves it out, or, with KIND, the directory colcon would build
    as a package of that kind though it has no package.xml, or, GONE, the install prefix an
    earlier build left of a package no longer in the sources."""

    where: str
    kind: str = ""
    build_type: str = ""
    gone: bool = False

    @property
    def what(self) -> str:
        if self.gone:
            return f"{self.where} is an earlier build's, of a package no longer in the sources (renamed or removed)"
        if not self.kind:
            return f"a workspace package, which {self.where} leaves out"
        return f"{self.where}, {self.kind} with no package.xml, which espdock does not build"

    @property
    def fix(self) -> str:
        if self.gone:
            return "restore its sources (renamed: depend on its new name)"
        if not self.kind:
            return f"remove {self.where}"
        return f"add a package.xml to {self.where} (<build_type>{self.build_type}</build_type>)"

    def not_built(self, name: str) -> str:
        """The warning for a project without a package.xml (unmanifested) that colcon names NAME."""
        return (
            f"warning: {self.where} is not built: {self.kind} with no package.xml, which colcon would build as "
            f"package '{name}'. To build it, {self.fix}; if it is no package, put a COLCON_IGNORE in it"
        )


def left_out(workspace: Workspace) -> dict[str, LeftOut]:
    """The packages under the workspace's package paths that espdock does not build, by name:
    those an ignore marker leaves out (colcon does not see them either), the projects colcon
    would build though they have no package.xml (unmanifested), and, after those, every package
    install/ holds (of a package no longer in the sources, where the name is none of the
    workspace's). Read only to explain a name nothing else provides: names are taken from the
    files as text."""
    found: dict[str, LeftOut] = {}
    outputs = _outputs(workspace)
    for rel in workspace.package_paths:
        for dirpath, dirnames, filenames in walk_following_links(workspace.root / rel):
            dirnames[:] = _sources(dirpath, dirnames, outputs)
            marker = next((m for m in IGNORE_MARKERS if m in filenames), None)
            if marker is None:
                continue
            dirnames[:] = []
            shown = os.path.relpath(os.path.join(dirpath, marker), workspace.root)
            for inner, _, names in walk_following_links(dirpath):
                if "package.xml" in names:
                    with suppress(OSError, UnicodeDecodeError):
                        text = Path(inner, "package.xml").read_text()
                        if match := re.search(r"<name>\s*([^<\s]+)\s*</name>", text):
                            found.setdefault(match.group(1), LeftOut(shown))
    for name, project in unmanifested(workspace).items():
        found.setdefault(name, project)
    # What an earlier build installed of a package renamed or removed since (colcon's marker of
    # its install prefix): a dependency on it is no rosdep key, whose "unknown" guessed another name.
    install = workspace.ws_dir / "install"
    for name in installed_packages(install):
        found.setdefault(name, LeftOut(os.path.relpath(install / name, workspace.root), gone=True))
    return found


def installed_packages(install: Path) -> list[str]:
    """The packages whose prefixes colcon's isolated install INSTALL holds (colcon-core marks
    each), by name."""
    try:
        entries = sorted(install.iterdir())
    except OSError:
        return []
    return [entry.name for entry in entries if (entry / "share" / "colcon-core" / "packages" / entry.name).is_file()]


def unmanifested(workspace: Workspace) -> dict[str, LeftOut]:
    """The directories under the workspace's package paths that colcon identifies as packages
    without a package.xml (its cmake, python and colcon.pkg identification), by the name colcon
    would give them, where no package lies below them (a repository's top-level CMakeLists.txt
    beside its packages is no package of its own to anyone building them). IDF components are
    not projects: the firmware that uses them builds them."""
    found: dict[str, LeftOut] = {}
    outputs = _outputs(workspace)
    for rel in workspace.package_paths:
        candidates: list[tuple[str, str, LeftOut]] = []
        manifests: list[str] = []
        for dirpath, filenames in _searched(workspace.root / rel, outputs):
            if "package.xml" in filenames:
                manifests.append(dirpath)
            elif (project := _project(Path(dirpath), set(filenames), workspace.root)) is not None:
                candidates.append((dirpath, *project))
        for dirpath, name, project in candidates:
            if not any(m.startswith(dirpath + os.sep) for m in manifests):
                found.setdefault(name, project)
    return found


def search_warnings(workspace: Workspace) -> list[str]:
    """A warning for each place under the workspace's package paths whose packages are not found,
    which colcon passes over without a word (the build then failed on a dependency of what it
    held, or a package was just absent): a link that leads nowhere (to another checkout, on a
    clone where that lies elsewhere), a git submodule that is not checked out (a clone made
    without --recurse-submodules, a new git worktree)."""
    return _dangling_links(workspace) + _unchecked_submodules(workspace)


def _unchecked_submodules(workspace: Workspace) -> list[str]:
    top = next((d for d in (workspace.root, *workspace.root.parents) if (d / ".git").exists()), None)
    try:
        text = (top / ".gitmodules").read_text(errors="replace") if top is not None else ""
    except OSError:
        return []
    searched = [(workspace.root / rel).resolve() for rel in workspace.package_paths]
    lines = []
    for path in re.findall(r"^\s*path\s*=\s*(.+?)\s*$", text, flags=re.M):
        module = (top / path).resolve()
        try:
            empty = module.is_dir() and next(module.iterdir(), None) is None
        except OSError:
            continue
        if empty and any(module == base or base in module.parents for base in searched):
            lines.append(
                f"warning: {os.path.relpath(module, workspace.root.resolve())} is a git submodule that is not "
                "checked out (empty): no package in it is found; `git submodule update --init` checks it out"
            )
    return lines


def _dangling_links(workspace: Workspace) -> list[str]:
    lines = []
    for rel in workspace.package_paths:
        for dirpath, filenames in _searched(workspace.root / rel, _outputs(workspace)):
            if "package.xml" in filenames:
                continue  # inside a package: no package is looked for there (a doc's broken link)
            for name in filenames:
                link = Path(dirpath, name)
                if link.is_symlink() and not link.exists():
                    lines.append(
                        f"warning: {os.path.relpath(link, workspace.root)} is a link that leads nowhere "
                        f"({os.readlink(link)}): no package under it is found"
                    )
    return lines


def idf_project_cmake(text: str) -> bool:
    """Whether TEXT, a CMakeLists.txt, is an ESP-IDF project's: it includes IDF's project.cmake."""
    return "project.cmake" in text and "IDF_PATH" in text


def _project(directory: Path, files: set[str], root: Path) -> tuple[str, LeftOut] | None:
    """The name and description of the package colcon would make of DIRECTORY (FILES: its
    files) with no package.xml, if any."""
    shown = os.path.relpath(directory, root)
    name = directory.name
    with suppress(OSError, UnicodeDecodeError):
        if "colcon.pkg" in files:
            import yaml  # only for a workspace with such a file

            with suppress(yaml.YAMLError):
                data = yaml.safe_load((directory / "colcon.pkg").read_text())
                if isinstance(data, dict) and data.get("type"):
                    kind = str(data["type"])
                    build_type = "cmake" if kind == "cmake" else "ament_python" if kind == "python" else kind
                    return str(data.get("name") or name), LeftOut(shown, f"a {kind} package of colcon.pkg", build_type)
        if "CMakeLists.txt" in files:
            text = (directory / "CMakeLists.txt").read_text()
            if re.search(r"^\s*idf_component_register\s*\(", text, re.MULTILINE | re.IGNORECASE):
                return None
            if idf_project_cmake(text):
                return name, LeftOut(shown, "an ESP-IDF project", FIRMWARE_BUILD_TYPE)
            match = re.search(r"^\s*project\s*\(\s*([\w.+-]+)", text, re.MULTILINE | re.IGNORECASE)
            return (match.group(1) if match else name), LeftOut(shown, "a CMake project", "cmake")
        if "setup.py" in files or "setup.cfg" in files:
            cfg = (directory / "setup.cfg").read_text() if "setup.cfg" in files else ""
            py = (directory / "setup.py").read_text() if "setup.py" in files else ""
            match = re.search(r"^\s*name\s*=\s*([\w.-]+)", cfg, re.MULTILINE) or re.search(
                r"""\bname\s*=\s*['"]([\w.-]+)['"]""", py
            )
            return (match.group(1) if match else name), LeftOut(shown, "a Python project", "ament_python")
    return None


class _ManifestCache:
    """Parsed package.xml files of one workspace by path, valid while the file's size, mtime and
    inode are unchanged; in the user's cache directory, best effort (any failure only means
    parsing).

    One small file per workspace, holding only the manifests its last discovery saw: a single
    file for every workspace ever built grew without end (2.7 MB and 8,887 manifests on a
    developer's machine, 54 ms to read at every start and rewritten whole on any change). The
    files of workspaces whose root is gone are removed when a new workspace's file is made."""

    FORMAT = 5

    def __init__(self, path: Path, root: Path, entries: dict, ros_distro: str = DEFAULT_ROS_DISTRO) -> None:
        self.path = path
        self.root = root
        self.entries = entries
        self.changed = False
        # The conditions evaluated depend on it.
        self.ros_distro = ros_distro

    @staticmethod
    def directory() -> Path:
        return xdg_dir(os.environ, "XDG_CACHE_HOME", ".cache") / "espdock" / "manifests"

    @classmethod
    def load(cls, workspace: Workspace, ros_distro: str = DEFAULT_ROS_DISTRO) -> _ManifestCache:
        root = workspace.root.resolve()
        path = cls.directory() / f"{root_key(root)}.json"
        try:
            data = json.loads(path.read_text())
            valid = data.get("format") == cls.FORMAT and data.get("root") == str(root)
            entries = data["entries"] if valid else {}
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            entries = {}
        return cls(path, root, entries if isinstance(entries, dict) else {}, ros_distro)

    @staticmethod
    def _stamp(manifest: Path) -> list[int]:
        # The change time too: `cp -p` of a same-size manifest keeps its size and time.
        info = manifest.stat()
        return [info.st_size, info.st_mtime_ns, info.st_ino, info.st_ctime_ns]

    def get(self, manifest: Path) -> Package | None:
        entry = self.entries.get(str(manifest))
        try:
            if not isinstance(entry, dict) or entry.get("stamp") != [*self._stamp(manifest), self.ros_distro]:
                return None
            build_type = str(entry["build_type"])
            return Package(
                name=str(entry["name"]),
                path=manifest.parent,
                kind=PackageKind.FIRMWARE if build_type == FIRMWARE_BUILD_TYPE else PackageKind.ROS,
                build_type=build_type,
                depends=frozenset(str(d) for d in entry["depends"]),
                is_interface=bool(entry["is_interface"]),
                test_only_depends=frozenset(str(d) for d in entry["test_only_depends"]),
                build_depends=frozenset(str(d) for d in entry["build_depends"]),
            )
        except (OSError, KeyError, TypeError):
            return None

    def put(self, manifest: Path, package: Package) -> None:
        self.entries[str(manifest)] = {
            "stamp": [*self._stamp(manifest), self.ros_distro],
            "name": package.name,
            "build_type": package.build_type,
            "depends": sorted(package.depends),
            "is_interface": package.is_interface,
            "test_only_depends": sorted(package.test_only_depends),
            "build_depends": sorted(package.depends if package.build_depends is None else package.build_depends),
        }
        self.changed = True

    def save(self, seen: Iterable[Path]) -> None:
        """Write the entries of the manifests SEEN (this discovery's), when they differ from the
        file's: a package removed since drops out."""
        seen = {str(manifest) for manifest in seen}
        if not self.changed and self.entries.keys() <= seen:
            return
        entries = {key: value for key, value in self.entries.items() if key in seen}
        try:
            new = not self.path.exists()
            self.path.parent.mkdir(parents=True, exist_ok=True)
            tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}")
            tmp.write_text(json.dumps({"format": self.FORMAT, "root": str(self.root), "entries": entries}))
            os.replace(tmp, self.path)
            if new:
                self._sweep()
        except OSError:
            pass  # a cache: without it, manifests are parsed again

    def _sweep(self) -> None:
        # The one file for every workspace that espdock kept before, and the workspaces since removed.
        self.path.parent.parent.joinpath("manifests.json").unlink(missing_ok=True)
        for other in self.path.parent.glob("*.json"):
            try:
                root = json.loads(other.read_text()).get("root")
                if isinstance(root, str) and workspace_gone(root):
                    other.unlink()
            except (OSError, ValueError, AttributeError):
                other.unlink(missing_ok=True)  # unreadable: nothing in it can be used


def read_package(manifest: Path, ros_distro: str = DEFAULT_ROS_DISTRO) -> Package:
    """The package a package.xml describes (a WorkspaceError when it is not valid)."""
    return _read_manifest(manifest, ros_distro)


def condition_context(ros_distro: str) -> dict[str, str]:
    """The variables package.xml conditions are evaluated with, as colcon-ros and rosdep see
    them in a ROS 2 environment (the ROS images set the same)."""
    return {"ROS_VERSION": "2", "ROS_DISTRO": ros_distro, "ROS_PYTHON_VERSION": "3"}


def _read_manifest(manifest: Path, ros_distro: str = DEFAULT_ROS_DISTRO) -> Package:
    # Imported here: with every manifest unchanged (_ManifestCache), a build never needs it.
    from catkin_pkg.package import InvalidPackage, parse_package

    try:
        pkg = parse_package(str(manifest))
        # catkin_pkg leaves every condition unevaluated (None) until asked; a dual ROS 1/ROS 2
        # package's `$ROS_VERSION == 1` dependencies and build type are not ROS 2's.
        pkg.evaluate_conditions(condition_context(ros_distro))
        build_type = pkg.get_build_type()
    except (InvalidPackage, ValueError, OSError) as exc:
        raise WorkspaceError(
            f"{manifest} is not a valid package.xml: {exc}",
            "Fix the manifest and run again; a package that is not yours to fix can be left out with a "
            "COLCON_IGNORE file in its directory (colcon itself warns of it and leaves it out).",
        ) from exc

    def names(*groups: list) -> set[str]:
        return {d.name for group in groups for d in group if d.evaluated_condition}

    built = names(pkg.build_depends, pkg.buildtool_depends, pkg.build_export_depends, pkg.buildtool_export_depends)
    deps = built | names(pkg.exec_depends)
    tests = names(pkg.test_depends)
    # catkin_pkg's default build type is catkin; espdock's has been ament_cmake (a package.xml
    # without <export><build_type>), which colcon-ros would call ros.catkin.
    build_type = build_type if any(e.tagname == "build_type" for e in pkg.exports) else "ament_cmake"
    return Package(
        name=pkg.name,
        path=manifest.parent,
        kind=PackageKind.FIRMWARE if build_type == FIRMWARE_BUILD_TYPE else PackageKind.ROS,
        build_type=build_type,
        depends=frozenset(deps | tests),
        is_interface="rosidl_interface_packages" in {g.name for g in pkg.member_of_groups},
        test_only_depends=frozenset(tests - deps),
        build_depends=frozenset(built),
    )


def order_packages(packages: Iterable[Package]) -> tuple[Package, ...]:
    """Packages so that each comes after the workspace packages it depends on (stable by name)."""
    by_name = {p.name: p for p in packages}
    ordered: list[Package] = []
    state: dict[str, str] = {}

    def visit(name: str, chain: tuple[str, ...]) -> None:
        if state.get(name) == "done":
            return
        if state.get(name) == "active":
            cycle = " -> ".join((*chain[chain.index(name) :], name))
            raise WorkspaceError(f"dependency cycle: {cycle}", "Remove one of these dependencies.")
        state[name] = "active"
        for dep in sorted(by_name[name].depends & by_name.keys()):
            visit(dep, (*chain, name))
        state[name] = "done"
        ordered.append(by_name[name])

    for name in sorted(by_name):
        visit(name, ())
    return tuple(ordered)


def unknown_package(
    name: str, known: Iterable[str], workspace: Workspace | None = None, kind: str = ""
) -> WorkspaceError:
    """The error for a package NAME the workspace's discovery did not find (KNOWN: what it found,
    of the KIND the command takes, "firmware": only those are offered): left out by an ignore
    marker in WORKSPACE, misspelt, or not there."""
    if workspace is not None and (left := left_out(workspace).get(name)):
        if not left.kind:
            return WorkspaceError(
                f"no package named '{name}' in this workspace: {left.where} leaves it out",
                f"Remove {left.where} to build and run {name}.",
            )
        return WorkspaceError(
            f"no package named '{name}' in this workspace: {left.where} is {left.kind} with no package.xml",
            f"To build and run it with espdock, {left.fix}.",
        )
    close = difflib.get_close_matches(name, list(known), n=1)
    listed = f"{kind.capitalize()} packages" if kind else "Packages"
    hint = f"Did you mean '{close[0]}'?" if close else f"{listed}: {', '.join(sorted(known)) or 'none'}."
    return WorkspaceError(f"no package named '{name}' in this workspace", hint)


def select_up_to(
    packages: tuple[Package, ...], names: Iterable[str], workspace: Workspace | None = None
) -> tuple[Package, ...]:
    """NAMES and every workspace package they depend on, transitively, in build order (WORKSPACE:
    where a name not found may be left out by an ignore marker)."""
    by_name = {p.name: p for p in packages}
    wanted: set[str] = set()
    stack = []
    for name in names:
        if name not in by_name:
            raise unknown_package(name, by_name, workspace)
        stack.append(name)
    while stack:
        name = stack.pop()
        if name in wanted:
            continue
        wanted.add(name)
        stack.extend(by_name[name].depends & by_name.keys())
    return tuple(p for p in order_packages(packages) if p.name in wanted)


def read_tree(base: Path, exclude: tuple[str, ...] = ()) -> dict[str, bytes]:
    """Every file under BASE by path relative to it, skipping caches, hidden and EXCLUDEd paths,
    editors' leftovers, and a file gone before it was read (an editor's save in progress)."""
    if not base.is_dir():
        return {}
    files = {}
    for path in sorted(base.rglob("*")):
        rel = path.relative_to(base)
        if not path.is_file() or any(part.startswith(".") or part == "__pycache__" for part in rel.parts):
            continue
        if any(rel.as_posix().startswith(prefix) for prefix in exclude) or editor_leftover(rel.name):
            continue
        try:
            files[rel.as_posix()] = path.read_bytes()
        except FileNotFoundError:
            continue
    return files


# What editors write beside a file while saving or editing it: vim's test of the directory (4913)
# and its swap files (.Foo.cpp.swp, .swo, ...), emacs' lock links (.#Foo.cpp), JetBrains' safe write
# (Foo.cpp___jb_tmp___, Foo.cpp___jb_old___).
_SAVING = re.compile(r"^4913$|___jb_(tmp|old)___$|^\..+\.sw[a-p]$|^\.#")


def editor_leftover(rel: str) -> bool:
    """Whether REL names an editor's or patch's leftover (Foo.msg~, #Foo.msg#, .orig, .rej, .bak, a
    save's temporary file): nothing a build reads, and in an interface package it would key a new
    micro-ROS library (minutes with the real toolchain)."""
    name = rel.rsplit("/", 1)[-1]
    return (
        name.endswith(("~", ".orig", ".rej", ".bak"))
        or (name.startswith("#") and name.endswith("#"))
        or bool(_SAVING.search(name))
    )


def as_lines(data: bytes) -> bytes:
    """A text file's DATA as its lines read: a checkout's line endings (Git for Windows' autocrlf
    makes every line CRLF) and a leading byte order mark aside."""
    return data.removeprefix(b"\xef\xbb\xbf").replace(b"\r\n", b"\n")


def text_digest(data: bytes) -> str:
    """sha256 of a text file's DATA as its lines read (as_lines)."""
    return hashlib.sha256(as_lines(data)).hexdigest()


def read_image_inputs(root: Path, directory: str, exclude: tuple[str, ...] = ()) -> dict[str, bytes]:
    """The files under ROOT/DIRECTORY that an image is built from, keyed by path relative to ROOT."""
    return {f"{directory}/{rel}": data for rel, data in read_tree(root / directory, exclude).items()}


@dataclass(frozen=True)
class BuildInputs:
    """Everything read from disk that decides the images, so planning itself reads nothing."""

    ros_dockerfile: str
    ros_files: dict[str, bytes]
    idf_dockerfile: str
    idf_files: dict[str, bytes]
    # Interface candidates' files by package name (ROS packages only), and each firmware's app-colcon.meta.
    package_files: dict[str, dict[str, bytes]]
    app_metas: dict[str, str]
    # Each firmware's sdkconfig.defaults files (name -> bytes), read for the library's settings,
    # and the ones its CMakeLists.txt names in order where it sets SDKCONFIG_DEFAULTS.
    sdkconfig_defaults: dict[str, dict[str, bytes]] = field(default_factory=dict)
    sdkconfig_order: dict[str, tuple[str, ...]] = field(default_factory=dict)
    # Which image input files the workspace has of its own (they win over espdock's defaults).
    own_files: frozenset[str] = frozenset()
    # The official-image flavour's Dockerfile, and the workspace's rosdep lock (None: none yet).
    ros_official_dockerfile: str = ""
    rosdep_lock: bytes | None = None
    # Each firmware's chips, as its main/idf_component.yml lists them (`targets`); absent: any.
    supported_targets: dict[str, tuple[str, ...]] = field(default_factory=dict)


def read_build_inputs(workspace: Workspace, packages: Iterable[Package]) -> BuildInputs:
    """Read the Dockerfiles, docker/ and the packages' files that image keys are made of."""
    packages = tuple(packages)
    firmware = [p for p in packages if p.kind is PackageKind.FIRMWARE]
    orders = {p.name: order for p in firmware if (order := named_sdkconfig_defaults(p.path / "CMakeLists.txt"))}
    # Each of Dockerfile.ros, Dockerfile.idf and the files under docker/: the workspace's own
    # where it has one, else espdock's default (espdock.defaults), file by file.
    defaults = defaults_root()
    own = {n for n in (ROS_DOCKERFILE, ROS_OFFICIAL_DOCKERFILE, IDF_DOCKERFILE) if (workspace.root / n).is_file()}
    own |= set(read_image_inputs(workspace.root, IMAGE_INPUT_DIR))
    files = {**read_image_inputs(defaults, IMAGE_INPUT_DIR), **read_image_inputs(workspace.root, IMAGE_INPUT_DIR)}

    def text(name: str) -> str:
        return ((workspace.root if name in own else defaults) / name).read_text()

    idf_prefix = f"{IDF_INPUT_DIR}/"
    return BuildInputs(
        ros_dockerfile=text(ROS_DOCKERFILE),
        ros_official_dockerfile=text(ROS_OFFICIAL_DOCKERFILE),
        rosdep_lock=lock.read_bytes() if (lock := workspace.root / ROSDEP_LOCK).is_file() else None,
        ros_files={rel: data for rel, data in files.items() if not rel.startswith(idf_prefix)},
        idf_dockerfile=text(IDF_DOCKERFILE),
        idf_files={rel.removeprefix(idf_prefix): data for rel, data in files.items() if rel.startswith(idf_prefix)},
        own_files=frozenset(own),
        # read_tree leaves editors' leftovers out: a new .msg~ would key a new micro-ROS library.
        package_files={
            p.name: read_tree(p.path, exclude=("build/", "install/", "log/"))
            for p in packages
            if p.kind is PackageKind.ROS and p.is_interface
        },
        app_metas={
            # Past a Windows editor's byte order mark, as colcon reads it (YAML).
            p.name: (p.path / "app-colcon.meta").read_text(encoding="utf-8-sig")
            for p in packages
            if p.kind is PackageKind.FIRMWARE and (p.path / "app-colcon.meta").is_file()
        },
        sdkconfig_defaults={
            p.name: {
                **{f.name: f.read_bytes() for f in sorted(p.path.glob("sdkconfig.defaults*")) if f.is_file()},
                # and any other its CMakeLists.txt names, by that name, with its chip's variant
                **{
                    name: (p.path / name).read_bytes()
                    for named in orders.get(p.name, ())
                    for name in (named, *(f"{named}.{chip}" for chip in CHIP_TARGETS))
                    if (p.path / name).is_file()
                },
            }
            for p in firmware
        },
        sdkconfig_order=orders,
        supported_targets={
            p.name: targets
            for p in packages
            if p.kind is PackageKind.FIRMWARE and (targets := component_targets(p.path / "main" / "idf_component.yml"))
        },
    )


# A CMake command and its arguments (up to the first `)`: the ones read here take no nested parentheses).
_COMMAND = re.compile(r"(?<![\w$\"])(\w+)\s*\(([^)]*)\)")  # several on a line too: `if(A) message(x) endif()`
_BLOCK_OPENS = {"if", "foreach", "while", "function", "macro", "block"}
_PROJECT_DIR_VARS = ("${CMAKE_CURRENT_LIST_DIR}/", "${CMAKE_CURRENT_SOURCE_DIR}/", "${CMAKE_SOURCE_DIR}/")


class DefaultsList(NamedTuple):
    """What a project's CMakeLists.txt sets SDKCONFIG_DEFAULTS to (sdkconfig_defaults_list)."""

    names: tuple[str, ...]
    conditional: bool  # some of it is set inside an if(), a loop or a function: it may not run


def named_sdkconfig_defaults(cmakelists: Path) -> tuple[str, ...]:
    """The defaults files a project's CMakeLists.txt sets SDKCONFIG_DEFAULTS to before its
    `project()`, in order, relative to the project: IDF reads them instead of sdkconfig.defaults,
    each then its chip's variant. () where it sets none, or names one espdock cannot tell (another
    variable, an absolute path)."""
    return sdkconfig_defaults_list(cmakelists).names


def sdkconfig_defaults_list(cmakelists: Path) -> DefaultsList:
    """named_sdkconfig_defaults, and whether any of it is set under a condition. Every set is taken,
    in order, as if it ran: `set(... base)` then `if(EXISTS ...) list(APPEND ... local)` is the base
    and the local file (the condition is the machine's, not known here)."""
    try:
        text = cmakelists.read_text(errors="replace")
    except OSError:
        return DefaultsList((), False)
    names: list[str] = []
    conditional = False
    opened = 0
    for name_given, args in _COMMAND.findall(_without_comments(text)):
        command = name_given.lower()
        if command in _BLOCK_OPENS:
            opened += 1
        elif command.startswith("end") and command[3:] in _BLOCK_OPENS:
            opened = max(0, opened - 1)
        if command == "project":
            break  # IDF's project() reads the variable: a set after it is read by nothing
        words = [w.strip('"') for w in re.findall(r'"[^"]*"|[^\s"]+', args)]
        if command == "unset" and words[:1] == ["SDKCONFIG_DEFAULTS"]:
            names = []
            continue
        if command == "set" and words[:1] == ["SDKCONFIG_DEFAULTS"]:
            given = words[1:]
            for keyword in ("CACHE", "PARENT_SCOPE"):  # set()'s own keywords, not files
                given = given[: given.index(keyword)] if keyword in given else given
            names, at = [], 0
        elif command == "list" and words[:2] in (["APPEND", "SDKCONFIG_DEFAULTS"], ["PREPEND", "SDKCONFIG_DEFAULTS"]):
            given, at = words[2:], (len(names) if words[0] == "APPEND" else 0)
        else:
            continue
        conditional = conditional or opened > 0
        added = []
        for item in (part for word in given for part in word.split(";")):
            name = next((item.removeprefix(p) for p in _PROJECT_DIR_VARS if item.startswith(p)), item)
            if not name or "$" in name or name.startswith("/"):
                return DefaultsList((), conditional)
            added.append(os.path.normpath(name))  # `./sdkconfig.defaults` is sdkconfig.defaults
        names[at:at] = added
    return DefaultsList(tuple(names), conditional)


def _without_comments(text: str) -> str:
    """TEXT with CMake's comments taken out: bracket comments (`#[[ ... ]]`, over lines), then line
    comments (a `#` in a quoted argument is not one)."""
    kept = []
    for line in re.sub(r"#\[(=*)\[.*?\]\1\]", "", text, flags=re.DOTALL).splitlines():
        quoted, end = False, len(line)
        for index, char in enumerate(line):
            if char == '"' and (index == 0 or line[index - 1] != "\\"):
                quoted = not quoted
            elif char == "#" and not quoted:
                end = index
                break
        kept.append(line[:end])
    return "\n".join(kept)


def component_targets(manifest: Path) -> tuple[str, ...]:
    """The chips an IDF component manifest (idf_component.yml) lists under its top-level
    `targets` (the component manager's field for the targets a component supports), read as the
    component manager reads it, YAML in any of its list forms; () when it lists none."""
    if not manifest.is_file():
        return ()
    import yaml  # only for a workspace with such a file

    try:
        data = yaml.safe_load(manifest.read_text(errors="replace"))
    except yaml.YAMLError as exc:
        raise WorkspaceError(f"{manifest} is not valid YAML: {_yaml_problem(exc)}", _REFUSED_TOO) from None
    if data is None:
        return ()
    # What the component manager's Manifest model refuses, where espdock read "any chip".
    if not isinstance(data, dict):
        shape = "a list" if isinstance(data, list) else "a single value"
        raise WorkspaceError(
            f"{manifest} is {shape}, not a mapping of fields (`targets:`, `dependencies:`)", _REFUSED_TOO
        )
    targets = data.get("targets")
    if targets is None:
        return ()
    if not isinstance(targets, list) or not all(isinstance(target, str) for target in targets):
        raise WorkspaceError(
            f"{manifest}: `targets` is not a list of chip names (`targets: [esp32, esp32s3]`)", _REFUSED_TOO
        )
    return tuple(targets)


_REFUSED_TOO = "Fix it: the IDF component manager refuses it too."


def _yaml_problem(exc: Exception) -> str:
    """PyYAML's error EXC in one line, with where it is (its first line alone says neither)."""
    problem, mark = getattr(exc, "problem", None), getattr(exc, "problem_mark", None)
    if not problem or mark is None:
        return " ".join(str(exc).split())
    return f"{problem} (line {mark.line + 1}, column {mark.column + 1})"


def write_atomically(path: Path, text: str) -> None:
    """Replace PATH's content with TEXT in one rename, keeping its mode and owner."""
    stat = path.stat()
    tmp = path.with_name(f".{path.name}.espdock-tmp")
    try:
        tmp.write_text(text)
        os.chmod(tmp, stat.st_mode & 0o7777)
        if os.geteuid() == 0:
            os.chown(tmp, stat.st_uid, stat.st_gid)
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def give_tree(root: Path, owner: tuple[int, int]) -> None:
    """Hand ROOT and everything under it to OWNER (links themselves, never what they point at)."""
    for dirpath, dirnames, filenames in os.walk(root):
        for name in (*dirnames, *filenames):
            os.lchown(os.path.join(dirpath, name), *owner)
    os.lchown(root, *owner)


@contextmanager
def workspace_lock(workspace: Workspace) -> Iterator[None]:
    """Hold an exclusive lock on the workspace for the duration of a build; a second build in the
    same workspace is refused naming the holder's pid and command."""
    fd = os.open(workspace.root, os.O_RDONLY)
    holder = _holder_path(workspace)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise _held(workspace, holder_text(holder)) from None
        write_holder(holder)
        try:
            yield
        finally:
            remove_holder(holder)
    finally:
        os.close(fd)


def _held(workspace: Workspace, holder: str) -> WorkspaceError:
    return WorkspaceError(
        f"another espdock build is running in {workspace.root}{holder}", "Wait for it to finish, then run again."
    )


def check_not_building(workspace: Workspace) -> None:
    """Refuse, as workspace_lock would, while another build holds the workspace: before a build or
    test writes anything (the rosdep lock it makes first)."""
    if (holder := build_running(workspace)) is not None:
        raise _held(workspace, holder)


def build_running(workspace: Workspace) -> str | None:
    """Who holds the workspace lock (" (pid N: COMMAND)", or "" unknown), None when nobody does."""
    fd = os.open(workspace.root, os.O_RDONLY)
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            return holder_text(_holder_path(workspace))
        fcntl.flock(fd, fcntl.LOCK_UN)
        return None
    finally:
        os.close(fd)


# In /tmp whatever TMPDIR says, as the image locks are: a build with a temp dir of its own (a CI
# job's, libpam-tmpdir's) named to a second one no holder.
HOLDER_DIR = Path("/tmp")


def _holder_path(workspace: Workspace) -> Path:
    """Where the lock's holder says who it is, for the error a second build gets: outside the
    workspace, so that espdock run as root creates nothing there that the user's colcon could not
    write into."""
    return HOLDER_DIR / f"espdock-build-{root_key(workspace.root)}.holder"


def write_holder(holder: Path) -> None:
    """Say in the file HOLDER who holds a lock (this process's pid and command), best effort.
    Where another user's note is there (a killed espdock's, in a sticky /tmp this user may not
    replace it in), beside it in one of this user's own (_own_holder), which holder_text reads too."""
    try:
        program = Path(sys.argv[0]).name
        program = "espdock" if program == "__main__.py" else program  # `python -m espdock`
        command = " ".join([program, *sys.argv[1:]]).encode(errors="backslashreplace")
        # A name no one can have planted a link at in /tmp: another user's link at a name the pid
        # gave had root's espdock write through it, into whatever file it led to.
        fd, temporary = tempfile.mkstemp(prefix=f".{holder.name}.", dir=holder.parent)
        try:
            os.fchmod(fd, 0o644)  # for the error another user's espdock gives while waiting
            os.write(fd, f"{os.getpid()}\n".encode() + command + b"\n")
        finally:
            os.close(fd)
        for path in (holder, _own_holder(holder)):
            try:
                os.replace(temporary, path)
                return
            except OSError:
                continue
        os.unlink(temporary)
    except OSError:
        pass  # only the error message a second build would give loses its detail


def remove_holder(holder: Path) -> None:
    """Remove the note write_holder left at HOLDER (or beside it), as the lock is let go."""
    for path in (holder, _own_holder(holder)):
        with suppress(OSError):  # another user's file in a sticky /tmp stays
            if _names_this_process(path):
                path.unlink()


def _own_holder(holder: Path) -> Path:
    """Where this user's note goes where another user's is at HOLDER."""
    return holder.with_name(f"{holder.name}.{os.getuid()}")


def _read_holder(path: Path) -> tuple[str, str] | None:
    """The pid and command write_holder wrote at PATH, or None where there is no such note."""
    try:
        pid, _, command = path.read_text(errors="replace").partition("\n")
    except OSError:
        return None  # the holder has not written it yet, or has just finished
    return pid.strip(), command.removesuffix("\n")


def _names_this_process(path: Path) -> bool:
    note = _read_holder(path)
    return note is not None and note[0] == str(os.getpid())


def holder_text(holder: Path) -> str:
    """ " (pid N: COMMAND)" of what write_holder wrote at HOLDER (or beside it), or "" where it did
    not, or where that process has gone: a killed espdock's note that the next holder could not
    replace (another user's, in a sticky /tmp) named a dead pid to every later waiter."""
    for path in (holder, *sorted(holder.parent.glob(f"{glob.escape(holder.name)}.*"))):
        note = _read_holder(path)
        if note is None:
            continue
        pid, command = note
        if pid.isdigit() and _still_running(int(pid), command):
            return f" (pid {pid}: {command.strip()})"
    return ""


def _still_running(pid: int, command: str) -> bool:
    """Whether process PID is alive and runs COMMAND (write_holder's: its arguments end its command
    line), not another process that got the pid since."""
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # another user's: alive
    try:
        argv = Path(f"/proc/{pid}/cmdline").read_bytes().rstrip(b"\0").split(b"\0")
    except OSError:  # hidden from this user (/proc's hidepid), or gone since: taken at its word
        return True
    arguments = command.split(" ")[1:]
    shown = [part.decode(errors="backslashreplace") for part in argv]
    return not arguments or " ".join(shown).endswith(" " + " ".join(arguments))
