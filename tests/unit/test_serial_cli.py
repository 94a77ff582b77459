"""`espdock new --transport` and what provisioning says of a serial board, through the CLI."""

import json
import re

import pytest

from tests.conftest import copy_workspace, espdock

NO_ENGINE = {"DOCKER_HOST": "unix:///nonexistent/docker.sock"}


def library_keys(plan: str) -> dict[str, str]:
    steps = " ".join(plan.split())
    return dict(re.findall(r"idf\.py build (\w+) in espdock/idf-micro-ros-jazzy-\w+:(\S+)", steps))


def test_new_serial_packages_need_no_wifi_and_get_a_custom_transport_library(tmp_path):
    root = copy_workspace(tmp_path / "w")
    for name, args in {
        "wifi_board": (),
        "uart_board": ("--transport", "serial"),
        "usb_board": ("--transport", "usb-serial-jtag"),
    }.items():
        created = espdock("new", name, *args, "--target", "esp32c3", cwd=root, env=NO_ENGINE)
        assert created.returncode == 0, created.stderr
    uart = (root / "firmware/uart_board/sdkconfig.defaults").read_text()
    assert "CONFIG_ESPDOCK_TRANSPORT_UART=y" in uart and "CONFIG_MICRO_ROS_ESP_UART_TRANSPORT=y" in uart
    assert "NETIF_WLAN" not in uart and "espdock provision" not in uart
    usb = (root / "firmware/usb_board/sdkconfig.defaults").read_text()
    assert "CONFIG_ESPDOCK_TRANSPORT_USB_SERIAL_JTAG=y" in usb and 'CONFIG_IDF_TARGET="esp32c3"' in usb
    meta = json.loads((root / "firmware/uart_board/app-colcon.meta").read_text())
    assert "-DRMW_UXRCE_TRANSPORT=custom" in meta["names"]["rmw_microxrcedds"]["cmake-args"]
    wifi = (root / "firmware/wifi_board/sdkconfig.defaults").read_text()
    assert "CONFIG_MICRO_ROS_ESP_NETIF_WLAN=y" in wifi and "ESPDOCK_TRANSPORT" not in wifi

    plan = espdock("build", "--dry-run", cwd=root, env=NO_ENGINE)
    assert plan.returncode == 0, plan.stderr
    keys = library_keys(plan.stdout)
    assert keys.keys() == {"wifi_board", "uart_board", "usb_board"}, plan.stdout
    # Two libraries for three boards: UDP, and one custom-transport library both serial boards share.
    assert keys["uart_board"] == keys["usb_board"] != keys["wifi_board"]


def test_new_refuses_an_unknown_transport_and_usb_on_a_chip_without_it(tmp_path):
    root = copy_workspace(tmp_path / "w")
    unknown = espdock("new", "board", "--transport", "bluetooth", cwd=root, env=NO_ENGINE)
    assert unknown.returncode == 2 and "unknown transport 'bluetooth'" in unknown.stderr
    no_usb = espdock("new", "board", "--transport", "usb-serial-jtag", "--target", "esp32", cwd=root, env=NO_ENGINE)
    assert no_usb.returncode == 2 and "esp32 has no USB-Serial-JTAG port" in no_usb.stderr
    assert "Use --transport uart" in no_usb.stderr and "sdkconfig" not in no_usb.stderr, "no package to edit yet"
    # No --target: the workspace's chip (esp32) is the package's, and has no such port either.
    implied = espdock("new", "board", "--transport", "usb-serial-jtag", cwd=root, env=NO_ENGINE)
    assert implied.returncode == 2 and "esp32 has no USB-Serial-JTAG port" in implied.stderr, implied.stderr
    assert "Traceback" not in unknown.stderr + no_usb.stderr
    assert not (root / "firmware/board").exists()


