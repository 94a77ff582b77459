"""Benchmark: `espdock build` after a one-line edit in one leaf package of a 15-package workspace,
against a bare `docker run ... colcon build --packages-select <that package>` of the same image
and workspace.

Run: .venv/bin/python tests/bench/colcon_partial.py [--runs N]

The workspace (tests/robot_packages.py): an interface package, 4 ament_python drivers on it,
10 ament_python nodes on the drivers. Both are timed in one session on their own copies, each
after the same kind of one-line edit in the same leaf, alternating A B A B so that machine load
hits both alike; prints the median of each and their ratio (target: at most 1.5). The bare run
is what a user who knew which package changed would type; espdock works that out from its stamps.
The workspace makes no runtime image with each build (espdock's default; `espdock run` and
`espdock compose` make it when they need it), as the bare run makes none.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from tests.bench.build_noop import timed  # noqa: E402
from tests.conftest import copy_workspace, ros_build_tag  # noqa: E402
from tests.robot_packages import write_robot  # noqa: E402

LEAF = "behaviour_9"


def edit(root: Path, count: int) -> None:
    """One line of the leaf's node changed: its default rate."""
    node = root / "ws/src" / LEAF / LEAF / f"{LEAF}_node.py"
    node.write_text(re.sub(r"declare_parameter\('rate_hz', [0-9.]+\)", f"declare_parameter('rate_hz', {count + 1}.0)",
                           node.read_text()))  # fmt: skip


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="espdock-bench-") as tmp:
        roots = []
        # Names of their own: runtime images are espdock/<name> on an engine others share.
        for name in (f"edit-a-{os.getpid()}", f"edit-b-{os.getpid()}"):
            root = copy_workspace(Path(tmp) / name, packages=())
            # espdock's default: no runtime image with each build (the repository's own asks for one).
            config = root / "espdock.toml"
            config.write_text("".join(line for line in config.read_text().splitlines(True)
                                      if not line.startswith("runtime_image")))  # fmt: skip
            graph = write_robot(root / "ws/src", 15)
            roots.append(root)
        assert len(graph) == 15 and not any(LEAF in deps for deps in graph.values())
        root, other = roots
        espdock = [sys.executable, "-m", "espdock", "build", "--only", "ros"]
        for workspace in roots:  # the image and both workspaces built in full
            subprocess.run(espdock, cwd=workspace, check=True, stdout=subprocess.DEVNULL)
        bare = ["docker", "run", "--rm", "-v", f"{other / 'ws'}:/workspace/ws", "-w", "/workspace/ws",
                "--user", f"{os.getuid()}:{os.getgid()}", "-e", "HOME=/tmp", ros_build_tag(root),
                "colcon", "build", "--base-paths", "src", "--packages-select", LEAF]  # fmt: skip
        a_times, b_times = [], []
        for run in range(args.runs + 1):
            edit(root, run)
            edit(other, run)
            a, b = timed(espdock, root), timed(bare, other)
            if run:  # the first pair warms caches
                a_times.append(a)
                b_times.append(b)
        ran = (root / "ws/log/latest_build/events.log").read_text()
        assert f"({LEAF}) JobEnded" in ran and ran.count("JobEnded") == 1, "espdock ran colcon on the leaf only"
        made = subprocess.run(["docker", "images", "-q", f"espdock/{root.name}"], capture_output=True, text=True,
                              check=True).stdout.split()  # fmt: skip
        assert not made, "espdock build made a runtime image nobody asked for"
    a, b = statistics.median(a_times), statistics.median(b_times)
    print(f"one-line edit in leaf {LEAF} of 15 packages, {args.runs} runs each, alternating")
    for label, times in (
        ("A  espdock build --only ros", a_times),
        ("B  docker run ... colcon --packages-select", b_times),
    ):
        median = statistics.median(times)
        print(f"{label:<45} median {median:6.2f} s  (min {min(times):.2f}, max {max(times):.2f})")
    print(f"A/B = {a / b:.2f}  (target <= 1.5)")


if __name__ == "__main__":
    main()
