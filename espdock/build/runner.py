"""Carries out a plan step by step; reports what happens as events, never prints."""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import posixpath
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from dataclasses import replace
from datetime import UTC, datetime
from pathlib import Path
from typing import assert_never

from espdock.build.plan import Step
from espdock.build.stamps import StampFile, listing_digest, package_stamps, tree_digest
from espdock.build.steps import LABEL_KEY, LABEL_WORKSPACE, EnsureBaseImage, EnsureImage, ImageSpec, Plan, cache_ref
from espdock.config import Config, resolve_ca_bundle
from espdock.errors import (
    BuildFailed,
    ConfigError,
    EspdockError,
    RegistryError,
    WorkspaceError,
    WorkspaceNotVisible,
    disk_full,
)
from espdock.events import Emit, Outcome, StepFinished, StepNote, StepOutput, StepStarted
from espdock.firmware.install import COMMANDS_SOURCE, install_firmware
from espdock.firmware.plan import LIBRARY_SDKCONFIG_PREFIXES, SDKCONFIG_LINE, IdfBuild, InstallFirmware
from espdock.images import bootstrap
from espdock.images.engine import Engine, Mount, RegistryAnswer, RegistryStatus, RunSpec
from espdock.images.visibility import CHECKED, engine_sees, ensure_engine_sees, workspace_mount
from espdock.layout import ROS_BUILD_BASE, install_prefix
from espdock.ros.colcon import (
    DEFAULTS_MOUNT,
    ColconLog,
    PackageState,
    explain_failure,
    retire_container_caches,
    usage_error,
)
from espdock.ros.plan import ColconBuild, RuntimeImage, runtime_image_spec
from espdock.ros.runtime_tree import runtime_files
from espdock.ros.testing import ColconTest, SourcedEnv
from espdock.workspace import Workspace

TARGET_MARKER = ".espdock-target"
DPKG_LINE = re.compile(r"^[a-z0-9][a-z0-9+.-]*(:[a-z0-9]+)?=\S+$")
# Under ws/build, beside the packages' build dirs (colcon skips dot dirs).
COMPONENT_CACHE = ".idf-component-cache"
MANAGED_COMPONENTS = "managed_components"
# Under ws/build: what the ROS packages and the firmware were last built from (espdock.build.stamps).
ROS_STAMPS = ".espdock-colcon-stamps.json"
FIRMWARE_STAMPS = ".espdock-firmware-stamps.json"
INSTALL_STAMPS = ".espdock-install-stamps.json"
EXTRA_CA_MOUNT = "/run/espdock/extra-ca.pem"
WITH_CA = "/opt/espdock/with-ca.sh"
BUILDKIT_STEP = re.compile(r"^#\d+ \[.*\] (?P<what>.+)$")


def stamp_files(workspace: Workspace) -> tuple[Path, ...]:
    """The files recording what the last build of each kind built (rewritten after each step)."""
    return tuple(workspace.ws_dir / "build" / name for name in (ROS_STAMPS, FIRMWARE_STAMPS, INSTALL_STAMPS))


def _first_line(text: str) -> str:
    return (text.strip().splitlines() or ["no details"])[0][:200]


def _denied(registry: str, what: str, answer: RegistryAnswer) -> RegistryError:
    host = registry.split("/", 1)[0]
    return RegistryError(
        f"the cache registry {registry} refused the engine's credentials to {what}: {_first_line(answer.detail)}",
        f"Log the engine in: `docker login {host}` (espdock uses the engine's login; it reads no credentials).",
    )


def workspace_commit_time(root: Path) -> str | None:
    """The committer time (Unix seconds) of ROOT's git HEAD, or None outside a repository."""
    if shutil.which("git") is None:
        return None
    # safe.directory: as root, reading a repository another user owns is what espdock does.
    argv = ["git", "-c", "safe.directory=*", "-C", str(root), "log", "-1", "--format=%ct"]
    result = subprocess.run(argv, capture_output=True, text=True, check=False, stdin=subprocess.DEVNULL)
    value = result.stdout.strip()
    return value if result.returncode == 0 and value.isdigit() else None


