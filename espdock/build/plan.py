"""The build plan: pure data, made from the workspace and config without touching the engine."""

from __future__ import annotations

from collections.abc import Mapping

from espdock.build.steps import (
    EnsureBaseImage,
    EnsureImage,
    ImageSpec,
    Plan,
)
from espdock.config import Config
from espdock.firmware.plan import (
    IdfBuild,
    InstallFirmware,
    firmware_steps,
    micro_ros_images,
)
from espdock.layout import (
    ROS_DOCKERFILE,
    ROSDEP_LOCK,
)
from espdock.ros import rosdeps
from espdock.ros.colcon import ColconSettings
from espdock.ros.plan import (
    OFFICIAL_ENTRYPOINT,
    ColconBuild,
    RuntimeImage,
    checked_packages,
    ros_build_image,
    ros_image,
    ros_steps,
)
from espdock.workspace import BuildInputs, Package, PackageKind, Workspace, left_out, select_up_to

Step = EnsureBaseImage | EnsureImage | ColconBuild | IdfBuild | InstallFirmware | RuntimeImage


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
    everything = all_packages or packages
    steps: list[Step] = []
    ros = tuple(p for p in packages if p.kind is PackageKind.ROS)
    if ros:
        steps += ros_steps(workspace, config, ros, ros_image, everything, force, colcon, testing, tests_off)
    firmware = tuple(p for p in packages if p.kind is PackageKind.FIRMWARE)
    fw, images = firmware_steps(workspace, config, firmware, idf_images or {}, everything, force)
    steps += fw
    return Plan(workspace=workspace, steps=tuple(steps), idf_images=images)


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
    selected = select_up_to(packages, names, workspace) if names else packages
    if only is not None:
        selected = tuple(p for p in selected if p.kind is only)
    name, text, image = ros_image(config, inputs)
    lock = rosdeps.read_lock(inputs.rosdep_lock, ROSDEP_LOCK)
    needed = rosdeps.needed_keys(packages, image)
    # The lock is current here (the caller made it so, or refused a stale one under --locked).
    to_check = checked_packages(packages, selected, colcon.args if colcon else (), checked)
    rosdeps.check_dependencies(
        to_check,
        needed,
        lock,
        image,
        command="build" if checked is None else None,
        ignored=lambda: left_out(workspace),
    )
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
