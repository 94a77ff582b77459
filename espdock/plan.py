"""The build plan: pure data, made from the workspace and config without touching the engine."""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Mapping
from dataclasses import dataclass, field

from espdock.config import Config
from espdock.errors import ConfigError, WorkspaceError
from espdock.workspace import BuildInputs, Package, PackageKind, Workspace

ROS_DOCKERFILE = "Dockerfile.ros"
IDF_DOCKERFILE = "Dockerfile.idf"
# What the images are built from besides their Dockerfiles; docker/idf belongs to the IDF image only.
IMAGE_INPUT_DIR = "docker"
IDF_INPUT_DIR = "docker/idf"
WORKSPACE_MOUNT = "/workspace"
LABEL_KEY = "io.espdock.key"
LABEL_INPUTS = "io.espdock.inputs"
LABEL_WORKSPACE = "io.espdock.workspace"
FIRMWARE_BUILD_TYPE = "esp_idf"


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
    """colcon build of the ROS packages, in a container of IMAGE with ws/ mounted."""

    image: str
    packages: tuple[str, ...]
    # Empty: the whole workspace; else colcon's --packages-up-to these.
    up_to: tuple[str, ...] = ()
    name: str = "colcon build"

    @property
    def workdir(self) -> str:
        return f"{WORKSPACE_MOUNT}/ws"

    def argv(self) -> tuple[str, ...]:
        args = [
            "colcon", "build", "--base-paths", "src",
            # Live output per line plus colcon's own start/finish lines.
            "--event-handlers", "console_direct+", "console_start_end+", "summary+",
        ]  # fmt: skip
        if self.up_to:
            args += ["--packages-up-to", *self.up_to]
        return tuple(args)


@dataclass(frozen=True)
class IdfBuild:
    """`idf.py build` of one firmware package in a container of IMAGE, output in ws/build/<package>."""

    package: str
    # The project dir relative to firmware/.
    project: str
    image: str
    target: str
    image_key: str

    @property
    def name(self) -> str:
        return f"idf.py build {self.package}"

    @property
    def project_dir(self) -> str:
        return f"{WORKSPACE_MOUNT}/firmware/{self.project}"

    @property
    def build_dir(self) -> str:
        return f"{WORKSPACE_MOUNT}/ws/build/{self.package}"

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


Step = EnsureBaseImage | EnsureImage | ColconBuild | IdfBuild | InstallFirmware


@dataclass(frozen=True)
class Plan:
    workspace: Workspace
    steps: tuple[Step, ...] = field(default_factory=tuple)
    idf_image: ImageSpec | None = None


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


def ros_build_image(config: Config, dockerfile_text: str, image_files: Mapping[str, bytes]) -> ImageSpec:
    """The image colcon runs in: Dockerfile.ros's `build` stage, keyed by its inputs."""
    base = config.base_image or dockerfile_args(dockerfile_text).get("BASE_IMAGE", "")
    return _keyed_image(
        f"espdock/ros-{config.ros_distro}-build",
        ROS_DOCKERFILE,
        "build",
        (("BASE_IMAGE", base),),
        {ROS_DOCKERFILE: dockerfile_text.encode(), **image_files},
    )


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


def derive_interface_packages(packages: tuple[Package, ...]) -> tuple[Package, ...]:
    """The workspace's interface packages firmware depends on, transitively, in dependency order.

    Standard interfaces (std_msgs, sensor_msgs, ...) are not in the workspace: micro-ROS has them.
    """
    by_name = {p.name: p for p in packages}
    wanted: set[str] = set()
    stack = [dep for p in packages if p.kind is PackageKind.FIRMWARE for dep in p.depends]
    while stack:
        name = stack.pop()
        package = by_name.get(name)
        if name in wanted or package is None or package.kind is not PackageKind.ROS or not package.is_interface:
            continue
        wanted.add(name)
        stack.extend(package.depends)
    return tuple(p for p in packages if p.name in wanted)


