"""Benchmark: reading a built image's Debian package set for its labels (what every keyed image
build does once), from dpkg's status file in a never-started container, against the way before:
a container that runs `dpkg-query -W` in the image.

Run: .venv/bin/python tests/bench/package_labels.py [IMAGE] [--runs N]

Alternating A B A B on one image (default: debian:bookworm-slim); prints the median wall time
and the machine's busy CPU (/proc/stat, so the engine's and the runtime's share counts) of each,
their ratios, and whether both gave the same package set.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(REPO))

from espdock.images.engine import Engine  # noqa: E402
from espdock.images.keyed import DPKG_LINE, DPKG_STATUS, installed_packages  # noqa: E402
from espdock.images.specs import RunSpec  # noqa: E402

QUERY = ("dpkg-query", "-W", "-f", "${Package}=${Version}\n")


def busy_seconds() -> float:
    fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()
    user, nice, system, irq, softirq = (int(fields[i]) for i in (1, 2, 3, 6, 7))
    return (user + nice + system + irq + softirq) / os.sysconf("SC_CLK_TCK")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("image", nargs="?", default="debian:bookworm-slim")
    parser.add_argument("--runs", type=int, default=15)
    args = parser.parse_args()
    engine = Engine.connect(os.environ)
    labels = {"io.espdock.bench": "package-labels"}

    def queried() -> list[str]:
        lines: list[str] = []
        spec = RunSpec(image=args.image, argv=QUERY, workdir="/", labels=tuple(labels.items()))
        if engine.run(spec, lines.append) != 0:
            sys.exit(f"dpkg-query failed in {args.image}")
        return sorted(line.strip() for line in lines if DPKG_LINE.match(line.strip()))

    def read() -> list[str]:
        status = engine.read_file(args.image, DPKG_STATUS, labels)
        if status is None:
            sys.exit(f"{args.image} has no {DPKG_STATUS}")
        return installed_packages(status.decode())

    times: dict[str, tuple[list[float], list[float]]] = {"dpkg-query run": ([], []), "status file read": ([], [])}
    sets = {}
    for _ in range(args.runs):
        for name, way in (("dpkg-query run", queried), ("status file read", read)):
            wall, cpu = time.monotonic(), busy_seconds()
            sets[name] = way()
            times[name][0].append(time.monotonic() - wall)
            times[name][1].append(busy_seconds() - cpu)
    print(f"{args.image}, {args.runs} runs each, alternating (load {os.getloadavg()[0]:.1f}):")
    medians = {name: (statistics.median(w), statistics.median(c)) for name, (w, c) in times.items()}
    for name, (wall, cpu) in medians.items():
        print(f"  {name}: wall {wall:.3f} s, machine CPU {cpu:.3f} s (medians)")
    (old_wall, old_cpu), (new_wall, new_cpu) = medians.values()
    print(f"  ratio read/run: wall {new_wall / old_wall:.2f}, CPU {new_cpu / old_cpu:.2f}")
    same = sets["dpkg-query run"] == sets["status file read"]
    print(f"  same package set: {same} ({len(sets['status file read'])} packages)")


if __name__ == "__main__":
    main()
