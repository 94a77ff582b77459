"""The suite's CPU meter (tests/bench/suite_cpu.py) on a small suite of its own, run by real pytest."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

from tests.bench.suite_cpu import report
from tests.conftest import REPO

SUITE = {
    "test_spins.py": "import time\n\ndef test_one():\n    end = time.process_time() + 0.3\n"
    "    while time.process_time() < end:\n        pass\n",
    "test_sleeps.py": "import time\n\ndef test_one():\n    time.sleep(0.3)\n\ndef test_two():\n    pass\n",
}


def measured(tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    for name, text in SUITE.items():
        (tmp_path / name).write_text(text)
    env = {**os.environ, "PYTHONPATH": str(REPO), "PYTEST_ADDOPTS": ""}
    # Into build/, as its docs say: a fresh clone has none.
    meter = ["-p", "tests.bench.suite_cpu", "--cpu-per-test", "build/cpu.jsonl"]
    command = [sys.executable, "-m", "pytest", *meter, *args]
    return subprocess.run(command, cwd=tmp_path, env=env, capture_output=True, text=True, check=False)


def test_each_test_gets_at_least_the_cpu_it_spent_itself_and_its_wall_time(tmp_path: Path):
    result = measured(tmp_path, "-p", "no:cacheprovider")
    assert result.returncode == 0, result.stdout + result.stderr
    records = {r["test"]: r for r in map(json.loads, (tmp_path / "build/cpu.jsonl").read_text().splitlines())}
    assert set(records) == {"test_spins.py::test_one", "test_sleeps.py::test_one", "test_sleeps.py::test_two"}
    # The machine's busy time holds the test's own CPU, whatever else the machine was doing.
    assert records["test_spins.py::test_one"]["cpu"] >= 0.25, records
    assert records["test_sleeps.py::test_one"]["wall"] >= 0.3, records


def test_the_meter_refuses_parallel_workers_whose_cpu_it_would_mix(tmp_path: Path):
    result = measured(tmp_path, "-n", "2")
    assert result.returncode == 4 and "run it with -n 0" in result.stderr, result.stdout + result.stderr
    assert not (tmp_path / "build/cpu.jsonl").exists()


def test_the_report_sums_modules_and_says_what_the_dearest_tests_hold():
    records = [{"test": f"tests/a.py::test_{n}", "cpu": 1.0, "wall": 2.0} for n in range(10)]
    records += [{"test": f"tests/b.py::test_{n}", "cpu": 10.0, "wall": 1.0} for n in range(9)]
    text = report(records, top=2)
    assert text.splitlines()[0] == "19 tests: 100 s of CPU in 29 s, so at least 50 s on two cores with nothing idle"
    assert "the dearest 10 tests: 91 s (91%)" in text
    assert "   10.0     10  tests/a.py" in text and "   90.0      9  tests/b.py" in text
    assert text.index("tests/b.py\n") < text.index("tests/a.py\n"), "the dearest module first"
    assert len([line for line in text.splitlines() if "::test_" in line]) == 2
