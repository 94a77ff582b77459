"""The firmware side's steps: idf.py in the micro-ROS image (build, and the tools `idf`, `flash`
and `monitor` run), the build dir kept safe to reuse, and the install into ws/install."""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import posixpath
import re
import shutil
import sys
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path

from espdock import interrupts
from espdock.build.stamps import StampFile, listing_digest, source_files, tree_digest
from espdock.build.steps import keyed_tag
from espdock.config import CHIP_TARGETS, resolve_ca_bundle
from espdock.errors import BuildFailed
from espdock.events import Outcome, StepNote, StepOutput
from espdock.firmware.agent_port import LIBRARY_HEADERS, check_agent_port
from espdock.firmware.install import COMMANDS_SOURCE, install_firmware
from espdock.firmware.plan import (
    LIBRARY_SDKCONFIG_PREFIXES,
    SDKCONFIG_LINE,
    IdfBuild,
    InstallFirmware,
    check_inside,
    micro_ros_repository,
)
from espdock.firmware.transport import applied_defaults, built_transport_record
from espdock.images import volume
from espdock.images.containers import Containers, give_to, make_dirs_for, volume_mode_refused, with_host_umask
from espdock.images.engine import KILLED
from espdock.images.specs import Mount, RunSpec
from espdock.images.visibility import host_paths, links_out
from espdock.layout import COLCON_RESULT_FILES, MANIFEST_NAME, firmware_build_dir, host_path, install_prefix
from espdock.workspace import Workspace, as_lines, editor_leftover, sdkconfig_defaults_list, workspace_lock

TARGET_MARKER = ".espdock-target"

# Under ws/build, beside the packages' build dirs (colcon skips dot dirs).
COMPONENT_CACHE = ".idf-component-cache"

MANAGED_COMPONENTS = "managed_components"

FIRMWARE_STAMPS = ".espdock-firmware-stamps.json"

INSTALL_STAMPS = ".espdock-install-stamps.json"

EXTRA_CA_MOUNT = "/run/espdock/extra-ca.pem"

WITH_CA = "/opt/espdock/with-ca.sh"


