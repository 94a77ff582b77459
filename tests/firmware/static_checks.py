#!/usr/bin/env python3
"""Static checks of the firmware packages that need no ESP-IDF toolchain.

    static_checks.py kconfig FILE...        parse each Kconfig file (esp-idf-kconfig's parser)
    static_checks.py package-xml FILE...    catkin_pkg validation, warnings count as errors
    static_checks.py apps FIRMWARE_DIR MSG  espdock conventions, names, colcon.meta sizing,
                                            CameraConfig ranges against the .msg

Each prints one line per problem and exits 1 if there was any.
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path

# Names the apps must use by default (the ROS graph).
REQUIRED_DEFAULTS = {
    "camera_node": {
        "ESPDOCK_CAM_IMAGE_TOPIC": "/esp32/camera/image_jpeg",
        "ESPDOCK_CAM_GET_CONFIG_SERVICE": "/esp32/camera/get_config",
        "ESPDOCK_CAM_SET_CONFIG_SERVICE": "/esp32/camera/set_config",
    },
    "led_strip_node": {
        "ESPDOCK_LED_COLOR_TOPIC": "/qr_message",
        "ESPDOCK_LED_STATE_TOPIC": "/esp32/led_strip/color",
    },
}
COMMON_OPTIONS = ("ESPDOCK_NODE_NAME",)
# The network fallbacks live once, in the shared component; provisioning (NVS) is the
# usual source, so the string defaults stay empty: a default build carries no network secrets.
NETWORK_FALLBACKS = {
    "ESPDOCK_WIFI_SSID": "",
    "ESPDOCK_WIFI_PASSWORD": "",
    "ESPDOCK_AGENT_IP": "",
    "ESPDOCK_AGENT_PORT": "8888",
    "ESPDOCK_ROS_DOMAIN_ID": "0",
}
# ESP-IDF's built-in partition tables (all have "nvs" at 0x9000, 0x6000 bytes).
BUILTIN_TABLES = ("SINGLE_APP", "SINGLE_APP_LARGE", "TWO_OTA", "TWO_OTA_LARGE", "SINGLE_APP_ENCRYPTED_NVS")

# esp32-camera 2.x framesize_t -> (width, height), up to the OV2640's UXGA.
FRAMESIZES = [
    (96, 96),
    (160, 120),
    (128, 128),
    (176, 144),
    (240, 176),
    (240, 240),
    (320, 240),
    (320, 320),
    (400, 296),
    (480, 320),
    (640, 480),
    (800, 600),
    (1024, 768),
    (1280, 720),
    (1280, 1024),
    (1600, 1200),
]

# Micro XRCE-DDS framing: session header with client key, submessage header,
# WRITE_DATA request/object ids. Defaults are the upstream libraries'.
XRCE_SESSION_HEADER = 8
XRCE_SUBHEADER = 4
XRCE_WRITE_DATA_PAYLOAD = 4
DEFAULT_UDP_MTU = 512
DEFAULT_STREAM_HISTORY = 4
# Micro XRCE-DDS Agent's UAGENT_CONFIG_RELIABLE_STREAM_DEPTH (CMake default).
AGENT_RELIABLE_STREAM_DEPTH = 16
# CDR encapsulation + stamp + string/sequence length fields and padding of a
# CompressedImage, on top of frame_id and format text.
COMPRESSED_IMAGE_OVERHEAD = 64

ENTITY_CALLS = {
    "RMW_UXRCE_MAX_PUBLISHERS": r"\brclc_publisher_init(?:_default|_best_effort)?\s*\(",
    "RMW_UXRCE_MAX_SUBSCRIPTIONS": r"\brclc_subscription_init(?:_default|_best_effort)?\s*\(",
    "RMW_UXRCE_MAX_SERVICES": r"\brclc_service_init(?:_default|_best_effort)?\s*\(",
    "RMW_UXRCE_MAX_CLIENTS": r"\brclc_client_init(?:_default|_best_effort)?\s*\(",
}


class Problems:
    """Collects problems so every check runs and all failures are reported."""

    def __init__(self) -> None:
        self.items: list[str] = []

    def add(self, where: object, message: str) -> None:
        self.items.append(f"{where}: {message}")

    def finish(self, what: str) -> int:
        for item in self.items:
            print(f"ERROR {item}")
        print(f"{what}: {'FAILED, ' + str(len(self.items)) + ' problem(s)' if self.items else 'OK'}")
        return 1 if self.items else 0


# Per target: (highest GPIO, highest output-capable GPIO), from ESP-IDF v5.3's soc_caps.h
# (SOC_GPIO_PIN_COUNT, SOC_GPIO_VALID_OUTPUT_GPIO_MASK): ESP32 34..39 and ESP32-S2 46 are inputs only.
GPIO_LIMITS = {
    "esp32": (39, 33), "esp32s2": (46, 45), "esp32s3": (48, 48), "esp32c3": (21, 21),
    "esp32c2": (20, 20), "esp32c6": (30, 30), "esp32h2": (27, 27), "esp32p4": (54, 54),
}  # fmt: skip
# Strapping pins (sampled at reset for the boot mode), per the chips' datasheets: a default output
# there could make a board boot into download mode or the wrong flash voltage.
STRAPPING_PINS = {
    "esp32": {0, 2, 5, 12, 15}, "esp32s2": {0, 45, 46}, "esp32s3": {0, 3, 45, 46}, "esp32c3": {2, 8, 9},
}  # fmt: skip
# Pins wired to the module's SPI flash and PSRAM: ESP32 6-11 (16-17 PSRAM on WROVER); ESP32-S3
# 26-32 (flash/PSRAM) and 33-37 (octal flash/PSRAM).
FLASH_PSRAM_PINS = {"esp32": {*range(6, 12), 16, 17}, "esp32s3": set(range(26, 38))}
# Camera signals the ESP32 only reads: these may use input-only pins.
INPUT_PINS = {f"ESPDOCK_CAM_PIN_{n}" for n in ("D0", "D1", "D2", "D3", "D4", "D5", "D6", "D7", "VSYNC", "HREF", "PCLK")}


def kconfig_module():
    try:
        import esp_kconfiglib as kconfiglib
    except ImportError:  # esp-idf-kconfig before 3.x
        import kconfiglib
    return kconfiglib


def expr_value(expr) -> int:
    """kconfiglib's value of a condition: 0 (n), 1 (m) or 2 (y)."""
    module = kconfig_module()
    return getattr(module, "expr_value", None)(expr) if hasattr(module, "expr_value") else module.core.expr_value(expr)


