"""Benchmark: a second machine with a warm cache registry against a cold build.

Run: .venv/bin/python tests/bench/cache_registry.py

A workspace with an interface and one firmware app (the IDF contract double stands in for
ESP-IDF). Both runs are fresh clones on an engine without espdock's keyed images:
  cold  - BuildKit's cache emptied too (`docker builder prune`): every keyed image is built;
  warm  - the first machine pushed its images to a local distribution registry: the second
          pulls them.
Prints each run's wall time, how many keyed images it built and pulled, and warm/cold.
Empties this engine's BuildKit cache: later image builds here start cold.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from espdock.config import Config, resolve_ca_bundle  # noqa: E402
from espdock.images.engine import Engine  # noqa: E402
from tests.conftest import copy_workspace  # noqa: E402
from tests.idf_contract_double.build import use_double  # noqa: E402
from tests.registry_server import PASSWORD, Registry, docker_config  # noqa: E402


def build(root: Path, env: dict[str, str], *options: str) -> tuple[float, dict[str, str], list[str]]:
    report = root / "report.json"
    started = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "espdock", "build", "--report", str(report), *options],
        cwd=root, env={**os.environ, **env}, check=True, stdout=subprocess.DEVNULL,
    )  # fmt: skip
    seconds = time.perf_counter() - started
    data = json.loads(report.read_text())
    images = {s["step"]: s["outcome"] for s in data["steps"] if s["step"].startswith("image ")}
    return seconds, images, sorted(data["manifest"]["images"])


def count(images: dict[str, str], outcome: str) -> int:
    return sum(1 for value in images.values() if value == outcome)


def main() -> None:
    engine = Engine.connect(os.environ)
    with tempfile.TemporaryDirectory(prefix="espdock-bench-cache-") as tmp:
        registry = Registry(Path(tmp) / "registry")
        registry.start()
        try:
            origin = copy_workspace(Path(tmp) / "origin")
            shutil.copy2(REPO / "Dockerfile.idf", origin / "Dockerfile.idf")
            shutil.copytree(REPO / "firmware", origin / "firmware")
            shutil.rmtree(origin / "firmware" / "camera_node")
            env = use_double(engine, resolve_ca_bundle(Config(), os.environ), lambda line: None, origin)
            msg = origin / "ws/src/custom_interface/msg/CameraConfig.msg"
            msg.write_text(msg.read_text() + f"# bench {uuid.uuid4().hex}\n")
            env |= {"ESPDOCK_CACHE_REGISTRY": registry.address}
            env |= docker_config(Path(tmp) / "docker", registry.address, PASSWORD)

            # Learn the keyed images' names, then start both runs without them.
            _, _, tags = build(shutil.copytree(origin, Path(tmp) / "probe"), env)
            subprocess.run(["docker", "rmi", "-f", *tags], capture_output=True, check=False)
            subprocess.run(["docker", "builder", "prune", "-af"], capture_output=True, check=False)
            cold, cold_images, _ = build(shutil.copytree(origin, Path(tmp) / "cold"), env, "--push-cache")
            subprocess.run(["docker", "rmi", "-f", *tags], capture_output=True, check=False)
            warm, warm_images, _ = build(shutil.copytree(origin, Path(tmp) / "warm"), env)
        finally:
            registry.stop()
    print(f"keyed images: {len(tags)} ({', '.join(tags)})")
    print(f"cold build (no images, no BuildKit cache; pushes): {cold:6.1f} s, "
          f"{count(cold_images, 'built')} built, {count(cold_images, 'pulled')} pulled")  # fmt: skip
    print(f"second machine, warm registry:                    {warm:6.1f} s, "
          f"{count(warm_images, 'built')} built, {count(warm_images, 'pulled')} pulled")  # fmt: skip
    print(f"warm/cold = {warm / cold:.2f}  (target: 0 images built on the second machine)")


if __name__ == "__main__":
    main()
