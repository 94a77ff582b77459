"""`espdock agent` against the real engine, with a stand-in for the micro-ROS agent image."""

from __future__ import annotations

import json
import os
import selectors
import signal
import stat
import subprocess
import sys
import time

import pytest

from tests.agent_double import build_double

pytestmark = pytest.mark.engine


def read_until(process: subprocess.Popen, text: str, timeout: float) -> str:
    seen = ""
    selector = selectors.DefaultSelector()
    selector.register(process.stdout, selectors.EVENT_READ)
    deadline = time.monotonic() + timeout
    while text not in seen and time.monotonic() < deadline and process.poll() is None:
        if selector.select(timeout=0.2):
            seen += os.read(process.stdout.fileno(), 4096).decode(errors="replace")
    return seen


def agent_containers(pid: int) -> list[dict]:
    names = subprocess.run(
        ["docker", "ps", "-aq", "--filter", f"name=espdock-agent-{pid}-"], capture_output=True, text=True, check=True
    ).stdout.split()
    if not names:
        return []
    return json.loads(subprocess.run(["docker", "inspect", *names], capture_output=True, text=True, check=True).stdout)


@pytest.mark.skipif(os.geteuid() != 0, reason="makes a device node (mknod) standing in for the board's port")
def test_the_agent_gets_only_the_board_s_device_and_stops_cleanly_on_ctrl_c(engine, tmp_path):
    tag = build_double(engine, None, lambda line: None)
    # A node of the host's last 8250 UART (no board behind it, never written to) under a
    # /dev/ttyACM-like name: a serial port to check_port, a character device to the engine. A
    # pseudo-terminal will not do: its /dev/pts node opens only in its own devpts instance.
    uarts = sorted(p for p in os.listdir("/dev") if p.startswith("ttyS"))
    if not uarts:
        pytest.skip("no /dev/ttyS* on this host to stand in for the board's port")
    device = tmp_path / "ttyACM0"
    os.mknod(device, 0o660 | stat.S_IFCHR, os.stat(f"/dev/{uarts[-1]}").st_rdev)
    process = subprocess.Popen(
        [sys.executable, "-m", "espdock", "agent", "--port", str(device), "--image", tag, "--domain-id", "7"],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        start_new_session=True,
    )
    try:
        out = read_until(process, "micro-ros-agent double: serial", 120)
        assert f"serial {device} at 115200 baud, ROS_DOMAIN_ID=7" in out, (out, process.stderr.read1())
        (container,) = agent_containers(process.pid)
        host = container["HostConfig"]
        assert host["Privileged"] is False and not host.get("CapAdd")
        assert [(d["PathOnHost"], d["PathInContainer"]) for d in host["Devices"]] == [(str(device), str(device))]
        assert host["NetworkMode"] == "host"
        assert container["Args"] == ["serial", "--dev", str(device), "-b", "115200"]
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=60) == 128 + signal.SIGINT
        assert "stopped" in out + process.stdout.read().decode()
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    assert agent_containers(process.pid) == [], "the agent's container outlived Ctrl-C"