class FirmwareSteps:
    """Runs the firmware side's steps in containers of CONTAINERS."""

    def __init__(self, containers: Containers) -> None:
        self.containers = containers

    def idf_build(self, workspace: Workspace, step: IdfBuild) -> tuple[Outcome, str]:
        build_dir = firmware_build_dir(workspace.ws_dir, step.package)
        image_id = self._image_id(step)  # the same after the build: asked once
        stamp_file, stamps, current = firmware_state(workspace, step, image_id)
        if current and not step.force:
            # Said again while it holds: the build that said it first installed the firmware,
            # and a warning that then fell silent left a library unlike the app unnoticed.
            self._library_settings_warning(workspace, step, _library_settings_changed(build_dir, False, record=False))
            return Outcome.CACHED, f"up to date ({step.target})"
        stamp_file.forget(stamps)
        project = workspace.root / step.project
        defaults = _defaults_digest(project, step.target)
        reset, replaced = _prepare_build_dir(
            build_dir, step.target, defaults, step.image_key, project, workspace.root, self.containers.owner
        )
        if replaced is not None:
            rel = build_dir.relative_to(workspace.root)
            if replaced:  # the chip the build dir was for
                why = f"{rel} was for {replaced}: made afresh for {step.target}, as IDF's set-target does"
            else:
                files = " or ".join(name for name, _ in _defaults_files(project, step.target))
                why = f"{step.project}/{files} changed: {rel}/sdkconfig is made afresh from it, as IDF would not"
            self.containers.emit(
                StepNote(
                    step.name, f"{why}; the sdkconfig before, with any menuconfig changes, is {rel}/{SDKCONFIG_OLD}"
                )
            )
        # What the sdkconfig is made from, before the build: a failed build's sdkconfig is of these
        # defaults, and the next build must not take it for the last successful build's.
        _write_marker(build_dir, step.target, defaults, _built_key(build_dir, step.target), self.containers.owner)
        fresh = not (build_dir / "sdkconfig").is_file()
        # The same directories after: the build's project_description.json may name more.
        roots = _stamp_roots(workspace, step)
        seen = _source_times(roots)
        missing: dict[str, str] = {}  # each header not found, by the file that includes it
        hints: list[str] = []

        def on_line(line: str) -> None:
            missing.update((header, source) for source, header in missing_includes(line))
            if (hint := failure_hint(line)) and hint not in hints:
                hints.append(hint)
            self.containers.emit(StepOutput(step.name, host_paths(line, workspace)))

        try:
            code = self.run_idf(workspace, step, step.argv(), on_line=on_line, sweep=True, reset=reset)
        finally:
            if fresh and (build_dir / "sdkconfig").is_file():
                # The sdkconfig as the defaults made it, failed build or not: one still like it
                # has no menuconfig change for sdkconfig.old to keep (_prepare_build_dir).
                shutil.copyfile(build_dir / "sdkconfig", build_dir / SDKCONFIG_MADE)
                give_to(build_dir / SDKCONFIG_MADE, self.containers.owner)
        if code == KILLED:
            raise BuildFailed(
                f"idf.py build of {step.package} was killed (exit code {code}, SIGKILL); build files in {build_dir}",
                "Something killed its container: `docker kill` or `docker rm -f`, the engine stopping, or the "
                "kernel's OOM killer for want of memory (`dmesg` says). Run `espdock build` again; installed "
                "firmware was left as it was.",
            )
        if code != 0:
            raise BuildFailed(
                f"idf.py build of {step.package} failed (exit code {code}); its output is above, "
                f"build files in {build_dir}",
                undeclared_interface_hint(step, missing)
                or unrequired_library_hint(workspace, step, missing)
                or " ".join(
                    [*hints, "Fix the firmware and run `espdock build` again; installed firmware was left as it was."]
                ),
            )
        _write_marker(build_dir, step.target, defaults, step.image_key, self.containers.owner)
        changed = _library_settings_changed(build_dir, fresh)
        give_to(build_dir / LIBRARY_BASELINE, self.containers.owner)
        self._library_settings_warning(workspace, step, changed)
        if edited := _edited_since(seen, _source_times(roots), workspace, step):
            # Recorded, the stamp of sources idf.py may not have read had the next build say "up to
            # date", and `espdock flash` write the firmware without the edit.
            shown = ", ".join(edited[:3]) + (", ..." if len(edited) > 3 else "")
            self.containers.emit(
                StepNote(
                    step.name,
                    f"warning: {shown} changed while idf.py built {step.package}: the firmware may not have the "
                    "change; the next `espdock build` builds it again",
                )
            )
        else:
            # After the build: IDF itself writes into the project (the component manager's lock).
            stamp_file.record(
                _firmware_stamp(workspace, step, image_id),
                {step.package: listing_digest(build_dir, COLCON_RESULT_FILES)},
            )
            give_to(stamp_file.path, self.containers.owner)
        return Outcome.BUILT, step.target

    def installed_from(self, workspace: Workspace, step: IdfBuild) -> tuple[IdfBuild, bool]:
        """What `flash`, `provision` and `monitor` run for STEP's package: STEP in the image its
        build dir was last built in (the installed firmware's, its library's header included)
        where that is another image still on the engine, else STEP; and whether the firmware is
        what its sources build now. Building the image of sources edited since, which may not
        even build, would stand between the user and the firmware they built."""
        built = _built_step(step, workspace)
        if (
            built is None
            or (built.target, built.image_key) == (step.target, step.image_key)
            or self.containers.engine.image(built.image) is None
        ):
            built = step
        # The sources against what the installed firmware was built from, not the build dir's
        # files: `espdock idf PKG -- fullclean` empties those, and the sources build the same. For
        # the chip it was built for: a `build --target` one is current until they change.
        stamp = _firmware_stamp(workspace, built, self._image_id(built))[step.package]
        recorded = StampFile(workspace.ws_dir / "build" / FIRMWARE_STAMPS).read().get(step.package) or {}
        # Of the same chip, another key is an interface (or library setting) changed since: stale,
        # though the old image is still there. Another chip's key the caller compares (its plan).
        return built, recorded.get("stamp") == stamp and (built.target != step.target or built is step)

    def _library_settings_warning(self, workspace: Workspace, step: IdfBuild, changed: list[str]) -> None:
        """Warn of CHANGED, library options the build dir's sdkconfig (menuconfig) sets otherwise than
        the library was built with."""
        if not changed:
            return
        build_dir = firmware_build_dir(workspace.ws_dir, step.package)
        shown = ", ".join(changed[:4]) + (", ..." if len(changed) > 4 else "")
        # An option the chip's own defaults file sets wins over sdkconfig.defaults, where
        # save-defconfig writes: the line goes there, or the change is lost at the next build.
        chip_file = workspace.root / step.project / f"sdkconfig.defaults.{step.target}"
        overridden = sorted(set(_library_lines(chip_file)) & {line.split("=", 1)[0] for line in changed})
        where = (
            f"{chip_file.relative_to(workspace.root)}, which sets {', '.join(overridden)} over "
            "sdkconfig.defaults (`save-defconfig` writes sdkconfig.defaults, which would lose it)"
            if overridden
            else f"{step.project}/sdkconfig.defaults (`espdock idf {step.package} -- save-defconfig`)"
        )
        self.containers.emit(
            StepNote(
                step.name,
                f"warning: {shown} changed in {build_dir.relative_to(workspace.root)}/sdkconfig (menuconfig) "
                f"reach the app but not libmicroros.a, built from the defaults files: put the line in {where} "
                "and build again, so a library with it is built (`espdock micro-ros rebuild` rebuilds it from "
                "scratch)",
            )
        )

    def _image_id(self, step: IdfBuild) -> str:
        """The ID of STEP's micro-ROS image ('' where the engine lacks it)."""
        image = self.containers.engine.image(step.image)
        return image.id if image else ""

    def run_idf(
        self,
        workspace: Workspace,
        step: IdfBuild,
        argv: tuple[str, ...],
        on_line: Callable[[str], None] | None = None,
        devices: tuple[str, ...] = (),
        network: str | None = None,
        workdir: str | None = None,
        sweep: bool = False,
        extra_mounts: tuple[Mount, ...] = (),
        reset: bool = False,
    ) -> int:
        """Run ARGV (idf.py or another tool of the IDF image) for STEP's package.

        With ON_LINE None the container is attached to the terminal (menuconfig, monitor).
        SWEEP only from a build, which holds the workspace lock (see Containers.container_identity).
        RESET: the host's build dir was emptied for a new target or image (_prepare_build_dir);
        in volume mode the volume's is emptied the same way.
        """
        check_inside(workspace, step.package, workspace.root / step.project)  # linked in since it was planned
        user, labels = self.containers.container_identity(workspace, f"idf-{step.package}", sweep)
        if not sweep and (swept := self.containers.engine.sweep(dict(labels))):
            # Without the workspace lock only a dead espdock's: a `monitor` killed outright
            # (kill -9, `timeout -s KILL`) leaves its container on the port, and the next `flash`
            # found the board silent.
            self.containers.emit(
                StepNote(
                    step.name,
                    interrupts.swept(swept, of=f"of {step.package}", where=" (a monitor holding the port, say)"),
                )
            )
        build_dir = firmware_build_dir(workspace.ws_dir, step.package)
        # The component manager extracts into <project>/managed_components, a place it does not
        # let anyone move; a mount keeps that in ws/build, and the source tree clean. On the
        # volume it stays in the project: the volume's copy of the sources is espdock's own.
        managed = build_dir / MANAGED_COMPONENTS
        mountpoint = workspace.root / step.project / MANAGED_COMPONENTS
        sync = None
        if self.containers.uses_volume(workspace, step.image, user, labels):
            if devices or extra_mounts:
                raise volume_mode_refused(f"a serial port for {step.package}")
            sync = self.containers.sync(workspace, step.name, step.image, user, labels, (build_dir,) if reset else ())
        else:
            for directory in (managed, mountpoint):
                make_dirs_for(directory, self.containers.owner)
        mounts, archives = self.containers.workspace_in(workspace, sync)
        if sync is not None:
            # espdock's records of the build dir live on the host (the volume's come back without
            # them), and a new volume gets menuconfig's sdkconfig, which outlives a reset.
            kept = (
                TARGET_MARKER,
                LIBRARY_BASELINE,
                SDKCONFIG_MADE,
                *(("sdkconfig", SDKCONFIG_OLD, OLD_CHANGED) if reset or sync.fresh else ()),
            )
            archives.append(volume.files_archive(workspace, build_dir, kept, self.containers.container_owner()))
        if sync is None:
            mounts += [
                Mount(managed, f"{step.project_dir}/{MANAGED_COMPONENTS}"),
                *_outside_build_dir(workspace, build_dir),
                *_linked_out(workspace, step),
                *extra_mounts,
            ]
        env = [
            ("HOME", "/tmp"),
            *self.containers.reproducible_env(workspace),
            ("IDF_TARGET", step.target),
            # The component manager's downloads outlive the container (it caches in HOME otherwise).
            ("IDF_COMPONENT_CACHE_PATH", f"{posixpath.dirname(step.build_dir)}/{COMPONENT_CACHE}"),
        ]
        ca_bundle = resolve_ca_bundle(self.containers.config, self.containers.env)
        if ca_bundle is not None:
            # The component manager downloads over HTTPS at configure time; with-ca.sh (from
            # Dockerfile.idf) hands it, and git, this bundle besides the system's.
            if sync is None:
                mounts.append(Mount(ca_bundle, EXTRA_CA_MOUNT, read_only=True))
            else:
                archives.append(volume.file_archive(EXTRA_CA_MOUNT, ca_bundle.read_bytes()))
            env.append(("ESPDOCK_EXTRA_CA", EXTRA_CA_MOUNT))
        spec = RunSpec(
            image=step.image,
            argv=with_host_umask(("sh", WITH_CA, *argv)),
            workdir=workdir or step.project_dir,
            user=user,
            mounts=tuple(mounts),
            env=tuple(env),
            labels=labels,
            devices=devices,
            group_add=(*_device_groups(devices), *self.containers.shared_group(workspace)),
            network=network,
            tty=on_line is None and bool(sys.stdin and sys.stdin.isatty()),
            archives=tuple(archives),
        )
        keep = self.containers.config.keep_containers
        if sync is not None:
            # The build dir comes back whole: the firmware's artefacts, and menuconfig's sdkconfig.
            with volume.fetched("build") as fetched:
                fetch = {volume.container_path(workspace, build_dir): fetched["build"]}
                if on_line is None:
                    code = self.containers.engine.run_attached(spec, keep=keep, fetch=fetch)
                else:
                    code = self.containers.engine.run(spec, on_line, keep=keep, fetch=fetch)
                volume.replace_tree(fetched["build"], build_dir, self.containers.owner)
                volume.record(workspace, self.containers.engine, sync, sync.installed)
                give_to(workspace.ws_dir / "build" / volume.SYNCED, self.containers.owner)
            return code
        try:
            if on_line is None:
                return self.containers.engine.run_attached(spec, keep=keep)
            return self.containers.engine.run(spec, on_line, keep=keep)
        finally:
            with contextlib.suppress(OSError):  # not empty: the user's own, left alone
                mountpoint.rmdir()

    def run_passthrough(
        self,
        workspace: Workspace,
        step: IdfBuild,
        args: tuple[str, ...],
        devices: tuple[str, ...] = (),
        network: str | None = None,
    ) -> int:
        """`idf.py ARGS` for STEP's package, attached to the terminal (`espdock idf`). The library
        settings of a build dir's first configure from sdkconfig.defaults are what the build warns
        against (_library_settings_changed): recorded after a run that made the sdkconfig, and
        for menuconfig, whose first run would save the user's changes with them, by a reconfigure
        before it."""
        sdkconfig = firmware_build_dir(workspace.ws_dir, step.package) / "sdkconfig"
        made = not sdkconfig.is_file()
        if made and "menuconfig" in args:
            say = lambda line: self.containers.emit(StepOutput("idf.py reconfigure", host_paths(line, workspace)))  # noqa: E731
            if code := self.run_idf(workspace, step, step.argv(("reconfigure",)), on_line=say):
                return code
            self._record_library_baseline(workspace, step)
            made = False
        code = self.run_idf(workspace, step, step.argv(args), devices=devices, network=network)
        if made and sdkconfig.is_file():
            self._record_library_baseline(workspace, step)
        return code

    def _record_library_baseline(self, workspace: Workspace, step: IdfBuild) -> None:
        build_dir = firmware_build_dir(workspace.ws_dir, step.package)
        _library_settings_changed(build_dir, fresh=True)
        give_to(build_dir / LIBRARY_BASELINE, self.containers.owner)

    def check_library_port(self, workspace: Workspace, step: IdfBuild, port: int) -> None:
        """Refuse an agent PORT the package's micro-ROS library would cut, reading the library's header
        in its image (a header that does not state MAX_PORT_LEN leaves it to the board)."""
        lines: list[str] = []
        # One of the two places holds it; cat's complaint about the other is of no interest.
        self.run_idf(workspace, step, ("cat", *LIBRARY_HEADERS), on_line=lines.append, workdir="/")
        check_agent_port(port, "\n".join(lines), step.package)

    def install(self, workspace: Workspace, step: InstallFirmware) -> tuple[Outcome, str]:
        stamp_file, stamps, installed, prefix = _install_stamps(workspace, step)
        if stamp_file.up_to_date(stamps, {step.package: listing_digest(installed)}):
            return Outcome.CACHED, "up to date"
        stamp_file.forget(stamps)
        owner = self.containers.owner if os.geteuid() == 0 else None
        firmware = install_firmware(
            package=step.package,
            manifest=workspace.root / step.project / "package.xml",
            build_dir=workspace.ws_dir / "build" / step.package,
            install_base=workspace.ws_dir / "install",
            run_depends=step.run_depends,
            owner=owner,
            prefix=prefix,
            workspace_root=workspace.root,
        )
        stamp_file.record(stamps, {step.package: listing_digest(installed)})
        give_to(stamp_file.path, self.containers.owner)
        return Outcome.BUILT, str(firmware.relative_to(workspace.root))


