"""The ROS side's steps: colcon build (only what changed, by the packages' stamps), colcon test,
and the runtime image made of the install trees."""

from __future__ import annotations

import contextlib
import os
import posixpath
import re
import shlex
import shutil
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import replace
from pathlib import Path

from espdock import interrupts
from espdock.build.stamps import StampFile, TreeState, listing_digest, package_stamps
from espdock.build.steps import EnsureImage
from espdock.errors import BuildFailed, ConfigError, EspdockError
from espdock.events import Outcome, StepNote, StepOutput
from espdock.images import volume
from espdock.images.containers import (
    Containers,
    give_to,
    make_dirs_for,
    permission_error,
    volume_mode_refused,
    with_host_umask,
)
from espdock.images.keyed import KeyedImages
from espdock.images.specs import Mount, RunSpec
from espdock.images.visibility import host_paths, links_out, workspace_mount
from espdock.layout import FIRMWARE_DIR, MANIFEST_NAME, ROS_BUILD_BASE, WORKSPACE_MOUNT
from espdock.ros import rmw
from espdock.ros.cmake_inputs import file_digests, fold
from espdock.ros.colcon import (
    DEFAULTS_MOUNT,
    EGG_INFO_ORDER,
    EGG_INFO_ORDER_CMAKE,
    SETUPTOOLS_CONFIG,
    SETUPTOOLS_FORCE,
    left_out,
    make_jobs,
)
from espdock.ros.colcon_log import ColconLog, PackageState, colcon_errors, explain_failure, named, usage_error
from espdock.ros.plan import ColconBuild, RuntimeImage
from espdock.ros.runtime_tree import installed_step, runtime_context, runtime_spec
from espdock.ros.staleness import (
    Rebuild,
    build_afresh,
    colcon_outputs,
    colcon_rebuild,
    read_outside,
    text_or_empty,
)
from espdock.ros.testing import (
    ROS_TEST_LOGS,
    ColconTest,
    PackageResults,
    SourcedEnv,
    clear_results,
    read_results,
    tests_env,
)
from espdock.ros.trees import (
    LAST_ARGS,
    check_isolated_install,
    native_setup_kept,
    record_build_args,
    record_install_kinds,
    retire_container_caches,
    retire_other_underlay,
)
from espdock.workspace import Workspace, workspace_lock

# Where a build keeps what it builds afresh (old build dirs, install prefixes) until colcon has run.
ASIDE = ".espdock-afresh"

# What `espdock test` needs on this machine, which the workspace volume does not give it.
TEST_RESULTS = "the test results `espdock test` reads"


# colcon's console_start_end handler's line as a package's job ends: "Finished <<< msgs [2.1s]".
ENDED = re.compile(r"^(Finished|Failed|Aborted) +<<< \S")
# The stamp of a package built on the old install of a dependency the build left out.
ON_OLD_INSTALL = "built on an old install of a dependency"


