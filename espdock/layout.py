"""Where things are in a workspace and in espdock's containers: the one place each is spelled."""

from __future__ import annotations

import os
import posixpath
import pwd
from collections.abc import Mapping
from pathlib import Path

from espdock.errors import ConfigError

# The workspace marker and its settings, at the workspace root.
CONFIG_FILE = "espdock.toml"
# The images' recipes at the workspace root, and the directories they are built from besides
# their Dockerfiles; docker/idf belongs to the IDF image only.
ROS_DOCKERFILE = "Dockerfile.ros"
# The same images from the official ros:<distro>-ros-base image (setting ros_image = "official").
ROS_OFFICIAL_DOCKERFILE = "Dockerfile.ros-official"
IDF_DOCKERFILE = "Dockerfile.idf"
IMAGE_INPUT_DIR = "docker"
IDF_INPUT_DIR = "docker/idf"
# The commit of every repository libmicroros.a is built from (espdock.firmware.pins).
SOURCES_NAME = "micro_ros_sources.txt"
SOURCES_FILE = f"{IDF_INPUT_DIR}/{SOURCES_NAME}"
# The rosdep resolution of the workspace's dependencies (espdock.ros.rosdeps), beside espdock.toml.
ROSDEP_LOCK = "rosdep.lock.json"
# Where the image builds find what that lock installs, in their build context.
ROSDEP_CONTEXT_DIR = "docker/rosdep"
# Where the workspace is mounted in build containers: one fixed path, whatever the host path,
# so what colcon and CMake record (install/ setup files, .pyc, CMake caches) is the same in every
# clone and the installed files are bit-identical.
WORKSPACE_MOUNT = "/workspace"


def host_path(path: str, root: Path) -> Path | None:
    """Where PATH, as the build containers see it, is on the host (workspace ROOT); None when it
    is not under the workspace mount."""
    normal = posixpath.normpath(path)
    if normal == WORKSPACE_MOUNT:
        return root
    if not normal.startswith(WORKSPACE_MOUNT + "/"):
        return None
    return root / normal[len(WORKSPACE_MOUNT) + 1 :]


# colcon's build base for the ROS packages espdock builds, relative to the colcon root. Not
# colcon's default build/: a CMake build dir records the paths it was configured at (the mount
# above in espdock's containers, the host path in a native `colcon build`), and CMake refuses a
# cache made at another path, so espdock's and native builds each keep their own. Under build/
# (so `rm -rf build` clears it); the hyphen keeps it apart from any package's build dir.
ROS_BUILD_BASE = "build/espdock-ros"


def firmware_build_dir(ws_dir: Path, package: str) -> Path:
    """PACKAGE's IDF build dir as espdock names it, ws/build/PKG: the directory itself, or a link to
    where `colcon build --build-base` put it (espdock.firmware.colcon_install). A link whose target
    is gone (`colcon clean`, `rm -rf` of that base) is dropped here, so the next build starts afresh
    in ws/build instead of failing on it."""
    path = ws_dir / "build" / package
    if path.is_symlink() and not path.exists():
        path.unlink()
    return path


# What colcon writes into a package's build dir after a verb (colcon-package-selection's record
# for --packages-select-build-failed and the like): in a firmware build dir, not the IDF build's.
COLCON_RESULT_FILES = ("colcon_build.rc", "colcon_test.rc")
# Under share/<package> of an installed firmware package: its flashable artefacts.
FIRMWARE_DIR = "firmware"
# In install/: what the last successful `espdock build` produced (espdock.build.manifest).
MANIFEST_NAME = "espdock-manifest.json"


# colcon's record of an install base's layout ("isolated" or "merged"): colcon-core writes it
# and refuses to build into an install base of the other layout; espdock's colcon extension
# writes it where an older colcon (Debian's 0.12) did not.
INSTALL_LAYOUT_FILE = ".colcon_install_layout"


def firmware_install_dir(package: str) -> str:
    """Where PACKAGE's flashable artefacts are installed, relative to the colcon root (colcon's
    default, isolated layout; installed_firmware_dir knows the merged one too)."""
    return f"install/{package}/share/{package}/{FIRMWARE_DIR}"


def merged_install(install_base: Path) -> bool:
    """Whether colcon made INSTALL_BASE a merged one (--merge-install): every package's files in
    the install base itself, where colcon's setup files and the ament index look for them."""
    try:
        return (install_base / INSTALL_LAYOUT_FILE).read_text().strip() == "merged"
    except OSError:
        return False


def install_prefix(install_base: Path, package: str) -> Path:
    """PACKAGE's prefix in INSTALL_BASE, in the layout colcon gave it."""
    return install_base if merged_install(install_base) else install_base / package


def installed_firmware_dir(ws_dir: Path, package: str) -> Path:
    """Where PACKAGE's flashable artefacts are installed in the colcon root WS_DIR."""
    return install_prefix(ws_dir / "install", package) / "share" / package / FIRMWARE_DIR


# The micro-ROS agent the starter compose file's `hardware` profile runs (espdock init).
MICRO_ROS_AGENT_IMAGE = "microros/micro-ros-agent:jazzy"
# The compose file names Compose looks for; espdock init writes the first, beside none of them.
COMPOSE_FILES = ("compose.yaml", "compose.yml", "docker-compose.yaml", "docker-compose.yml")


def xdg_dir(env: Mapping[str, str], variable: str, fallback: str) -> Path:
    """The XDG base directory VARIABLE (XDG_CACHE_HOME, ...) names in ENV, else ~/FALLBACK; a
    relative value is ignored, as the XDG Base Directory spec says (it made directories in
    whatever directory espdock ran in)."""
    value = env.get(variable, "")
    if value and os.path.isabs(value):
        return Path(value)
    return home_dir(env) / fallback


def home_dir(env: Mapping[str, str]) -> Path:
    """The user's home: HOME in ENV, else their passwd entry's. A uid with neither (a CI runner's
    or OpenShift's random uid, run under `env -i`) is told what to set: Python's own lookup raised
    a RuntimeError, "a bug in espdock", at nearly every command."""
    if value := env.get("HOME"):
        return Path(value)
    try:
        return Path(pwd.getpwuid(os.getuid()).pw_dir)
    except KeyError:
        raise ConfigError(
            f"HOME is not set and uid {os.getuid()} has no entry in /etc/passwd, so it has no home",
            "Set HOME to a directory of yours (espdock keeps its caches and state under it, as the Docker CLI "
            "keeps its configuration), e.g. `export HOME=$(mktemp -d)` in a CI job.",
        ) from None