def load_kconfig(path: Path, target: str = "esp32"):
    """Parses one Kconfig file with esp-idf-kconfig's kconfiglib, under a root that defines
    IDF's target symbols (IDF_TARGET, IDF_TARGET_<CHIP>) for TARGET, as IDF's root Kconfig does."""
    import tempfile

    kconfiglib = kconfig_module()

    root = [f'config IDF_TARGET\n    string\n    default "{target}"\n']
    root += [
        f'config IDF_TARGET_{chip.upper()}\n    bool\n    default y if IDF_TARGET = "{chip}"\n' for chip in GPIO_LIMITS
    ]
    root.append(f'source "{path.resolve()}"\n')
    with tempfile.NamedTemporaryFile("w", suffix=".Kconfig") as tmp:
        tmp.write("\n".join(root))
        tmp.flush()
        return kconfiglib.Kconfig(tmp.name, warn=False)


def check_gpio_ranges(path: Path, problems: Problems) -> None:
    """Every GPIO option's range, for every target, ends at that chip's last usable pin."""
    for target, (highest, highest_output) in GPIO_LIMITS.items():
        kconf = load_kconfig(path, target)
        if "ESPDOCK_CAM_BOARD_CUSTOM" in kconf.syms:
            kconf.syms["ESPDOCK_CAM_BOARD_CUSTOM"].set_value(2)  # the pin options depend on it
        for name, sym in kconf.syms.items():
            if not ("_PIN_" in name or name.endswith("_GPIO")) or not sym.nodes:
                continue
            active = [(low, high) for low, high, cond in sym.ranges if expr_value(cond) == 2]
            limit = highest if name in INPUT_PINS else highest_output
            if not active or int(active[0][1].name) != limit:
                got = active[0][1].name if active else "no range"
                problems.add(path, f"{name} on {target}: range ends at {got}, the chip's last usable pin is {limit}")


def component_targets(manifest: Path) -> list[str]:
    """The `targets:` list of an idf_component.yml (block style, as the apps write it)."""
    block = re.search(r"^targets:\n((?:[ \t]+-[ \t]*\S+[ \t]*\n)+)", manifest.read_text(), re.M)
    return re.findall(r"-[ \t]*(\S+)", block.group(1)) if block else []


