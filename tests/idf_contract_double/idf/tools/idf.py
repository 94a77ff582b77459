#!/usr/bin/env python3
"""contract double: stands in for ESP-IDF v5.3.5's idf.py, because ESP-IDF, its CMake build
and the Espressif cross compilers cannot be fetched here.

It honours the part of idf.py's contract espdock relies on: the global options -C/-B/-D/-p/-b,
the actions build, reconfigure, set-target, fullclean, clean, menuconfig (a no-op here),
flash and monitor, IDF's target checks, EXTRA_COMPONENT_DIRS, the micro-ROS component's
configure-time `make -f libmicroros.mk`, sdkconfig from kconfgen (esp-idf-kconfig, the tool
IDF runs) and the build outputs IDF v5.3 writes (bootloader, partition table, app .bin/.elf/
.map, flasher_args.json, flash_args, project_description.json). No C is compiled: each source
is checked (no #error taken, every ROS header it includes exists in the micro-ROS component),
and the ELF files are synthesised from a digest of the inputs, then turned into real ESP
images by esptool's elf2image, as IDF does. Failures exit with status 2, as idf.py does.
"""

from __future__ import annotations

import argparse
import csv
import hashlib
import json
import os
import re
import shutil
import struct
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import cmakelite

IDF_VERSION = "5.3.5"
IDF_VER = f"v{IDF_VERSION}"
PROG = "idf.py"
SUPPORTED_TARGETS = ["esp32", "esp32s2", "esp32c3", "esp32s3", "esp32c2", "esp32c6", "esp32h2", "esp32p4"]
PREVIEW_TARGETS = ["linux", "esp32c5", "esp32c61"]
XTENSA_TARGETS = {"esp32", "esp32s2", "esp32s3"}
# espressif/esp32-camera's CMakeLists.txt adds its driver sources (driver/esp_camera.c, sensors/,
# target/<chip>/) only for these targets; elsewhere the component holds only the JPEG/BMP
# conversions, so an app calling the driver does not link.
CAMERA_DRIVER_TARGETS = {"esp32", "esp32s2", "esp32s3"}
CAMERA_DRIVER_SYMBOLS = re.compile(r"\b(esp_camera_(?:init|deinit|fb_get|fb_return|sensor_get|return_all))\s*\(")
# ESP-IDF v5.3.5's own components, so REQUIRES naming one of them resolves.
IDF_COMPONENTS = set(
    "app_trace app_update bootloader bootloader_support bt cmock console cxx driver efuse esp-tls esp_adc "
    "esp_app_format esp_bootloader_format esp_coex esp_common esp_driver_ana_cmpr esp_driver_cam esp_driver_dac "
    "esp_driver_gpio esp_driver_gptimer esp_driver_i2c esp_driver_i2s esp_driver_isp esp_driver_jpeg "
    "esp_driver_ledc esp_driver_mcpwm esp_driver_parlio esp_driver_pcnt esp_driver_ppa esp_driver_rmt "
    "esp_driver_sdio esp_driver_sdm esp_driver_sdmmc esp_driver_sdspi esp_driver_spi esp_driver_touch_sens "
    "esp_driver_tsens esp_driver_uart esp_driver_usb_serial_jtag esp_eth esp_event esp_gdbstub esp_hid "
    "esp_http_client esp_http_server esp_https_ota esp_https_server esp_hw_support esp_lcd esp_local_ctrl esp_mm "
    "esp_netif esp_netif_stack esp_partition esp_phy esp_pm esp_psram esp_ringbuf esp_rom esp_system esp_timer "
    "esp_vfs_console esp_wifi espcoredump esptool_py fatfs freertos hal heap http_parser idf_test ieee802154 json "
    "linux log lwip mbedtls mqtt newlib nvs_flash nvs_sec_provider openthread partition_table perfmon protobuf-c "
    "protocomm pthread riscv sdmmc soc spi_flash spiffs tcp_transport touch_element ulp unity usb vfs "
    "wear_levelling wifi_provisioning wpa_supplicant xtensa".split()
)
# Headers of ESP-IDF v5.3.5 components that the double checks a source can see, and the public
# REQUIRES of the IDF components through which they can reach it (from each component's
# CMakeLists.txt in v5.3.5; private ones do not propagate). A source sees a component's headers
# only when its component requires it, directly or through public REQUIRES, as in IDF; `main`
# without REQUIRES sees every component. Other IDF headers are assumed visible.
IDF_HEADER_OWNERS = {
    "driver/gpio.h": "esp_driver_gpio",
    "driver/spi_master.h": "esp_driver_spi",
    "driver/spi_common.h": "esp_driver_spi",
    "esp_wifi.h": "esp_wifi",
    "esp_eth.h": "esp_eth",
    "nvs_flash.h": "nvs_flash",
    "esp_netif.h": "esp_netif",
}
IDF_PUBLIC_REQUIRES = {
    "driver": (
        "esp_pm",
        "esp_ringbuf",
        "freertos",
        "soc",
        "hal",
        "esp_hw_support",
        "esp_driver_gpio",
        "esp_driver_pcnt",
        "esp_driver_gptimer",
        "esp_driver_spi",
        "esp_driver_mcpwm",
        "esp_driver_ana_cmpr",
        "esp_driver_i2s",
        "esp_driver_sdmmc",
        "esp_driver_sdspi",
        "esp_driver_sdio",
        "esp_driver_dac",
        "esp_driver_rmt",
        "esp_driver_tsens",
        "esp_driver_sdm",
        "esp_driver_i2c",
        "esp_driver_uart",
        "esp_driver_ledc",
        "esp_driver_parlio",
        "esp_driver_usb_serial_jtag",
    ),
    "esp_lcd": ("driver", "esp_driver_gpio", "esp_driver_i2c", "esp_driver_spi"),
    "esp_driver_sdmmc": ("sdmmc", "esp_driver_gpio"),
    "esp_driver_sdspi": ("sdmmc", "esp_driver_spi", "esp_driver_gpio"),
    "esp_driver_spi": ("esp_pm",),
    "esp_wifi": ("esp_event", "esp_phy", "esp_netif"),
    "esp_eth": ("esp_event",),
    "esp_netif": ("esp_event",),
    "nvs_flash": ("esp_partition",),
    "lwip": (),
}
# First path elements (prefixes) of headers that only the micro-ROS component provides.
ROS_HEADER_PREFIXES = (
    "rcl",
    "rmw",
    "rosidl",
    "micro_ros_utilities",
    "std_msgs",
    "sensor_msgs",
    "builtin_interfaces",
    "rcutils",
    "geometry_msgs",
    "micro_ros_msgs",
    "uxr",
    "ucdr",
    "espdock_double",
)
# Partition tables IDF v5.3 ships, as (name, type, subtype, offset, size, flags) rows.
BUILTIN_TABLES = {
    "partitions_singleapp.csv": [
        ("nvs", "data", "nvs", "", "0x6000", ""),
        ("phy_init", "data", "phy", "", "0x1000", ""),
        ("factory", "app", "factory", "", "1M", ""),
    ],
    "partitions_singleapp_large.csv": [
        ("nvs", "data", "nvs", "", "0x6000", ""),
        ("phy_init", "data", "phy", "", "0x1000", ""),
        ("factory", "app", "factory", "", "1500K", ""),
    ],
    "partitions_two_ota.csv": [
        ("nvs", "data", "nvs", "", "0x4000", ""),
        ("otadata", "data", "ota", "", "0x2000", ""),
        ("phy_init", "data", "phy", "", "0x1000", ""),
        ("factory", "app", "factory", "", "1M", ""),
        ("ota_0", "app", "ota_0", "", "1M", ""),
        ("ota_1", "app", "ota_1", "", "1M", ""),
    ],
}
PART_TYPES = {"app": 0x00, "data": 0x01}
PART_SUBTYPES = {
    "app": {"factory": 0x00, "test": 0x20, **{f"ota_{i}": 0x10 + i for i in range(16)}},
    "data": {
        "ota": 0x00,
        "phy": 0x01,
        "nvs": 0x02,
        "coredump": 0x03,
        "nvs_keys": 0x04,
        "efuse": 0x05,
        "undefined": 0x06,
        "esphttpd": 0x80,
        "fat": 0x81,
        "spiffs": 0x82,
        "littlefs": 0x83,
    },
}


class FatalError(Exception):
    """What idf.py prints before exiting with status 2."""


def out(text: str = "") -> None:
    print(text, flush=True)


# ---------------------------------------------------------------- arguments


