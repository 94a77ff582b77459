"""The test run's own cleanup (tests/engine_sweep.py) on the real engine: of the images the run's
builds recorded, the runtime images go; the keyed base images, and whatever was there before
the run, stay."""

from __future__ import annotations

import json
import subprocess
import time
import uuid

import pytest

from espdock.build.steps import LABEL_INPUTS
from espdock.images.prune import record_use
from tests.engine_sweep import runtime_tags, tagged_images

pytestmark = [pytest.mark.engine]


def make_image(tag: str, inputs: dict[str, str]) -> None:
    """A small image labelled as espdock labels a keyed image made from INPUTS."""
    subprocess.run(
        ["docker", "build", "-q", "--label", f"{LABEL_INPUTS}={json.dumps(inputs)}", "-t", tag, "-"],
        input="FROM debian:bookworm-slim\n", capture_output=True, text=True, check=True, timeout=300,
    )  # fmt: skip


def test_the_run_removes_the_runtime_images_its_builds_made_and_keeps_base_images_and_older_tags(engine, tmp_path):
    run = uuid.uuid4().hex[:8]
    runtime, base, older = (f"espdock/sweep-{kind}-{run}" for kind in ("runtime", "base", "older"))
    made = [f"{runtime}:aaaa", f"{runtime}:latest", f"{base}:bbbb", f"{older}:cccc"]
    try:
        make_image(f"{older}:cccc", {"base": "1", "install": "2"})
        before = tagged_images()
        make_image(f"{runtime}:aaaa", {"base": "1", "install": "3"})
        subprocess.run(["docker", "tag", f"{runtime}:aaaa", f"{runtime}:latest"], check=True)
        make_image(f"{base}:bbbb", {"Dockerfile.ros": "4", "arg:ROS_DISTRO": "5"})
        used = [(f"{runtime}:aaaa", runtime), (f"{base}:bbbb", base), (f"{older}:cccc", older)]
        record_use(tmp_path / "state", tmp_path / "ws", used, time.time())
        assert runtime_tags(tmp_path / "state", before) == [f"{runtime}:aaaa", f"{runtime}:latest"]
    finally:
        subprocess.run(["docker", "rmi", *made], capture_output=True, check=False)
