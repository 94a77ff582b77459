"""The order `make test`'s workers take modules in (tests/longest_first.py), on a small suite of
its own run by real pytest-xdist."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.conftest import REPO

SUITE = {
    "pytest.ini": "[pytest]\nmarkers =\n  slow: long\n  engine: needs an engine\n",
    "test_many.py": "".join(f"def test_{n}():\n    pass\n" for n in range(4)),
    "test_engine.py": "import pytest\n\n@pytest.mark.engine\ndef test_one():\n    pass\n",
    "test_slow.py": "import pytest\n\npytestmark = pytest.mark.slow\n\ndef test_one():\n    pass\n",
    "test_sleeps.py": "import time\n\ndef test_one():\n    time.sleep(0.5)\n",
}


@pytest.fixture
def suite(tmp_path: Path) -> Path:
    for name, text in SUITE.items():
        (tmp_path / name).write_text(text)
    return tmp_path


def run_order(suite: Path, *args: str) -> list[str]:
    """The modules of SUITE in the order one xdist worker ran them (the Makefile's options)."""
    env = {**os.environ, "PYTHONPATH": str(REPO), "PYTEST_ADDOPTS": ""}
    command = [sys.executable, "-m", "pytest", "-p", "tests.longest_first", "-v", *args]
    xdist = ["-n", "1", "--dist", "loadfile", "--no-loadscope-reorder"]
    result = subprocess.run([*command, *xdist], cwd=suite, env=env, capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stdout + result.stderr
    modules: list[str] = []
    for module in re.findall(r"PASSED (test_\w+)\.py::", result.stdout):
        if module not in modules:
            modules.append(module)
    return modules


def test_unknown_modules_go_by_markers_then_the_longest_measured_goes_first(suite: Path):
    # A fresh clone: nothing measured, so slow, then engine, then the most tests.
    assert run_order(suite) == ["test_slow", "test_engine", "test_many", "test_sleeps"]
    # Next run: the one that took 0.5 s first.
    assert run_order(suite)[0] == "test_sleeps"

    # A module added since is not known: it goes before every measured one.
    (suite / "test_new.py").write_text("def test_one():\n    pass\n")
    assert run_order(suite)[0] == "test_new"


def test_a_selection_does_not_record_a_module_as_short(suite: Path):
    run_order(suite)
    (suite / "test_sleeps.py").write_text(SUITE["test_sleeps.py"] + "\n\ndef test_two():\n    pass\n")

    run_order(suite, "-k", "test_two")
    assert run_order(suite)[0] == "test_sleeps"