def test_provisioning_a_serial_board_says_there_is_nothing_to_provision(tmp_path):
    root = copy_workspace(tmp_path / "w")
    assert espdock("new", "board", "--transport", "uart", cwd=root, env=NO_ENGINE).returncode == 0
    for argv in (
        ("provision", "board", "--port", "/dev/ttyUSB0"),
        ("provision", "board", "--port", "/dev/ttyUSB0", "--wifi-ssid", "lab", "--agent", "10.0.0.2:8888"),
        ("flash", "board", "--port", "/dev/ttyUSB0", "--wifi-ssid", "lab", "--agent", "10.0.0.2:8888"),
        # A domain alone is a provisioning setting too: it was answered with "needs both --wifi-ssid
        # and --agent", which a serial board cannot take.
        ("flash", "board", "--port", "/dev/ttyUSB0", "--domain-id", "3"),
        ("flash", "board", "--port", "/dev/ttyUSB0", "--wifi-password-file", "-"),
    ):
        result = espdock(*argv, cwd=root, env=NO_ENGINE)
        assert result.returncode == 2, (argv, result.stderr)
        text = " ".join(result.stderr.split())
        assert "board reaches the micro-ROS agent over uart" in text and "nothing to provision" in text.lower()
        assert "espdock agent --port" in text
        assert "CONFIG_ESPDOCK_ROS_DOMAIN_ID" in text, "where a serial board's domain is set"
        assert "its sdkconfig.defaults sets CONFIG_ESPDOCK_TRANSPORT_UART=y" in text, "the file to edit"
    # The file named is the one that chose, wherever the CMakeLists puts the choice.
    project = root / "firmware/board"
    defaults = project / "sdkconfig.defaults"
    (project / "sdkconfig.serial").write_text(defaults.read_text())
    defaults.write_text(defaults.read_text().replace("CONFIG_ESPDOCK_TRANSPORT_UART=y", ""))
    cmake = project / "CMakeLists.txt"
    cmake.write_text(
        cmake.read_text().replace(
            "project(", 'set(SDKCONFIG_DEFAULTS "sdkconfig.defaults;sdkconfig.serial")\nproject(', 1
        )
    )
    result = espdock("provision", "board", "--port", "/dev/ttyUSB0", cwd=root, env=NO_ENGINE)
    assert result.returncode == 2 and "its sdkconfig.serial sets" in " ".join(result.stderr.split()), result.stderr


def test_provision_of_a_wifi_board_still_asks_for_its_settings(tmp_path):
    root = copy_workspace(tmp_path / "w")
    assert espdock("new", "board", cwd=root, env=NO_ENGINE).returncode == 0
    result = espdock("provision", "board", "--port", "/dev/ttyUSB0", cwd=root, env=NO_ENGINE)
    assert result.returncode == 2 and "needs --wifi-ssid and --agent" in result.stderr


def test_the_starter_compose_runs_a_serial_agent_with_only_the_board_s_device(tmp_path):
    """`espdock init`'s compose.yaml as real Compose resolves it (`docker compose config`: no engine)."""
    import os
    import shutil
    import subprocess

    import pytest

    from espdock.ros.compose import starter_compose

    if not shutil.which("docker"):
        pytest.skip("the docker CLI is not on PATH")
    (tmp_path / "compose.yaml").write_text(starter_compose("robot", "espdock/robot:latest", {"talk": ["talker"]}))
    env = {k: v for k, v in os.environ.items() if not k.startswith(("MICROROS_", "ROS_DOMAIN_ID"))}

    def config(*args: str, **extra: str) -> dict:
        result = subprocess.run(
            ["docker", "compose", "--project-directory", str(tmp_path), *args, "config", "--format", "json"],
            capture_output=True, text=True, env={**env, **extra}, check=False,
        )  # fmt: skip
        if "is not a docker command" in result.stderr:
            pytest.skip("`docker compose` (v2) is missing")
        assert result.returncode == 0, result.stderr
        return json.loads(result.stdout)["services"]

    agent = config("--profile", "serial", MICROROS_SERIAL_DEVICE="/dev/ttyACM1", ROS_DOMAIN_ID="5")[
        "micro_ros_agent_serial"
    ]
    assert agent["command"] == ["serial", "--dev", "/dev/microros", "-b", "115200"]
    assert [(d["source"], d["target"]) for d in agent["devices"]] == [("/dev/ttyACM1", "/dev/microros")]
    assert not agent.get("privileged") and not agent.get("cap_add")
    assert agent["environment"]["ROS_DOMAIN_ID"] == "5"
    assert "micro_ros_agent_serial" not in config() and "micro_ros_agent_serial" not in config("--profile", "hardware")


def test_the_agent_command_refuses_what_the_agent_cannot_open_before_touching_the_engine(tmp_path):
    url = espdock("agent", "--port", "socket://127.0.0.1:4000", cwd=tmp_path, env=NO_ENGINE)
    assert url.returncode == 2 and "opens serial devices only" in url.stderr
    missing = espdock("agent", "--port", str(tmp_path / "ttyACM7"), cwd=tmp_path, env=NO_ENGINE)
    assert missing.returncode == 6 and "does not exist" in missing.stderr
    baud = espdock("agent", "--port", "/dev/ttyACM0", "--baud", "0", cwd=tmp_path, env=NO_ENGINE)
    assert baud.returncode == 2 and "--baud 0 is not a baud rate" in baud.stderr
    assert "Traceback" not in url.stderr + missing.stderr + baud.stderr


