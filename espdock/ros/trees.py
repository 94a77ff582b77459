"""colcon's build and install trees as espdock leaves them between builds: what a build must
clear or refuse first (CMake caches made at another path or against another ROS image, an install
a native `--merge-install` made), what it must leave as the user's (a native build's setup
scripts), and what it records there of the last build's options and each package's install kind."""

from __future__ import annotations

import json
import os
import re
import shutil
from collections.abc import Iterable, Iterator, Mapping
from contextlib import contextmanager, suppress
from pathlib import Path

from espdock.errors import WorkspaceError
from espdock.images.containers import give_to, make_dirs_for
from espdock.layout import ROS_BUILD_BASE
from espdock.workspace import installed_packages, write_atomically


def retire_container_caches(build: Path, packages: Iterable[str], mounted_build: str) -> list[str]:
    """Remove PACKAGES' build dirs under BUILD (colcon's default build base) whose CMake cache
    was configured at MOUNTED_BUILD, the build containers' path of BUILD: what espdock built
    there before it had a build base of its own. A native `colcon build` refuses them
    ("CMakeCache.txt directory ... is different"); they are only caches. Returns the names."""
    retired = []
    for name in packages:
        cache = build / name / "CMakeCache.txt"
        try:
            text = cache.read_text(errors="replace")
        except OSError:
            continue
        if f"CMAKE_CACHEFILE_DIR:INTERNAL={mounted_build}/{name}\n" in text:
            shutil.rmtree(build / name)
            retired.append(name)
    return retired


def check_isolated_install(install: Path) -> None:
    """Refuse an INSTALL a native `colcon build --merge-install` made: espdock installs each package
    in its own prefix, and colcon will not mix the two layouts in one install base (it stops before
    any package, advising an option espdock keeps to itself)."""
    try:
        layout = (install / ".colcon_install_layout").read_text().strip()
    except OSError:
        return
    if layout == "merged":
        raise WorkspaceError(
            f"{install} was made by `colcon build --merge-install` (its .colcon_install_layout says merged); "
            "espdock builds an isolated install (install/PKG), and colcon will not mix the two",
            "Remove install/ (your native build makes it again), or give your merged builds an install base of "
            "their own (`colcon build --merge-install --install-base install-merged`); nothing was built.",
        )


# The install space's scripts that chain the underlays colcon was given before its own packages.
CHAINING_SCRIPTS = ("setup.bash", "setup.sh", "setup.zsh", "setup.ps1")


@contextmanager
def native_setup_kept(install: Path) -> Iterator[None]:
    """Put back INSTALL's chaining scripts as they were, when a native colcon build wrote them
    (its setup.sh names INSTALL's host path, where a container's names the mount): a build in a
    container writes the image's underlay (/opt/espdock/venv, /opt/ros/jazzy) in place of the
    host's, and `source install/setup.bash` then lost the user's ROS and said "not found"."""
    try:
        native = str(install).encode() in (install / "setup.sh").read_bytes()
    except OSError:
        native = False
    kept = {}
    for name in CHAINING_SCRIPTS if native else ():
        with suppress(OSError):
            kept[install / name] = (install / name).read_bytes()
    try:
        yield
    finally:
        for path, data in kept.items():
            with suppress(OSError):
                if path.read_bytes() != data:
                    write_atomically(path, data.decode())


# In espdock's build base: the ROS image kind its build dirs were configured against.
UNDERLAY_MARKER = ".espdock-underlay"


def retire_other_underlay(base: Path, underlay: str, owner: tuple[int, int]) -> list[str] | None:
    """Remove the package build dirs under BASE (espdock's build base) that were configured
    against another ROS image than UNDERLAY (see ColconBuild.underlay), and record UNDERLAY. Their
    CMake caches hold that image's paths: BUILD_TESTING as it set it, its gtest sources, its
    Python; CMake keeps them, and the build fails or builds other than asked. Returns the names
    (maybe none here: in the workspace volume they are the volume's), None where nothing changed.
    OWNER: who the marker (and a base it makes) belongs to, as root."""
    marker = base / UNDERLAY_MARKER
    try:
        before = marker.read_text().strip()
    except OSError:
        before = None  # a new base, or one from before the marker: taken as configured for UNDERLAY
    if before == underlay:
        return None
    retired = None if before is None else []
    if retired is not None:
        for entry in sorted(base.iterdir()):
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
                retired.append(entry.name)
    make_dirs_for(base, owner)
    marker.write_text(f"{underlay}\n")  # torn, it names no image: the dirs go once more
    give_to(marker, owner)
    return retired


def orphan_installs(install: Path, packages: Iterable[str]) -> list[str]:
    """The package prefixes in INSTALL (colcon's isolated install) of no package in PACKAGES: a
    package renamed or removed since it was built. colcon leaves them, and its setup scripts and
    `ros2 run` still find them (a firmware package's `flash` then fails: no such package)."""
    names = set(packages)
    return [name for name in installed_packages(install) if name not in names]


def package_trees(ws_dir: Path, name: str) -> list[str]:
    """What colcon root WS_DIR holds of package NAME, relative to it: its install prefix, espdock's
    build dir and the one a native `colcon build` (or espdock's firmware build) makes."""
    places = (f"install/{name}", f"{ROS_BUILD_BASE}/{name}", f"build/{name}")
    return [rel for rel in places if (ws_dir / rel).exists() or (ws_dir / rel).is_symlink()]


