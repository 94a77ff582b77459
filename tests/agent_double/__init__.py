"""contract double: builds the image that stands in for microros/micro-ros-agent:jazzy, which
cannot be pulled on espdock's test machines (see Dockerfile).

    tag = build_double(engine, ca_bundle, on_line)   # espdock-test/micro-ros-agent-double:jazzy-<hash>
"""

from __future__ import annotations

from pathlib import Path

from espdock.images.engine import Engine
from espdock.images.specs import LineSink
from tests.double_image import ensure_double

HERE = Path(__file__).resolve().parent
IMAGE_REPOSITORY = "espdock-test/micro-ros-agent-double"
INPUTS_LABEL = "io.espdock.micro-ros-agent-double.inputs"
IMAGE_INPUTS = (".dockerignore", "Dockerfile", "agent_entrypoint.sh")


def build_double(engine: Engine, ca_bundle: Path | None, on_line: LineSink) -> str:
    """Build the double image unless one built from the same files exists; return its tag."""
    return ensure_double(engine, HERE, IMAGE_INPUTS, f"{IMAGE_REPOSITORY}:jazzy", INPUTS_LABEL, ca_bundle, on_line)
