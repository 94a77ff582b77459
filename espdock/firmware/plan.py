"""Planning the firmware side: each package's chip, its micro-ROS (IDF) image, its build and install steps."""

from __future__ import annotations

import difflib
import json
import re
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, replace
from pathlib import Path

from espdock.build.steps import (
    EnsureImage,
    ImageSpec,
    Plan,
    container_path,
    dockerfile_args,
    image_origin,
    keyed_image,
)
from espdock.config import CHIP_TARGETS, Config, check_target
from espdock.errors import WorkspaceError
from espdock.firmware import transport
from espdock.firmware.pins import parse_sources
from espdock.layout import (
    IDF_DOCKERFILE,
    IDF_INPUT_DIR,
    SOURCES_FILE,
    SOURCES_NAME,
    firmware_install_dir,
)
from espdock.workspace import (
    FIRMWARE_BUILD_TYPE,
    BuildInputs,
    Package,
    PackageKind,
    Workspace,
    idf_project_cmake,
    unknown_package,
)


@dataclass(frozen=True)
class IdfBuild:
    """`idf.py build` of one firmware package in a container of IMAGE, output in ws/build/<package>."""

    package: str
    # The project dir relative to the workspace root.
    project: str
    image: str
    target: str
    image_key: str
    force: bool = False
    colcon_root: str = "ws"
    # The workspace's interface packages it does not depend on: its library has no headers of theirs.
    unreached: tuple[str, ...] = ()

    @property
    def name(self) -> str:
        return f"idf.py build {self.package}"

    @property
    def project_dir(self) -> str:
        return container_path(self.project)

    @property
    def build_dir(self) -> str:
        return container_path(f"{self.colcon_root}/build/{self.package}")

    @property
    def install_dir(self) -> str:
        """Where the installed artefacts are in the container (flashing runs there)."""
        return container_path(f"{self.colcon_root}/{firmware_install_dir(self.package)}")

    def argv(self, action: tuple[str, ...] = ("build",)) -> tuple[str, ...]:
        # sdkconfig lives in the build dir: the committed sdkconfig.defaults stays the source,
        # and switching targets never trips over a project-level sdkconfig of another chip.
        return (
            "idf.py", "-C", self.project_dir, "-B", self.build_dir,
            f"-DSDKCONFIG={self.build_dir}/sdkconfig", *action,
        )  # fmt: skip


@dataclass(frozen=True)
class InstallFirmware:
    """Install a built firmware package into ws/install as colcon would, its artefacts atomically."""

    package: str
    project: str
    run_depends: tuple[str, ...] = ()

    @property
    def name(self) -> str:
        return f"install {self.package}"


# The interface packages micro-ROS's library is built with, the jazzy component's standard set.
STANDARD_INTERFACES = (
    "action_msgs", "actionlib_msgs", "builtin_interfaces", "composition_interfaces", "diagnostic_msgs",
    "example_interfaces", "geometry_msgs", "lifecycle_msgs", "micro_ros_msgs", "nav_msgs", "rcl_interfaces",
    "rosgraph_msgs", "sensor_msgs", "shape_msgs", "statistics_msgs", "std_msgs", "std_srvs", "stereo_msgs",
    "trajectory_msgs", "type_description_interfaces", "unique_identifier_msgs", "visualization_msgs",
)  # fmt: skip


def unknown_dependencies(firmware: Package, packages: tuple[Package, ...]) -> list[str]:
    """FIRMWARE's build dependencies that are neither packages of the workspace (PACKAGES) nor
    interface packages micro-ROS builds: a header the firmware includes of one is missing at
    compile time, where the message blames the firmware. Named before the build."""
    names = {p.name for p in packages}
    deps = firmware.depends - firmware.test_only_depends
    return sorted(d for d in deps if d not in names and d not in STANDARD_INTERFACES)


