"""Benchmark: the first ROS build image on an empty engine, and a one-line change of Dockerfile.ros.

Run: .venv/bin/python tests/bench/ros_image_cold.py

A copy of this workspace whose Dockerfile.ros carries one extra line in stage `base` (a
comment-like `RUN true # NONCE`), so every image here is this run's own:
  cold      BuildKit's cache emptied (`docker builder prune -af`): every layer built and
            every .deb and wheel downloaded; prints the steps that took longest;
  warm      the line changed: every layer after it is rebuilt, the .debs and wheels come
            from BuildKit's cache mounts (docker/apt-install.sh, docker/pip-install.sh);
  no-mounts the line changed again, after emptying only the cache mounts: what every such
            change cost before the mounts (every download again).
Prints wall times and warm/no-mounts. Empties this engine's BuildKit cache.
"""

from __future__ import annotations

import re
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from tests.conftest import copy_workspace  # noqa: E402

DONE = re.compile(r"^#(\d+) DONE (\d+(?:\.\d+)?)s$")


def mark(root: Path, nonce: str) -> None:
    """Put the line `RUN true # NONCE` right after stage base's FROM line (the image key changes)."""
    recipe = root / "Dockerfile.ros"
    lines = [line for line in recipe.read_text().splitlines() if not line.startswith("RUN true # bench ")]
    at = next(i for i, line in enumerate(lines) if line.startswith("FROM ") and line.endswith(" AS base"))
    lines.insert(at + 1, f"RUN true # bench {nonce}")
    recipe.write_text("\n".join(lines) + "\n")


def build(root: Path) -> tuple[float, list[tuple[float, str]]]:
    """Wall time of `espdock build --only ros -v`, and each BuildKit step's time (from its plain progress)."""
    started = time.perf_counter()
    result = subprocess.run(
        [sys.executable, "-m", "espdock", "build", "--only", "ros", "--verbose"],
        cwd=root, capture_output=True, text=True, check=False,
    )  # fmt: skip
    seconds = time.perf_counter() - started
    if result.returncode != 0:
        sys.exit(f"build failed:\n{result.stdout[-3000:]}{result.stderr[-2000:]}")
    # espdock shows a step's "#N [stage i/n] RUN ..." line as "RUN ..." (espdock.images.keyed.BUILDKIT_STEP):
    # the next "#N" line that has no name yet names it.
    names: dict[str, str] = {}
    steps: list[tuple[float, str]] = []
    pending = ""
    for line in map(str.strip, result.stdout.splitlines()):
        if not line.startswith("#"):
            pending = line if line.split(" ", 1)[0] in ("RUN", "COPY", "FROM", "ADD") else pending
        elif (match := DONE.match(line)) and match[1] in names:
            steps.append((float(match[2]), names[match[1]]))
        elif (number := line[1:].split(" ", 1)[0]).isdigit() and number not in names:
            rest = line.split(" ", 1)[1] if " " in line else ""
            if pending:
                names[number], pending = " ".join(re.sub(r"--mount=\S+", "", pending).split())[:100], ""
            elif rest and not rest[0].isdigit() and not rest.startswith(("DONE", "CACHED")):
                names[number] = rest[:100]  # a step of BuildKit's own, e.g. "exporting to image"
    return seconds, sorted(steps, reverse=True)


def prune(*options: str) -> None:
    subprocess.run(["docker", "builder", "prune", "-af", *options], check=True, capture_output=True)


def main() -> None:
    before = images()
    with tempfile.TemporaryDirectory(prefix="espdock-bench-ros-image-") as tmp:
        root = copy_workspace(Path(tmp) / "ws")
        try:
            mark(root, uuid.uuid4().hex)
            prune()
            cold, steps = build(root)
            print(f"cold (empty BuildKit cache): {cold:.1f} s; longest steps:")
            for seconds, name in steps[:6]:
                print(f"  {seconds:6.1f} s  {name}")
            mark(root, uuid.uuid4().hex)
            warm, _ = build(root)
            prune("--filter", "type=exec.cachemount")
            mark(root, uuid.uuid4().hex)
            bare, _ = build(root)
            print(f"one line of Dockerfile.ros changed: {warm:.1f} s with the cache mounts, {bare:.1f} s without "
                  f"them (every download again): ratio {warm / bare:.2f}")  # fmt: skip
        finally:  # this run's images only: the line makes their keys its own
            made = [ref for ref, image in images().items() if image not in before.values()]
            subprocess.run(["docker", "rmi", *made], capture_output=True, check=False)


def images() -> dict[str, str]:
    """espdock's ROS images: repository:tag -> image ID."""
    listed = subprocess.run(
        ["docker", "images", "--format", "{{.Repository}}:{{.Tag}} {{.ID}}", "espdock/ros-*"],
        capture_output=True, text=True, check=True,
    ).stdout.split("\n")  # fmt: skip
    return dict(line.split() for line in listed if line.strip())


if __name__ == "__main__":
    main()
