"""Plain `colcon build` (the real colcon from PyPI, colcon-common-extensions) with espdock's
colcon extension, building firmware packages through the IDF contract double."""

from __future__ import annotations

import importlib.util
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from espdock.config import Config, resolve_ca_bundle
from espdock.layout import firmware_install_dir
from tests.conftest import REPO, copy_workspace, espdock
from tests.idf_contract_double.build import use_double
from tests.integration.test_firmware import emulated_board

pytestmark = [pytest.mark.engine, pytest.mark.slow]
COLCON = Path(sys.executable).parent / "colcon"
ARTEFACTS = ("led_strip_node.bin", "led_strip_node.elf", "flasher_args.json", "bootloader/bootloader.bin")


def firmware_workspace(place: Path, engine) -> tuple[Path, dict[str, str]]:
    """This repository's layout with a Python ROS package and the two firmware apps; the double selected."""
    if not COLCON.exists():
        pytest.fail(f"{COLCON} is missing: colcon-common-extensions belongs in requirements/dev.txt")
    root = copy_workspace(place / "ws-root", test_packages=("beacon_nodes",))
    shutil.copy2(REPO / "Dockerfile.idf", root / "Dockerfile.idf")
    shutil.copytree(REPO / "firmware", root / "firmware")
    env = {**os.environ, **use_double(engine, resolve_ca_bundle(Config(), os.environ), lambda line: None, root)}
    return root, env


@pytest.fixture(scope="module")
def colcon_ws(tmp_path_factory, engine) -> tuple[Path, dict[str, str]]:
    return firmware_workspace(tmp_path_factory.mktemp("colcon"), engine)


def colcon(root: Path, env: dict[str, str], *args: str, executable: Path = COLCON) -> subprocess.CompletedProcess[str]:
    """`colcon ARGS` in the colcon root (ws/), over both package paths, as a ROS developer types it."""
    argv = [str(executable), *args[:1], "--base-paths", "src", "../firmware", *args[1:]]
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
    # A workspace espdock built before: its colcon wrote the install root's setup scripts (the container's paths).
    ros = espdock("build", "beacon_nodes", cwd=root, env=env)
    assert ros.returncode == 0, ros.stdout[-2000:] + ros.stderr
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
    # colcon rewrote the install root's setup scripts (the host's paths) after the espdock build in it wrote
    # its manifest: the next build, with nothing to build, records them (it kept the manifest, which verify
    # then failed on every script).
    cached = espdock("build", "--only", "firmware", "led_strip_node", cwd=root, env=env)
    assert cached.returncode == 0, cached.stdout + cached.stderr
    verified = espdock("verify", "ws/install/espdock-manifest.json", cwd=root, env=env)
    assert verified.returncode == 0, verified.stdout[-2000:] + verified.stderr
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


def clean_build_base(root: Path, env: dict[str, str], base: Path, package: str) -> None:
    """`colcon clean packages` where colcon-clean is installed; else what it does, `rm -rf`."""
    if (COLCON.parent / "colcon-clean").exists() or importlib.util.find_spec("colcon_clean") is not None:
        cleaned = subprocess.run(
            [str(COLCON), "clean", "packages", "--build-base", str(base), "--packages-select", package, "-y"],
            cwd=root / "ws", env=env, capture_output=True, text=True, check=False,
        )  # fmt: skip
        assert cleaned.returncode == 0, cleaned.stdout + cleaned.stderr
    else:
        shutil.rmtree(base)


