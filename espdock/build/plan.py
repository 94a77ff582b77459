"""The build plan: pure data, made from the workspace and config without touching the engine."""

from __future__ import annotations

import hashlib
import json
import os
import posixpath
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, replace
from pathlib import Path

from espdock.config import Config, check_target
from espdock.errors import WorkspaceError
from espdock.firmware import transport
from espdock.firmware.pins import parse_sources
from espdock.layout import (
    IDF_DOCKERFILE,
    IDF_INPUT_DIR,
    ROS_BUILD_BASE,
    ROS_DOCKERFILE,
    ROS_OFFICIAL_DOCKERFILE,
    ROSDEP_CONTEXT_DIR,
    ROSDEP_LOCK,
    SOURCES_FILE,
    SOURCES_NAME,
    WORKSPACE_MOUNT,
    firmware_install_dir,
)
from espdock.ros import rosdeps
from espdock.ros.colcon import ColconSettings, left_out, sets_build_testing, with_build_testing
from espdock.workspace import BuildInputs, Package, PackageKind, Workspace, select_up_to

LABEL_KEY = "io.espdock.key"
LABEL_INPUTS = "io.espdock.inputs"
LABEL_WORKSPACE = "io.espdock.workspace"


def cache_ref(registry: str, tag: str) -> str:
    """Where a keyed image TAG lives in the cache REGISTRY: the same name and key, under it."""
    return f"{registry.rstrip('/')}/{tag}"


@dataclass(frozen=True)
class ImageSpec:
    """An image espdock builds, tagged by a hash of everything that decides its content."""

    repository: str
    key: str
    dockerfile: str
    target: str
    build_args: tuple[tuple[str, str], ...]
    # The inputs that made the key, name -> sha256, shown by status commands.
    inputs: tuple[tuple[str, str], ...] = ()
    # The build context, by relative path; None: the workspace root (filtered by .dockerignore).
    context: tuple[tuple[str, bytes], ...] | None = None
    # Where the Dockerfile came from, and why (the workspace's own wins over espdock's default).
    origin: str = ""

    @property
    def tag(self) -> str:
        return f"{self.repository}:{self.key[:16]}"

    def labels(self) -> dict[str, str]:
        return {LABEL_KEY: self.key, LABEL_INPUTS: json.dumps(dict(self.inputs), sort_keys=True)}


@dataclass(frozen=True)
class EnsureBaseImage:
    """Make the base image a Dockerfile starts FROM available locally."""

    image: str

    @property
    def name(self) -> str:
        return f"base image {self.image}"


@dataclass(frozen=True)
class EnsureImage:
    """Build SPEC unless an image with its key already exists (or always, when FORCE)."""

    spec: ImageSpec
    force: bool = False

    @property
    def name(self) -> str:
        return f"image {self.spec.repository}"


