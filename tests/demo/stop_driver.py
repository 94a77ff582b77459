"""Runs inside the demo image: starts each demo node again and again as its service does (under
demo_watchdog) and stops it with SIGTERM or SIGINT after a random delay counted from the node's
start (during its Python's start-up, its imports, rclpy.init, node setup or spinning), then prints
one JSON line per stop: node, signal, delay, exit code, and the output's tail if it held a traceback.

Usage: python stop_driver.py ROUNDS SEED [NODE...]   (the nodes run side by side, one process each)
"""

from __future__ import annotations

import json
import os
import random
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

LIB = "/opt/espdock/ws/install/espdock_demo/lib/espdock_demo"
NODES = ("camera_sim", "qr_detector", "led_strip_sim", "camera_ui", "demo_monitor")
# Long enough to reach the spinning loop on a loaded 2-core machine (a node is up in about 1 s).
MAX_DELAY = 3.0


def node_started(watchdog: subprocess.Popen) -> float:
    """When WATCHDOG started its node (the moment its child appears), by the monotonic clock."""
    children = Path(f"/proc/{watchdog.pid}/task/{watchdog.pid}/children")
    while watchdog.poll() is None:
        try:
            if children.read_text().strip():
                break
        except OSError:
            break
        time.sleep(0.005)
    return time.monotonic()


def stop_many(node: str, rounds: int, rng: random.Random, lock: threading.Lock) -> None:
    for _ in range(rounds):
        delay = rng.uniform(0.0, MAX_DELAY)
        signum = rng.choice((signal.SIGTERM, signal.SIGINT))
        process = subprocess.Popen(
            [f"{LIB}/demo_watchdog", "--", f"{LIB}/{node}"],
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            start_new_session=True,  # a hung node is killed with its watchdog, and frees the pipe
        )
        started = node_started(process)
        try:
            process.wait(timeout=max(0.0, started + delay - time.monotonic()))
        except subprocess.TimeoutExpired:
            process.send_signal(signum)
        try:
            output, _ = process.communicate(timeout=20)
            code = process.returncode
        except subprocess.TimeoutExpired:
            os.killpg(process.pid, signal.SIGKILL)
            output, _ = process.communicate()
            code = "hung"
        text = output.decode(errors="replace")
        record = {
            "node": node,
            "signal": signal.Signals(signum).name,
            "delay": round(delay, 3),
            "code": code,
            "traceback": text[-3000:] if "Traceback" in text else "",
        }
        with lock:
            print(json.dumps(record), flush=True)


def main() -> None:
    rounds, seed = int(sys.argv[1]), int(sys.argv[2])
    nodes = sys.argv[3:] or NODES
    lock = threading.Lock()
    threads = [
        threading.Thread(target=stop_many, args=(node, rounds, random.Random(f"{seed}-{node}"), lock)) for node in nodes
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()


if __name__ == "__main__":
    main()