def test_a_build_base_outside_the_workspace_holds_the_firmware_build_that_cleaning_it_removes(tmp_path, engine):
    root, env = firmware_workspace(tmp_path, engine)
    ws = root / "ws"
    base = tmp_path / "elsewhere" / "build"
    built = colcon(root, env, "build", "--packages-select", "camera_node", "--build-base", str(base))
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]
    tree = base / "camera_node"
    # The real build tree is where colcon says, not a link into the workspace.
    assert not tree.is_symlink() and (tree / "flasher_args.json").is_file() and (tree / "sdkconfig").is_file()
    # espdock's own build finds that tree (up to date: no second build in ws/build) and flashes it.
    again = espdock("build", "--only", "firmware", "camera_node", cwd=root, env=env)
    assert again.returncode == 0, again.stdout + again.stderr
    assert "up to date" in again.stdout, again.stdout
    assert (ws / "build" / "camera_node").resolve() == tree.resolve()
    with emulated_board("esp32") as port:
        flashed = espdock("flash", "camera_node", "--port", port, "--verify", cwd=root, env=env)
    assert flashed.returncode == 0, flashed.stdout[-3000:] + flashed.stderr

    clean_build_base(root, env, base, "camera_node")
    assert not tree.exists()
    rebuilt = espdock("build", "--only", "firmware", "camera_node", cwd=root, env=env)
    assert rebuilt.returncode == 0, rebuilt.stdout + rebuilt.stderr
    assert "up to date" not in rebuilt.stdout
    assert (ws / "build" / "camera_node" / "flasher_args.json").is_file()
    assert not (ws / "build" / "camera_node").is_symlink()

    # Back to that build base: the tree moves there again with its sdkconfig (menuconfig's changes).
    sdkconfig = ws / "build" / "camera_node" / "sdkconfig"
    sdkconfig.write_text(sdkconfig.read_text().replace('NODE_NAME="esp32_camera_node"', 'NODE_NAME="x31b_cam"'))
    built = colcon(root, env, "build", "--packages-select", "camera_node", "--build-base", str(base))
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]
    assert (tree / "flasher_args.json").is_file() and not tree.is_symlink()
    assert 'CONFIG_ESPDOCK_NODE_NAME="x31b_cam"' in (tree / "sdkconfig").read_text()
    assert (ws / "build" / "camera_node").resolve() == tree.resolve()


@pytest.mark.parametrize("which", ["venv-colcon", "debian-colcon"])
def test_merge_install_into_the_default_install_base_leaves_one_copy_which_espdock_flashes(
    which, tmp_path, engine, request
):
    """colcon-core 0.21 records the install layout before any package builds; Debian's 0.12 does not."""
    root, env = firmware_workspace(tmp_path, engine)
    ws = root / "ws"
    executable = COLCON
    if which == "debian-colcon":
        executable, pipx_espdock = debian_colcon(), request.getfixturevalue("wheel_espdock")
        env = pipx_user(env, pipx_espdock, executable, tmp_path)
        registered = subprocess.run([str(pipx_espdock), "colcon-extension", "install"], env=env,
                                    capture_output=True, text=True, check=False)  # fmt: skip
        assert registered.returncode == 0, registered.stdout + registered.stderr
    built = colcon(root, env, "build", "--packages-select", "camera_node", "--merge-install", executable=executable)
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]
    merged = ws / "install" / "share" / "camera_node" / "firmware"
    assert (merged / "flasher_args.json").is_file()
    # Only the merged layout colcon was asked for: no isolated install/camera_node beside it.
    assert not (ws / "install" / "camera_node").exists()
    # espdock's own build afterwards keeps to that layout (colcon refuses to mix them).
    again = espdock("build", "--only", "firmware", "--force", "camera_node", cwd=root, env=env)
    assert again.returncode == 0, again.stdout + again.stderr
    assert not (ws / "install" / "camera_node").exists()
    # `ros2 run camera_node flash` in that layout: espdock flash writes the merged install's firmware.
    with emulated_board("esp32") as port:
        flashed = espdock("flash", "camera_node", "--port", port, "--verify", cwd=root, env=env)
    assert flashed.returncode == 0, flashed.stdout[-3000:] + flashed.stderr
    assert f"flashed camera_node through {port} and verified it" in flashed.stdout


def without_pythonpath(env) -> dict[str, str]:
    """ENV for a process of another Python: the separate colcon sees its own packages only."""
    return {name: value for name, value in env.items() if name != "PYTHONPATH"}


def pipx_user(env: dict[str, str], pipx_espdock: Path, colcon: Path, home: Path) -> dict[str, str]:
    """ENV as a user of COLCON and a pipx espdock has it: espdock on PATH, as pipx puts it, then
    colcon; the user site a system colcon reads (~/.local) one of HOME's own."""
    path = f"{pipx_espdock.parent}:{colcon.parent}:{env['PATH']}"
    return {**without_pythonpath(env), "PATH": path, "PYTHONUSERBASE": str(home / "user-base")}


def venv_colcon() -> Path:
    """colcon in a venv of its own, without espdock: a colcon venv beside a pipx espdock."""
    from importlib.metadata import version

    pins = [f"{name}=={version(name)}" for name in ("colcon-common-extensions", "colcon-core", "colcon-ros")]

    def make(place: Path) -> None:
        subprocess.run([sys.executable, "-m", "venv", str(place / "venv")], check=True)
        subprocess.run([str(place / "venv/bin/pip"), "install", "-q", *pins], check=True, capture_output=True)

    from tests.conftest import kept_in_temp

    return kept_in_temp("espdock-colcon-venv", "-".join(pins).replace("==", "_"), make) / "venv" / "bin" / "colcon"