@dataclass(frozen=True)
class ColconBuild:
    """colcon build of PACKAGES (in build order), in a container of IMAGE with the workspace mounted,
    run in its colcon root."""

    image: str
    packages: tuple[str, ...]
    # Each package's directory relative to the colcon root, and its workspace dependencies: what
    # colcon is pointed at, and what the runner's stamps are made of (a no-change build starts
    # no container).
    sources: tuple[tuple[str, str], ...] = ()
    depends: tuple[tuple[str, tuple[str, ...]], ...] = ()
    colcon_root: str = "ws"
    force: bool = False
    name: str = "colcon build"
    # The options given after `--` (checked: espdock.ros.colcon), each package's colcon settings
    # digest, and the user's colcon defaults file on the host (mounted), if any.
    colcon_args: tuple[str, ...] = ()
    settings: tuple[tuple[str, str], ...] = ()
    defaults_file: str | None = None
    # TESTING: a build for `espdock test` (tests configured, in the image with the test
    # dependencies); TESTS_OFF: CMake packages configured with BUILD_TESTING=OFF (the wheels
    # image lacks ament's lint packages), unless the options after `--` set it.
    testing: bool = False
    tests_off: bool = False
    # Each package's package.xml dependencies, and which of them are test_depend only: what a
    # failure's hint says about a dependency colcon could not find.
    declared: tuple[tuple[str, frozenset[str], frozenset[str]], ...] = ()

    @property
    def workdir(self) -> str:
        return _container_path(self.colcon_root)

    @property
    def options(self) -> tuple[str, ...]:
        """The options after `--`, with BUILD_TESTING=OFF where TESTS_OFF asks for it, and ON for
        a test build (CMake would keep the OFF an earlier build cached)."""
        if self.testing:
            return with_build_testing(self.colcon_args, "ON")
        return with_build_testing(self.colcon_args, "OFF") if self.tests_off else self.colcon_args

    @property
    def says_tests_off(self) -> bool:
        """Whether this build turns the CMake packages' tests off itself (the user did not set it)."""
        return self.tests_off and not sets_build_testing(self.colcon_args)

    @property
    def stamp_image(self) -> str:
        """What the packages' stamps hold of the image and how tests are configured: a test build
        and a plain one never pass for each other."""
        configured = "tests" if self.testing else "no-tests" if self.says_tests_off else ""
        return f"{self.image}\0{configured}" if configured else self.image

    def argv(self, rebuild: tuple[str, ...] = ()) -> tuple[str, ...]:
        """colcon's command line; REBUILD: only these packages (the changed ones and their
        dependents), the others being up to date in install/, where colcon finds them."""
        # Exactly these packages: colcon never sees the firmware packages (a build type it has
        # no task for) nor, for a selection, the packages left out.
        select = ("--packages-select", *rebuild) if rebuild and len(rebuild) < len(self.packages) else ()
        return (
            "colcon", "build", "--base-paths", *(rel for _, rel in self.sources), "--build-base", ROS_BUILD_BASE,
            # Live output per line plus colcon's own start/finish lines.
            "--event-handlers", "console_direct+", "console_start_end+", "summary+",
            *select, *self.options,
        )  # fmt: skip


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

    @property
    def name(self) -> str:
        return f"idf.py build {self.package}"

    @property
    def project_dir(self) -> str:
        return _container_path(self.project)

    @property
    def build_dir(self) -> str:
        return _container_path(f"{self.colcon_root}/build/{self.package}")

    @property
    def install_dir(self) -> str:
        """Where the installed artefacts are in the container (flashing runs there)."""
        return _container_path(f"{self.colcon_root}/{firmware_install_dir(self.package)}")

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


@dataclass(frozen=True)
class RuntimeImage:
    """The workspace's runtime image: BASE (no compilers) plus the install trees of PACKAGES, tagged
    REPOSITORY:<key> (the key hashes BASE's key and every installed file) and REPOSITORY:latest."""

    base: ImageSpec
    repository: str
    packages: tuple[str, ...]
    colcon_root: str = "ws"
    name: str = "runtime image"

    @property
    def stable_tag(self) -> str:
        return f"{self.repository}:latest"


Step = EnsureBaseImage | EnsureImage | ColconBuild | IdfBuild | InstallFirmware | RuntimeImage

# Where a runtime image holds the workspace's install tree (the entrypoint sources it).
RUNTIME_INSTALL = "/opt/espdock/ws/install"
# What Dockerfile.ros-official's runtime stage adds from docker/.
OFFICIAL_ENTRYPOINT = "docker/ros-entrypoint.sh"
# The stage of the ROS image's Dockerfile that runtime images start from.
RUNTIME_STAGE = "runtime"


def _container_path(rel: str) -> str:
    """Where REL (relative to the workspace root) is in a build container."""
    return posixpath.normpath(f"{WORKSPACE_MOUNT}/{rel}")


@dataclass(frozen=True)
class Plan:
    workspace: Workspace
    steps: tuple[Step, ...] = field(default_factory=tuple)
    # The distinct micro-ROS images the firmware steps use.
    idf_images: tuple[ImageSpec, ...] = ()


def dockerfile_args(text: str) -> dict[str, str]:
    """The build args a Dockerfile declares with a default (ARG NAME=value)."""
    args = {}
    for match in re.finditer(r"^\s*ARG\s+([A-Za-z_][A-Za-z0-9_]*)=(\S+)\s*$", text, re.MULTILINE):
        args.setdefault(match.group(1), match.group(2).strip("\"'"))
    return args


