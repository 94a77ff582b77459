"""Benchmark: the machine's CPU for each test of the suite, and where the suite's time goes.

Run, one test at a time (about 25 min on two cores), then the report:
    CI=true .venv/bin/python -m pytest -n 0 -p tests.bench.suite_cpu --cpu-per-test build/cpu.jsonl
    .venv/bin/python tests/bench/suite_cpu.py build/cpu.jsonl [--top 40]

`make test` is bound by CPU on a two-core machine (its three workers leave a few per cent idle),
so its time is the CPU its tests cause divided by the cores, and a test's cost is its CPU, not its
wall time (a test waiting on a restart costs the others nothing). What a test causes runs in
other processes: espdock's starts, the engine, containerd and runc, the build containers, the
kernel. So this reads the whole machine's busy time (/proc/stat) from a test's setup to its
teardown: one test at a time, on an otherwise idle machine, that is the test's. Module fixtures
count in the test that first asks for them. The report gives each module's CPU, the dearest
tests, how much of the whole the dearest hold, and the least time two cores would need.
"""

from __future__ import annotations

import argparse
import json
import time
from collections import defaultdict
from pathlib import Path

import pytest


def busy_seconds() -> float:
    """The CPU time every core has spent busy since boot (user, system, interrupts, steal; not idle
    or waiting on I/O), from the first line of /proc/stat."""
    with open("/proc/stat") as stat:
        ticks = [int(field) for field in stat.readline().split()[1:9]]
    return (sum(ticks) - ticks[3] - ticks[4]) / 100  # USER_HZ is 100 on Linux


def pytest_addoption(parser: pytest.Parser) -> None:
    parser.addoption("--cpu-per-test", metavar="FILE", help="append each test's machine CPU to FILE (JSON lines)")


def pytest_configure(config: pytest.Config) -> None:
    out = config.getoption("--cpu-per-test")
    if not out:
        return
    if (config.getoption("numprocesses", None) or 0) > 0:
        # The machine's busy time during one test would hold its neighbours' as well.
        raise pytest.UsageError("--cpu-per-test measures one test at a time: run it with -n 0")
    Path(out).parent.mkdir(parents=True, exist_ok=True)  # build/ of a fresh clone


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_protocol(item: pytest.Item, nextitem: pytest.Item | None):
    out = item.config.getoption("--cpu-per-test")
    if not out:
        yield
        return
    cpu, wall = busy_seconds(), time.monotonic()
    yield
    record = {"test": item.nodeid, "cpu": round(busy_seconds() - cpu, 2), "wall": round(time.monotonic() - wall, 2)}
    with open(out, "a") as file:
        file.write(json.dumps(record) + "\n")


def report(records: list[dict], top: int) -> str:
    total = sum(r["cpu"] for r in records)
    lines = [
        f"{len(records)} tests: {total:.0f} s of CPU in {sum(r['wall'] for r in records):.0f} s, "
        f"so at least {total / 2:.0f} s on two cores with nothing idle"
    ]
    dearest = sorted(records, key=lambda r: -r["cpu"])
    for n in (10, 40, 100):
        if n < len(dearest):
            held = sum(r["cpu"] for r in dearest[:n])
            lines.append(f"the dearest {n} tests: {held:.0f} s ({held / total:.0%})")
    modules: dict[str, list[float]] = defaultdict(lambda: [0.0, 0])
    for r in records:
        module = modules[r["test"].split("::", 1)[0]]
        module[0] += r["cpu"]
        module[1] += 1
    lines += ["", "    CPU  tests  module"]
    lines += [f"{cpu:7.1f}  {n:5d}  {m}" for m, (cpu, n) in sorted(modules.items(), key=lambda kv: -kv[1][0])]
    lines += ["", "    CPU    wall  test"]
    lines += [f"{r['cpu']:7.1f} {r['wall']:7.1f}  {r['test']}" for r in dearest[:top]]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("file", type=Path, help="what --cpu-per-test wrote")
    parser.add_argument("--top", type=int, default=40, help="how many of the dearest tests to list")
    args = parser.parse_args()
    print(report([json.loads(line) for line in args.file.read_text().splitlines() if line], args.top))


if __name__ == "__main__":
    main()
