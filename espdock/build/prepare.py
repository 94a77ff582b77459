"""What a command needs before any step runs: the workspace's packages in build order, the
inputs and colcon settings they are planned from, a rosdep lock that answers for them, and the plan."""

from __future__ import annotations

import dataclasses
import functools
import os
from collections.abc import Callable, Iterable, Mapping
from pathlib import Path

from espdock.build.lock import current_rosdep_inputs, current_test_inputs, rosdep_lock_stale, stale_rosdep_lock
from espdock.build.plan import plan_workspace
from espdock.build.steps import EnsureImage, Plan
from espdock.config import Config, invoking_user
from espdock.errors import ConfigError, DependencyError, EspdockError, WorkspaceError
from espdock.firmware.plan import (
    STANDARD_INTERFACES,
    IdfBuild,
    check_idf_projects_typed,
    check_no_vendored_micro_ros,
    derive_interface_packages,
    firmware_step,
    not_in_micro_ros,
    sdkconfig_target,
    unknown_dependencies,
)
from espdock.firmware.steps import installed_image, recorded_step
from espdock.layout import ROS_BUILD_BASE, ROSDEP_LOCK, firmware_build_dir
from espdock.ros import interfaces, rosdeps, testdeps
from espdock.ros.colcon import defaults_with_mixins, output_args, read_colcon_settings, without_build_testing
from espdock.ros.plan import ColconBuild, RuntimeImage, checked_packages, ros_image
from espdock.ros.runtime_tree import runtime_spec
from espdock.ros.testing import ColconTest
from espdock.ros.trees import last_build_args, symlink_installed
from espdock.workspace import (
    DEFAULT_ROS_DISTRO,
    BuildInputs,
    Package,
    PackageKind,
    Workspace,
    discover_packages,
    left_out,
    order_packages,
    read_build_inputs,
    search_warnings,
    select_up_to,
    unknown_package,
    unmanifested,
)


def workspace_packages(ws: Workspace, ros_distro: str = DEFAULT_ROS_DISTRO) -> tuple[Package, ...]:
    return order_packages(discover_packages(ws, ros_distro))


def sourced_underlay(names: Iterable[str], env: Mapping[str, str], ws: Workspace) -> dict[str, Path]:
    """Those of NAMES (packages depended on) installed in an underlay the caller sourced
    (AMENT_PREFIX_PATH), by the prefix that holds each: not ROS's own, nor this workspace's install."""
    prefixes = [Path(p) for p in env.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p.startswith("/")]
    own = ws.ws_dir.resolve() / "install"
    found = {}
    for name in names:
        for prefix in prefixes:
            if prefix.is_relative_to("/opt/ros") or prefix.resolve().is_relative_to(own):
                continue
            if (prefix / "share" / name / "package.xml").is_file():
                found[name] = prefix
                break
    return found


def underlay_hint(found: Mapping[str, Path]) -> str:
    where = "; ".join(f"{name} in {prefix}" for name, prefix in found.items())
    return (
        f"The underlay you sourced has {where}: espdock's build containers see none of your environment, so a "
        "workspace is no overlay of another; link the package's source directory into src/ (`ln -s "
        "~/underlay_ws/src/PKG src/`) and it is built here with the rest."
    )


def _underlay_named(plan: Callable[..., Plan]) -> Callable[..., Plan]:
    """PLAN, whose refusal of dependencies rosdep cannot serve names those of them the caller's
    sourced underlay holds (a ROS team's overlay habit), with the way that works."""

    @functools.wraps(plan)
    def planned(ws: Workspace, *args: object, **kwargs: object) -> Plan:
        try:
            return plan(ws, *args, **kwargs)
        except EspdockError as exc:  # rosdep's refusal, or a lock it could not make for them
            env = kwargs.get("env")
            if isinstance(env, Mapping) and (found := sourced_underlay(exc.keys, env, ws)):
                exc.hint = f"{underlay_hint(found)} {exc.hint or ''}".strip()
            raise

    return planned


