"""How a firmware package reaches the micro-ROS agent, and what that asks of its library.

The transport is chosen in the package's sdkconfig.defaults (the espdock_uros component's
ESPDOCK_TRANSPORT choice). UDP is micro-ROS's default library (RMW_UXRCE_TRANSPORT=udp);
both serial transports need a library built with RMW_UXRCE_TRANSPORT=custom, which the
component's espdock_transport.c fills with its UART or USB-Serial-JTAG callbacks.
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

from espdock.errors import ConfigError, WorkspaceError
from espdock.workspace import named_sdkconfig_defaults

UDP = "udp"
UART = "uart"
USB_SERIAL_JTAG = "usb-serial-jtag"
TRANSPORTS = (UDP, UART, USB_SERIAL_JTAG)
SERIAL_TRANSPORTS = (UART, USB_SERIAL_JTAG)

# The Kconfig choice's symbols (firmware/components/espdock_uros/Kconfig.projbuild).
SYMBOLS = {
    "CONFIG_ESPDOCK_TRANSPORT_UDP": UDP,
    "CONFIG_ESPDOCK_TRANSPORT_UART": UART,
    "CONFIG_ESPDOCK_TRANSPORT_USB_SERIAL_JTAG": USB_SERIAL_JTAG,
}
# Chips with SOC_USB_SERIAL_JTAG_SUPPORTED in ESP-IDF v5.3 among those micro-ROS builds for
# (esp32 and esp32s2 have none; the esp32s2's USB is OTG only).
USB_SERIAL_JTAG_CHIPS = ("esp32c3", "esp32s3")

_CHOICE_LINE = re.compile(r"^(CONFIG_ESPDOCK_TRANSPORT_[A-Z_]+)=y\s*$")
_TRANSPORT_ARG = "-DRMW_UXRCE_TRANSPORT="


ALIASES = {"serial": UART}


def parse_transport(text: str) -> str:
    """A transport name as the user gives it (`espdock new --transport`)."""
    name = ALIASES.get(text.strip().lower(), text.strip().lower())
    if name not in TRANSPORTS:
        raise ConfigError(
            f"unknown transport '{text}'",
            f"Choose one of {', '.join(TRANSPORTS)} (serial means uart: UART0, the board's USB-to-UART bridge).",
        )
    return name


def applied_defaults(target: str, order: Sequence[str] = ()) -> list[str]:
    """The names of a package's defaults files as IDF applies them for TARGET, the later winning:
    those its CMakeLists.txt sets SDKCONFIG_DEFAULTS to (ORDER), else sdkconfig.defaults, each
    followed by its .TARGET variant."""
    return [name for base in order or ("sdkconfig.defaults",) for name in (base, f"{base}.{target}")]


def defaults_in_order(defaults: Mapping[str, bytes], target: str, order: Sequence[str] = ()) -> list[bytes]:
    """DEFAULTS' files (by name) in the order applied_defaults gives, an absent one empty."""
    return [defaults.get(name, b"") for name in applied_defaults(target, order)]


def firmware_transport(defaults: Mapping[str, bytes], target: str, order: Sequence[str] = ()) -> str:
    """The transport a package's sdkconfig.defaults (then .TARGET, which wins) selects; UDP if none."""
    return transport_choice(defaults, target, order)[0]


def transport_choice(defaults: Mapping[str, bytes], target: str, order: Sequence[str] = ()) -> tuple[str, str | None]:
    """firmware_transport's choice and the name of the defaults file that made it (None: UDP by default)."""
    chosen: tuple[str, str | None] = (UDP, None)
    for name in applied_defaults(target, order):
        for line in defaults.get(name, b"").decode(errors="replace").splitlines():
            match = _CHOICE_LINE.match(line.strip())
            if match and match.group(1) in SYMBOLS:
                chosen = (SYMBOLS[match.group(1)], name)
    return chosen


def lacks_port(transport: str, target: str) -> bool:
    """Whether chip TARGET has no hardware for TRANSPORT (USB-Serial-JTAG on a chip without one)."""
    return transport == USB_SERIAL_JTAG and target not in USB_SERIAL_JTAG_CHIPS


def check_transport(package: str, transport: str, target: str, new: bool = False, where: str | None = None) -> None:
    """Refuse a transport the chip has no hardware for, before anything builds; NEW: as `espdock
    new --transport` asks for it, before the package exists. WHERE: the defaults file that chose it."""
    if lacks_port(transport, target):
        chips = " or ".join(USB_SERIAL_JTAG_CHIPS)
        if new:
            raise ConfigError(
                f"{package}: {target} has no USB-Serial-JTAG port (--transport usb-serial-jtag)",
                f"Use --transport uart (the board's USB-to-UART bridge on UART0), or --target {chips}.",
            )
        raise WorkspaceError(
            f"{package}: {target} has no USB-Serial-JTAG port, but its {where or 'sdkconfig.defaults'} selects "
            "CONFIG_ESPDOCK_TRANSPORT_USB_SERIAL_JTAG",
            f"Use it on {chips}, or set CONFIG_ESPDOCK_TRANSPORT_UART=y (the board's USB-to-UART bridge on UART0).",
        )


def rmw_transport(transport: str) -> str:
    """rmw_microxrcedds's RMW_UXRCE_TRANSPORT for a firmware transport."""
    return UDP if transport == UDP else "custom"