def pin_defaults(path: Path, target: str, enable: str | None = None) -> dict[str, int]:
    """Each GPIO option's default value on TARGET (with the bool option ENABLE set first)."""
    kconf = load_kconfig(path, target)
    if enable:
        kconf.syms[enable].set_value(2)
    return {
        name: int(sym.str_value)
        for name, sym in kconf.syms.items()
        if ("_PIN_" in name or name.endswith("_GPIO")) and sym.nodes and sym.str_value not in ("", "-1")
    }


def check_pin_defaults(app: Path, problems: Problems) -> None:
    """Per chip the app builds for, its default pins stay off flash/PSRAM pins (camera) and strapping
    pins (LED data), and the chips ESP-IDF enforces (REQUIRED_IDF_TARGETS) are the manifest's."""
    kconfig = app / "main" / "Kconfig.projbuild"
    targets = component_targets(app / "main" / "idf_component.yml")
    required = re.search(r"^\s+REQUIRED_IDF_TARGETS\s([^)]*)\)", (app / "main" / "CMakeLists.txt").read_text(), re.M)
    if targets and (required is None or required.group(1).split() != targets):
        problems.add(app, f"main/CMakeLists.txt must register REQUIRED_IDF_TARGETS {' '.join(targets)}, as targets")
    if app.name == "camera_node":
        for target in targets:
            for name, pin in pin_defaults(kconfig, target, "ESPDOCK_CAM_BOARD_CUSTOM").items():
                if pin in FLASH_PSRAM_PINS.get(target, ()):
                    problems.add(kconfig, f"{name} defaults to GPIO {pin} on {target}, a flash/PSRAM pin")
    if app.name == "led_strip_node":
        for target in ("esp32", "esp32s2", "esp32s3", "esp32c3"):  # the chips micro-ROS builds for
            pin = pin_defaults(kconfig, target)["ESPDOCK_LED_STRIP_GPIO"]
            if pin in STRAPPING_PINS[target]:
                problems.add(kconfig, f"ESPDOCK_LED_STRIP_GPIO defaults to GPIO {pin} on {target}, a strapping pin")


def is_literal(name: str) -> bool:
    return re.fullmatch(r"-?(0x[0-9a-fA-F]+|[0-9]+)", name) is not None


def check_kconfig_file(path: Path, problems: Problems) -> None:
    try:
        kconf = load_kconfig(path)
    except Exception as exc:  # the parser raises KconfigError and OSError subclasses
        problems.add(path, f"does not parse: {exc}")
        return
    check_gpio_ranges(path, problems)
    for name, sym in kconf.syms.items():
        if name == "IDF_TARGET" or name.startswith("IDF_TARGET_"):
            continue
        if not sym.nodes and not is_literal(name):
            problems.add(path, f"references undefined symbol {name}")
            continue
        check_default_in_range(path, sym, problems)
    for sym in kconf.unique_defined_syms:
        for node in sym.nodes:
            if node.prompt and not node.help and sym.choice is None and not is_hidden_pin(sym.name):
                problems.add(path, f"{sym.name} has a prompt but no help text")


def is_hidden_pin(name: str) -> bool:
    # Pin numbers are self-explanatory by their prompt ("D7 (Y9)").
    return name.startswith("ESPDOCK_CAM_PIN_")


def check_default_in_range(path: Path, sym, problems: Problems) -> None:
    if not sym.ranges or not sym.defaults:
        return
    low, high = sym.ranges[0][0].name, sym.ranges[0][1].name
    for default, _cond in sym.defaults:
        if is_literal(default.name) and is_literal(low) and is_literal(high):
            value, lo, hi = (int(x, 0) for x in (default.name, low, high))
            if not lo <= value <= hi:
                problems.add(path, f"{sym.name} default {value} outside range {lo}..{hi}")


def cmd_kconfig(files: list[str]) -> int:
    problems = Problems()
    for name in files:
        check_kconfig_file(Path(name), problems)
    return problems.finish(f"Kconfig parse of {len(files)} file(s)")