# What micro-ROS's library build can find_package(): the packages of the repositories
# docker/idf/micro_ros_sources.txt lists (ament's, rosidl's, rcl's, rclc's, rmw's, the XRCE-DDS
# pair, tracing) and interface packages. Its colcon runs with --packages-ignore-regex=.*_cpp:
# no C++ package is built, and there is no rclcpp, rclpy or launch.
MICRO_ROS_TREE = re.compile(
    r"ament_\w+|rosidl_\w+|rcutils|rcl(_\w+)?|rclc(_\w+)?|rmw(_\w+)?|micro_ros_\w+|microxrcedds_client|microcdr"
    r"|tracetools\w*|test_interface_files|gtest_vendor|gmock_vendor"
)
_FIND_PACKAGE = re.compile(r"find_package\s*\(\s*(\w+)([^)]*)\)", re.IGNORECASE)
_IF = re.compile(r"\s*if\s*\(", re.IGNORECASE)
_ENDIF = re.compile(r"\s*endif\s*\(", re.IGNORECASE)
_IF_TESTING = re.compile(r"\s*if\s*\(\s*BUILD_TESTING\s*\)", re.IGNORECASE)


def required_packages(cmakelists: str) -> list[str]:
    """The ROS packages CMAKELISTS find_package()s REQUIRED, outside its if(BUILD_TESTING) blocks
    (micro-ROS's library build sets BUILD_TESTING=OFF), in order."""
    found: list[str] = []
    depth = 0  # inside an if(BUILD_TESTING) block: 1, plus the ifs open within it
    for raw in cmakelists.splitlines():
        line = raw.split("#", 1)[0]
        if depth:
            depth += bool(_IF.match(line)) - bool(_ENDIF.match(line))
        elif _IF_TESTING.match(line):
            depth = 1
        else:
            found += [name for name, rest in _FIND_PACKAGE.findall(line) if "REQUIRED" in rest.split()]
    return [name for name in dict.fromkeys(found) if re.fullmatch(r"[a-z][a-z0-9_]*", name)]


def not_in_micro_ros(cmakelists: str, interface_packages: Iterable[str]) -> list[str]:
    """What CMAKELISTS requires that micro-ROS's library build does not have, besides INTERFACE_PACKAGES."""
    known = {*STANDARD_INTERFACES, *interface_packages}
    return [
        name
        for name in required_packages(cmakelists)
        if name not in known and (name.endswith("_cpp") or not MICRO_ROS_TREE.fullmatch(name))
    ]


# What marks a copy of micro_ros_espidf_component: the makefile that builds the library.
UROS_COMPONENT_MARK = "libmicroros.mk"


def check_no_vendored_micro_ros(packages: Iterable[Package], root: Path) -> None:
    """Refuse a copy of micro_ros_espidf_component in a firmware project's components/ (upstream's
    README clones it there) or the shared one beside it, or taken for a ROS package (its
    package.xml, in a project colcon then searched): the copy replaced the library the IDF image
    keeps (a component of the same name), and would build micro-ROS inside the firmware build, or
    colcon failed on it."""
    for package in packages:
        if package.kind is PackageKind.FIRMWARE:
            # Its own components/, and the one beside it that `espdock new` makes the projects share.
            places = (package.path / "components", package.path.parent / "components")
            copies = sorted(d for place in places for d in place.glob("*") if (d / UROS_COMPONENT_MARK).is_file())
        else:
            copies = [package.path] if (package.path / UROS_COMPONENT_MARK).is_file() else []
        if copies:
            raise WorkspaceError(
                f"{copies[0].relative_to(root)} is a copy of micro_ros_espidf_component: espdock builds micro-ROS "
                "once, in the IDF image, as a component of the same name, which this copy would replace "
                "(and colcon cannot build it)",
                "Remove it, and name the image's in the project's CMakeLists.txt: `list(APPEND EXTRA_COMPONENT_DIRS "
                "$ENV{UROS_COMPONENT_DIR})` before include(.../project.cmake). Its settings go in the firmware "
                "project: app-colcon.meta beside its CMakeLists.txt, the interface packages it uses as workspace "
                'packages it <depend>s on (docs/firmware.md, "The IDF image and the micro-ROS cache").',
            )