def image_key(parts: Mapping[str, bytes]) -> tuple[str, tuple[tuple[str, str], ...]]:
    """A content key over named inputs: the same inputs give the same key, any change a new one."""
    inputs = tuple((name, hashlib.sha256(parts[name]).hexdigest()) for name in sorted(parts))
    digest = hashlib.sha256()
    for name, sha in inputs:
        digest.update(f"{name}\0{sha}\n".encode())
    return digest.hexdigest(), inputs


def base_image(config: Config, ros_dockerfile_text: str) -> str:
    """The image a ROS Dockerfile starts FROM: the configured one, else its BASE_IMAGE default."""
    return config.base_image or dockerfile_args(ros_dockerfile_text).get("BASE_IMAGE", "")


def ros_build_image(
    config: Config,
    dockerfile_text: str,
    image_files: Mapping[str, bytes],
    own_files: frozenset[str] = frozenset(),
    rosdep_lock: dict | None = None,
    dockerfile: str = ROS_DOCKERFILE,
) -> ImageSpec:
    """The image colcon runs in: DOCKERFILE's `build` stage, keyed by its inputs, built from a
    context of just those (docker/ for the wheels, and what the rosdep lock installs)."""
    base = base_image(config, dockerfile_text)
    files = {
        dockerfile: dockerfile_text.encode(),
        **image_files,
        **{f"{ROSDEP_CONTEXT_DIR}/{n}": data for n, data in rosdeps.image_files(rosdep_lock).items()},
    }
    flavour = "" if dockerfile == ROS_DOCKERFILE else "-official"
    repository = f"espdock/ros-{config.ros_distro}{flavour}-build"
    spec = _keyed_image(repository, dockerfile, "build", (("BASE_IMAGE", base),), files, context=files)
    return replace(spec, origin=_origin(dockerfile, files, own_files))


def ros_image(config: Config, inputs: BuildInputs) -> tuple[str, str, rosdeps.RosImage]:
    """The chosen ROS image (setting ros_image): its Dockerfile's name and text, and what it provides."""
    if config.ros_image == "official":
        text = inputs.ros_official_dockerfile
        # The official image's ament index is not known before it is pulled: every dependency
        # goes through rosdep, whose ROS package rules (ros-<distro>-*) apt finds installed.
        # Its apt's Python packages constrain the lock's pip part: another image, another lock.
        constraints = (("BASE_IMAGE", base_image(config, text)),)
        image = rosdeps.RosImage("official", config.ros_distro, _rosdep_os(text), frozenset(), constraints)
        return ROS_OFFICIAL_DOCKERFILE, text, image
    text = inputs.ros_dockerfile
    locks = {rel: d for rel, d in sorted(inputs.ros_files.items()) if re.fullmatch(r"docker/ros-[a-z]+\.txt", rel)}
    provided = rosdeps.wheel_packages((data.decode(errors="replace") for data in locks.values()), config.ros_distro)
    constraints = tuple((rel, hashlib.sha256(data).hexdigest()) for rel, data in locks.items())
    return ROS_DOCKERFILE, text, rosdeps.RosImage("wheels", config.ros_distro, _rosdep_os(text), provided, constraints)


def _rosdep_os(dockerfile_text: str) -> str:
    os_spec = dockerfile_args(dockerfile_text).get("ROSDEP_OS", "")
    if not re.fullmatch(r"[a-z]+:[a-z0-9.]+", os_spec):
        raise WorkspaceError(
            f"the ROS image's Dockerfile declares no ARG ROSDEP_OS=<os>:<version> (got {os_spec!r})",
            "It names the OS rosdep resolves the packages' dependencies for, e.g. ARG ROSDEP_OS=debian:bookworm.",
        )
    return os_spec


def has_stage(dockerfile: bytes, stage: str) -> bool:
    """Whether DOCKERFILE declares a build stage named STAGE (`FROM ... AS STAGE`)."""
    pattern = rb"(?im)^\s*FROM\s+(--\S+\s+)*\S+\s+AS\s+" + re.escape(stage.encode()) + rb"\s*$"
    return re.search(pattern, dockerfile) is not None


