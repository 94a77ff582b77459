"""Measurement: do two clean builds of the ROS build image on this engine give the same image?

Run: .venv/bin/python tests/bench/image_digest.py

Builds the image twice from nothing (its tag removed and BuildKit's cache emptied before
each build: this empties the engine's build cache) in one workspace with a fixed
SOURCE_DATE_EPOCH, and prints whether the image IDs match and how many of the layers do.
Not a test: whether they can match depends on the engine (BuildKit honours SOURCE_DATE_EPOCH
from 0.11, Docker 23; file times inside layers only with its rewrite-timestamp option).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from tests.conftest import copy_workspace, ros_build_tag  # noqa: E402


def build_once(root: Path) -> dict:
    subprocess.run(["docker", "rmi", "-f", ros_build_tag(root)], capture_output=True, check=False)
    subprocess.run(["docker", "builder", "prune", "-af"], capture_output=True, check=True)
    subprocess.run(
        [sys.executable, "-m", "espdock", "build", "--only", "ros"],
        cwd=root, env={**os.environ, "SOURCE_DATE_EPOCH": "1767323045"}, check=True, stdout=subprocess.DEVNULL,
    )  # fmt: skip
    inspect = subprocess.run(
        ["docker", "image", "inspect", ros_build_tag(root)], capture_output=True, text=True, check=True
    )
    return json.loads(inspect.stdout)[0]


def main() -> None:
    engine = subprocess.run(
        ["docker", "version", "-f", "{{.Server.Version}}"], capture_output=True, text=True, check=True
    )
    with tempfile.TemporaryDirectory(prefix="espdock-bench-digest-") as tmp:
        root = copy_workspace(Path(tmp) / "ws")
        first, second = build_once(root), build_once(root)
    layers = list(zip(first["RootFS"]["Layers"], second["RootFS"]["Layers"], strict=False))
    same = sum(1 for a, b in layers if a == b)
    print(f"engine {engine.stdout.strip()}; two clean builds of {ros_build_tag(REPO)}")
    print(f"image IDs equal: {first['Id'] == second['Id']} ({first['Id'][:19]} vs {second['Id'][:19]})")
    print(f"layers identical: {same} of {max(len(first['RootFS']['Layers']), len(second['RootFS']['Layers']))}")
    print(f"created: {first['Created']} vs {second['Created']}")


if __name__ == "__main__":
    main()