@_underlay_named
def build_plan(
    ws: Workspace,
    config: Config,
    names: list[str],
    only: PackageKind | None = None,
    force: bool = False,
    colcon_args: tuple[str, ...] | None = None,
    locked: bool | None = None,
    target: str | None = None,
    checked: tuple[str, ...] | None = None,
    dry_run: bool = False,
    testing: bool = False,
    known: tuple[tuple[Package, ...], BuildInputs] | None = None,
    *,
    env: Mapping[str, str],
    notify: Callable[[str], None],
    left_out_unread: bool = False,
) -> Plan:
    """The build's plan; LOCKED not None: first a rosdep lock that answers for the packages
    (refusing a stale one when LOCKED). CHECKED: the packages whose dependencies must be served
    (None: those built). DRY_RUN: the lock is neither made nor refreshed, only reported. KNOWN:
    the workspace's packages and build inputs as the caller read them (and checked the lock). NOTIFY
    says what happened to the lock. LEFT_OUT_UNREAD: KNOWN lacks packages whose package.xml could
    not be read (the caller says so): a firmware dependency no package holds may be one of them."""
    packages, known_inputs = known or (workspace_packages(ws, config.ros_distro), None)
    inputs = known_inputs or read_build_inputs(ws, packages)
    ros = {p.name: p.path for p in packages if p.kind is PackageKind.ROS}
    colcon = read_colcon_settings(ws.ws_dir, ros, colcon_args, env)
    for shown in defaults_with_mixins(ws.ws_dir, env):
        notify(
            f"warning: {shown} names colcon mixins, which the build image's colcon does not have (no colcon-mixin): "
            "they are not applied. Give their options after `--` (e.g. `--cmake-args -DCMAKE_BUILD_TYPE=Release`)"
        )
    if dry_run:
        reason = rosdep_lock_stale(config, packages, inputs)
        if reason and locked:
            raise stale_rosdep_lock(ws.root, reason)  # as the build would, before anything
        if reason:
            notify(f"{reason}: a build would make it first; the plan below uses it as it is, unchecked")
            checked = ()
    elif locked is not None:
        owner = invoking_user(env, ws.root) if os.geteuid() == 0 else None
        selected = select_up_to(packages, names, ws) if names else packages
        built = checked_packages(packages, tuple(p for p in selected if only in (None, p.kind)), colcon.args)
        inputs, note = current_rosdep_inputs(
            ws.root, config, packages, inputs, locked, env, owner, built, ignored=lambda: left_out(ws), notify=notify
        )
        if note:
            notify(note)
    chosen = select_up_to(packages, names, ws) if names else packages
    for package in chosen:
        for line in interfaces.undeclared(package, inputs.package_files.get(package.name, {})):
            notify(f"warning: {line}")
    for name, project in unmanifested(ws).items():
        notify(project.not_built(name))
    for line in search_warnings(ws):
        notify(line)
    of_kind = [p for p in chosen if only in (None, p.kind)]
    check_no_vendored_micro_ros(of_kind, ws.root)
    check_idf_projects_typed(of_kind, ws.root)
    if only in (None, PackageKind.FIRMWARE):
        for firmware in (p for p in chosen if p.kind is PackageKind.FIRMWARE):
            if (firmware.path / "extra_ros_packages").is_dir():
                notify(
                    f"warning: {(firmware.path / 'extra_ros_packages').relative_to(ws.root)} is not read (upstream's "
                    f"micro_ros_espidf_component reads it): the library holds the workspace's interface packages "
                    f"{firmware.name} <depend>s on. Move them into a package path and add the <depend>"
                )
            if (firmware.path / "sdkconfig").is_file():
                rel = (firmware.path / "sdkconfig").relative_to(ws.root)
                used = (firmware_build_dir(ws.ws_dir, firmware.name) / "sdkconfig").relative_to(ws.root)
                # `idf.py set-target` writes the chip there alone: espdock's comes from the defaults.
                chip = sdkconfig_target((firmware.path / "sdkconfig").read_bytes())
                notify(
                    f"warning: {rel} is not read: the build's sdkconfig is {used}, made from "
                    f"sdkconfig.defaults (plain idf.py would take the project's). Put its settings in "
                    f"sdkconfig.defaults (`idf.py save-defconfig` writes the ones that differ) and remove it"
                    + (f'; its chip too: CONFIG_IDF_TARGET="{chip}"' if chip else "")
                )
            if not left_out_unread and (unknown := unknown_dependencies(firmware, packages)):
                found = sourced_underlay(unknown, env, ws)
                notify(
                    f"warning: {firmware.name} depends on {', '.join(unknown)}: in no package of this workspace, nor "
                    "an interface package micro-ROS builds (std_msgs, sensor_msgs, ...), so the library has no "
                    "headers of it" + (f". {underlay_hint(found)}" if found else "")
                )
            for line in unbuildable_in_library(firmware, packages, inputs):
                notify(f"warning: {line}")
            for line in host_side_in_library(firmware, packages, inputs):
                notify(f"warning: {line}")
    return plan_workspace(
        ws, config, packages, inputs, tuple(names), only, force, target, colcon, checked, testing=testing
    )


