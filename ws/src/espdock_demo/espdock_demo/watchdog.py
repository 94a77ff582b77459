"""demo_watchdog: runs a demo node and ends the container when the node stops beating.

    demo_watchdog [--stale-after S] [--first-beat S] -- NODE [ARGS...]

Every node touches its heartbeat file (ESPDOCK_HEARTBEAT) from its executor each second.
Docker's healthcheck sees a stale file and marks the container unhealthy, but never restarts
an unhealthy container, so a stuck node (a deadlock, a blocked callback, a SIGSTOP) would stay
stuck. A watchdog inside the node cannot help there: a stopped or deadlocked process stops its
watchdog thread too. So this runs as the node's parent, in another process: when the
heartbeat is older than --stale-after seconds it kills the node and exits non-zero, and the
service's `restart: unless-stopped` starts a fresh one. SIGTERM and SIGINT stop the node
(as SIGTERM); a node ended by that signal before it could handle it exits 0, as a stop.
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

from espdock_demo.names import HEARTBEAT_FILE_DEFAULT


def beat_age(path: Path, since: float) -> float:
    """Seconds since the node's last beat after SINCE (wall clock), counting from SINCE if none."""
    try:
        last = max(path.stat().st_mtime, since)
    except FileNotFoundError:
        last = since
    return time.time() - last


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="demo_watchdog", description=__doc__.splitlines()[0])
    parser.add_argument("--stale-after", type=float, default=6.0, help="seconds without a beat before the kill")
    parser.add_argument("--first-beat", type=float, default=30.0, help="seconds a starting node has for its first beat")
    parser.add_argument("command", nargs=argparse.REMAINDER)
    args = parser.parse_args(argv)
    command = args.command[1:] if args.command[:1] == ["--"] else args.command
    if not command:
        parser.error("give the node's command after --")
    heartbeat = Path(os.environ.get("ESPDOCK_HEARTBEAT", HEARTBEAT_FILE_DEFAULT))
    started = time.time()
    stops: list[int] = []
    node: subprocess.Popen | None = None

    def forward(_signum: int, _frame: object) -> None:
        # Either is a stop, and the node handles both alike; a SIGINT that comes while the node's
        # Python is still starting would print a KeyboardInterrupt traceback, SIGTERM ends it quietly.
        stops.append(signal.SIGTERM)
        if node is not None:
            node.send_signal(signal.SIGTERM)

    # Before the node starts: a stop at any moment reaches it, none leaves it running without us.
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, forward)
    node = subprocess.Popen(command)
    if stops:  # came while it was being started
        node.send_signal(signal.SIGTERM)
    try:
        while True:
            try:
                code = node.wait(timeout=0.5)
            except subprocess.TimeoutExpired:
                pass
            else:
                if code < 0 and -code in stops:
                    return 0  # the stop asked for ended a node still too young to handle it: a stop
                return code if code >= 0 else 128 - code  # killed by signal N: 128 + N, as a shell says
            age = beat_age(heartbeat, started)
            beaten = heartbeat.exists() and heartbeat.stat().st_mtime > started
            limit = args.stale_after if beaten else args.first_beat
            if age > limit:
                name = os.path.basename(command[0])
                print(
                    f"demo_watchdog: {name} has not beaten for {age:.0f} s (limit {limit:g} s): stuck; "
                    "killing it so the service restarts",
                    file=sys.stderr,
                    flush=True,
                )
                node.kill()  # SIGKILL also ends a stopped process
                node.wait()
                return 1
    finally:
        # The node is gone: a stop that comes now has nothing to stop, and as the interpreter exits
        # it puts the default action back for the signals it handled, which killed it (exit 130).
        for signum in (signal.SIGTERM, signal.SIGINT):
            signal.signal(signum, signal.SIG_IGN)


if __name__ == "__main__":
    sys.exit(main())