def runtime_base_image(build: ImageSpec) -> ImageSpec:
    """The runtime base that goes with the ROS build image BUILD: the `runtime` stage of the same
    Dockerfile, from the same inputs. Whichever ROS image the build uses (its Dockerfile is chosen
    in one place), its runtime images start from this stage of it."""
    files = dict(build.context or ())
    spec = _keyed_image(
        build.repository.removesuffix("-build") + "-runtime",
        build.dockerfile,
        RUNTIME_STAGE,
        build.build_args,
        files,
        context=files,
        extra={"target": RUNTIME_STAGE.encode()},
    )
    return replace(spec, origin=build.origin)


def runtime_repository(config: Config, workspace: Workspace) -> str:
    """espdock/<name>: the workspace's runtime images (name: the setting, else the directory's name)."""
    name = config.name or re.sub(r"[^a-z0-9._-]+", "-", workspace.root.name.lower()).strip("._-")
    return f"espdock/{name or 'workspace'}"


def runtime_image_spec(step: RuntimeImage, install_digest: str) -> ImageSpec:
    """The runtime image of STEP for an install tree with INSTALL_DIGEST: one layer over the base."""
    dockerfile = f"FROM {step.base.tag} AS workspace\nCOPY install {RUNTIME_INSTALL}\n"
    key, inputs = image_key({"base": step.base.key.encode(), "install": install_digest.encode()})
    return ImageSpec(
        repository=step.repository,
        key=key,
        dockerfile="Dockerfile",
        target="workspace",
        build_args=(),
        inputs=inputs,
        context=(("Dockerfile", dockerfile.encode()),),
        origin=f"generated: {step.base.tag} plus the install trees of {', '.join(step.packages)}",
    )


def _origin(dockerfile: str, files: Mapping[str, bytes], own_files: frozenset[str]) -> str:
    """Which of an image's input files are the workspace's own, which espdock's defaults."""
    own = sorted(n for n in files if n in own_files)
    if dockerfile in own_files:
        head = f"{dockerfile}: the workspace's own (a workspace file wins over espdock's default)"
    else:
        head = f"{dockerfile}: espdock's default (the workspace has none of its own)"
    others = [n for n in own if n != dockerfile]
    return head + (f"; the workspace's own {', '.join(others)}" if others else "")


def _keyed_image(
    repository: str,
    dockerfile: str,
    target: str,
    build_args: tuple[tuple[str, str], ...],
    files: Mapping[str, bytes],
    context: Mapping[str, bytes] | None = None,
    extra: Mapping[str, bytes] | None = None,
) -> ImageSpec:
    """An ImageSpec keyed by FILES, the build args and EXTRA (what else decides the image)."""
    parts = {**files, **{f"arg:{k}": v.encode() for k, v in build_args}, **(extra or {})}
    key, inputs = image_key(parts)
    return ImageSpec(
        repository=repository,
        key=key,
        dockerfile=dockerfile,
        target=target,
        build_args=build_args,
        inputs=inputs,
        context=None if context is None else tuple(sorted(context.items())),
    )


def derive_interface_packages(packages: tuple[Package, ...], firmware: Package | None = None) -> tuple[Package, ...]:
    """The workspace's interface packages FIRMWARE (default: every firmware package) depends on,
    transitively, in dependency order.

    Standard interfaces (std_msgs, sensor_msgs, ...) are not in the workspace: micro-ROS has them.
    """
    by_name = {p.name: p for p in packages}
    roots = [firmware] if firmware is not None else [p for p in packages if p.kind is PackageKind.FIRMWARE]
    wanted: set[str] = set()
    stack = [dep for p in roots for dep in p.depends]
    while stack:
        name = stack.pop()
        package = by_name.get(name)
        if name in wanted or package is None or package.kind is not PackageKind.ROS or not package.is_interface:
            continue
        wanted.add(name)
        stack.extend(package.depends)
    return tuple(p for p in packages if p.name in wanted)


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
SDKCONFIG_LINE = re.compile(r"^(CONFIG_[A-Za-z0-9_]+)=(.*)$|^#\s*(CONFIG_[A-Za-z0-9_]+) is not set\s*$")