def firmware_state(workspace: Workspace, step: IdfBuild, image_id: str) -> tuple[StampFile, dict[str, str], bool]:
    """STEP's stamp file, its stamp now, and whether its build dir holds what its sources build
    now in the image of IMAGE_ID."""
    build_dir = firmware_build_dir(workspace.ws_dir, step.package)
    stamp_file = StampFile(workspace.ws_dir / "build" / FIRMWARE_STAMPS)
    stamps = _firmware_stamp(workspace, step, image_id)
    listing = {step.package: listing_digest(build_dir, COLCON_RESULT_FILES)}
    return stamp_file, stamps, stamp_file.up_to_date(stamps, listing)


def install_up_to_date(workspace: Workspace, step: InstallFirmware) -> bool:
    """Whether STEP's package is installed from its build dir as it is now."""
    stamp_file, stamps, installed, _ = _install_stamps(workspace, step)
    return stamp_file.up_to_date(stamps, {step.package: listing_digest(installed)})


def _install_stamps(workspace: Workspace, step: InstallFirmware) -> tuple[StampFile, dict[str, str], Path, Path]:
    """STEP's stamp file, its stamp now, the installed files it lists and the install prefix."""
    build_dir = firmware_build_dir(workspace.ws_dir, step.package)
    # A merged install/ (colcon --merge-install, which refuses an install/<package> there):
    # the firmware goes where that layout's setup files and ament index see it.
    prefix = install_prefix(workspace.ws_dir / "install", step.package)
    # What the stamp lists: the package's own files, not a merged prefix's other packages.
    installed = prefix / "share" / step.package if prefix == workspace.ws_dir / "install" else prefix
    manifest = workspace.root / step.project / "package.xml"
    # The ros2 run commands' text too: an install made before them (or another version) is redone.
    # So is one whose record beside the firmware is not the one this espdock writes (one before the
    # domain was recorded: flash and provision said "ROS domain as built" with no number).
    source = hashlib.sha256(
        f"{listing_digest(build_dir, COLCON_RESULT_FILES)}\0{':'.join(step.run_depends)}\0".encode()
        + manifest.read_bytes()
        + COMMANDS_SOURCE
        + b"\0"
        + (built_transport_record(build_dir) or b"")
    )
    stamps = {step.package: source.hexdigest()}
    return StampFile(workspace.ws_dir / "build" / INSTALL_STAMPS), stamps, installed, prefix


