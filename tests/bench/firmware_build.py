"""Benchmark: firmware builds with a cached micro-ROS image, and what a second firmware package costs on disk.

Run: .venv/bin/python tests/bench/firmware_build.py [--runs N]

Uses the IDF contract double (tests/idf_contract_double/) as the IDF image, since
espressif/idf cannot be pulled on these machines: the timings are espdock's own
overhead plus the double's, not a real ESP-IDF compile. The disk numbers show
where micro-ROS lives: once, in the image, never in a project.
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

from espdock.config import Config, resolve_ca_bundle  # noqa: E402
from espdock.images.engine import Engine  # noqa: E402
from tests.conftest import copy_workspace  # noqa: E402
from tests.idf_contract_double.build import use_double  # noqa: E402


def du(path: Path) -> int:
    return sum(p.lstat().st_size for p in path.rglob("*") if p.is_file() and not p.is_symlink()) if path.exists() else 0


def espdock(root: Path, env: dict[str, str], *args: str) -> float:
    started = time.perf_counter()
    subprocess.run([sys.executable, "-m", "espdock", *args], cwd=root, env=env, check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)  # fmt: skip
    return time.perf_counter() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=5)
    args = parser.parse_args()
    engine = Engine.connect(os.environ)

    with tempfile.TemporaryDirectory(prefix="espdock-bench-") as tmp:
        root = copy_workspace(Path(tmp) / "ws-root")
        env = {**os.environ, **use_double(engine, resolve_ca_bundle(Config(), os.environ), lambda line: None, root)}
        shutil.copy2(REPO / "Dockerfile.idf", root / "Dockerfile.idf")
        shutil.copytree(REPO / "firmware", root / "firmware")
        shutil.rmtree(root / "firmware/camera_node")
        first = espdock(root, env, "build")
        noop_all = [espdock(root, env, "build") for _ in range(args.runs)]
        noop = [espdock(root, env, "build", "--only", "firmware") for _ in range(args.runs)]
        one = {space: du(root / "ws" / space / "led_strip_node") for space in ("build", "install")}

        shutil.copytree(REPO / "firmware/camera_node", root / "firmware/camera_node")
        second = espdock(root, env, "build", "--only", "firmware")
        two = {space: du(root / "ws" / space / "camera_node") for space in ("build", "install")}
        copies = [str(p.relative_to(root)) for p in root.rglob("libmicroros.a")]
        status = subprocess.run([sys.executable, "-m", "espdock", "micro-ros", "status", "--json"], cwd=root,
                                env=env, capture_output=True, text=True, check=True)  # fmt: skip
        image = __import__("json").loads(status.stdout)["firmware"]["led_strip_node"]
        component = subprocess.run(
            ["docker", "run", "--rm", "--entrypoint", "du", image, "-sb", "/opt/espdock/micro_ros_espidf_component"],
            capture_output=True, text=True, check=True,
        ).stdout.split()[0]  # fmt: skip

    print("firmware builds in the IDF contract double image (not a real ESP-IDF compile)")
    print(f"first build (colcon, micro-ROS image, app) {first:6.2f} s")
    for label, values in (("no-change build, whole workspace", noop_all), ("no-change build, --only firmware", noop)):
        print(f"{label:<42} median {statistics.median(values):.2f} s "
              f"(min {min(values):.2f}, max {max(values):.2f}, {args.runs} runs, micro-ROS image cached)")  # fmt: skip
    print(f"adding a second firmware package         {second:6.2f} s (camera_node: its own micro-ROS image, "
          "since its meta and sdkconfig differ)")  # fmt: skip
    print(f"disk, led_strip_node: build {one['build'] / 1e3:.0f} kB, install {one['install'] / 1e3:.0f} kB")
    print(f"disk, camera_node (second): build {two['build'] / 1e3:.0f} kB, install {two['install'] / 1e3:.0f} kB")
    print(f"micro-ROS component, once in the image: {int(component) / 1e6:.2f} MB; "
          f"copies of libmicroros.a in the workspace: {len(copies)}")  # fmt: skip


if __name__ == "__main__":
    main()
