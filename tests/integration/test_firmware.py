"""The ESP-IDF side end to end: micro-ROS image cache, firmware builds and installs, flashing.

The Espressif image and the micro-ROS sources can't be fetched on these machines, so
the IDF image here is the IDF contract double (tests/idf_contract_double/), which
honours only what espdock relies on. Flashing is real esptool against
esp32-mock-bootloader. Tests against the real espressif/idf image are at the end and
skip where it is not present.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import pty
import re
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest
from esptool.cmds import detect_chip

from espdock.config import Config, resolve_ca_bundle
from espdock.firmware.flashing import chip_probe_argv, detected_chip, esptool_major, parse_port
from espdock.images.prune import read_records, state_dir
from espdock.layout import firmware_install_dir
from tests.conftest import (
    REPO,
    Started,
    build_holding,
    containers_created,
    copy_workspace,
    espdock,
    leftover_containers,
    remove_images_built_from,
    ros_build_tag,
)
from tests.idf_contract_double.build import use_double
from tests.nvs_reader import read_nvs
from tests.ports import free_port

pytestmark = [pytest.mark.engine, pytest.mark.slow]

USER_UID = 4243
REAL_IDF_IMAGE = "espressif/idf:v5.3.5"


STRUCT_HEADER = (
    "/opt/espdock/micro_ros_espidf_component/include/custom_interface/custom_interface/msg/detail/"
    "camera_config__struct.h"
)


@pytest.fixture(scope="module")
def fw_ws_and_env(tmp_path_factory, engine, double):
    """A workspace with custom_interface and the repo's two firmware apps, owned by a normal user, built once,
    and the settings that select the double."""
    root = copy_workspace(tmp_path_factory.mktemp("fw") / "ws-root")
    shutil.copy2(REPO / "Dockerfile.idf", root / "Dockerfile.idf")
    shutil.copytree(REPO / "firmware", root / "firmware")
    double_env = use_double(engine, resolve_ca_bundle(Config(), os.environ), lambda line: None, root)
    # Comments unique to this run: its micro-ROS images can't be left over from an earlier one,
    # nor be another pytest worker's (led_strip_node's library does not use the message).
    run = uuid.uuid4().hex
    for source in (root / "ws/src/custom_interface/msg/CameraConfig.msg", root / "Dockerfile.idf"):
        source.write_text(source.read_text() + f"# test run {run}\n")
    subprocess.run(["chown", "-R", f"{USER_UID}:{USER_UID}", str(root)], check=True)
    first = espdock("build", cwd=root, env=double_env)
    yield root, first, double_env
    engine.remove_containers({"io.espdock.workspace": str(root)})
    remove_images_built_from(root / "Dockerfile.idf")


@pytest.fixture(scope="module")
def fw_ws(fw_ws_and_env):
    root, first, _ = fw_ws_and_env
    return root, first


@pytest.fixture(scope="module")
def double_env(fw_ws_and_env) -> dict[str, str]:
    return fw_ws_and_env[2]


def header(image: str) -> str:
    result = subprocess.run(
        ["docker", "run", "--rm", image, "cat", STRUCT_HEADER], capture_output=True, text=True, check=False
    )
    assert result.returncode == 0, result.stderr
    return result.stdout


def firmware_dir(root: Path, package: str) -> Path:
    return root / "ws" / firmware_install_dir(package)


def status(root: Path, env: dict[str, str], package: str = "camera_node") -> dict:
    """The `micro-ros status --json` entry of the image PACKAGE builds against."""
    result = espdock("micro-ros", "status", "--json", cwd=root, env=env)
    assert result.returncode == 0, result.stderr
    report = json.loads(result.stdout)
    (image,) = [image for image in report["images"] if package in image["firmware_packages"]]
    assert report["firmware"][package] == image["image"]
    return image


def test_first_build_makes_the_micro_ros_image_and_installs_both_apps(fw_ws, double_env):
    root, first = fw_ws
    assert first.returncode == 0, first.stdout[-3000:] + first.stderr
    assert "cache miss" in first.stdout
    manifest = json.loads((root / "ws/install/espdock-manifest.json").read_text())
    # One build, each package for its own chip: camera_node the workspace's esp32, led_strip_node
    # the esp32c3 its sdkconfig.defaults names, each against a micro-ROS image for that chip.
    for package, chip in (("camera_node", "esp32"), ("led_strip_node", "esp32c3")):
        assert manifest["firmware"][package]["target"] == chip
        assert manifest["firmware"][package]["image"].startswith(f"espdock/idf-micro-ros-jazzy-{chip}:")
        assert status(root, double_env, package)["target"] == chip
        installed = firmware_dir(root, package)
        flasher_args = json.loads((installed / "flasher_args.json").read_text())
        assert flasher_args["extra_esptool_args"]["chip"] == chip
        for rel in flasher_args["flash_files"].values():
            # ESP app/bootloader images start with 0xE9; a partition table with its entry magic 0xAA50.
            magic = b"\xaa\x50" if "partition" in rel else b"\xe9"
            assert (installed / rel).read_bytes().startswith(magic), f"{package}: {rel} has the wrong header"
        assert (root / "ws/build" / package / "flasher_args.json").is_file()
        # The manifest holds the artefacts (in the versioned directory the firmware link names).
        files = json.loads((root / "ws/install/espdock-manifest.json").read_text())["files"]
        link = firmware_install_dir(package).removeprefix("install/")
        assert files[link] == "symlink:" + os.readlink(installed)
        assert f"{link.rsplit('/', 1)[0]}/{os.readlink(installed)}/flasher_args.json" in files


def test_status_json_into_a_pipe_its_reader_closed_ends_quietly_with_141(fw_ws, double_env):
    """`espdock micro-ros status --json | head -0`: the JSON meets a pipe nobody reads, which
    ends the command as SIGPIPE ends one, not as a bug of espdock's."""
    root, _ = fw_ws
    read, write = os.pipe()
    os.close(read)
    try:
        result = subprocess.run(
            [sys.executable, "-m", "espdock", "micro-ros", "status", "--json"], cwd=root,
            env={**os.environ, **double_env}, stdout=write, stderr=subprocess.PIPE, text=True, timeout=120, check=False,
        )  # fmt: skip
    finally:
        os.close(write)
    assert result.returncode == 141, result.stderr
    assert "bug" not in result.stderr


def test_everything_written_belongs_to_the_workspace_owner(fw_ws):
    root, first = fw_ws
    assert first.returncode == 0
    strangers = [
        str(path) for space in ("build", "install", "log")
        for path in (root / "ws" / space).rglob("*") if path.lstat().st_uid != USER_UID
    ]  # fmt: skip
    assert strangers == []


def test_a_built_micro_ros_image_records_its_debian_packages(fw_ws, double_env):
    root, first = fw_ws
    assert first.returncode == 0
    tag = status(root, double_env)["image"]
    inspect = ["docker", "image", "inspect", "-f", "{{json .Config.Labels}}", tag]
    labels = json.loads(subprocess.run(inspect, capture_output=True, text=True, check=True).stdout)
    packages = labels["io.espdock.debian-packages"].split()
    assert any(p.startswith("git=") for p in packages) and all("=" in p for p in packages)
    assert labels["io.espdock.debian-packages.sha256"] == hashlib.sha256(" ".join(packages).encode()).hexdigest()


def test_the_library_is_not_copied_into_any_project(fw_ws):
    root, first = fw_ws
    assert first.returncode == 0
    assert not list(root.rglob("libmicroros.a")), "the seed's complaint: a micro-ROS copy per project"


def test_the_custom_interface_went_into_the_library(fw_ws, double_env):
    root, first = fw_ws
    assert first.returncode == 0
    report = status(root, double_env)
    assert report["present"]
    assert report["interface_packages"] == ["custom_interface"]
    assert status(root, double_env, "led_strip_node")["interface_packages"] == []
    struct = header(report["image"])
    assert "framesize" in struct and "colorbar" in struct


MANIFEST_HEADER = "/opt/espdock/micro_ros_espidf_component/include/espdock_double/manifest.h"
RMW_CONFIG = "/opt/espdock/micro_ros_espidf_component/include/rmw_microxrcedds_c/rmw_microxrcedds_c/config.h"


def image_file(image: str, path: str) -> str:
    result = subprocess.run(["docker", "run", "--rm", image, "cat", path], capture_output=True, text=True, check=False)
    assert result.returncode == 0, result.stderr
    return result.stdout


def define(text: str, name: str) -> str:
    (value,) = re.findall(rf"^#define {name} (.*)$", text, re.MULTILINE)
    return value


def test_each_app_gets_a_library_built_for_its_own_meta_and_sdkconfig(fw_ws, double_env):
    root, first = fw_ws
    assert first.returncode == 0
    camera, led = status(root, double_env, "camera_node"), status(root, double_env, "led_strip_node")
    assert camera["key"] != led["key"] and camera["present"] and led["present"]
    # The LED strip does not carry the camera's output stream in its RAM.
    assert define(image_file(camera["image"], RMW_CONFIG), "RMW_UXRCE_STREAM_HISTORY_OUTPUT") == "16"
    assert define(image_file(led["image"], RMW_CONFIG), "RMW_UXRCE_STREAM_HISTORY_OUTPUT") == "2"
    # The firmware's sdkconfig.defaults reached the library build (CONFIG_FREERTOS_HZ, PSRAM).
    camera_config, led_config = (
        json.loads(json.loads(define(image_file(image["image"], MANIFEST_HEADER), "ESPDOCK_DOUBLE_SDKCONFIG")))
        for image in (camera, led)
    )
    assert camera_config["CONFIG_FREERTOS_HZ"] == "1000" and camera_config["CONFIG_SPIRAM"] == "1"
    assert led_config["CONFIG_FREERTOS_HZ"] == "100" and "CONFIG_SPIRAM" not in led_config
    assert camera_config["CONFIG_MICRO_ROS_ESP_NETIF_WLAN"] == "1"


