"""The workspace volume's cost: a one-line-edit rebuild on an engine reached over TCP that does not
see the workspace (workspace_mode auto picks the volume), against the same engine seeing another
copy of the workspace at the same path (a bind mount), measured alternately in one run.

    .venv/bin/python tests/bench/volume_mode.py [--rounds 5]

The engine is a private dockerd (tests/integration/test_engines.py's RemoteEngine) started from the
shared engine's Debian and ROS images; both workspaces are test_engines' once_workspace (beacon_nodes,
ament_python). Prints each round's two wall times, their medians and ratio (target <= 1.3), and the
median of no-op builds in volume mode (target <= 1 s) beside the mount's, measured alternately too.
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from tests.conftest import espdock, ros_build_tag, ros_runtime_tag  # noqa: E402
from tests.integration.test_engines import RemoteEngine, edit_word, once_workspace  # noqa: E402
from tests.integration.test_faults import drop_private_engine, private_home  # noqa: E402


def timed_build(root: Path, env: dict[str, str], *extra: str) -> float:
    started = time.monotonic()
    result = espdock("build", "--only", "ros", *extra, cwd=root, env=env)
    seconds = time.monotonic() - started
    if result.returncode != 0:
        raise SystemExit(f"build in {root} failed ({result.returncode}):\n{result.stdout}{result.stderr}")
    return seconds


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("--rounds", type=int, default=5)
    args = parser.parse_args()
    with tempfile.TemporaryDirectory(prefix="espdock-volume-bench-") as tmp:
        hidden, seen = Path(tmp, "hidden"), Path(tmp, "seen")
        hidden.mkdir()
        volume_root = once_workspace(hidden / "ws-volume")
        mount_root = once_workspace(seen / "ws-mount")
        warm = espdock("build", "--only", "ros", cwd=mount_root)  # the shared engine makes the images
        if warm.returncode != 0:
            raise SystemExit(warm.stdout + warm.stderr)
        engine = RemoteEngine(private_home(), hidden)
        try:
            engine.start()
            engine.load("debian:bookworm-slim", ros_build_tag(mount_root), ros_runtime_tag(mount_root))
            print(f"engine: {engine.env['DOCKER_HOST']} (sees {seen}, not {hidden})", flush=True)
            for root in (volume_root, mount_root):
                timed_build(root, engine.env, "--force")
            volume_times: list[float] = []
            mount_times: list[float] = []
            for index in range(args.rounds):
                # Alternating, each first in turn: neither gets the other's warm caches every time.
                pairs = [(volume_root, volume_times), (mount_root, mount_times)]
                for root, times in pairs if index % 2 == 0 else reversed(pairs):
                    edit_word(root, f"edit-{index}")
                    times.append(timed_build(root, engine.env))
                print(f"round {index + 1}: volume {volume_times[-1]:.2f} s, mount {mount_times[-1]:.2f} s", flush=True)
            noop: list[float] = []
            noop_mount: list[float] = []
            for _ in range(args.rounds):
                noop.append(timed_build(volume_root, engine.env))
                noop_mount.append(timed_build(mount_root, engine.env))
            volume_median, mount_median = statistics.median(volume_times), statistics.median(mount_times)
            ratio = volume_median / mount_median
            print(f"one-line-edit rebuild, median of {args.rounds}: volume {volume_median:.2f} s, "
                  f"same-path mount {mount_median:.2f} s, ratio {ratio:.2f} (target <= 1.3)")  # fmt: skip
            print(
                f"no-op build in volume mode, median of {args.rounds}: {statistics.median(noop):.2f} s "
                f"(max {max(noop):.2f} s; target <= 1 s); same-path mount {statistics.median(noop_mount):.2f} s"
            )
            volume = engine.docker("volume", "ls", "-q").stdout.split()
            subprocess.run(["docker", "volume", "rm", *volume], env=engine.env, capture_output=True, check=False)
        finally:
            drop_private_engine(engine)


if __name__ == "__main__":
    main()