def _outside_build_dir(workspace: Workspace, build_dir: Path) -> tuple[Mount, ...]:
    """The mount of BUILD_DIR's target when it links out of the workspace (colcon's --build-base
    elsewhere): at its own host path, where the link's absolute target points in the container too,
    so idf.py's -B (the link) and the paths CMake records are the same in every build."""
    if not build_dir.is_symlink():
        return ()
    real = build_dir.resolve()
    if real.is_relative_to(workspace.root.resolve()):
        return ()  # the workspace mount has it, and the link is relative
    return (Mount(real, str(real)),)


def _linked_out(workspace: Workspace, step: IdfBuild) -> tuple[Mount, ...]:
    """The mounts of the directories links lead to out of the workspace from STEP's project or the
    components beside it (a `shared -> ~/repos/components` EXTRA_COMPONENT_DIRS names), as the ROS
    side's: the stamps already follow such links, and without the mounts IDF found nothing there."""
    project = workspace.root / step.project
    return links_out(workspace, (root for root in (project, project.parent / "components") if root.is_dir()))


def _firmware_stamp(workspace: Workspace, step: IdfBuild, image_id: str) -> dict[str, str]:
    """What decides a firmware build: the project, the shared components, the sdkconfig in
    the build dir (menuconfig's changes), the image and the target. The image by its ID (IMAGE_ID) as
    well: `micro-ros rebuild` makes another image of the same key, whose library may differ
    (a source that follows its branch head), and the firmware must be linked against it."""
    sdkconfig = workspace.ws_dir / "build" / step.package / "sdkconfig"
    digest = hashlib.sha256(f"{step.image_key}\0{image_id}\0{step.target}\n".encode())
    digest.update(tree_digest(workspace.root / step.project).encode())
    # Shared components beside the project (CMake's EXTRA_COMPONENT_DIRS ../components).
    components = (workspace.root / step.project).parent / "components"
    if components.is_dir():
        digest.update(tree_digest(components).encode())
    if sdkconfig.is_file():
        digest.update(hashlib.sha256(sdkconfig.read_bytes()).digest())
    for path in _other_components(workspace, step):
        digest.update(f"{path}\0{tree_digest(path)}\n".encode())
    for path in _outside_files(workspace, step):
        content = hashlib.sha256(path.read_bytes()).hexdigest() if path.is_file() else "missing"
        digest.update(f"{path}\0{content}\n".encode())
    return {step.package: digest.hexdigest()}


