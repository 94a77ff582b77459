"""Benchmark: a no-change `espdock build` against colcon's own no-op build in the same image.

Run: .venv/bin/python tests/bench/build_noop.py [--runs N]
Prints median and spread of both and espdock's overhead (target: under 2 s).
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from tests.conftest import ros_build_tag  # noqa: E402


def timed(argv: list[str], cwd: Path) -> float:
    started = time.perf_counter()
    subprocess.run(argv, cwd=cwd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=7)
    args = parser.parse_args()

    espdock = [sys.executable, "-m", "espdock", "build", "--only", "ros"]
    subprocess.run(espdock, cwd=REPO, check=True, stdout=subprocess.DEVNULL)  # warm: images and ws built
    espdock_times = [timed(espdock, REPO) for _ in range(args.runs)]

    # colcon's own no-op, in a container that is already running (so no container start is counted).
    name = "espdock-bench-colcon"
    subprocess.run(["docker", "rm", "-f", name], capture_output=True, check=False)
    subprocess.run(
        ["docker", "run", "-d", "--name", name, "-v", f"{REPO / 'ws'}:/workspace/ws", "-w", "/workspace/ws",
         "--user", f"{REPO.stat().st_uid}:{REPO.stat().st_gid}", "-e", "HOME=/tmp",
         ros_build_tag(REPO), "sleep", "infinity"],
        check=True, capture_output=True,
    )
    try:
        colcon = ["docker", "exec", name, "colcon", "build", "--base-paths", "src"]
        timed(colcon, REPO)
        started = time.perf_counter()
        subprocess.run(["docker", "exec", name, "true"], check=True)
        exec_cost = time.perf_counter() - started
        colcon_times = [timed(colcon, REPO) - exec_cost for _ in range(args.runs)]
    finally:
        subprocess.run(["docker", "rm", "-f", name], capture_output=True, check=False)

    def row(label: str, values: list[float]) -> str:
        median = statistics.median(values)
        return f"{label:<28} median {median:6.2f} s   min {min(values):6.2f} s   max {max(values):6.2f} s"

    overhead = statistics.median(espdock_times) - statistics.median(colcon_times)
    print(f"no-op build, {args.runs} runs each, workspace {REPO / 'ws'}")
    print(row("espdock build (end to end)", espdock_times))
    print(row("colcon build (in container)", colcon_times))
    print(f"espdock overhead over colcon: {overhead:.2f} s (target < 2 s)   "
          f"ratio {statistics.median(espdock_times) / statistics.median(colcon_times):.2f}x")


if __name__ == "__main__":
    main()