def library_sdkconfig(defaults: Mapping[str, bytes], target: str) -> str:
    """The micro-ROS-relevant lines of a firmware's sdkconfig.defaults (then .TARGET), later wins.

    Returned sorted, so that apps whose library settings agree share one image.
    """
    values: dict[str, str] = {}
    for name in ("sdkconfig.defaults", f"sdkconfig.defaults.{target}"):
        for line in defaults.get(name, b"").decode(errors="replace").splitlines():
            match = SDKCONFIG_LINE.match(line.strip())
            if not match:
                continue
            key = match.group(1) or match.group(3)
            if key.startswith(LIBRARY_SDKCONFIG_PREFIXES):
                values[key] = match.group(2) if match.group(1) else "n"
    return "".join(
        f"# {key} is not set\n" if value == "n" else f"{key}={value}\n" for key, value in sorted(values.items())
    )


# Chips whose compiler rejects what upstream's toolchain template (esp32_toolchain.cmake.in)
# gives every chip but esp32c3: `-mlongcalls`, an Xtensa option, so libmicroros.a cannot build.
LONGCALLS_RISCV = ("esp32c2", "esp32c5", "esp32c6", "esp32h2", "esp32p4")
_IDF_TARGET_LINE = re.compile(r'^CONFIG_IDF_TARGET="?([A-Za-z0-9_]+)"?\s*$', re.MULTILINE)


def declared_target(defaults: Mapping[str, bytes]) -> str | None:
    """The chip a firmware's sdkconfig.defaults names (CONFIG_IDF_TARGET, as IDF reads it), if any."""
    match = _IDF_TARGET_LINE.search(defaults.get("sdkconfig.defaults", b"").decode(errors="replace"))
    return match.group(1) if match else None


def package_target(config: Config, inputs: BuildInputs, firmware: Package, override: str | None = None) -> str:
    """The chip FIRMWARE builds for: OVERRIDE (--target), else CONFIG_IDF_TARGET in its
    sdkconfig.defaults, else the workspace's `target`. Refused (before anything builds) when the
    package does not list it among its chips, or when micro-ROS cannot be built for it."""
    declared = declared_target(inputs.sdkconfig_defaults.get(firmware.name, {}))
    if declared is not None:
        check_target(declared, f"CONFIG_IDF_TARGET in {firmware.name}/sdkconfig.defaults")
    target = override or declared or config.target
    supported = inputs.supported_targets.get(firmware.name)
    if supported and target not in supported:
        raise WorkspaceError(
            f"{firmware.name} does not support {target}: it supports {', '.join(supported)}",
            f"Its main/idf_component.yml lists them under `targets`; build it for one (--target {supported[0]}).",
        )
    if target in LONGCALLS_RISCV:
        raise WorkspaceError(
            f"{firmware.name}: micro-ROS cannot be built for {target}: the pinned micro_ros_espidf_component "
            "gives every chip but esp32c3 the Xtensa option -mlongcalls, which the RISC-V compiler rejects",
            "Build it for esp32, esp32s2, esp32s3 or esp32c3.",
        )
    return target


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


