"""Plain `colcon build` (the real colcon from PyPI, colcon-common-extensions) with espdock's
colcon extension, building firmware packages through the IDF contract double."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from espdock.config import Config, resolve_ca_bundle
from espdock.layout import firmware_install_dir
from tests.conftest import REPO, copy_workspace, espdock
from tests.idf_contract_double.build import use_double

pytestmark = [pytest.mark.engine, pytest.mark.slow]
COLCON = Path(sys.executable).parent / "colcon"
ARTEFACTS = ("led_strip_node.bin", "led_strip_node.elf", "flasher_args.json", "bootloader/bootloader.bin")


@pytest.fixture(scope="module")
def colcon_ws(tmp_path_factory, engine) -> tuple[Path, dict[str, str]]:
    """This repository's layout with a Python ROS package and the two firmware apps; the double selected."""
    if not COLCON.exists():
        pytest.fail(f"{COLCON} is missing: colcon-common-extensions belongs in requirements/dev.txt")
    root = copy_workspace(tmp_path_factory.mktemp("colcon") / "ws-root", test_packages=("beacon_nodes",))
    shutil.copy2(REPO / "Dockerfile.idf", root / "Dockerfile.idf")
    shutil.copytree(REPO / "firmware", root / "firmware")
    env = {**os.environ, **use_double(engine, resolve_ca_bundle(Config(), os.environ), lambda line: None, root)}
    return root, env


def colcon(root: Path, env: dict[str, str], *args: str) -> subprocess.CompletedProcess[str]:
    """`colcon ARGS` in the colcon root (ws/), over both package paths, as a ROS developer types it."""
    argv = [str(COLCON), *args[:1], "--base-paths", "src", "../firmware", *args[1:]]
    if args[0] == "build":
        argv += ["--event-handlers", "console_direct+"]
    return subprocess.run(
        argv, cwd=root / "ws", env=env, capture_output=True, text=True, timeout=1800, check=False
    )  # fmt: skip


def test_colcon_list_sees_the_firmware_packages_and_not_the_shared_component(colcon_ws):
    root, env = colcon_ws
    listed = colcon(root, env, "list")
    assert listed.returncode == 0, listed.stderr
    types = dict(line.split("\t")[::2] for line in listed.stdout.splitlines())
    assert types["led_strip_node"] == "(ros.esp_idf)" and types["camera_node"] == "(ros.esp_idf)"
    assert types["custom_interface"] == "(ros.ament_cmake)"
    assert "espdock_uros" not in types


def test_packages_select_builds_the_firmware_and_installs_it_where_espdock_build_does(colcon_ws):
    root, env = colcon_ws
    built = colcon(root, env, "build", "--packages-select", "led_strip_node")
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]
    assert "Finished <<< led_strip_node" in built.stdout + built.stderr
    firmware = root / "ws" / firmware_install_dir("led_strip_node")
    assert {name for name in ARTEFACTS if (firmware / name).is_file()} == set(ARTEFACTS)
    assert not (root / "ws" / firmware_install_dir("camera_node")).exists()  # not selected
    # What `ros2 run led_strip_node flash|idf|monitor` finds, as after `espdock build`.
    lib = root / "ws" / "install" / "led_strip_node" / "lib" / "led_strip_node"
    assert sorted(p.name for p in lib.iterdir() if os.access(p, os.X_OK)) == ["flash", "idf", "monitor"]
    assert b"exec espdock flash led_strip_node " in (lib / "flash").read_bytes()
    # espdock build agrees: the same artefacts, byte for byte, where it installs them.
    before = {name: (firmware / name).read_bytes() for name in ARTEFACTS}
    again = espdock("build", "--only", "firmware", "--force", "led_strip_node", cwd=root, env=env)
    assert again.returncode == 0, again.stdout + again.stderr
    assert {name: (firmware / name).read_bytes() for name in ARTEFACTS} == before


def test_a_ros_package_and_a_firmware_package_build_in_one_colcon_build(colcon_ws):
    root, env = colcon_ws
    built = colcon(root, env, "build", "--packages-select", "beacon_nodes", "led_strip_node")
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]
    log = built.stdout + built.stderr
    assert "Finished <<< beacon_nodes" in log and "Finished <<< led_strip_node" in log
    assert (root / "ws" / "install" / "beacon_nodes" / "lib" / "beacon_nodes" / "beacon").is_file()
    assert (root / "ws" / firmware_install_dir("led_strip_node") / "flasher_args.json").is_file()


def test_without_an_engine_colcon_reports_the_package_failed_with_espdocks_message(colcon_ws):
    root, env = colcon_ws
    no_engine = {**env, "DOCKER_HOST": "unix:///nonexistent/docker.sock"}
    built = colcon(
        root, no_engine, "build", "--packages-select", "beacon_nodes", "led_strip_node", "--continue-on-error"
    )
    log = built.stdout + built.stderr
    assert built.returncode != 0
    assert "Failed   <<< led_strip_node" in log and "Finished <<< beacon_nodes" in log
    assert "no Docker engine answers" in log
