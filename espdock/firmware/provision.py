"""A board's network settings, written into its NVS partition at flash time.

The firmware (components/espdock_uros, net_settings.h) reads the namespace and
keys below at boot and falls back to its Kconfig options for what is absent, so
one build serves every network and every agent address, and no build carries the
Wi-Fi password.

The image replaces the whole NVS partition: whatever else the board kept there (other
namespaces, Wi-Fi calibration the app stored) is erased.

The password is held in memory, in a CSV and the NVS image generated from it (both 0600
from their creation), both in a private temporary directory outside the workspace that is
removed on success, failure and Ctrl-C alike; it is never part of a command line.
"""

from __future__ import annotations

import contextlib
import csv
import io
import ipaddress
import json
import os
import re
import shutil
import struct
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

from espdock import scratch
from espdock.errors import ConfigError, EspdockError, WorkspaceError

# The firmware's side of the contract: firmware/components/espdock_uros/include/net_settings.h.
NVS_NAMESPACE = "espdock"
KEY_SSID, KEY_PASSWORD, KEY_AGENT_HOST, KEY_AGENT_PORT, KEY_DOMAIN_ID = (
    "ssid", "password", "agent_host", "agent_port", "domain_id",
)  # fmt: skip
SSID_MAX_BYTES = 32
PASSWORD_MIN, PASSWORD_MAX = 8, 63
DOMAIN_ID_MAX = 232

# ESP-IDF's partition table (components/partition_table/gen_esp32part.py): 32-byte entries.
_ENTRY = struct.Struct("<2sBBII16sI")
_ENTRY_MAGIC = b"\xaa\x50"
_MD5_MAGIC = b"\xeb\xeb"
_TYPE_DATA, _SUBTYPE_NVS = 0x01, 0x02
_TABLE_MAX = 0xC00

_PORT = re.compile(r"[0-9]{1,5}")
_DOMAIN_ID = re.compile(r"[0-9]{1,3}")
_BROADCAST = ipaddress.IPv4Address("255.255.255.255")
_THIS_NETWORK = ipaddress.IPv4Network("0.0.0.0/8")  # "this host on this network": no destination
# A password file is read no further than the longest valid password and its line end.
_PASSWORD_READ_MAX = PASSWORD_MAX + len("\r\n")

# Where the container sees the generated image.
IMAGE_MOUNT = "/run/espdock-provision"
IMAGE_NAME = "nvs.bin"


@dataclass(frozen=True)
class NetSettings:
    ssid: str
    password: str = field(repr=False)
    agent_host: str
    agent_port: int
    # None: none written, and the firmware keeps the domain it was built with (CONFIG_ESPDOCK_ROS_DOMAIN_ID).
    domain_id: int | None = None


@dataclass(frozen=True)
class Partition:
    label: str
    type: int
    subtype: int
    offset: int
    size: int
    flags: int = 0


def parse_agent(text: str) -> tuple[str, int]:
    """HOST:PORT with an IPv4 HOST (the board has no resolver for host names)."""
    host, sep, port_text = text.rpartition(":")
    if not sep or not host:
        raise ConfigError(f"--agent '{text}' is not HOST:PORT", "e.g. --agent 192.168.1.10:8888")
    try:
        address = ipaddress.IPv4Address(host)
    except ValueError:
        raise ConfigError(
            f"agent host '{host}' is not an IPv4 address",
            "The board cannot resolve host names: give the agent host's address (e.g. from `ip -4 addr`).",
        ) from None
    if address.is_unspecified or address in _THIS_NETWORK:
        raise ConfigError(f"agent host {host} is not an address the board can send to")
    if address.is_multicast or address == _BROADCAST or address.is_reserved:
        raise ConfigError(
            f"agent host {host} is not one host's address (broadcast, multicast or reserved)",
            "The board sends to one agent: give the address of the host running micro_ros_agent.",
        )
    if address.is_loopback:
        raise ConfigError(f"agent host {host} is the board itself (loopback)", "Give the agent host's LAN address.")
    # ASCII digits only: str.isdigit() takes "²" (int() then fails) and other scripts' digits.
    if not _PORT.fullmatch(port_text) or not 1 <= int(port_text) <= 65535:
        raise ConfigError(f"agent port '{port_text}' is not 1..65535", "micro_ros_agent's default is 8888.")
    return str(address), int(port_text)