def check_only(
    packages: Iterable[Package], names: Iterable[str], only: PackageKind, plan: Plan, notify: Callable[[str], None]
) -> None:
    """Refuse a PLAN of nothing where --only ONLY left out every package NAMES asked for; say which
    it left out where it built the others."""
    kinds = {p.name: p.kind for p in packages}
    kind = {PackageKind.ROS: "ROS", PackageKind.FIRMWARE: "firmware"}
    if not plan.steps:
        # `espdock build FIRMWARE_PKG --only ros` in a Makefile: it built nothing and passed.
        named = ", ".join(f"{name} ({kind[kinds[name]]})" for name in names)
        raise ConfigError(
            f"nothing to build: --only {only} builds no package of {named}",
            f"Name a {kind[only]} package, or leave --only out.",
        )
    if others := [name for name in names if kinds[name] is not only]:
        notify(f"note: not built, --only {only} leaves them out: {', '.join(others)} ({kind[kinds[others[0]]]})")


def unbuildable_in_library(firmware: Package, packages: tuple[Package, ...], inputs: BuildInputs) -> list[str]:
    """The types that interface packages of FIRMWARE's micro-ROS library use from a package in
    neither the workspace (PACKAGES) nor micro-ROS's standard set, one line each: rosdep may give
    the ROS side the package, where the library build failed on it, minutes in."""
    in_workspace = {p.name for p in packages}
    return [
        f"{firmware.name}'s micro-ROS library holds {library.name}, whose {rel} uses {type_name}: {other} is in no "
        "package of this workspace, nor an interface package micro-ROS builds, so the library build fails on it. "
        f"Add the package to the workspace, or keep that type out of what {firmware.name} depends on"
        for library in derive_interface_packages(packages, firmware)
        for other, (type_name, rel) in sorted(interfaces.references(inputs.package_files.get(library.name, {})).items())
        if other not in in_workspace and other not in STANDARD_INTERFACES
    ]


def host_side_in_library(firmware: Package, packages: tuple[Package, ...], inputs: BuildInputs) -> list[str]:
    """The interface packages of FIRMWARE's micro-ROS library whose CMakeLists.txt requires what
    the library build does not have (a node's rclcpp beside the interfaces), one line each: that
    build runs a package's whole CMakeLists.txt, and failed on it minutes in, where the ROS side
    built it."""
    library = derive_interface_packages(packages, firmware)
    # The workspace's other interface packages too: one the library lacks is a <depend> left out of
    # a package.xml (said apart, by interfaces.undeclared), not a host-side requirement to move.
    workspace_interfaces = {p.name for p in packages if p.is_interface}
    lines = []
    for package in library:
        text = inputs.package_files.get(package.name, {}).get("CMakeLists.txt", b"").decode("utf-8", "replace")
        if missing := not_in_micro_ros(text, workspace_interfaces | {p.name for p in library}):
            lines.append(
                f"{firmware.name}'s micro-ROS library holds {package.name}, whose CMakeLists.txt requires "
                f"{', '.join(missing)}: micro-ROS's library build runs the whole of it with micro-ROS's own "
                "colcon, which has no rclcpp, rclpy or launch and builds no *_cpp package, so it fails there. "
                f"Keep {package.name}'s interfaces in a package of their own that {firmware.name} depends on "
                f"(the ROS habit: {package.name}_msgs or {package.name}_interfaces)"
            )
    return lines