class Runner:
    """Runs plan steps against one engine."""

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
        self._engine = engine
        self._config = config
        self._env = env
        self._emit = emit
        self._owner = owner
        self._push_cache = push_cache
        self._commit_times: dict[Path, str | None] = {}
        # The keyed images this runner's steps used (tag, repository), for espdock.images.prune's record.
        self.used_images: list[tuple[str, str]] = []
        # Packages this run was to build and did not: their install trees are old, so no runtime
        # image is made from them.
        self._unbuilt: set[str] = set()
        # Per workspace root: whether its build containers use its volume (espdock.volume).
        self._volume: dict[Path, bool] = {}

    @property
    def engine(self) -> Engine:
        return self._engine

    @property
    def owner(self) -> tuple[int, int]:
        """uid, gid that containers writing into the workspace run as."""
        return self._owner

    def _source_date(self, workspace: Workspace) -> tuple[tuple[str, str], ...]:
        """SOURCE_DATE_EPOCH for the build containers: the caller's, else the workspace's last commit.

        Tools that stamp their output read it instead of the clock (Python's .pyc files switch
        to source hashes, GCC's __DATE__/__TIME__, ...), so two builds of a commit match."""
        if workspace.root not in self._commit_times:  # one git call per run, not one per container
            self._commit_times[workspace.root] = workspace_commit_time(workspace.root)
        epoch = self._env.get("SOURCE_DATE_EPOCH") or self._commit_times[workspace.root]
        return (("SOURCE_DATE_EPOCH", epoch),) if epoch else ()

    def _reproducible_env(self, workspace: Workspace) -> tuple[tuple[str, str], ...]:
        """SOURCE_DATE_EPOCH, and a fixed PYTHONHASHSEED: rosidl's generators write some lists in
        set order (a service type description's includes), which the hash seed would shuffle."""
        return (*self._source_date(workspace), ("PYTHONHASHSEED", "0"))

    def run(self, plan: Plan, lock: bool = True) -> list[StepFinished]:
        """Run every step in order; stops at the first failure, raising its error.

        LOCK: hold the workspace lock (builds); `espdock run` only ensures images, and two of
        them start at once."""
        results = []
        with workspace_lock(plan.workspace) if lock else contextlib.nullcontext():
            # Before any step: a container an espdock killed earlier (kill -9, a lost terminal)
            # may still hold the workspace's files open or write into them.
            if any(isinstance(step, (ColconBuild, IdfBuild)) for step in plan.steps):
                self._engine.sweep({LABEL_WORKSPACE: str(plan.workspace.root)})
            for step in plan.steps:
                results.append(self._run_step(plan.workspace, step))
        return results

    def _run_step(self, workspace: Workspace, step: Step) -> StepFinished:
        self._emit(StepStarted(step.name))
        started = time.monotonic()
        try:
            try:
                outcome, detail = self._dispatch(workspace, step)
            except (EspdockError, OSError) as exc:
                # A build that failed for want of space says so (a compiler's "No space left"
                # is easy to miss in its log); espdock's own writes fail with ENOSPC.
                full = disk_full(workspace.ws_dir)
                if full is not None:
                    raise full from exc
                if isinstance(exc, PermissionError):
                    raise _permission_error(exc) from exc
                raise
        except BaseException as exc:
            if isinstance(exc, EspdockError):
                detail = exc.message.splitlines()[0]
            elif isinstance(exc, KeyboardInterrupt):
                detail = "interrupted"
            else:
                detail = f"espdock bug: {type(exc).__name__}"
            self._emit(StepFinished(step.name, Outcome.FAILED, time.monotonic() - started, detail))
            raise
        finished = StepFinished(step.name, outcome, time.monotonic() - started, detail)
        self._emit(finished)
        return finished

    def _dispatch(self, workspace: Workspace, step: Step) -> tuple[Outcome, str]:
        match step:
            case EnsureBaseImage():
                how = bootstrap.ensure_base_image(
                    self._engine, step.image, self._config, lambda text: self._emit(StepNote(step.name, text))
                )
                return (Outcome.CACHED, "present") if how == "present" else (Outcome.BUILT, how)
            case EnsureImage():
                return self._ensure_image(workspace, step)
            case ColconBuild():
                return self._colcon(workspace, step)
            case IdfBuild():
                return self._idf_build(workspace, step)
            case InstallFirmware():
                return self._install(workspace, step)
            case RuntimeImage():
                return self._runtime_image(workspace, step)
            case _:
                assert_never(step)

    def _ensure_image(
        self, workspace: Workspace, step: EnsureImage, extra_context: Mapping[str, Path | bytes] | None = None
    ) -> tuple[Outcome, str]:
        """EXTRA_CONTEXT: files copied into the build context (relative path -> source)."""
        spec = step.spec
        self.used_images.append((spec.tag, spec.repository))
        existing = self._engine.image(spec.tag)
        if not step.force and existing is not None and existing.labels.get(LABEL_KEY) == spec.key:
            age = datetime.now(UTC) - existing.created
            self._emit(
                StepNote(
                    step.name, f"{spec.tag}: cache hit (key {spec.key[:16]}, built {age_text(age.total_seconds())} ago)"
                )
            )
            self._publish(step)
            return Outcome.CACHED, spec.tag
        if not step.force and self._pull_from_cache(step):
            return Outcome.PULLED, f"{spec.tag} from {self._config.cache_registry}"
        why = "rebuild requested" if step.force else "cache miss"
        self._emit(StepNote(step.name, f"{spec.tag}: {why} (key {spec.key[:16]}), building stage {spec.target}"))
        bootstrap.ensure_compose(self._env, lambda text: self._emit(StepNote(step.name, text)))

        def on_line(line: str) -> None:
            match = BUILDKIT_STEP.match(line)
            self._emit(StepOutput(step.name, match.group("what") if match else line, progress=True))

        with _context_dir(workspace, spec, extra_context or {}) as context:
            self._engine.build_image(
                context=context,
                dockerfile=spec.dockerfile,
                target=spec.target,
                tag=spec.tag,
                # Not part of the key: BuildKit (0.11 and newer) stamps the image with it instead of now.
                build_args=dict(spec.build_args) | dict(self._source_date(workspace)),
                labels=spec.labels(),
                ca_bundle=resolve_ca_bundle(self._config, self._env),
                on_line=on_line,
                no_cache=step.force,
            )
        self._record_packages(workspace, step)
        self._publish(step)
        return Outcome.BUILT, spec.tag

    def runtime_spec(self, workspace: Workspace, step: RuntimeImage) -> ImageSpec:
        """The keyed runtime image for STEP's install trees as they are now."""
        step = _installed(workspace, step)
        digest = runtime_install_digest(workspace.ws_dir / "install", step.packages, workspace.root)
        return runtime_image_spec(step, digest)

    def _runtime_image(self, workspace: Workspace, step: RuntimeImage) -> tuple[Outcome, str]:
        # Only what is installed and, of what this run was to build, what it built.
        installed = _installed(
            workspace, replace(step, packages=tuple(p for p in step.packages if p not in self._unbuilt))
        )
        if missing := sorted(set(step.packages) - set(installed.packages)):
            # A build of a selection (`espdock build PKG`) leaves the others unbuilt: the image
            # holds what is installed, and says what it lacks.
            self._emit(StepNote(step.name, f"not in the image (not built yet): {', '.join(missing)}"))
        step = installed
        spec = self.runtime_spec(workspace, step)
        install = workspace.ws_dir / "install"
        outcome, _ = self._ensure_image(
            workspace, EnsureImage(spec), extra_context=runtime_context(install, step, workspace.root)
        )
        keyed = self._engine.image(spec.tag)
        stable = self._engine.image(step.stable_tag)
        if keyed is not None and (stable is None or stable.id != keyed.id):
            self._engine.tag(spec.tag, step.stable_tag)
            self._emit(StepNote(step.name, f"{step.stable_tag} is now {spec.tag}"))
        return outcome, f"{spec.tag}, {step.stable_tag}"

    def _record_packages(self, workspace: Workspace, step: EnsureImage) -> None:
        """The image's Debian package set (what its apt installs gave today) as labels, as the base has."""
        listing: list[str] = []
        query = ("dpkg-query", "-W", "-f", "${Package}=${Version}\n")
        labels = ((LABEL_WORKSPACE, str(workspace.root)), ("io.espdock.step", "dpkg"))
        if self._engine.run(RunSpec(image=step.spec.tag, argv=query, workdir="/", labels=labels), listing.append) != 0:
            self._emit(StepNote(step.name, "warning: no dpkg in the image: its package set is not recorded"))
            return
        # An entrypoint (the IDF image's sources export.sh) may print before the command runs.
        packages = sorted(line.strip() for line in listing if DPKG_LINE.match(line.strip()))
        self._engine.add_labels(step.spec.tag, bootstrap.package_labels(packages))
        self._emit(StepNote(step.name, f"{len(packages)} Debian packages recorded in the image's labels"))

    def _pull_from_cache(self, step: EnsureImage) -> bool:
        """Take STEP's image from the cache registry, if it has one with the right key label."""
        registry = self._config.cache_registry
        if not registry:
            return False
        spec = step.spec
        remote = cache_ref(registry, spec.tag)
        answer = self._engine.pull_cached(remote)
        if answer.status is RegistryStatus.DENIED:
            raise _denied(registry, "pull", answer)
        if answer.status is RegistryStatus.UNREACHABLE:
            why = _first_line(answer.detail)
            self._emit(
                StepNote(step.name, f"warning: cache registry {registry} did not answer ({why}); building locally")
            )
            return False
        if answer.status is RegistryStatus.MISSING:
            self._emit(StepNote(step.name, f"{remote}: not in the cache registry"))
            return False
        pulled = self._engine.image(remote)
        label = pulled.labels.get(LABEL_KEY) if pulled else None
        if label != spec.key:
            # Someone pushed another image under this key: building is safer than trusting it.
            self._engine.untag(remote)
            found = (label or "missing")[:16]
            self._emit(
                StepNote(step.name, f"warning: rejected {remote}: its key label is {found}, expected {spec.key[:16]}")
            )
            return False
        self._engine.tag(remote, spec.tag)
        self._engine.untag(remote)
        self._emit(StepNote(step.name, f"{spec.tag}: pulled from the cache registry {registry} (key {spec.key[:16]})"))
        return True

    def _publish(self, step: EnsureImage) -> None:
        """With --push-cache, push STEP's image unless the cache registry holds it already."""
        registry = self._config.cache_registry
        if not (self._push_cache and registry):
            return
        remote = cache_ref(registry, step.spec.tag)
        held = self._engine.registry_has(remote)
        if held.status is RegistryStatus.OK:
            self._emit(StepNote(step.name, f"{remote}: already in the cache registry"))
            return
        if held.status is RegistryStatus.DENIED:
            raise _denied(registry, "push", held)
        if held.status is RegistryStatus.MISSING:
            self._engine.tag(step.spec.tag, remote)
            try:
                held = self._engine.push_cached(remote)
            finally:
                self._engine.untag(remote)
            if held.status is RegistryStatus.OK:
                self._emit(StepNote(step.name, f"pushed {remote}"))
                return
            if held.status is RegistryStatus.DENIED:
                raise _denied(registry, "push", held)
        why = _first_line(held.detail)
        self._emit(StepNote(step.name, f"warning: could not push to the cache registry {registry} ({why})"))

    def _colcon(self, workspace: Workspace, step: ColconBuild) -> tuple[Outcome, str]:
        stamp_file = StampFile(workspace.ws_dir / "build" / ROS_STAMPS)
        sources = {name: tree_digest(workspace.ws_dir / rel) for name, rel in step.sources}
        stamps = package_stamps(sources, dict(step.depends), step.stamp_image, dict(step.settings))

        def installed() -> dict[str, str | None]:
            return {name: listing_digest(workspace.ws_dir / "install" / name) for name in stamps}

        # The changed packages and, their stamps being chained, what depends on them; the rest
        # are up to date in install/, where colcon finds them.
        rebuild = tuple(stamps) if step.force else stamp_file.stale(stamps, installed())
        if not rebuild:
            return Outcome.CACHED, f"up to date ({len(stamps)} package(s))"
        user, labels = self._container_identity(workspace, "colcon", sweep=True)
        sync = self._sync(workspace, step.name, step.image, user, labels)
        if sync is not None and (sync.fresh or sync.installed != listing_digest(workspace.ws_dir / "install")):
            # install/ is swapped for the volume's whole: every package must be built there.
            rebuild = tuple(stamps)
        # Until this build succeeds, none of them counts as built.
        recorded = stamp_file.read()
        stamp_file.forget(rebuild)
        mounted_build = posixpath.join(step.workdir, "build")
        if retired := retire_container_caches(workspace.ws_dir / "build", stamps, mounted_build):
            why = f"espdock's CMake caches from before {ROS_BUILD_BASE}, which a native colcon build refuses"
            self._emit(StepNote(step.name, f"removed {', '.join(f'build/{name}' for name in retired)}: {why}"))
        if step.says_tests_off:
            self._emit(
                StepNote(
                    step.name,
                    "CMake packages are configured with BUILD_TESTING=OFF: the wheels image lacks ament's lint "
                    "packages (ament_lint_auto, ...); `espdock test` builds them with their tests",
                )
            )
        mounts, archives = self._workspace_in(workspace, sync)
        env = [("HOME", "/tmp"), *self._reproducible_env(workspace)]
        if step.defaults_file is not None:
            # colcon reads the user's defaults from their home, which the container does not have.
            if sync is None:
                mounts.append(Mount(Path(step.defaults_file), DEFAULTS_MOUNT, read_only=True))
            else:
                archives.append(volume.file_archive(DEFAULTS_MOUNT, Path(step.defaults_file).read_bytes()))
            env.append(("COLCON_DEFAULTS_FILE", DEFAULTS_MOUNT))
        log = ColconLog(workspace.ws_dir / "log")
        output: list[str] = []

        def on_line(line: str) -> None:
            output.append(line)
            self._emit(StepOutput(step.name, line))

        spec = RunSpec(
            image=step.image,
            argv=step.argv(rebuild),
            workdir=step.workdir,
            user=user,
            mounts=tuple(mounts),
            env=tuple(env),
            labels=labels,
            archives=tuple(archives),
        )
        if sync is None:
            code = self._engine.run(spec, on_line, keep=self._config.keep_containers)
        else:
            with volume.fetched("install", "log") as fetched:
                install, logs = workspace.ws_dir / "install", workspace.ws_dir / "log"
                paths = {volume.container_path(workspace, install): fetched["install"],
                         volume.container_path(workspace, logs): fetched["log"]}  # fmt: skip
                code = self._engine.run(spec, on_line, keep=self._config.keep_containers, fetch=paths)
                volume.merge_logs(fetched["log"], logs, self._owner)
                volume.replace_tree(fetched["install"], install, self._owner)
                volume.record(workspace, self._engine, sync, listing_digest(install))
                _give_to(workspace.ws_dir / "build" / volume.SYNCED, self._owner)
        states = log.states()
        built = [name for name, state in (states or {}).items() if state is PackageState.BUILT and name in stamps]
        if built:
            stamp_file.record({name: stamps[name] for name in built}, installed())
            _give_to(stamp_file.path, self._owner)
        self._unbuilt |= set(rebuild) - set(built)
        if states is None and code != 0:
            # Nothing in build/ or install/ changed: the packages keep their records, and the
            # next build with other options rebuilds only what those change.
            stamp_file.restore({name: recorded[name] for name in rebuild if name in recorded})
            last = next((line for line in reversed(output) if line.strip()), "no output")
            if "PermissionError" in last or "Permission denied" in last:
                # colcon may not write its log or build dirs: they belong to someone else.
                where = next((d for d in (workspace.ws_dir / n for n in ("log", "build", "install")) if d.exists()
                              and d.stat().st_uid != self._owner[0]), workspace.ws_dir)  # fmt: skip
                raise _permission_error(PermissionError(13, last.strip(), str(where)))
            said = usage_error(output, step.colcon_args)
            raise ConfigError(
                said or f"colcon stopped before building any package (exit code {code}): {last.strip()}",
                "Check the colcon options after `--` (`colcon build --help` in `espdock shell` lists them) "
                "and colcon's defaults files; nothing was built.",
            )
        if code != 0:
            logs = {
                name: (log.package_log(name), _read_text(log.package_log(name)))
                for name, state in (states or {}).items()
                if state is PackageState.FAILED
            }
            declared = {name: (depends, tests) for name, depends, tests in step.declared}
            failure = explain_failure(code, states or {}, logs, step.colcon_args, declared)
            raise BuildFailed(failure.message, failure.hint)
        others = [n for n in rebuild if n not in built]
        # Asked for and neither built nor left out as told (`-- --packages-skip`): colcon did not
        # find it where espdock did (a package linked from outside the workspace, say).
        if lost := [n for n in others if n not in (states or {}) and n not in log.unselected()]:
            rels = dict(step.sources)
            raise BuildFailed(
                f"colcon did not find {len(lost)} of the {len(rebuild)} package(s) it was to build: "
                + ", ".join(f"{n} ({posixpath.join(step.colcon_root, rels.get(n, '?'))})" for n in lost),
                "The build container sees the workspace at "
                f"{workspace_mount(workspace).target} and nothing outside it: a package directory, or one above it, "
                "that links out of the workspace leads nowhere there. Move the package into the workspace, then "
                "build again; nothing of it was installed.",
            )
        detail = f"{len(built)} package(s) built, {len(stamps) - len(rebuild)} up to date"
        return Outcome.BUILT, detail + (f", {len(others)} not built ({' '.join(others)})" if others else "")

    def colcon_test(self, workspace: Workspace, step: ColconTest, on_line: Callable[[str], None]) -> int:
        """Run STEP (colcon test) as the invoking user, its output to ON_LINE; colcon's exit code."""
        user, labels = self._container_identity(workspace, "colcon-test", sweep=False)
        if self.uses_volume(workspace, step.image, user, labels):
            raise volume_mode_refused("the test results `espdock test` reads")
        mounts = [workspace_mount(workspace)]
        env = [("HOME", "/tmp"), *self._reproducible_env(workspace)]
        if step.defaults_file is not None:
            mounts.append(Mount(Path(step.defaults_file), DEFAULTS_MOUNT, read_only=True))
            env.append(("COLCON_DEFAULTS_FILE", DEFAULTS_MOUNT))
        sourced = SourcedEnv(workspace.ws_dir, step.image, tuple(env))
        with workspace_lock(workspace):
            key = sourced.key()
            recorded = sourced.recorded(key)
            if key is not None and recorded is None:
                sourced.forget()
            spec = RunSpec(
                image=step.image,
                argv=step.argv(source=key is not None and recorded is None),
                workdir=_container_path(workspace, workspace.ws_dir),
                user=user,
                mounts=tuple(mounts),
                env=recorded or tuple(env),
                labels=labels,
            )
            code = self._engine.run(spec, on_line, keep=self._config.keep_containers)
            if key is not None and recorded is None and (written := sourced.record(key)) is not None:
                _give_to(written, self._owner)
            return code

    def _idf_build(self, workspace: Workspace, step: IdfBuild) -> tuple[Outcome, str]:
        build_dir = workspace.ws_dir / "build" / step.package
        stamp_file = StampFile(workspace.ws_dir / "build" / FIRMWARE_STAMPS)
        stamps = self._firmware_stamp(workspace, step)
        if not step.force and stamp_file.up_to_date(stamps, {step.package: listing_digest(build_dir)}):
            return Outcome.CACHED, f"up to date ({step.target})"
        stamp_file.forget(stamps)
        defaults = _defaults_digest(workspace.root / step.project)
        reset = _prepare_build_dir(build_dir, step.target, defaults, step.image_key)
        fresh = not (build_dir / "sdkconfig").is_file()
        code = self.run_idf(
            workspace,
            step,
            step.argv(),
            on_line=lambda line: self._emit(StepOutput(step.name, line)),
            sweep=True,
            reset=reset,
        )
        if code != 0:
            raise BuildFailed(
                f"idf.py build of {step.package} failed (exit code {code}); its output is above, "
                f"build files in {build_dir}",
                "Fix the firmware and run `espdock build` again; installed firmware was left as it was.",
            )
        (build_dir / TARGET_MARKER).write_text(f"{step.target}\n{defaults}\n{step.image_key}\n")
        _give_to(build_dir / TARGET_MARKER, self._owner)
        changed = _library_settings_changed(build_dir, fresh)
        _give_to(build_dir / LIBRARY_BASELINE, self._owner)
        if changed:
            shown = ", ".join(changed[:4]) + (", ..." if len(changed) > 4 else "")
            self._emit(
                StepNote(
                    step.name,
                    f"warning: {shown} changed in {build_dir.relative_to(workspace.root)}/sdkconfig (menuconfig) "
                    "reach the app but not libmicroros.a, built from sdkconfig.defaults: put the line in "
                    f"{step.project}/sdkconfig.defaults (`espdock idf {step.package} -- save-defconfig`) and "
                    "build again, so a library with it is built (`espdock micro-ros rebuild` rebuilds it from "
                    "scratch)",
                )
            )
        # After the build: IDF itself writes into the project (the component manager's lock).
        stamp_file.record(self._firmware_stamp(workspace, step), {step.package: listing_digest(build_dir)})
        _give_to(stamp_file.path, self._owner)
        return Outcome.BUILT, step.target

    @staticmethod
    def _firmware_stamp(workspace: Workspace, step: IdfBuild) -> dict[str, str]:
        """What decides a firmware build: the project, the shared components, the sdkconfig in
        the build dir (menuconfig's changes), the image and the target."""
        sdkconfig = workspace.ws_dir / "build" / step.package / "sdkconfig"
        digest = hashlib.sha256(f"{step.image_key}\0{step.target}\n".encode())
        digest.update(tree_digest(workspace.root / step.project).encode())
        # Shared components beside the project (CMake's EXTRA_COMPONENT_DIRS ../components).
        components = (workspace.root / step.project).parent / "components"
        if components.is_dir():
            digest.update(tree_digest(components).encode())
        if sdkconfig.is_file():
            digest.update(hashlib.sha256(sdkconfig.read_bytes()).digest())
        return {step.package: digest.hexdigest()}

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
        SWEEP only from a build, which holds the workspace lock (see _container_identity).
        RESET: the host's build dir was emptied for a new target or image (_prepare_build_dir);
        in volume mode the volume's is emptied the same way.
        """
        user, labels = self._container_identity(workspace, f"idf-{step.package}", sweep)
        build_dir = workspace.ws_dir / "build" / step.package
        # The component manager extracts into <project>/managed_components, a place it does not
        # let anyone move; a mount keeps that in ws/build, and the source tree clean. On the
        # volume it stays in the project: the volume's copy of the sources is espdock's own.
        managed = build_dir / MANAGED_COMPONENTS
        mountpoint = workspace.root / step.project / MANAGED_COMPONENTS
        sync = None
        if self.uses_volume(workspace, step.image, user, labels):
            if devices or extra_mounts:
                raise volume_mode_refused(f"a serial port for {step.package}")
            sync = self._sync(workspace, step.name, step.image, user, labels, (build_dir,) if reset else ())
        else:
            for directory in (managed, mountpoint):
                _make_dirs_for(directory, self._owner)
        mounts, archives = self._workspace_in(workspace, sync)
        if sync is not None:
            # espdock's records of the build dir live on the host (the volume's come back without
            # them), and a new volume gets menuconfig's sdkconfig, which outlives a reset.
            kept = (TARGET_MARKER, LIBRARY_BASELINE, *(("sdkconfig",) if reset or sync.fresh else ()))
            archives.append(volume.files_archive(workspace, build_dir, kept, self.container_owner()))
        if sync is None:
            mounts += [Mount(managed, f"{step.project_dir}/{MANAGED_COMPONENTS}"), *extra_mounts]
        env = [
            ("HOME", "/tmp"),
            *self._reproducible_env(workspace),
            ("IDF_TARGET", step.target),
            # The component manager's downloads outlive the container (it caches in HOME otherwise).
            ("IDF_COMPONENT_CACHE_PATH", f"{posixpath.dirname(step.build_dir)}/{COMPONENT_CACHE}"),
        ]
        ca_bundle = resolve_ca_bundle(self._config, self._env)
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
            argv=("sh", WITH_CA, *argv),
            workdir=workdir or step.project_dir,
            user=user,
            mounts=tuple(mounts),
            env=tuple(env),
            labels=labels,
            devices=devices,
            group_add=tuple(_device_groups(devices)),
            network=network,
            tty=on_line is None and bool(sys.stdin and sys.stdin.isatty()),
            archives=tuple(archives),
        )
        keep = self._config.keep_containers
        if sync is not None:
            # The build dir comes back whole: the firmware's artefacts, and menuconfig's sdkconfig.
            with volume.fetched("build") as fetched:
                fetch = {volume.container_path(workspace, build_dir): fetched["build"]}
                if on_line is None:
                    code = self._engine.run_attached(spec, keep=keep, fetch=fetch)
                else:
                    code = self._engine.run(spec, on_line, keep=keep, fetch=fetch)
                volume.replace_tree(fetched["build"], build_dir, self._owner)
                volume.record(workspace, self._engine, sync, sync.installed)
                _give_to(workspace.ws_dir / "build" / volume.SYNCED, self._owner)
            return code
        try:
            if on_line is None:
                return self._engine.run_attached(spec, keep=keep)
            return self._engine.run(spec, on_line, keep=keep)
        finally:
            with contextlib.suppress(OSError):  # not empty: the user's own, left alone
                mountpoint.rmdir()

    def _check_mount(self, workspace: Workspace, image: str, user: str, labels: tuple[tuple[str, str], ...]) -> None:
        """Make sure the engine's containers see the workspace (espdock.images.visibility), once per engine and path."""
        _make_dirs_for(workspace.ws_dir / "build", self._owner)
        ensure_engine_sees(self._engine, workspace, image, user, labels)
        if (workspace.ws_dir / "build" / CHECKED).exists():
            _give_to(workspace.ws_dir / "build" / CHECKED, self._owner)

    def uses_volume(self, workspace: Workspace, image: str, user: str, labels: tuple[tuple[str, str], ...]) -> bool:
        """Whether WORKSPACE's build containers mount its volume (espdock.volume), not the workspace:
        workspace_mode volume, or auto on an engine whose containers do not see the workspace."""
        if workspace.root not in self._volume:
            mode = self._config.workspace_mode
            if mode == "auto":
                _make_dirs_for(workspace.ws_dir / "build", self._owner)
                self._volume[workspace.root] = not engine_sees(self._engine, workspace, image, user, labels)
                _give_to(workspace.ws_dir / "build" / CHECKED, self._owner)
            else:
                if mode == "mount":
                    self._check_mount(workspace, image, user, labels)
                self._volume[workspace.root] = mode == "volume"
        return self._volume[workspace.root]

    def _sync(
        self,
        workspace: Workspace,
        step_name: str,
        image: str,
        user: str,
        labels: tuple[tuple[str, str], ...],
        emptied: tuple[Path, ...] = (),
    ) -> volume.Sync | None:
        """In volume mode, the sources the volume lacks (for the build container's archives), with
        the ones deleted since the last sync, and EMPTIED (host paths), removed from it; None in
        mount mode."""
        if not self.uses_volume(workspace, image, user, labels):
            return None
        _make_dirs_for(workspace.ws_dir / "build", self._owner)
        sync = volume.prepare(self._engine, workspace, self.container_owner())
        sync = replace(sync, deleted=(*sync.deleted, *(volume.container_path(workspace, p) for p in emptied)))
        new = " (new)" if sync.fresh else ""
        sent = f"{sync.sent} file(s) sent, {len(sync.deleted)} removed"
        self._emit(StepNote(step_name, f"workspace volume {sync.volume}{new}: {sent}"))
        if sync.deleted:
            spec = RunSpec(
                image=image,
                argv=("rm", "-rf", "--", *sync.deleted),
                workdir="/",
                user=user,
                mounts=(volume.volume_mount(workspace),),
                labels=(*labels, ("io.espdock.step", "volume-sync")),
            )
            output: list[str] = []
            if self._engine.run(spec, output.append) != 0:
                raise EspdockError(
                    f"could not remove deleted sources from volume {sync.volume}: {_first_line(chr(10).join(output))}",
                    "Remove the volume (`espdock prune --volume`) and build again: it is made afresh.",
                )
        return sync

    def needs_this_machine(self, workspace: Workspace, image: str, what: str) -> None:
        """Refuse WHAT (a command that needs this machine's files or devices) in volume mode."""
        user, labels = self._container_identity(workspace, "mount-check", sweep=False)
        if self.uses_volume(workspace, image, user, labels):
            raise volume_mode_refused(what)

    def workspace_for(self, workspace: Workspace, image: str, step_label: str) -> Mount:
        """The workspace for an interactive container of IMAGE (espdock shell): the bind mount, or in
        volume mode the volume, with the sources synced first."""
        user, labels = self._container_identity(workspace, step_label, sweep=False)
        sync = self._sync(workspace, step_label, image, user, labels)
        if sync is None:
            return workspace_mount(workspace)
        mounts, archives = self._workspace_in(workspace, sync)
        spec = RunSpec(image=image, argv=("true",), workdir="/", user=user, mounts=tuple(mounts),
                       labels=(*labels, ("io.espdock.step", "volume-sync")), archives=tuple(archives))  # fmt: skip
        output: list[str] = []
        if self._engine.run(spec, output.append) != 0:
            said = _first_line(chr(10).join(output))
            raise EspdockError(f"could not send the sources to volume {sync.volume}: {said}")
        volume.record(workspace, self._engine, sync, sync.installed)
        _give_to(workspace.ws_dir / "build" / volume.SYNCED, self._owner)
        return mounts[0]

    def _workspace_in(
        self, workspace: Workspace, sync: volume.Sync | None
    ) -> tuple[list[Mount], list[tuple[str, bytes]]]:
        """The mounts and archives that give a build container the workspace: the bind mount, or
        the volume and SYNC's changed sources."""
        if sync is None:
            return [workspace_mount(workspace)], []
        return [volume.volume_mount(workspace)], [(volume.WORKSPACE_MOUNT, sync.archive)]

    def _container_identity(
        self, workspace: Workspace, step_label: str, sweep: bool
    ) -> tuple[str, tuple[tuple[str, str], ...]]:
        """The user a workspace container runs as, and its labels.

        With SWEEP, containers with the same labels are removed first: left by an espdock
        killed outright. Only a caller holding the workspace lock may sweep, since only
        then can none of them be live.
        """
        labels = {LABEL_WORKSPACE: str(workspace.root), "io.espdock.step": step_label}
        if sweep:
            self._engine.remove_containers(labels)
        return self.container_user(), tuple(labels.items())

    def container_user(self) -> str:
        uid, gid = self.container_owner()
        return f"{uid}:{gid}"

    def container_owner(self) -> tuple[int, int]:
        """Who a container writing into the workspace runs as, so its files are the invoking user's:
        that user's uid, gid, or in a rootless engine 0, 0, which is the engine's own user outside."""
        return (0, 0) if self._engine.info().rootless else self._owner

    def _install(self, workspace: Workspace, step: InstallFirmware) -> tuple[Outcome, str]:
        build_dir = workspace.ws_dir / "build" / step.package
        # A merged install/ (colcon --merge-install, which refuses an install/<package> there):
        # the firmware goes where that layout's setup files and ament index see it.
        prefix = install_prefix(workspace.ws_dir / "install", step.package)
        # What the stamp lists: the package's own files, not a merged prefix's other packages.
        installed = prefix / "share" / step.package if prefix == workspace.ws_dir / "install" else prefix
        manifest = workspace.root / step.project / "package.xml"
        stamp_file = StampFile(workspace.ws_dir / "build" / INSTALL_STAMPS)
        # The ros2 run commands' text too: an install made before them (or another version) is redone.
        source = hashlib.sha256(
            f"{listing_digest(build_dir)}\0{':'.join(step.run_depends)}\0".encode()
            + manifest.read_bytes()
            + COMMANDS_SOURCE
        )
        stamps = {step.package: source.hexdigest()}
        if stamp_file.up_to_date(stamps, {step.package: listing_digest(installed)}):
            return Outcome.CACHED, "up to date"
        stamp_file.forget(stamps)
        owner = self._owner if os.geteuid() == 0 else None
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
        _give_to(stamp_file.path, self._owner)
        return Outcome.BUILT, str(firmware.relative_to(workspace.root))