def is_domain_id(text: str) -> bool:
    """Whether TEXT is a ROS domain id 0..DOMAIN_ID_MAX in ASCII digits."""
    return bool(_DOMAIN_ID.fullmatch(text)) and int(text) <= DOMAIN_ID_MAX


def parse_domain_id(text: str) -> int:
    """--domain-id: ASCII digits only (int() takes other scripts' digits, '4_2', ' 42 ' and '+42')."""
    if not is_domain_id(text):
        raise ConfigError(f"ROS domain id {text!r} is not 0..{DOMAIN_ID_MAX}", "Give it in ASCII digits, e.g. 42.")
    return int(text)


def check_settings(ssid: str, password: str, agent: str, domain_id: int | None) -> NetSettings:
    """The settings, or a ConfigError (exit 2) naming what the firmware would refuse."""
    try:
        size = len(ssid.encode())
    except UnicodeEncodeError:
        # Python hands over command-line bytes that are not UTF-8 as lone surrogates; the NVS
        # string and the firmware's log lines are UTF-8.
        raw = ssid.encode(errors="surrogateescape").decode("ascii", errors="backslashreplace")
        raise ConfigError(
            f"the Wi-Fi SSID is not UTF-8 text ({raw})", "Give the SSID as UTF-8 (what `nmcli dev wifi` shows)."
        ) from None
    if not 1 <= size <= SSID_MAX_BYTES:
        raise ConfigError(f"the Wi-Fi SSID is {size} bytes; it must be 1..{SSID_MAX_BYTES}")
    # C0, DEL and C1 (U+0080..U+009F): the firmware prints the SSID, a terminal would obey them.
    if any(ord(c) < 0x20 or 0x7F <= ord(c) <= 0x9F for c in ssid):
        raise ConfigError("the Wi-Fi SSID contains control characters")
    if password and not PASSWORD_MIN <= len(password) <= PASSWORD_MAX:
        raise ConfigError(
            f"the Wi-Fi password is {len(password)} characters; WPA2 needs {PASSWORD_MIN}..{PASSWORD_MAX}",
            "An empty password means an open network.",
        )
    if any(not " " <= c <= "~" for c in password):
        raise ConfigError("the Wi-Fi password must be printable ASCII (a WPA2 passphrase)")
    if domain_id is not None and not 0 <= domain_id <= DOMAIN_ID_MAX:
        raise ConfigError(f"ROS domain id {domain_id} is not 0..{DOMAIN_ID_MAX}")
    host, port = parse_agent(agent)
    return NetSettings(ssid, password, host, port, domain_id)


def network_settings(
    ssid: str, password_file: str | None, agent: str, domain_id: int | None, stdin, prompt
) -> NetSettings:
    """The settings the command line gives; the password is read last, once everything else
    checked out, so a typo in the address costs no typing."""
    check_settings(ssid, "", agent, domain_id)
    return check_settings(ssid, read_password(password_file, stdin, prompt), agent, domain_id)


def optional_network_settings(
    ssid: str | None, password_file: str | None, agent: str | None, domain_id: int | None, stdin, prompt
) -> NetSettings | None:
    """As network_settings, or None when the command line asks for no provisioning at all."""
    if ssid is None and agent is None and password_file is None and domain_id is None:
        return None
    if ssid is None or agent is None:
        raise ConfigError("provisioning needs both --wifi-ssid and --agent HOST:PORT")
    return network_settings(ssid, password_file, agent, domain_id, stdin, prompt)


def read_password(source: str | None, stdin: io.TextIOBase | None, prompt) -> str:
    """From FILE, '-' (stdin), or PROMPT when stdin is a terminal; one trailing newline dropped.
    STDIN is None when the standard input is closed (`<&-`)."""
    if source is None:
        if stdin is None or not stdin.isatty():
            raise ConfigError(
                "no Wi-Fi password given and no terminal to ask on",
                "Use --wifi-password-file FILE (- reads stdin; /dev/null for an open network).",
            )
        return prompt()
    # One character more than a valid password can take tells a too-long one, so a file without
    # an end (/dev/zero, a pipe that keeps writing) is refused instead of read into memory.
    if source == "-":
        if stdin is None:
            raise ConfigError(
                "--wifi-password-file - reads stdin, which is closed", "Pipe the password in, or give a file."
            )
        try:
            text = stdin.read(_PASSWORD_READ_MAX + 1)
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"cannot read the password from stdin: {getattr(exc, 'strerror', exc)}") from None
    else:
        try:
            # utf-8-sig: a Windows editor's byte order mark is no character of the password.
            with open(source, encoding="utf-8-sig") as handle:
                text = handle.read(_PASSWORD_READ_MAX + 1)
        except (OSError, UnicodeDecodeError) as exc:
            raise ConfigError(f"cannot read the password file {source}: {getattr(exc, 'strerror', exc)}") from None
    if len(text) > _PASSWORD_READ_MAX:
        where = "stdin" if source == "-" else source
        raise ConfigError(
            f"{where} holds more than a Wi-Fi password: WPA2 passwords are {PASSWORD_MIN}..{PASSWORD_MAX} characters",
            "Give a file with the password alone (one trailing newline allowed).",
        )
    return text.removesuffix("\n").removesuffix("\r")