def cmd_package_xml(files: list[str]) -> int:
    from catkin_pkg.package import InvalidPackage, parse_package

    problems = Problems()
    for name in files:
        warnings: list[str] = []
        try:
            package = parse_package(name, warnings=warnings)
            package.validate(warnings=warnings)
        except InvalidPackage as exc:
            problems.add(name, f"invalid: {exc}")
            continue
        for warning in warnings:
            problems.add(name, f"warning: {warning}")
        if package.package_format != 3:
            problems.add(name, f"format {package.package_format}, expected 3")
        if package.get_build_type() != "esp_idf":
            problems.add(name, f"build_type {package.get_build_type()}, expected esp_idf")
        if Path(name).parent.name != package.name:
            problems.add(name, f"package name {package.name} differs from its directory")
    return problems.finish(f"package.xml validation of {len(files)} file(s)")


def meta_args(meta: dict) -> dict[str, dict[str, str]]:
    """{ros package: {CMAKE_VAR: value}} from a colcon.meta document."""
    result: dict[str, dict[str, str]] = {}
    for package, settings in meta.get("names", {}).items():
        variables = {}
        for arg in settings.get("cmake-args", []):
            match = re.fullmatch(r"-D([A-Z0-9_]+)=(.*)", arg)
            if match:
                variables[match.group(1)] = match.group(2)
        result[package] = variables
    return result


def check_colcon_meta(app: Path, problems: Problems) -> dict[str, dict[str, str]]:
    path = app / "app-colcon.meta"
    try:
        meta = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        problems.add(path, f"not readable JSON: {exc}")
        return {}
    if set(meta) != {"names"} or not isinstance(meta["names"], dict):
        problems.add(path, 'top level must be {"names": {...}} (upstream colcon.meta format)')
        return {}
    for package, settings in meta["names"].items():
        args = settings.get("cmake-args") if isinstance(settings, dict) else None
        if not isinstance(args, list) or set(settings) != {"cmake-args"}:
            problems.add(path, f"{package}: expected only a cmake-args list")
            continue
        for arg in args:
            match = re.fullmatch(r"-D([A-Z0-9_]+)=(-?[0-9]+)", arg)
            if package == "rmw_microxrcedds" and re.fullmatch(r"-DRMW_UXRCE_TRANSPORT=(udp|custom)", arg):
                continue
            if not match:
                problems.add(path, f"{package}: {arg!r} is not -DNAME=<integer>")
            elif "HISTORY" in match.group(1) and "MAX_HISTORY" not in match.group(1):
                value = int(match.group(2))
                if value <= 0 or value & (value - 1):
                    problems.add(path, f"{match.group(1)}={value} must be a power of two")
    return meta_args(meta)


# espdock_uros's Kconfig choice (Kconfig.projbuild) -> rmw_microxrcedds's RMW_UXRCE_TRANSPORT.
TRANSPORT_LIBRARY = {"UDP": "udp", "UART": "custom", "USB_SERIAL_JTAG": "custom"}


def check_transport(component: Path, app: Path, rmw: dict[str, str], problems: Problems) -> None:
    """The app's transport choice exists in the component, and its app-colcon.meta builds the library
    that matches it (a plain idf.py build reads only the meta)."""
    choices = set(
        re.findall(r"^\s*config ESPDOCK_TRANSPORT_(\w+)\s*$", (component / "Kconfig.projbuild").read_text(), re.M)
    )
    if choices - {"SERIAL"} != set(TRANSPORT_LIBRARY):
        problems.add(
            component / "Kconfig.projbuild", f"transport choices {sorted(choices)} != {sorted(TRANSPORT_LIBRARY)}"
        )
    chosen = re.findall(r"^CONFIG_ESPDOCK_TRANSPORT_(\w+)=y$", (app / "sdkconfig.defaults").read_text(), re.M)
    transport = chosen[-1] if chosen else "UDP"
    if transport not in TRANSPORT_LIBRARY:
        problems.add(app / "sdkconfig.defaults", f"unknown transport CONFIG_ESPDOCK_TRANSPORT_{transport}")
        return
    wanted, given = TRANSPORT_LIBRARY[transport], rmw.get("RMW_UXRCE_TRANSPORT", "udp")
    if given != wanted:
        problems.add(
            app / "app-colcon.meta", f"RMW_UXRCE_TRANSPORT={given}, but the {transport} transport needs {wanted}"
        )


def app_sources(app: Path) -> str:
    return "\n".join(p.read_text() for p in sorted((app / "main").glob("*.c")))


