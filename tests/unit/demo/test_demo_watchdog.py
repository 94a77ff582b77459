"""demo_watchdog with real child processes: a node that stops beating is killed, the exit tells Docker."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

PACKAGE_DIR = Path(__file__).resolve().parents[3] / "ws" / "src" / "espdock_demo"

NODE = textwrap.dedent("""
    import os, pathlib, sys, time
    beat = pathlib.Path(os.environ["ESPDOCK_HEARTBEAT"])
    pathlib.Path(os.environ["NODE_PID_FILE"]).write_text(str(os.getpid()))
    for _ in range(int(sys.argv[1])):
        beat.touch()
        time.sleep(0.2)
    if sys.argv[2] == "hang":
        time.sleep(600)
    sys.exit(int(sys.argv[3]))
""")


def watchdog(tmp_path: Path, beats: int, then: str, code: int = 0) -> tuple[subprocess.Popen, Path]:
    script = tmp_path / "node.py"
    script.write_text(NODE)
    env = {**os.environ, "ESPDOCK_HEARTBEAT": str(tmp_path / "beat"), "NODE_PID_FILE": str(tmp_path / "pid"),
           "PYTHONPATH": str(PACKAGE_DIR)}  # fmt: skip
    argv = [sys.executable, "-m", "espdock_demo.watchdog", "--stale-after", "1.5", "--first-beat", "5", "--",
            sys.executable, str(script), str(beats), then, str(code)]  # fmt: skip
    return subprocess.Popen(argv, env=env, stderr=subprocess.PIPE, text=True), tmp_path / "pid"


def test_a_node_that_exits_passes_its_status_on(tmp_path):
    process, _ = watchdog(tmp_path, beats=2, then="exit", code=3)
    assert process.wait(timeout=20) == 3


def test_a_node_that_stops_beating_is_killed_and_the_watchdog_fails(tmp_path):
    process, pid_file = watchdog(tmp_path, beats=5, then="hang")
    started = time.monotonic()
    assert process.wait(timeout=30) == 1
    assert time.monotonic() - started < 10
    assert "has not beaten" in process.stderr.read()
    node = int(pid_file.read_text())
    assert not Path(f"/proc/{node}").exists() or "Z" in Path(f"/proc/{node}/stat").read_text().split()[2]


def test_a_stopped_node_is_killed_too(tmp_path):
    process, pid_file = watchdog(tmp_path, beats=1000, then="exit")
    deadline = time.monotonic() + 10
    while not pid_file.exists() and time.monotonic() < deadline:
        time.sleep(0.1)
    time.sleep(0.5)
    os.kill(int(pid_file.read_text()), signal.SIGSTOP)
    assert process.wait(timeout=30) == 1


def test_sigterm_reaches_the_node(tmp_path):
    process, pid_file = watchdog(tmp_path, beats=1000, then="exit")
    deadline = time.monotonic() + 10
    while not pid_file.exists() and time.monotonic() < deadline:
        time.sleep(0.1)
    process.send_signal(signal.SIGTERM)
    # The node (a plain child here, ended by the signal's default action) stopped as asked: exit 0.
    assert process.wait(timeout=20) == 0
    node = int(pid_file.read_text())
    with pytest.raises(ProcessLookupError):
        os.kill(node, 0)


def test_sigint_stops_the_node_as_sigterm_does_with_no_traceback(tmp_path):
    """A Ctrl-C for the service reaches the node as SIGTERM: a node still starting (here: no
    handler at all) ends quietly instead of printing a KeyboardInterrupt traceback."""
    process, pid_file = watchdog(tmp_path, beats=1000, then="exit")
    deadline = time.monotonic() + 10
    while not pid_file.exists() and time.monotonic() < deadline:
        time.sleep(0.1)
    process.send_signal(signal.SIGINT)
    assert process.wait(timeout=20) == 0
    assert "Traceback" not in process.stderr.read()


def test_a_second_stop_as_the_watchdog_exits_does_not_kill_it(tmp_path):
    """`docker compose stop` then Ctrl-C, or two kills: a signal that came as the watchdog's
    Python was finishing found the default action back (the interpreter restores it for the
    signals it handled) and killed it, exit 130 with no output, where the stop had exited 0."""
    codes = []
    for _ in range(10):
        process, pid_file = watchdog(tmp_path, beats=1000, then="exit")
        deadline = time.monotonic() + 10
        while not pid_file.exists() and time.monotonic() < deadline:
            time.sleep(0.05)
        pid_file.unlink()
        process.send_signal(signal.SIGTERM)
        while process.poll() is None:  # Ctrl-C after Ctrl-C while it stops
            with contextlib.suppress(ProcessLookupError):
                process.send_signal(signal.SIGINT)
            time.sleep(0.0005)
        codes.append(process.wait())
    assert codes == [0] * 10
