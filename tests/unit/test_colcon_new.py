"""`espdock new` in a colcon workspace leaves plain colcon clean (the real colcon, no engine needed)."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

COLCON = Path(sys.executable).parent / "colcon"


def run(*argv: str, cwd: Path) -> subprocess.CompletedProcess[str]:
    return subprocess.run(argv, cwd=cwd, capture_output=True, text=True, timeout=120, check=False)


def test_colcon_list_after_new_shows_the_firmware_package_and_no_idf_component(tmp_path):
    if not COLCON.exists():
        pytest.fail(f"{COLCON} is missing: colcon-common-extensions belongs in requirements/dev.txt")
    espdock = (sys.executable, "-m", "espdock")
    assert run(*espdock, "init", cwd=tmp_path).returncode == 0
    created = run(*espdock, "new", "my_board", cwd=tmp_path)
    assert created.returncode == 0, created.stderr
    assert (tmp_path / "src" / "components" / "espdock_uros" / "CMakeLists.txt").is_file()
    listed = run(str(COLCON), "list", cwd=tmp_path)
    assert listed.returncode == 0, listed.stderr
    names = [line.split("\t")[0] for line in listed.stdout.splitlines()]
    assert names == ["my_board"], listed.stdout