def library_colcon_meta(package: str, meta: str, transport: str, where: str | None = None) -> str:
    """The app-colcon.meta the micro-ROS library is built with for TRANSPORT (chosen in the
    defaults file WHERE; None: by default).

    A UDP package's meta is returned unchanged (UDP is the library's default, so its image key
    stays what it was); a serial one gets RMW_UXRCE_TRANSPORT=custom. A meta that sets another
    RMW_UXRCE_TRANSPORT than the Kconfig choice is refused: the firmware would not compile.
    META's form is checked before (the plan refuses a meta colcon would not take as meant).
    """
    wanted = rmw_transport(transport)
    data = json.loads(meta) if meta.strip() else {"names": {}}
    args = data.setdefault("names", {}).setdefault("rmw_microxrcedds", {}).setdefault("cmake-args", [])
    given = [a[len(_TRANSPORT_ARG) :] for a in args if isinstance(a, str) and a.startswith(_TRANSPORT_ARG)]
    if any(value != wanted for value in given):
        raise WorkspaceError(
            f"{package}/app-colcon.meta sets {_TRANSPORT_ARG}{given[-1]}, but "
            + (f"its {where} selects the {transport} transport" if where else f"it uses the {transport} transport")
            + f", which needs {_TRANSPORT_ARG}{wanted}",
            f"Remove that argument (espdock adds the right one; `espdock new --transport` wrote it there for "
            f"plain idf.py builds), or set it to {wanted}.",
        )
    if transport == UDP or given:
        return meta
    args.append(f"{_TRANSPORT_ARG}{wanted}")
    return json.dumps(data, indent=2, sort_keys=True) + "\n"


def project_transport(project: Path, target: str) -> str:
    """The transport of the firmware project at PROJECT, built for TARGET."""
    return _project_choice(project, target)[0]


def _project_choice(project: Path, target: str) -> tuple[str, str | None]:
    order = named_sdkconfig_defaults(project / "CMakeLists.txt")
    found = {n: (project / n).read_bytes() for n in applied_defaults(target, order) if (project / n).is_file()}
    return transport_choice(found, target, order)


# Beside the installed firmware: the transport its build chose and the ROS domain it was built
# with, from the build's own configuration. Provisioning asks the board's firmware, not sources
# edited since its build, and says the domain a board keeps when given none.
TRANSPORT_RECORD = "espdock-transport.json"
DOMAIN_SYMBOL = "ESPDOCK_ROS_DOMAIN_ID"


def built_transport_record(build_dir: Path) -> bytes | None:
    """TRANSPORT_RECORD's content for the build in BUILD_DIR: the choice in the configuration
    kconfgen wrote (config/sdkconfig.json, symbols without CONFIG_), and its ROS domain; None where
    the build has no such configuration or made no choice (an app without the espdock_uros component)."""
    try:
        config = json.loads((build_dir / "config" / "sdkconfig.json").read_text())
    except (OSError, ValueError):
        return None
    if not isinstance(config, dict):
        return None
    chosen = [t for symbol, t in SYMBOLS.items() if config.get(symbol[7:]) is True]
    if len(chosen) != 1:
        return None
    record: dict[str, object] = {"transport": chosen[0]}
    if isinstance(domain := config.get(DOMAIN_SYMBOL), int) and not isinstance(domain, bool):
        record["ros_domain_id"] = domain
    return json.dumps(record).encode() + b"\n"


def _installed_record(firmware_dir: Path, key: str) -> object:
    """KEY of TRANSPORT_RECORD beside the firmware installed at FIRMWARE_DIR (None: not recorded)."""
    try:
        return json.loads((firmware_dir / TRANSPORT_RECORD).read_text()).get(key)
    except (OSError, ValueError, AttributeError):
        return None


def installed_domain_id(firmware_dir: Path) -> int | None:
    """The ROS domain the firmware installed at FIRMWARE_DIR was built with (None: not recorded)."""
    domain = _installed_record(firmware_dir, "ros_domain_id")
    return domain if isinstance(domain, int) and not isinstance(domain, bool) else None


def installed_transport(firmware_dir: Path) -> str | None:
    """The transport the firmware installed at FIRMWARE_DIR was built with (None: not recorded)."""
    link = _installed_record(firmware_dir, "transport")
    return link if link in TRANSPORTS else None


def check_provisionable(package: str, project: Path, target: str, firmware_dir: Path) -> None:
    """Provisioning writes Wi-Fi and agent settings: a serial board has neither to write. The
    board's firmware says which it is (the one installed at FIRMWARE_DIR); firmware installed
    before espdock recorded it, or none, is judged by its project at PROJECT, built for TARGET."""
    installed = installed_transport(firmware_dir)
    link, where = (installed, None) if installed else _project_choice(project, target)
    if link != UDP:
        symbol = next(s for s, t in SYMBOLS.items() if t == link)
        chose = f"its {where} sets {symbol}=y" if where else f"its installed firmware was built with {symbol}=y"
        raise ConfigError(
            f"{package} reaches the micro-ROS agent over {link} ({chose}): nothing to provision, it uses no Wi-Fi "
            "and no agent address",
            "Flash it (espdock flash without --wifi-ssid, --agent, --wifi-password-file or --domain-id: its ROS "
            "domain is the build's CONFIG_ESPDOCK_ROS_DOMAIN_ID) and start the agent on its port, e.g. "
            "`espdock agent --port /dev/ttyACM0`.",
        )