# What idf.py itself writes into a project: the component manager's lock, at its root.
IDF_WRITES = ("dependencies.lock",)


# A file's size, modification time and mode.
_Seen = dict[Path, tuple[int, int, int]]


def _stamp_roots(workspace: Workspace, step: IdfBuild) -> tuple[Path, ...]:
    """The directories and files STEP's firmware stamp (_firmware_stamp) hashes."""
    project = workspace.root / step.project
    return (
        project,
        project.parent / "components",
        *_other_components(workspace, step),
        *_outside_files(workspace, step),
    )


def _source_times(roots: tuple[Path, ...]) -> _Seen:
    """Each file under ROOTS (_stamp_roots) with its size, modification time and mode: cheap,
    read before and after idf.py to see an editor's save between."""
    seen: _Seen = {}
    for root in roots:
        for path in source_files(root, follow_links=True) if root.is_dir() else [root] if root.is_file() else ():
            with contextlib.suppress(OSError):
                info = path.stat()
                seen[path] = (info.st_size, info.st_mtime_ns, info.st_mode)
    return seen


def _edited_since(before: _Seen, after: _Seen, workspace: Workspace, step: IdfBuild) -> list[str]:
    """The files (relative to the workspace where inside it) added, removed or changed between
    BEFORE and AFTER (_source_times), but those idf.py writes itself."""
    project = workspace.root / step.project
    changed = sorted(path for path in before.keys() | after.keys() if before.get(path) != after.get(path))
    return [
        str(path.relative_to(workspace.root)) if path.is_relative_to(workspace.root) else str(path)
        for path in changed
        if not (path.parent == project and path.name in IDF_WRITES)
    ]


def _other_components(workspace: Workspace, step: IdfBuild) -> list[Path]:
    """The components of the workspace the last build of STEP used from outside its project and
    the components beside it (another EXTRA_COMPONENT_DIRS entry, an idf_component.yml `path:`
    dependency): an edit of one must build the app again, as idf.py would. IDF's
    project_description.json names every component the build used by its path in the container;
    those of the image are the image's ID's, downloaded ones are the component manager's lock's."""
    description = firmware_build_dir(workspace.ws_dir, step.package) / "project_description.json"
    try:
        paths = json.loads(description.read_text()).get("build_component_paths", [])
    except (OSError, ValueError, AttributeError):
        return []
    project = workspace.root / step.project
    covered = (project, project.parent / "components", workspace.ws_dir / "build", workspace.ws_dir / "install")
    found = set()
    for raw in paths if isinstance(paths, list) else []:
        host = host_path(raw, workspace.root) if isinstance(raw, str) and raw else None
        if host is not None and host.is_dir() and not any(host.is_relative_to(place) for place in covered):
            found.add(host)
    return sorted(found)


def _outside_files(workspace: Workspace, step: IdfBuild) -> list[Path]:
    """The files of the workspace outside STEP's project and the components beside it that its
    build reads by name: the defaults files its SDKCONFIG_DEFAULTS names (a monorepo's
    `../common/sdkconfig.common`), the custom partition table its last sdkconfig names (IDF
    takes a relative one from the project) and the files its last configure read (a
    `include(../common/board.cmake)`). An edit of one must build again, as idf.py would."""
    project = workspace.root / step.project
    build_dir = firmware_build_dir(workspace.ws_dir, step.package)
    named: list[Path | None] = [path for _, path in _defaults_files(project, step.target)]
    config = _config_lines(build_dir / "sdkconfig", ("CONFIG_PARTITION_",))
    table = config.get("CONFIG_PARTITION_TABLE_FILENAME", "").strip('"')
    if config.get("CONFIG_PARTITION_TABLE_CUSTOM") == "y" and table:
        named.append(host_path(table, workspace.root) if table.startswith("/") else project / table)
    named += [host_path(path, workspace.root) for path in _configure_inputs(build_dir)]
    covered = (project, project.parent / "components", workspace.ws_dir / "build", workspace.ws_dir / "install")
    normal = {Path(os.path.normpath(path)) for path in named if path is not None}
    return sorted(path for path in normal if not any(path.is_relative_to(place) for place in covered))


def _configure_inputs(build_dir: Path) -> list[str]:
    """The absolute paths of the files the last configure in BUILD_DIR read (CMake's list files,
    CMAKE_CONFIGURE_DEPENDS), as the rule of build.ninja that re-runs CMake names them: the
    inputs of `build build.ninja: RERUN_CMAKE | ...`, one line, in Ninja's escapes."""
    try:
        text = (build_dir / "build.ninja").read_text(errors="replace")
    except OSError:
        return []
    rule = re.search(r"^build build\.ninja\b[^\n]*?: RERUN_CMAKE\b[^|\n]*\| ([^\n]*)$", text, re.MULTILINE)
    implicit = rule.group(1).split(" || ")[0] if rule else ""  # not its order-only inputs
    paths = [re.sub(r"\$(.)", r"\1", word) for word in re.findall(r"(?:\$.|[^ $])+", implicit)]
    return [path for path in paths if path.startswith("/")]  # not CMakeCache.txt, in the build dir


def _read_marker(build_dir: Path) -> tuple[str, str, str] | None:
    """The target, sdkconfig.defaults digest and image key the build dir was last built with
    (missing lines empty), None where it has no record."""
    try:
        lines = (build_dir / TARGET_MARKER).read_text().split("\n")
    except OSError:
        return None
    target, defaults, key, *_ = [*lines, "", "", ""]
    return target, defaults, key


