"""Carries out a plan step by step; reports what happens as events, never prints."""

from __future__ import annotations

import contextlib
import errno
import time
from collections.abc import Mapping
from pathlib import Path
from typing import assert_never

from espdock import interrupts
from espdock.build.plan import Step
from espdock.build.steps import LABEL_WORKSPACE, EnsureBaseImage, EnsureImage, Plan
from espdock.config import Config
from espdock.errors import BuildFailed, DiskFull, EspdockError, ImageBuildError, disk_full
from espdock.events import Emit, Outcome, StepFinished, StepNote, StepStarted
from espdock.firmware.plan import IdfBuild, InstallFirmware
from espdock.firmware.steps import FIRMWARE_STAMPS, INSTALL_STAMPS, FirmwareSteps
from espdock.images.containers import Containers, permission_error
from espdock.images.engine import Engine
from espdock.images.keyed import KeyedImages
from espdock.ros.plan import ColconBuild, RuntimeImage
from espdock.ros.staleness import ROS_STAMPS
from espdock.ros.steps import RosSteps
from espdock.workspace import Workspace, workspace_lock


def stamp_files(workspace: Workspace) -> tuple[Path, ...]:
    """The files recording what the last build of each kind built (rewritten after each step)."""
    return tuple(workspace.ws_dir / "build" / name for name in (ROS_STAMPS, FIRMWARE_STAMPS, INSTALL_STAMPS))


class Runner:
    """Runs plan steps against one engine: each step in its world's module (images, ros,
    firmware), in plan order, under the workspace lock."""

    def __init__(
        self,
        engine: Engine,
        config: Config,
        env: Mapping[str, str],
        emit: Emit,
        owner: tuple[int, int],
        push_cache: bool = False,
    ) -> None:
        """OWNER (uid, gid): who containers run as and who owns what a build writes (config.invoking_user).
        PUSH_CACHE: make sure config.cache_registry holds every keyed image this run ensures."""
        self.containers = Containers(engine, config, env, emit, owner)
        self.images = KeyedImages(self.containers, push_cache)
        self.ros = RosSteps(self.containers, self.images)
        self.firmware = FirmwareSteps(self.containers)

    @property
    def engine(self) -> Engine:
        return self.containers.engine

    @property
    def owner(self) -> tuple[int, int]:
        """uid, gid that containers writing into the workspace run as."""
        return self.containers.owner

    @property
    def used_images(self) -> list[tuple[str, str]]:
        """The keyed images this runner's steps used (tag, repository), for espdock.images.prune's record."""
        return self.images.used

    @property
    def unpushed(self) -> list[tuple[str, str]]:
        """The images --push-cache could not push (reference, why)."""
        return self.images.unpushed

    def run(self, plan: Plan, lock: bool = True) -> list[StepFinished]:
        """Run every step in order; stops at the first failure, raising its error.

        LOCK: hold the workspace lock (builds); `espdock run` only ensures images, and two of
        them start at once."""
        results = []
        self.images.planned = [step for step in plan.steps if isinstance(step, EnsureImage)]
        with workspace_lock(plan.workspace) if lock else contextlib.nullcontext():
            # Before any step: a container an espdock killed earlier (kill -9, a lost terminal)
            # may still hold the workspace's files open or write into them.
            if any(isinstance(step, (ColconBuild, IdfBuild)) for step in plan.steps):
                if swept := self.containers.engine.sweep({LABEL_WORKSPACE: str(plan.workspace.root)}):
                    self.containers.emit(StepNote("workspace", interrupts.swept(swept, where=" in this workspace")))
            for index, step in enumerate(plan.steps):
                try:
                    results.append(self._run_step(plan.workspace, step))
                except (BuildFailed, ImageBuildError) as exc:
                    if left := _packages_of(plan.steps[index + 1 :]):
                        # Each firmware package is a step of its own: the summary ends at the failure.
                        said = f"Not built, the build having stopped here: {', '.join(left)}."
                        exc.hint = f"{exc.hint} {said}" if exc.hint else said
                    raise
        return results

    def _run_step(self, workspace: Workspace, step: Step) -> StepFinished:
        self.containers.emit(StepStarted(step.name))
        started = time.monotonic()
        try:
            try:
                outcome, detail = self._dispatch(workspace, step)
            except (EspdockError, OSError) as exc:
                # A build that failed for want of space says so (a compiler's "No space left"
                # is easy to miss in its log); espdock's own writes fail with ENOSPC.
                full = _full_disk(workspace, exc, self.containers.engine)
                if full is not None:
                    raise full from exc
                if isinstance(exc, PermissionError):
                    raise permission_error(exc, within=workspace.ws_dir) from exc
                raise
        except BaseException as exc:
            if isinstance(exc, EspdockError):
                detail = exc.message.splitlines()[0]
            elif isinstance(exc, KeyboardInterrupt):
                detail = "interrupted"
            elif isinstance(exc, OSError) and exc.filename:  # a read-only mount: said below, no bug
                detail = f"{exc.strerror}: {exc.filename}"
            else:
                detail = f"espdock bug: {type(exc).__name__}"
            self.containers.emit(StepFinished(step.name, Outcome.FAILED, time.monotonic() - started, detail))
            raise
        finished = StepFinished(step.name, outcome, time.monotonic() - started, detail)
        self.containers.emit(finished)
        return finished

    def _dispatch(self, workspace: Workspace, step: Step) -> tuple[Outcome, str]:
        match step:
            case EnsureBaseImage():
                return self.images.ensure_base(step)
            case EnsureImage():
                return self.images.ensure(workspace, step)
            case ColconBuild():
                return self.ros.colcon_build(workspace, step)
            case IdfBuild():
                return self.firmware.idf_build(workspace, step)
            case InstallFirmware():
                return self.firmware.install(workspace, step)
            case RuntimeImage():
                return self.ros.runtime_image(workspace, step)
            case _:
                assert_never(step)


def _packages_of(steps: tuple[Step, ...]) -> list[str]:
    """The packages STEPS build, in order."""
    names: list[str] = []
    for step in steps:
        if isinstance(step, ColconBuild):
            names += step.building
        elif isinstance(step, IdfBuild):
            names.append(step.package)
    return list(dict.fromkeys(names))


def _full_disk(workspace: Workspace, exc: Exception, engine: Engine) -> DiskFull | None:
    """The full disk a step failed for: the one an ENOSPC names, else a nearly full one of the trees
    a build writes (build/ or install/ may be filesystems of their own), or for a failed build on
    an engine of this machine, its data root: the containers' own files (/tmp: the CA bundle
    espdock's with-ca.sh writes there) fail there first, and the build said "fix the firmware"."""
    if isinstance(exc, OSError) and exc.errno == errno.ENOSPC:
        return disk_full(exc.filename or workspace.ws_dir, known=True)
    trees = [workspace.ws_dir, workspace.ws_dir / "build", workspace.ws_dir / "install"]
    if isinstance(exc, BuildFailed) and engine.host.startswith("unix://") and (root := engine.data_root()) != "unknown":
        trees.append(Path(root))
    return next((full for tree in trees if (full := disk_full(tree)) is not None), None)
