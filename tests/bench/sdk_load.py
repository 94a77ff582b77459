"""Benchmark: what loading the Docker SDK (and requests), or other modules, costs a short espdock command.

Run: .venv/bin/python tests/bench/sdk_load.py [--runs N] [--preload MODULE,...] [--command ARG,...]

On the local socket espdock talks plain HTTP, so a command that only lists and runs containers
never imports the SDK. The command runs as it is (A) and with the SDK and requests
imported first (B): B is what every such start paid while a listing still went through the
SDK (a no-change build's container sweeps and its closing size note, `micro-ros status`).
`--preload typer.rich_utils` gives what every start paid while espdock imported Typer's help
drawing (rich's Markdown and tracebacks) to patch its console; `--preload http.client,yaml
--command list,-n` what a command that talks to no engine (`list`, `verify`, a refusal of bad
input, shell completion) paid while espdock imported them with its engine client and compose.yaml's
checks (a build talks to the engine and reads a firmware package's idf_component.yml anyway).
A B A B in one session, so that machine load hits both alike; prints the medians of wall time
and of the process's CPU (user + system) and their ratios.
"""

from __future__ import annotations

import argparse
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from tests.conftest import copy_workspace  # noqa: E402


def preloaded(modules: str) -> str:
    """A script that starts espdock as `espdock` does, with MODULES (if any) imported first: A and B
    start alike but for them (`python -m` runs espdock's __main__ another way)."""
    return "\n".join(
        ("import sys", *([f"import {modules}"] if modules else []), "from espdock.__main__ import run", "run()")
    )


def timed(argv: list[str], cwd: Path) -> tuple[float, float]:
    """(wall s, CPU s of the process and its children) of ARGV in CWD."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    started = time.perf_counter()
    subprocess.run(argv, cwd=cwd, check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    wall = time.perf_counter() - started
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def medians(runs: list[tuple[float, float]]) -> tuple[float, float]:
    return statistics.median(wall for wall, _ in runs), statistics.median(cpu for _, cpu in runs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=11)
    parser.add_argument("--preload", default="docker,docker.errors,requests", help="modules B imports first")
    parser.add_argument("--command", default="build,--only,ros", help="the espdock command timed, after a build")
    args = parser.parse_args()
    build = ["build", "--only", "ros"]
    command = args.command.split(",")
    with tempfile.TemporaryDirectory(prefix="espdock-bench-") as tmp:
        # No runtime image: the bench leaves nothing on the engine but the project's ROS image.
        root = copy_workspace(Path(tmp) / "ws-root", packages=(), test_packages=("beacon_nodes",), runtime_image=False)
        subprocess.run([sys.executable, "-m", "espdock", *build], cwd=root, check=True, stdout=subprocess.DEVNULL)
        plain, first = [], []
        script = preloaded(", ".join(args.preload.split(",")))
        for _ in range(args.runs):  # the first build of the loop has nothing to do either
            plain.append(timed([sys.executable, "-c", preloaded(""), *command], root))
            first.append(timed([sys.executable, "-c", script, *command], root))
    (a_wall, a_cpu), (b_wall, b_cpu) = medians(plain), medians(first)
    print(f"espdock {' '.join(command)} (after a build): {args.runs} runs each, alternating, medians")
    print(f"  A  as it is              wall {a_wall:6.3f} s  CPU {a_cpu:6.3f} s")
    print(f"  B  {args.preload} imported first")
    print(f"                           wall {b_wall:6.3f} s  CPU {b_cpu:6.3f} s")
    print(f"  A/B  wall {a_wall / b_wall:.2f}  CPU {a_cpu / b_cpu:.2f}")


if __name__ == "__main__":
    main()