def debian_colcon() -> Path:
    """Debian's colcon (apt's python3-colcon-* in /usr/lib/python3/dist-packages, run by the system
    Python): the README's apt colcon beside a pipx espdock, as a user has it."""
    colcon = Path("/usr/bin/colcon")
    if not colcon.exists():
        pytest.skip("Debian's colcon is not installed (tests/install-system-deps.sh installs it)")
    return colcon


@pytest.fixture(scope="module", params=[venv_colcon, debian_colcon], ids=["venv-colcon", "debian-colcon"])
def separate_colcon(request) -> Path:
    """A colcon in a Python without espdock."""
    colcon = request.param()
    probe = [str(colcon.parent / "python3"), "-c", "import espdock"]
    if colcon.parent == Path("/usr/bin"):
        probe[0] = "/usr/bin/python3"
    # Not from the checkout: a Python started there imports its espdock/ from the current directory.
    clean = without_pythonpath(os.environ)
    found = subprocess.run(probe, cwd="/", env=clean, capture_output=True, check=False)
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
    # The extension must run espdock's own Python, not colcon's.
    user = pipx_user(env, wheel_espdock, separate_colcon, tmp_path)
    skipped = subprocess.run(argv, cwd=ws, env=user, capture_output=True, text=True, check=False)
    assert "No task extension to 'build' a 'ros.esp_idf' package" in skipped.stderr + skipped.stdout
    assert skipped.returncode == 0 and not firmware.exists()  # colcon's own way: a warning, success
    # What espdock says about it: `colcon-extension check` fails, `init` notes it.
    check = [str(wheel_espdock), "colcon-extension", "check"]
    checked = subprocess.run(check, env=user, capture_output=True, text=True, check=False)
    assert checked.returncode == 2, checked.stdout + checked.stderr
    assert f"`colcon build` with {separate_colcon} skips firmware packages" in " ".join(checked.stderr.split())
    init = subprocess.run(
        [str(wheel_espdock), "init", str(root)], env=user, capture_output=True, text=True, check=False
    )
    assert "`espdock colcon-extension install` registers it" in " ".join(init.stdout.split()), init.stdout + init.stderr

    installed = subprocess.run(
        [str(wheel_espdock), "colcon-extension", "install"],
        env=user, capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert installed.returncode == 0, installed.stdout + installed.stderr
    try:
        built = subprocess.run(argv, cwd=ws, env=user, capture_output=True, text=True, timeout=1800, check=False)
        assert built.returncode == 0, built.stdout[-3000:] + built.stderr[-3000:]
        assert "No task extension" not in built.stdout + built.stderr
        assert (firmware / "flasher_args.json").is_file()
        again = subprocess.run(
            [str(wheel_espdock), "colcon-extension", "install"],
            env=user, capture_output=True, text=True, check=False,
        )  # fmt: skip
        assert again.returncode == 0 and "now loads" in again.stdout
        checked = subprocess.run(check, env=user, capture_output=True, text=True, check=False)
        assert checked.returncode == 0, checked.stdout + checked.stderr
        init = subprocess.run(
            [str(wheel_espdock), "init", str(root)], env=user, capture_output=True, text=True, check=False
        )
        assert "colcon-extension" not in init.stdout
    finally:
        removed = subprocess.run(
            [str(wheel_espdock), "colcon-extension", "uninstall"],
            env=user, capture_output=True, text=True, check=False,
        )  # fmt: skip
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
    # The tag naming a directory that is not there: the package fails with the tag's words (it was
    # colcon's traceback of a missing cwd).
    misspelt = tmp_path / "misspelt"
    shutil.copytree(REPO / "tests/firmware_packages/blink_fw", misspelt / "src/blink_fw")
    manifest = misspelt / "src/blink_fw/package.xml"
    manifest.write_text(re.sub(r">([^<]*)</espdock_host_tests>", r">\1s</espdock_host_tests>", manifest.read_text()))
    refused = subprocess.run(
        [str(COLCON), "test", "--event-handlers", "console_direct+"],
        cwd=misspelt, capture_output=True, text=True, timeout=600, check=False,
    )  # fmt: skip
    said = refused.stdout + refused.stderr
    assert "blink_fw's package.xml declares its host tests in" in said and "Traceback" not in said, said[-3000:]
    assert "Failed   <<< blink_fw" in said, said[-3000:]