def nvs_csv(settings: NetSettings) -> str:
    """The NVS partition generator's CSV for SETTINGS."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["key", "type", "encoding", "value"])
    writer.writerow([NVS_NAMESPACE, "namespace", "", ""])
    writer.writerow([KEY_SSID, "data", "string", settings.ssid])
    writer.writerow([KEY_PASSWORD, "data", "string", settings.password])
    writer.writerow([KEY_AGENT_HOST, "data", "string", settings.agent_host])
    writer.writerow([KEY_AGENT_PORT, "data", "u16", str(settings.agent_port)])
    if settings.domain_id is not None:  # else the firmware's own, as built
        writer.writerow([KEY_DOMAIN_ID, "data", "u8", str(settings.domain_id)])
    return out.getvalue()


def parse_partition_table(data: bytes) -> list[Partition]:
    """The entries of an ESP-IDF partition-table.bin, up to the MD5 entry or the erased end."""
    entries = []
    for start in range(0, min(len(data), _TABLE_MAX), _ENTRY.size):
        chunk = data[start : start + _ENTRY.size]
        if len(chunk) < _ENTRY.size or chunk[:2] in (_MD5_MAGIC, b"\xff\xff"):
            break
        magic, ptype, subtype, offset, size, label, flags = _ENTRY.unpack(chunk)
        if magic != _ENTRY_MAGIC:
            raise ValueError(f"entry {len(entries)} has no partition magic")
        entries.append(Partition(label.rstrip(b"\0").decode(errors="replace"), ptype, subtype, offset, size, flags))
    return entries


# The component that reads NVS_NAMESPACE at boot (firmware/components/espdock_uros).
SETTINGS_COMPONENT = "espdock_uros"


def check_reads_settings(firmware_dir: Path, package: str) -> None:
    """Refuse to provision firmware whose build used no SETTINGS_COMPONENT (a plain IDF app, a
    micro-ROS app that takes its agent from Kconfig): nothing on it reads the settings, and writing
    them erases its NVS partition. IDF's project_description.json names the components the build
    used; firmware installed without one is not judged."""
    try:
        used = json.loads((firmware_dir / "project_description.json").read_text()).get("build_components")
    except (OSError, ValueError, AttributeError):
        return
    if isinstance(used, list) and SETTINGS_COMPONENT not in used:
        raise ConfigError(
            f"{package} does not read the settings provisioning writes: its build used no {SETTINGS_COMPONENT} "
            f"component (of {len(used)}), and writing them would erase its NVS partition",
            f"Flash it without --wifi-ssid/--agent; to provision it, build it on {SETTINGS_COMPONENT} "
            "(`espdock new` makes such a package). Nothing was written.",
        )


def nvs_partition(firmware_dir: Path, flasher_args: dict, package: str) -> Partition:
    """The NVS partition of PACKAGE's installed partition table (the one `nvs_flash_init` uses)."""
    entry = flasher_args.get("partition-table") or {}
    table = firmware_dir / entry.get("file", "partition_table/partition-table.bin")
    rebuild = f"Run `espdock build {package}` again."
    try:
        partitions = parse_partition_table(table.read_bytes())
    except FileNotFoundError:
        raise WorkspaceError(f"{package} has no installed partition table ({table})", rebuild) from None
    except ValueError as exc:
        raise WorkspaceError(f"{table} is not an ESP-IDF partition table: {exc}", rebuild) from None
    nvs = [p for p in partitions if (p.type, p.subtype) == (_TYPE_DATA, _SUBTYPE_NVS)]
    # nvs_flash_init() opens the partition labelled "nvs" (NVS_DEFAULT_PART_NAME) and no other:
    # settings written to another NVS partition are never read, and it is erased for them.
    chosen = next((p for p in nvs if p.label == "nvs"), None)
    if chosen is None:
        others = f" (its NVS partitions: {', '.join(repr(p.label) for p in nvs)}; the firmware reads none of them)"
        raise ConfigError(
            f"{package}'s partition table has no NVS partition labelled 'nvs' to provision" + (others if nvs else ""),
            "Use a built-in table (CONFIG_PARTITION_TABLE_SINGLE_APP*, *TWO_OTA*) or add an "
            '"nvs, data, nvs" row to your partitions.csv; nothing was written.',
        )
    if chosen.size < NVS_MIN_SIZE and not chosen.flags & _FLAG_READONLY:
        # nvs_flash_init() refuses a read-write one this small (ESP_ERR_NVS_NO_FREE_PAGES), and
        # apps answer that by erasing it: the settings would be gone at the first boot.
        raise ConfigError(
            f"{package}'s 'nvs' partition is {chosen.size:#x} bytes; a read-write NVS partition needs at least "
            f"{NVS_MIN_SIZE:#x} (3 pages), or nvs_flash_init() does not open it",
            "Make the nvs row of your partitions.csv 0x3000 or more (IDF's tables have 0x6000) and build again; "
            "nothing was written.",
        )
    return chosen