def _write_marker(build_dir: Path, target: str, defaults: str, image_key: str, owner: tuple[int, int]) -> None:
    make_dirs_for(build_dir, owner)
    (build_dir / TARGET_MARKER).write_text(f"{target}\n{defaults}\n{image_key}\n")
    give_to(build_dir / TARGET_MARKER, owner)


def installed_image(workspace: Workspace, step: IdfBuild) -> str:
    """The micro-ROS image STEP's package's installed firmware was built in (which `flash`,
    `provision` and `monitor` run in: installed_from); STEP's own where nothing says."""
    built = _built_step(step, workspace)
    return step.image if built is None else built.image


def _built_step(step: IdfBuild, workspace: Workspace) -> IdfBuild | None:
    """STEP as its package's installed firmware was built: its chip (a one-off `--target` is
    another's) and the image of its key, as its build dir's record of the last build that
    finished says or, that gone (`rm -rf build`), the install's manifest; None where neither does.
    Without the manifest's word, a flash after `rm -rf build` built the library of the sources as
    they are, edited since or not building at all."""
    target, key = _recorded(workspace, step.package)
    repository = step.image.rpartition(":")[0]
    if not target or not key or (target != step.target and not repository.endswith(f"-{step.target}")):
        return None
    if target != step.target:  # the micro-ROS images are named for their chip
        repository = repository.removesuffix(step.target) + target
    return replace(step, image=keyed_tag(repository, key), image_key=key, target=target)


def recorded_step(workspace: Workspace, package: str, project: str, ros_distro: str) -> IdfBuild | None:
    """PACKAGE's installed firmware's build step from its records alone (_built_step's), for
    `flash`, `provision` and `monitor` when its own sources, mid-edit, do not plan (a chip
    misspelt in sdkconfig.defaults, an idf_component.yml half typed); None where nothing records it."""
    target, key = _recorded(workspace, package)
    if not target or not key:
        return None
    image = keyed_tag(micro_ros_repository(ros_distro, target), key)
    return IdfBuild(package, project, image, target, key, colcon_root=workspace.colcon_root)


def _recorded(workspace: Workspace, package: str) -> tuple[str, str]:
    """The chip and image key PACKAGE's installed firmware was built with, as its build dir's record
    of the last build that finished says, else the install's manifest ('' each where neither does)."""
    target, _, key = _read_marker(firmware_build_dir(workspace.ws_dir, package)) or ("", "", "")
    if not target or not key:
        target, key = _manifest_entry(workspace.ws_dir / "install" / MANIFEST_NAME, package)
    return target, key


def _manifest_entry(manifest: Path, package: str) -> tuple[str, str]:
    """The chip and image key the install's MANIFEST records PACKAGE's firmware built with ('' each
    where it records none, or an image not named for that chip)."""
    try:
        entry = json.loads(manifest.read_text()).get("firmware", {}).get(package, {})
        target, image = entry.get("target"), entry.get("image")
    except (OSError, ValueError, AttributeError):
        return "", ""
    if not isinstance(target, str) or not isinstance(image, str):
        return "", ""
    repository, _, key = image.rpartition(":")
    return (target, key) if target and repository.endswith(f"-{target}") else ("", "")


def built_chip(workspace: Workspace, package: str) -> str:
    """The chip PACKAGE's build dir was last configured for ('' where it has no record)."""
    target, _, _ = _read_marker(firmware_build_dir(workspace.ws_dir, package)) or ("", "", "")
    return target


def _built_key(build_dir: Path, target: str) -> str:
    """The image key of the build dir's last successful build for TARGET ('' if none)."""
    built_target, _, key = _read_marker(build_dir) or ("", "", "")
    return key if built_target == target else ""


SDKCONFIG_OLD = "sdkconfig.old"  # the name menuconfig gives the one it replaces
SDKCONFIG_MADE = ".espdock-sdkconfig-made"  # the sdkconfig as the defaults made it
OLD_CHANGED = ".espdock-sdkconfig-old-changed"  # there when sdkconfig.old has menuconfig's changes


def _prepare_build_dir(
    build_dir: Path, target: str, defaults: str, image_key: str, project: Path, root: Path, owner: tuple[int, int]
) -> tuple[bool, str | None]:
    """Make a build dir safe to reuse for PROJECT (on the host, in workspace ROOT).

    IDF refuses a build dir configured for another chip or another project directory (a project
    moved or renamed: "Run 'idf.py fullclean'"), and one configured in another image keeps that
    image's toolchain paths and library in CMakeCache.txt and ninja's state, so any of them
    starts afresh. The sdkconfig (menuconfig's changes) survives an image or project change; an
    existing sdkconfig wins over sdkconfig.defaults, so it is set aside as sdkconfig.old when the
    defaults changed, and with the target (as IDF's set-target does). Returns whether it removed
    anything, and whether it set the sdkconfig aside: None if not, else the chip it was for when
    the target changed ('' when the defaults did).
    """
    marker = _read_marker(build_dir)
    if marker is None:
        return False, None
    built_target, built_defaults, built_key = marker
    keep = "sdkconfig" if built_defaults == defaults and built_target == target else None
    replaced = None
    if keep is None and (build_dir / "sdkconfig").is_file():
        changed = not _same_file(build_dir / "sdkconfig", build_dir / SDKCONFIG_MADE)
        if not changed and (build_dir / OLD_CHANGED).is_file() and (build_dir / SDKCONFIG_OLD).is_file():
            # No menuconfig change since the defaults made it: sdkconfig.old keeps the one that had
            # some (a branch switched there and back replaced it with this one).
            (build_dir / "sdkconfig").unlink()
        else:
            (build_dir / "sdkconfig").replace(build_dir / SDKCONFIG_OLD)
            if changed:
                (build_dir / OLD_CHANGED).touch()
                give_to(build_dir / OLD_CHANGED, owner)
            else:
                (build_dir / OLD_CHANGED).unlink(missing_ok=True)
        (build_dir / SDKCONFIG_MADE).unlink(missing_ok=True)
        replaced = built_target if built_target != target else ""
    # As IDF compares them: by real path (here, the host's: ROOT is the workspace mount's).
    configured = _configured_project(build_dir)
    moved = configured is not None and (host_path(configured, root) or Path(configured)).resolve() != project.resolve()
    if built_key != image_key or built_target != target or moved:
        # What the last library's settings were compared against is another chip's library's.
        baseline = LIBRARY_BASELINE if built_target == target else None
        kept = {keep, baseline, SDKCONFIG_OLD, OLD_CHANGED, TARGET_MARKER, *((SDKCONFIG_MADE,) if keep else ())}
        for entry in build_dir.iterdir():
            if entry.name in kept:
                continue
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()
        return True, replaced
    return keep is None, replaced