def firmware_plan(
    ws: Workspace,
    config: Config,
    name: str,
    env: Mapping[str, str],
    notify: Callable[[str], None],
    target: str | None = None,
    installed: bool = False,
) -> tuple[Plan, IdfBuild]:
    """The plan that ensures firmware package NAME's IDF image, and its build step (for TARGET,
    as `espdock build --target`, where given). INSTALLED: for a command that works with the
    installed firmware (flash, provision, monitor), which another package's package.xml, half
    edited, does not stop."""
    unreadable: list[WorkspaceError] | None = [] if installed else None
    packages = order_packages(discover_packages(ws, config.ros_distro, unreadable))
    try:
        if name not in {p.name for p in packages}:
            # Offered among the firmware packages: a renamed one's old name got an ament_python package.
            raise unknown_package(name, [p.name for p in packages if p.kind is PackageKind.FIRMWARE], ws, "firmware")
        known = (packages, read_build_inputs(ws, packages))  # found once
        # A dependency among the packages left out is in no package to the plan: the notes below
        # name the manifest to mend, not a dependency to add.
        plan = build_plan(
            ws, config, [name], target=target, known=known, env=env, notify=notify, left_out_unread=bool(unreadable)
        )
    except EspdockError as exc:
        if unreadable:  # NAME's own, or one NAME depends on: that manifest is what to fix
            raise unreadable[0] from None
        own = next((p for p in packages if p.name == name and p.kind is PackageKind.FIRMWARE), None)
        recorded = None
        if installed and own is not None and isinstance(exc, (WorkspaceError, ConfigError)):
            recorded = recorded_step(ws, name, own.path.relative_to(ws.root).as_posix(), config.ros_distro)
        if recorded is None:
            raise
        # Its own sources mid-edit: what they plan is the next build's business. The image is the
        # caller's to find (an empty plan makes none).
        notify(f"note: {exc.message}; the installed firmware of {name} is used as it was built")
        return Plan(ws, (), ()), recorded
    for error in unreadable or ():
        notify(f"note: {error.message}; that package is left out, and {name}'s installed firmware used as it was built")
    return firmware_step(plan, name)


def current_tags(ws: Workspace, config: Config, *, env: Mapping[str, str]) -> set[str]:
    """The keyed images the workspace's inputs use now: its plan's images and the runtime image
    (and its base) `espdock run` makes of the install tree as it is, runtime_image set or not.
    Planned without a word: a plan's notes are the build's to say (prune_auto's plan, after a
    build, said them a second time)."""
    config = dataclasses.replace(config, runtime_image=True)
    plan = build_plan(ws, config, [], env=env, notify=lambda text: None)
    tags = {step.spec.tag for step in plan.steps if isinstance(step, EnsureImage)}
    if any(isinstance(step, ColconBuild) for step in plan.steps):
        # `espdock test`'s: the build image plus the lock's test part.
        path = ws.root / ROSDEP_LOCK
        lock = rosdeps.read_lock(path.read_bytes() if path.is_file() else None, ROSDEP_LOCK)
        tested = testdeps.with_test_image(plan, lock, config.ros_image == "official")
        tags |= {step.spec.tag for step in tested.steps if isinstance(step, EnsureImage)}
    for step in plan.steps:
        if isinstance(step, IdfBuild):
            # The installed firmware's, which flash and monitor run in: a board not rebuilt since
            # an interface edit keeps using the image of the old one.
            tags.add(installed_image(ws, step))
        if isinstance(step, RuntimeImage):
            tags.add(step.base.tag)
            try:
                tags.add(runtime_spec(ws, step).tag)
            except EspdockError:
                pass  # nothing installed yet: no runtime image is current
    return tags


def last_build_options(ws: Workspace) -> tuple[str, ...] | None:
    """The options the last build was given that decide what it produced (None: none): a plan
    given them makes that build's stamps, and says what is up to date by it. As given, not with
    what the colcon defaults file adds, which it adds again."""
    return output_args(last_build_args(ws.ws_dir / ROS_BUILD_BASE)) or None