@contextmanager
def _context_dir(workspace: Workspace, spec: ImageSpec, files: Mapping[str, Path | bytes]) -> Iterator[Path]:
    """The build context: the workspace root, or a temporary directory staged from the spec
    and FILES (relative path -> a file copied there with its mode, symlinks staying links, or
    the content itself)."""
    if spec.context is None:
        yield workspace.root
        return
    with tempfile.TemporaryDirectory(prefix="espdock-context-") as tmp:
        for rel, data in spec.context:
            path = Path(tmp, rel)
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)
        for rel, source in files.items():
            path = Path(tmp, rel)
            path.parent.mkdir(parents=True, exist_ok=True)
            if isinstance(source, bytes):
                path.write_bytes(source)
                path.chmod(0o644)
            else:
                shutil.copy2(source, path, follow_symlinks=False)
        yield Path(tmp)


def runtime_install_digest(install: Path, packages: tuple[str, ...], root: Path | None = None) -> str:
    """sha256 over the paths, modes and contents of what a runtime image takes from INSTALL
    (ROOT: the workspace root, where links of a symlink install lead)."""
    digest = hashlib.sha256()
    for rel, path in runtime_files(install, packages, root).items():
        if isinstance(path, bytes):
            mode, data = 0o644, path
        else:
            mode = path.lstat().st_mode & 0o777
            data = os.readlink(path).encode() if path.is_symlink() else path.read_bytes()
        digest.update(f"{rel}\0{mode:o}\0".encode())
        digest.update(hashlib.sha256(data).digest())
    return digest.hexdigest()


