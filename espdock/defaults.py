"""The workspace files espdock falls back on where a workspace has none of its own.

They are this repository's own Dockerfile.ros, Dockerfile.idf, docker/ and the shared
firmware component firmware/components/espdock_uros: one source each. A wheel carries copies
made at build time (setup.py) under espdock/workspace_defaults; a source checkout (an
editable install) reads them where they are.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from espdock.layout import IDF_DOCKERFILE, IMAGE_INPUT_DIR, ROS_DOCKERFILE, ROS_OFFICIAL_DOCKERFILE

# What setup.py copies into the wheel, relative to the repository root.
SHIPPED = (ROS_DOCKERFILE, ROS_OFFICIAL_DOCKERFILE, IDF_DOCKERFILE, IMAGE_INPUT_DIR, "firmware/components/espdock_uros")
PACKAGED = "workspace_defaults"


def defaults_root() -> Path:
    """The directory holding the default workspace files (see the module docstring)."""
    packaged = Path(str(resources.files("espdock"))) / PACKAGED
    if (packaged / ROS_DOCKERFILE).is_file():
        return packaged
    checkout = Path(__file__).resolve().parents[1]
    if (checkout / ROS_DOCKERFILE).is_file():
        return checkout
    raise FileNotFoundError(f"espdock's default workspace files are missing (looked in {packaged} and {checkout})")


def default_file(rel: str) -> Path:
    """The default of the workspace file REL (e.g. Dockerfile.ros, docker/ros-build.txt)."""
    return defaults_root() / rel


def locate(root: Path, rel: str) -> Path | None:
    """The workspace's own REL, else espdock's packaged default of it (as the image builds read
    them, file by file), else None."""
    own = root / rel
    if own.is_file():
        return own
    if any(rel == s or rel.startswith(f"{s}/") for s in SHIPPED):
        default = defaults_root() / rel
        if default.is_file():
            return default
    return None