def test_only_the_selected_network_interface_is_compiled(fw_ws, double_env):
    root, first = fw_ws
    assert first.returncode == 0
    wlan = (root / "ws/build/led_strip_node/esp-idf").rglob("*.obj")
    assert not [p for p in wlan if "ethernet" in p.name]
    eth = root / "firmware/eth_node"
    shutil.copytree(root / "firmware/led_strip_node", eth)
    try:
        (eth / "package.xml").write_text((eth / "package.xml").read_text().replace("led_strip_node", "eth_node"))
        cmake = eth / "CMakeLists.txt"
        cmake.write_text(cmake.read_text().replace("project(led_strip_node)", "project(eth_node)"))
        defaults = eth / "sdkconfig.defaults"
        defaults.write_text(
            defaults.read_text().replace("CONFIG_MICRO_ROS_ESP_NETIF_WLAN=y", "CONFIG_MICRO_ROS_ESP_NETIF_ENET=y")
        )
        result = espdock("build", "eth_node", "--only", "firmware", cwd=root, env=double_env)
        assert result.returncode == 0, result.stdout[-3000:] + result.stderr
        assert "uros_ethernet_netif.c.obj" in result.stdout and "uros_wlan_netif.c.obj" not in result.stdout
        assert status(root, double_env, "eth_node")["key"] != status(root, double_env, "led_strip_node")["key"]
    finally:
        for leftover in (eth, root / "ws/build/eth_node", root / "ws/install/eth_node"):
            shutil.rmtree(leftover, ignore_errors=True)


COMPONENT_INCLUDE = "/opt/espdock/micro_ros_espidf_component/include"


def image_has(image: str, path: str) -> bool:
    return subprocess.run(["docker", "run", "--rm", image, "test", "-e", path], check=False).returncode == 0


def test_the_library_comes_from_the_pinned_commits_not_the_branch_heads(fw_ws, double_env, double):
    """The double's upstream repositories moved on after their pins (a MovedOn message on jazzy's head)."""
    root, first = fw_ws
    assert first.returncode == 0
    sources = root / "docker/idf/micro_ros_sources.txt"
    pinned = sources.read_text()
    url = "file:///opt/espdock-double/repos/common_interfaces.git"
    (pin,) = re.findall(rf"^{re.escape(url)} jazzy (\w+)$", pinned, re.MULTILINE)
    report = status(root, double_env, "led_strip_node")
    assert report["built_from"][url] == pin
    assert image_has(report["image"], f"{COMPONENT_INCLUDE}/std_msgs/std_msgs/msg/string.h")
    assert not image_has(report["image"], f"{COMPONENT_INCLUDE}/std_msgs/std_msgs/msg/moved_on.h")
    head = subprocess.run(
        ["docker", "run", "--rm", double[0], "git", f"--git-dir={url.removeprefix('file://')}", "rev-parse", "jazzy"],
        capture_output=True, text=True, check=True,
    ).stdout.split()[-1]  # fmt: skip
    assert head != pin
    try:
        # Not listed: the build fails and names the repository, instead of taking today's head.
        sources.write_text("\n".join(line for line in pinned.splitlines() if url not in line) + "\n")
        unpinned = espdock("build", "led_strip_node", "--only", "firmware", "-v", cwd=root, env=double_env)
        assert unpinned.returncode == 4, unpinned.stdout[-3000:] + unpinned.stderr
        assert f"{url} is cloned by the micro-ROS build but not pinned" in unpinned.stdout
        # "-": the head of the day, said out loud; `micro-ros pin` then pins what was built.
        sources.write_text(pinned.replace(f"{url} jazzy {pin}", f"{url} jazzy -"))
        moved = espdock("build", "led_strip_node", "--only", "firmware", cwd=root, env=double_env)
        assert moved.returncode == 0, moved.stdout[-3000:] + moved.stderr
        following = json.loads(espdock("micro-ros", "status", "--json", cwd=root, env=double_env).stdout)
        assert following["following_branch_head"] == [url]
        # (The build's own warning is BuildKit output, hidden when the step is cached from an
        # earlier run; the image's record of what it checked out is not.)
        moved_image = status(root, double_env, "led_strip_node")
        assert moved_image["built_from"][url] == head
        assert image_has(moved_image["image"], f"{COMPONENT_INCLUDE}/std_msgs/std_msgs/msg/moved_on.h")
        pinning = espdock("micro-ros", "pin", cwd=root, env=double_env)
        assert pinning.returncode == 0, pinning.stderr
        assert f"pinned {url} (jazzy) at {head}" in pinning.stdout
        # The double was built here, so there is no registry digest to pin it to.
        assert "is pinned by tag only: this engine did not pull it from a registry" in pinning.stdout
        assert sources.read_text() == pinned.replace(f"{url} jazzy {pin}", f"{url} jazzy {head}")
        assert sources.stat().st_uid == USER_UID
    finally:
        sources.write_text(pinned)


def test_managed_components_stay_out_of_the_source_tree_and_downloads_are_cached(fw_ws, double_env):
    root, first = fw_ws
    assert first.returncode == 0
    project = root / "firmware/led_strip_node"
    assert not (project / "managed_components").exists()
    assert (root / "ws/build/led_strip_node/managed_components/espressif__led_strip").is_dir()
    assert (root / "ws/build/.idf-component-cache/espressif__led_strip").is_dir()
    source = project / "main/led_strip_node_main.c"
    source.write_text(source.read_text() + "\n/* rebuild */\n")
    again = espdock("build", "led_strip_node", "--only", "firmware", cwd=root, env=double_env)
    assert again.returncode == 0, again.stdout[-2000:] + again.stderr
    assert "Using espressif/led_strip from the component cache" in again.stdout
    assert "Downloading" not in again.stdout
    assert not (project / "managed_components").exists()