def check_idf_projects_typed(packages: Iterable[Package], root: Path) -> None:
    """Refuse a ROS package whose CMakeLists.txt is an ESP-IDF project's (it includes IDF's
    project.cmake) under another build type: colcon ran CMake on it, which failed on
    `include($ENV{IDF_PATH}/...)` with a hint to fix the package's code."""
    for package in packages:
        if package.kind is not PackageKind.ROS:
            continue
        try:
            text = (package.path / "CMakeLists.txt").read_text(errors="replace")
        except OSError:
            continue
        if idf_project_cmake(text):
            if package.build_type in ("ament_cmake", "cmake"):
                said = f"says build type {package.build_type} (or names none), which colcon builds with CMake alone"
            else:  # a misspelt one (`esp-idf`): no build type colcon knows either
                said = f"says build type {package.build_type}, not {FIRMWARE_BUILD_TYPE}"
            raise WorkspaceError(
                f"{package.name} ({package.path.relative_to(root)}) is an ESP-IDF project (its CMakeLists.txt "
                f"includes IDF's project.cmake), but its package.xml {said}",
                f"Set <export><build_type>{FIRMWARE_BUILD_TYPE}</build_type></export> in its package.xml: espdock "
                "builds it in the IDF image.",
            )


EXTRA_PACKAGES_DIR = "/opt/uros_builder/extra_ros_packages"


def derive_interface_packages(packages: tuple[Package, ...], firmware: Package | None = None) -> tuple[Package, ...]:
    """The workspace's interface packages FIRMWARE (default: every firmware package) depends on,
    transitively, in dependency order.

    Standard interfaces (std_msgs, sensor_msgs, ...) are not in the workspace: micro-ROS has them.
    A <test_depend> is no dependency of the library: the firmware's tests run on the host.
    """
    by_name = {p.name: p for p in packages}
    roots = [firmware] if firmware is not None else [p for p in packages if p.kind is PackageKind.FIRMWARE]
    wanted: set[str] = set()
    stack = [dep for p in roots for dep in p.depends - p.test_only_depends]
    while stack:
        name = stack.pop()
        package = by_name.get(name)
        if name in wanted or package is None or package.kind is not PackageKind.ROS:
            continue
        if name in STANDARD_INTERFACES:
            # micro-ROS builds its own beside the library's extra packages, and colcon there
            # refuses two packages of one name ("duplicate package name").
            raise WorkspaceError(
                f"{package.path} is a package named {name}, which micro-ROS builds itself: its library "
                "cannot take a second one, which firmware here depends on",
                f"Give the workspace's package a name of its own (and its users the new name), or keep "
                f"firmware off it: micro-ROS's {name} is the standard one.",
            )
        if not package.is_interface:
            if GENERATORS in package.depends:
                # Only that group goes into the library: its headers would be missing from the
                # firmware's build, which would blame the firmware.
                raise WorkspaceError(
                    f"{package.name} generates interfaces ({GENERATORS}), which firmware uses, but is not "
                    "in rosidl_interface_packages: micro-ROS's library holds only that group's packages",
                    "Add <member_of_group>rosidl_interface_packages</member_of_group> to "
                    f"{package.path / 'package.xml'}, as ROS 2's interface packages have it.",
                )
            continue
        wanted.add(name)
        stack.extend(package.depends - package.test_only_depends)
    return tuple(p for p in packages if p.name in wanted)


# What an interface package depends on to generate its code (rosidl_generate_interfaces).
GENERATORS = "rosidl_default_generators"


