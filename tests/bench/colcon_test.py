"""Benchmark: `espdock test` on a built 5-package workspace against a bare `docker run ... colcon
test` of the same image and workspace.

Run: .venv/bin/python tests/bench/colcon_test.py [--runs N]

The workspace: tests/ros_packages' tested_cpp (ament_cmake, gtest) and tested_py (ament_python,
pytest and ament_flake8) with three renamed copies of it, resolved through the tests' rosdep
database. After one `espdock test` builds them with their tests and makes the test image, both
are timed alternating A B A B (the build is up to date: what is timed is the check that it is,
and the tests); prints the median of each, their ratio (target: at most 1.1), and the tests
found, passed and failed, from espdock's summary and from the JUnit files of --results.
"""

from __future__ import annotations

import argparse
import compileall
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from espdock.layout import ROS_BUILD_BASE  # noqa: E402
from tests.integration.test_testing import junit_counts  # noqa: E402
from tests.rosdep_db import environment  # noqa: E402

COPIES = ("tested_py_2", "tested_py_3", "tested_py_4")


def timed(argv: list[str], cwd: Path, env: dict[str, str] | None = None) -> float:
    """Seconds ARGV took; exit code 10 (a test failed: the failing fixture test) counts as done."""
    started = time.perf_counter()
    code = subprocess.run(argv, cwd=cwd, env=env, check=False, capture_output=True).returncode
    assert code in (0, 10), (argv, code)
    return time.perf_counter() - started


def make_workspace(root: Path) -> Path:
    (root / "src").mkdir(parents=True)
    for name in ("tested_cpp", "tested_py"):
        shutil.copytree(REPO / "tests/ros_packages" / name, root / "src" / name)
    for copy in COPIES:
        shutil.copytree(REPO / "tests/ros_packages/tested_py", root / "src" / copy)
        (root / "src" / copy / "tested_py").rename(root / "src" / copy / copy)
        (root / "src" / copy / "resource" / "tested_py").rename(root / "src" / copy / "resource" / copy)
        for path in (root / "src" / copy).rglob("*"):
            if path.is_file() and path.suffix in (".py", ".xml", ".cfg"):
                path.write_text(path.read_text().replace("tested_py", copy))
    (root / "espdock.toml").write_text("[espdock]\n")
    return root


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    # espdock as pip installs it, its modules' bytecode written: where PYTHONDONTWRITEBYTECODE is
    # set, every run would compile them all again (0.1 s or more, nothing `espdock test` does).
    compileall.compile_dir(REPO / "espdock", quiet=1)
    loads = [os.getloadavg()[0]]
    with tempfile.TemporaryDirectory(prefix="espdock-bench-") as tmp:
        root = make_workspace(Path(tmp) / "w")
        env = {**os.environ, **environment(Path(tmp))}
        espdock = [sys.executable, "-m", "espdock", "test", "--results", str(Path(tmp) / "results")]
        first = subprocess.run(espdock, cwd=root, env=env, capture_output=True, text=True, check=False)
        assert first.returncode in (0, 10), first.stdout[-3000:] + first.stderr
        image = re.search(r"espdock/ros-jazzy-test:[0-9a-f]{16}", first.stdout).group(0)
        bare = ["docker", "run", "--rm", "-v", f"{root}:/workspace", "-w", "/workspace",
                "--user", f"{os.getuid()}:{os.getgid()}", "-e", "HOME=/tmp", image,
                "colcon", "test", "--base-paths", "src", "--build-base", ROS_BUILD_BASE]  # fmt: skip
        a_times, b_times = [], []
        for run in range(args.runs + 1):
            a, b = timed(espdock, root, env=env), timed(bare, root)
            if run:  # the first pair warms caches
                a_times.append(a)
                b_times.append(b)
        loads.append(os.getloadavg()[0])
        last = subprocess.run(espdock, cwd=root, env=env, capture_output=True, text=True, check=False)
        summary = re.search(r"Summary: \d+ tests.*", last.stdout).group(0)
        tests, failures, errors, skipped = junit_counts(Path(tmp) / "results")
    a, b = statistics.median(a_times), statistics.median(b_times)
    print(f"colcon test of 5 built packages (1 ament_cmake, 4 ament_python), {args.runs} runs each, alternating")
    for label, times in (("A  espdock test", a_times), ("B  docker run ... colcon test", b_times)):
        median = statistics.median(times)
        print(f"{label:<32} median {median:6.2f} s  (min {min(times):.2f}, max {max(times):.2f})")
    print(f"A/B = {a / b:.2f}  (target <= 1.1); load average {loads[0]:.1f} before, {loads[1]:.1f} after")
    print(f"espdock's summary: {summary}")
    passed = tests - failures - errors - skipped
    print(f"JUnit files: {tests} tests, {passed} passed, {failures} failed, {errors} errored, {skipped} skipped")


if __name__ == "__main__":
    main()