def merge_colcon_meta(metas: Mapping[str, str]) -> str:
    """One app-colcon.meta for the shared library from each firmware package's (package -> JSON text).

    Every app must fit in the one libmicroros.a, so for each `-DNAME=VALUE` cmake arg the
    largest number wins; differing non-numeric values (say two transports) are an error.
    """
    merged: dict[str, dict[str, tuple[str, str]]] = {}
    for package in sorted(metas):
        try:
            data = json.loads(metas[package])
            names = data.get("names", {})
        except (json.JSONDecodeError, AttributeError) as exc:
            raise WorkspaceError(f"{package}/app-colcon.meta is not colcon.meta JSON: {exc}") from exc
        for colcon_package, settings in sorted(names.items()):
            args = merged.setdefault(colcon_package, {})
            for arg in settings.get("cmake-args", []):
                name, sep, value = arg.partition("=")
                if not sep:
                    name, value = arg, ""
                if name not in args:
                    args[name] = (value, package)
                    continue
                old, owner = args[name]
                if old == value:
                    continue
                if old.isdigit() and value.isdigit():
                    args[name] = (str(max(int(old), int(value))), package if int(value) > int(old) else owner)
                    continue
                raise ConfigError(
                    f"firmware packages {owner} and {package} need different {name} "
                    f"({old!r} vs {value!r}) in the one micro-ROS library",
                    "Make their app-colcon.meta agree on it.",
                )
    names = {
        pkg: {"cmake-args": [f"{name}={value}" if value != "" else name for name, (value, _) in sorted(args.items())]}
        for pkg, args in sorted(merged.items())
    }
    return json.dumps({"names": names}, indent=2, sort_keys=True) + "\n"


def micro_ros_image(config: Config, inputs: BuildInputs, packages: tuple[Package, ...]) -> ImageSpec:
    """The IDF image with micro-ROS prebuilt for this workspace's firmware and target."""
    defaults = dockerfile_args(inputs.idf_dockerfile)
    build_args = (
        ("IDF_IMAGE", config.idf_image or defaults.get("IDF_IMAGE", "")),
        ("IDF_TARGET", config.target),
        ("MICRO_ROS_COMMIT", config.micro_ros_commit or defaults.get("MICRO_ROS_COMMIT", "")),
        ("MICRO_ROS_REPO", config.micro_ros_repo or defaults.get("MICRO_ROS_REPO", "")),
    )
    firmware = [p for p in packages if p.kind is PackageKind.FIRMWARE]
    metas = {p.name: inputs.app_metas[p.name] for p in firmware if p.name in inputs.app_metas}
    context: dict[str, bytes] = {
        IDF_DOCKERFILE: inputs.idf_dockerfile.encode(),
        **{f"{IDF_INPUT_DIR}/{rel}": data for rel, data in inputs.idf_files.items()},
        "micro-ros/app-colcon.meta": merge_colcon_meta(metas).encode(),
        # COPY needs the directory even when no interface package goes in.
        "micro-ros/extra_packages/.espdock-keep": b"",
    }
    for package in derive_interface_packages(packages):
        for rel, data in inputs.package_files[package.name].items():
            context[f"micro-ros/extra_packages/{package.name}/{rel}"] = data
    return _keyed_image(
        f"espdock/idf-micro-ros-{config.ros_distro}-{config.target}",
        IDF_DOCKERFILE,
        "final",
        build_args,
        context,
        context=context,
        extra={"ros_distro": config.ros_distro.encode()},
    )


def plan_build(
    workspace: Workspace,
    config: Config,
    packages: tuple[Package, ...],
    ros_image: ImageSpec,
    selected: tuple[str, ...] = (),
    idf_image: ImageSpec | None = None,
    all_packages: tuple[Package, ...] | None = None,
) -> Plan:
    """The steps of `espdock build [SELECTED...]` over PACKAGES (already in build order)."""
    ros = tuple(p.name for p in packages if p.kind is PackageKind.ROS)
    firmware = [p for p in packages if p.kind is PackageKind.FIRMWARE]
    steps: list[Step] = []
    if ros:
        base = dict(ros_image.build_args)["BASE_IMAGE"]
        up_to = tuple(n for n in selected if n in ros)
        steps += [
            EnsureBaseImage(base),
            EnsureImage(ros_image),
            ColconBuild(image=ros_image.tag, packages=ros, up_to=up_to),
        ]
    if firmware:
        if idf_image is None:
            raise WorkspaceError("firmware packages need Dockerfile.idf at the workspace root")
        steps.append(EnsureImage(idf_image))
        everything = {p.name for p in (all_packages or packages)}
        for package in firmware:
            project = package.path.relative_to(workspace.firmware_dir).as_posix()
            steps.append(IdfBuild(package.name, project, idf_image.tag, config.target, idf_image.key))
            run_depends = tuple(sorted(package.depends & everything))
            steps.append(InstallFirmware(package.name, project, run_depends))
    return Plan(workspace=workspace, steps=tuple(steps), idf_image=idf_image)
