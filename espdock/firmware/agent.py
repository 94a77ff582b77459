"""The micro-ROS agent for a board: what `espdock agent` runs, as data (no engine here).

The agent image (microros/micro-ros-agent) runs `ros2 run micro_ros_agent micro_ros_agent "$@"`
from its entrypoint, so the container's command is the agent's own: `serial --dev DEV -b BAUD`
for a board on a serial line, `udp4 --port PORT` for one on Wi-Fi.
"""

from __future__ import annotations

import os
import secrets
from collections.abc import Mapping

from espdock.errors import ConfigError
from espdock.firmware.flashing import Port
from espdock.firmware.provision import DOMAIN_ID_MAX, is_domain_id
from espdock.images.specs import RunSpec

# micro_ros_agent's default and the firmware's (CONFIG_ESPDOCK_UART_BAUD).
DEFAULT_BAUD = 115200
DEFAULT_UDP_PORT = 8888
# The environment the compose files give the agent: Fast DDS over UDP only (shared memory does
# not cross containers), the ROS domain of the rest of the graph.
PASSED_ENV = ("ROS_DOMAIN_ID", "RMW_IMPLEMENTATION", "FASTDDS_BUILTIN_TRANSPORTS")


def agent_argv(port: Port | None, baud: int = DEFAULT_BAUD, udp_port: int = DEFAULT_UDP_PORT) -> tuple[str, ...]:
    """micro_ros_agent's arguments for a board on PORT (None: boards on Wi-Fi, over UDP)."""
    if port is None:
        if not 1 <= udp_port <= 65535:
            raise ConfigError(f"--udp-port {udp_port} is not 1..65535")
        return ("udp4", "--port", str(udp_port))
    if port.is_url:
        raise ConfigError(
            f"the micro-ROS agent cannot use {port.spec}: it opens serial devices only",
            "Give the board's device, e.g. --port /dev/ttyACM0 (USB-Serial-JTAG) or /dev/ttyUSB0 (a USB-UART bridge).",
        )
    if baud <= 0:
        raise ConfigError(f"--baud {baud} is not a baud rate", f"The firmware's default is {DEFAULT_BAUD}.")
    return ("serial", "--dev", str(port.device), "-b", str(baud))


def agent_spec(
    image: str,
    port: Port | None,
    env: Mapping[str, str],
    baud: int = DEFAULT_BAUD,
    udp_port: int = DEFAULT_UDP_PORT,
    domain_id: int | None = None,
    tty: bool = False,
) -> RunSpec:
    """The agent's container: only PORT's device passed in (no privileges), on the host's network
    so that its DDS side meets the host's ROS graph (and a UDP agent is reachable by the boards)."""
    if port is not None and udp_port != DEFAULT_UDP_PORT:
        # A serial agent listens on no UDP port: the option went unused without a word.
        raise ConfigError(
            f"--udp-port {udp_port} goes with boards on Wi-Fi, and --port {port.spec} makes a serial agent",
            "Leave one out: --port for a board on serial, --udp-port for boards on Wi-Fi (one agent each).",
        )
    settings = {name: env[name] for name in PASSED_ENV if name in env}
    settings.setdefault("FASTDDS_BUILTIN_TRANSPORTS", "UDPv4")
    if domain_id is not None:
        if not 0 <= domain_id <= DOMAIN_ID_MAX:
            raise ConfigError(f"--domain-id {domain_id} is not 0..{DOMAIN_ID_MAX}")
        settings["ROS_DOMAIN_ID"] = str(domain_id)
    elif (given := settings.get("ROS_DOMAIN_ID", "").strip()) and not is_domain_id(given):
        # As --domain-id is checked: the agent's rmw refused it inside the container, or took another.
        raise ConfigError(
            f"ROS_DOMAIN_ID={given} (from the environment) is not a ROS domain id 0..{DOMAIN_ID_MAX}",
            "Set it to one, or give --domain-id.",
        )
    return RunSpec(
        image=image,
        argv=agent_argv(port, baud, udp_port),
        workdir="/",
        env=tuple(sorted(settings.items())),
        labels=(("io.espdock.role", "micro-ros-agent"),),
        devices=port.devices if port is not None else (),
        network="host",
        tty=tty,
        name=f"espdock-agent-{os.getpid()}-{secrets.token_hex(4)}",
    )
