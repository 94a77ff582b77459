"""Which serial server a port URL (socket://, rfc2217://) reaches, whatever name or address it is
written with: what tells a flash's or monitor's port busy (Engine.device_users) and what names
its machine lock (espdock.firmware.flashing)."""

from __future__ import annotations

import re
import socket
from urllib.parse import urlsplit

# A serial port's URL in a container's command line (esptool's, idf.py's, the agent's).
PORT_URL = re.compile(r"(?i)\b(?:socket|rfc2217)://[^\s'\"]+")


def same_port_url(one: str, other: str) -> bool:
    """Whether URLs ONE and OTHER (socket://, rfc2217://) reach the same serial server: the same
    port on an address both names resolve to. Compared as text, `socket://localhost:4000` and a
    monitor's `socket://127.0.0.1:4000/` were two servers, and the second client saw a silent board."""
    first, second = _endpoint(one), _endpoint(other)
    return first is not None and second is not None and first[1] == second[1] and bool(first[0] & second[0])


def port_url_key(url: str) -> str | None:
    """A name for the serial server URL reaches, the same for every URL same_port_url takes for it
    (on this machine's view of the names)."""
    found = _endpoint(url)
    if found is None:
        return None
    addresses, port = found
    # One address of those it resolves to, the same for a name and its literal address (a bridge
    # named esp-bridge.lan with an A and an AAAA record, and 192.168.1.50).
    ipv4 = sorted(a for a in addresses if "." in a and ":" not in a)
    return f"{_THIS_MACHINE if _THIS_MACHINE in addresses else (ipv4 or sorted(addresses))[0]}-{port}"


# What a client on this machine reaches as this machine: one name for all of them (a dual-stack
# server on ::1 is the one on 127.0.0.1).
_THIS_MACHINE = "loopback"


def _endpoint(url: str) -> tuple[frozenset[str], int] | None:
    import ipaddress

    parts = urlsplit(url.strip())
    try:
        port = parts.port
    except ValueError:
        return None
    host = parts.hostname
    if not host or port is None:
        return None
    try:
        found = {str(info[4][0]).partition("%")[0] for info in socket.getaddrinfo(host, port, type=socket.SOCK_STREAM)}
    except (OSError, UnicodeError):
        found = {host}
    addresses = set()
    for text in found:
        try:
            address = ipaddress.ip_address(text)
        except ValueError:
            addresses.add(text)
            continue
        if isinstance(address, ipaddress.IPv6Address) and address.ipv4_mapped is not None:
            address = address.ipv4_mapped  # ::ffff:127.0.0.1 is 127.0.0.1
        # A client connecting to "any address" (0, 0.0.0.0, ::) reaches this machine.
        addresses.add(_THIS_MACHINE if address.is_loopback or address.is_unspecified else str(address))
    return frozenset(addresses), port
