"""Every demo node stops cleanly whenever SIGTERM or SIGINT comes: exit 0, no traceback.

The nodes run as real processes in the demo's runtime image, as their services run them (under
demo_watchdog), with this checkout's espdock_demo mounted over the image's copy (pure Python: the
same as building it in), each started and stopped many times at random moments, side by side."""

from __future__ import annotations

import json
import random
import subprocess

import pytest

from demo_stack import ROOT
from demo_support import need

IMAGE = "espdock/demo:latest"
INSTALLED = "/opt/espdock/ws/install/espdock_demo/lib/python3.11/site-packages/espdock_demo"
NODES = ("camera_sim", "qr_detector", "led_strip_sim", "camera_ui", "demo_monitor")
ROUNDS = 10  # per node: 50 stops in all


@pytest.fixture(scope="module")
def image(request) -> str:
    """The runtime image (for rclpy and the messages); built only when there is none."""
    from demo_stack import docker_problem

    need(docker_problem())
    present = subprocess.run(["docker", "image", "inspect", IMAGE], capture_output=True, check=False)
    if present.returncode != 0:
        request.getfixturevalue("demo_image")
    return IMAGE


def test_every_node_stops_cleanly_whenever_it_is_signalled(image):
    seed = random.randrange(1 << 30)
    argv = [
        "docker", "run", "--rm", "--network", "none", "-e", f"ROS_DOMAIN_ID={random.randrange(1, 100)}",
        "-v", f"{ROOT}/ws/src/espdock_demo/espdock_demo:{INSTALLED}:ro",
        "-v", f"{ROOT}/tests/demo/stop_driver.py:/tmp/stop_driver.py:ro",
        image, "python", "/tmp/stop_driver.py", str(ROUNDS), str(seed), *NODES,
    ]  # fmt: skip
    result = subprocess.run(argv, capture_output=True, text=True, timeout=900, check=False)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr[-2000:]
    stops = [json.loads(line) for line in result.stdout.splitlines() if line.startswith("{")]
    failed = [stop for stop in stops if stop["code"] != 0 or stop["traceback"]]
    print(f"\n{len(stops)} stops (seed {seed}), {len(failed)} not clean")
    assert len(stops) == ROUNDS * len(NODES)
    assert {stop["node"] for stop in stops} == set(NODES)
    assert not failed, f"seed {seed}: " + "\n".join(
        f"{f['node']} {f['signal']} after {f['delay']} s: exit {f['code']}\n{f['traceback'][-1500:]}" for f in failed
    )
