"""The wheel's workspace defaults as setup.py copies them (espdock/defaults.py's SHIPPED)."""

from __future__ import annotations

import shutil
import subprocess
import sys

from espdock.defaults import SHIPPED
from tests.conftest import REPO


def test_a_file_deleted_since_the_last_build_in_the_checkout_is_not_shipped(tmp_path):
    """`pip wheel` twice in one checkout: setuptools' build/lib outlives the first, and a file of
    docker/idf/ deleted since shipped again, changed the IDF image's key on every machine that
    installed that wheel, and `espdock new` copied a deleted component file."""
    checkout = tmp_path / "checkout"
    for rel in ("setup.py", "pyproject.toml", "README.md", "espdock", *SHIPPED):
        copy = shutil.copytree if (REPO / rel).is_dir() else shutil.copy2
        (checkout / rel).parent.mkdir(parents=True, exist_ok=True)
        copy(REPO / rel, checkout / rel)
    retired = checkout / "docker/idf/retired-helper.sh"
    retired.write_text("#!/bin/sh\n")
    module = checkout / "espdock/ros/retired_module.py"
    module.write_text('"""Gone in the next commit."""\n')
    shipped = checkout / "build/lib/espdock/workspace_defaults/docker/idf"

    def build_py() -> None:
        built = subprocess.run([sys.executable, "setup.py", "-q", "build_py"], cwd=checkout, capture_output=True,
                               text=True, check=False)  # fmt: skip
        assert built.returncode == 0, built.stderr[-2000:]

    build_py()
    assert (shipped / retired.name).is_file() and (checkout / "build/lib/espdock/ros" / module.name).is_file()
    retired.unlink()
    module.unlink()
    build_py()
    assert not (shipped / retired.name).exists()
    assert not (checkout / "build/lib/espdock/ros" / module.name).exists()
    assert (shipped / "micro_ros_sources.txt").is_file()
