"""The build plan: pure data, made from the workspace and config without touching the engine."""

from __future__ import annotations

import hashlib
import re
from collections.abc import Mapping
from dataclasses import dataclass, field

from espdock.config import Config
from espdock.workspace import Package, PackageKind, Workspace

ROS_DOCKERFILE = "Dockerfile.ros"
# What the ROS images are built from besides their Dockerfile: requirements and entry point.
IMAGE_INPUT_DIR = "docker"
WORKSPACE_MOUNT = "/workspace"
LABEL_KEY = "io.espdock.key"
LABEL_WORKSPACE = "io.espdock.workspace"


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

    @property
    def tag(self) -> str:
        return f"{self.repository}:{self.key[:16]}"


@dataclass(frozen=True)
class EnsureBaseImage:
    """Make the base image a Dockerfile starts FROM available locally."""

    image: str

    @property
    def name(self) -> str:
        return f"base image {self.image}"


@dataclass(frozen=True)
class EnsureImage:
    """Build SPEC unless an image with its key already exists."""

    spec: ImageSpec

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
            "colcon",
            "build",
            "--base-paths",
            "src",
            # Live output per line plus colcon's own start/finish lines.
            "--event-handlers",
            "console_direct+",
            "console_start_end+",
            "summary+",
        ]
        if self.up_to:
            args += ["--packages-up-to", *self.up_to]
        return tuple(args)


Step = EnsureBaseImage | EnsureImage | ColconBuild


@dataclass(frozen=True)
class Plan:
    workspace: Workspace
    steps: tuple[Step, ...] = field(default_factory=tuple)


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
    build_args = (("BASE_IMAGE", base),)
    parts = {ROS_DOCKERFILE: dockerfile_text.encode(), **image_files}
    parts.update({f"arg:{k}": v.encode() for k, v in build_args})
    key, inputs = image_key(parts)
    return ImageSpec(
        repository=f"espdock/ros-{config.ros_distro}-build",
        key=key,
        dockerfile=ROS_DOCKERFILE,
        target="build",
        build_args=build_args,
        inputs=inputs,
    )


def plan_build(
    workspace: Workspace,
    config: Config,
    packages: tuple[Package, ...],
    ros_image: ImageSpec,
    selected: tuple[str, ...] = (),
) -> Plan:
    """The steps of `espdock build [SELECTED...]` over PACKAGES (already in build order)."""
    ros = tuple(p.name for p in packages if p.kind is PackageKind.ROS)
    steps: list[Step] = []
    if ros:
        base = dict(ros_image.build_args)["BASE_IMAGE"]
        up_to = tuple(n for n in selected if n in ros)
        steps += [
            EnsureBaseImage(base),
            EnsureImage(ros_image),
            ColconBuild(image=ros_image.tag, packages=ros, up_to=up_to),
        ]
    return Plan(workspace=workspace, steps=tuple(steps))