def test_ros_tools_find_the_firmware_through_the_ament_index(fw_ws):
    root, first = fw_ws
    assert first.returncode == 0
    probe = subprocess.run(
        ["docker", "run", "--rm", "-v", f"{root / 'ws'}:/workspace/ws:ro",
         "-e", "ESPDOCK_WS_INSTALL=/workspace/ws/install", ros_build_tag(root), "python3", "-c",
         ("from ament_index_python.packages import get_package_share_directory as d; import os; "
          "p = d('camera_node'); print(p, os.path.isfile(os.path.join(p, 'firmware', 'flasher_args.json')))")],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert probe.returncode == 0, probe.stderr
    assert probe.stdout.split() == ["/workspace/ws/install/camera_node/share/camera_node", "True"]


def test_a_build_with_nothing_changed_starts_no_container(fw_ws, double_env):
    root, first = fw_ws
    assert first.returncode == 0
    espdock("build", cwd=root, env=double_env)  # whatever earlier tests left: settle
    with containers_created(root) as created:
        noop = espdock("build", cwd=root, env=double_env)
    assert noop.returncode == 0, noop.stdout[-2000:] + noop.stderr
    assert created == []
    for step in ("colcon build", "idf.py build camera_node", "install led_strip_node"):
        assert any(step in line and "up to date" in line for line in noop.stdout.splitlines()), noop.stdout
    # --dry-run says what the build would find: here every step up to date, its images present.
    steps = dry_run_states(root, double_env)
    assert steps and all(state.startswith(("up to date", "present")) for state in steps.values()), steps
    # menuconfig's changes live in the build dir's sdkconfig: they must build.
    sdkconfig = root / "ws/build/led_strip_node/sdkconfig"
    sdkconfig.write_text(sdkconfig.read_text() + "# changed by menuconfig\n")
    with containers_created(root) as created:
        steps = dry_run_states(root, double_env)
    assert created == []
    assert steps["idf.py build led_strip_node"] == "would build (esp32c3)", steps
    assert steps["install led_strip_node"].startswith("would install"), steps
    assert steps["idf.py build camera_node"] == "up to date (esp32)", steps
    changed = espdock("build", "led_strip_node", "--only", "firmware", cwd=root, env=double_env)
    assert changed.returncode == 0 and "Building C object" in changed.stdout
    assert dry_run_states(root, double_env)["idf.py build led_strip_node"] == "up to date (esp32c3)"


def dry_run_states(root: Path, env: dict[str, str]) -> dict[str, str]:
    """Each step of `espdock build --dry-run` by name, with the state its `now:` line names."""
    planned = espdock("build", "--dry-run", cwd=root, env={**env, "COLUMNS": "400"})
    assert planned.returncode == 0, planned.stdout[-2000:] + planned.stderr
    blocks = re.findall(r"^\d+\. (.+)$((?:\n   .*)*)", planned.stdout, flags=re.M)
    return {name: re.search(r"^   now: (.+)$", block, flags=re.M).group(1) for name, block in blocks}


def test_a_library_option_changed_after_a_first_configure_through_idf_is_still_warned_about(fw_ws, double_env):
    """The build dir configured by `espdock idf PKG -- reconfigure` (or menuconfig) before any build:
    the build took the edited sdkconfig for what the library was built with, and said nothing."""
    root, first = fw_ws
    assert first.returncode == 0
    build_dir = root / "ws/build/led_strip_node"
    shutil.rmtree(build_dir)
    configured = espdock("idf", "led_strip_node", "--", "reconfigure", cwd=root, env=double_env)
    assert configured.returncode == 0, configured.stdout[-2000:] + configured.stderr
    sdkconfig = build_dir / "sdkconfig"
    fresh = sdkconfig.read_text()
    assert "CONFIG_FREERTOS_HZ=100\n" in fresh
    sdkconfig.write_text(fresh.replace("CONFIG_FREERTOS_HZ=100\n", "CONFIG_FREERTOS_HZ=1000\n"))
    try:
        built = espdock("build", "led_strip_node", "--only", "firmware", cwd=root, env=double_env)
        assert built.returncode == 0, built.stdout[-2000:] + built.stderr
        assert "CONFIG_FREERTOS_HZ=1000 (was 100)" in built.stdout and "not libmicroros.a" in built.stdout
        # Up to date, the firmware installed: the library still lacks it, and the build says so again.
        again = espdock("build", "led_strip_node", "--only", "firmware", cwd=root, env=double_env)
        assert again.returncode == 0 and "up to date" in again.stdout, again.stdout[-2000:] + again.stderr
        assert "CONFIG_FREERTOS_HZ=1000 (was 100)" in again.stdout and "not libmicroros.a" in again.stdout
    finally:
        sdkconfig.write_text(fresh)  # the next build of it, a later test's, builds it so


def test_a_firmware_source_change_rebuilds_the_app_but_reuses_the_library(fw_ws, double_env):
    root, first = fw_ws
    assert first.returncode == 0
    key_before = status(root, double_env, "led_strip_node")["key"]
    app = firmware_dir(root, "led_strip_node") / "led_strip_node.bin"
    before = app.read_bytes()
    source = root / "firmware/led_strip_node/main/led_strip_node_main.c"
    source.write_text(source.read_text() + "\n/* a change */\n")
    result = espdock("build", "led_strip_node", cwd=root, env=double_env)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr
    assert "cache hit" in result.stdout and "cache miss" not in result.stdout
    assert status(root, double_env, "led_strip_node")["key"] == key_before
    assert app.read_bytes() != before


def component_edits_rebuild_the_app(root: Path, env: dict[str, str], components: Path, listed: str) -> None:
    """Add the component board_led in COMPONENTS, which the app takes through the EXTRA_COMPONENT_DIRS
    entry LISTED; build, edit it, build: the app is built again with the edit."""
    (components / "board_led").mkdir(parents=True)
    (components / "board_led/CMakeLists.txt").write_text(
        'idf_component_register(SRCS "board_led.c" INCLUDE_DIRS ".")\n'
    )
    (components / "board_led/board_led.c").write_text("int board_led_level(void) { return 1; }\n")
    project = root / "firmware/led_strip_node/CMakeLists.txt"
    original = project.read_text()
    project.write_text(
        original.replace(
            "${CMAKE_CURRENT_LIST_DIR}/../components)", f"${{CMAKE_CURRENT_LIST_DIR}}/../components\n    {listed})"
        )
    )
    app = firmware_dir(root, "led_strip_node") / "led_strip_node.bin"
    try:
        built = espdock("build", "led_strip_node", "--only", "firmware", cwd=root, env=env)
        assert built.returncode == 0, built.stdout[-2000:] + built.stderr
        before = app.read_bytes()
        (components / "board_led/board_led.c").write_text("int board_led_level(void) { return 2; }\n")
        rebuilt = espdock("build", "led_strip_node", "--only", "firmware", cwd=root, env=env)
        assert rebuilt.returncode == 0, rebuilt.stdout[-2000:] + rebuilt.stderr
        assert "board_led.c" in rebuilt.stdout and app.read_bytes() != before, rebuilt.stdout[-2000:]
    finally:
        project.write_text(original)


def test_an_edit_of_a_component_the_app_takes_from_elsewhere_in_the_workspace_rebuilds_it(fw_ws, double_env):
    """A component shared through another EXTRA_COMPONENT_DIRS entry than ../components: its edit
    left the build "up to date" and the old firmware installed (and flashed) until --force."""
    root, first = fw_ws
    assert first.returncode == 0
    (root / "firmware/common").mkdir()
    (root / "firmware/common/COLCON_IGNORE").touch()
    try:
        component_edits_rebuild_the_app(
            root, double_env, root / "firmware/common", "${CMAKE_CURRENT_LIST_DIR}/../common"
        )
    finally:
        shutil.rmtree(root / "firmware/common")
    settled = espdock("build", "led_strip_node", "--only", "firmware", cwd=root, env=double_env)
    assert settled.returncode == 0, settled.stdout[-2000:] + settled.stderr


def test_components_a_link_in_the_project_leads_to_out_of_the_workspace_are_built_in(fw_ws, double_env, tmp_path):
    """`shared -> ~/repos/components` in a firmware project, named in EXTRA_COMPONENT_DIRS: the IDF
    container had only the workspace, and IDF said the directory did not exist."""
    root, first = fw_ws
    assert first.returncode == 0
    outside = tmp_path / "repos/components"
    link = root / "firmware/led_strip_node/shared"
    outside.mkdir(parents=True)
    link.symlink_to(outside)
    try:
        component_edits_rebuild_the_app(root, double_env, outside, "${CMAKE_CURRENT_LIST_DIR}/shared")
    finally:
        link.unlink()
    settled = espdock("build", "led_strip_node", "--only", "firmware", cwd=root, env=double_env)
    assert settled.returncode == 0, settled.stdout[-2000:] + settled.stderr


SHARED_TABLE = """\
# Name,   Type, SubType, Offset,  Size
nvs,      data, nvs,     0x9000,  0x6000,
phy_init, data, phy,     0xf000,  0x1000,
factory,  app,  factory, 0x10000, 0x180000,
storage,  data, spiffs,  ,        {storage},
"""


def test_an_edit_of_a_defaults_file_or_partition_table_shared_from_outside_the_project_rebuilds_it(fw_ws, double_env):
    """A monorepo's `../common/sdkconfig.common` in SDKCONFIG_DEFAULTS, naming a custom partition
    table `../common/partitions.csv`, and its `include(../common/board.cmake)`: an edit of any
    left the build "up to date" and the old firmware installed (and flashed: the old partition
    table) until --force."""
    root, first = fw_ws
    assert first.returncode == 0
    common = root / "firmware/common"
    common.mkdir()
    (common / "COLCON_IGNORE").touch()
    shared = common / "sdkconfig.common"
    shared.write_text(
        "# CONFIG_PARTITION_TABLE_SINGLE_APP_LARGE is not set\nCONFIG_PARTITION_TABLE_CUSTOM=y\n"
        'CONFIG_PARTITION_TABLE_CUSTOM_FILENAME="../common/partitions.csv"\nCONFIG_ESPDOCK_LED_STRIP_GPIO=5\n'
    )
    (common / "partitions.csv").write_text(SHARED_TABLE.format(storage="0x10000"))
    (common / "board.cmake").write_text("set(BOARD_LEDS 8)\n")
    project = root / "firmware/led_strip_node/CMakeLists.txt"
    original = project.read_text()
    project.write_text(
        original.replace(
            "include($ENV{IDF_PATH}",
            'set(SDKCONFIG_DEFAULTS "sdkconfig.defaults;../common/sdkconfig.common")\n'
            "include(${CMAKE_CURRENT_LIST_DIR}/../common/board.cmake)\ninclude($ENV{IDF_PATH}",
        )
    )
    table = firmware_dir(root, "led_strip_node") / "partition_table/partition-table.bin"
    sdkconfig = root / "ws/build/led_strip_node/sdkconfig"

    def build() -> None:
        built = espdock("build", "led_strip_node", "--only", "firmware", cwd=root, env=double_env)
        assert built.returncode == 0, built.stdout[-2000:] + built.stderr
        assert "up to date" not in built.stdout, built.stdout[-2000:]

    try:
        build()
        assert "CONFIG_ESPDOCK_LED_STRIP_GPIO=5\n" in sdkconfig.read_text()
        before = table.read_bytes()
        (common / "partitions.csv").write_text(SHARED_TABLE.format(storage="0x20000"))
        build()
        assert table.read_bytes() != before
        shared.write_text(shared.read_text().replace("GPIO=5", "GPIO=6"))
        build()
        assert "CONFIG_ESPDOCK_LED_STRIP_GPIO=6\n" in sdkconfig.read_text()
        (common / "board.cmake").write_text("set(BOARD_LEDS 16)\n")
        build()
    finally:
        project.write_text(original)
        shutil.rmtree(common)
    settled = espdock("build", "led_strip_node", "--only", "firmware", cwd=root, env=double_env)
    assert settled.returncode == 0, settled.stdout[-2000:] + settled.stderr


def test_a_msg_change_is_never_served_a_stale_library(fw_ws, double_env):
    root, first = fw_ws
    assert first.returncode == 0
    old = status(root, double_env)
    msg = root / "ws/src/custom_interface/msg/CameraConfig.msg"
    original = msg.read_text()
    field = f"espdock_field_{uuid.uuid4().hex[:8]}"
    msg.write_text(original + f"uint8 {field}\n")
    try:
        changed = status(root, double_env)
        assert changed["key"] != old["key"] and not changed["present"]
        assert "micro-ros/extra_packages/custom_interface/msg/CameraConfig.msg" in changed["changed_inputs"]
        assert status(root, double_env, "led_strip_node")["present"], "led_strip_node does not use the .msg"

        app = firmware_dir(root, "camera_node") / "camera_node.bin"
        before = app.read_bytes()
        # Firmware only: the ROS side's rebuild on a .msg change is test_colcon's, and here it would
        # build the interface package twice (the change, then the restore: ~40 s of CPU).
        # First with the app broken: the library is built, the app fails, and prune knows the image
        # (a failed build's images were never recorded, so never pruned).
        source = root / "firmware/camera_node/main/frame_pacer.c"
        code = source.read_text()
        source.write_text(code + "\n#error deliberately broken\n")
        try:
            failed = espdock("build", "camera_node", "--only", "firmware", cwd=root, env=double_env)
        finally:
            source.write_text(code)
        assert failed.returncode == 5, failed.stdout[-2000:] + failed.stderr
        assert "cache miss" in failed.stdout
        (record,) = [r for r in read_records(state_dir(os.environ)) if r.root == str(root)]
        assert changed["image"] in record.current, record.current
        result = espdock("build", "camera_node", "--only", "firmware", cwd=root, env=double_env)
        assert result.returncode == 0, result.stdout[-2000:] + result.stderr
        assert field in header(changed["image"])
        assert app.read_bytes() != before, "the app must relink against the new library"
    finally:
        msg.write_text(original)  # the other tests share this workspace


def test_a_broken_firmware_build_keeps_the_installed_firmware(fw_ws, double_env, engine):
    root, first = fw_ws
    assert first.returncode == 0
    installed = firmware_dir(root, "led_strip_node")
    before = {p.name: p.read_bytes() for p in installed.iterdir() if p.is_file()}
    source = root / "firmware/led_strip_node/main/color_parse.c"
    original = source.read_text()
    source.write_text(original + "\n#error deliberately broken\n")
    try:
        result = espdock("build", "led_strip_node", cwd=root, env=double_env)
    finally:
        source.write_text(original)
    assert result.returncode == 5, result.stdout[-2000:] + result.stderr
    assert "led_strip_node" in result.stderr
    # The compiler's error names the file as the user opens it, not as the container saw it.
    assert f"{root}/firmware/led_strip_node/main/color_parse.c:" in result.stdout, result.stdout[-2000:]
    assert "deliberately broken" in result.stdout
    assert {p.name: p.read_bytes() for p in installed.iterdir() if p.is_file()} == before
    assert leftover_containers(engine, root) == []


def test_a_component_that_includes_micro_ros_without_requiring_it_is_told_how(fw_ws, double_env):
    """A component of the workspace's own that includes an interface's header: IDF gives it only
    the components it names (main gets every one), and the compiler's "No such file" was followed
    by "Fix the firmware"; the component to require is named nowhere but espdock's own glue."""
    root, first = fw_ws
    assert first.returncode == 0
    component = root / "firmware/components/board_pub"
    component.mkdir()
    (component / "CMakeLists.txt").write_text('idf_component_register(SRCS "board_pub.c" INCLUDE_DIRS ".")\n')
    (component / "board_pub.c").write_text(
        '#include "std_msgs/msg/string.h"\nint board_pub_ready(void) { return 1; }\n'
    )
    try:
        failed = espdock("build", "led_strip_node", "--only", "firmware", cwd=root, env=double_env)
    finally:
        shutil.rmtree(component)
    said = " ".join(failed.stderr.split())
    assert failed.returncode == 5, failed.stdout[-2000:] + said
    assert "std_msgs/msg/string.h is the micro-ROS library's, and firmware/components/board_pub does not" in said
    assert "add `PRIV_REQUIRES micro_ros_espidf_component`" in said, said
    settled = espdock("build", "led_strip_node", "--only", "firmware", cwd=root, env=double_env)
    assert settled.returncode == 0, settled.stdout[-2000:] + settled.stderr


def test_new_defaults_set_menuconfig_s_sdkconfig_aside_and_a_failed_build_s_is_never_kept_for_others(fw_ws, double_env):
    """sdkconfig.defaults edited (and the app broken), the build failed, the edit undone and the app
    mended: the next build kept the failed build's sdkconfig, made from the undone edit, without a
    word; and the edit had deleted the sdkconfig menuconfig changed, without a word either."""
    root, first = fw_ws
    assert first.returncode == 0
    project = root / "firmware/led_strip_node"
    defaults, source = project / "sdkconfig.defaults", project / "main/color_parse.c"
    sdkconfig = root / "ws/build/led_strip_node/sdkconfig"
    original, code = defaults.read_text(), source.read_text()
    assert "CONFIG_ESPDOCK_LED_COUNT=8\n" in sdkconfig.read_text()
    sdkconfig.write_text(sdkconfig.read_text().replace("CONFIG_ESPDOCK_LED_COUNT=8\n", "CONFIG_ESPDOCK_LED_COUNT=9\n"))
    try:
        defaults.write_text(original + "CONFIG_ESPDOCK_LED_COUNT=30\n")
        source.write_text(code + "\n#error deliberately broken\n")
        failed = espdock("build", "led_strip_node", "--only", "firmware", cwd=root, env=double_env)
        assert failed.returncode == 5, failed.stdout[-2000:] + failed.stderr
        said = "sdkconfig.defaults changed: ws/build/led_strip_node/sdkconfig is made afresh from it"
        assert said in failed.stdout, failed.stdout[-2000:]
        assert "CONFIG_ESPDOCK_LED_COUNT=9\n" in (sdkconfig.parent / "sdkconfig.old").read_text()
        assert "CONFIG_ESPDOCK_LED_COUNT=30\n" in sdkconfig.read_text()
    finally:
        defaults.write_text(original)
        source.write_text(code)
    built = espdock("build", "led_strip_node", "--only", "firmware", cwd=root, env=double_env)
    assert built.returncode == 0, built.stdout[-2000:] + built.stderr
    assert "CONFIG_ESPDOCK_LED_COUNT=8\n" in sdkconfig.read_text()
    # The defaults back as they were (a branch switched there and back): the sdkconfig set aside
    # had no menuconfig change, and sdkconfig.old still has the one that had.
    assert "CONFIG_ESPDOCK_LED_COUNT=9\n" in (sdkconfig.parent / "sdkconfig.old").read_text()


def test_a_broken_interface_fails_the_library_build_and_tags_nothing(fw_ws, double_env, engine):
    root, first = fw_ws
    assert first.returncode == 0
    msg = root / "ws/src/custom_interface/msg/CameraConfig.msg"
    original = msg.read_text()
    msg.write_text(original + "no_such_type broken_field\n")
    try:
        broken = status(root, double_env)
        # Firmware only: colcon would otherwise refuse the .msg first.
        result = espdock("build", "camera_node", "--only", "firmware", cwd=root, env=double_env)
    finally:
        msg.write_text(original)
    assert result.returncode == 4, result.stdout[-2000:] + result.stderr
    assert engine.image(broken["image"]) is None
    assert (firmware_dir(root, "camera_node") / "flasher_args.json").is_file()
    # rosidl's error names the .msg as the user knows it, not where the image build copied it.
    said = f"{msg}:{len(original.splitlines()) + 1}: error: unknown field type 'no_such_type'"
    assert said in result.stdout and said in result.stderr, result.stdout[-2000:] + result.stderr
    assert "extra_ros_packages/custom_interface" not in result.stdout + result.stderr


def test_switching_the_chip_target_builds_a_new_library_and_retargets(fw_ws, double_env):
    root, first = fw_ws
    assert first.returncode == 0
    esp32 = status(root, double_env, "camera_node")
    result = espdock("build", "camera_node", "--target", "esp32s3", cwd=root, env=double_env)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr
    assert "espdock/idf-micro-ros-jazzy-esp32s3:" in result.stdout
    flasher_args = json.loads((firmware_dir(root, "camera_node") / "flasher_args.json").read_text())
    assert flasher_args["extra_esptool_args"]["chip"] == "esp32s3"
    assert "0x0" in flasher_args["flash_files"]
    # On the S3 the board defaults to an S3 board (its pins exist there) with octal PSRAM.
    sdkconfig = (root / "ws/build/camera_node/sdkconfig").read_text()
    assert "CONFIG_ESPDOCK_CAM_BOARD_XIAO_ESP32S3=y" in sdkconfig and "CONFIG_SPIRAM_MODE_OCT=y" in sdkconfig
    assert "CONFIG_ESPDOCK_CAM_BOARD_AI_THINKER=y" not in sdkconfig
    # `espdock idf` runs for the chip of the build dir, as flash does: for the package's own, IDF
    # refused the build dir's sdkconfig ("generated for target 'esp32s3'") and set-target is refused.
    reconfigured = espdock("idf", "camera_node", "--", "reconfigure", cwd=root, env=double_env)
    assert reconfigured.returncode == 0, reconfigured.stdout[-2000:] + reconfigured.stderr
    assert "build/camera_node was last built for esp32s3" in " ".join(reconfigured.stdout.split())
    # And back: the esp32 image is still cached.
    back = espdock("build", "camera_node", cwd=root, env=double_env)
    assert back.returncode == 0
    assert status(root, double_env, "camera_node")["key"] == esp32["key"]
    sdkconfig = (root / "ws/build/camera_node/sdkconfig").read_text()
    assert "CONFIG_ESPDOCK_CAM_BOARD_AI_THINKER=y" in sdkconfig and "SPIRAM_MODE_OCT" not in sdkconfig
    # Each switch set the chip's sdkconfig (menuconfig's changes) aside, as IDF's set-target does, and said so.
    said = " ".join(back.stdout.split())
    assert "ws/build/camera_node was for esp32s3: made afresh for esp32" in said, back.stdout[-3000:]
    assert "CONFIG_SPIRAM_MODE_OCT=y" in (root / "ws/build/camera_node/sdkconfig.old").read_text()


def test_a_moved_firmware_project_builds_in_its_build_dir_made_afresh(fw_ws, double_env):
    """`mv firmware/led_strip_node firmware/led_strip`: IDF refused the build dir, configured for the
    old path ("Run 'idf.py fullclean'"), and espdock's hint said to fix the firmware."""
    root, first = fw_ws
    assert first.returncode == 0
    shutil.move(root / "firmware/led_strip_node", root / "firmware/led_strip")
    try:
        moved = espdock("build", "led_strip_node", "--only", "firmware", cwd=root, env=double_env)
        assert moved.returncode == 0, moved.stdout[-2000:] + moved.stderr
    finally:
        shutil.move(root / "firmware/led_strip", root / "firmware/led_strip_node")
    back = espdock("build", "led_strip_node", "--only", "firmware", cwd=root, env=double_env)
    assert back.returncode == 0, back.stdout[-2000:] + back.stderr


def test_new_makes_a_package_that_builds(fw_ws, double_env):
    root, first = fw_ws
    assert first.returncode == 0
    created = espdock("new", "blinky", "--depends", "custom_interface", cwd=root, env=double_env)
    assert created.returncode == 0, created.stderr
    again = espdock("new", "blinky", cwd=root, env=double_env)
    assert again.returncode == 2 and "already exists" in again.stderr
    bad = espdock("new", "Blinky-2", cwd=root, env=double_env)
    assert bad.returncode == 2 and "not a valid ROS package name" in bad.stderr
    result = espdock("build", "blinky", cwd=root, env=double_env)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr
    assert (firmware_dir(root, "blinky") / "blinky.bin").is_file()
    shutil.rmtree(root / "firmware/blinky")


def test_a_firmware_project_linked_in_from_outside_is_refused_naming_it(fw_ws, double_env, tmp_path):
    """colcon finds packages through links, so espdock does; the IDF containers get only the
    workspace, so a linked firmware project is bad input, said before any IDF container starts."""
    root, first = fw_ws
    assert first.returncode == 0
    created = espdock("new", "linked_fw", cwd=root, env=double_env)
    assert created.returncode == 0, created.stderr
    outside = tmp_path / "linked_fw"
    shutil.move(root / "firmware/linked_fw", outside)
    (root / "firmware/linked_fw").symlink_to(outside)
    try:
        result = espdock("build", "linked_fw", cwd=root, env=double_env)
        assert result.returncode == 2, result.stdout[-2000:] + result.stderr
        assert f"firmware package linked_fw is linked from outside the workspace ({root}/firmware/linked_fw -> " in (
            result.stderr
        )
        assert not firmware_dir(root, "linked_fw").exists()
    finally:
        (root / "firmware/linked_fw").unlink()


def test_idf_passthrough_runs_idf_py_in_the_image(fw_ws, double_env):
    root, first = fw_ws
    assert first.returncode == 0
    result = espdock("idf", "led_strip_node", "--", "--version", cwd=root, env=double_env)
    assert result.returncode == 0, result.stderr
    assert "ESP-IDF v5.3.5" in result.stdout
    # IDF's set-target would empty the build dir, then refuse the chip espdock passes.
    before = sorted(p.name for p in (root / "ws/build/led_strip_node").iterdir())
    result = espdock("idf", "led_strip_node", "--", "set-target", "esp32", cwd=root, env=double_env)
    assert result.returncode == 2 and "idf.py set-target is not how espdock changes" in result.stderr, result.stderr
    assert "CONFIG_IDF_TARGET" in result.stderr and "--target CHIP" in result.stderr
    assert sorted(p.name for p in (root / "ws/build/led_strip_node").iterdir()) == before
    # Another build dir: idf.py built into the container's /tmp, exit 0, and it went with the container.
    elsewhere = espdock("idf", "led_strip_node", "--", "-B", "/tmp/xx", "build", cwd=root, env=double_env)
    assert elsewhere.returncode == 2, elsewhere.stdout[-2000:] + elsewhere.stderr
    assert "idf.py -B: espdock decides where led_strip_node is built" in elsewhere.stderr


@contextlib.contextmanager
def emulated_board(chip: str):
    """esp32-mock-bootloader emulating CHIP on a loopback port it picks: the ROM bootloader esptool
    talks to. Run in the foreground as this process's child, it ends the moment it is told to (the
    tool's `stop` waits 2 s for its daemon) and no other test's `stop` can take it."""
    tool = Path(sys.executable).with_name("esp32-mock-bootloader")
    with tempfile.TemporaryDirectory(prefix="espdock-board-") as tmp:
        port_file = Path(tmp, "port")
        server = subprocess.Popen(
            [str(tool), "run", "--chip", chip, "--port", "0", "--port-file", str(port_file)],
            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
        )  # fmt: skip
        try:
            deadline = time.monotonic() + 60
            # The server listens before it writes the file.
            while not (port_file.is_file() and port_file.read_text().strip()):
                assert server.poll() is None and time.monotonic() < deadline, "the emulated board did not start"
                time.sleep(0.02)
            yield f"socket://127.0.0.1:{port_file.read_text().strip()}"
        finally:
            server.terminate()
            server.wait(timeout=30)


@pytest.fixture
def mock_bootloader():
    """A board of camera_node's chip (esp32). (The emulator's esp32c3 reports chip revision v0.0, below
    IDF's default minimum for the C3, v0.3, so esptool refuses to flash led_strip_node to it, as it would
    refuse such a board.)"""
    with emulated_board("esp32") as port:
        yield port


def test_flash_writes_and_verifies_through_esptool_while_a_build_runs(fw_ws, double_env, mock_bootloader, engine):
    """Flashing one board while another board's firmware builds (a fleet's habit): flash,
    provision and monitor were refused as "another espdock build is running", though they
    write the installed firmware, which a build swaps in whole."""
    root, first = fw_ws
    assert first.returncode == 0
    with build_holding(root, "build", "led_strip_node"):
        result = espdock("flash", "camera_node", "--port", mock_bootloader, "--verify", cwd=root, env=double_env)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr
    assert "verified" in result.stdout
    assert leftover_containers(engine, root) == []


def test_a_build_swapping_the_firmware_between_flash_and_verify_leaves_one_firmware_written_and_verified(
    fw_ws, double_env, mock_bootloader, tmp_path
):
    """`flash --verify` runs esptool twice; a build of the same package that installed its new
    firmware in between had the verify read the new one ("verify FAILED (digest mismatch)", exit 6)
    against a board written whole with the old. espdock is stopped the moment it says the verify's
    command line, the swap made by the install a build makes (install_firmware, with an app one
    byte different), then espdock goes on."""
    from espdock.firmware.install import install_firmware

    root, first = fw_ws
    assert first.returncode == 0
    installed = firmware_dir(root, "camera_node")
    old = installed.parent / os.readlink(installed)
    flasher_args = json.loads((old / "flasher_args.json").read_text())
    app = flasher_args["app"]["file"]
    offset = int(next(address for address, name in flasher_args["flash_files"].items() if name == app), 16)
    old_app = (old / app).read_bytes()

    def install(build_dir: Path) -> None:
        install_firmware(
            "camera_node", root / "firmware/camera_node/package.xml", build_dir, root / "ws/install", (),
            (USER_UID, USER_UID), workspace_root=root,
        )  # fmt: skip

    original, edited = tmp_path / "original", tmp_path / "edited"
    shutil.copytree(old, original)
    shutil.copytree(old, edited)
    (edited / app).write_bytes(old_app[:-1] + bytes([old_app[-1] ^ 0xFF]))
    argv = [sys.executable, "-m", "espdock", "flash", "camera_node", "--port", mock_bootloader, "--verify"]
    with subprocess.Popen(
        argv, cwd=root, env={**os.environ, **double_env}, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
        stderr=subprocess.PIPE, text=True,
    ) as flashing:  # fmt: skip
        said = []
        try:
            for line in flashing.stdout:
                said.append(line)
                if "verify_flash" in line:  # printed before its container starts
                    flashing.send_signal(signal.SIGSTOP)
                    install(edited)
                    flashing.send_signal(signal.SIGCONT)
                    break
            said += flashing.stdout.readlines()
            flashing.wait(timeout=300)
        finally:
            flashing.kill()
            install(original)  # the module's later tests flash the firmware the build made
        stderr = flashing.stderr.read()
    out = "".join(said)
    assert flashing.returncode == 0, out[-3000:] + stderr
    assert "verified" in out
    assert flash_md5(mock_bootloader, offset, len(old_app)) == hashlib.md5(old_app).hexdigest()
    # The version the flash held stayed for it; the install after it removed the one it replaced.
    assert os.readlink(installed) == old.name
    assert [p.name for p in installed.parent.glob(".firmware-*")] == [old.name]


def test_flash_after_a_fullclean_writes_the_firmware_without_calling_it_stale(fw_ws, double_env, mock_bootloader):
    """`espdock idf PKG -- fullclean`, then `flash`: "the installed firmware of PKG is not what its
    sources build now", with no source changed."""
    root, first = fw_ws
    assert first.returncode == 0
    cleaned = espdock("idf", "camera_node", "--", "fullclean", cwd=root, env=double_env)
    assert cleaned.returncode == 0, cleaned.stdout[-2000:] + cleaned.stderr
    flashed = espdock("flash", "camera_node", "--port", mock_bootloader, cwd=root, env=double_env)
    assert flashed.returncode == 0, flashed.stdout[-3000:] + flashed.stderr
    assert "not what its sources build now" not in flashed.stdout, flashed.stdout[-2000:]
    source = root / "firmware/camera_node/main/camera_node_main.c"
    original = source.read_text()
    source.write_text(original + "\n/* an edit since the build */\n")
    try:
        edited = espdock("flash", "camera_node", "--port", mock_bootloader, cwd=root, env=double_env)
    finally:
        source.write_text(original)
    assert edited.returncode == 0 and "not what its sources build now" in " ".join(edited.stdout.split())


def test_flash_writes_the_installed_firmware_while_its_interface_is_mid_edit(fw_ws, double_env, mock_bootloader):
    """A .msg edited since the build, here half typed: flash (and provision and monitor) built the
    micro-ROS image of the sources as they are, stopping on the edit with exit 4, or, for an edit
    that builds, making a library (minutes with the real toolchain) the firmware was not built with."""
    root, first = fw_ws
    assert first.returncode == 0
    message = root / "ws/src/custom_interface/msg/CameraConfig.msg"
    text = message.read_text()
    build, aside = root / "ws/build", root / "ws/build-aside"
    message.write_text(text + "uint8 exposure_half_typed\n")  # an edit that builds: no library of it is made
    try:
        result = espdock("flash", "camera_node", "--port", mock_bootloader, "--verify", cwd=root, env=double_env)
        assert not status(root, double_env)["present"], "the image of the edited sources was built"
        message.write_text(text + "float33 exposure_half_typed\n")  # one that does not: it cannot stop flashing
        broken = espdock("flash", "camera_node", "--port", mock_bootloader, cwd=root, env=double_env)
        # `rm -rf build`, which held the build dir's record of the image: the install's manifest has it.
        build.rename(aside)
        cleaned = espdock("flash", "camera_node", "--port", mock_bootloader, cwd=root, env=double_env)
    finally:
        message.write_text(text)
        if aside.is_dir():
            shutil.rmtree(build, ignore_errors=True)
            aside.rename(build)
    for flashed in (result, broken, cleaned):
        assert flashed.returncode == 0, flashed.stdout[-3000:] + flashed.stderr
        assert "note: the installed firmware of camera_node is not what its sources build now" in flashed.stdout
    assert "verified" in result.stdout


def test_flash_writes_the_installed_firmware_while_its_own_sources_are_mid_edit(fw_ws, double_env, mock_bootloader):
    """The firmware package's own sources mid-edit, as no build takes them yet (a chip misspelt in
    sdkconfig.defaults, its idf_component.yml half typed): flash stopped with exit 2 on what their
    plan said, where it writes the firmware as it was last built, and says why the sources do not count."""
    root, first = fw_ws
    assert first.returncode == 0
    project = root / "firmware/camera_node"
    edits = (
        (project / "sdkconfig.defaults", 'CONFIG_IDF_TARGET="esp32x"\n', "esp32x"),
        (project / "main/idf_component.yml", "dependencies: [espressif/esp32-camera\n", "idf_component.yml"),
    )
    for source, edit, named in edits:
        text = source.read_text()
        source.write_text(text + edit)
        try:
            flashed = espdock("flash", "camera_node", "--port", mock_bootloader, cwd=root, env=double_env)
            built = espdock("build", "camera_node", "--dry-run", cwd=root, env=double_env)
        finally:
            source.write_text(text)
        said = " ".join((flashed.stdout + flashed.stderr).split())
        assert flashed.returncode == 0, said[-3000:]
        assert "flashed camera_node" in said
        assert named in said and "the installed firmware of camera_node is used as it was built" in said, said[-3000:]
        # A build plans the sources: the edit is still its error.
        assert built.returncode == 2 and named in built.stderr, built.stdout[-2000:] + built.stderr


def test_flash_and_provision_write_the_installed_firmware_while_a_package_xml_is_mid_edit(
    fw_ws, double_env, mock_bootloader, tmp_path
):
    """Another package's package.xml half typed (its closing tag not yet), or that of the interface
    the firmware depends on: flash, provision and monitor stopped with "is not a valid package.xml"
    (exit 2), where they work with the firmware as it was last built."""
    root, first = fw_ws
    assert first.returncode == 0
    password = tmp_path / "password"
    password.write_text("labpassword1\n")
    provision = ("--wifi-ssid", "lab", "--wifi-password-file", str(password), "--agent", "192.168.1.10:8888")
    # A package being written, half typed yet, and the interface's own.
    new = root / "ws/src/notes_pkg/package.xml"
    new.parent.mkdir()
    new.write_text((root / "ws/src/custom_interface/package.xml").read_text().replace("custom_interface", "notes_pkg"))
    for manifest in (new, root / "ws/src/custom_interface/package.xml"):
        text = manifest.read_text()
        manifest.write_text(text.replace("</package>", "</packag"))
        try:
            flashed = espdock("flash", "camera_node", "--port", mock_bootloader, cwd=root, env=double_env)
            provisioned = espdock(
                "provision", "camera_node", "--port", mock_bootloader, *provision, cwd=root, env=double_env
            )
            built = espdock("build", "camera_node", "--dry-run", cwd=root, env=double_env)
        finally:
            manifest.write_text(text)
            if manifest == new:
                shutil.rmtree(new.parent)
        for result in (flashed, provisioned):
            said = " ".join((result.stdout + result.stderr).split())
            assert result.returncode == 0, (manifest, said[-3000:])
            assert f"{manifest} is not a valid package.xml" in said and "left out" in said, said[-3000:]
            # The interface's manifest unreadable is not a dependency no package holds.
            assert "depends on custom_interface: in no package" not in said, said[-3000:]
        assert "flashed camera_node" in flashed.stdout and "provisioned camera_node" in provisioned.stdout
        # A build reads the sources: the manifest is still an error there.
        assert built.returncode == 2 and f"{manifest} is not a valid package.xml" in built.stderr, built.stderr


def test_the_chip_probe_speaks_the_esptool_it_finds_and_tells_its_version(mock_bootloader):
    """The double's image holds esptool 4 (the flash tests above); this venv's is esptool 5, which
    takes the probe's words hyphenated. One run detects the chip and names esptool's version."""
    argv = chip_probe_argv(parse_port(mock_bootloader))
    assert argv[0] == "python"
    probe = subprocess.run([sys.executable, *argv[1:]], capture_output=True, text=True, timeout=120, check=False)
    output = (probe.stdout + probe.stderr).splitlines()
    assert probe.returncode == 0, "\n".join(output[-20:])
    assert detected_chip(output) == "esp32"
    assert esptool_major(output) == 5
    assert not [line for line in output if "deprecated" in line.lower()], "esptool 5 was given esptool 4's words"


def ros2_run(package: str, executable: str, *args: str, env: dict[str, str], cwd: Path) -> subprocess.CompletedProcess:
    """`ros2 run PACKAGE EXECUTABLE ARGS` the way ros2run finds and starts it (ros2cli is not installable
    here): the package's prefix from the ament index on AMENT_PREFIX_PATH, then the executable file
    <prefix>/lib/<package>/EXECUTABLE, run with ARGS."""
    prefixes = [Path(p) for p in env["AMENT_PREFIX_PATH"].split(os.pathsep)]
    (prefix,) = [p for p in prefixes if (p / "share/ament_index/resource_index/packages" / package).is_file()][:1]
    path = prefix / "lib" / package / executable
    assert path.is_file() and os.access(path, os.X_OK), f"no executable {executable} in {path.parent}"
    return subprocess.run(
        [str(path), *args],
        cwd=cwd,
        env=env,
        stdin=subprocess.DEVNULL,
        capture_output=True,
        text=True,
        timeout=900,
        check=False,
    )


def sourced_env(root: Path, double_env: dict[str, str]) -> dict[str, str]:
    """What sourcing the workspace's install/setup.sh gives the two apps, with espdock on PATH (pip-installed)."""
    install = root / "ws" / "install"
    path = f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"
    prefixes = os.pathsep.join(str(install / p) for p in ("camera_node", "led_strip_node"))
    return {**os.environ, **double_env, "PATH": path, "AMENT_PREFIX_PATH": prefixes}


def test_ros2_run_flash_flashes_the_package_from_outside_the_workspace(fw_ws, double_env, mock_bootloader, tmp_path):
    root, first = fw_ws
    assert first.returncode == 0
    env = sourced_env(root, double_env)
    result = ros2_run("camera_node", "flash", "--port", mock_bootloader, "--verify", env=env, cwd=tmp_path)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr
    assert f"flashed camera_node through {mock_bootloader} and verified it" in result.stdout


def test_ros2_run_idf_and_monitor_reach_espdock_for_their_package(fw_ws, double_env, mock_bootloader, tmp_path):
    root, first = fw_ws
    assert first.returncode == 0
    env = sourced_env(root, double_env)
    idf = ros2_run("led_strip_node", "idf", "--version", env=env, cwd=tmp_path)
    assert idf.returncode == 0, idf.stderr
    assert "ESP-IDF v5.3.5" in idf.stdout
    # No terminal here: `espdock monitor` refuses with its usage error, which shows the script reached it.
    monitor = ros2_run("camera_node", "monitor", "--port", mock_bootloader, env=env, cwd=tmp_path)
    assert monitor.returncode == 2, monitor.stdout + monitor.stderr
    assert "the monitor needs a terminal" in monitor.stdout + monitor.stderr


def test_ros2_run_without_espdock_on_path_says_so(fw_ws, double_env, tmp_path):
    root, first = fw_ws
    assert first.returncode == 0
    env = {**sourced_env(root, double_env), "PATH": "/usr/bin:/bin"}
    result = ros2_run("camera_node", "flash", "--port", "/dev/ttyUSB0", env=env, cwd=tmp_path)
    assert result.returncode == 127
    assert "espdock is not on PATH; activate the venv it is installed in" in result.stderr
    assert "pip install espdock" not in result.stderr  # not on PyPI: that would install someone else's


def test_ctrl_c_during_flash_ends_with_130_leaving_no_container_and_the_next_flash_works(fw_ws, double_env, engine):
    root, first = fw_ws
    assert first.returncode == 0
    with emulated_board("esp32") as port:
        flashing = Started(root, "flash", "camera_node", "--port", port, "--verify", env=double_env)
        code, took = flashing.interrupt_on("Writing at")
        assert code == 130, flashing.output()
        assert took < 10, f"espdock flash took {took:.1f} s to end after Ctrl-C"
        assert leftover_containers(engine, root) == []
    with emulated_board("esp32") as port:  # the user resets the board, which esptool left mid-write
        again = espdock("flash", "camera_node", "--port", port, "--verify", cwd=root, env=double_env)
        assert again.returncode == 0, again.stdout[-2000:] + again.stderr


def test_a_second_flash_of_a_board_between_the_first_s_containers_is_refused(fw_ws, double_env, engine):
    """A flash runs three containers (the chip probe, the write, the verify): a second flash of the
    same board, its port written otherwise, that came between two of them passed the busy check
    (no container had the port) and wrote the board while the first went on to write it too; on a
    real board the two esptools' frames interleave. The first is held still (SIGSTOP) in such a gap."""
    root, first = fw_ws
    assert first.returncode == 0
    with emulated_board("esp32") as port:
        flashing = Started(root, "flash", "camera_node", "--port", port, env=double_env)
        try:
            flashing.wait_for("camera_node.bin", timeout=300)  # the write's command line: the probe is done
            flashing.process.send_signal(signal.SIGSTOP)
            deadline = time.monotonic() + 120
            while engine.device_users([], port):  # the write's, where it had started: it runs on
                assert time.monotonic() < deadline, "the first flash's container did not end"
                time.sleep(0.2)
            other = port.replace("127.0.0.1", "localhost") + "/"
            second = espdock("flash", "camera_node", "--port", other, cwd=root, env=double_env)
            said = " ".join(second.stderr.split())
            assert second.returncode == 6, second.stdout[-2000:] + second.stderr
            holder = f"(pid {flashing.process.pid}: espdock flash camera_node --port {port})"
            assert f"serial port {other} is busy: another espdock has it {holder}" in said, said
        finally:
            flashing.process.send_signal(signal.SIGCONT)
        assert flashing.process.wait(timeout=300) == 0, flashing.output()
    assert leftover_containers(engine, root) == []


def test_ctrl_c_during_idf_passthrough_ends_with_130_leaving_no_container(fw_ws, double_env, engine):
    """`espdock idf PKG -- ARGS` runs idf.py attached to espdock's streams: here `flash` through
    esptool, to the port given to idf.py (passed into the container), interrupted while it writes."""
    root, first = fw_ws
    assert first.returncode == 0
    with emulated_board("esp32") as port:
        flashing = Started(root, "idf", "camera_node", "--", "-p", port, "flash", env=double_env)
        code, took = flashing.interrupt_on("Writing at")
    assert code == 130, flashing.output()
    assert took < 10, f"espdock idf took {took:.1f} s to end after Ctrl-C"
    assert leftover_containers(engine, root) == []


@contextlib.contextmanager
def monitor_running(root: Path, env: dict[str, str], port: str) -> Iterator[tuple[subprocess.Popen, bytes]]:
    """`espdock monitor camera_node` on a pseudo-terminal (it needs one), once idf.py monitor is
    up: the process and what it printed so far. It is killed on the way out if still running."""
    controller, terminal = pty.openpty()
    monitor = subprocess.Popen(
        [sys.executable, "-m", "espdock", "monitor", "camera_node", "--port", port],
        cwd=root, env={**os.environ, **env}, stdin=terminal, stdout=terminal, stderr=terminal,
    )  # fmt: skip
    os.close(terminal)
    seen = b""
    try:
        deadline = time.monotonic() + 300
        while b"esp-idf-monitor" not in seen and time.monotonic() < deadline and monitor.poll() is None:
            if select.select([controller], [], [], 0.5)[0]:
                with contextlib.suppress(OSError):
                    seen += os.read(controller, 65536)
        assert b"esp-idf-monitor" in seen, seen.decode(errors="replace")[-2000:]
        yield monitor, seen
    finally:
        if monitor.poll() is None:
            monitor.kill()
            monitor.wait()
        os.close(controller)


def test_a_monitor_killed_outright_leaves_the_port_free_at_once_or_for_the_next_flash(fw_ws, double_env, engine):
    """`kill -9` (or `timeout -s KILL`) of `espdock monitor` left its container on the port: the next
    `flash` found the board silent ("esptool could not tell which chip"), and only a build removed
    it. Its watcher removes it at once; where the watcher was killed too (a whole cgroup), the next
    flash does."""
    root, first = fw_ws
    assert first.returncode == 0
    with emulated_board("esp32") as port:
        with monitor_running(root, double_env, port) as (monitor, _):
            monitor.kill()
            monitor.wait()
        deadline = time.monotonic() + 20
        while leftover_containers(engine, root) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert leftover_containers(engine, root) == [], "the killed monitor's container is left on the port"
        with monitor_running(root, double_env, port) as (monitor, _):
            watcher = subprocess.run(
                ["pgrep", "-f", f"espdock-reaper {monitor.pid} "], capture_output=True, text=True, check=False
            )
            assert watcher.stdout.split(), "no watcher of the running monitor"
            for pid in watcher.stdout.split():
                os.kill(int(pid), signal.SIGKILL)
            monitor.kill()
            monitor.wait()
        assert leftover_containers(engine, root), "the killed monitor's container is left running"
        flashed = espdock("flash", "camera_node", "--port", port, cwd=root, env=double_env)
    assert flashed.returncode == 0, flashed.stdout[-3000:] + flashed.stderr
    assert "removed 1 container(s) of camera_node an espdock that ended before its cleanup" in " ".join(
        flashed.stdout.split()
    ), flashed.stdout[-3000:]
    assert leftover_containers(engine, root) == []


def test_ctrl_c_ends_the_monitor_with_130_leaving_no_container(fw_ws, double_env, engine):
    """`espdock monitor` needs a terminal: it runs on a pseudo-terminal here, and gets SIGINT as
    from `kill -INT` (at the terminal itself, Ctrl-C goes to the board and Ctrl-] ends the monitor,
    as in idf.py monitor)."""
    root, first = fw_ws
    assert first.returncode == 0
    with emulated_board("esp32") as port, monitor_running(root, double_env, port) as (monitor, seen):
        sent = time.monotonic()
        monitor.send_signal(signal.SIGINT)
        code = monitor.wait(timeout=60)
        took = time.monotonic() - sent
    assert code == 130, seen.decode(errors="replace")[-2000:]
    assert took < 10, f"espdock monitor took {took:.1f} s to end after Ctrl-C"
    assert leftover_containers(engine, root) == []


def test_flash_and_provision_refuse_a_board_of_another_chip_before_writing(fw_ws, double_env, tmp_path):
    root, first = fw_ws
    assert first.returncode == 0
    with emulated_board("esp32c3") as esp32c3:
        before = flash_md5(esp32c3, 0x0, 0x20000)
        flashed = espdock("flash", "camera_node", "--port", esp32c3, cwd=root, env=double_env)
        assert flashed.returncode == 2, flashed.stdout[-2000:] + flashed.stderr
        assert f"the board at {esp32c3} is an esp32c3, but camera_node is built for esp32" in flashed.stderr
        provisioned = espdock(
            "provision", "camera_node", "--port", esp32c3, "--wifi-ssid", "lab",
            "--wifi-password-file", "/dev/null", "--agent", "10.0.0.2:8888", cwd=root, env=double_env,
        )  # fmt: skip
        assert provisioned.returncode == 2 and "is an esp32c3" in provisioned.stderr
        # Its own chip at revision v0.0, below IDF's default minimum (v0.3): a board matter, not the port's
        # (it was exit 6, "esptool failed").
        older = espdock("flash", "led_strip_node", "--port", esp32c3, cwd=root, env=double_env)
        assert older.returncode == 2, older.stdout[-2000:] + older.stderr
        assert f"the board at {esp32c3} is older than led_strip_node is built for" in older.stderr
        assert "requires chip revision" in older.stderr and "CONFIG_ESP32C3_REV_MIN_0=y" in older.stderr
        assert "--force" not in older.stderr, "flash has no --force: esptool's advice is not espdock's"
        assert flash_md5(esp32c3, 0x0, 0x20000) == before, "a board of another chip was written to"


def test_what_espdock_s_hints_say_to_do_works(fw_ws, double_env):
    """The revision refusal says to set CONFIG_ESP32C3_REV_MIN_0=y, and the menuconfig warning to
    run `espdock idf PKG -- save-defconfig`: the double knew neither, so no test could follow them."""
    root, first = fw_ws
    assert first.returncode == 0
    defaults = root / "firmware/led_strip_node/sdkconfig.defaults"
    original = defaults.read_text()
    try:
        saved = espdock("idf", "led_strip_node", "--", "save-defconfig", cwd=root, env=double_env)
        assert saved.returncode == 0, saved.stdout[-2000:] + saved.stderr
        written = defaults.read_text()
        # kconfgen's minimal config: what differs from the Kconfig defaults (not the micro-ROS
        # component's own defaults, Wi-Fi and XRCE-DDS).
        assert 'CONFIG_IDF_TARGET="esp32c3"\n' in written, written
        assert "CONFIG_PARTITION_TABLE_SINGLE_APP_LARGE=y\n" in written, written
        assert defaults.stat().st_uid == USER_UID, "written into the sources as their owner"

        defaults.write_text(original + "CONFIG_ESP32C3_REV_MIN_0=y\n")
        built = espdock("build", "led_strip_node", "--only", "firmware", cwd=root, env=double_env)
        assert built.returncode == 0, built.stdout[-2000:] + built.stderr
        with emulated_board("esp32c3") as esp32c3:  # revision v0.0
            flashed = espdock("flash", "led_strip_node", "--port", esp32c3, cwd=root, env=double_env)
        assert flashed.returncode == 0, flashed.stdout[-2000:] + flashed.stderr
    finally:
        defaults.write_text(original)
    again = espdock("build", "led_strip_node", "--only", "firmware", cwd=root, env=double_env)
    assert again.returncode == 0, again.stdout[-2000:] + again.stderr


def test_flash_to_a_missing_or_silent_port_says_so(fw_ws, double_env):
    root, first = fw_ws
    assert first.returncode == 0
    missing = espdock("flash", "led_strip_node", "--port", "/dev/ttyESPDOCK9", cwd=root, env=double_env)
    assert missing.returncode == 6 and "/dev/ttyESPDOCK9 does not exist" in missing.stderr
    silent = f"socket://127.0.0.1:{free_port()}"
    result = espdock("flash", "led_strip_node", "--port", silent, cwd=root, env=double_env)
    assert result.returncode == 6 and "nothing answers" in result.stderr


@pytest.mark.skipif(
    subprocess.run(["docker", "image", "inspect", REAL_IDF_IMAGE], capture_output=True, check=False).returncode != 0,
    reason=f"needs the real {REAL_IDF_IMAGE} image, which no registry here can provide",
)
def test_real_idf_builds_the_apps(tmp_path):
    root = copy_workspace(tmp_path / "ws-root")
    shutil.copy2(REPO / "Dockerfile.idf", root / "Dockerfile.idf")
    shutil.copytree(REPO / "firmware", root / "firmware")
    started = time.monotonic()
    result = espdock("build", cwd=root, timeout=5400)
    assert result.returncode == 0, result.stdout[-5000:] + result.stderr
    print(f"real IDF build took {time.monotonic() - started:.0f} s")


def test_micro_ros_rebuild_builds_the_named_package_s_image_afresh_and_removes_the_one_it_replaced(
    fw_ws, double_env, engine
):
    root, first = fw_ws
    assert first.returncode == 0
    settled = espdock("build", "--only", "firmware", cwd=root, env=double_env)  # whatever earlier tests left
    assert settled.returncode == 0, settled.stdout[-2000:] + settled.stderr
    report, other = status(root, double_env, "led_strip_node"), status(root, double_env, "camera_node")
    assert report["present"]
    before, untouched = engine.image(report["image"]), engine.image(other["image"])
    # One package's image: what the command names is what it rebuilds (each rebuild takes
    # ~25 s of CPU here).
    result = espdock("micro-ros", "rebuild", "led_strip_node", cwd=root, env=double_env)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr
    assert "rebuild requested" in result.stdout
    after = engine.image(report["image"])
    assert after is not None and after.id != before.id
    assert status(root, double_env, "led_strip_node")["key"] == report["key"]
    assert engine.image(before.id) is None, "the image the rebuild replaced was left on the engine, untagged"
    assert engine.image(other["image"]).id == untouched.id, "camera_node's image was rebuilt, though not named"
    # The firmware is linked against the new library (a source following its branch head may differ).
    relinked = espdock("build", "--only", "firmware", cwd=root, env=double_env)
    assert relinked.returncode == 0, relinked.stdout[-2000:] + relinked.stderr
    lines = relinked.stdout.splitlines()
    assert not any("idf.py build led_strip_node" in line and "up to date" in line for line in lines), relinked.stdout
    assert any("idf.py build camera_node" in line and "up to date" in line for line in lines), relinked.stdout


def host_esptool(port: str, *args: str) -> None:
    """esptool from the test venv, straight at the mock: the test's own view of the flash."""
    tool = Path(sys.executable).with_name("esptool")
    argv = [str(tool), "--port", port, "--before", "no-reset", "--after", "no-reset", "--no-stub"]
    result = subprocess.run([*argv, *args], capture_output=True, text=True, check=False, timeout=120)
    assert result.returncode == 0, result.stdout[-2000:] + result.stderr


def flash_md5(port: str, offset: int, size: int) -> str:
    """The MD5 the board computes over SIZE bytes of its flash at OFFSET (the ROM's SPI_FLASH_MD5, as
    esptool's verify uses): what a region holds, without the ROM's 64-byte reads (5 s for 128 KiB)."""
    with detect_chip(port, connect_mode="no-reset") as esp:
        return esp.flash_md5sum(offset, size)


def read_flash(port: str, offset: int, size: int, tmp_path: Path) -> bytes:
    out = tmp_path / f"read-{offset:x}-{uuid.uuid4().hex[:6]}.bin"
    host_esptool(port, "read-flash", hex(offset), hex(size), str(out))
    return out.read_bytes()


class ArgvWatch:
    """Every command line on the machine (containers' included) that contains NEEDLE while it runs."""

    def __init__(self, needle: str) -> None:
        self.needle = needle.encode()
        self.seen: list[str] = []
        self.scans = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._watch, daemon=True)

    def _watch(self) -> None:
        while not self._stop.is_set():
            for cmdline in Path("/proc").glob("[0-9]*/cmdline"):
                try:
                    argv = cmdline.read_bytes()
                except OSError:
                    continue
                if self.needle in argv:
                    self.seen.append(argv.replace(b"\0", b" ").decode(errors="replace"))
            self.scans += 1
            time.sleep(0.005)

    def __enter__(self) -> ArgvWatch:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def files_containing(root: Path, needle: bytes) -> list[Path]:
    hits = []
    for path in root.rglob("*"):
        if path.is_file() and not path.is_symlink():
            with contextlib.suppress(OSError):
                if needle in path.read_bytes():
                    hits.append(path)
    return hits