class RosSteps:
    """Runs the ROS side's steps in containers of CONTAINERS, its images through IMAGES."""

    def __init__(self, containers: Containers, images: KeyedImages) -> None:
        self.containers = containers
        self.images = images
        # Packages this run was to build and did not: their install trees are old, so no runtime
        # image is made from them.
        self.unbuilt: set[str] = set()
        # What _build_afresh moved aside (where it was, where it is) until colcon has run.
        self._aside: list[tuple[Path, Path]] = []
        # What this run's colcon builds built so far (the failure of a later one keeps them).
        self._built: list[str] = []

    def _build_afresh(
        self,
        workspace: Workspace,
        step: ColconBuild,
        rebuild: tuple[str, ...],
        stamp_file: StampFile,
        trees: Mapping[str, TreeState],
        installed: Mapping[str, str | None],
    ) -> tuple[Path, ...]:
        """Remove what colcon would build on wrongly from REBUILD's trees (build_afresh says which),
        and say why. Returns them, for the workspace volume to remove its copies as well. They are
        moved aside (ASIDE), for _put_back when colcon then stops before building any package (an
        option it does not know): removed, a typo after `--` left those packages uninstalled."""
        base = workspace.ws_dir / ROS_BUILD_BASE
        shutil.rmtree(base / ASIDE, ignore_errors=True)  # an espdock killed outright left it
        self._aside = []
        reasons = build_afresh(workspace, step, rebuild, stamp_file, trees, installed)
        for trees, why in reasons:
            for tree in trees:
                self._set_aside(tree, base / ASIDE)
            self.containers.emit(StepNote(step.name, why))
        return tuple(tree for trees, _ in reasons for tree in trees)

    def _set_aside(self, tree: Path, aside: Path) -> None:
        """Move TREE into ASIDE (removed where it cannot be moved: another file system)."""
        if not tree.exists() and not tree.is_symlink():
            return
        kept = aside / str(len(self._aside))
        try:
            aside.mkdir(parents=True, exist_ok=True)
            tree.rename(kept)
            self._aside.append((tree, kept))
        except OSError:
            if tree.is_dir() and not tree.is_symlink():
                shutil.rmtree(tree, ignore_errors=True)
            else:
                tree.unlink(missing_ok=True)

    def _put_back(self, base: Path, restore: bool, built: Iterable[str] | None = None) -> set[str]:
        """RESTORE: move what _build_afresh set aside back where it was (colcon built nothing);
        else remove it, but for the packages whose install prefix it set aside and that this build
        did not build (BUILT: those it did; None, not known): their build dir and install prefix
        are put back in place of what the build left there, and they are returned. A setup.py
        typo, or Ctrl-C mid-compile, in a package built afresh left no install of it at all: its
        nodes, which ran before, were gone, where a plain colcon keeps the old install."""
        install = base.parent.parent / "install"
        done = None if restore or built is None else set(built)
        whole = (
            set() if done is None else {t.name for t, _ in self._aside if t.parent == install and t.name not in done}
        )
        put_back = set()
        for tree, kept in self._aside:
            if not restore and tree.name not in whole:
                continue
            with contextlib.suppress(OSError):
                if restore and (tree.exists() or tree.is_symlink()):
                    continue
                if tree.is_dir() and not tree.is_symlink():
                    shutil.rmtree(tree)  # what the failed build of it left
                elif tree.is_symlink() or tree.exists():
                    tree.unlink()
                kept.rename(tree)
                put_back.add(tree.name)
        self._aside = []
        shutil.rmtree(base / ASIDE, ignore_errors=True)
        return put_back & whole

    def colcon_build(self, workspace: Workspace, step: ColconBuild) -> tuple[Outcome, str]:
        found = colcon_rebuild(workspace, step)
        stamp_file, stamps, rebuild, trees = found.stamp_file, found.stamps, found.rebuild, found.trees
        if found.unlisted:
            stamp_file.list_outside({name: {} for name in found.unlisted})
        if not rebuild:
            return Outcome.CACHED, f"up to date ({len(stamps)} package(s))"
        check_isolated_install(workspace.ws_dir / "install")
        user, labels = self.containers.container_identity(workspace, "colcon", sweep=True)
        base = workspace.ws_dir / ROS_BUILD_BASE
        retired = retire_other_underlay(base, step.underlay, self.containers.owner) if step.underlay else None
        if retired:
            self.containers.emit(
                StepNote(
                    step.name,
                    f"removed the build dirs of {', '.join(retired)} in {ROS_BUILD_BASE}: configured against "
                    f"another ROS image than {step.underlay}, whose paths their CMake caches held",
                )
            )
        emptied = (base,) if retired is not None else ()  # in the workspace volume, its build dirs as well
        # install/ as the last build left it: what _build_afresh empties goes from the volume's too,
        # and is no change of the host's that would make the volume's another.
        listed = (
            volume_listing(workspace.ws_dir / "install")
            if self.containers.uses_volume(workspace, step.image, user, labels)
            else None
        )
        emptied += self._build_afresh(workspace, step, rebuild, stamp_file, trees, found.installed)
        sync = self.containers.sync(workspace, step.name, step.image, user, labels, emptied)
        whole = sync is not None and (sync.fresh or sync.installed != listed)
        if whole:
            # install/ is swapped for the volume's whole: every package must be built there.
            rebuild = step.packages
            if sync is not None and not sync.fresh:
                why = (
                    "the last build in the workspace volume brought back only some packages (a selection, or a failure)"
                    if sync.installed is None
                    else "install/ is not as the last build in the workspace volume left it (a build of your own?)"
                )
                self.containers.emit(StepNote(step.name, f"{why}: every package is built there again"))
        # Until this build succeeds, none of them counts as built; what the options after `--`
        # leave out (`--packages-skip`), colcon neither builds nor touches: it keeps its record
        # (`espdock run` of it refused it as "did not finish": it warns of what it was built on).
        recorded = stamp_file.read()
        told = left_out(step.colcon_args, dict(step.depends), base)
        stamp_file.forget([name for name in rebuild if name not in told], dict(step.sources), trees)
        mounted_build = posixpath.join(step.workdir, "build")
        if retired := retire_container_caches(workspace.ws_dir / "build", stamps, mounted_build):
            why = f"espdock's CMake caches from before {ROS_BUILD_BASE}, which a native colcon build refuses"
            self.containers.emit(
                StepNote(step.name, f"removed {', '.join(f'build/{name}' for name in retired)}: {why}")
            )
        if step.says_tests_off and any(name not in step.python for name in rebuild):
            self.containers.emit(
                StepNote(
                    step.name,
                    "CMake packages are configured with BUILD_TESTING=OFF: the wheels image lacks ament's lint "
                    "packages (ament_lint_auto, ...); `espdock test` builds them with their tests",
                )
            )
        spec = self._colcon_spec(workspace, step, rebuild, sync, user, labels)
        log = ColconLog(workspace.ws_dir / "log", workspace.ws_dir / "install")
        output: list[str] = []
        on_line = self._colcon_lines(workspace, step, len(rebuild), output)

        def keep_built(states: dict[str, PackageState] | None) -> list[str]:
            return self._record_built(workspace, step, found, rebuild, recorded, sync, states)

        try:
            # A native build's setup scripts chain the host's ROS; the container's chain the image's.
            with native_setup_kept(workspace.ws_dir / "install"):
                code, states = self._run_colcon(workspace, step, spec, on_line, log, sync, whole, rebuild, keep_built)
        except BaseException:
            # Ctrl-C, an engine gone: what colcon finished, its event log says (nothing read, none is
            # put back); what it did not build keeps the install it had, and the record of it.
            finished = None
            with contextlib.suppress(Exception):
                finished = _built(log.states() or {})
            restored = self._put_back(base, restore=False, built=finished)
            kept = _kept_records(workspace, recorded, rebuild, finished or (), restored)
            stamp_file.restore(kept)
            # Their install kind too, which their records above are of: a package it switched and
            # finished was otherwise taken for the other kind, and rebuilt afresh at its next edit,
            # "--symlink-install off since their last build".
            with contextlib.suppress(Exception):
                if finished and (kinds := record_install_kinds(base, finished, step.effective_args)):
                    give_to(kinds, self.containers.owner)
            _unfinished(base, restored | log.unfinished)
            raise
        if states is not None and (kinds := record_install_kinds(base, _built(states), step.effective_args)):
            give_to(kinds, self.containers.owner)
        # The options as given (those a defaults file adds, it adds again to a replay of them), of a
        # build of every package: a selection's, taken for the workspace's, had `espdock test` switch
        # every package to its --symlink-install, and `run` warn of packages nothing touched.
        every_package = step.whole or not (base / LAST_ARGS).is_file()
        if (
            states is not None
            and not step.testing
            and every_package
            and (args_file := record_build_args(base, step.colcon_args))
        ):
            give_to(args_file, self.containers.owner)
        built = keep_built(states)
        earlier, self._built = tuple(self._built), [*self._built, *built]
        self.unbuilt |= set(rebuild) - set(built)
        restored = self._put_back(base, states is None and code != 0, None if states is None else built)
        if (left := base / ASIDE).exists():
            # What a `sudo colcon build` left in the trees set aside (another user's files): removed
            # silently where it could be, and where it could not, a `rm -rf build` failed later, unsaid.
            self.containers.emit(
                StepNote(
                    step.name,
                    f"warning: could not remove {left}, the old build dirs and installs this build replaced: it "
                    f"holds files of another user (a `sudo colcon build`?); `sudo rm -rf {shlex.quote(str(left))}` "
                    "removes it",
                )
            )
        if states is not None:
            stamp_file.restore(_kept_records(workspace, recorded, rebuild, built, restored))
            _unfinished(base, {name for name in restored if name in states} | log.unfinished)
        if states is None and code != 0:
            # Nothing in build/ or install/ changed: the packages keep their records, and the
            # next build with other options rebuilds only what those change.
            stamp_file.restore({name: recorded[name] for name in rebuild if name in recorded}, rebuild)
            raise self._stopped_before_building(workspace, step, code, output)
        if code != 0:
            raise self._failed(workspace, step, code, states or {}, log, output, earlier)
        others = [n for n in rebuild if n not in built]
        # Asked for and neither built nor left out as told (`-- --packages-skip`): colcon did not
        # find it where espdock did (a package linked from outside the workspace, say).
        # colcon logs no event of a package an option ignores (`--packages-ignore`): as if not found.
        if lost := [n for n in others if n not in (states or {}) and n not in log.unselected() and n not in told]:
            rels = dict(step.sources)
            raise BuildFailed(
                f"colcon did not find {len(lost)} of the {len(rebuild)} package(s) it was to build: "
                + ", ".join(f"{n} ({posixpath.join(step.colcon_root, rels.get(n, '?'))})" for n in lost),
                "The build container sees the workspace at "
                f"{workspace_mount(workspace).target}, and where links lead out of it, their directories; in the "
                "workspace volume, nothing outside it: a package directory, or one above it, that links out of "
                "the workspace leads nowhere there. Move the package into the workspace, then build again; "
                "nothing of it was installed.",
            )
        detail = f"{len(built)} package(s) built, {len(set(stamps) - set(rebuild))} up to date"
        return Outcome.BUILT, detail + (f", {named(others, 'not built')}" if others else "")

    def _colcon_spec(
        self,
        workspace: Workspace,
        step: ColconBuild,
        rebuild: Sequence[str],
        sync: volume.Sync | None,
        user: str,
        labels: tuple[tuple[str, str], ...],
    ) -> RunSpec:
        """The container colcon builds REBUILD in: the workspace (bound, or SYNC's volume), the
        setuptools and colcon settings it needs there, and the reproducible environment."""
        base = workspace.ws_dir / ROS_BUILD_BASE
        mounts, archives = self.containers.workspace_in(workspace, sync)
        if sync is None:
            mounts += _linked(workspace, step.sources)
        env = [("HOME", "/tmp"), ("DIST_EXTRA_CONFIG", SETUPTOOLS_CONFIG), *self.containers.reproducible_env(workspace)]
        if jobs := make_jobs(self.containers.env):
            env.append(("MAKEFLAGS", jobs))
        archives.append(volume.file_archive(SETUPTOOLS_CONFIG, SETUPTOOLS_FORCE))
        _write_owned(base / EGG_INFO_ORDER, EGG_INFO_ORDER_CMAKE, self.containers.owner)
        if sync is not None:  # and into the workspace volume's build base, as the build's user's
            archives.append(volume.files_archive(workspace, base, (EGG_INFO_ORDER,), self.containers.container_owner()))
        if step.defaults_file is not None:
            # colcon reads the user's defaults from their home, which the container does not have.
            if sync is None:
                mounts.append(Mount(Path(step.defaults_file), DEFAULTS_MOUNT, read_only=True))
            else:
                archives.append(volume.file_archive(DEFAULTS_MOUNT, Path(step.defaults_file).read_bytes()))
            env.append(("COLCON_DEFAULTS_FILE", DEFAULTS_MOUNT))
        return RunSpec(
            image=step.image,
            argv=with_host_umask(step.argv(rebuild)),
            workdir=step.workdir,
            user=user,
            group_add=self.containers.shared_group(workspace),
            mounts=tuple(mounts),
            env=tuple(env),
            labels=labels,
            archives=tuple(archives),
        )

    def _colcon_lines(
        self, workspace: Workspace, step: ColconBuild, packages: int, output: list[str]
    ) -> Callable[[str], None]:
        """What takes colcon's output lines: each into OUTPUT and the step's output (host paths),
        and the count of PACKAGES done as the step's status."""
        ended = 0

        def on_line(line: str) -> None:
            nonlocal ended
            output.append(line)
            self.containers.emit(StepOutput(step.name, host_paths(line, workspace)))
            if ENDED.match(line):
                # At a terminal, the step's status line counts (colcon's own would: "[12/48 done]").
                ended += 1
                self.containers.emit(StepOutput(step.name, f"{ended} of {packages} package(s) done", status=True))

        return on_line

    def _run_colcon(
        self,
        workspace: Workspace,
        step: ColconBuild,
        spec: RunSpec,
        on_line: Callable[[str], None],
        log: ColconLog,
        sync: volume.Sync | None,
        whole: bool,
        rebuild: Sequence[str],
        keep_built: Callable[[dict[str, PackageState] | None], list[str]],
    ) -> tuple[int, dict[str, PackageState] | None]:
        """colcon's exit code and its event log's states; in the workspace volume, with what it
        built brought back to the host's install/."""
        keep = self.containers.config.keep_containers
        if sync is None:
            try:
                code = self.containers.engine.run(spec, on_line, keep=keep)
            except KeyboardInterrupt:
                # What colcon finished before Ctrl-C (or a CI job's cancel) is built: the next
                # build goes on from there, where it built all of them again.
                keep_built(log.states())
                raise
            return code, log.states()
        with volume.fetched("install", "log") as fetched:
            install, logs = workspace.ws_dir / "install", workspace.ws_dir / "log"
            paths = {volume.container_path(workspace, install): fetched["install"],
                     volume.container_path(workspace, logs): fetched["log"]}  # fmt: skip
            code = self.containers.engine.run(spec, on_line, keep=keep, fetch=paths)
            # The copy back and its record at once: a Ctrl-C between them left an install/ the
            # record did not describe, and the next build built every package again.
            with interrupts.held():
                volume.merge_logs(fetched["log"], logs, self.containers.owner)
                states = log.states()
                # A whole build that failed, or did not build all it was to (colcon found not all
                # of them, or left some out as told: `--packages-skip`), lacks some of what the
                # host has: it brings back what it built, and the host's other packages stay as
                # they were. install/ is then not the volume's, so the next build is a whole one too.
                built_here = _built(states or {})
                unbuilt = set(rebuild) - set(built_here)
                # So does a selection's (`espdock build PKG`), which the volume's install/
                # holds alone: swapped in, it removed every other package from the host's.
                merge = whole and (code != 0 or bool(unbuilt) or not step.whole)
                # The host's own entries stay: a build of the ROS packages (`--only ros`, a
                # selection) removed the firmware installs, and `espdock flash` found none.
                kept = host_added(install)
                theirs = built_here if merge else [e for e in _entries(install) if e not in kept]
                volume.replace_tree(fetched["install"], install, self.containers.owner, theirs)
                volume.record(workspace, self.containers.engine, sync, None if merge else volume_listing(install))
                give_to(workspace.ws_dir / "build" / volume.SYNCED, self.containers.owner)
        return code, states

    def _record_built(
        self,
        workspace: Workspace,
        step: ColconBuild,
        found: Rebuild,
        rebuild: Sequence[str],
        recorded: Mapping[str, object],
        sync: volume.Sync | None,
        states: dict[str, PackageState] | None,
    ) -> list[str]:
        """Record the packages colcon built (its event log's STATES) in FOUND's stamp file, and
        return them. RECORDED: the stamp file before the build."""
        stamps, trees, stamp_file = found.stamps, found.trees, found.stamp_file
        built = [name for name, state in (states or {}).items() if state is PackageState.BUILT and name in stamps]
        # A dependency this build was to build and did not (`-- --packages-skip` it, or it failed
        # under --continue-on-error): what built on it built on its old install, so it is not up
        # to date once that dependency is built.
        depends, reads = dict(step.depends), dict(step.reads)
        read_by = {name: step.build_reads(name) for name in built}
        on_old = {name: read_by[name] & (set(rebuild) - set(built)) for name in built}
        if against := [name for name in built if on_old[name]]:
            olds = sorted(set().union(*(on_old[name] for name in against)))
            self.containers.emit(
                StepNote(
                    step.name,
                    f"{', '.join(against)} built on the old install of {', '.join(olds)}, which this build "
                    "did not build: the next build builds them again",
                )
            )
        if not built:
            return built
        # What each read of the workspace outside its directory, as this build found it (a
        # volume's build dirs are on the engine: not looked at), and the stamps that counts.
        # A file it read before is taken as it was before the build (one saved during the
        # build may not be what it compiled); one new to it, as it is now.
        sources_of = dict(step.sources)
        outside = dict(found.outside)
        for name in built:
            before = found.outside[name]
            paths = read_outside(workspace, name, sources_of[name]) if sync is None else []
            now_read = file_digests(workspace.root, [path for path in paths if path not in before])
            outside[name] = {path: before.get(path) or now_read[path] for path in paths}
        sources = {name: fold(tree.digest, outside[name]) for name, tree in trees.items()}
        chained = package_stamps(sources, depends, step.stamp_images(), dict(step.settings), reads)
        now = {name: chained[name] for name in stamps}
        # Those recorded as built (their install is espdock's: `espdock run` takes it), with a
        # stamp no package has: the next build builds them again.
        recorded_stamps = {name: ON_OLD_INSTALL if on_old[name] else now[name] for name in built}
        serves = None
        if step.serves:
            served = dict(step.serves)
            images = {name: served.get(name, "") for name in sources}
            plain = package_stamps(sources, depends, images, dict(step.settings), reads)
            serves = {name: plain[name] for name in built if not on_old[name]}

        # Each one's dependencies' stamps as this build leaves them (built now, or up to
        # date): a dependency rebuilt since, or edited, is one it was built on an older
        # state of, whatever options either build was given. Those this step did not build
        # (an `espdock test` step builds the packages tested; their dependencies, built by
        # the step before, are in no stamp of its own) as recorded, or its record named
        # nothing an edit of could make it older.
        def stamp_of(dep: str) -> object:
            entry = recorded.get(dep)
            return now[dep] if dep in now else entry.get("stamp") if isinstance(entry, dict) else None

        built_on = {
            name: {dep: stamp for dep in read_by[name] if (stamp := stamp_of(dep)) is not None} for name in built
        }
        outside_built = {name: outside[name] for name in built}
        installed = {name: listing_digest(workspace.ws_dir / "install" / name) for name in stamps}
        settings = {name: digest for name, digest in step.settings if name in built}
        stamp_file.record(recorded_stamps, installed, sources_of, trees, serves, built_on, outside_built, settings)
        give_to(stamp_file.path, self.containers.owner)
        return built

    def _stopped_before_building(
        self, workspace: Workspace, step: ColconBuild, code: int, output: Sequence[str]
    ) -> EspdockError:
        """What to say of a colcon that built no package and failed (CODE): its options, or a tree it
        may not write."""
        last = next((line for line in reversed(output) if line.strip()), "no output")
        if "PermissionError" in last or "Permission denied" in last:
            # colcon may not write its log or build dirs: they belong to someone else.
            where = next((d for d in (workspace.ws_dir / n for n in ("log", "build", "install")) if d.exists()
                          and d.stat().st_uid != self.containers.owner[0]), workspace.ws_dir)  # fmt: skip
            refused = PermissionError(13, last.strip(), str(where))
            return permission_error(refused, self.containers.owner, workspace.ws_dir)
        said = usage_error(output, step.colcon_args)
        return ConfigError(
            said or f"colcon stopped before building any package (exit code {code}): {last.strip()}",
            "Check the colcon options after `--` (`colcon build --help` in `espdock shell` lists them) "
            "and colcon's defaults files; nothing was built.",
        )

    def _failed(
        self,
        workspace: Workspace,
        step: ColconBuild,
        code: int,
        states: Mapping[str, PackageState],
        log: ColconLog,
        output: Sequence[str],
        earlier: tuple[str, ...],
    ) -> EspdockError:
        """What to say of a colcon that failed (CODE) with its packages in STATES; EARLIER: what this
        run's builds before it built."""
        # A package colcon failed before its build began (a dependency's install missing, as
        # ament_python's task checks first) has no log: what colcon said of it is its output.
        logs = {
            name: (path, text_or_empty(path))
            if (path := log.package_log(name)).is_file()
            else (None, colcon_errors(output))
            for name, state in states.items()
            if state is PackageState.FAILED
        }
        # colcon's own errors (its shell hooks) are in its output; a package's build, in its log.
        texts = ("\n".join(output), *(text for _, text in logs.values()))
        denied = denied_path(texts, workspace.root, self.containers.owner[0])
        if denied is not None:
            # Another user's file in the trees colcon writes (a `sudo colcon build`): not the package's fault.
            return permission_error(
                PermissionError(13, "Permission denied", str(denied)), self.containers.owner, workspace.ws_dir
            )
        declared = {name: (depends, tests) for name, depends, tests in step.declared}
        failure = explain_failure(
            code, dict(states), logs, step.colcon_args, declared, "test" if step.testing else "build",
            frozenset(step.packages), earlier,
        )  # fmt: skip
        return BuildFailed(failure.message, failure.hint)

    def colcon_test(self, workspace: Workspace, step: ColconTest, on_line: Callable[[str], None]) -> int:
        """Run STEP (colcon test) as the invoking user, its output to ON_LINE; colcon's exit code."""
        user, labels = self.containers.container_identity(workspace, "colcon-test", sweep=False)
        if self.containers.uses_volume(workspace, step.image, user, labels):
            raise volume_mode_refused(TEST_RESULTS, firmware=False)
        mounts = [
            workspace_mount(workspace),
            *_linked(workspace, step.sources),
        ]
        env = [("HOME", "/tmp"), *self.containers.reproducible_env(workspace)]
        if step.defaults_file is not None:
            mounts.append(Mount(Path(step.defaults_file), DEFAULTS_MOUNT, read_only=True))
            env.append(("COLCON_DEFAULTS_FILE", DEFAULTS_MOUNT))
        sourced = SourcedEnv(workspace.ws_dir, step.image, tuple(env))
        caller, said = rmw.for_image(
            self.containers.engine, step.image, self.containers.config, self.containers.env, dict(labels)
        )
        if said:
            self.containers.emit(StepNote(step.name, said.removeprefix("warning: ")))
        with workspace_lock(workspace):
            key = sourced.key()
            recorded = sourced.recorded(key)
            if key is not None and recorded is None:
                sourced.forget()
            colcon_root = _container_path(workspace, workspace.ws_dir)
            make_dirs_for(workspace.ws_dir / ROS_TEST_LOGS, self.containers.owner)
            spec = RunSpec(
                image=step.image,
                argv=step.argv(source=key is not None and recorded is None),
                workdir=colcon_root,
                user=user,
                mounts=tuple(mounts),
                # Not in the sourced environment's key: a CI job's domain needs no sourcing again.
                env=(*(recorded or env), *tests_env(caller, colcon_root)),
                labels=labels,
            )
            code = self.containers.engine.run(spec, on_line, keep=self.containers.config.keep_containers)
            if key is not None and recorded is None and (written := sourced.record(key)) is not None:
                give_to(written, self.containers.owner)
            return code

    def test_packages(
        self, workspace: Workspace, step: ColconTest, on_line: Callable[[str], None]
    ) -> tuple[dict[str, PackageResults], int]:
        """Run STEP (colcon test) after a build with tests: each package's results, from this run
        only, and colcon's exit code; colcon stopping before it tested anything is an error."""
        build_base = workspace.ws_dir / ROS_BUILD_BASE
        clear_results(build_base, step.packages)
        output: list[str] = []

        def collect(line: str) -> None:
            output.append(line)
            on_line(host_paths(line, workspace))

        code = self.colcon_test(workspace, step, collect)
        found = read_results(build_base, step.packages)
        for results in found.values():  # cpplint names a case by its file: the container's path
            results.failing = [host_paths(name, workspace) for name in results.failing]
            results.erroring = {host_paths(name, workspace) for name in results.erroring}
        if code != 0 and not any(r.files for r in found.values()):
            last = next((line for line in reversed(output) if line.strip()), "no output")
            raise ConfigError(
                f"colcon test stopped before testing (exit code {code}): {last.strip()}",
                "Check the colcon options after `--`; nothing was tested.",
            )
        return found, code

    def runtime_image(self, workspace: Workspace, step: RuntimeImage) -> tuple[Outcome, str]:
        # Only what is installed and, of what this run was to build, what it built.
        installed = installed_step(
            workspace, replace(step, packages=tuple(p for p in step.packages if p not in self.unbuilt))
        )
        if missing := sorted(set(step.packages) - set(installed.packages)):
            # A build of a selection (`espdock build PKG`) leaves the others unbuilt: the image
            # holds what is installed, and says what it lacks.
            self.containers.emit(StepNote(step.name, f"not in the image (not built yet): {', '.join(missing)}"))
        step = installed
        spec = runtime_spec(workspace, step)
        install = workspace.ws_dir / "install"
        outcome, _ = self.images.ensure(
            workspace, EnsureImage(spec, cached=False), extra_context=runtime_context(install, step, workspace.root)
        )
        keyed = self.containers.engine.image(spec.tag)
        stable = self.containers.engine.image(step.stable_tag)
        if keyed is not None and (stable is None or stable.id != keyed.id):
            self.containers.engine.tag(spec.tag, step.stable_tag)
            self.containers.emit(StepNote(step.name, f"{step.stable_tag} is now {spec.tag}"))
        return outcome, f"{spec.tag}, {step.stable_tag}"


