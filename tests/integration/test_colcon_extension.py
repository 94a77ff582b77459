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


def test_merge_install_and_other_bases_put_the_firmware_where_the_ament_index_sees_it(colcon_ws):
    root, env = colcon_ws
    ws = root / "ws"
    built = colcon(
        root, env, "build", "--packages-select", "led_strip_node", "--merge-install",
        "--install-base", "install-merged", "--build-base", "build-other",
    )  # fmt: skip
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]
    merged = ws / "install-merged"
    assert (merged / "share" / "ament_index" / "resource_index" / "packages" / "led_strip_node").is_file()
    firmware = merged / "share" / "led_strip_node" / "firmware"
    assert {name for name in ARTEFACTS if (firmware / name).is_file()} == set(ARTEFACTS)
    # What colcon's merged setup files and ament_index_python see: the package, its share dir.
    probe = subprocess.run(
        ["bash", "-c", ". install-merged/local_setup.bash && python3 -c "
         "'import ament_index_python as a; print(a.get_package_share_directory(\"led_strip_node\"))'"],
        cwd=ws, capture_output=True, text=True, check=False,
    )  # fmt: skip
    if "No module named 'ament_index_python'" not in probe.stderr:
        assert probe.stdout.strip() == str(merged / "share" / "led_strip_node"), probe.stderr
    assert ":" + str(merged) in ":" + subprocess.run(
        ["bash", "-c", ". install-merged/local_setup.bash && echo $AMENT_PREFIX_PATH"],
        cwd=ws, capture_output=True, text=True, check=True,
    ).stdout.strip()  # fmt: skip
    assert (ws / "build-other" / "led_strip_node" / "flasher_args.json").is_file()
    # `ros2 run led_strip_node monitor` in the merged layout reaches espdock for this workspace (which,
    # without a terminal, refuses with its own message; a wrong workspace would be "not inside").
    path = f"{Path(sys.executable).parent}{os.pathsep}{env['PATH']}"
    monitor = subprocess.run(
        [str(merged / "lib" / "led_strip_node" / "monitor"), "--port", "socket://127.0.0.1:1"],
        cwd="/", env={**env, "PATH": path}, stdin=subprocess.DEVNULL, capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert monitor.returncode == 2 and "the monitor needs a terminal" in monitor.stderr, monitor.stderr


def without_pythonpath(env) -> dict[str, str]:
    """ENV for a process of another Python: the separate colcon sees its own packages only."""
    return {name: value for name, value in env.items() if name != "PYTHONPATH"}


@pytest.fixture(scope="module")
def separate_colcon() -> Path:
    """colcon in a venv of its own, without espdock: apt's colcon beside a pipx espdock, in small."""
    from importlib.metadata import version

    pins = [f"{name}=={version(name)}" for name in ("colcon-common-extensions", "colcon-core", "colcon-ros")]

    def make(place: Path) -> None:
        subprocess.run([sys.executable, "-m", "venv", str(place / "venv")], check=True)
        subprocess.run([str(place / "venv/bin/pip"), "install", "-q", *pins], check=True, capture_output=True)

    from tests.conftest import kept_in_temp

    colcon = kept_in_temp("espdock-colcon-venv", "-".join(pins).replace("==", "_"), make) / "venv" / "bin" / "colcon"
    probe = [str(colcon.parent / "python"), "-c", "import espdock"]
    # Not from the checkout: a Python started there imports its espdock/ from the current directory.
    clean = without_pythonpath(os.environ)
    found = subprocess.run(probe, cwd=colcon.parent, env=clean, capture_output=True, check=False)
    assert found.returncode != 0, "the separate colcon must not see espdock"
    return colcon


def test_a_colcon_in_another_python_builds_firmware_once_the_extension_is_installed_there(
    colcon_ws, separate_colcon, wheel_espdock, tmp_path
):
    root, env = colcon_ws
    ws = root / "ws"
    firmware = ws / firmware_install_dir("camera_node")
    shutil.rmtree(ws / "install" / "camera_node", ignore_errors=True)
    argv = [str(separate_colcon), "build", "--base-paths", "src", "../firmware", "--packages-select", "camera_node"]
    # espdock on PATH as pipx puts it; the extension must run espdock's own Python, not colcon's.
    path = f"{wheel_espdock.parent}:{separate_colcon.parent}:{env['PATH']}"
    user = {**without_pythonpath(env), "PATH": path}
    skipped = subprocess.run(argv, cwd=ws, env=user, capture_output=True, text=True, check=False)
    assert "No task extension to 'build' a 'ros.esp_idf' package" in skipped.stderr + skipped.stdout
    assert not firmware.exists()

    installed = subprocess.run(
        [str(wheel_espdock), "colcon-extension", "install"], env=user, capture_output=True, text=True, check=False
    )
    assert installed.returncode == 0, installed.stdout + installed.stderr
    try:
        built = subprocess.run(argv, cwd=ws, env=user, capture_output=True, text=True, timeout=1800, check=False)
        assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]
        assert "No task extension" not in built.stdout + built.stderr
        assert (firmware / "flasher_args.json").is_file()
        again = subprocess.run(
            [str(wheel_espdock), "colcon-extension", "install"], env=user, capture_output=True, text=True, check=False
        )
        assert again.returncode == 0 and "now loads" in again.stdout
    finally:
        removed = subprocess.run(
            [str(wheel_espdock), "colcon-extension", "uninstall"], env=user, capture_output=True, text=True, check=False
        )
    assert removed.returncode == 0 and "removed" in removed.stdout
    after = subprocess.run(argv, cwd=ws, env=user, capture_output=True, text=True, check=False)
    assert "No task extension to 'build' a 'ros.esp_idf' package" in after.stderr + after.stdout


def test_colcon_test_runs_declared_host_tests_and_passes_over_firmware_without_any(tmp_path):
    """Plain `colcon test` on firmware packages, as a ROS developer runs it over a mixed workspace:
    no warning, no failure; the host tests a package declares run and count in test-result."""
    for package in (REPO / "tests/firmware_packages/blink_fw", REPO / "firmware/led_strip_node"):
        shutil.copytree(package, tmp_path / "src" / package.name)
    tested = subprocess.run(
        [str(COLCON), "test", "--event-handlers", "console_direct+"],
        cwd=tmp_path, capture_output=True, text=True, timeout=600, check=False,
    )  # fmt: skip
    log = tested.stdout + tested.stderr
    assert tested.returncode == 0, log[-3000:]
    assert "WARNING" not in log, log[-3000:]
    assert "led_strip_node: firmware package without host tests (espdock_host_tests): nothing to run" in log
    result = subprocess.run(
        [str(COLCON), "test-result", "--all"], cwd=tmp_path, capture_output=True, text=True, timeout=120, check=False
    )
    assert "build/blink_fw/test_results/blink_fw/host_tests.xml: 2 tests, 0 errors, 0 failures" in result.stdout