def parse_args(argv: list[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog=PROG,
        description="ESP-IDF CLI build management tool (espdock contract double of ESP-IDF v5.3.5)",
    )
    parser.add_argument("--version", action="store_true", help="Show IDF version and exit.")
    parser.add_argument("-C", "--project-dir", default=os.getcwd(), help="Project directory.")
    parser.add_argument("-B", "--build-dir", default=None, help="Build directory.")
    parser.add_argument(
        "-D",
        "--define-cache-entry",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="Create a cmake cache entry (repeatable).",
    )
    parser.add_argument("-p", "--port", default=os.environ.get("ESPPORT"), help="Serial port.")
    parser.add_argument(
        "-b", "--baud", type=int, default=int(os.environ.get("ESPBAUD", "460800")), help="Baud rate for flashing."
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="Verbose build output.")
    parser.add_argument("--preview", action="store_true", help="Enable IDF features that are still in preview.")
    parser.add_argument(
        "-G", "--cmake-generator", dest="generator", default=None, help="CMake generator (accepted, unused)."
    )
    parser.add_argument(
        "--ccache", dest="ccache", action="store_true", default=os.environ.get("IDF_CCACHE_ENABLE") == "1"
    )
    parser.add_argument("--no-ccache", dest="ccache", action="store_false")
    parser.add_argument("--no-hints", action="store_true", help="Accepted for compatibility.")
    parser.add_argument(
        "actions",
        nargs="*",
        help="build | all | reconfigure | set-target T | fullclean | clean | "
        "clean-microros | menuconfig | flash | monitor",
    )
    return parser.parse_intermixed_args(argv)


def plan_actions(tokens: list[str]) -> list[tuple[str, str | None]]:
    """ACTIONS in the order idf.py runs them, with dependencies added (flash needs a build)."""
    known = {
        "build",
        "all",
        "reconfigure",
        "set-target",
        "fullclean",
        "clean",
        "clean-microros",
        "menuconfig",
        "save-defconfig",
        "flash",
        "monitor",
    }
    actions: list[tuple[str, str | None]] = []
    it = iter(tokens)
    for token in it:
        if token not in known:
            raise FatalError(f"Error: No such command '{token}'.")
        if token == "set-target":
            target = next(it, None)
            if target is None:
                raise FatalError("Error: Missing argument 'IDF_TARGET'.")
            actions.append((token, target.lower().replace("-", "")))
        else:
            actions.append(("build" if token == "all" else token, None))
    names = [a for a, _ in actions]
    if "set-target" in names and "fullclean" not in names:
        actions.insert(0, ("fullclean", None))
    if "flash" in names and "build" not in names:
        actions.insert(names.index("flash") + (1 if "set-target" in names else 0), ("build", None))
    order = {
        "fullclean": 0,
        "clean": 0,
        "clean-microros": 0,
        "set-target": 1,
        "menuconfig": 2,
        "reconfigure": 3,
        "save-defconfig": 3,
        "build": 4,
        "flash": 5,
        "monitor": 6,
    }
    return sorted(dict.fromkeys(actions), key=lambda a: order[a[0]])


# ---------------------------------------------------------------- context


@dataclass
class Component:
    name: str
    path: Path
    priority: int
    reg: cmakelite.Registration | None = None
    micro_ros: str | None = None  # "source" (runs libmicroros.mk) or "prebuilt"
    include_dirs: list[Path] = field(default_factory=list)
    priv_include_dirs: list[Path] = field(default_factory=list)
    sources: list[Path] = field(default_factory=list)
    included: list[str] = field(default_factory=list)  # the files its CMakeLists include()s


@dataclass
class Project:
    name: str
    components: dict[str, Component]
    managed: set[str]
    sdkconfig: Path
    defaults: list[Path]
    config: dict[str, object]
    target: str


class Context:
    def __init__(self, args: argparse.Namespace) -> None:
        self.args = args
        self.project_dir = Path(os.path.realpath(args.project_dir))
        build = args.build_dir or str(self.project_dir / "build")
        self.build_dir = Path(os.path.realpath(build))
        if self.build_dir == self.project_dir:
            raise FatalError(
                "Setting the build directory to the project directory is not supported. Suggest dropping "
                "--build-dir option, the default is a 'build' subdirectory inside the project directory."
            )
        self.idf_path = Path(os.environ.get("IDF_PATH") or Path(__file__).resolve().parent.parent)
        self.defines = self._defines(args.define_cache_entry)
        self.env = dict(os.environ)
        # namespace/name of every registry dependency in the components' idf_component.yml.
        self.registry_dependencies: set[str] = set()
        # save-defconfig's output, which kconfgen then writes too.
        self.savedefconfig: Path | None = None

    @staticmethod
    def _defines(entries: list[str]) -> dict[str, str]:
        defines: dict[str, str] = {}
        for entry in entries:
            name, sep, value = entry.partition("=")
            if not sep:
                raise FatalError(
                    f"Error: Invalid value for '-D' / '--define-cache-entry': '{entry}' is not NAME=VALUE."
                )
            defines[name.split(":")[0]] = value
        return defines

    @property
    def cache_path(self) -> Path:
        return self.build_dir / "CMakeCache.txt"

    def read_cache(self) -> dict[str, str]:
        cache: dict[str, str] = {}
        if self.cache_path.is_file():
            for line in self.cache_path.read_text(errors="replace").splitlines():
                m = re.match(r"^([^#/:=]+):([^:=]+)=(.*)$", line)
                if m:
                    cache[m.group(1)] = m.group(3)
        return cache

    def sdkconfig_path(self) -> Path:
        if "SDKCONFIG" in self.defines:
            return Path(os.path.abspath(self.defines["SDKCONFIG"]))
        desc = self.build_dir / "project_description.json"
        try:
            return Path(json.loads(desc.read_text())["config_file"])
        except (OSError, ValueError, KeyError):
            return self.project_dir / "sdkconfig"


def sdkconfig_value(path: Path, key: str) -> str | None:
    if not path.is_file():
        return None
    value = None
    for line in path.read_text(errors="replace").splitlines():
        m = re.match(rf'^{key}="?([^"]*)"?$', line)
        if m:
            value = m.group(1)
    return value


# ---------------------------------------------------------------- target


def target_sources(ctx: Context, set_target: bool) -> tuple[Path, str | None, str | None, str | None, str | None]:
    """Where a target can come from: (sdkconfig path, its target, environment, CMakeCache.txt, -D)."""
    sdkconfig = ctx.sdkconfig_path()
    from_sdkconfig = None if set_target else sdkconfig_value(sdkconfig, "CONFIG_IDF_TARGET")
    from_env = ctx.env.get("IDF_TARGET") or None
    return sdkconfig, from_sdkconfig, from_env, ctx.read_cache().get("IDF_TARGET"), ctx.defines.get("IDF_TARGET")


def check_target_settings(ctx: Context, set_target: bool) -> None:
    """idf.py's cross-check of sdkconfig, CMakeCache.txt and the environment, before CMake runs."""
    sdkconfig, from_sdkconfig, from_env, from_cache, from_cmdl = target_sources(ctx, set_target)
    if from_env:
        if from_sdkconfig and from_sdkconfig != from_env:
            raise FatalError(
                f"Project sdkconfig '{sdkconfig}' was generated for target '{from_sdkconfig}', but environment "
                f"variable IDF_TARGET is set to '{from_env}'. Run '{PROG} set-target {from_env}' to generate new "
                f"sdkconfig file for target {from_env}."
            )
        if from_cache and from_cache != from_env:
            raise FatalError(
                f"Target settings are not consistent: '{from_env}' in the environment, '{from_cache}' in "
                f"CMakeCache.txt. Run '{PROG} fullclean' to start again."
            )
        if from_cmdl and from_cmdl != from_env:
            raise FatalError(
                f"Target '{from_cmdl}' specified on command line is not consistent with target '{from_env}' in "
                "the environment."
            )
    elif from_cmdl:
        if from_cache and from_cache != from_cmdl:
            raise FatalError(
                f"Target '{from_cmdl}' specified on command line is not consistent with target '{from_cache}' in "
                f"CMakeCache.txt. Run '{PROG} set-target {from_cmdl}' to re-generate CMakeCache.txt."
            )
    elif from_cache and from_sdkconfig and from_cache != from_sdkconfig:
        raise FatalError(
            f"Project sdkconfig '{sdkconfig}' was generated for target '{from_sdkconfig}', but CMakeCache.txt "
            f"contains '{from_cache}'. To keep the setting in sdkconfig ({from_sdkconfig}) and re-generate "
            f"CMakeCache.txt, run '{PROG} fullclean'. To re-generate sdkconfig for '{from_cache}' target, run "
            f"'{PROG} set-target {from_cache}'."
        )


def select_target(ctx: Context, set_target: bool) -> str:
    """project.cmake's __target_init: environment, then cache (-D wins over it), then a guess."""
    sdkconfig, from_sdkconfig, from_env, from_cache, from_cmdl = target_sources(ctx, set_target)
    target = from_env or from_cmdl or from_cache
    if not target:
        defaults_env = ctx.defines.get("SDKCONFIG_DEFAULTS") or ctx.env.get("SDKCONFIG_DEFAULTS")
        candidates = [sdkconfig, ctx.project_dir / "sdkconfig"]
        candidates += (
            [Path(p) for p in defaults_env.split(";")] if defaults_env else [ctx.project_dir / "sdkconfig.defaults"]
        )
        for candidate in candidates:
            guess = sdkconfig_value(
                candidate if candidate.is_absolute() else ctx.project_dir / candidate, "CONFIG_IDF_TARGET"
            )
            if guess:
                out(f"-- IDF_TARGET is not set, guessed '{guess}' from sdkconfig '{candidate}'")
                target = guess
                break
        else:
            target = "esp32"
            out(f"-- IDF_TARGET not set, using default target: {target}")
    if from_cache and from_cache != target:
        raise cmakelite.CMakeError(
            f"CMake Error at {ctx.idf_path}/tools/cmake/targets.cmake:85 (message):\n   IDF_TARGET '{from_cache}' in "
            f"CMake cache does not match currently selected IDF_TARGET '{target}'. To change the target, clear the "
            "build directory and sdkconfig file, and build the project again."
        )
    if from_sdkconfig and from_sdkconfig != target:
        raise cmakelite.CMakeError(
            f"CMake Error at {ctx.idf_path}/tools/cmake/targets.cmake:97 (message):\n   Target '{from_sdkconfig}' in "
            f"sdkconfig '{sdkconfig}' does not match currently selected IDF_TARGET '{target}'. To change the target, "
            "clear the build directory and sdkconfig file, and build the project again."
        )
    if target not in SUPPORTED_TARGETS and not (ctx.args.preview and target in PREVIEW_TARGETS):
        raise cmakelite.CMakeError(
            f"CMake Error at {ctx.idf_path}/tools/cmake/targets.cmake:170 (message):\n  Toolchain file "
            f"{ctx.idf_path}/tools/cmake/toolchain-{target}.cmake not found"
        )
    return target


# ---------------------------------------------------------------- configure


def run_configure(ctx: Context, set_target: str | None = None) -> Project:
    """What `cmake` does for an IDF project; raises CMakeError like CMake would fail."""
    if set_target:
        ctx.defines["IDF_TARGET"] = set_target
    check_target_settings(ctx, set_target is not None)
    out(f"Running cmake in directory {ctx.build_dir}")
    out(
        f'Executing "cmake -G Ninja -DPYTHON_DEPS_CHECKED=1 -DPYTHON={sys.executable} -DESP_PLATFORM=1 '
        + "".join(f"-D{k}={v} " for k, v in ctx.defines.items())
        + f'{ctx.project_dir}"...'
    )
    sdkconfig = ctx.sdkconfig_path()
    if set_target and sdkconfig.exists():
        sdkconfig.rename(str(sdkconfig) + ".old")
        out(f"-- Existing sdkconfig '{sdkconfig}' renamed to '{sdkconfig}.old'.")
    target = select_target(ctx, set_target is not None)
    out(f"-- Building ESP-IDF components for target {target}")
    ctx.env["IDF_TARGET"] = target

    project_cmake = ctx.idf_path / "tools" / "cmake" / "project.cmake"
    top = cmakelite.Interpreter(
        {
            **ctx.defines,
            "CMAKE_CURRENT_LIST_DIR": str(ctx.project_dir),
            "CMAKE_CURRENT_SOURCE_DIR": str(ctx.project_dir),
            "CMAKE_SOURCE_DIR": str(ctx.project_dir),
            "CMAKE_BINARY_DIR": str(ctx.build_dir),
            "CMAKE_CURRENT_BINARY_DIR": str(ctx.build_dir),
            "IDF_TARGET": target,
            "IDF_PATH": str(ctx.idf_path),
            "__DOUBLE_IDF_PROJECT_CMAKE": str(project_cmake),
        },
        ctx.env,
        out,
    )
    top.run_file(ctx.project_dir / "CMakeLists.txt")
    if top.project_name is None:
        raise cmakelite.CMakeError(
            f"CMake Warning (dev) in CMakeLists.txt:\n  No project() command is present.\n\n"
            f"CMake Error: {ctx.project_dir}/CMakeLists.txt does not call project(), so there is no IDF project."
        )
    if not top.vars.get("__DOUBLE_IDF_INCLUDED"):
        raise cmakelite.CMakeError(
            f"CMake Error at {ctx.project_dir}/CMakeLists.txt:{top.project_line} (project):\n  project() is called "
            f"without include($ENV{{IDF_PATH}}/tools/cmake/project.cmake) before it: this is not an ESP-IDF project."
        )
    name = top.project_name

    components, managed = discover_components(ctx, top)
    prepare_dependencies(ctx)
    for component in components.values():
        if (component.path / "libmicroros.mk").is_file():
            component.micro_ros = "source"
        elif "libmicroros.a" in (component.path / "CMakeLists.txt").read_text(errors="replace"):
            component.micro_ros = "prebuilt"

    # IDF v5.3 project.cmake: the environment's, unless the variable is set (-D, or set() in the CMakeLists).
    defaults_spec = (
        top.sdkconfig_defaults_at_project or ctx.defines.get("SDKCONFIG_DEFAULTS") or ctx.env.get("SDKCONFIG_DEFAULTS")
    )
    defaults: list[Path] = []
    for item in defaults_spec.split(";") if defaults_spec else ["sdkconfig.defaults"]:
        path = Path(item) if os.path.isabs(item) else ctx.project_dir / item
        if not path.is_file():
            if defaults_spec:
                raise cmakelite.CMakeError(
                    f"CMake Error at {ctx.idf_path}/tools/cmake/kconfig.cmake:160 (message):\n"
                    f"  SDKCONFIG_DEFAULTS '{path}' does not exist."
                )
            continue
        defaults.append(path)
        if Path(f"{path}.{target}").is_file():
            defaults.append(Path(f"{path}.{target}"))
    config = run_kconfgen(ctx, target, components, sdkconfig, defaults)

    for component in components.values():
        evaluate_component(ctx, component, target, name, config)
    check_requirements(components, managed)
    for component in components.values():
        if component.micro_ros == "source":
            build_micro_ros(ctx, component, target)

    write_cache(ctx, target)
    write_project_description(ctx, name, target, components, sdkconfig, defaults, config)
    write_ninja_manifest(ctx, top, components)
    out("-- Configuring done")
    out("-- Generating done")
    out(f"-- Build files have been written to: {ctx.build_dir}")
    return Project(name, components, managed, sdkconfig, defaults, config, target)


def discover_components(ctx: Context, top: cmakelite.Interpreter) -> tuple[dict[str, Component], set[str]]:
    """Components by name, higher priority winning: project ones over EXTRA_COMPONENT_DIRS ones."""
    found: dict[str, Component] = {}

    def add(path: Path, priority: int) -> None:
        comp = Component(path.name, path, priority)
        if comp.name not in found or found[comp.name].priority <= priority:
            found[comp.name] = comp

    for entry in top.extra_component_dirs_at_project:
        path = Path(os.path.normpath(entry if os.path.isabs(entry) else ctx.project_dir / entry))
        if not path.exists():
            raise cmakelite.CMakeError(
                f"CMake Error at {ctx.idf_path}/tools/cmake/project.cmake:472 (message):\n  Directory specified in "
                f"EXTRA_COMPONENT_DIRS doesn't exist: {path}"
            )
        if (path / "CMakeLists.txt").is_file():
            add(path, 1)
        else:
            for sub in sorted(path.iterdir()):
                if sub.is_dir() and (sub / "CMakeLists.txt").is_file():
                    add(sub, 1)
    project_components = ctx.project_dir / "components"
    if project_components.is_dir():
        for sub in sorted(project_components.iterdir()):
            if sub.is_dir() and (sub / "CMakeLists.txt").is_file():
                add(sub, 2)
    main = ctx.project_dir / "main"
    if (main / "CMakeLists.txt").is_file():
        add(main, 3)

    managed: set[str] = set()
    for comp in found.values():
        manifest = comp.path / "idf_component.yml"
        if manifest.is_file():
            # Registry dependencies the component manager would download (the double cannot).
            for m in re.finditer(
                r"^\s+([A-Za-z0-9_.-]+/[A-Za-z0-9_.-]+|[A-Za-z0-9_.-]+)\s*:", manifest.read_text(), re.M
            ):
                dep = m.group(1)
                if dep == "idf" or dep in ("version", "rules", "path", "git", "override_path", "require", "public"):
                    continue
                managed.add(dep.split("/")[-1])
                managed.add(dep.replace("/", "__"))
                ctx.registry_dependencies.add(dep if "/" in dep else f"espressif/{dep}")
    return found, managed


def prepare_dependencies(ctx: Context) -> None:
    """Where the IDF component manager puts what it resolves, at configure time: the download
    cache ($IDF_COMPONENT_CACHE_PATH, else ~/.cache/Espressif/ComponentManager), the extracted
    components in <project>/managed_components/<namespace>__<name> (a fixed place in component
    manager 2.x), and <project>/dependencies.lock when there is none. The double downloads
    nothing: each component is a marker directory, and the lock carries no hashes."""
    if not ctx.registry_dependencies:
        return
    cache = Path(
        ctx.env.get("IDF_COMPONENT_CACHE_PATH")
        or Path(ctx.env.get("HOME", "/tmp")) / ".cache" / "Espressif" / "ComponentManager"
    )
    managed = ctx.project_dir / "managed_components"
    for dep in sorted(ctx.registry_dependencies):
        cached = cache / dep.replace("/", "__")
        if cached.is_dir():
            out(f"NOTICE: Using {dep} from the component cache {cache}")
        else:
            out(f"NOTICE: Downloading {dep} into the component cache {cache}")
            cached.mkdir(parents=True, exist_ok=True)
            (cached / "idf_component.yml").write_text(f"# contract double: stands in for {dep}\n")
        target = managed / dep.replace("/", "__")
        if target.exists():
            shutil.rmtree(target)
        shutil.copytree(cached, target)
    lock = ctx.project_dir / "dependencies.lock"
    if not lock.exists():
        lock.write_text(
            "# contract double: shaped like a component manager 2.x lock, without hashes\n"
            "dependencies:\n"
            + "".join(f"  {dep}:\n    source:\n      type: service\n" for dep in sorted(ctx.registry_dependencies))
            + "version: 2.0.0\n"
        )


def run_kconfgen(
    ctx: Context, target: str, components: dict[str, Component], sdkconfig: Path, defaults: list[Path]
) -> dict[str, object]:
    config_dir = ctx.build_dir / "config"
    config_dir.mkdir(parents=True, exist_ok=True)
    kconfigs = [str(c.path / "Kconfig") for c in components.values() if (c.path / "Kconfig").is_file()]
    projbuilds = [
        str(c.path / "Kconfig.projbuild") for c in components.values() if (c.path / "Kconfig.projbuild").is_file()
    ]
    (ctx.build_dir / "kconfigs.in").write_text("".join(f'source "{k}"\n' for k in kconfigs))
    (ctx.build_dir / "kconfigs_projbuild.in").write_text("".join(f'source "{k}"\n' for k in projbuilds))
    env = {
        "COMPONENT_KCONFIGS": ";".join(kconfigs),
        "COMPONENT_KCONFIGS_PROJBUILD": ";".join(projbuilds),
        "COMPONENT_SDKCONFIG_RENAMES": "",
        "IDF_TARGET": target,
        "IDF_TOOLCHAIN": "gcc",
        "IDF_VERSION": IDF_VERSION,
        "IDF_ENV_FPGA": "",
        "IDF_PATH": str(ctx.idf_path),
        "IDF_INIT_VERSION": IDF_VERSION,
        "COMPONENT_KCONFIGS_SOURCE_FILE": str(ctx.build_dir / "kconfigs.in"),
        "COMPONENT_KCONFIGS_PROJBUILD_SOURCE_FILE": str(ctx.build_dir / "kconfigs_projbuild.in"),
    }
    (ctx.build_dir / "config.env").write_text(json.dumps(env, indent=4) + "\n")
    argv = [
        sys.executable,
        "-m",
        "kconfgen",
        "--list-separator=semicolon",
        "--kconfig",
        str(ctx.idf_path / "Kconfig"),
        "--sdkconfig-rename",
        str(ctx.idf_path / "sdkconfig.rename"),
        "--config",
        str(sdkconfig),
    ]
    for d in defaults:
        argv += ["--defaults", str(d)]
    argv += [
        "--env-file",
        str(ctx.build_dir / "config.env"),
        "--output",
        "header",
        str(config_dir / "sdkconfig.h"),
        "--output",
        "cmake",
        str(config_dir / "sdkconfig.cmake"),
        "--output",
        "json",
        str(config_dir / "sdkconfig.json"),
        "--output",
        "config",
        str(sdkconfig),
    ]
    if ctx.savedefconfig is not None:
        argv += ["--output", "savedefconfig", str(ctx.savedefconfig)]
    result = subprocess.run(argv, capture_output=True, text=True, check=False)
    for line in (result.stdout + result.stderr).splitlines():
        out(line)
    if result.returncode != 0:
        raise cmakelite.CMakeError(
            f"CMake Error at {ctx.idf_path}/tools/cmake/kconfig.cmake:222 (message):\n  Failed to run kconfgen "
            f"({' '.join(argv[:4])} ...). Error {result.returncode}"
        )
    return json.loads((config_dir / "sdkconfig.json").read_text())


def evaluate_component(ctx: Context, comp: Component, target: str, project: str, config: dict[str, object]) -> None:
    variables = {
        "COMPONENT_DIR": str(comp.path),
        "COMPONENT_PATH": str(comp.path),
        "COMPONENT_NAME": comp.name,
        "COMPONENT_ALIAS": comp.name,
        "COMPONENT_LIB": f"__idf_{comp.name}",
        "CMAKE_CURRENT_LIST_DIR": str(comp.path),
        "CMAKE_CURRENT_SOURCE_DIR": str(comp.path),
        "CMAKE_SOURCE_DIR": str(ctx.project_dir),
        "CMAKE_BINARY_DIR": str(ctx.build_dir),
        "CMAKE_CURRENT_BINARY_DIR": str(ctx.build_dir / "esp-idf" / comp.name),
        "PROJECT_DIR": str(ctx.project_dir),
        "PROJECT_NAME": project,
        "IDF_TARGET": target,
        "IDF_PATH": str(ctx.idf_path),
        "BUILD_DIR": str(ctx.build_dir),
        "CMAKE_C_COMPILER": "gcc",
        "CMAKE_CXX_COMPILER": "g++",
        "CMAKE_AR": "ar",
        "IDF_VERSION_MAJOR": "5",
        "IDF_VERSION_MINOR": "3",
        "IDF_VERSION_PATCH": "5",
        "IDF_VER": IDF_VER,
    }
    # IDF's early expansion: requirements are read with no sdkconfig yet (no CONFIG_* variables),
    # and those are the requirements the build uses; Kconfig may choose sources, never REQUIRES.
    early = cmakelite.Interpreter(dict(variables), ctx.env, lambda text: None)
    early.run_file(comp.path / "CMakeLists.txt")
    for key, value in config.items():
        variables[f"CONFIG_{key}"] = "y" if value is True else ("" if value is False else str(value))
    interp = cmakelite.Interpreter(variables, ctx.env, out)
    interp.run_file(comp.path / "CMakeLists.txt")
    comp.included = interp.included
    if not interp.registrations:
        comp.reg = cmakelite.Registration()
        return
    reg = comp.reg = interp.registrations[-1]
    if early.registrations:
        reg.requires = early.registrations[-1].requires
        reg.priv_requires = early.registrations[-1].priv_requires
    where = f"{comp.path}/CMakeLists.txt:{reg.line}"

    def resolve(items: list[str]) -> list[Path]:
        return [Path(os.path.normpath(i if os.path.isabs(i) else comp.path / i)) for i in items]

    for kind in ("include_dirs", "priv_include_dirs"):
        dirs = resolve(getattr(reg, kind))
        for d in dirs:
            if not d.is_dir():
                raise cmakelite.CMakeError(
                    f"CMake Error at {ctx.idf_path}/tools/cmake/component.cmake:321 (message):\n  Include directory "
                    f"'{d}' is not a directory.\nCall Stack (most recent call first):\n"
                    f"  {where} (idf_component_register)"
                )
        setattr(comp, kind, dirs)
    sources = resolve(reg.srcs)
    for src_dir in resolve(reg.src_dirs):
        if not src_dir.is_dir():
            raise cmakelite.CMakeError(
                f"CMake Error at {where} (idf_component_register):\n  SRC_DIRS entry '{src_dir}' does not exist"
            )
        sources += sorted(p for p in src_dir.iterdir() if p.suffix in (".c", ".cpp", ".cc", ".S"))
    excluded = set(resolve(reg.exclude_srcs))
    comp.sources = [s for s in dict.fromkeys(sources) if s not in excluded]
    for src in comp.sources:
        if not src.is_file():
            raise cmakelite.CMakeError(
                f"CMake Error at {ctx.idf_path}/tools/cmake/component.cmake:539 (add_library):\n  Cannot find source "
                f"file:\n\n    {src}\nCall Stack (most recent call first):\n  {where} (idf_component_register)"
            )


def check_requirements(components: dict[str, Component], managed: set[str]) -> None:
    for comp in components.values():
        reg = comp.reg or cmakelite.Registration()
        for req in reg.requires + reg.priv_requires:
            if req not in components and req not in IDF_COMPONENTS and req not in managed:
                raise cmakelite.CMakeError(
                    f"CMake Error at /opt/esp/idf/tools/cmake/build.cmake:300 (message):\n  Failed to resolve "
                    f"component '{req}'.\nCall Stack (most recent call first):\n  {comp.path}/CMakeLists.txt "
                    f"(idf_component_register)"
                )


def build_micro_ros(ctx: Context, comp: Component, target: str) -> None:
    """The configure-time `make -f libmicroros.mk` of micro_ros_espidf_component's CMakeLists."""
    app_meta = ctx.project_dir / "app-colcon.meta"
    extra = ctx.project_dir / "extra_ros_packages"
    argv = [
        "make",
        "-j",
        "-f",
        "libmicroros.mk",
        "X_CC=gcc",
        "X_AR=ar",
        "X_CXX=g++",
        "C_STANDARD=17",
        "MIDDLEWARE=microxrcedds",
        f"BUILD_DIR={ctx.build_dir}",
        "IDF_INCLUDES=",
        f"IDF_PATH={ctx.idf_path}",
        f"IDF_TARGET={target}",
        f"APP_COLCON_META={app_meta if app_meta.is_file() else ''}",
        f"EXTRA_ROS_PACKAGES={extra if extra.is_dir() else comp.path / 'extra_packages'}",
    ]
    process = subprocess.Popen(
        argv, cwd=comp.path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, errors="replace", env=ctx.env
    )
    assert process.stdout is not None
    for line in process.stdout:
        print(line, end="", flush=True)
    code = process.wait()
    if code != 0:
        raise cmakelite.CMakeError(f"CMake Error at {comp.path}/CMakeLists.txt (message):\n  FAILED: {code}")


def write_cache(ctx: Context, target: str) -> None:
    lines = [
        "# This is the CMakeCache file.",
        "# contract double: written by the espdock IDF contract double's idf.py (no CMake ran).",
        f"CMAKE_HOME_DIRECTORY:INTERNAL={ctx.project_dir}",
        "CMAKE_GENERATOR:INTERNAL=Ninja",
        f"IDF_TARGET:STRING={target}",
        "IDF_TOOLCHAIN:STRING=gcc",
        f"PYTHON:UNINITIALIZED={sys.executable}",
        f"CCACHE_ENABLE:UNINITIALIZED={int(ctx.args.ccache)}",
    ]
    lines += [f"{k}:UNINITIALIZED={v}" for k, v in ctx.defines.items() if k not in ("IDF_TARGET",)]
    ctx.cache_path.write_text("\n".join(lines) + "\n")


def toolchain_prefix(target: str) -> str:
    return f"xtensa-{target}-elf-" if target in XTENSA_TARGETS else "riscv32-esp-elf-"


def write_ninja_manifest(ctx: Context, top: cmakelite.Interpreter, components: dict[str, Component]) -> None:
    """build.ninja's rule to re-run CMake, as CMake's Ninja generator writes it: its implicit
    inputs are every file the configure read (CMake's list files: each CMakeLists.txt, each file
    they include(), IDF's CMAKE_CONFIGURE_DEPENDS such as a component's idf_component.yml),
    absolute, and CMakeCache.txt, relative to the build dir. The targets' own rules are not here:
    the double compiles nothing."""
    inputs = {str(ctx.project_dir / "CMakeLists.txt"), *top.included}
    for comp in components.values():
        inputs.add(str(comp.path / "CMakeLists.txt"))
        inputs.update(comp.included)
        if (comp.path / "idf_component.yml").is_file():
            inputs.add(str(comp.path / "idf_component.yml"))
    deps = " ".join(_ninja_escape(os.path.normpath(path)) for path in sorted(inputs))
    (ctx.build_dir / "build.ninja").write_text(
        "# CMAKE generated file: DO NOT EDIT!\n"
        '# Generated by "Ninja" Generator, CMake Version 3.30\n\n'
        "#############################################\n"
        "# Re-run CMake if any of its inputs changed.\n\n"
        f"build build.ninja: RERUN_CMAKE | {deps} CMakeCache.txt\n"
        "  pool = console\n"
    )


def _ninja_escape(path: str) -> str:
    return path.replace("$", "$$").replace(" ", "$ ").replace(":", "$:")


def write_project_description(
    ctx: Context,
    name: str,
    target: str,
    components: dict[str, Component],
    sdkconfig: Path,
    defaults: list[Path],
    config: dict[str, object],
) -> None:
    desc = {
        "version": "1.2",
        "project_name": name,
        "project_version": project_version(ctx, config),
        "project_path": str(ctx.project_dir),
        "idf_path": str(ctx.idf_path),
        "build_dir": str(ctx.build_dir),
        "config_file": str(sdkconfig),
        "config_defaults": ";".join(str(d) for d in defaults),
        "bootloader_elf": str(ctx.build_dir / "bootloader" / "bootloader.elf"),
        "app_elf": f"{name}.elf",
        "app_bin": f"{name}.bin",
        "build_type": "flash_app",
        "git_revision": IDF_VER,
        "target": target,
        "rev": "",
        "min_rev": str(config.get("ESP_REV_MIN_FULL", "")),
        "max_rev": str(config.get("ESP_REV_MAX_FULL", "")),
        "phy_data_partition": "",
        "monitor_baud": str(config.get("ESPTOOLPY_MONITOR_BAUD", 115200)),
        "monitor_toolprefix": toolchain_prefix(target),
        "c_compiler": f"{toolchain_prefix(target)}gcc",
        "config_environment": {
            "COMPONENT_KCONFIGS": ";".join(
                str(c.path / "Kconfig") for c in components.values() if (c.path / "Kconfig").is_file()
            ),
            "COMPONENT_KCONFIGS_PROJBUILD": ";".join(
                str(c.path / "Kconfig.projbuild")
                for c in components.values()
                if (c.path / "Kconfig.projbuild").is_file()
            ),
        },
        "common_component_reqs": [],
        "build_components": sorted(components),
        "build_component_paths": sorted(str(c.path) for c in components.values()),
        "build_component_info": {},
        "all_component_info": {},
        "debug_prefix_map_gdbinit": "",
        "gdbinit_files": {},
        "debug_arguments_openocd": "",
        "contract_double": "espdock IDF contract double: no compiler ran; images are synthesised",
    }
    (ctx.build_dir / "project_description.json").write_text(json.dumps(desc, indent=4) + "\n")


def project_version(ctx: Context, config: dict[str, object]) -> str:
    if config.get("APP_PROJECT_VER_FROM_CONFIG"):
        return str(config.get("APP_PROJECT_VER", "1"))
    version_file = ctx.project_dir / "version.txt"
    if version_file.is_file():
        return version_file.read_text().strip()
    return "1"  # IDF also tries `git describe`; the double stays deterministic


# ---------------------------------------------------------------- the "compile" check


def is_ros_header(include: str) -> bool:
    if "/" not in include:
        return False
    first = include.split("/")[0]
    return "/msg/" in include or "/srv/" in include or "/action/" in include or first.startswith(ROS_HEADER_PREFIXES)


DIRECTIVE = re.compile(r"^\s*#\s*(\w+)\s*(.*)$")


def logical_lines(text: str) -> list[tuple[int, str]]:
    """Source lines without comments, continuation lines joined, with their first line number."""
    no_comments = []
    i, n = 0, len(text)
    state = None
    while i < n:
        ch = text[i]
        if state is None:
            if text.startswith("/*", i):
                end = text.find("*/", i + 2)
                end = n if end < 0 else end + 2
                no_comments.append(" " + "\n" * text.count("\n", i, end))
                i = end
                continue
            if text.startswith("//", i):
                end = text.find("\n", i)
                i = n if end < 0 else end
                continue
            if ch in "\"'":
                state = ch
        elif ch == "\\" and i + 1 < n and text[i + 1] != "\n":
            no_comments.append(text[i : i + 2])
            i += 2
            continue
        elif ch == state or ch == "\n":
            state = None
        no_comments.append(ch)
        i += 1
    lines: list[tuple[int, str]] = []
    pending, start = "", 0
    for number, line in enumerate("".join(no_comments).split("\n"), start=1):
        if not pending:
            start = number
        if line.endswith("\\"):
            pending += line[:-1] + " "
            continue
        lines.append((start, pending + line))
        pending = ""
    if pending:
        lines.append((start, pending))
    return lines


class Unknown(Exception):
    """An #if expression the double cannot evaluate."""


def eval_condition(expr: str, macros: dict[str, str]) -> bool:
    expr = re.sub(
        r"ESP_IDF_VERSION_VAL\s*\(\s*(\d+)\s*,\s*(\d+)\s*,\s*(\d+)\s*\)",
        lambda m: str((int(m[1]) << 16) | (int(m[2]) << 8) | int(m[3])),
        expr,
    )
    expr = re.sub(
        r"\bdefined\s*\(\s*(\w+)\s*\)|\bdefined\s+(\w+)", lambda m: "1" if (m[1] or m[2]) in macros else "0", expr
    )

    def ident(m: re.Match[str]) -> str:
        name = m.group(0)
        if name in macros:
            value = macros[name].strip() or "1"
            if re.fullmatch(r"-?(0x[0-9A-Fa-f]+|\d+)[uUlL]*", value):
                return str(int(value.rstrip("uUlL"), 0))
            raise Unknown(name)
        return "0"

    expr = re.sub(r"\b[A-Za-z_]\w*\b", ident, expr)
    expr = re.sub(r"(0x[0-9A-Fa-f]+|\d+)[uUlL]+", r"\1", expr)
    if not re.fullmatch(r"[\d\s()+\-*/%<>=!&|^~x0-9A-Fa-f?:]*", expr):
        raise Unknown(expr)
    py = expr.replace("&&", " and ").replace("||", " or ")
    py = re.sub(r"!(?!=)", " not ", py)
    try:
        return bool(eval(py, {"__builtins__": {}}, {}))
    except Exception as exc:
        raise Unknown(expr) from exc


@dataclass(frozen=True)
class Diagnostic:
    path: Path
    line: int
    column: int
    message: str
    chain: tuple[tuple[Path, int], ...] = ()

    def render(self) -> str:
        # gcc names a file as its command line or the -I path it was found through did: IDF's
        # CMake passes every source and include directory as an absolute path.
        def show(p: Path) -> str:
            return str(p)

        last = len(self.chain) - 1
        lead = ("In file included from",) + ("                 from",) * last
        prefix = "".join(
            # gcc names the direct includer first, then outwards
            f"{lead[i]} {show(p)}:{line}{':' if i == last else ','}\n"
            for i, (p, line) in enumerate(reversed(self.chain))
        )
        return f"{prefix}{show(self.path)}:{self.line}:{self.column}: {self.message}"


class SourceChecker:
    """Checks sources as far as the double can: taken #error directives and ROS headers."""

    def __init__(self, macros: dict[str, str]) -> None:
        self.base_macros = macros
        self.scanned: dict[tuple, list[Diagnostic]] = {}
        # What each scanned file leaves #defined (as the C preprocessor, an includer sees it).
        self.exports: dict[Path, dict[str, str]] = {}
        self.read: set[Path] = set()

    def check(
        self,
        path: Path,
        local_dirs: list[Path],
        ros_dirs: list[Path],
        idf_seen: frozenset[str] | None = None,
        chain: tuple[tuple[Path, int], ...] = (),
        stack: tuple[Path, ...] = (),
    ) -> list[Diagnostic]:
        key = (path, tuple(local_dirs), tuple(ros_dirs), idf_seen)
        if key in self.scanned:
            return [Diagnostic(d.path, d.line, d.column, d.message, chain + d.chain) for d in self.scanned[key]]
        if path in stack:
            return []
        self.read.add(path)
        found: list[Diagnostic] = []
        macros = dict(self.base_macros)
        # Each entry: (this branch taken: True/False/None for unknown, some branch already taken)
        conds: list[list[object]] = []

        def active() -> bool | None:
            state: bool | None = True
            for taken, _ in conds:
                if taken is False:
                    return False
                if taken is None:
                    state = None
            return state

        def evaluate(kind: str, rest: str) -> bool | None:
            try:
                if kind in ("ifdef", "ifndef"):
                    name = rest.split()[0] if rest.split() else ""
                    return (name in macros) == (kind == "ifdef")
                return eval_condition(rest, macros)
            except Unknown:
                return None

        text = path.read_text(errors="replace")
        for number, line in logical_lines(text):
            m = DIRECTIVE.match(line)
            if not m:
                continue
            kind, rest = m.group(1), m.group(2).strip()
            if kind in ("if", "ifdef", "ifndef"):
                taken = evaluate(kind, rest) if active() is not False else False
                conds.append([taken, taken is True])
            elif kind in ("elif", "else") and conds:
                entry = conds[-1]
                parent_active = all(t is not False for t, _ in conds[:-1])
                if entry[1] or not parent_active:
                    entry[0] = False
                else:
                    taken = True if kind == "else" else evaluate("if", rest)
                    if entry[0] is None and taken is True:
                        taken = None
                    entry[0] = taken
                    entry[1] = taken is True
            elif kind == "endif" and conds:
                conds.pop()
            elif active() is False:
                continue
            elif kind == "define" and active() is True:
                dm = re.match(r"(\w+)(\([^)]*\))?\s*(.*)", rest)
                if dm:
                    macros[dm.group(1)] = dm.group(3) if not dm.group(2) else "1"
            elif kind == "undef" and active() is True:
                macros.pop(rest.split()[0] if rest.split() else "", None)
            elif kind == "error" and active() is True:
                found.append(Diagnostic(path, number, line.index("#") + 2, f"error: #error {rest}"))
            elif kind == "include":
                im = re.match(r'([<"])([^>"]+)[>"]', rest)
                if not im:
                    continue
                quoted, include = im.group(1) == '"', im.group(2)
                column = line.index(im.group(0)) + 1
                found += self._include(
                    path, number, column, include, quoted, local_dirs, ros_dirs, idf_seen, chain, stack
                )
                if active() is True:
                    for header in self._resolved(path, include, quoted, local_dirs, ros_dirs):
                        macros.update(self.exports.get(header, {}))
        self.scanned[key] = [Diagnostic(d.path, d.line, d.column, d.message, d.chain[len(chain) :]) for d in found]
        self.exports[path] = {k: v for k, v in macros.items() if self.base_macros.get(k) != v}
        return found

    def _resolved(
        self, path: Path, include: str, quoted: bool, local_dirs: list[Path], ros_dirs: list[Path]
    ) -> list[Path]:
        """The file an #include names, if the double reads it (for a header scanned before)."""
        dirs = ([path.parent] if quoted else []) + (ros_dirs if is_ros_header(include) else local_dirs)
        return next(([d / include] for d in dirs if (d / include).is_file()), [])

    def _include(
        self,
        path: Path,
        number: int,
        column: int,
        include: str,
        quoted: bool,
        local_dirs: list[Path],
        ros_dirs: list[Path],
        idf_seen: frozenset[str] | None,
        chain: tuple[tuple[Path, int], ...],
        stack: tuple[Path, ...],
    ) -> list[Diagnostic]:
        here = (*chain, (path, number))
        missing = [Diagnostic(path, number, column, f"fatal error: {include}: No such file or directory", chain)]
        candidates = ([path.parent] if quoted else []) + local_dirs
        if is_ros_header(include):
            for d in ([path.parent] if quoted else []) + ros_dirs:
                hit = d / include
                if hit.is_file():
                    return self.check(hit, [], ros_dirs, idf_seen, here, (*stack, path))
            return missing
        for d in candidates:
            hit = d / include
            if hit.is_file():
                return self.check(hit, local_dirs, ros_dirs, idf_seen, here, (*stack, path))
        owner = IDF_HEADER_OWNERS.get(include)
        if owner is not None and idf_seen is not None and owner not in idf_seen:
            return missing  # the header's component is not among the requirements
        return []  # an ESP-IDF, toolchain or managed-component header: assumed to exist


def visible_dirs(
    comp: Component, components: dict[str, Component]
) -> tuple[list[Path], list[Path], frozenset[str] | None]:
    """(project include dirs, micro-ROS include dirs, IDF components whose headers it sees or None
    for all) for a component's sources, via REQUIRES as IDF does."""
    reg = comp.reg or cmakelite.Registration()
    idf_seen: set[str] | None = set()
    if comp.name == "main" and not (reg.requires or reg.priv_requires):
        reachable, idf_seen = set(components), None
    else:
        reachable, todo = {comp.name}, list(reg.requires + reg.priv_requires)
        while todo:
            name = todo.pop()
            if name in components:
                if name in reachable:
                    continue
                reachable.add(name)
                dep = components[name].reg or cmakelite.Registration()
                todo += dep.requires
            elif name not in idf_seen:
                idf_seen.add(name)
                todo += IDF_PUBLIC_REQUIRES.get(name, ())
    local = list(comp.include_dirs) + list(comp.priv_include_dirs)
    ros: list[Path] = []
    for name in sorted(reachable):
        other = components[name]
        if name != comp.name:
            local += other.include_dirs
        if other.micro_ros:
            root = other.path / "include"
            ros += [root, *sorted(p for p in root.glob("*") if p.is_dir())] if root.is_dir() else []
    return list(dict.fromkeys(local)), ros, None if idf_seen is None else frozenset(idf_seen)


# ---------------------------------------------------------------- images


def esptool_chip(target: str):
    from esptool.targets import CHIP_DEFS  # esptool is the real one, in IDF's venv

    return CHIP_DEFS[target]


def memory_start(chip, kind: str) -> int:
    for start, _end, name in chip.MEMORY_MAP:
        if name == kind:
            return start
    raise FatalError(f"esptool knows no {kind} region for {chip.CHIP_NAME}")


def stream(seed: bytes, size: int) -> bytes:
    """SIZE deterministic bytes derived from SEED."""
    blocks = []
    counter = 0
    while sum(len(b) for b in blocks) < size:
        blocks.append(hashlib.sha256(seed + counter.to_bytes(8, "little")).digest())
        counter += 1
    return b"".join(blocks)[:size]


@dataclass(frozen=True)
class Section:
    name: str
    addr: int
    data: bytes
    flags: int  # SHF_*: 1 write, 2 alloc, 4 exec


def write_elf(path: Path, target: str, entry: int, sections: list[Section], note: bytes) -> None:
    """A small ELF32 executable: one PT_LOAD per section, plus a non-allocated note section."""
    machine = 94 if target in XTENSA_TARGETS else 243
    all_sections = [*sections, Section(".espdock_double.note", 0, note, 0)]
    names = b"\0" + b"".join(s.name.encode() + b"\0" for s in all_sections) + b".shstrtab\0"
    phnum = len(sections)
    offset = 52 + 32 * phnum
    blobs, placed = [], []
    for s in all_sections:
        offset = (offset + 3) & ~3
        placed.append(offset)
        blobs.append((offset, s.data))
        offset += len(s.data)
    shstr_off = offset
    offset += len(names)
    shoff = (offset + 3) & ~3
    buf = bytearray(shoff + 40 * (len(all_sections) + 2))
    ident = b"\x7fELF" + bytes([1, 1, 1, 0]) + bytes(8)
    struct.pack_into(
        "<16sHHIIIIIHHHHHH",
        buf,
        0,
        ident,
        2,
        machine,
        1,
        entry,
        52,
        shoff,
        0,
        52,
        32,
        phnum,
        40,
        len(all_sections) + 2,
        len(all_sections) + 1,
    )
    for i, s in enumerate(sections):
        pflags = 4 | (2 if s.flags & 1 else 0) | (1 if s.flags & 4 else 0)
        struct.pack_into(
            "<IIIIIIII", buf, 52 + 32 * i, 1, placed[i], s.addr, s.addr, len(s.data), len(s.data), pflags, 4
        )
    for off, data in blobs:
        buf[off : off + len(data)] = data
    buf[shstr_off : shstr_off + len(names)] = names
    name_off = 1
    for i, s in enumerate(all_sections):
        struct.pack_into(
            "<IIIIIIIIII", buf, shoff + 40 * (i + 1), name_off, 1, s.flags, s.addr, placed[i], len(s.data), 0, 0, 4, 0
        )
        name_off += len(s.name) + 1
    struct.pack_into(
        "<IIIIIIIIII", buf, shoff + 40 * (len(all_sections) + 1), name_off, 3, 0, 0, shstr_off, len(names), 0, 0, 1, 0
    )
    path.write_bytes(bytes(buf))


def app_desc(name: str, version: str, stamped: bool) -> bytes:
    """esp_app_desc_t (256 bytes); elf2image fills app_elf_sha256 at image offset 0xb0.

    STAMPED (CONFIG_APP_COMPILE_TIME_DATE, on unless CONFIG_APP_REPRODUCIBLE_BUILD) puts in
    __TIME__ and __DATE__ as the compiler expands them: the build's wall clock, or
    SOURCE_DATE_EPOCH, which GCC honours."""

    def fixed(text: str, size: int) -> bytes:
        return text.encode()[: size - 1].ljust(size, b"\0")

    when = time.gmtime(int(os.environ["SOURCE_DATE_EPOCH"])) if "SOURCE_DATE_EPOCH" in os.environ else time.localtime()
    return (
        struct.pack("<II8x", 0xABCD5432, 0)
        + fixed(version, 32)
        + fixed(name, 32)
        + fixed(time.strftime("%H:%M:%S", when) if stamped else "", 16)
        + fixed(time.strftime("%b %e %Y", when) if stamped else "", 16)
        + fixed(IDF_VER, 32)
        + bytes(32)
        + struct.pack("<HH", 0, 99)
        + bytes(76)
    )


def elf2image(ctx: Context, target: str, config: dict[str, object], elf: Path, image: Path, app: bool) -> None:
    argv = [
        sys.executable,
        "-m",
        "esptool",
        "--chip",
        target,
        "elf2image",
        "--flash_mode",
        str(config["ESPTOOLPY_FLASHMODE"]),
        "--flash_freq",
        str(config["ESPTOOLPY_FLASHFREQ"]),
        "--flash_size",
        str(config["ESPTOOLPY_FLASHSIZE"]),
    ]
    if app:
        argv += ["--elf-sha256-offset", "0xb0"]
    rev_min = int(config.get("ESP_REV_MIN_FULL", 0))
    if target == "esp32" and rev_min // 100:
        argv += ["--min-rev", str(rev_min // 100)]
    if target == "esp32c3" and rev_min % 100:
        argv += ["--min-rev", str(rev_min % 100)]
    argv += [
        "--min-rev-full",
        str(rev_min),
        "--max-rev-full",
        str(config.get("ESP_REV_MAX_FULL", 65535)),
        "-o",
        str(image),
        str(elf),
    ]
    result = subprocess.run(argv, capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise FatalError(f"esptool elf2image failed for {elf.name}:\n{result.stdout}{result.stderr}")


def parse_size(text: str) -> int:
    text = text.strip()
    m = re.fullmatch(r"(0x[0-9A-Fa-f]+|\d+)\s*([KkMm]?)", text)
    if not m:
        raise ValueError(text)
    return int(m.group(1), 0) * {"": 1, "K": 1024, "M": 1024 * 1024}[m.group(2).upper()]


def partition_rows(ctx: Context, config: dict[str, object]) -> tuple[list[tuple[str, ...]], str]:
    filename = str(config.get("PARTITION_TABLE_FILENAME", "partitions_singleapp.csv"))
    if filename in BUILTIN_TABLES and not config.get("PARTITION_TABLE_CUSTOM"):
        return BUILTIN_TABLES[filename], filename
    path = Path(filename) if os.path.isabs(filename) else ctx.project_dir / filename
    if not path.is_file():
        raise FatalError(f"Partition table CSV {path} not found (CONFIG_PARTITION_TABLE_CUSTOM_FILENAME)")
    rows = []
    for row in csv.reader(
        line for line in path.read_text().splitlines() if line.strip() and not line.lstrip().startswith("#")
    ):
        rows.append(tuple(c.strip() for c in row) + ("",) * (6 - len(row)))
    return rows, str(path)


def partition_table(ctx: Context, config: dict[str, object]) -> tuple[bytes, list[dict]]:
    """The binary partition table IDF's gen_esp32part.py writes, and the parsed rows."""
    rows, source = partition_rows(ctx, config)
    table_offset = int(str(config.get("PARTITION_TABLE_OFFSET", "0x8000")), 0)
    cursor = table_offset + 0x1000
    parts = []
    for name, ptype, subtype, offset, size, flags in (r[:6] for r in rows):
        try:
            type_code = PART_TYPES[ptype] if ptype in PART_TYPES else int(ptype, 0)
            sub_code = PART_SUBTYPES.get(ptype, {}).get(subtype)
            sub_code = sub_code if sub_code is not None else int(subtype, 0)
            align = 0x10000 if type_code == 0 else 0x1000
            start = parse_size(offset) if offset else (cursor + align - 1) & ~(align - 1)
            length = parse_size(size)
        except (ValueError, KeyError):
            raise FatalError(f"{source}: cannot parse partition '{name}'") from None
        if start < cursor:
            raise FatalError(
                f"{source}: partition '{name}' at 0x{start:x} overlaps the one before it (ends 0x{cursor:x})"
            )
        cursor = start + length
        parts.append(
            {
                "name": name,
                "type": type_code,
                "subtype": sub_code,
                "offset": start,
                "size": length,
                "flags": (1 if "encrypted" in flags else 0) | (2 if "readonly" in flags else 0),
            }
        )
    # gen_esp32part.py's verify(): each partition's alignment (an app's offset to 64 KB, its size
    # to a flash sector; data to a sector), then one name per partition.
    for part in parts:
        align = 0x10000 if part["type"] == 0 else 0x1000
        if part["offset"] % align:
            raise FatalError(
                f"Partition {part['name']} invalid: Offset 0x{part['offset']:x} is not aligned to 0x{align:x}"
            )
        if part["type"] == 0 and part["size"] % 0x1000:
            raise FatalError(f"Partition {part['name']} invalid: Size 0x{part['size']:x} is not aligned to 0x1000")
    names = [part["name"] for part in parts]
    if duplicates := sorted({name for name in names if names.count(name) > 1}):
        print("A list of partitions that have the same name:", file=sys.stderr)
        for row in rows:
            if row[0] in duplicates:
                print(",".join(row[:6]), file=sys.stderr)
        raise FatalError("Partition names must be unique")
    flash_size = parse_size(str(config["ESPTOOLPY_FLASHSIZE"]).replace("MB", "M"))
    if cursor > flash_size:
        raise FatalError(
            f"Partitions tables occupies {cursor / 1024 / 1024:.1f}MB of flash ({cursor} bytes) which does not fit in "
            f"configured flash size {config['ESPTOOLPY_FLASHSIZE']}. Change the flash size in menuconfig under the "
            "'Serial Flasher Config' menu."
        )
    blob = b"".join(
        struct.pack(
            "<2sBBLL16sL",
            b"\xaa\x50",
            p["type"],
            p["subtype"],
            p["offset"],
            p["size"],
            p["name"].encode()[:16],
            p["flags"],
        )
        for p in parts
    )
    if config.get("PARTITION_TABLE_MD5", True):
        blob += b"\xeb\xeb" + b"\xff" * 14 + hashlib.md5(blob).digest()
    return blob + b"\xff" * (0xC00 - len(blob)), parts


def boot_partition(parts: list[dict]) -> dict:
    apps = [p for p in parts if p["type"] == 0]
    factory = [p for p in apps if p["subtype"] == 0]
    if not apps:
        raise FatalError("Partition table has no app partition to boot")
    return (factory or apps)[0]


# ---------------------------------------------------------------- build


def run_build(ctx: Context, project: Project) -> None:
    target, config, name = project.target, project.config, project.name
    out(f"Running ninja in directory {ctx.build_dir}")
    out('Executing "ninja all"...')
    macros = {f"CONFIG_{k}": ("1" if v is True else str(v)) for k, v in config.items() if v is not False}
    macros.update(
        {
            "ESP_PLATFORM": "1",
            "IDF_VER": f'"{IDF_VER}"',
            "ESP_IDF_VERSION_MAJOR": "5",
            "ESP_IDF_VERSION_MINOR": "3",
            "ESP_IDF_VERSION_PATCH": "5",
            "ESP_IDF_VERSION": str((5 << 16) | (3 << 8) | 5),
            "__GNUC__": "13",
            "__STDC__": "1",
            "__STDC_VERSION__": "201710",
        }
    )
    macros["__XTENSA__" if target in XTENSA_TARGETS else "__riscv"] = "1"
    checker = SourceChecker(macros)

    libraries: list[Path] = []
    for comp in sorted(project.components.values(), key=lambda c: c.name):
        if comp.micro_ros:
            lib = comp.path / "libmicroros.a"
            if not lib.is_file():
                raise FatalError(
                    f"ninja: error: '{lib}', needed by '{name}.elf', missing and no known rule to make it\n"
                    "ninja failed with exit code 1"
                )
            libraries.append(lib)

    steps = [(comp, src) for comp in sorted(project.components.values(), key=lambda c: c.name) for src in comp.sources]
    total = len(steps) + 7
    diagnostics: list[Diagnostic] = []
    for index, (comp, src) in enumerate(steps, start=1):
        obj = f"esp-idf/{comp.name}/CMakeFiles/__idf_{comp.name}.dir/{src.relative_to(comp.path)}.obj"
        out(f"[{index}/{total}] Building C object {obj}")
        local, ros, idf_seen = visible_dirs(comp, project.components)
        found = checker.check(src, local, ros, idf_seen)
        if found:
            out(f"FAILED: {obj}")
        for d in found:
            print(d.render(), file=sys.stderr, flush=True)
        diagnostics += found
        if found:
            break  # ninja -k 1: no new jobs after the first failure
    if diagnostics:
        out("ninja: build stopped: subcommand failed.")
        raise FatalError("ninja failed with exit code 1")
    check_camera_driver_link(ctx, project, steps, len(steps), total)

    staging = Path(tempfile.mkdtemp(prefix=".double-staging-", dir=ctx.build_dir))
    try:
        produce_artefacts(ctx, project, staging, checker, libraries, len(steps), total)
        for path in sorted(p for p in staging.rglob("*") if p.is_file()):
            dest = ctx.build_dir / path.relative_to(staging)
            dest.parent.mkdir(parents=True, exist_ok=True)
            os.replace(path, dest)
    finally:
        shutil.rmtree(staging, ignore_errors=True)
    print_flash_hint(ctx, project)


def check_camera_driver_link(ctx: Context, project: Project, steps: list, done: int, total: int) -> None:
    """The link step's failure for an app calling esp32-camera's driver on a target the
    component builds no driver for (as ld reports the first undefined reference)."""
    if "espressif/esp32-camera" not in ctx.registry_dependencies or project.target in CAMERA_DRIVER_TARGETS:
        return
    for comp, src in steps:
        match = CAMERA_DRIVER_SYMBOLS.search(src.read_text(errors="replace"))
        if match:
            name = project.name
            out(f"[{done + 1}/{total}] Linking CXX executable {name}.elf")
            out(f"FAILED: {name}.elf")
            print(
                f"/opt/esp/tools/riscv32-esp-elf/bin/ld: esp-idf/{comp.name}/libmain.a({src.name}.obj): in function "
                f"`{src.stem}':\n{src.name}: undefined reference to `{match.group(1)}'\n"
                "collect2: error: ld returned 1 exit status",
                file=sys.stderr,
                flush=True,
            )
            out("ninja: build stopped: subcommand failed.")
            raise FatalError("ninja failed with exit code 1")


def source_paths(ctx: Context, project: Project, checker: SourceChecker, debug: bool, reproducible: bool) -> bytes:
    """The source paths the compiler puts into the app, as IDF v5.3's __generate_prefix_map maps them.

    __FILE__ (assert and log strings, DEBUG False): CONFIG_COMPILER_HIDE_PATHS_MACROS, on by
    default, maps the project to "." and IDF to /IDF. Debug information (DEBUG True, in the
    ELF only): absolute paths unless CONFIG_APP_REPRODUCIBLE_BUILD maps IDF to /IDF, the project
    to /IDF_PROJECT, the build dir to /IDF_BUILD and each component to /COMPONENT_<NAME>_DIR."""
    idf_path = os.environ.get("IDF_PATH", "/opt/esp/idf")
    if not debug:
        prefixes = [(str(ctx.project_dir), "."), (idf_path, "/IDF")]
    elif reproducible:
        prefixes = [(idf_path, "/IDF"), (str(ctx.project_dir), "/IDF_PROJECT"), (str(ctx.build_dir), "/IDF_BUILD")]
        prefixes += [(str(c.path), f"/COMPONENT_{c.name.upper()}_DIR") for c in project.components.values()]
    else:
        prefixes = []
    names = []
    for path in sorted(checker.read):
        text = str(path)
        # GCC tries the last map given first; IDF gives the component maps last.
        for prefix, mapped in reversed(prefixes):
            if text == prefix or text.startswith(prefix + "/"):
                text = mapped + text[len(prefix) :]
                break
        names.append(text.encode() + b"\0")
    return b"".join(names)


def produce_artefacts(
    ctx: Context, project: Project, staging: Path, checker: SourceChecker, libraries: list[Path], done: int, total: int
) -> None:
    target, config, name = project.target, project.config, project.name
    chip = esptool_chip(target)
    step = done

    def progress(text: str) -> None:
        nonlocal step
        step += 1
        out(f"[{step}/{total}] {text}")

    # What the app is a function of: target, name, every source and project header read, the
    # configuration and every micro-ROS library linked.
    inputs = hashlib.sha256()
    manifest_lines = [f"target {target}", f"project {name}"]
    inputs.update(f"{target}\0{name}\0".encode())
    for path in sorted(checker.read):
        rel = display(path, ctx.project_dir, project.components)
        digest = hashlib.sha256(path.read_bytes()).hexdigest()
        inputs.update(f"{rel}\0{digest}\0".encode())
        manifest_lines.append(f"source {rel} sha256={digest}")
    config_bytes = json.dumps(config, sort_keys=True).encode()
    inputs.update(config_bytes)
    manifest_lines.append(f"sdkconfig sha256={hashlib.sha256(config_bytes).hexdigest()}")
    for d in project.defaults:
        digest = hashlib.sha256(d.read_bytes()).hexdigest()
        inputs.update(f"defaults\0{digest}\0".encode())
        manifest_lines.append(f"sdkconfig.defaults {d.name} sha256={digest}")
    for lib in libraries:
        digest = hashlib.sha256(lib.read_bytes()).hexdigest()
        inputs.update(f"lib\0{digest}\0".encode())
        manifest_lines.append(f"library {display(lib, ctx.project_dir, project.components)} sha256={digest}")
    seed = inputs.digest()
    source_bytes = sum(p.stat().st_size for p in checker.read)

    progress("Generating ../../partition_table/partition-table.bin")
    table, parts = partition_table(ctx, config)
    (staging / "partition_table").mkdir()
    (staging / "partition_table" / "partition-table.bin").write_bytes(table)

    progress("Building bootloader (bootloader/bootloader.elf)")
    boot_seed = hashlib.sha256(b"bootloader\0" + target.encode() + b"\0" + config_bytes).digest()
    iram, dram = memory_start(chip, "IRAM"), memory_start(chip, "DRAM")
    (staging / "bootloader").mkdir()
    boot_elf = staging / "bootloader" / "bootloader.elf"
    write_elf(
        boot_elf,
        target,
        iram + 0x400,
        [
            Section(".dram0.rodata", dram + 0x10000, stream(boot_seed + b"d", 0x800), 2 | 1),
            Section(".iram_loader.text", iram + 0x400, stream(boot_seed + b"i", 0x4000), 2 | 4),
        ],
        b"contract double: synthesised ESP-IDF v5.3.5 2nd stage bootloader for " + target.encode(),
    )
    progress("Generating binary image from built executable (bootloader)")
    elf2image(ctx, target, config, boot_elf, staging / "bootloader" / "bootloader.bin", app=False)
    (staging / "bootloader" / "bootloader.map").write_text(
        f"contract double: no linker ran; bootloader of ESP-IDF {IDF_VER} for {target}\n"
    )
    boot_size = (staging / "bootloader" / "bootloader.bin").stat().st_size
    boot_offset = int(str(config.get("BOOTLOADER_OFFSET_IN_FLASH", "0x1000")), 0)
    table_offset = int(str(config.get("PARTITION_TABLE_OFFSET", "0x8000")), 0)
    room = table_offset - boot_offset
    if boot_size > room:
        raise FatalError(
            f"Bootloader binary size 0x{boot_size:x} bytes is too large for partition table offset 0x{table_offset:x}."
        )
    spare = room - boot_size
    out(f"Bootloader binary size 0x{boot_size:x} bytes. 0x{spare:x} bytes ({spare * 100 // room}%) free.")

    progress(f"Linking C executable {name}.elf")
    note = (
        "contract double: synthesised ESP-IDF v5.3.5 app, no compiler ran\n" + "\n".join(manifest_lines) + "\n"
    ).encode()
    drom, irom = chip.DROM_MAP_START, chip.IROM_MAP_START
    rodata = app_desc(name, project_version(ctx, config), bool(config.get("APP_COMPILE_TIME_DATE"))) + note
    rodata += source_paths(ctx, project, checker, debug=False, reproducible=False)
    rodata += stream(seed + b"r", 0x2000)
    rodata += bytes(-len(rodata) % 4)
    text_base = irom if irom > drom else drom
    pages = (0x20 + len(rodata) + 0xFFFF) // 0x10000
    text_addr = text_base + pages * 0x10000 + 0x20
    entry = iram + 0x100
    app_elf = staging / f"{name}.elf"
    write_elf(
        app_elf,
        target,
        entry,
        [
            Section(".flash.appdesc", drom + 0x20, rodata[:256], 2),
            Section(".flash.rodata", drom + 0x20 + 256, rodata[256:], 2),
            Section(".dram0.data", dram + 0x4000, stream(seed + b"d", 0x40), 2 | 1),
            Section(".iram0.text", entry, stream(seed + b"i", 0x100), 2 | 4),
            Section(".flash.text", text_addr, stream(seed + b"t", 0x6000 + (source_bytes & ~3)), 2 | 4),
        ],
        note + source_paths(ctx, project, checker, debug=True, reproducible=bool(config.get("APP_REPRODUCIBLE_BUILD"))),
    )
    progress(f"Generating binary image from built executable ({name}.bin)")
    app_bin = staging / f"{name}.bin"
    elf2image(ctx, target, config, app_elf, app_bin, app=True)
    out(f"Generated {ctx.build_dir / (name + '.bin')}")
    (staging / f"{name}.map").write_text(
        f"contract double: no linker ran. Archive member list and inputs of {name}.elf\n\n"
        + "\n".join(manifest_lines)
        + "\n"
    )
    app_part = boot_partition(parts)
    app_size = app_bin.stat().st_size
    progress(f"cd {ctx.build_dir}/esp-idf/esptool_py && python check_sizes.py --offset 0x{table_offset:x} partition")
    if app_size > app_part["size"]:
        raise FatalError(
            f"Error: app partition is too small for binary {name}.bin size 0x{app_size:x}:\n"
            f"  - Part '{app_part['name']}' "
            f"0/0 @ 0x{app_part['offset']:x} size 0x{app_part['size']:x} (overflow 0x{app_size - app_part['size']:x})"
        )
    free = app_part["size"] - app_size
    out(
        f"{name}.bin binary size 0x{app_size:x} bytes. Smallest app partition is 0x{app_part['size']:x} bytes. "
        f"0x{free:x} bytes ({free * 100 // app_part['size']}%) free."
    )

    progress("Generating flasher_args.json, flash_args")
    write_flash_files(staging, project, boot_offset, table_offset, app_part["offset"])


def display(path: Path, project_dir: Path, components: dict[str, Component]) -> str:
    try:
        return str(path.relative_to(project_dir))
    except ValueError:
        for comp in components.values():
            try:
                return f"{comp.name}/{path.relative_to(comp.path)}"
            except ValueError:
                continue
    return path.name


def write_flash_files(staging: Path, project: Project, boot: int, table: int, app: int) -> None:
    config, name = project.config, project.name
    mode, freq, size = (str(config[k]) for k in ("ESPTOOLPY_FLASHMODE", "ESPTOOLPY_FLASHFREQ", "ESPTOOLPY_FLASHSIZE"))
    files = [
        ("bootloader", f"0x{boot:x}", "bootloader/bootloader.bin"),
        ("app", f"0x{app:x}", f"{name}.bin"),
        ("partition-table", f"0x{table:x}", "partition_table/partition-table.bin"),
    ]
    sub_args = f"--flash_mode {mode} --flash_freq {freq} --flash_size {size}"
    (staging / "flash_args").write_text(sub_args + "\n" + "\n".join(f"{o} {f}" for _, o, f in files) + "\n")
    for key, offset, path in files:
        prefix = sub_args + "\n" if key == "bootloader" else "\n"
        (staging / f"{key}-flash_args").write_text(f"{prefix}{offset} {path}\n")
    flasher = {
        "write_flash_args": ["--flash_mode", mode, "--flash_size", size, "--flash_freq", freq],
        "flash_settings": {"flash_mode": mode, "flash_size": size, "flash_freq": freq},
        "flash_files": {o: f for _, o, f in files},
        **{key: {"offset": o, "file": f, "encrypted": "false"} for key, o, f in files},
        "extra_esptool_args": {
            "after": str(config.get("ESPTOOLPY_AFTER", "hard_reset")),
            "before": str(config.get("ESPTOOLPY_BEFORE", "default_reset")),
            "stub": not config.get("ESPTOOLPY_NO_STUB", False),
            "chip": project.target,
        },
    }
    (staging / "flasher_args.json").write_text(json.dumps(flasher, indent=4) + "\n")


def print_flash_hint(ctx: Context, project: Project) -> None:
    flasher = json.loads((ctx.build_dir / "flasher_args.json").read_text())
    extra = flasher["extra_esptool_args"]
    items = sorted(flasher["flash_files"].items(), key=lambda kv: int(kv[0], 0))
    files = " ".join(f"{o} {os.path.relpath(ctx.build_dir / f)}" for o, f in items)
    out("\nProject build complete. To flash, run:")
    out(" idf.py flash")
    out("or")
    out(" idf.py -p PORT flash")
    out("or")
    head = (
        f" python -m esptool --chip {extra['chip']} -b {ctx.args.baud} --before {extra['before']}"
        f" --after {extra['after']}{'' if extra['stub'] else ' --no-stub'} write_flash"
    )
    out(f"{head} {' '.join(flasher['write_flash_args'])} {files}")
    out(f'or from the "{ctx.build_dir}" directory')
    out(f'{head} "@flash_args"')


# ---------------------------------------------------------------- other actions


def fullclean(ctx: Context) -> None:
    build_dir = ctx.build_dir
    if not build_dir.is_dir():
        out(f"Build directory '{build_dir}' not found. Nothing to clean.")
        return
    if not any(build_dir.iterdir()):
        out(f"Build directory '{build_dir}' is empty. Nothing to clean.")
        return
    if not ctx.cache_path.exists():
        raise FatalError(
            f"Directory '{build_dir}' doesn't seem to be a CMake build directory. Refusing to automatically delete "
            "files in this directory. Delete the directory manually to 'clean' it."
        )
    for red in ("CMakeLists.txt", ".git", ".svn"):
        if (build_dir / red).exists():
            raise FatalError(
                f"Refusing to automatically delete files in directory containing '{build_dir / red}'. "
                "Delete files manually if you're sure."
            )
    for entry in build_dir.iterdir():
        if entry.is_dir() and not entry.is_symlink():
            shutil.rmtree(entry)
        else:
            entry.unlink()
    out("Done")


def clean(ctx: Context) -> None:
    if not ctx.cache_path.exists():
        out(f"Build directory '{ctx.build_dir}' not found or not configured. Nothing to clean.")
        return
    for pattern in ("*.bin", "*.elf", "*.map", "bootloader", "partition_table", "flasher_args.json", "*flash_args"):
        for entry in ctx.build_dir.glob(pattern):
            shutil.rmtree(entry) if entry.is_dir() else entry.unlink()
    out("Done")


def check_build_dir(ctx: Context) -> None:
    """idf.py's checks of an existing build directory before it runs CMake."""
    if not ctx.project_dir.is_dir():
        if not ctx.project_dir.exists():
            raise FatalError(f"Project directory {ctx.project_dir} does not exist")
        raise FatalError(f"{ctx.project_dir} must be a project directory")
    if not (ctx.project_dir / "CMakeLists.txt").exists():
        raise FatalError(f"CMakeLists.txt not found in project directory {ctx.project_dir}")
    ctx.build_dir.mkdir(parents=True, exist_ok=True)
    cache = ctx.read_cache()
    home = cache.get("CMAKE_HOME_DIRECTORY")
    if home and os.path.realpath(home) != str(ctx.project_dir):
        raise FatalError(
            f"Build directory '{ctx.build_dir}' configured for project '{os.path.realpath(home)}' not "
            f"'{ctx.project_dir}'. Run '{PROG} fullclean' to start again."
        )
    python = cache.get("PYTHON")
    if python and os.path.normcase(python) != os.path.normcase(sys.executable):
        raise FatalError(
            f"'{sys.executable}' is currently active in the environment while the project was configured "
            f"with '{python}'. Run '{PROG} fullclean' to start again."
        )


def configure(ctx: Context, set_target: str | None = None) -> Project:
    check_build_dir(ctx)
    try:
        return run_configure(ctx, set_target)
    except cmakelite.CMakeError as exc:
        print(str(exc) + "\n\n", file=sys.stderr)
        out("-- Configuring incomplete, errors occurred!")
        # idf.py never keeps a half-valid CMakeCache.txt
        if ctx.cache_path.exists():
            ctx.cache_path.unlink()
        raise FatalError("cmake failed with exit code 1") from None


def require_port(ctx: Context) -> str:
    if not ctx.args.port:
        raise FatalError("No serial ports found. Connect a device, or use '-p PORT' option to set a specific port.")
    return ctx.args.port


def flash(ctx: Context, project: Project) -> None:
    port = require_port(ctx)
    flasher = json.loads((ctx.build_dir / "flasher_args.json").read_text())
    extra = flasher["extra_esptool_args"]
    argv = [
        sys.executable,
        "-m",
        "esptool",
        "--chip",
        extra["chip"],
        "-p",
        port,
        "-b",
        str(ctx.args.baud),
        f"--before={extra['before']}",
        f"--after={extra['after']}",
    ]
    if not extra["stub"]:
        argv.append("--no-stub")
    argv += ["write_flash", "@flash_args"]
    out(f"Serial port {port}")
    out(f"Running esptool.py in directory {ctx.build_dir}")
    out('Executing "' + " ".join(argv) + '"...')
    code = subprocess.call(argv, cwd=ctx.build_dir)
    if code != 0:
        raise FatalError(f"esptool.py failed with exit code {code}")
    out("Done")


def monitor(ctx: Context) -> None:
    port = require_port(ctx)
    desc_path = ctx.build_dir / "project_description.json"
    if not desc_path.is_file():
        raise FatalError(f"Cannot load {desc_path}. Run '{PROG} build' first.")
    desc = json.loads(desc_path.read_text())
    baud = os.environ.get("IDF_MONITOR_BAUD") or os.environ.get("MONITORBAUD") or desc["monitor_baud"]
    argv = [
        sys.executable,
        "-m",
        "esp_idf_monitor",
        "-p",
        port,
        "-b",
        str(baud),
        "--toolchain-prefix",
        desc["monitor_toolprefix"],
        "--target",
        desc["target"],
        str(ctx.build_dir / desc["app_elf"]),
    ]
    out('Executing "' + " ".join(argv) + '"...')
    sys.stdout.flush()
    os.execv(sys.executable, argv)


def clean_microros(ctx: Context) -> None:
    project = configure(ctx)
    for comp in project.components.values():
        if comp.micro_ros == "source":
            subprocess.run(["make", "-f", "libmicroros.mk", "clean"], cwd=comp.path, check=False)


def main(argv: list[str]) -> int:
    args = parse_args(argv)
    if args.version:
        out(f"ESP-IDF {IDF_VER} (espdock contract double)")
        return 0
    actions = plan_actions(args.actions)
    if not actions:
        parse_args(["--help"])
        return 0
    ctx = Context(args)
    project: Project | None = None
    for action, value in actions:
        out(f"Executing action: {'all (aliases: build)' if action == 'build' else action}")
        if action == "fullclean":
            fullclean(ctx)
        elif action == "clean":
            clean(ctx)
        elif action == "clean-microros":
            clean_microros(ctx)
        elif action == "menuconfig":
            out("contract double: there is no menuconfig in the espdock IDF contract double; nothing was changed.")
        elif action == "set-target":
            if value not in SUPPORTED_TARGETS and not (args.preview and value in PREVIEW_TARGETS):
                raise FatalError(
                    f"Error: Invalid value for '{{{','.join(SUPPORTED_TARGETS)}}}': '{value}' is not one of "
                    + ", ".join(f"'{t}'" for t in SUPPORTED_TARGETS)
                    + "."
                )
            out(f"Set Target to: {value}, new sdkconfig will be created.")
            project = configure(ctx, set_target=value)
        elif action == "reconfigure":
            project = configure(ctx)
        elif action == "save-defconfig":
            # tools/cmake/kconfig.cmake's target: kconfgen's minimal config (what differs from
            # the Kconfig defaults) over the project's sdkconfig.defaults.
            ctx.savedefconfig = ctx.project_dir / "sdkconfig.defaults"
            project = configure(ctx)
        elif action == "build":
            project = project or configure(ctx)
            run_build(ctx, project)
        elif action == "flash":
            flash(ctx, project or configure(ctx))
        elif action == "monitor":
            monitor(ctx)
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main(sys.argv[1:]))
    except FatalError as e:
        print(e, file=sys.stderr)
        sys.exit(2)