# sdkconfig settings that change what libmicroros.a is: upstream compiles the library against
# the app's sdkconfig.h (FreeRTOS tick rate, PSRAM cache workarounds, optimisation, lwIP
# options) and picks the middleware and network interface from the micro-ROS options.
LIBRARY_SDKCONFIG_PREFIXES = (
    "CONFIG_MICRO_ROS_",
    "CONFIG_FREERTOS_",
    "CONFIG_SPIRAM",
    "CONFIG_COMPILER_",
    "CONFIG_LWIP_",
    "CONFIG_ESP32_REV_MIN",
    "CONFIG_ESP_REV_MIN",
)
# The micro-ROS options only the app reads (upstream's examples pass them to
# rmw_uros_options_set_udp_address at run time): a new agent address builds no new library.
APP_ONLY_SDKCONFIG = frozenset({"CONFIG_MICRO_ROS_AGENT_IP", "CONFIG_MICRO_ROS_AGENT_PORT"})


# micro_ros_espidf_component's Kconfig choices, each its default first. `idf.py save-defconfig`
# writes no line for a default: the template's explicit ones gone, the same library was keyed
# afresh, a micro-ROS image (minutes on real IDF) for a configuration that had not changed. A
# choice no line makes is its default, as Kconfig makes it.
LIBRARY_CHOICES = (
    ("CONFIG_MICRO_ROS_ESP_XRCE_DDS_MIDDLEWARE", "CONFIG_MICRO_ROS_ESP_EMBEDDEDRTPS_MIDDLEWARE"),
    ("CONFIG_MICRO_ROS_ESP_NETIF_WLAN", "CONFIG_MICRO_ROS_ESP_NETIF_ENET", "CONFIG_MICRO_ROS_ESP_UART_TRANSPORT"),
)


SDKCONFIG_LINE = re.compile(r"^(CONFIG_[A-Za-z0-9_]+)=(.*)$|^#\s*(CONFIG_[A-Za-z0-9_]+) is not set\s*$")


def library_sdkconfig(defaults: Mapping[str, bytes], target: str, order: Sequence[str] = ()) -> str:
    """The micro-ROS-relevant lines of a firmware's sdkconfig.defaults (then .TARGET), later wins;
    of the files its CMakeLists.txt names instead (ORDER), as IDF reads them for the app.

    Returned sorted, so that apps whose library settings agree share one image.
    """
    values: dict[str, str] = {}
    for data in transport.defaults_in_order(defaults, target, order):
        for line in data.decode(errors="replace").splitlines():
            match = SDKCONFIG_LINE.match(line.strip())
            if not match:
                continue
            key = match.group(1) or match.group(3)
            if key.startswith(LIBRARY_SDKCONFIG_PREFIXES) and key not in APP_ONLY_SDKCONFIG:
                values[key] = match.group(2) if match.group(1) else "n"
    for choice in LIBRARY_CHOICES:
        if not values.keys() & set(choice):
            values[choice[0]] = "y"
    return "".join(
        f"# {key} is not set\n" if value == "n" else f"{key}={value}\n" for key, value in sorted(values.items())
    )


# Chips whose compiler rejects what upstream's toolchain template (esp32_toolchain.cmake.in)
# gives every chip but esp32c3: `-mlongcalls`, an Xtensa option, so libmicroros.a cannot build.
LONGCALLS_RISCV = ("esp32c2", "esp32c5", "esp32c6", "esp32h2", "esp32p4")


# Any value: IDF reads only "chip" (its __target_from_config), and a chip misspelt in it, "esp32-c3"
# or 'esp32c3', was passed over here, the firmware built for the workspace's chip without a word.
_IDF_TARGET_LINE = re.compile(r"^CONFIG_IDF_TARGET=(.*?)\s*$", re.MULTILINE)


def declared_target(defaults: Mapping[str, bytes], order: Sequence[str] = ()) -> str | None:
    """The chip a firmware's sdkconfig.defaults names (CONFIG_IDF_TARGET, as IDF reads it), if any;
    of the files its CMakeLists' SDKCONFIG_DEFAULTS names (ORDER), the first that names one, as IDF's
    __target_guess takes it."""
    return next(
        (chip for base in order or ("sdkconfig.defaults",) if (chip := sdkconfig_target(defaults.get(base, b"")))),
        None,
    )