def host_added(install: Path) -> set[str]:
    """What espdock adds to INSTALL on the host, beside what the workspace volume's colcon built:
    the manifest, the firmware packages' installs."""
    firmware = {name for name in _entries(install) if (install / name / "share" / name / FIRMWARE_DIR).is_dir()}
    return {MANIFEST_NAME, *firmware}


def volume_listing(install: Path) -> str | None:
    """INSTALL's listing as the workspace volume's build left it (without host_added). With what
    the host added, every build on the volume took install/ for one another build had changed,
    and rebuilt every package."""
    return listing_digest(install, host_added(install))


def _kept_records(
    workspace: Workspace,
    recorded: Mapping[str, object],
    rebuild: Iterable[str],
    built: Iterable[str],
    restored: Iterable[str],
) -> dict:
    """The records (RECORDED, before the build) of the packages of REBUILD the build did not build
    (BUILT: those it did) whose install is as the record says: put back as it was (RESTORED), or
    untouched (never started: a dependency failed, or Ctrl-C came first). Forgotten, `espdock run`
    refused each as "did not finish ... half written". One whose own build failed keeps none:
    colcon wrote its hook files again before it failed, and may have installed part of it."""
    install, done, back = workspace.ws_dir / "install", set(built), set(restored)
    kept = {}
    for name in rebuild:
        entry = recorded.get(name)
        if name in done or not isinstance(entry, dict) or "stamp" not in entry:
            continue
        if name in back or entry.get("installed") == listing_digest(install / name):
            kept[name] = entry
    return kept


