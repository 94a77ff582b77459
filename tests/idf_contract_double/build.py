"""contract double: builds the image that stands in for espressif/idf:v5.3.5 and the
micro_ros_espidf_component repository, because neither can be fetched on espdock's test
machines (see README.md).

    tag, commit = build_double(engine, ca_bundle, on_line)

then build Dockerfile.idf with IDF_IMAGE=tag, MICRO_ROS_REPO=MICRO_ROS_REPO and
MICRO_ROS_COMMIT=commit, and docker/idf/micro_ros_sources.txt pinning the double's
repositories; `use_double(engine, ca_bundle, on_line, workspace_root)` does all of that
for a workspace and returns the ESPDOCK_* settings.
"""

from __future__ import annotations

import re
from pathlib import Path

from espdock.errors import ImageBuildError
from espdock.images.engine import Engine
from espdock.images.specs import LineSink, RunSpec
from tests.double_image import ensure_double

HERE = Path(__file__).resolve().parent
# One tag per version of the double's files: branches that change the double share an engine
# without rebuilding one tag from under each other's builds.
IMAGE_REPOSITORY = "espdock-test/idf-contract-double"
INPUTS_LABEL = "io.espdock.idf-contract-double.inputs"
MICRO_ROS_REPO = "file:///opt/espdock-double/micro_ros_espidf_component.git"
COMMIT_FILE = "/opt/espdock-double/MICRO_ROS_COMMIT"
# What goes into the image (the rest of this directory is excluded by .dockerignore).
IMAGE_INPUTS = ("Dockerfile", ".dockerignore", "requirements.txt", "idf", "micro_ros_component", "upstream_repos")
# The double's micro_ros_sources.txt: its upstream repositories, each pinned behind its head.
SOURCES_FILE = "/opt/espdock-double/micro_ros_sources.txt"


def build_double(engine: Engine, ca_bundle: Path | None, on_line: LineSink) -> tuple[str, str]:
    """Build the double image unless one built from the same files exists; return (tag, micro-ROS commit)."""
    tag = ensure_double(engine, HERE, IMAGE_INPUTS, f"{IMAGE_REPOSITORY}:v5.3.5", INPUTS_LABEL, ca_bundle, on_line)
    return tag, micro_ros_commit(engine, tag)


def micro_ros_commit(engine: Engine, image: str) -> str:
    """The commit of the double's micro_ros_espidf_component repository in IMAGE."""
    lines = _read(engine, image, COMMIT_FILE)
    commits = [line.strip() for line in lines if re.fullmatch(r"[0-9a-f]{40}", line.strip())]
    if len(commits) != 1:
        raise ImageBuildError(
            f"no micro-ROS commit in {image} ({COMMIT_FILE}): {lines[-5:]}", f"Rebuild the double: docker rmi {image}"
        )
    return commits[0]


def use_double(engine: Engine, ca_bundle: Path | None, on_line: LineSink, root: Path) -> dict[str, str]:
    """Build the double, pin workspace ROOT's micro-ROS sources to the double's repositories
    (ROOT/docker/idf/micro_ros_sources.txt), and return the ESPDOCK_* settings that select it."""
    tag, commit = build_double(engine, ca_bundle, on_line)
    sources = [line for line in _read(engine, tag, SOURCES_FILE) if line.startswith(("#", "file://"))]
    (root / "docker/idf/micro_ros_sources.txt").write_text("".join(f"{line}\n" for line in sources))
    return {"ESPDOCK_IDF_IMAGE": tag, "ESPDOCK_MICRO_ROS_REPO": MICRO_ROS_REPO, "ESPDOCK_MICRO_ROS_COMMIT": commit}


def _read(engine: Engine, image: str, path: str) -> list[str]:
    lines: list[str] = []
    code = engine.run(RunSpec(image=image, argv=("cat", path), workdir="/"), lines.append)
    if code != 0:
        raise ImageBuildError(
            f"could not read {path} from {image}: exit {code}, output {lines[-5:]}",
            f"Rebuild the double: docker rmi {image}",
        )
    # The entrypoint sources export.sh, which prints its own lines first.
    return [line.rstrip("\n") for line in lines]
