"""Benchmark: time from `espdock run PKG EXE` to the node's first output, against `docker run`
of the same image and command.

Run: .venv/bin/python tests/bench/run_start.py [--runs N] [--data-mb MB]

One workspace (beacon_nodes from tests/ros_packages) is built once; then A B A B ...: each run
starts the beacon node, waits for its first line ("beacon up"), and stops it. Prints the
median of each and their ratio (espdock's cost: its own start, finding the workspace, the
executable and the keyed runtime image). --data-mb adds a package that installs MB of
meshes, as a robot's description package does: espdock reads what it has not read before,
and every byte of sources and install tree counts in the runtime image's key and the check
of what is stale.
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


def description(package: Path, megabytes: int) -> None:
    """An ament_cmake package installing MEGABYTES of meshes (random bytes, 8 MB a file)."""
    (package / "meshes").mkdir(parents=True)
    (package / "package.xml").write_text(
        '<?xml version="1.0"?>\n<package format="3">\n  <name>bench_description</name>\n  <version>0.0.1</version>\n'
        '  <description>Meshes</description>\n  <maintainer email="bench@example.com">bench</maintainer>\n'
        "  <license>Apache-2.0</license>\n  <buildtool_depend>ament_cmake</buildtool_depend>\n"
        "  <export><build_type>ament_cmake</build_type></export>\n</package>\n"
    )
    (package / "CMakeLists.txt").write_text(
        "cmake_minimum_required(VERSION 3.8)\nproject(bench_description)\nfind_package(ament_cmake REQUIRED)\n"
        "install(DIRECTORY meshes DESTINATION share/${PROJECT_NAME})\nament_package()\n"
    )
    for index in range(0, megabytes, 8):
        (package / "meshes" / f"part_{index // 8}.stl").write_bytes(os.urandom(min(8, megabytes - index) << 20))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=7)
    parser.add_argument("--data-mb", type=int, default=0)
    args = parser.parse_args()
    env = {**os.environ, "ROS_DOMAIN_ID": "199"}
    with tempfile.TemporaryDirectory(prefix="espdock-bench-") as tmp:
        root = copy_workspace(Path(tmp) / "runbench", packages=())
        shutil.copytree(REPO / "tests" / "ros_packages" / "beacon_nodes", root / "ws" / "src" / "beacon_nodes")
        if args.data_mb:
            description(root / "ws" / "src" / "bench_description", args.data_mb)
        subprocess.run(
            [sys.executable, "-m", "espdock", "build", "--only", "ros"], cwd=root, check=True, stdout=subprocess.DEVNULL
        )
        image = "espdock/runbench:latest"
        espdock = [sys.executable, "-m", "espdock", "run", "beacon_nodes", "beacon"]
        uid = f"{os.getuid()}:{os.getgid()}"
        timings: dict[str, list[float]] = {"espdock run": [], "docker run": []}
        try:
            for run in range(args.runs):
                name = f"espdock-bench-run-{os.getpid()}-{run}"
                docker = ["docker", "run", "--rm", "--name", name, "--network", "host", "--user", uid, "--env",
                          "ROS_DOMAIN_ID=199", "--env", "FASTDDS_BUILTIN_TRANSPORTS=UDPv4", image, NODE]  # fmt: skip
                timings["espdock run"].append(first_line(espdock, root, env))
                stop = ["docker", "kill", "-s", "INT", name]
                timings["docker run"].append(first_line(docker, root, env, stop=stop))
        finally:
            made = subprocess.run(
                ["docker", "image", "ls", "--format", "{{.Repository}}:{{.Tag}}",
                 "--filter=reference=espdock/runbench"],
                capture_output=True, text=True, check=True,
            ).stdout.split()  # fmt: skip
            if made:
                subprocess.run(["docker", "image", "rm", *made], check=True, stdout=subprocess.DEVNULL)
        medians = {what: statistics.median(values) for what, values in timings.items()}
        for what, values in timings.items():
            print(f"{what:12} median {medians[what]:.3f} s  ({', '.join(f'{v:.2f}' for v in values)})")
        print(f"ratio espdock run / docker run: {medians['espdock run'] / medians['docker run']:.2f}")


if __name__ == "__main__":
    main()