def _same_file(one: Path, other: Path) -> bool:
    try:
        return one.read_bytes() == other.read_bytes()
    except OSError:
        return False


def _configured_project(build_dir: Path) -> str | None:
    """The project directory BUILD_DIR's CMake cache was configured for (None: no cache)."""
    try:
        with (build_dir / "CMakeCache.txt").open(encoding="utf-8", errors="replace") as cache:
            for line in cache:
                if line.startswith("CMAKE_HOME_DIRECTORY:"):
                    return line.split("=", 1)[1].strip()
    except OSError:
        pass
    return None


LIBRARY_BASELINE = ".espdock-library-sdkconfig"


def _config_lines(sdkconfig: Path, prefixes: tuple[str, ...] = ("CONFIG_",)) -> dict[str, str]:
    """The options of SDKCONFIG (a defaults file too) named with one of PREFIXES, and their values
    ('n' for `# CONFIG_X is not set`)."""
    values = {}
    for line in sdkconfig.read_text(errors="replace").splitlines() if sdkconfig.is_file() else ():
        match = SDKCONFIG_LINE.match(line.strip())
        if match and (key := match.group(1) or match.group(3)).startswith(prefixes):
            values[key] = match.group(2) if match.group(1) else "n"
    return values


def _library_lines(sdkconfig: Path) -> dict[str, str]:
    return _config_lines(sdkconfig, LIBRARY_SDKCONFIG_PREFIXES)


def chip_overrides(project: Path, target: str, order: Sequence[str] = ()) -> list[str] | None:
    """The options PROJECT's sdkconfig.defaults (where save-defconfig writes) sets that a defaults
    file IDF applies after it sets to another value, which wins: the chip's sdkconfig.defaults.TARGET,
    or one the CMakeLists' SDKCONFIG_DEFAULTS (ORDER) names after it. After `save-defconfig`, a
    menuconfig change to such an option is in sdkconfig.defaults, and the next sdkconfig made from
    the defaults loses it. None where ORDER leaves sdkconfig.defaults out: no build reads it."""
    applied = applied_defaults(target, order)
    if "sdkconfig.defaults" not in applied:
        return None
    saved = _config_lines(project / "sdkconfig.defaults")
    winners: dict[str, tuple[str, str]] = {}
    for name in applied[applied.index("sdkconfig.defaults") + 1 :]:
        for key, value in _config_lines(project / name).items():
            winners[key] = (value, name)
    return [
        f"{key}={winners[key][0]} ({winners[key][1]}) over {saved[key]}"
        for key in sorted(saved.keys() & winners.keys())
        if saved[key] != winners[key][0]
    ]


def _library_settings_changed(build_dir: Path, fresh: bool, record: bool = True) -> list[str]:
    """The library-relevant options (FreeRTOS, lwIP, PSRAM, CONFIG_MICRO_ROS_*, ...) of the build
    dir's sdkconfig that differ from what it held when configured afresh from sdkconfig.defaults,
    which is what libmicroros.a was built with: menuconfig's changes that the library lacks.
    FRESH, or no record of that yet: none, and (with RECORD) the sdkconfig as it is now is the record."""
    baseline = build_dir / LIBRARY_BASELINE
    current = _library_lines(build_dir / "sdkconfig")
    if fresh or not baseline.is_file():
        if record:
            baseline.write_text(json.dumps(current, sort_keys=True))
        return []
    try:
        before = json.loads(baseline.read_text())
    except ValueError:
        before = {}
    return [
        f"{key}={current.get(key, 'n')} (was {before.get(key, 'n')})"
        for key in sorted(set(before) | set(current))
        if before.get(key, "n") != current.get(key, "n")
    ]


def reset_build_dir(workspace: Workspace, step: IdfBuild) -> Path:
    """espdock's `idf.py fullclean`: empty STEP's build dir but for its sdkconfig and sdkconfig.old
    (menuconfig's changes, which IDF's fullclean leaves in the project dir) and espdock's record of what it was
    built with (which image the installed firmware is of: `flash` after a fullclean and an
    interface edit built the edited sources' image). IDF's own would delete the source of the
    managed_components mount, and the component manager would fail (EBUSY) removing the
    mountpoint; here the next build extracts it again from the download cache."""
    build_dir = workspace.ws_dir / "build" / step.package
    with workspace_lock(workspace):
        if build_dir.is_dir():
            for entry in build_dir.iterdir():
                # sdkconfig.old too: the one an earlier build set aside, with menuconfig's changes.
                if entry.name in (
                    "sdkconfig",
                    SDKCONFIG_OLD,
                    OLD_CHANGED,
                    SDKCONFIG_MADE,
                    LIBRARY_BASELINE,
                    TARGET_MARKER,
                ):
                    continue
                if entry.is_dir() and not entry.is_symlink():
                    shutil.rmtree(entry)
                else:
                    entry.unlink()
    return build_dir