def sdkconfig_target(data: bytes) -> str | None:
    """The chip an sdkconfig or defaults file's DATA names (CONFIG_IDF_TARGET), if any."""
    # utf-8-sig: past a Windows editor's byte order mark, which IDF's CMake (file(STRINGS)) skips too.
    match = _IDF_TARGET_LINE.search(data.decode("utf-8-sig", errors="replace"))
    if match is None:
        return None
    value = match.group(1)
    return (value[1:-1] if len(value) > 1 and value[0] == value[-1] == '"' else value) or None


def declared_chips(config: Config, inputs: BuildInputs, packages: Iterable[Package]) -> dict[str, str]:
    """The chip each firmware package among PACKAGES builds for as `espdock list` shows it: its
    CONFIG_IDF_TARGET, else the workspace's `target` (unchecked: package_target refuses a bad one
    before a build)."""
    return {p.name: _declared(inputs, p) or config.target for p in packages if p.kind is PackageKind.FIRMWARE}


def _declared(inputs: BuildInputs, firmware: Package) -> str | None:
    return declared_target(
        inputs.sdkconfig_defaults.get(firmware.name, {}), inputs.sdkconfig_order.get(firmware.name, ())
    )


def package_target(config: Config, inputs: BuildInputs, firmware: Package, override: str | None = None) -> str:
    """The chip FIRMWARE builds for: OVERRIDE (--target), else CONFIG_IDF_TARGET in its
    sdkconfig.defaults, else the workspace's `target`. Refused (before anything builds) when the
    package does not list it among its chips, or when micro-ROS cannot be built for it."""
    declared = _declared(inputs, firmware)
    if declared is not None:
        check_target(declared, f"CONFIG_IDF_TARGET in {firmware.name}/sdkconfig.defaults")
    target = override or declared or config.target
    supported = inputs.supported_targets.get(firmware.name)
    if supported and target not in supported:
        chips = [chip for chip in supported if chip in CHIP_TARGETS]
        raise WorkspaceError(
            f"{firmware.name} does not support {target}: it supports {', '.join(supported)}",
            f"Its main/idf_component.yml lists them under `targets`; build it for one (--target {chips[0]})."
            if chips
            else f"Its main/idf_component.yml lists them under `targets`, and none is an ESP-IDF chip: correct the "
            f"list (chips: {', '.join(CHIP_TARGETS)}).",
        )
    check_micro_ros_target(firmware.name, target)
    return target


def check_micro_ros_target(package: str, target: str, fix: str = "Build it for") -> None:
    """Refuse TARGET for PACKAGE where the pinned micro-ROS cannot be built for it."""
    if target in LONGCALLS_RISCV:
        raise WorkspaceError(
            f"{package}: micro-ROS cannot be built for {target}: the pinned micro_ros_espidf_component "
            "gives every chip but esp32c3 the Xtensa option -mlongcalls, which the RISC-V compiler rejects",
            f"{fix} esp32, esp32s2, esp32s3 or esp32c3.",
        )


# The prebuilt micro-ROS component requires esp_driver_gpio and esp_driver_spi, which ESP-IDF
# has only from v5.3 on (v5.2 has neither directory under components/). ESP-IDF 6 changed the
# default libc to picolibc, and micro-ROS needed upstream work for it (micro_ros_espidf_component
# #334): below 6 until a pin of micro-ROS is verified with it.
MIN_IDF, BELOW_IDF = (5, 3), (6, 0)


_IDF_TAG_VERSION = re.compile(r":(?:release-)?v(\d+)\.(\d+)")