def runtime_context(install: Path, step: RuntimeImage, root: Path | None = None) -> dict[str, Path | bytes]:
    """The runtime image's build context besides its Dockerfile: exactly the files
    runtime_install_digest hashed, under install/."""
    return {f"install/{rel}": path for rel, path in runtime_files(install, step.packages, root).items()}


@contextmanager
def workspace_lock(workspace: Workspace) -> Iterator[None]:
    """Hold an exclusive lock on the workspace for the duration of a build; a second build in the
    same workspace is refused naming the holder's pid and command."""
    fd = os.open(workspace.root, os.O_RDONLY)
    # Who holds it, for the error a second build gets: outside the workspace, so that espdock
    # run as root creates nothing there that the user's colcon could not write into.
    name = hashlib.sha256(str(workspace.root).encode()).hexdigest()[:16]
    holder = Path(tempfile.gettempdir()) / f"espdock-build-{name}.holder"
    try:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            raise WorkspaceError(
                f"another espdock build is running in {workspace.root}{_holder_text(holder)}",
                "Wait for it to finish, then run again.",
            ) from None
        _write_holder(holder)
        try:
            yield
        finally:
            holder.unlink(missing_ok=True)
    finally:
        os.close(fd)


def _write_holder(holder: Path) -> None:
    try:
        command = " ".join([Path(sys.argv[0]).name, *sys.argv[1:]]).encode(errors="backslashreplace")
        temporary = holder.with_name(f".{holder.name}.{os.getpid()}")
        temporary.write_bytes(f"{os.getpid()}\n".encode() + command + b"\n")
        os.replace(temporary, holder)
    except OSError:
        pass  # only the error message a second build would give loses its detail


