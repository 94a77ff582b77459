"""Serial-transport firmware built against the IDF contract double with the real Dockerfile.idf:
its own custom-transport library, and the double refusing what ESP-IDF would."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest

from espdock.config import Config, resolve_ca_bundle
from espdock.layout import firmware_install_dir
from tests.conftest import REPO, copy_workspace, espdock
from tests.idf_contract_double.build import use_double

pytestmark = [pytest.mark.engine, pytest.mark.slow]

RMW_CONFIG = "/opt/espdock/micro_ros_espidf_component/include/rmw_microxrcedds_c/rmw_microxrcedds_c/config.h"


def micro_ros_image(root: Path, env: dict[str, str], package: str) -> str:
    plan = espdock("build", package, "--dry-run", cwd=root, env=env)
    assert plan.returncode == 0, plan.stderr
    (tag,) = re.findall(rf"idf\.py build {package}\S* in (espdock/idf-micro-ros-\S+)", " ".join(plan.stdout.split()))
    return tag


def in_image(image: str, project: Path, *argv: str, env: tuple[str, ...] = ()) -> subprocess.CompletedProcess:
    extra = [arg for item in env for arg in ("-e", item)]
    return subprocess.run(
        ["docker", "run", "--rm", "-e", "HOME=/tmp", *extra, "-v", f"{project.parent}:/src", image,
         "idf.py", "-C", f"/src/{project.name}", "-B", "/tmp/build", *argv],
        capture_output=True, text=True, check=False,
    )  # fmt: skip


@pytest.fixture(scope="module")
def serial_ws(tmp_path_factory, engine):
    root = copy_workspace(tmp_path_factory.mktemp("serial") / "ws-root")
    shutil.copy2(REPO / "Dockerfile.idf", root / "Dockerfile.idf")
    env = use_double(engine, resolve_ca_bundle(Config(), os.environ), lambda line: None, root)
    for name, link in (("uart_board", "uart"), ("usb_board", "usb-serial-jtag")):
        made = espdock("new", name, "--transport", link, "--target", "esp32c3", cwd=root, env=env)
        assert made.returncode == 0, made.stderr
    built = espdock("build", "uart_board", "usb_board", "--only", "firmware", cwd=root, env=env)
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr
    yield root, env
    engine.remove_containers({"io.espdock.workspace": str(root)})


def test_serial_boards_build_against_one_custom_transport_library(serial_ws):
    root, env = serial_ws
    for name, symbol in (("uart_board", "UART"), ("usb_board", "USB_SERIAL_JTAG")):
        assert (root / "ws" / firmware_install_dir(name) / f"{name}.bin").is_file()
        sdkconfig = (root / f"ws/build/{name}/sdkconfig").read_text()
        assert f"CONFIG_ESPDOCK_TRANSPORT_{symbol}=y" in sdkconfig and "CONFIG_ESPDOCK_TRANSPORT_SERIAL=y" in sdkconfig
    image = micro_ros_image(root, env, "uart_board")
    assert image == micro_ros_image(root, env, "usb_board")
    config = subprocess.run(
        ["docker", "run", "--rm", image, "cat", RMW_CONFIG], capture_output=True, text=True, check=False
    )
    assert "#define RMW_UXRCE_TRANSPORT_CUSTOM" in config.stdout and "TRANSPORT_UDP" not in config.stdout


def test_the_double_refuses_usb_serial_jtag_on_an_esp32_and_a_library_of_the_other_transport(serial_ws, tmp_path):
    root, env = serial_ws
    image = micro_ros_image(root, env, "usb_board")
    # The same project for an esp32 (no USB-Serial-JTAG): ESP-IDF compiles espdock_transport.c into its #error.
    project = tmp_path / "usb_board"
    shutil.copytree(root / "firmware/usb_board", project)
    shutil.copytree(root / "firmware/components", tmp_path / "components")
    defaults = project / "sdkconfig.defaults"
    defaults.write_text(defaults.read_text().replace('CONFIG_IDF_TARGET="esp32c3"', ""))
    esp32 = in_image(image, project, "build", env=("IDF_TARGET=esp32",))
    assert esp32.returncode == 2, esp32.stdout[-3000:]
    assert "this chip has no USB-Serial-JTAG port" in esp32.stdout + esp32.stderr
    # A UDP build of it in this custom-transport library's image fails on the mismatch, not at run time.
    (project / "sdkconfig").unlink(missing_ok=True)
    defaults.write_text(
        defaults.read_text().replace("CONFIG_ESPDOCK_TRANSPORT_USB_SERIAL_JTAG=y", "CONFIG_ESPDOCK_TRANSPORT_UDP=y")
    )
    udp = in_image(image, project, "build", env=("IDF_TARGET=esp32c3",))
    assert udp.returncode == 2, udp.stdout[-3000:]
    assert "not built with RMW_UXRCE_TRANSPORT=udp" in udp.stdout + udp.stderr
    # Where the fix is: menuconfig's choice alone reaches the app, not the library (it named app-colcon.meta).
    assert "choose the transport in sdkconfig.defaults" in udp.stdout + udp.stderr
    # And as it is, for its own chip, it builds.
    (project / "sdkconfig").unlink(missing_ok=True)
    defaults.write_text(
        defaults.read_text().replace("CONFIG_ESPDOCK_TRANSPORT_UDP=y", "CONFIG_ESPDOCK_TRANSPORT_USB_SERIAL_JTAG=y")
    )
    usb = in_image(image, project, "build", env=("IDF_TARGET=esp32c3",))
    assert usb.returncode == 0, usb.stdout[-3000:] + usb.stderr


def test_provisioning_asks_the_installed_firmware_not_the_sources_edited_since(serial_ws):
    """A serial board whose sources were switched to Wi-Fi but not rebuilt still runs its UART
    firmware: provisioning it would erase its NVS for settings it never reads."""
    root, env = serial_ws
    defaults, meta = (root / "firmware/uart_board" / name for name in ("sdkconfig.defaults", "app-colcon.meta"))
    kept = {path: path.read_text() for path in (defaults, meta)}
    defaults.write_text(kept[defaults].replace("CONFIG_ESPDOCK_TRANSPORT_UART=y", "CONFIG_ESPDOCK_TRANSPORT_UDP=y"))
    # The whole switch: a serial library's argument left in the meta stops the flash on its own.
    meta.write_text(kept[meta].replace(',\n        "-DRMW_UXRCE_TRANSPORT=custom"', ""))
    try:
        for argv in (
            ("provision", "uart_board", "--port", "/dev/ttyUSB0", "--wifi-ssid", "lab", "--agent", "10.0.0.2:8888"),
            ("flash", "uart_board", "--port", "/dev/ttyUSB0", "--wifi-ssid", "lab", "--agent", "10.0.0.2:8888"),
        ):
            result = espdock(*argv, cwd=root, env=env)
            text = " ".join(result.stderr.split())
            assert result.returncode == 2, (argv, result.stdout, result.stderr)
            assert "uart_board reaches the micro-ROS agent over uart" in text, text
            assert "its installed firmware was built with CONFIG_ESPDOCK_TRANSPORT_UART=y" in text, text
    finally:
        for path, text in kept.items():
            path.write_text(text)
