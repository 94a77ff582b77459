"""Benchmark: a no-change `espdock build` against a bare `docker run ... colcon build` of the same workspace.

Run: .venv/bin/python tests/bench/build_noop.py [--runs N]

Both run in one session on copies of this repository's workspace (custom_interface and
espdock_demo), alternating A B A B so that machine load hits both alike; prints the median
of each and their ratio (targets: espdock's no-op under 0.5 s and under 20 % of the bare run).
Each has its own copy: colcon rewrites files in the install tree even when it builds nothing,
which espdock rightly takes as a changed install tree. The runtime images the copies' builds
make (espdock/noop-bench-a and -b) are removed at the end.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from tests.conftest import copy_workspace, ros_build_tag  # noqa: E402


def timed(argv: list[str], cwd: Path) -> float:
    started = time.perf_counter()
    subprocess.run(argv, cwd=cwd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    names = ("noop-bench-a", "noop-bench-b")
    try:
        a_times, b_times = measure(names, args.runs)
    finally:
        made = subprocess.run(
            ["docker", "image", "ls", "--format", "{{.Repository}}:{{.Tag}}",
             *(f"--filter=reference=espdock/{n}" for n in names)],
            capture_output=True, text=True, check=True,
        ).stdout.split()  # fmt: skip
        if made:
            subprocess.run(["docker", "image", "rm", *made], check=True, stdout=subprocess.DEVNULL)
    a, b = statistics.median(a_times), statistics.median(b_times)
    print(f"no-change build, {args.runs} runs each, alternating, workspace: custom_interface + espdock_demo")
    print(f"A  espdock build --only ros        median {a:6.3f} s  (min {min(a_times):.3f}, max {max(a_times):.3f})")
    print(f"B  docker run ... colcon build     median {b:6.3f} s  (min {min(b_times):.3f}, max {max(b_times):.3f})")
    print(f"A/B = {a / b:.2f}  (target < 0.20; A target < 0.5 s)")


def measure(names: tuple[str, str], runs: int) -> tuple[list[float], list[float]]:
    with tempfile.TemporaryDirectory(prefix="espdock-bench-") as tmp:
        root, other = (copy_workspace(Path(tmp) / name, packages=("custom_interface", "espdock_demo"))
                       for name in names)  # fmt: skip
        espdock = [sys.executable, "-m", "espdock", "build", "--only", "ros"]
        for workspace in (root, other):  # images and both workspaces built
            subprocess.run(espdock, cwd=workspace, check=True, stdout=subprocess.DEVNULL)
        bare = ["docker", "run", "--rm", "-v", f"{other / 'ws'}:/workspace/ws", "-w", "/workspace/ws",
                "--user", f"{os.getuid()}:{os.getgid()}", "-e", "HOME=/tmp", ros_build_tag(root),
                "colcon", "build", "--base-paths", "src"]  # fmt: skip
        timed(bare, other)  # warm
        a_times, b_times = [], []
        for _ in range(runs):
            a_times.append(timed(espdock, root))
            b_times.append(timed(bare, other))
    return a_times, b_times


if __name__ == "__main__":
    main()