NVS_MIN_SIZE = 0x3000
_FLAG_READONLY = 0x2  # ESP-IDF's partition table flag `readonly`


@contextlib.contextmanager
def nvs_image(settings: NetSettings, size: int, owner: tuple[int, int] | None = None) -> Iterator[Path]:
    """A private directory holding IMAGE_NAME, the NVS partition image for SETTINGS (SIZE bytes),
    readable by OWNER (the container's user); removed on exit, however it is left."""
    # 0700, and named with this process's identity: the next run removes what a kill -9 left.
    directory = scratch.make("espdock-provision-")
    try:
        source = directory / "nvs.csv"
        image = directory / IMAGE_NAME
        descriptor = os.open(source, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(descriptor, "w", encoding="utf-8") as handle:
            handle.write(nvs_csv(settings))
        argv = [sys.executable, "-m", "esp_idf_nvs_partition_gen", "generate", str(source), str(image), hex(size)]
        # umask 077: the generator creates the image; it must never exist readable by others.
        result = subprocess.run(
            argv, capture_output=True, text=True, check=False, stdin=subprocess.DEVNULL, umask=0o077
        )
        source.unlink()
        if result.returncode != 0 or not image.is_file():
            lines = (result.stdout + result.stderr).strip().splitlines()
            raise EspdockError("the NVS partition generator failed: " + " | ".join(lines[-3:]))
        if owner is not None and os.geteuid() == 0:
            for path in (directory, image):
                os.chown(path, *owner)
        yield image
    finally:
        shutil.rmtree(directory, ignore_errors=True)


# Interfaces of this machine's container engines: docker0, a swarm's docker_gwbridge, a Compose
# network's br-<12 hex digits of its id>, Podman's (not OpenStack's br-ex or a router's br-lan, which are the LAN's).
_BRIDGES = re.compile(r"docker\d*|docker_gwbridge|br-[0-9a-f]{12}|podman\d*|cni-podman\d*")
_SIOCGIFADDR, _SIOCGIFNETMASK = 0x8915, 0x891B  # linux/sockios.h


def container_bridge(host: str) -> str | None:
    """The container bridge of this machine whose network HOST is on (docker0, ...: the bridge's own
    address, or a container's from `docker inspect`), None where it is on none. Only this machine
    reaches such an address: a board on Wi-Fi does not."""
    import fcntl
    import socket

    try:
        names = [name for _, name in socket.if_nameindex() if _BRIDGES.fullmatch(name)]
        with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as probe:
            for name in names:
                with contextlib.suppress(OSError, ValueError):  # no IPv4 address, or gone meanwhile
                    request = struct.pack("256s", name.encode()[:15])
                    address = socket.inet_ntoa(fcntl.ioctl(probe.fileno(), _SIOCGIFADDR, request)[20:24])
                    mask = socket.inet_ntoa(fcntl.ioctl(probe.fileno(), _SIOCGIFNETMASK, request)[20:24])
                    if ipaddress.IPv4Address(host) in ipaddress.IPv4Network(f"{address}/{mask}", strict=False):
                        return name
    except (OSError, AttributeError):  # no interface list here (not Linux)
        return None
    return None