def natively_linked(install: Path, packages: Iterable[str], root: Path) -> list[str]:
    """PACKAGES whose install prefix in INSTALL holds a link to a path of this machine's workspace
    (ROOT): a native `colcon build --symlink-install` made it. colcon in the container, where
    that path is not, fails on such a link ("[Errno 17] File exists"), blaming the package."""
    inside = f"{root}/"
    found = []
    for name in packages:
        for directory, dirnames, filenames in os.walk(install / name):
            links = (os.path.join(directory, entry) for entry in (*dirnames, *filenames))
            if any(os.path.islink(link) and os.readlink(link).startswith(inside) for link in links):
                found.append(name)
                break
    return found


# The options after `--` of the last colcon build that ran (in the ROS build base): what install/
# is built with, which `espdock test`'s builds keep (a --symlink-install stays one).
LAST_ARGS = ".espdock-colcon-args"


def record_build_args(base: Path, args: tuple[str, ...]) -> Path | None:
    """Keep ARGS as the last build's options in BASE (the ROS build base colcon made); the file."""
    if not base.is_dir():
        return None
    path = base / LAST_ARGS
    path.write_text(json.dumps(list(args)) + "\n")
    return path


def last_build_args(base: Path) -> tuple[str, ...]:
    """The options after `--` of the last colcon build in BASE (none when unknown)."""
    try:
        args = json.loads((base / LAST_ARGS).read_text())
    except (OSError, ValueError):
        return ()
    return tuple(str(arg) for arg in args) if isinstance(args, list) else ()


# Each package's install kind as its last build made it (true: --symlink-install), in the ROS build base.
INSTALL_KINDS = ".espdock-install-kinds.json"


def record_install_kinds(base: Path, names: Iterable[str], args: tuple[str, ...]) -> Path | None:
    """Keep in BASE that NAMES were built with ARGS' install kind (ColconBuild.effective_args).
    The first time, every other package built in BASE gets the kind the last build's options say
    (an older espdock kept only those): call it before record_build_args replaces them."""
    if not base.is_dir():
        return None
    kinds = _install_kinds(base)
    if not (base / INSTALL_KINDS).is_file() and (base / LAST_ARGS).is_file():
        before = "--symlink-install" in last_build_args(base)
        kinds = {entry.name: before for entry in base.iterdir() if entry.is_dir() and not entry.name.startswith(".")}
    kinds = {**kinds, **dict.fromkeys(names, "--symlink-install" in args)}
    path = base / INSTALL_KINDS
    path.write_text(json.dumps(kinds, sort_keys=True) + "\n")
    return path


def _install_kinds(base: Path) -> dict[str, bool]:
    try:
        kinds = json.loads((base / INSTALL_KINDS).read_text())
    except (OSError, ValueError):
        return {}
    return {name: kind for name, kind in kinds.items() if isinstance(kind, bool)} if isinstance(kinds, dict) else {}


def symlink_installed(base: Path, name: str, kinds: Mapping[str, bool] | None = None) -> bool | None:
    """Whether package NAME's last build in BASE was a --symlink-install: as its CMake cache says
    for an ament_cmake package, else its own record (in KINDS where the caller read them), else the
    last build's options (an older espdock kept only those); None where nothing says."""
    if (cached := _cached_symlink_install(base / name / "CMakeCache.txt")) is not None:
        # A build in `espdock shell` shares the build base and keeps no record. Its symlink install
        # stays in the cache (colcon sets it only on), which every later build then makes.
        return cached
    kinds = _install_kinds(base) if kinds is None else kinds
    if name in kinds:
        return kinds[name]
    return "--symlink-install" in last_build_args(base) if (base / LAST_ARGS).is_file() else None


_SYMLINK_INSTALL_CACHED = re.compile(r"^AMENT_CMAKE_SYMLINK_INSTALL:BOOL=(.*)$", re.MULTILINE)


def _cached_symlink_install(cache: Path) -> bool | None:
    """AMENT_CMAKE_SYMLINK_INSTALL in the CMake cache CACHE (ament_cmake's option), None where it is not there."""
    try:
        found = _SYMLINK_INSTALL_CACHED.search(cache.read_text(errors="replace"))
    except OSError:
        return None
    return None if found is None else found.group(1).strip().upper() in ("1", "ON", "TRUE", "YES", "Y")


def install_kind_switched(
    base: Path, names: Iterable[str], args: tuple[str, ...], install: Path | None = None
) -> list[str]:
    """Those of NAMES whose last build in BASE made the other install kind than ARGS (with what the
    defaults file turns on: ColconBuild.effective_args) make. colcon does not switch a build dir in
    place: an interface package's ament_cmake Python install fails on the directories a copying
    install left, one package per run. Kept per package: a selection's switch, kept for the
    workspace, had the next build of the rest build in place (failing, or leaving links in a copying
    install). Where espdock has no word of a package (a native `colcon build` made its prefix in
    INSTALL), its installed package.xml tells."""
    wanted, kinds = "--symlink-install" in args, _install_kinds(base)
    switched = []
    for name in names:
        kind = symlink_installed(base, name, kinds)
        if kind is None and install is not None:
            kind = _installed_kind(install / name / "share" / name / "package.xml")
        if kind not in (None, wanted):
            switched.append(name)
    return switched


def _installed_kind(manifest: Path) -> bool | None:
    """Whether the package.xml an install prefix holds (MANIFEST) is a symlink install's link; None
    where there is none. Both ament_cmake and ament_python install it, a link when symlinking."""
    if manifest.is_symlink():
        return True
    return False if manifest.is_file() else None
