"""`espdock agent`: the micro-ROS agent for a board on a serial line (or on Wi-Fi)."""

from __future__ import annotations

import os
import sys
from contextlib import nullcontext
from typing import Annotated

import typer

from espdock.cli.core import app, command, notify
from espdock.errors import ImageBuildError
from espdock.firmware.agent import DEFAULT_BAUD, DEFAULT_UDP_PORT, agent_spec
from espdock.firmware.flashing import check_port, parse_port, port_held
from espdock.images import bootstrap
from espdock.layout import MICRO_ROS_AGENT_IMAGE


@app.command()
@command
def agent(
    port: Annotated[
        str | None,
        typer.Option(
            "--port", "-p", help="The board's serial device (/dev/ttyACM0, /dev/ttyUSB0); without it: UDP (Wi-Fi)."
        ),
    ] = None,
    baud: Annotated[int, typer.Option("--baud", "-b", help="The firmware's CONFIG_ESPDOCK_UART_BAUD.")] = DEFAULT_BAUD,
    udp_port: Annotated[int, typer.Option(help="UDP port for boards on Wi-Fi (without --port).")] = DEFAULT_UDP_PORT,
    domain_id: Annotated[
        int | None,
        typer.Option(
            help="The agent's own ROS_DOMAIN_ID (default: the environment's); a board's entities are in the "
            "domain it was provisioned with."
        ),
    ] = None,
    image: Annotated[str, typer.Option(help="The micro-ROS agent image.")] = MICRO_ROS_AGENT_IMAGE,
) -> None:
    """Run the micro-ROS agent in a container until Ctrl-C, passing in only the board's device
    (no privileges), on the host's network, where the host's ROS 2 nodes see its topics."""
    serial = parse_port(port) if port is not None else None
    spec = agent_spec(image, serial, os.environ, baud, udp_port, domain_id, sys.stdin.isatty() and sys.stdout.isatty())
    if serial is not None:
        check_port(serial, urls=False)
    engine = bootstrap.ensure_engine(os.environ, notify)
    with port_held(engine, serial) if serial is not None else nullcontext():
        if engine.image(image) is None and not engine.pull(image):
            raise ImageBuildError(  # as a missing IDF image is
                f"the agent image {image} is not here and could not be pulled",
                f"Pull it where a registry is reachable (`docker pull {image}`), or give another with --image.",
            )
        code, stopped_by = engine.run_foreground(spec)
    raise typer.Exit(128 + stopped_by if stopped_by else code)