def _unfinished(base: Path, names: Iterable[str]) -> None:
    """Mark the build dirs of NAMES, put back after colcon began building them or cut short by a
    Ctrl-C colcon logged as their end, as not finished: their colcon_build.rc said 0, and
    `-- --packages-skip-build-finished` skipped the package whose build had not finished."""
    for name in names:
        with contextlib.suppress(OSError):
            (base / name / "colcon_build.rc").unlink()


def _built(states: Mapping[str, PackageState]) -> list[str]:
    return [name for name, state in states.items() if state is PackageState.BUILT]


def _entries(directory: Path) -> list[str]:
    try:
        return os.listdir(directory)
    except OSError:
        return []


def _linked(workspace: Workspace, sources: Iterable[tuple[str, str]]) -> tuple[Mount, ...]:
    """The mounts of the directories that links lead to from the packages at SOURCES (name, path
    under the colcon root), from within them, or from beside them: what colcon, and CMake, follow
    there, which the workspace's mount lacks."""
    packages = [workspace.ws_dir / rel for _, rel in sources]
    return links_out(workspace, [*packages, *_beside(workspace, packages)])


def _beside(workspace: Workspace, packages: Iterable[Path]) -> list[Path]:
    """The links to directories in the directories above PACKAGES, up to the workspace's root: a
    monorepo's `vendor -> ~/sdk` beside its packages, whose headers they include. colcon's own
    outputs and hidden entries aside."""
    above = {d for p in packages for d in p.parents if d.is_relative_to(workspace.root) and d != workspace.root}
    outputs = set(colcon_outputs(workspace))
    found = []
    for directory in sorted(above):
        try:
            with os.scandir(directory) as entries:
                links = [Path(e.path) for e in entries if e.is_symlink() and not e.name.startswith(".")]
        except OSError:
            continue
        found += [link for link in links if link not in outputs and link.is_dir()]
    return found