def test_the_agent_s_arguments_are_micro_ros_agent_s_own():
    from espdock.firmware.agent import agent_spec
    from espdock.firmware.flashing import parse_port

    spec = agent_spec("img", parse_port("/dev/ttyACM0"), {"ROS_DOMAIN_ID": "3", "HOME": "/root"}, baud=921600)
    assert spec.argv == ("serial", "--dev", "/dev/ttyACM0", "-b", "921600")
    assert spec.devices == ("/dev/ttyACM0",) and spec.network == "host" and spec.user is None
    assert dict(spec.env) == {"ROS_DOMAIN_ID": "3", "FASTDDS_BUILTIN_TRANSPORTS": "UDPv4"}
    udp = agent_spec("img", None, {}, domain_id=9)
    assert udp.argv == ("udp4", "--port", "8888") and udp.devices == () and dict(udp.env)["ROS_DOMAIN_ID"] == "9"
    # What the agent would not use, or rmw would refuse in its container, is said first.
    from espdock.errors import ConfigError

    with pytest.raises(ConfigError, match="--udp-port 9999 goes with boards on Wi-Fi"):
        agent_spec("img", parse_port("/dev/ttyACM0"), {}, udp_port=9999)
    for bad in ("300", "abc", "\u00b2"):  # "²": str.isdigit() took it, and int() then raised
        with pytest.raises(ConfigError, match=f"ROS_DOMAIN_ID={bad} \\(from the environment\\)"):
            agent_spec("img", None, {"ROS_DOMAIN_ID": bad})
    assert dict(agent_spec("img", None, {"ROS_DOMAIN_ID": "232"}).env)["ROS_DOMAIN_ID"] == "232"


def test_flash_and_monitor_take_the_port_and_baud_idf_py_takes_from_the_environment(tmp_path):
    """ESPPORT (and ESPBAUD), which idf.py and an IDF developer's shell use: `espdock idf -- flash`
    took them, `espdock flash` and `monitor` asked for --port."""
    root = copy_workspace(tmp_path / "w")
    for command in ("flash", "monitor"):
        asked = espdock(command, "led_strip_node", cwd=root, env=NO_ENGINE)
        assert asked.returncode == 2 and "Missing option '--port'" in asked.stderr, asked.stderr
        given = espdock(command, "led_strip_node", cwd=root, env={**NO_ENGINE, "ESPPORT": "/dev/espdock-none"})
        assert "Missing option" not in given.stderr, given.stderr  # on to what the port or firmware says
    baud = espdock("flash", "led_strip_node", cwd=root, env={**NO_ENGINE, "ESPPORT": "/dev/x", "ESPBAUD": "fast"})
    assert "Invalid value for '--baud'" in baud.stderr, baud.stderr
    for rate in ("0", "-5"):
        for command in ("flash", "provision"):
            none = espdock(command, "led_strip_node", "--port", "/dev/x", "--baud", rate, cwd=root, env=NO_ENGINE)
            assert none.returncode == 2 and f"--baud {rate} is not a baud rate" in none.stderr, none.stderr
    from_env = espdock("flash", "led_strip_node", "--port", "/dev/x", cwd=root, env={**NO_ENGINE, "ESPBAUD": "0"})
    assert from_env.returncode == 2 and "ESPBAUD=0 is not a baud rate" in from_env.stderr, from_env.stderr


def test_a_wifi_board_s_installed_firmware_is_provisionable_whatever_its_sources_say_now(tmp_path):
    """The board runs what was installed: sources switched to a serial link since do not refuse it."""
    from espdock.errors import ConfigError
    from espdock.firmware.transport import TRANSPORT_RECORD, check_provisionable

    project = tmp_path / "board"
    project.mkdir()
    (project / "sdkconfig.defaults").write_text("CONFIG_ESPDOCK_TRANSPORT_UART=y\n")
    installed = tmp_path / "firmware"
    installed.mkdir()
    with pytest.raises(ConfigError, match=r"its sdkconfig\.defaults sets CONFIG_ESPDOCK_TRANSPORT_UART=y"):
        check_provisionable("board", project, "esp32", installed)  # nothing recorded: the sources decide
    (installed / TRANSPORT_RECORD).write_text('{"transport": "udp"}\n')
    check_provisionable("board", project, "esp32", installed)