def check_idf_image(reference: str) -> None:
    """Refuse an Espressif image whose tag names an ESP-IDF outside MIN_IDF..BELOW_IDF (a tag without
    a version, a digest, is left to the component manager's `idf: ">=5.3,<6"`)."""
    match = _IDF_TAG_VERSION.search(reference)
    if match is None:
        return
    version = (int(match.group(1)), int(match.group(2)))
    if version < MIN_IDF:
        raise WorkspaceError(
            f"idf_image {reference} is ESP-IDF {match.group(1)}.{match.group(2)}; espdock's micro-ROS component "
            "needs ESP-IDF 5.3 or newer (esp_driver_gpio, esp_driver_spi)",
            "Set idf_image to espressif/idf:v5.3.5 (the pinned default) or a later v5.x.",
        )
    if version >= BELOW_IDF:
        raise WorkspaceError(
            f"idf_image {reference} is ESP-IDF {match.group(1)}.{match.group(2)}; espdock supports ESP-IDF 5.3 up "
            "to, not including, 6: ESP-IDF 6 builds with picolibc instead of newlib, and no micro-ROS pin of "
            "espdock's is verified with it yet (micro_ros_espidf_component #334)",
            "Set idf_image to espressif/idf:v5.3.5 (the pinned default) or another v5.x.",
        )


COLCON_META_FORM = 'colcon.meta is {"names": {"<package>": {"cmake-args": ["-D..."]}}}.'
# What colcon's meta files hold (colcon-metadata): any other key is passed over without a word.
COLCON_META_KEYS = ("names", "paths")


def _check_colcon_meta(package: str, text: str) -> None:
    """Refuse an app-colcon.meta the micro-ROS build would not take as meant: colcon skips one
    that is no object, passes over a key it does not know (`name` for `names`: every setting
    dropped), and fails on a package entry that is no object."""
    where = f"{package}/app-colcon.meta"
    try:
        data = json.loads(text)
    except json.JSONDecodeError as exc:
        raise WorkspaceError(f"{where} is not colcon.meta JSON: {exc}", COLCON_META_FORM) from exc
    if not isinstance(data, dict):
        raise WorkspaceError(
            f"{where} is a JSON {_json_kind(data)}, not an object: colcon would skip it", COLCON_META_FORM
        )
    for unknown in (key for key in data if key not in COLCON_META_KEYS):
        close = difflib.get_close_matches(unknown, COLCON_META_KEYS, n=1)
        raise WorkspaceError(
            f"{where} has '{unknown}', which colcon does not read (it reads names and paths): what it "
            "sets would be dropped without a word",
            f"Did you mean '{close[0]}'?" if close else COLCON_META_FORM,
        )
    for key in COLCON_META_KEYS:
        entries = data.get(key, {})
        if not isinstance(entries, dict):
            raise WorkspaceError(f"{where}: {key} is a JSON {_json_kind(entries)}, not an object", COLCON_META_FORM)
        for name, entry in entries.items():
            if not isinstance(entry, dict):
                raise WorkspaceError(
                    f"{where}: {key}.{name} is a JSON {_json_kind(entry)}, not an object of colcon options",
                    COLCON_META_FORM,
                )
            args = entry.get("cmake-args", [])
            if not isinstance(args, list) or not all(isinstance(arg, str) for arg in args):
                raise WorkspaceError(f"{where}: {key}.{name}.cmake-args is not a list of strings", COLCON_META_FORM)


def _json_kind(value: object) -> str:
    kinds = {list: "list", str: "string", bool: "boolean", int: "number", float: "number", type(None): "null"}
    return kinds.get(type(value), "object")


def micro_ros_repository(ros_distro: str, target: str) -> str:
    """The repository of the micro-ROS images for ROS_DISTRO and chip TARGET (their tags are keys)."""
    return f"espdock/idf-micro-ros-{ros_distro}-{target}"