# Python's `PermissionError: [Errno 13] Permission denied: '/workspace/...'`, and CMake's
# `file INSTALL cannot copy file "..." to "/workspace/...": Permission denied.`
_REFUSED = "(?:Permission denied|Operation not permitted)"
_DENIED = re.compile(
    rf"{_REFUSED}: ['\"]({re.escape(WORKSPACE_MOUNT)}/[^'\"]+)['\"]"
    rf"|['\"]({re.escape(WORKSPACE_MOUNT)}/[^'\"]+)['\"][^\n]*{_REFUSED}"
    # CMake's file(INSTALL) of an unchanged file it may not chmod: the path, then on the next line
    # "Operation not permitted."
    rf"|['\"]({re.escape(WORKSPACE_MOUNT)}/[^'\"]+)['\"]:?[ \t]*\n[ \t]*{_REFUSED}"
)


def denied_path(texts: Iterable[str], root: Path, uid: int) -> Path | None:
    """The workspace path (under ROOT) a failed build's logs (TEXTS) were denied, where it (or,
    for a file of UID's, its directory), or the nearest of its directories that exists, belongs
    to another user than UID."""
    for text in texts:
        for match in _DENIED.finditer(text):
            inside = match.group(1) or match.group(2) or match.group(3)
            path = root / posixpath.relpath(inside, WORKSPACE_MOUNT)
            existing = next((p for p in (path, *path.parents) if p.exists() or p.is_symlink()), None)
            if existing is None:
                continue
            # A file of the user's own in a directory of another's: removing or replacing it is
            # the directory's to allow (setuptools' "could not delete '...'").
            for denied in (existing, existing.parent) if existing == path else (existing,):
                if denied.is_relative_to(root) and denied.lstat().st_uid != uid:
                    return denied
    return None


def _container_path(workspace: Workspace, path: Path) -> str:
    """Where PATH (inside the workspace) is in a container with the workspace mounted."""
    return posixpath.join(workspace_mount(workspace).target, path.relative_to(workspace.root).as_posix())


def _write_owned(path: Path, data: bytes, owner: tuple[int, int]) -> None:
    """PATH holding DATA, OWNER's; left alone (its time too) where it holds it already."""
    if path.is_file() and path.read_bytes() == data:
        return
    make_dirs_for(path.parent, owner)
    path.write_bytes(data)
    give_to(path, owner)