def _holder_text(holder: Path) -> str:
    try:
        pid, _, command = holder.read_text(errors="replace").partition("\n")
    except OSError:
        return ""  # the holder has not written it yet, or has just finished
    return f" (pid {pid.strip()}: {command.strip()})" if pid.strip().isdigit() else ""


def _prepare_build_dir(build_dir: Path, target: str, defaults: str, image_key: str) -> bool:
    """Make a build dir safe to reuse.

    IDF refuses a build dir configured for another chip, and one configured in another image
    keeps that image's toolchain paths and library in CMakeCache.txt and ninja's state, so a
    new target or image key starts afresh. The sdkconfig (menuconfig's changes) survives an
    image change; an existing sdkconfig wins over sdkconfig.defaults, so it goes when the
    defaults changed, and with the target. True when it removed anything.
    """
    marker = build_dir / TARGET_MARKER
    if not marker.is_file():
        return False
    built_target, built_defaults, built_key, *_ = [*marker.read_text().split("\n"), "", "", ""]
    if built_target != target:
        shutil.rmtree(build_dir)  # only a cache
        return True
    keep = "sdkconfig" if built_defaults == defaults else None
    if built_key != image_key:
        for entry in build_dir.iterdir():
            if keep is not None and entry.name in (keep, LIBRARY_BASELINE):
                continue
            if entry.is_dir() and not entry.is_symlink():
                shutil.rmtree(entry)
            else:
                entry.unlink()
    elif keep is None:
        (build_dir / "sdkconfig").unlink(missing_ok=True)
    return built_key != image_key or keep is None


