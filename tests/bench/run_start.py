"""Benchmark: time from `espdock run PKG EXE` to the node's first output, against `docker run`
of the same image and command.

Run: .venv/bin/python tests/bench/run_start.py [--runs N]

One workspace (beacon_nodes from tests/ros_packages) is built once; then A B A B ...: each run
starts the beacon node, waits for its first line ("beacon up"), and stops it. Prints the
median of each and their ratio (espdock's cost: its own start, finding the workspace, the
executable and the keyed runtime image).
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from tests.conftest import copy_workspace  # noqa: E402

NODE = "/opt/espdock/ws/install/beacon_nodes/lib/beacon_nodes/beacon"


def first_line(argv: list[str], cwd: Path, env: dict[str, str], stop: list[str] | None = None) -> float:
    """Seconds from starting ARGV to its first output line; then it is stopped (STOP, else SIGINT)."""
    started = time.perf_counter()
    process = subprocess.Popen(
        argv, cwd=cwd, env=env, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    assert process.stdout is not None
    line = process.stdout.readline()
    took = time.perf_counter() - started
    if "beacon up" not in line:
        raise SystemExit(f"unexpected first line from {argv[:4]}: {line!r}")
    if stop:
        subprocess.run(stop, capture_output=True, check=False)
    else:
        process.send_signal(2)
    process.communicate(timeout=60)
    return took


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=7)
    args = parser.parse_args()
    env = {**os.environ, "ROS_DOMAIN_ID": "199"}
    with tempfile.TemporaryDirectory(prefix="espdock-bench-") as tmp:
        root = copy_workspace(Path(tmp) / "runbench", packages=())
        shutil.copytree(REPO / "tests" / "ros_packages" / "beacon_nodes", root / "ws" / "src" / "beacon_nodes")
        subprocess.run(
            [sys.executable, "-m", "espdock", "build", "--only", "ros"], cwd=root, check=True, stdout=subprocess.DEVNULL
        )
        image = "espdock/runbench:latest"
        espdock = [sys.executable, "-m", "espdock", "run", "beacon_nodes", "beacon"]
        uid = f"{os.getuid()}:{os.getgid()}"
        timings: dict[str, list[float]] = {"espdock run": [], "docker run": []}
        for run in range(args.runs):
            name = f"espdock-bench-run-{os.getpid()}-{run}"
            docker = ["docker", "run", "--rm", "--name", name, "--network", "host", "--user", uid, "--env",
                      "ROS_DOMAIN_ID=199", "--env", "FASTDDS_BUILTIN_TRANSPORTS=UDPv4", image, NODE]  # fmt: skip
            timings["espdock run"].append(first_line(espdock, root, env))
            timings["docker run"].append(first_line(docker, root, env, stop=["docker", "kill", "-s", "INT", name]))
        medians = {what: statistics.median(values) for what, values in timings.items()}
        for what, values in timings.items():
            print(f"{what:12} median {medians[what]:.3f} s  ({', '.join(f'{v:.2f}' for v in values)})")
        print(f"ratio espdock run / docker run: {medians['espdock run'] / medians['docker run']:.2f}")


if __name__ == "__main__":
    main()