def _defaults_files(project: Path, target: str) -> list[tuple[str, Path]]:
    """The defaults files of PROJECT that an IDF build for TARGET reads, by the names its CMakeLists
    gives them: those its SDKCONFIG_DEFAULTS names, else sdkconfig.defaults and its variants (but
    other chips' and an editor's or patch's leftovers)."""
    named, conditional = sdkconfig_defaults_list(project / "CMakeLists.txt")
    listed = [(n, project / n) for n in applied_defaults(target, named) if (project / n).is_file()] if named else []
    if listed and not conditional:
        # Those alone: an edit of an sdkconfig.defaults the list leaves out made the sdkconfig
        # afresh, and lost a menuconfig change save-defconfig had just written there.
        return listed
    # Where a condition decides the list (`if(DEFINED ENV{CI})`), sdkconfig.defaults may be what IDF reads.
    others = {f"sdkconfig.defaults.{chip}" for chip in CHIP_TARGETS if chip != target}
    globbed = [
        (path.name, path)
        for path in sorted(project.glob("sdkconfig.defaults*"))
        if path.is_file() and path.name not in others and not editor_leftover(path.name)
    ]
    seen = {name for name, _ in globbed}
    return globbed + [entry for entry in listed if entry[0] not in seen]


def _defaults_digest(project: Path, target: str) -> str:
    """The digest of the defaults files PROJECT's build for TARGET reads, whose change makes the
    sdkconfig afresh: of their settings, not of a checkout's line endings (Git for Windows'
    autocrlf, then WSL's git, rewrite every line and nothing else) or byte order mark."""
    digest = hashlib.sha256()
    for name, path in _defaults_files(project, target):
        digest.update(name.encode() + b"\0" + as_lines(path.read_bytes()))
    return digest.hexdigest()[:16]


def _device_groups(devices: tuple[str, ...]) -> list[int]:
    # Serial devices belong to a group (dialout); the container user needs it to open them.
    return sorted({os.stat(d).st_gid for d in devices})


# gcc's words for an #include it cannot find: `main.c:3:10: fatal error: pkg/msg/x.h: No such file or directory`.
_MISSING_INCLUDE = re.compile(r"^(\S+?):\d+:\d+: fatal error: ([^\s:]+): No such file or directory")
# The micro-ROS library's headers: its interface packages' and its client library's.
_LIBRARY_HEADER = re.compile(r"^(?:[a-z][a-z0-9_]*/(?:msg|srv|action)/|rclc/|rcl/|rmw_microros/|micro_ros_utilities/)")


def missing_includes(line: str) -> list[tuple[str, str]]:
    """(the file that includes it, the header) for a header LINE says the compiler could not find."""
    return [(match.group(1), match.group(2))] if (match := _MISSING_INCLUDE.match(line.strip())) else []


def unrequired_library_hint(workspace: Workspace, step: IdfBuild, missing: Mapping[str, str]) -> str | None:
    """The hint for a build that failed on a micro-ROS header (MISSING: header -> the file in the
    container that includes it) in a component of the workspace other than the project's main,
    which requires every component: the others see only the components they name."""
    project = workspace.root / step.project
    for header, source in missing.items():
        host = host_path(source, workspace.root)
        if not _LIBRARY_HEADER.match(header) or host is None:
            continue
        places = (d for d in host.parents if d.is_relative_to(workspace.root))
        component = next((d for d in places if (d / "CMakeLists.txt").is_file()), None)
        if component in (None, project, project / "main"):
            continue
        return (
            f"{header} is the micro-ROS library's, and {component.relative_to(workspace.root)} does not require its "
            "component: add `PRIV_REQUIRES micro_ros_espidf_component` (`REQUIRES` where its own headers include "
            "micro-ROS's) to its idf_component_register (main requires every component; the others only those "
            "they name). Installed firmware was left as it was."
        )
    return None


# IDF's words (CMake's FATAL_ERROR, its first line) for a project set up for another world, and what to do.
_FAILURE_HINTS = (
    (
        "Failed to resolve component 'micro_ros_espidf_component'",
        "The project names micro_ros_espidf_component but not where the IDF image keeps it: add "
        "`list(APPEND EXTRA_COMPONENT_DIRS $ENV{UROS_COMPONENT_DIR})` to its CMakeLists.txt before "
        "include($ENV{IDF_PATH}/tools/cmake/project.cmake), as `espdock new`'s does.",
    ),
    (
        "EXTRA_COMPONENT_DIRS doesn't exist",
        "idf.py runs in a container that has the workspace (at /workspace) and the directories links in it lead "
        "to, not the host's other paths: name the directory relative to the project "
        "(`${CMAKE_CURRENT_LIST_DIR}/../common`), linking it into the workspace where it lies outside; for "
        "micro_ros_espidf_component, name the image's: $ENV{UROS_COMPONENT_DIR}.",
    ),
)


def failure_hint(line: str) -> str | None:
    """What to do about the failure LINE (idf.py's output) names, where it is one of _FAILURE_HINTS'."""
    return next((hint for words, hint in _FAILURE_HINTS if words in line), None)


def undeclared_interface_hint(step: IdfBuild, missing: Iterable[str]) -> str | None:
    """The hint for a build that failed on a header of an interface package of the workspace STEP's
    package does not depend on (a ROS habit: find_package, no <depend>), which the micro-ROS library
    holds only for the packages it depends on; None where MISSING names none."""
    named = sorted({header.split("/", 1)[0] for header in missing if "/" in header} & set(step.unreached))
    if not named:
        return None
    depends = "".join(f"<depend>{name}</depend>" for name in named)
    return (
        f"{step.package} includes headers of {', '.join(named)}, an interface package of this workspace it does not "
        f"depend on, so its micro-ROS library has none of them: add {depends} to {step.project}/package.xml and run "
        "`espdock build` again; installed firmware was left as it was."
    )
