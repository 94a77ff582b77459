"""`espdock run` with the real engine, the real runtime image and real DDS: a workspace of
Python nodes written for these tests (tests/ros_packages/beacon_nodes)."""

from __future__ import annotations

import json
import os
import random
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from tests.conftest import REPO, copy_workspace, espdock, leftover_containers

pytestmark = pytest.mark.engine


@pytest.fixture(scope="module")
def node_workspace(engine, tmp_path_factory) -> Path:
    root = copy_workspace(tmp_path_factory.mktemp("run") / "nodes", packages=())
    shutil.copytree(REPO / "tests" / "ros_packages" / "beacon_nodes", root / "ws" / "src" / "beacon_nodes")
    built = espdock("build", "--only", "ros", cwd=root)
    assert built.returncode == 0, built.stdout + built.stderr
    return root


class Node:
    """`espdock run ARGS` in the background, its output (stdout and stderr) collected by line."""

    def __init__(self, root: Path, *args: str, domain: int) -> None:
        env = {**os.environ, "ROS_DOMAIN_ID": str(domain)}
        self.process = subprocess.Popen(
            [sys.executable, "-m", "espdock", "run", *args],
            cwd=root,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
        )
        self.lines: list[str] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.process.stdout is not None
        for line in self.process.stdout:
            self.lines.append(line.rstrip("\n"))

    def wait_for(self, text: str, timeout: float = 90) -> str:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            found = next((line for line in self.lines if text in line), None)
            if found:
                return found
            if self.process.poll() is not None and not self._reader.is_alive():
                break
            time.sleep(0.1)
        raise AssertionError(f"no line with {text!r} within {timeout:g} s; output:\n" + "\n".join(self.lines[-30:]))

    def interrupt(self, timeout: float = 30) -> int:
        self.process.send_signal(signal.SIGINT)
        code = self.process.wait(timeout=timeout)
        self._reader.join(timeout=5)
        return code

    def stop(self) -> None:
        if self.process.poll() is None:
            self.process.kill()
            self.process.wait()


def no_containers_left(engine, root: Path) -> list[str]:
    deadline = time.monotonic() + 10  # the engine's auto-remove finishes just after the CLI
    while (left := leftover_containers(engine, root)) and time.monotonic() < deadline:
        time.sleep(0.2)
    return left


def test_run_prints_the_nodes_output_and_ctrl_c_ends_it_with_130_leaving_no_container(engine, node_workspace):
    node = Node(node_workspace, "beacon_nodes", "beacon", domain=random.randrange(100, 200))
    try:
        node.wait_for("beacon up")
        node.wait_for("sent: beacon 2")
        assert node.interrupt() == 130
    finally:
        node.stop()
    assert no_containers_left(engine, node_workspace) == []


def test_two_nodes_started_with_run_talk_over_a_topic(engine, node_workspace):
    domain = random.randrange(100, 200)
    listener = Node(node_workspace, "beacon_nodes", "beacon_log", domain=domain)
    talker = Node(
        node_workspace, "beacon_nodes", "beacon", "--ros-args", "-p", "prefix:=ping", "-p", "period:=0.1", domain=domain
    )
    try:
        listener.wait_for("heard: ping")
        assert talker.interrupt() == 130
        assert listener.interrupt() == 130
    finally:
        talker.stop()
        listener.stop()
    assert no_containers_left(engine, node_workspace) == []


def test_another_domain_hears_nothing(engine, node_workspace):
    """ROS_DOMAIN_ID reaches the node: a listener in another domain hears no beacon."""
    domain = random.randrange(100, 200)
    listener = Node(node_workspace, "beacon_nodes", "beacon_log", domain=domain + 1)
    talker = Node(node_workspace, "beacon_nodes", "beacon", "--ros-args", "-p", "period:=0.1", domain=domain)
    try:
        talker.wait_for("sent: beacon 20")
        assert not [line for line in listener.lines if "heard:" in line]
    finally:
        for node in (talker, listener):
            node.interrupt()
            node.stop()


def test_an_unknown_executable_is_exit_2_listing_what_there_is(node_workspace):
    result = espdock("run", "beacon_nodes", "beacon_lgo", cwd=node_workspace)
    assert result.returncode == 2
    assert "no executable 'beacon_lgo'" in result.stderr and "beacon, beacon_log" in result.stderr
    result = espdock("run", "beacon_node", "beacon", cwd=node_workspace)
    assert result.returncode == 2 and "beacon_nodes: beacon, beacon_log" in result.stderr


def test_the_node_exit_code_passes_through(node_workspace):
    # A parameter of the wrong type makes rclpy raise at start-up: the node fails, so does run.
    result = espdock("run", "beacon_nodes", "beacon", "--ros-args", "-p", "period:=fast", cwd=node_workspace)
    assert result.returncode not in (0, 130), result.stdout + result.stderr


def test_init_writes_a_starter_compose_file_whose_services_start_and_talk(engine, node_workspace):
    written = espdock("init", cwd=node_workspace)
    assert written.returncode == 0 and "wrote compose.yaml" in written.stdout, written.stdout + written.stderr
    again = espdock("init", cwd=node_workspace)
    assert again.returncode == 0 and "wrote compose.yaml" not in again.stdout  # never overwritten
    project = f"espdock-test-run-{os.getpid()}-{random.randrange(16**6):06x}"
    env = {**os.environ, "ROS_DOMAIN_ID": str(random.randrange(100, 200))}

    def compose(*args: str) -> subprocess.CompletedProcess[str]:
        argv = ["docker", "compose", "-p", project, *args]
        return subprocess.run(
            argv, cwd=node_workspace, env=env, capture_output=True, text=True, timeout=300, check=False
        )

    config = compose("config", "--format", "json")
    assert config.returncode == 0, config.stderr
    assert {"beacon", "beacon_log"} <= set(json.loads(config.stdout)["services"])
    assert compose("--profile", "hardware", "config", "-q").returncode == 0
    try:
        up = compose("up", "-d", "beacon", "beacon_log")
        assert up.returncode == 0, up.stderr
        deadline = time.monotonic() + 90
        logs = ""
        while "heard: beacon" not in logs and time.monotonic() < deadline:
            time.sleep(1)
            logs = compose("logs", "--no-color", "beacon_log").stdout
        assert "heard: beacon" in logs, compose("logs", "--no-color").stdout[-3000:]
    finally:
        compose("--profile", "*", "down", "-v", "--remove-orphans", "-t", "3")