def plan_tests(
    ws: Workspace,
    config: Config,
    every: tuple[Package, ...],
    ros: tuple[Package, ...],
    colcon_args: tuple[str, ...],
    locked: bool | None,
    official: bool,
    *,
    env: Mapping[str, str],
    notify: Callable[[str], None],
) -> tuple[Plan, ColconTest]:
    """`espdock test`'s plan for the ROS packages ROS (of EVERY package): their build with tests in
    the test image, after a rosdep lock whose test part answers for them; and the colcon test to
    run after it."""
    # A defaults file that sets what espdock controls is exit 2 before the lock, which may need
    # the network and the engine.
    settings = read_colcon_settings(ws.ws_dir, {p.name: p.path for p in ros}, None, env)
    # The rosdep lock, its test part included, answers for the packages before anything is built
    # (checked here once: the plan takes the packages and inputs as they are).
    owner = invoking_user(env, ws.root) if os.geteuid() == 0 else None
    inputs, note = current_test_inputs(
        ws.root, config, every, read_build_inputs(ws, every), locked, env, owner, tested=ros, notify=notify
    )
    if note:
        notify(note)
    lock = rosdeps.read_lock(inputs.rosdep_lock, ROSDEP_LOCK)
    try:
        testdeps.check_tests(ros, lock, ros_image(config, inputs)[2], every)
        tests_refused = None
    except DependencyError as exc:
        tests_refused = exc  # said with what the build lacks, below: one round of fixes, not two
    names = tuple(p.name for p in ros)
    known = (every, inputs)
    # The builds keep install/ as the last build made it: its options after `--` (a
    # --symlink-install stays one, and dependencies it built are up to date), BUILD_TESTING aside,
    # and those that only leave packages out or schedule them: a package the last build skipped
    # kept its tests unconfigured, and its failing tests passed for none.
    built_with = last_build_args(ws.ws_dir / ROS_BUILD_BASE)
    last = output_args(built_with)
    if last:
        notify(f"building with the options of the last espdock build: {' '.join(last)}")
    # The install kind the packages tested have, where they agree and the options above (a whole
    # build's) say the other: a selection's own `-- --symlink-install` was made copies again,
    # build dirs and install prefixes removed, by the tests' build.
    kinds = {symlink_installed(ws.ws_dir / ROS_BUILD_BASE, p.name) for p in ros}
    if kinds == {True} and "--symlink-install" not in last and not settings.symlink_install:
        last = (*last, "--symlink-install")
        notify("building with --symlink-install, as the last builds of the packages tested were")
    elif kinds == {False} and "--symlink-install" in last:
        last = tuple(arg for arg in last if arg != "--symlink-install")
        notify("building without --symlink-install, as the last builds of the packages tested were")
    if dropped := [arg for arg in built_with if arg not in last]:
        notify(f"not with its {' '.join(dropped)}: the packages tested are built with their tests")
    tested_args = without_build_testing(last) or None
    try:
        plan = build_plan(
            ws,
            config,
            list(names),
            PackageKind.ROS,
            colcon_args=tested_args,
            testing=True,
            known=known,
            env=env,
            notify=notify,
        )
    except DependencyError as exc:
        if tests_refused is None:
            raise
        said = tests_refused.message
        raise DependencyError(
            f"{exc.message}\nand for their tests, {said[0].lower()}{said[1:]}",
            exc.hint,
            tuple(sorted({*exc.keys, *tests_refused.keys})),
        ) from None
    if tests_refused is not None:
        raise tests_refused
    plan = testdeps.with_test_image(_test_build(plan), lock, official)
    build = next(step for step in plan.steps if isinstance(step, ColconBuild))
    step = ColconTest(
        image=build.image,
        packages=names,
        sources=build.sources,
        colcon_args=colcon_args,
        defaults_file=build.defaults_file,
    )
    # The plain build of these packages, as `espdock build` would build them (of the same
    # workspace and inputs: what it would say, the plan above said).
    plain = build_plan(
        ws, config, list(names), PackageKind.ROS, colcon_args=last or None, known=known, env=env, notify=lambda _: None
    )
    first = next(s for s in plain.steps if isinstance(s, ColconBuild))
    tested = dataclasses.replace(
        build, selected=names, name="colcon build: with tests", serves=tuple(first.stamp_images().items())
    )
    steps: tuple[ColconBuild, ...] = (tested,)
    if dependencies := tuple(name for name in build.packages if name not in names):
        # Built, not tested: as `espdock build` builds them, in the build image (made before the
        # test image over it), with their tests configured only where a plain build configures
        # them. A template's `find_package(ament_lint_auto)` under BUILD_TESTING in a dependency
        # then needs nothing, and a build before leaves them up to date.
        steps = (dataclasses.replace(first, selected=dependencies, name="colcon build: dependencies"), tested)
    out = [new for s in plan.steps for new in (steps if s is build else (s,))]
    return Plan(plan.workspace, tuple(out), plan.idf_images), step


def _test_build(plan: Plan) -> Plan:
    """The plan up to its colcon build: testing needs no runtime image."""
    end = next(i for i, step in enumerate(plan.steps) if isinstance(step, ColconBuild))
    return Plan(plan.workspace, plan.steps[: end + 1], plan.idf_images)
