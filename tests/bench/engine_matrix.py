"""Exit codes and wall times of espdock's everyday commands against one engine.

    DOCKER_HOST=... python tests/bench/engine_matrix.py WORKSPACE [--prefix CMD ...]

WORKSPACE: a workspace whose one ROS package is beacon_nodes with an executable `once` that prints
`word: ...` (tests/integration/test_engines.py's once_workspace makes one). The commands run in
order: setup, first build (--only ros), no-op build, a one-line edit and its build, `run
beacon_nodes once`, `compose up -d` of the compose file `espdock init` writes of the built nodes
when the workspace has none (then `compose down`). Each
row: the command, its exit code and its wall time; the engine is the one DOCKER_HOST names.
"""

from __future__ import annotations

import argparse
import os
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path


def timed(argv: list[str], cwd: Path) -> tuple[int, float, str]:
    started = time.monotonic()
    result = subprocess.run(argv, cwd=cwd, capture_output=True, text=True, stdin=subprocess.DEVNULL, check=False)
    return result.returncode, time.monotonic() - started, (result.stdout + result.stderr)[-600:]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("workspace", type=Path)
    parser.add_argument("--espdock", default=f"{sys.executable} -m espdock", help="how to start espdock")
    args = parser.parse_args()
    root = args.workspace.resolve()
    espdock = shlex.split(args.espdock)
    once = next((root / "ws/src/beacon_nodes/beacon_nodes").glob("once.py"), None) or next(root.rglob("once.py"))
    rows = []

    def step(name: str, *command: str) -> int:
        code, seconds, tail = timed([*espdock, *command], root)
        rows.append((name, code, seconds))
        print(f"{name:<22} exit {code:>3}  {seconds:7.1f} s", flush=True)
        if code != 0:
            print("    " + tail.replace("\n", "\n    "), flush=True)
        return code

    print(f"engine: {os.environ.get('DOCKER_HOST', 'unix:///var/run/docker.sock')}; workspace {root}")
    step("setup", "setup")
    if step("first build", "build", "--only", "ros") != 0:
        return
    timed([*espdock, "init", "."], root)  # the starter compose file, of the nodes now installed
    step("no-op build", "build", "--only", "ros")
    text = once.read_text()
    once.write_text(re.sub(r'print\("word: [^"]*"\)', f'print("word: edit-{int(time.time())}")', text))
    step("one-line-edit build", "build", "--only", "ros")
    step("run", "run", "beacon_nodes", "once")
    if (root / "compose.yaml").is_file():
        step("compose up -d", "compose", "up", "-d")
        timed([*espdock, "compose", "down", "-t", "0"], root)


if __name__ == "__main__":
    main()
