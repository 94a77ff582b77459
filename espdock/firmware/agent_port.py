"""Whether the micro-ROS library of a firmware build keeps every digit of an agent port.

rmw_microxrcedds copies the agent port into char[MAX_PORT_LEN] with snprintf(.., MAX_PORT_LEN, ..)
(rmw_microxrcedds_c/src/rmw_microros/init_options.c), so it keeps MAX_PORT_LEN - 1 digits:
MAX_PORT_LEN is 5 before micro-ROS/rmw_microxrcedds#315 (issue #314: ports of 10000 and up are cut
to port/10, and the board talks to another port) and 6 after it. The board refuses such a port at
run time (espdock_uros_setup); provisioning refuses it first, from the library's own header.
"""

from __future__ import annotations

import re

from espdock.errors import ConfigError

# Where the IDF image keeps the header (include/<package>/<package>/, as libmicroros.mk installs
# ROS 2 headers from Humble on; the flat include/<package>/ of older trees as a fallback).
_COMPONENT = "/opt/espdock/micro_ros_espidf_component/include"
LIBRARY_HEADERS = (
    f"{_COMPONENT}/rmw_microros/rmw_microros/rmw_microros.h",
    f"{_COMPONENT}/rmw_microros/rmw_microros.h",
)
_MAX_PORT_LEN = re.compile(r"^[ \t]*#[ \t]*define[ \t]+MAX_PORT_LEN[ \t]+\(?[ \t]*([0-9]+)[ \t]*\)?[ \t]*$", re.M)


def port_digits_kept(header: str) -> int | None:
    """The digits of an agent port the library whose rmw_microros.h is HEADER keeps (None: not stated)."""
    match = _MAX_PORT_LEN.search(header)
    return int(match.group(1)) - 1 if match else None


def check_agent_port(port: int, header: str, package: str) -> None:
    """A ConfigError (exit 2) when PACKAGE's library, by its rmw_microros.h HEADER, would cut PORT."""
    kept = port_digits_kept(header)
    if kept is None or len(str(port)) <= kept:
        return
    cut = str(port)[:kept] if kept > 0 else "nothing"
    raise ConfigError(
        f"agent port {port} does not fit {package}'s micro-ROS library: its rmw_microxrcedds keeps {kept} digits "
        f"of a port (MAX_PORT_LEN {kept + 1}, before micro-ROS/rmw_microxrcedds#315), so the board would talk "
        f"to port {cut}, and it refuses the port",
        "Run the agent on a port below 10000 (micro_ros_agent's default is 8888), or pin a rmw_microxrcedds "
        "commit with #315 in docker/idf/micro_ros_sources.txt and build again.",
    )
