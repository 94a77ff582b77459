"""Benchmark: the venv both make commands start with, from a fresh clone.

Run: .venv/bin/python tests/bench/venv_setup.py [--runs N]

A is `make .venv/.installed` as the Makefile has it (uv installs the hashed lock); B is the
same lock installed by pip alone (`python3 -m venv`, the pinned pip, `pip install
--require-hashes -r requirements/dev.txt`, `pip install --no-deps -e .`), which is what the
Makefile did before and what it falls back to where uv cannot install. Each run clones this
checkout's HEAD into a new temp dir; A and B alternate; both use this machine's caches as
they are (pip's and uv's), as a developer's or CI machine's second setup would. Prints the
medians and their ratio.
"""

from __future__ import annotations

import argparse
import shutil
import statistics
import subprocess
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]

PIP_ONLY = (
    ("python3", "-m", "venv", ".venv"),
    (".venv/bin/python", "-m", "pip", "install", "-q", "--require-hashes", "-r", "docker/pip-installer.txt"),
    (".venv/bin/python", "-m", "pip", "install", "-q", "--require-hashes", "-r", "requirements/dev.txt"),
    (".venv/bin/python", "-m", "pip", "install", "-q", "--no-deps", "-e", "."),
)


def timed_setup(commands: tuple[tuple[str, ...], ...]) -> float:
    """Seconds to run COMMANDS in a fresh clone of HEAD, which is then removed."""
    scratch = Path(tempfile.mkdtemp(prefix="espdock-venv-bench-"))
    try:
        clone = scratch / "x"
        subprocess.run(["git", "clone", "-q", str(REPO), str(clone)], check=True)
        started = time.perf_counter()
        for command in commands:
            subprocess.run(command, cwd=clone, check=True, capture_output=True)
        elapsed = time.perf_counter() - started
        check = [str(clone / ".venv/bin/python"), "-c", "import espdock.cli, pytest, mkdocs"]
        subprocess.run(check, check=True)
        return elapsed
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=3)
    runs = parser.parse_args().runs
    a_times, b_times = [], []
    for _ in range(runs):
        a_times.append(timed_setup((("make", "-s", ".venv/.installed"),)))
        b_times.append(timed_setup(PIP_ONLY))
    a, b = statistics.median(a_times), statistics.median(b_times)
    print(f"A make .venv/.installed (uv)  median {a:6.1f} s (min {min(a_times):.1f}, max {max(a_times):.1f})")
    print(f"B the same lock by pip alone  median {b:6.1f} s (min {min(b_times):.1f}, max {max(b_times):.1f})")
    print(f"A/B = {a / b:.2f}")


if __name__ == "__main__":
    main()
