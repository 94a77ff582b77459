"""compose.yaml as Compose resolves it (`docker compose config`: the CLI only, no engine, no images)."""

from __future__ import annotations

import json
import os
import shutil
import subprocess

import pytest
import yaml

from demo_stack import COMPOSE_FILE, ROOT
from demo_support import need
from espdock_demo.health import HARDWARE_NODES

ROS_SERVICES = ("camera_sim", "led_strip_sim", "qr_detector", "camera_ui", "demo")


def config(*args: str, **env: str) -> dict:
    need(None if shutil.which("docker") else "the docker CLI is not on PATH (run `make setup`)")
    clean = {k: v for k, v in os.environ.items() if not k.startswith(("ESPDOCK_DEMO_", "ROS_DOMAIN_ID"))}
    result = subprocess.run(
        [
            "docker",
            "compose",
            "-f",
            str(COMPOSE_FILE),
            "--project-directory",
            str(ROOT),
            *args,
            "config",
            "--format",
            "json",
        ],
        capture_output=True,
        text=True,
        env={**clean, **env},
        check=False,
    )
    if result.returncode != 0 and "is not a docker command" in result.stderr:
        need("`docker compose` (v2) is missing (run `espdock setup`)")
    assert result.returncode == 0, result.stderr
    return json.loads(result.stdout)


def test_up_demo_brings_every_node_and_the_console_starts_with_them():
    """The console reports the nodes coming up itself: waiting for their first healthcheck
    would hold it back 10 s."""
    services = config("--profile", "sim")["services"]
    assert set(ROS_SERVICES) <= services.keys()
    assert "micro_ros_agent" not in services
    assert {name: dep["condition"] for name, dep in services["demo"]["depends_on"].items()} == {
        "camera_sim": "service_started",
        "led_strip_sim": "service_started",
        "qr_detector": "service_started",
        "camera_ui": "service_started",
    }


def test_the_hardware_profile_is_valid_and_leaves_the_simulators_out():
    services = config("--profile", "hardware")["services"]
    assert "camera_sim" not in services and "led_strip_sim" not in services
    agent = services["micro_ros_agent"]
    assert agent["image"] == "microros/micro-ros-agent:jazzy"
    assert agent["command"] == ["udp4", "--port", "8888"]
    assert agent["ports"][0]["target"] == 8888 and agent["ports"][0]["protocol"] == "udp"
    assert {"qr_detector", "camera_ui", "demo-hardware"} <= services.keys()
    # Its console watches the nodes that run in containers: it waited for the simulators, never there.
    command = services["demo-hardware"]["command"]
    watched = [arg.removeprefix("watch_nodes:=") for arg in command if arg.startswith("watch_nodes:=")]
    assert [yaml.safe_load(value) for value in watched] == [list(HARDWARE_NODES)], command


def test_every_node_restarts_after_a_crash_has_a_healthcheck_and_talks_udp_only():
    services = config("--profile", "sim", ROS_DOMAIN_ID="42")["services"]
    for name in ROS_SERVICES:
        service = services[name]
        assert service["restart"] == "unless-stopped", name
        assert service["healthcheck"]["test"][:2] == ["CMD", "python"], name
        assert service["environment"]["FASTDDS_BUILTIN_TRANSPORTS"] == "UDPv4", name
        assert service["environment"]["ROS_DOMAIN_ID"] == "42", name
        assert service["image"] == services["qr_detector"]["image"]


def test_the_ui_is_published_on_localhost_8080_unless_told_otherwise():
    (port,) = config()["services"]["camera_ui"]["ports"]
    assert (port["host_ip"], port["published"], port["target"]) == ("127.0.0.1", "8080", 8080)
    (port,) = config(ESPDOCK_DEMO_BIND="0.0.0.0", ESPDOCK_DEMO_PORT="9000")["services"]["camera_ui"]["ports"]
    assert (port["host_ip"], port["published"]) == ("0.0.0.0", "9000")


def test_every_node_runs_the_runtime_image_espdock_build_makes_and_compose_builds_none():
    services = config("--profile", "*")["services"]
    for name, service in services.items():
        if not name.startswith("micro_ros_agent"):
            assert service["image"] == "espdock/demo:latest", name
            assert "build" not in service, name


@pytest.mark.parametrize("profile", ["sim", "hardware", "test"])
def test_each_profile_resolves(profile):
    assert config("--profile", profile)["services"]


def test_the_control_path_runs_first_when_the_cpu_is_contended_and_nothing_is_starved():
    """The detector, the LED node and the agent outweigh every other service 32 to 1 (the latency
    benchmark's tail came from the UI and the console waking on the same frames and texts), and no
    service is below Docker's default weight (1024 where a service sets none): below it, the UI
    streamed 4 fps instead of 30 beside four busy containers."""
    services = config("--profile", "*")["services"]
    weight = {name: service.get("cpu_shares", 1024) for name, service in services.items()}
    control = {"qr_detector", "led_strip_sim", "micro_ros_agent", "micro_ros_agent_serial"}
    others = services.keys() - control
    assert min(weight[name] for name in control) >= 32 * max(weight[name] for name in others), weight
    assert min(weight.values()) >= 1024, weight


def test_the_serial_agent_gets_only_the_board_s_device_and_no_privileges():
    """A board on USB (espdock new --transport serial): `--profile hardware --profile serial`."""
    services = config("--profile", "hardware", "--profile", "serial", MICROROS_SERIAL_DEVICE="/dev/ttyUSB3")["services"]
    agent = services["micro_ros_agent_serial"]
    assert agent["image"] == "microros/micro-ros-agent:jazzy"
    assert agent["command"] == ["serial", "--dev", "/dev/microros", "-b", "115200"]
    (device,) = agent["devices"]
    assert (device["source"], device["target"]) == ("/dev/ttyUSB3", "/dev/microros")
    assert not agent.get("privileged") and not agent.get("cap_add") and "volumes" not in agent
    assert {"micro_ros_agent", "qr_detector", "demo-hardware"} <= services.keys()
    assert "micro_ros_agent_serial" not in config("--profile", "hardware")["services"]
    baud = config("--profile", "serial", MICROROS_SERIAL_BAUD="921600")["services"]["micro_ros_agent_serial"]
    assert baud["command"][-1] == "921600"
