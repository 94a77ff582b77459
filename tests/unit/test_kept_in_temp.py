"""tests/conftest.py's kept_in_temp: directories (wheel venvs, colcon venvs) kept in a temp dir that
concurrent runs of other checkouts share; one run's cleanup must not remove another's in use."""

from __future__ import annotations

import subprocess
import sys
import tempfile
from pathlib import Path

from tests.conftest import REPO, kept_in_temp

# Another run: another process that took NAME-KEY and keeps using it until told to stop.
HOLDER = """
import sys, tempfile
tempfile.tempdir = sys.argv[1]
from tests.conftest import kept_in_temp
kept_in_temp("espdock-kept", sys.argv[2], lambda place: (place / "venv").mkdir())
print("ready", flush=True)
sys.stdin.readline()
"""


def test_a_directory_another_run_uses_survives_a_run_with_another_key(tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    holder = subprocess.Popen(
        [sys.executable, "-c", HOLDER, str(tmp_path), "other"],
        cwd=REPO, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    try:
        assert holder.stdout.readline().strip() == "ready"
        mine = kept_in_temp("espdock-kept", "mine", lambda place: (place / "venv").mkdir())
        assert (tmp_path / "espdock-kept-other" / "venv").is_dir()  # still in use by the other run
        assert (mine / "venv").is_dir()
    finally:
        holder.communicate("\n", timeout=30)
    # Once no run uses it, it is stale: the next new key removes it, not the one this run holds.
    kept_in_temp("espdock-kept", "newer", lambda place: None)
    assert not (tmp_path / "espdock-kept-other").exists()
    assert (mine / "venv").is_dir()
    assert sorted(p.name for p in Path(tmp_path).glob("espdock-kept-*")) == ["espdock-kept-mine", "espdock-kept-newer"]