LIBRARY_BASELINE = ".espdock-library-sdkconfig"


def _library_lines(sdkconfig: Path) -> dict[str, str]:
    values = {}
    for line in sdkconfig.read_text(errors="replace").splitlines() if sdkconfig.is_file() else ():
        match = SDKCONFIG_LINE.match(line.strip())
        if match and (key := match.group(1) or match.group(3)).startswith(LIBRARY_SDKCONFIG_PREFIXES):
            values[key] = match.group(2) if match.group(1) else "n"
    return values


def _library_settings_changed(build_dir: Path, fresh: bool) -> list[str]:
    """The library-relevant options (FreeRTOS, lwIP, PSRAM, CONFIG_MICRO_ROS_*, ...) of the build
    dir's sdkconfig that differ from what it held when configured afresh from sdkconfig.defaults,
    which is what libmicroros.a was built with: menuconfig's changes that the library lacks."""
    baseline = build_dir / LIBRARY_BASELINE
    current = _library_lines(build_dir / "sdkconfig")
    if fresh or not baseline.is_file():
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
    """espdock's `idf.py fullclean`: empty STEP's build dir but for its sdkconfig (menuconfig's
    changes, which IDF's fullclean leaves in the project dir). IDF's own would delete the source
    of the managed_components mount, and the component manager would fail (EBUSY) removing the
    mountpoint; here the next build extracts it again from the download cache."""
    build_dir = workspace.ws_dir / "build" / step.package
    with workspace_lock(workspace):
        if build_dir.is_dir():
            for entry in build_dir.iterdir():
                if entry.name in ("sdkconfig", LIBRARY_BASELINE):
                    continue
                if entry.is_dir() and not entry.is_symlink():
                    shutil.rmtree(entry)
                else:
                    entry.unlink()
    return build_dir