def micro_ros_image(
    config: Config, inputs: BuildInputs, packages: tuple[Package, ...], firmware: Package, target: str
) -> ImageSpec:
    """The IDF image with micro-ROS prebuilt for FIRMWARE's library inputs and its chip TARGET.

    The key covers only what goes into the library, so firmware packages with the same
    app-colcon.meta, library sdkconfig settings and interfaces get the same image.
    """
    defaults = dockerfile_args(inputs.idf_dockerfile)
    idf_image = config.idf_image or defaults.get("IDF_IMAGE", "")
    check_idf_image(idf_image)
    build_args = (
        ("IDF_IMAGE", idf_image),
        ("IDF_TARGET", target),
        ("MICRO_ROS_COMMIT", config.micro_ros_commit or defaults.get("MICRO_ROS_COMMIT", "")),
        ("MICRO_ROS_REPO", config.micro_ros_repo or defaults.get("MICRO_ROS_REPO", "")),
    )
    sources = inputs.idf_files.get(SOURCES_NAME)
    if sources is None:
        raise WorkspaceError(f"{SOURCES_FILE} is missing", "It pins every repository micro-ROS is built from.")
    parse_sources(sources.decode(errors="replace"))  # a malformed pin fails here, not in the image build
    meta = inputs.app_metas.get(firmware.name, "")
    if meta:
        _check_colcon_meta(firmware.name, meta)
    order = inputs.sdkconfig_order.get(firmware.name, ())
    link, where = transport.transport_choice(inputs.sdkconfig_defaults.get(firmware.name, {}), target, order)
    transport.check_transport(firmware.name, link, target, where=where)
    meta = transport.library_colcon_meta(firmware.name, meta, link, where)
    context: dict[str, bytes] = {
        IDF_DOCKERFILE: inputs.idf_dockerfile.encode(),
        **{f"{IDF_INPUT_DIR}/{rel}": data for rel, data in inputs.idf_files.items()},
        # An empty meta is colcon's "no app meta"; the file must exist for COPY.
        "micro-ros/app-colcon.meta": meta.encode() or b'{"names": {}}\n',
        "micro-ros/sdkconfig.defaults": library_sdkconfig(
            inputs.sdkconfig_defaults.get(firmware.name, {}), target, order
        ).encode(),
        # COPY needs the directory even when no interface package goes in.
        "micro-ros/extra_packages/.espdock-keep": b"",
    }
    interfaces = derive_interface_packages(packages, firmware)
    for package in interfaces:
        for rel, data in inputs.package_files[package.name].items():
            context[f"micro-ros/extra_packages/{package.name}/{rel}"] = data
    spec = keyed_image(
        micro_ros_repository(config.ros_distro, target),
        IDF_DOCKERFILE,
        "final",
        build_args,
        context,
        context=context,
        extra={"ros_distro": config.ros_distro.encode()},
    )
    # Where espdock's Dockerfile.idf copies them: rosidl's errors in the library build name these.
    sources = tuple((f"{EXTRA_PACKAGES_DIR}/{p.name}", str(p.path)) for p in interfaces)
    return replace(spec, origin=image_origin(IDF_DOCKERFILE, context, inputs.own_files), sources=sources)


def micro_ros_images(
    config: Config,
    inputs: BuildInputs,
    packages: tuple[Package, ...],
    override: str | None = None,
    selected: frozenset[str] | None = None,
) -> dict[str, ImageSpec]:
    """Each firmware package's micro-ROS image (package name -> spec) for its own chip; equal
    inputs, equal spec. OVERRIDE (--target) applies to the SELECTED packages (None: all)."""
    return {
        p.name: micro_ros_image(
            config,
            inputs,
            packages,
            p,
            package_target(config, inputs, p, override if selected is None or p.name in selected else None),
        )
        for p in packages
        if p.kind is PackageKind.FIRMWARE
    }


def spec_target(spec: ImageSpec, default: str = "esp32") -> str:
    """The chip a micro-ROS image (and every firmware built in it) is for."""
    return dict(spec.build_args).get("IDF_TARGET", default)


def workspace_micro_ros_images(
    config: Config, inputs: BuildInputs, packages: tuple[Package, ...], override: str | None = None
) -> dict[str, ImageSpec]:
    """micro_ros_images for the `micro-ros` commands: a workspace without firmware has none to act on."""
    specs = micro_ros_images(config, inputs, packages, override)
    if not specs:
        raise WorkspaceError("this workspace has no firmware packages, so no micro-ROS library", "See `espdock new`.")
    return specs


