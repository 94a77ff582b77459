"""The test run's own set-up around the tests (tests/engine_sweep.py), for the unit tier."""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import threading
import time

from tests.conftest import REPO


def test_the_unit_tier_does_not_wait_on_an_engine_that_never_answers(tmp_path):
    """A remote DOCKER_HOST that accepts and never answers (off the VPN): `make unit`, which needs no
    engine, waited a minute for the run's engine listing at its start and another at its end."""
    path = tmp_path / "s"
    silent = socket.socket(socket.AF_UNIX)
    silent.bind(str(path))
    silent.listen(8)
    held: list[socket.socket] = []
    threading.Thread(target=lambda: held.extend(iter(lambda: silent.accept()[0], None)), daemon=True).start()
    env = {**os.environ, "DOCKER_HOST": f"unix://{path}", "PYTEST_ADDOPTS": ""}
    started = time.monotonic()
    ran = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "tests/unit/test_durable.py"],
                         cwd=REPO, env=env, capture_output=True, text=True, timeout=300, check=False)  # fmt: skip
    took = time.monotonic() - started
    silent.close()
    assert ran.returncode == 0, ran.stdout[-2000:] + ran.stderr[-2000:]
    assert took < 45, f"{took:.0f} s: the run waited on the silent engine"


def test_the_double_is_not_pointed_at_espdock_s_own_checkout():
    """`python -m tests.idf_contract_double use .` in the checkout rewrote the micro-ROS sources
    espdock ships (docker/idf/micro_ros_sources.txt) to the double's, unsaid."""
    sources = REPO / "docker/idf/micro_ros_sources.txt"
    before = sources.read_bytes()
    ran = subprocess.run([sys.executable, "-m", "tests.idf_contract_double", "use", str(REPO)], cwd=REPO,
                         capture_output=True, text=True, timeout=120, check=False)  # fmt: skip
    assert ran.returncode == 2 and "is a checkout of espdock" in ran.stderr, ran.stderr
    assert sources.read_bytes() == before
    # Nor a directory of it that is no workspace (its pins read by no build, left in the checkout).
    ran = subprocess.run([sys.executable, "-m", "tests.idf_contract_double", "use", str(REPO / "ws")], cwd=REPO,
                         capture_output=True, text=True, timeout=120, check=False)  # fmt: skip
    assert ran.returncode == 2 and "no espdock workspace" in ran.stderr, ran.stderr
    assert not (REPO / "ws/docker").exists()