def _check_colcon_meta(package: str, text: str) -> None:
    try:
        names = json.loads(text).get("names", {})
        if not isinstance(names, dict):
            raise AttributeError("'names' is not an object")
    except (json.JSONDecodeError, AttributeError) as exc:
        raise WorkspaceError(f"{package}/app-colcon.meta is not colcon.meta JSON: {exc}") from exc


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
    link = transport.firmware_transport(inputs.sdkconfig_defaults.get(firmware.name, {}), target)
    transport.check_transport(firmware.name, link, target)
    meta = transport.library_colcon_meta(firmware.name, meta, link)
    context: dict[str, bytes] = {
        IDF_DOCKERFILE: inputs.idf_dockerfile.encode(),
        **{f"{IDF_INPUT_DIR}/{rel}": data for rel, data in inputs.idf_files.items()},
        # An empty meta is colcon's "no app meta"; the file must exist for COPY.
        "micro-ros/app-colcon.meta": meta.encode() or b'{"names": {}}\n',
        "micro-ros/sdkconfig.defaults": library_sdkconfig(
            inputs.sdkconfig_defaults.get(firmware.name, {}), target
        ).encode(),
        # COPY needs the directory even when no interface package goes in.
        "micro-ros/extra_packages/.espdock-keep": b"",
    }
    for package in derive_interface_packages(packages, firmware):
        for rel, data in inputs.package_files[package.name].items():
            context[f"micro-ros/extra_packages/{package.name}/{rel}"] = data
    spec = _keyed_image(
        f"espdock/idf-micro-ros-{config.ros_distro}-{target}",
        IDF_DOCKERFILE,
        "final",
        build_args,
        context,
        context=context,
        extra={"ros_distro": config.ros_distro.encode()},
    )
    return replace(spec, origin=_origin(IDF_DOCKERFILE, context, inputs.own_files))


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


def plan_build(
    workspace: Workspace,
    config: Config,
    packages: tuple[Package, ...],
    ros_image: ImageSpec,
    selected: tuple[str, ...] = (),
    idf_images: Mapping[str, ImageSpec] | None = None,
    all_packages: tuple[Package, ...] | None = None,
    force: bool = False,
    colcon: ColconSettings | None = None,
    testing: bool = False,
    tests_off: bool = False,
) -> Plan:
    """The steps of `espdock build [SELECTED...]` over PACKAGES (already in build order: the
    selection closed over its dependencies when SELECTED names any).

    IDF_IMAGES: each firmware package's micro-ROS image (see micro_ros_images). FORCE: build
    even what is up to date. COLCON: the options after `--` and colcon's settings files.
    TESTING: build for `espdock test`; TESTS_OFF: configure CMake packages without tests.
    """
    colcon = colcon or ColconSettings()
    ros = [p for p in packages if p.kind is PackageKind.ROS]
    firmware = [p for p in packages if p.kind is PackageKind.FIRMWARE]
    names = {p.name for p in ros}
    steps: list[Step] = []
    if ros:
        base = dict(ros_image.build_args)["BASE_IMAGE"]
        steps += [
            EnsureBaseImage(base),
            EnsureImage(ros_image),
            ColconBuild(
                image=ros_image.tag,
                packages=tuple(p.name for p in ros),
                sources=tuple((p.name, Path(os.path.relpath(p.path, workspace.ws_dir)).as_posix()) for p in ros),
                depends=tuple((p.name, tuple(sorted(p.depends & names))) for p in ros),
                colcon_root=workspace.colcon_root,
                force=force,
                colcon_args=colcon.args,
                settings=tuple(item for item in colcon.digests if item[0] in names),
                defaults_file=colcon.defaults_file,
                testing=testing,
                tests_off=tests_off and not testing,
                declared=tuple((p.name, p.depends, p.test_only_depends) for p in ros),
            ),
        ]
        built = {p.name for p in (all_packages or packages) if p.kind is PackageKind.ROS}
        # Only when asked (setting runtime_image): `espdock run` and `espdock compose` make it
        # when they need it, so an edit-build loop does not pay for it. A workspace's own ROS
        # Dockerfile without a runtime stage builds, but makes no runtime image.
        dockerfile = dict(ros_image.context or ()).get(ros_image.dockerfile, b"")
        if config.runtime_image and has_stage(dockerfile, RUNTIME_STAGE):
            base_runtime = runtime_base_image(ros_image)
            steps += [
                EnsureImage(base_runtime),
                RuntimeImage(
                    base_runtime, runtime_repository(config, workspace), tuple(sorted(built)), workspace.colcon_root
                ),
            ]
    ensured: dict[str, ImageSpec] = {}
    everything = {p.name for p in (all_packages or packages)}
    for package in firmware:
        spec = (idf_images or {}).get(package.name)
        if spec is None:
            raise WorkspaceError(f"firmware package {package.name} needs Dockerfile.idf at the workspace root")
        if spec.key not in ensured:
            ensured[spec.key] = spec
            steps.append(EnsureImage(spec))
        project = package.path.relative_to(workspace.root).as_posix()
        target = spec_target(spec, config.target)
        steps.append(IdfBuild(package.name, project, spec.tag, target, spec.key, force, workspace.colcon_root))
        run_depends = tuple(sorted(package.depends & everything))
        steps.append(InstallFirmware(package.name, project, run_depends))
    return Plan(workspace=workspace, steps=tuple(steps), idf_images=tuple(ensured.values()))