def not_a_firmware_package(name: str) -> WorkspaceError:
    return WorkspaceError(f"'{name}' is not a firmware package", "Firmware packages have build type esp_idf.")


def images_to_rebuild(
    specs: Mapping[str, ImageSpec], names: Sequence[str], packages: Iterable[str], workspace: Workspace
) -> tuple[ImageSpec, ...]:
    """The distinct micro-ROS images of the firmware packages NAMES (every one's when none is
    named), from SPECS (workspace_micro_ros_images); PACKAGES: every package WORKSPACE has."""
    known = set(packages)
    for name in names:
        if name not in known:  # a misspelt board is no package at all, not one of another kind
            raise unknown_package(name, specs, workspace, "firmware")
        if name not in specs:
            raise not_a_firmware_package(name)
    chosen = [specs[name] for name in names] if names else list(specs.values())
    return tuple({spec.key: spec for spec in chosen}.values())


def firmware_step(plan: Plan, name: str) -> tuple[Plan, IdfBuild]:
    """From a plan that builds firmware package NAME: the plan that only ensures its IDF image,
    and its build step (what `espdock idf`, `flash` and `monitor` run in)."""
    step = next((s for s in plan.steps if isinstance(s, IdfBuild) and s.package == name), None)
    if step is None:
        raise not_a_firmware_package(name)
    spec = next(spec for spec in plan.idf_images if spec.key == step.image_key)
    return Plan(plan.workspace, (EnsureImage(spec),), (spec,)), step


def check_inside(workspace: Workspace, package: str, project: Path) -> None:
    """Refuse a firmware PROJECT found through a link to outside the workspace, as colcon finds
    it: the IDF containers see only the workspace (ROS packages get the link's directory mounted)."""
    if not (real := project.resolve()).is_relative_to(workspace.root.resolve()):
        raise WorkspaceError(
            f"firmware package {package} is linked from outside the workspace ({project} -> "
            f"{real}): the IDF containers see only the workspace",
            "Move the project into the workspace; ROS packages may be linked in, firmware projects may not.",
        )


def firmware_steps(
    workspace: Workspace,
    config: Config,
    firmware: tuple[Package, ...],
    idf_images: Mapping[str, ImageSpec],
    all_packages: tuple[Package, ...],
    force: bool = False,
) -> tuple[list[EnsureImage | IdfBuild | InstallFirmware], tuple[ImageSpec, ...]]:
    """The firmware side of a build of FIRMWARE: each distinct micro-ROS image once, then each
    package's IDF build and install; and those images (IDF_IMAGES: each package's, see
    micro_ros_images)."""
    steps: list[EnsureImage | IdfBuild | InstallFirmware] = []
    ensured: dict[str, ImageSpec] = {}
    everything = {p.name for p in all_packages}
    interfaces = {p.name for p in all_packages if p.kind is PackageKind.ROS and p.is_interface}
    for package in firmware:
        check_inside(workspace, package.name, package.path)  # before minutes of its micro-ROS image
        spec = idf_images.get(package.name)
        if spec is None:
            raise WorkspaceError(f"firmware package {package.name} needs Dockerfile.idf at the workspace root")
        if spec.key not in ensured:
            ensured[spec.key] = spec
            steps.append(EnsureImage(spec))
        project = package.path.relative_to(workspace.root).as_posix()
        target = spec_target(spec, config.target)
        reached = {p.name for p in derive_interface_packages(all_packages, package)}  # what its library holds
        steps.append(
            IdfBuild(
                package.name,
                project,
                spec.tag,
                target,
                spec.key,
                force,
                workspace.colcon_root,
                tuple(sorted(interfaces - reached)),
            )
        )
        run_depends = tuple(sorted(package.depends & everything))
        steps.append(InstallFirmware(package.name, project, run_depends))
    return steps, tuple(ensured.values())