def _defaults_digest(project: Path) -> str:
    digest = hashlib.sha256()
    for path in sorted(project.glob("sdkconfig.defaults*")):
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    return digest.hexdigest()[:16]


def _read_text(path: Path) -> str:
    try:
        return path.read_text(errors="replace")
    except OSError:
        return ""


def _make_dirs_for(directory: Path, owner: tuple[int, int]) -> None:
    """mkdir -p DIRECTORY; as root, the directories it creates belong to OWNER."""
    missing = [d for d in (directory, *directory.parents) if not d.exists()]
    directory.mkdir(parents=True, exist_ok=True)
    for created in missing:
        _give_to(created, owner)


def _give_to(path: Path, owner: tuple[int, int]) -> None:
    if os.geteuid() == 0:
        os.chown(path, *owner)


def _permission_error(exc: PermissionError) -> WorkspaceError:
    """A path espdock may not write or read, named with its owner (a rootless engine's files, say)."""
    path = Path(exc.filename) if exc.filename else None
    owner = ""
    if path is not None:
        try:
            info = path.lstat() if path.exists() or path.is_symlink() else path.parent.lstat()
            where = "" if path.exists() else ", its directory"
            owner = f" (owner uid {info.st_uid}, mode {info.st_mode & 0o7777:04o}{where})"
        except OSError:
            pass
    return WorkspaceError(
        f"permission denied on {path or 'a workspace file'}{owner}; espdock runs as uid {os.geteuid()}",
        "Give that path back to you (e.g. `sudo chown -R $(id -u):$(id -g) PATH`); files a container wrote as "
        "another user are the engine's doing: see the Engines page of espdock's docs (rootless engines).",
    )


