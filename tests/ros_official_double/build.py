"""contract double: builds the image that stands in for the official ROS image
ros:jazzy-ros-base, which cannot be pulled on espdock's test machines (see README.md).

    tag = build_double(engine, ca_bundle, on_line)   # espdock-test/ros-official-double:jazzy-ros-base-<hash>

then select it with ros_image = "official" and base_image = tag (ESPDOCK_ROS_IMAGE,
ESPDOCK_BASE_IMAGE): Dockerfile.ros-official builds unchanged on top of it.
"""

from __future__ import annotations

from pathlib import Path

from espdock.images.engine import Engine
from espdock.images.specs import LineSink
from tests.double_image import ensure_double

HERE = Path(__file__).resolve().parent
# Tagged by the hash of its inputs: a changed double is another base image reference, so the
# images espdock builds on it get new keys (as a new digest pin of the real image would).
IMAGE_REPOSITORY = "espdock-test/ros-official-double"
INPUTS_LABEL = "io.espdock.ros-official-double.inputs"
# What goes into the image (.dockerignore lets in only these).
IMAGE_INPUTS = (".dockerignore", "Dockerfile", "requirements.txt", "ros_entrypoint.sh", "setup.sh", "setup.bash")


def build_double(engine: Engine, ca_bundle: Path | None, on_line: LineSink) -> str:
    """Build the double image unless one built from the same files exists; return its tag."""
    return ensure_double(
        engine, HERE, IMAGE_INPUTS, f"{IMAGE_REPOSITORY}:jazzy-ros-base", INPUTS_LABEL, ca_bundle, on_line
    )


def settings(tag: str) -> dict[str, str]:
    """The ESPDOCK_* settings that build a workspace against the double."""
    return {"ESPDOCK_ROS_IMAGE": "official", "ESPDOCK_BASE_IMAGE": tag}
