"""colcon's build and install trees as espdock leaves them between builds: what a build must
clear or refuse first (CMake caches made at another path or against another ROS image, an install
a native `--merge-install` made) and what it must leave as the user's (a native build's setup
scripts)."""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterable, Iterator
from contextlib import contextmanager, suppress
from pathlib import Path

from espdock.errors import WorkspaceError
from espdock.images.containers import give_to, make_dirs_for
from espdock.layout import ROS_BUILD_BASE
from espdock.workspace import write_atomically


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
    try:
        entries = sorted(install.iterdir())
    except OSError:
        return []
    return [
        entry.name
        for entry in entries
        if entry.name not in names and (entry / "share" / "colcon-core" / "packages" / entry.name).is_file()
    ]


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