def plan_workspace(
    workspace: Workspace,
    config: Config,
    packages: tuple[Package, ...],
    inputs: BuildInputs,
    names: tuple[str, ...] = (),
    only: PackageKind | None = None,
    force: bool = False,
    target: str | None = None,
    colcon: ColconSettings | None = None,
    checked: tuple[str, ...] | None = None,
    testing: bool = False,
) -> Plan:
    """`espdock build [NAMES...] [--only KIND] [--force] [--target CHIP] [-- COLCON_ARGS...]` over
    the workspace's PACKAGES (in build order). Each firmware package builds for its own chip
    (package_target); TARGET overrides it for the packages built. CHECKED: see checked_packages.
    TESTING: the build `espdock test` runs first (tests configured on every image flavour; on the
    wheels image a plain build configures CMake packages without them, since it lacks ament's lint
    packages)."""
    selected = select_up_to(packages, names) if names else packages
    if only is not None:
        selected = tuple(p for p in selected if p.kind is only)
    name, text, image = ros_image(config, inputs)
    lock = rosdeps.read_lock(inputs.rosdep_lock, ROSDEP_LOCK)
    needed = rosdeps.needed_keys(packages, image)
    # The lock is current here (the caller made it so, or refused a stale one under --locked).
    to_check = checked_packages(packages, selected, colcon.args if colcon else (), checked)
    rosdeps.check_dependencies(to_check, needed, lock, image, building=checked is None)
    # The official image reads only the rosdep installer of docker/, and the entry point (runtime).
    official = {k: v for k, v in inputs.ros_files.items() if "rosdep" in k or k == OFFICIAL_ENTRYPOINT}
    files = inputs.ros_files if name == ROS_DOCKERFILE else official
    ros_spec = ros_build_image(config, text, files, inputs.own_files, lock if needed else None, name)
    chosen = frozenset(p.name for p in selected)
    # Only the packages built must be buildable for their chip; the others keep their own.
    firmware = tuple(p for p in packages if p.kind is not PackageKind.FIRMWARE or p.name in chosen)
    idf_images = micro_ros_images(config, inputs, firmware, target, chosen)
    return plan_build(
        workspace,
        config,
        selected,
        ros_spec,
        names,
        idf_images=idf_images,
        all_packages=packages,
        force=force,
        colcon=colcon,
        testing=testing,
        tests_off=image.flavour == "wheels",
    )


def checked_packages(
    packages: tuple[Package, ...],
    selected: tuple[Package, ...],
    colcon_args: tuple[str, ...] = (),
    checked: tuple[str, ...] | None = None,
) -> tuple[Package, ...]:
    """The packages whose dependencies the image must serve: what colcon builds of SELECTED (its
    --packages-skip and --packages-ignore options honoured), or, for `run` and `shell`, CHECKED
    and the workspace packages they depend on (none for a shell)."""
    if checked is not None:
        return select_up_to(packages, checked) if checked else ()
    depends = {p.name: p.depends for p in packages}
    skipped = left_out(colcon_args, depends)
    return tuple(p for p in selected if p.name not in skipped)


def firmware_step(plan: Plan, name: str) -> tuple[Plan, IdfBuild]:
    """From a plan that builds firmware package NAME: the plan that only ensures its IDF image,
    and its build step (what `espdock idf`, `flash` and `monitor` run in)."""
    step = next((s for s in plan.steps if isinstance(s, IdfBuild) and s.package == name), None)
    if step is None:
        raise WorkspaceError(f"'{name}' is not a firmware package", "Firmware packages have build type esp_idf.")
    spec = next(spec for spec in plan.idf_images if spec.key == step.image_key)
    return Plan(plan.workspace, (EnsureImage(spec),), (spec,)), step