def volume_mode_refused(what: str) -> WorkspaceNotVisible:
    """The error of a command that needs this machine's files or devices in volume mode."""
    return WorkspaceNotVisible(
        f"the build containers use the workspace's volume on an engine that does not see this machine "
        f"(workspace_mode), and {what} is on this machine",
        "Use an engine that sees this machine's files and devices for it (a local engine: unset DOCKER_HOST, "
        "or ESPDOCK_WORKSPACE_MODE=mount with an engine sharing the path); the firmware `espdock build` "
        "installed is in install/<package>/share/<package>/firmware for any flasher.",
    )


def _device_groups(devices: tuple[str, ...]) -> list[int]:
    # Serial devices belong to a group (dialout); the container user needs it to open them.
    return sorted({os.stat(d).st_gid for d in devices})


def age_text(seconds: float) -> str:
    """SECONDS as a short age: 3 min, 2 h, 5 d."""
    for unit, size in (("d", 86400), ("h", 3600), ("min", 60)):
        if seconds >= size:
            return f"{seconds / size:.0f} {unit}"
    return f"{max(seconds, 0):.0f} s"


def _installed(workspace: Workspace, step: RuntimeImage) -> RuntimeImage:
    """STEP for the packages among its own that have an install tree; none at all is an error."""
    install = workspace.ws_dir / "install"
    present = tuple(name for name in step.packages if (install / name).is_dir())
    if step.packages and not present:
        raise WorkspaceError(f"no ROS package is installed in {install}", "Run `espdock build` to build them.")
    return replace(step, packages=present)


def _container_path(workspace: Workspace, path: Path) -> str:
    """Where PATH (inside the workspace) is in a container with the workspace mounted."""
    return posixpath.join(workspace_mount(workspace).target, path.relative_to(workspace.root).as_posix())
