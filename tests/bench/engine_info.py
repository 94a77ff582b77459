"""Benchmark: what espdock asks an engine to learn what it is (Engine.info), against what it asked before.

Run: .venv/bin/python tests/bench/engine_info.py [--runs N]

On a Podman service of its own (Debian's podman, rootful, storage in a temp dir) and on the
machine's Docker engine: A is `Engine.connect(env).info()`, espdock's code as it is; B is the
requests espdock made before over the same socket (Docker: /_ping, /info, /version; Podman:
those and /libpod/info). Podman's Docker API /info and /version ask dpkg the versions of its
packages on every call (0.4 to 0.7 s each); /_ping names Podman in its headers. Alternating
A B A B; prints the medians and their ratio.
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

from espdock.images.engine import LIBPOD_INFO, Engine  # noqa: E402
from espdock.images.local_api import exchange  # noqa: E402
from tests.integration.test_podman import ULIMITS, PodmanService  # noqa: E402


def before(sock: str, podman: bool) -> None:
    for path in ("/_ping", "/info", "/version", *((LIBPOD_INFO,) if podman else ())):
        exchange(sock, 60, "GET", path)


def timed(call) -> float:
    started = time.perf_counter()
    call()
    return time.perf_counter() - started


def compare(name: str, env: dict[str, str], podman: bool, runs: int) -> None:
    sock = env["DOCKER_HOST"].removeprefix("unix://")
    info = Engine.connect(env).info()
    assert info.kind == ("podman" if podman else "docker"), info
    a_times, b_times = [], []
    for _ in range(runs):
        a_times.append(timed(lambda: Engine.connect(env).info()))
        b_times.append(timed(lambda: before(sock, podman)))
    a, b = statistics.median(a_times), statistics.median(b_times)
    pad = " " * len(name)
    print(f"{name}: A espdock's Engine.info   median {a:6.3f} s (min {min(a_times):.3f}, max {max(a_times):.3f})")
    print(f"{pad}  B what it asked before median {b:6.3f} s (min {min(b_times):.3f}, max {max(b_times):.3f})")
    print(f"{pad}  A/B = {a / b:.2f}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=7)
    args = parser.parse_args()
    if shutil.which("podman") is None:
        sys.exit("needs podman (Debian's package): `make test` installs it")
    home = Path(tempfile.mkdtemp(prefix="espdock-bench-podman-"))
    runroot = Path(tempfile.mkdtemp(prefix="ebp-", dir="/tmp"))  # Podman refuses a long run root
    service = PodmanService(home, runroot, ULIMITS)
    try:
        service.start(home)
        compare("Podman", service.env, True, args.runs)
    finally:
        service.stop()
        subprocess.run(["umount", "--lazy", str(home / "storage/overlay")], capture_output=True, check=False)
        shutil.rmtree(home, ignore_errors=True)
        shutil.rmtree(runroot, ignore_errors=True)
    compare("Docker", {**os.environ, "DOCKER_HOST": os.environ.get("DOCKER_HOST", "unix:///var/run/docker.sock")},
            False, args.runs)  # fmt: skip


if __name__ == "__main__":
    main()