def check_entity_counts(app: Path, rmw: dict[str, str], problems: Problems) -> None:
    sources = app_sources(app)
    for var, pattern in ENTITY_CALLS.items():
        used = len(re.findall(pattern, sources))
        declared = int(rmw.get(var, "-1"))
        if declared < 0:
            problems.add(app / "app-colcon.meta", f"{var} not set (the app creates {used})")
        elif declared < used:
            problems.add(app / "app-colcon.meta", f"{var}={declared} but the app creates {used}")
    if int(rmw.get("RMW_UXRCE_MAX_NODES", "0")) < 1:
        problems.add(app / "app-colcon.meta", "RMW_UXRCE_MAX_NODES must be at least 1")


def check_camera_stream(
    app: Path, args: dict[str, dict[str, str]], defaults: dict[str, str], problems: Problems
) -> None:
    """The reliable output stream must fit the agent's window; say how many windows a frame takes.

    The agent accepts reliable messages only AGENT_RELIABLE_STREAM_DEPTH sequence numbers ahead
    of what it acknowledged; a longer history only gets dropped and resent.
    """
    rmw = args.get("rmw_microxrcedds", {})
    client = args.get("microxrcedds_client", {})
    mtu = int(client.get("UCLIENT_UDP_TRANSPORT_MTU", DEFAULT_UDP_MTU))
    slots = int(rmw.get("RMW_UXRCE_STREAM_HISTORY_OUTPUT", rmw.get("RMW_UXRCE_STREAM_HISTORY", DEFAULT_STREAM_HISTORY)))
    framesize = int(defaults.get("ESPDOCK_CAM_MAX_FRAMESIZE_VALUE", "-1"))
    if not 0 <= framesize < len(FRAMESIZES):
        problems.add(app, f"cannot read the default largest frame size ({framesize})")
        return
    if slots > AGENT_RELIABLE_STREAM_DEPTH:
        problems.add(
            app / "app-colcon.meta",
            f"RMW_UXRCE_STREAM_HISTORY_OUTPUT={slots}, but the agent accepts only "
            f"{AGENT_RELIABLE_STREAM_DEPTH} reliable messages ahead of its acknowledgement",
        )
    width, height = FRAMESIZES[framesize]
    largest_jpeg = width * height // 5  # esp32-camera's JPEG buffer for that size
    text = len(defaults.get("ESPDOCK_CAM_FRAME_ID", "")) + len("jpeg")
    needed = largest_jpeg + COMPRESSED_IMAGE_OVERHEAD + text + XRCE_SUBHEADER + XRCE_WRITE_DATA_PAYLOAD
    fragment = mtu - XRCE_SESSION_HEADER - XRCE_SUBHEADER
    fragments = -(-needed // fragment)
    print(
        f"{app.name}: a {width}x{height} frame is up to {needed} B = {fragments} fragments of {fragment} B, "
        f"{-(-fragments // slots)} acknowledged windows of {slots}"
    )
    if mtu > 1472:
        problems.add(app / "app-colcon.meta", f"MTU {mtu} exceeds one Ethernet/Wi-Fi UDP datagram")


def kconfig_defaults(path: Path) -> dict[str, str]:
    kconf = load_kconfig(path)
    return {name: sym.str_value for name, sym in kconf.syms.items() if sym.nodes}


def check_top_cmake(app: Path, problems: Problems) -> None:
    path = app / "CMakeLists.txt"
    text = path.read_text()
    required = {
        r"cmake_minimum_required\(VERSION 3\.16\)": "cmake_minimum_required(VERSION 3.16)",
        r"message\(FATAL_ERROR[^)]*espdock build": "FATAL_ERROR pointing to `espdock build`",
        r"list\(APPEND EXTRA_COMPONENT_DIRS\s+\$ENV\{UROS_COMPONENT_DIR\}": "the micro-ROS component dir",
        r"\.\./components": "the shared components directory",
        r"include\(\$ENV\{IDF_PATH\}/tools/cmake/project\.cmake\)": "include of project.cmake",
        rf"project\({app.name}\)": f"project({app.name})",
    }
    for pattern, what in required.items():
        if not re.search(pattern, text):
            problems.add(path, f"missing {what}")


def check_interface_depends(app: Path, problems: Problems) -> None:
    from catkin_pkg.package import parse_package

    package = parse_package(str(app / "package.xml"))
    declared = {dep.name for dep in package.build_depends} & {dep.name for dep in package.exec_depends}
    included = set(re.findall(r"#include\s*<(\w+)/(?:msg|srv|action)/", app_sources(app)))
    for missing in sorted(included - declared):
        problems.add(app / "package.xml", f"main/ uses {missing} but there is no <depend> on it")


def check_camera_ranges(header: Path, msg: Path, problems: Problems) -> None:
    """camera_config.h's table must match CameraConfig.msg field by field."""
    c_rows = re.findall(
        r"X\((\w+),\s*\w+,\s*(u?int\d+)_t,\s*(-?\d+),\s*(-?\d+),\s*(?:true|false)\)", header.read_text()
    )
    msg_rows = re.findall(r"^\s*(u?int\d+)\s+(\w+)\s*#\s*(-?\d+)\.\.(-?\d+)", msg.read_text(), re.M)
    c_table = [(name, ctype, int(lo), int(hi)) for name, ctype, lo, hi in c_rows]
    msg_table = [(name, mtype, int(lo), int(hi)) for mtype, name, lo, hi in msg_rows]
    if not msg_table:
        problems.add(msg, "no 'type name  # min..max' fields found")
    if c_table != msg_table:
        for c_row, m_row in zip(c_table, msg_table, strict=False):
            if c_row != m_row:
                problems.add(header, f"{c_row} does not match {msg.name} {m_row}")
        if len(c_table) != len(msg_table):
            problems.add(header, f"{len(c_table)} fields, {msg.name} has {len(msg_table)}")


def check_network_fallbacks(component: Path, problems: Problems) -> None:
    kconfig = component / "Kconfig"
    if not kconfig.is_file():
        problems.add(component, "missing Kconfig (the network fallbacks)")
        return
    defaults = kconfig_defaults(kconfig)
    for option, value in NETWORK_FALLBACKS.items():
        if defaults.get(option) != value:
            problems.add(kconfig, f"{option} defaults to {defaults.get(option)!r}, expected {value!r}")


def check_nvs_partition(app: Path, problems: Problems) -> None:
    """`espdock provision` writes the NVS partition the app's partition table names."""
    text = (app / "sdkconfig.defaults").read_text()
    chosen = re.findall(r"^CONFIG_PARTITION_TABLE_(\w+)=y$", text, re.M)
    if any(name in BUILTIN_TABLES for name in chosen) or not chosen:
        return  # IDF's default is SINGLE_APP
    match = re.search(r'^CONFIG_PARTITION_TABLE_CUSTOM_FILENAME="([^"]+)"', text, re.M)
    csv = app / (match.group(1) if match else "partitions.csv")
    rows = [line.split(",") for line in csv.read_text().splitlines() if csv.is_file() and line.strip()]
    if not any(len(r) > 2 and r[1].strip() == "data" and r[2].strip() == "nvs" for r in rows):
        problems.add(app, f"partition table {csv.name} has no data/nvs partition to provision")


def check_wifi_lifecycle(component: Path, apps: list[Path], problems: Problems) -> None:
    """Credentials only in espdock's NVS namespace (the driver keeps its copy in RAM), Wi-Fi that
    fails to start retried by every app, and the agent-port check compiled in."""
    wifi = (component / "espdock_wifi.c").read_text()
    storage = wifi.find("esp_wifi_set_storage(WIFI_STORAGE_RAM)")
    config = wifi.find("esp_wifi_set_config(")
    if storage < 0 or storage > config:
        problems.add(component, "espdock_wifi.c must call esp_wifi_set_storage(WIFI_STORAGE_RAM) before set_config")
    uros = (component / "espdock_uros.c").read_text()
    if "agent_port_check.h" in uros or "_Static_assert" in uros:
        problems.add(component, "espdock_uros.c must not fail every build for one port: refuse the port at run time")
    check = uros.find("net_agent_port_fits(config->agent_port, MAX_PORT_LEN)")
    # The UDP address is set by espdock_transport_configure (espdock_transport.c).
    if check < 0 or check > uros.find("espdock_transport_configure("):
        problems.add(component, "espdock_uros_setup must refuse a port the library cuts (net_agent_port_fits) first")
    for app in apps:
        sources = app_sources(app)
        if "espdock_wifi_start(" in sources or "espdock_wifi_start_retrying(" not in sources:
            problems.add(app, "must start Wi-Fi with espdock_wifi_start_retrying (a failed start is retried)")


def cmd_apps(firmware: str, msg_file: str) -> int:
    problems = Problems()
    root = Path(firmware)
    check_network_fallbacks(root / "components" / "espdock_uros", problems)
    # `espdock new`'s template starts Wi-Fi like the apps (its sources carry @NAME@ placeholders).
    template = root.parent / "espdock" / "firmware" / "templates" / "firmware"
    apps_and_template = [*sorted(p.parent for p in root.glob("*/package.xml")), template]
    check_wifi_lifecycle(root / "components" / "espdock_uros", apps_and_template, problems)
    client = meta_args(json.loads((template / "app-colcon.meta").read_text())).get("microxrcedds_client", {})
    if "UCLIENT_MAX_SESSION_CONNECTION_ATTEMPTS" not in client:
        problems.add(
            template / "app-colcon.meta",
            "microxrcedds_client must set UCLIENT_MAX_SESSION_CONNECTION_ATTEMPTS (the default 10 tries hold up "
            "each reconnection)",
        )
    apps = sorted(p.parent for p in root.glob("*/package.xml"))
    if {a.name for a in apps} != set(REQUIRED_DEFAULTS):
        problems.add(root, f"expected apps {sorted(REQUIRED_DEFAULTS)}, found {[a.name for a in apps]}")
    if (root / "components" / "package.xml").exists():
        problems.add(root / "components", "is not a ROS package and must not have a package.xml")
    for app in apps:
        missing = [
            rel
            for rel in (
                "CMakeLists.txt",
                "main/CMakeLists.txt",
                "main/Kconfig.projbuild",
                "main/idf_component.yml",
                "app-colcon.meta",
                "sdkconfig.defaults",
            )
            if not (app / rel).is_file()
        ]
        for rel in missing:
            problems.add(app, f"missing {rel}")
        if missing:
            continue
        check_top_cmake(app, problems)
        if not re.search(r'^\s+idf: ">=5\.3,<6"$', (app / "main" / "idf_component.yml").read_text(), re.M):
            problems.add(
                app,
                'main/idf_component.yml must require idf: ">=5.3,<6" (esp_driver_gpio/esp_driver_spi from 5.3; '
                "IDF 6's picolibc not verified with micro-ROS)",
            )
        check_interface_depends(app, problems)
        check_pin_defaults(app, problems)
        defaults = kconfig_defaults(app / "main" / "Kconfig.projbuild")
        for option in COMMON_OPTIONS:
            if option not in defaults:
                problems.add(app, f"Kconfig lacks {option}")
        for option in set(NETWORK_FALLBACKS) & set(defaults):
            problems.add(app, f"{option} belongs to components/espdock_uros/Kconfig, not the app")
        check_nvs_partition(app, problems)
        if not re.search(r"^CONFIG_APP_REPRODUCIBLE_BUILD=y$", (app / "sdkconfig.defaults").read_text(), re.M):
            problems.add(app, "sdkconfig.defaults lacks CONFIG_APP_REPRODUCIBLE_BUILD=y (bit-identical builds)")
        for option, value in REQUIRED_DEFAULTS.get(app.name, {}).items():
            if defaults.get(option) != value:
                problems.add(app, f"{option} defaults to {defaults.get(option)!r}, expected {value!r}")
        args = check_colcon_meta(app, problems)
        check_entity_counts(app, args.get("rmw_microxrcedds", {}), problems)
        check_transport(root / "components" / "espdock_uros", app, args.get("rmw_microxrcedds", {}), problems)
        if app.name == "led_strip_node" and "rclc_subscription_init_best_effort(" not in app_sources(app):
            # A reliable input stream holds HISTORY_INPUT x MTU bytes; a longer /qr_message can never be
            # reassembled and jams it: the colour subscription must be best effort (firmware/README.md).
            problems.add(app, "the /qr_message subscription must be best effort (a long message jams a reliable one)")
        if app.name == "camera_node":
            check_camera_stream(app, args, defaults, problems)
            check_camera_ranges(app / "main" / "camera_config.h", Path(msg_file), problems)
    return problems.finish(f"firmware conventions of {len(apps)} app(s)")


def main(argv: list[str]) -> int:
    if len(argv) >= 2 and argv[0] == "kconfig":
        return cmd_kconfig(argv[1:])
    if len(argv) >= 2 and argv[0] == "package-xml":
        return cmd_package_xml(argv[1:])
    if len(argv) == 3 and argv[0] == "apps":
        return cmd_apps(argv[1], argv[2])
    print(__doc__, file=sys.stderr)
    return 2


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
