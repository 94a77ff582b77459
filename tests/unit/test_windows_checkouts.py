"""A workspace as a team on Windows checks it out: Git for Windows' `core.autocrlf=true` makes
every text file's lines CRLF, and Windows editors start files with a UTF-8 byte order mark.
Neither changes what a file says, to colcon, CMake or IDF; neither may change what espdock
decides from it."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

from espdock.config import load_config
from espdock.firmware.plan import declared_target
from espdock.firmware.provision import read_password
from espdock.firmware.steps import _defaults_digest
from tests.conftest import REPO, copy_workspace, espdock
from tests.unit.test_provision import Stdin

BOM = b"\xef\xbb\xbf"
NO_ENGINE = {"DOCKER_HOST": "unix:///nonexistent/docker.sock"}


def crlf(path: Path, bom: bool = False) -> None:
    """PATH as an autocrlf checkout (and a Windows editor's save, with BOM) writes it."""
    path.write_bytes((BOM if bom else b"") + path.read_bytes().replace(b"\n", b"\r\n"))


def test_committed_locks_are_current_in_a_crlf_checkout(tmp_path):
    """A teammate's autocrlf clone, `git status` clean: `CI=true espdock build` refused the
    committed locks as stale ("docker/ros-runtime.in changed since it was locked"), and without
    --locked its images had other keys than a Linux clone's."""
    root = copy_workspace(tmp_path / "w")
    for path in (root / "docker").glob("ros-*"):
        crlf(path, bom=path.suffix == ".in")
    result = espdock("build", cwd=root, env={**NO_ENGINE, "CI": "true"})
    # Past the locks' check (exit 2), to the engine this machine lacks.
    assert result.returncode == 3, result.stdout + result.stderr
    assert "stale" not in result.stderr, result.stderr


def test_line_endings_alone_keep_the_sdkconfig_and_a_bom_keeps_the_chip(tmp_path):
    """WSL's git rewrote sdkconfig.defaults with LF after Windows' CRLF: the build made the
    sdkconfig afresh and menuconfig's changes went to sdkconfig.old. A BOM before
    CONFIG_IDF_TARGET (which IDF's CMake reads past) built for the workspace's chip instead."""
    defaults = tmp_path / "sdkconfig.defaults"
    defaults.write_bytes(b'CONFIG_IDF_TARGET="esp32c3"\nCONFIG_FREERTOS_HZ=1000\n')
    digest = _defaults_digest(tmp_path, "esp32c3")
    crlf(defaults, bom=True)
    assert _defaults_digest(tmp_path, "esp32c3") == digest
    assert declared_target({"sdkconfig.defaults": defaults.read_bytes()}) == "esp32c3"
    defaults.write_bytes(defaults.read_bytes().replace(b"1000", b"100"))
    assert _defaults_digest(tmp_path, "esp32c3") != digest


def test_files_a_windows_editor_saved_with_a_bom_are_read(tmp_path):
    """espdock.toml: "not valid TOML (at line 1, column 1)"; app-colcon.meta, which colcon
    reads as YAML: "Unexpected UTF-8 BOM"; a Wi-Fi password file: "must be printable ASCII"."""
    (tmp_path / "espdock.toml").write_bytes(BOM + b'# settings\r\n[espdock]\r\ntarget = "esp32s3"\r\n')
    assert load_config(tmp_path, {}).target == "esp32s3"
    root = copy_workspace(tmp_path / "w", packages=())
    shutil.copytree(REPO / "firmware", root / "firmware")
    crlf(root / "firmware/camera_node/app-colcon.meta", bom=True)
    planned = espdock("build", "--dry-run", cwd=root, env=NO_ENGINE)
    assert planned.returncode == 0, planned.stdout[-2000:] + planned.stderr
    assert "idf.py build camera_node" in planned.stdout
    secret = tmp_path / "wifi"
    secret.write_bytes(BOM + b"hunter2hunter2\r\n")
    assert read_password(str(secret), Stdin(), lambda: "x") == "hunter2hunter2"


def test_a_name_read_from_a_crlf_script_is_shown_with_its_carriage_return(tmp_path):
    """`espdock run $(cat pkg.txt) ...` from a CRLF file: "no ROS package 'talk'" beside
    "Did you mean 'talk'?", the name's \\r dropped by the terminal output."""
    root = copy_workspace(tmp_path / "w", packages=(), test_packages=("beacon_nodes",))
    result = subprocess.run(
        [sys.executable, "-m", "espdock", "run", "beacon_nodes\r", "beacon"],
        cwd=root,
        capture_output=True,
        text=True,
        env=NO_ENGINE,
        check=False,
    )
    assert result.returncode == 2, result.stdout + result.stderr
    assert "no ROS package 'beacon_nodes\\r'" in result.stderr, result.stderr
    assert "Did you mean 'beacon_nodes'?" in result.stderr, result.stderr