def image_ids() -> set[str]:
    """Every image on the engine, intermediate and untagged ones too."""
    listed = subprocess.run(["docker", "images", "-aq", "--no-trunc"], capture_output=True, text=True, check=True)
    return set(listed.stdout.split())


def inspect_images(images: set[str]) -> list[dict]:
    """`docker image inspect` of IMAGES, but for any removed meanwhile (another worker's test may
    remove an image it made): any other failure to inspect one is a failure."""
    if not images:
        return []
    result = subprocess.run(["docker", "image", "inspect", *images], capture_output=True, text=True, check=False)
    found = json.loads(result.stdout or "[]")
    gone = images - {image["Id"] for image in found}
    assert all(f"No such image: {image}" in result.stderr for image in gone), result.stderr
    return found


def layers(image: dict) -> set[str]:
    return set(image["RootFS"].get("Layers") or ())


def image_metadata_contains(image: str, needle: str) -> bool:
    """Whether NEEDLE is in what IMAGE says of itself beside its layers: its config (env, labels,
    command) and its history (each layer's command and comment)."""
    inspect = subprocess.run(["docker", "image", "inspect", image], capture_output=True, text=True, check=False)
    history = subprocess.run(
        ["docker", "image", "history", "--no-trunc", "--format", "{{.CreatedBy}} {{.Comment}}", image],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    # Removed meanwhile (another worker's), it holds nothing; any other failure is a failure.
    assert inspect.returncode == 0 or "No such image" in inspect.stderr, inspect.stderr
    return needle in inspect.stdout + history.stdout


def image_layers_contain(image: str, needle: bytes) -> bool:
    """Whether NEEDLE is anywhere in `docker save IMAGE` (every layer, config and history); an image
    removed meanwhile holds nothing."""
    with subprocess.Popen(["docker", "image", "save", image], stdout=subprocess.PIPE) as save:
        tail = b""
        found = False
        while chunk := save.stdout.read(1 << 20):
            if needle in tail + chunk:
                found = True
            tail = chunk[-len(needle) :]
    if save.returncode != 0:
        # Another worker's test may remove an image it made while this one reads it: gone, it
        # holds nothing. Any other failure to read an image is a failure.
        inspect = subprocess.run(["docker", "image", "inspect", image], capture_output=True, check=False)
        assert inspect.returncode != 0, f"docker save {image} failed"
    return found


NVS_OFFSET, NVS_SIZE, APP_OFFSET = 0x9000, 0x6000, 0x10000  # IDF's single-app tables


def test_provision_and_flash_refuse_an_agent_port_the_library_would_cut(fw_ws, double_env, mock_bootloader):
    """The double's library is shaped as rmw_microxrcedds before #315 (MAX_PORT_LEN 5): port 10000 would
    reach the board as 1000, so it is refused from the library's header, and 9999 is not."""
    root, first = fw_ws
    assert first.returncode == 0
    for command in ("provision", "flash"):
        result = espdock(
            command, "camera_node", "--port", mock_bootloader, "--wifi-ssid", "lab",
            "--wifi-password-file", "/dev/null", "--agent", "10.0.0.2:10000", cwd=root, env=double_env,
        )  # fmt: skip
        assert result.returncode == 2, result.stdout[-3000:] + result.stderr
        assert "agent port 10000 does not fit camera_node's micro-ROS library" in result.stderr
        assert "would talk to port 1000" in result.stderr
        assert "esptool" not in result.stdout and "flashed" not in result.stdout


def test_provision_writes_the_network_settings_and_leaves_the_app(fw_ws, double_env, mock_bootloader, tmp_path, engine):
    root, first = fw_ws
    assert first.returncode == 0
    sentinel = f"sentinel-{uuid.uuid4().hex[:24]}"
    password_file = tmp_path / "wifi-password"
    password_file.write_text(sentinel + "\n")
    app_marker = os.urandom(4096)
    (tmp_path / "marker.bin").write_bytes(app_marker)
    host_esptool(mock_bootloader, "write-flash", hex(APP_OFFSET), str(tmp_path / "marker.bin"))
    temp_before = set(Path(tempfile.gettempdir()).glob("espdock-provision-*"))
    images_before = image_ids()
    layers_before = set().union(*map(layers, inspect_images(images_before)))

    with ArgvWatch(sentinel) as watch:
        result = espdock(
            "provision", "camera_node", "--port", mock_bootloader, "--wifi-ssid", "lab net",
            "--wifi-password-file", str(password_file), "--agent", "10.0.0.2:9999", "--domain-id", "42",
            cwd=root, env=double_env,
        )  # fmt: skip
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr
    assert "provisioned camera_node" in result.stdout
    assert watch.scans > 10 and watch.seen == [], "the password was on a command line"
    assert sentinel not in result.stdout + result.stderr
    settings = read_nvs(read_flash(mock_bootloader, NVS_OFFSET, NVS_SIZE, tmp_path))["espdock"]
    assert settings == {
        "ssid": "lab net", "password": sentinel, "agent_host": "10.0.0.2", "agent_port": 9999, "domain_id": 42,
    }  # fmt: skip

    # Moving the board to another network and agent: a second provision, no rebuild, no reflash.
    result = espdock(
        "provision", "camera_node", "--port", mock_bootloader, "--wifi-ssid", "field",
        "--wifi-password-file", "/dev/null", "--agent", "192.168.7.20:8888", cwd=root, env=double_env,
    )  # fmt: skip
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr
    settings = read_nvs(read_flash(mock_bootloader, NVS_OFFSET, NVS_SIZE, tmp_path))["espdock"]
    # No --domain-id: none written, and the board keeps the one it was built with (it was set to 0,
    # off the robot's graph, by the option's default).
    assert settings == {"ssid": "field", "password": "", "agent_host": "192.168.7.20", "agent_port": 8888}
    said = " ".join(result.stdout.split())
    # Which domain that is, by its number (the Kconfig default: camera_node's defaults set none).
    assert "ROS domain 0 as built (CONFIG_ESPDOCK_ROS_DOMAIN_ID" in said and "'field' (an open network" in said, said
    assert flash_md5(mock_bootloader, APP_OFFSET, len(app_marker)) == hashlib.md5(app_marker).hexdigest(), (
        "provision wrote the app"
    )

    assert files_containing(root, sentinel.encode()) == []
    assert set(Path(tempfile.gettempdir()).glob("espdock-provision-*")) == temp_before, "temporary files left"
    assert leftover_containers(engine, root) == []
    # The password is new to this test, so an image holding it was made since it began (tagged or
    # not, of any name), in its metadata or in a layer no image had before. Only images with such a
    # layer are read through (`docker save`, 20 s for a 770 MB ROS image): other workers' images
    # made meanwhile are mostly relabelled ones, of layers the engine already held.
    made = inspect_images(image_ids() - images_before)
    assert not [image["Id"] for image in made if image_metadata_contains(image["Id"], sentinel)]
    new_layers = [image["Id"] for image in made if layers(image) - layers_before]
    assert not [image for image in new_layers if image_layers_contain(image, sentinel.encode())]


def test_flash_with_network_options_writes_app_and_settings_in_one_run(fw_ws, double_env, mock_bootloader, tmp_path):
    root, first = fw_ws
    assert first.returncode == 0
    result = subprocess.run(
        [sys.executable, "-m", "espdock", "flash", "camera_node", "--port", mock_bootloader, "--verify",
         "--wifi-ssid", "lab", "--wifi-password-file", "-", "--agent", "10.0.0.3:8888", "--domain-id", "5"],
        input="via-stdin-pass\n", cwd=root, env={**os.environ, **double_env}, capture_output=True, text=True,
        check=False, timeout=600,
    )  # fmt: skip
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr
    assert "with its network settings" in result.stdout and "verified" in result.stdout
    assert result.stdout.count("write") >= 1 and "0x9000" in result.stdout
    settings = read_nvs(read_flash(mock_bootloader, NVS_OFFSET, NVS_SIZE, tmp_path))["espdock"]
    assert settings["password"] == "via-stdin-pass" and settings["domain_id"] == 5
    app = json.loads((firmware_dir(root, "camera_node") / "flasher_args.json").read_text())["app"]
    installed = (firmware_dir(root, "camera_node") / app["file"]).read_bytes()
    assert flash_md5(mock_bootloader, int(app["offset"], 16), len(installed)) == hashlib.md5(installed).hexdigest()


def test_bad_provisioning_input_is_refused_and_the_board_is_left_alone(fw_ws, double_env, mock_bootloader, tmp_path):
    root, first = fw_ws
    assert first.returncode == 0
    before = flash_md5(mock_bootloader, NVS_OFFSET, NVS_SIZE)
    short = tmp_path / "short"
    short.write_text("1234567\n")
    good = ("--wifi-ssid", "lab", "--wifi-password-file", "/dev/null", "--agent", "10.0.0.2:8888")
    cases = {
        "SSID is 33 bytes": ("--wifi-ssid", "x" * 33, "--wifi-password-file", "/dev/null", "--agent", "10.0.0.2:8888"),
        "password is 7 characters": ("--wifi-ssid", "lab", "--wifi-password-file", str(short), "--agent", "10.0.0.2:1"),
        "not an IPv4 address": ("--wifi-ssid", "lab", "--wifi-password-file", "/dev/null", "--agent", "agent.lan:8888"),
        "port '70000' is not 1..65535": ("--wifi-ssid", "lab", "--agent", "10.0.0.2:70000"),
        "domain id '233' is not 0..232": (*good, "--domain-id", "233"),
        "no terminal to ask on": ("--wifi-ssid", "lab", "--agent", "10.0.0.2:8888"),
    }
    for message, options in cases.items():
        result = espdock("provision", "camera_node", "--port", mock_bootloader, *options, cwd=root, env=double_env)
        assert result.returncode == 2 and message in result.stderr, (message, result.stderr)
        assert "Traceback" not in result.stderr

    table = firmware_dir(root, "camera_node") / "partition_table/partition-table.bin"
    original = table.read_bytes()
    try:  # the same app with a table that has no NVS partition
        table.write_bytes(original[32:])
        result = espdock("provision", "camera_node", "--port", mock_bootloader, *good, cwd=root, env=double_env)
        assert result.returncode == 2 and "no NVS partition labelled 'nvs' to provision" in result.stderr, result.stderr
    finally:
        table.write_bytes(original)
    assert flash_md5(mock_bootloader, NVS_OFFSET, NVS_SIZE) == before, "the board was written to"
