"""What colcon said of a run: a usage error for the options given after `--`, each package's state
in its event log (log/<run>/events.log), and why a failed run failed, with what to do about it."""

from __future__ import annotations

import ast
import os
import re
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

from espdock.images.engine import KILLED
from espdock.layout import ROS_BUILD_BASE

_QUOTED = re.compile(r"'(-[^']*)'|: (--?[\w-]+)")


def usage_error(output: Iterable[str], args: Iterable[str]) -> str | None:
    """What colcon's usage error in OUTPUT (`colcon build: error: ...`) says of the options ARGS
    given after `--`: argparse blames the option before an unknown one (espdock's own
    --event-handlers); None when OUTPUT has no usage error."""
    line = next((line for line in output if "colcon build: error:" in line), None)
    if line is None:
        return None
    said = line.split("colcon build: error:", 1)[1].strip()
    given = {a.split("=", 1)[0] for a in args if a.startswith("-")}
    unknown = [m.group(1) or m.group(2) for m in _QUOTED.finditer(said) if (m.group(1) or m.group(2)) in given]
    if unknown:
        return f"colcon build does not accept {unknown[0]} (given after `--`)"
    return f"colcon build refused its options: {said[:300]}"


class PackageState(StrEnum):
    """What colcon did with a package in one run (its summary's words)."""

    BUILT = "built"
    FAILED = "failed"
    ABORTED = "aborted"  # stopped because another package failed
    NOT_PROCESSED = "not processed"  # never started: colcon stopped, or a dependency failed


_EVENT = re.compile(r"^\[[0-9.]+\] \((?P<job>[^)]*)\) (?P<event>\w+): (?P<data>.*)$")


def parse_events(lines: Iterable[str]) -> dict[str, PackageState]:
    """Each package's state from colcon's log/<run>/events.log (colcon-output's event_log handler).

    Packages colcon was not asked to build (JobUnselected) are left out.
    """
    states: dict[str, PackageState] = {}
    for line in lines:
        match = _EVENT.match(line.rstrip("\n"))
        if not match or match.group("job") == "-":
            continue
        job, event = match.group("job"), match.group("event")
        if event == "JobQueued":
            states.setdefault(job, PackageState.NOT_PROCESSED)
        elif event == "JobEnded":
            try:
                rc = ast.literal_eval(match.group("data")).get("rc")
            except (ValueError, SyntaxError, AttributeError):
                rc = None
            if rc == 0:
                states[job] = PackageState.BUILT
            elif rc == "SIGINT":  # colcon-core's SIGINT_RESULT: aborted, not failed
                states[job] = PackageState.ABORTED
            else:
                states[job] = PackageState.FAILED
        elif event == "JobSkipped":
            states[job] = PackageState.NOT_PROCESSED
    return states


def unselected(lines: Iterable[str]) -> set[str]:
    """The packages colcon found and left out as told (JobUnselected: `--packages-skip` and the like)."""
    found = set()
    for line in lines:
        match = _EVENT.match(line.rstrip("\n"))
        if match and match.group("event") == "JobUnselected":
            try:
                found.add(str(ast.literal_eval(match.group("data")).get("identifier")))
            except (ValueError, SyntaxError, AttributeError):
                continue
    return found


# colcon's executors' word, in its logger_all.log, for a Ctrl-C that came while jobs ran (the
# sequential one names the job: "run_until_complete 'pkg' was interrupted").
_INTERRUPTED = re.compile(r"run_until_complete\b.* was interrupted")


class ColconLog:
    """colcon's log of the run about to start, told apart from earlier runs' by latest_build;
    INSTALL_BASE, the install/ it builds into."""

    def __init__(self, log_base: Path, install_base: Path) -> None:
        self.latest = log_base / "latest_build"
        self._before = self._target()
        self._install = install_base
        self._started = time.time()
        # The packages colcon's event log says it built, which it had not finished (states()).
        self.unfinished: set[str] = set()

    def _target(self) -> str | None:
        return os.path.realpath(self.latest) if self.latest.exists() else None

    def states(self) -> dict[str, PackageState] | None:
        """Each package's state in this run; None when colcon wrote no log (it stopped before
        building anything, e.g. on an option it does not know)."""
        target = self._target()
        if target is None or target == self._before:
            return None
        try:
            states = parse_events((self.latest / "events.log").read_text(errors="replace").splitlines())
        except OSError:
            return None
        if self._interrupted():
            # A Ctrl-C that lands in a job's own Python code (not in the event loop's wait)
            # ends it through a `finally` that logs "JobEnded rc 0": colcon's override to
            # SIGINT comes after the event. Taken for built, the package's next build said "up
            # to date" over the install it never wrote. Every build task's last act is its
            # runtime-dependencies file (colcon-core's create_file_with_runtime_dependencies):
            # one not written by this run is of a job that did not finish.
            self.unfinished = {
                name for name, state in states.items() if state is PackageState.BUILT and not self._finished(name)
            }
            states.update(dict.fromkeys(self.unfinished, PackageState.ABORTED))
        return states

    def _interrupted(self) -> bool:
        try:
            return bool(_INTERRUPTED.search((self.latest / "logger_all.log").read_text(errors="replace")))
        except OSError:
            return False

    def _finished(self, name: str) -> bool:
        """Whether this run wrote NAME's runtime-dependencies file. The build container's clock is
        espdock's: the install it reads after an interruption is the bind-mounted one (the
        workspace volume's brings back nothing then)."""
        try:
            written = (self._install / name / "share" / "colcon-core" / "packages" / name).stat().st_mtime
        except OSError:
            return False
        return written >= self._started

    def unselected(self) -> set[str]:
        """The packages this run found but was told to leave out (none when it wrote no log)."""
        if self._target() in (None, self._before):
            return set()
        try:
            return unselected((self.latest / "events.log").read_text(errors="replace").splitlines())
        except OSError:
            return set()

    def package_log(self, package: str) -> Path:
        return self.latest / package / "stdout_stderr.log"


# Output of a package's build that says a dependency is missing, not that the package is wrong.
_MISSING = (
    re.compile(r'Could not find a package configuration file provided by\s+"(?P<dep>[\w.-]+)"'),
    re.compile(r"By not providing \"Find(?P<dep>[\w.-]+)\.cmake\""),
    # find_package_handle_standard_args's form (a Find module's: OpenSSL, Boost, ...).
    re.compile(r"Could NOT find (?P<dep>[\w.-]+)"),
    re.compile(r"No module named '(?P<dep>[\w.]+)'"),
    re.compile(r"Check that the following packages have been built:\s*\n- (?P<dep>[\w.-]+)"),
)


# colcon's logger on the console: "[0.283s] ERROR:colcon.colcon_ros.task.ament_python.build:...".
_COLCON_ERROR = re.compile(r"^(\[[0-9.]+s\] )?ERROR:colcon")


def colcon_errors(output: Iterable[str]) -> str:
    """colcon's own errors in its console OUTPUT (an ERROR: line and the list lines under it),
    without the packages' interleaved output: what it says of a package it failed before the
    package's build began, which then has no log."""
    kept: list[str] = []
    inside = False
    for line in output:
        inside = bool(_COLCON_ERROR.match(line)) or (inside and line.startswith(("- ", "Check that")))
        if inside:
            kept.append(line)
    return "\n".join(kept)


def missing_dependencies(output: str) -> tuple[str, ...]:
    """What a failed package's OUTPUT says it could not find, in order, without repeats."""
    found: dict[str, None] = {}
    for pattern in _MISSING:
        for match in pattern.finditer(output):
            found.setdefault(match.group("dep"), None)
    return tuple(found)


@dataclass(frozen=True)
class ColconFailure:
    """A failed colcon run, as a message and a hint that say what failed and what to do."""

    message: str
    hint: str


# What ament_cmake's symlink install says where a copying build left a directory.
SYMLINK_OVER_COPY = "because existing path cannot be removed: Is a directory"
# The wheels image's Fast DDS CMake files, which rcl's (through rmw_implementation's) load: they
# need OpenSSL and name libraries at the wheels' manylinux build paths, so no C or C++ code
# linking rcl (rcl, rclcpp, rcl_action, ...) configures there; its rclpy uses the libraries alone.
WHEELS_FASTDDS_CMAKE = re.compile(r"/opt/espdock/venv/share/(fastrtps|fastdds|rmw_fastrtps\w*)/cmake/")


# gcc's and clang's word for a compiler process the kernel killed (its OOM killer, for want of memory).
COMPILER_KILLED = re.compile(r"Killed signal terminated program|virtual memory exhausted|signal: killed")
# What a build runs at once, and how to run fewer (colcon-cmake runs a compile per core).
FEWER_AT_ONCE = (
    "build fewer things at once: `MAKEFLAGS=-j2 espdock build` (compiles per package) and `-- --parallel-workers 1` "
    "(packages at once), or give the machine (Docker Desktop's VM) more memory"
)


# Above this many, a count says a state's packages, not their names: a failure in a workspace of
# dozens named every one (the summary's cell wrapped into forty lines, then said it all again).
NAMED = 5


def named(names: list[str], state: str) -> str:
    """`3 built (a b c)`, or beyond NAMED of them, `46 not processed`."""
    return f"{len(names)} {state} ({' '.join(names)})" if len(names) <= NAMED else f"{len(names)} {state}"


def explain_failure(
    code: int,
    states: Mapping[str, PackageState],
    logs: Mapping[str, tuple[Path | None, str]],
    args: tuple[str, ...],
    declared: Mapping[str, tuple[frozenset[str], frozenset[str]]] | None = None,
    command: str = "build",
    ours: frozenset[str] = frozenset(),
    earlier: tuple[str, ...] = (),
) -> ColconFailure:
    """Why colcon exited with CODE: STATES from its event log, LOGS (failed package -> its log
    file, None where colcon failed it before its build began and wrote none, and its output), ARGS
    the options given after `--`, DECLARED (package -> what its package.xml names, and which of
    those only as test_depend), OURS the workspace's packages. COMMAND: the espdock command whose
    build it was (`espdock test`'s configures the tests, which a plain build does not compile). EARLIER:
    the packages an earlier colcon build of the same run built (`espdock test` builds the dependencies
    of the packages tested first)."""
    by_state: dict[PackageState, list[str]] = {}
    for name, state in sorted(states.items()):
        by_state.setdefault(state, []).append(name)
    failed = by_state.get(PackageState.FAILED, [])
    counts = ", ".join(named(names, state.value) for state, names in sorted(by_state.items()))
    lines = [f"colcon build failed (exit code {code}) in {', '.join(failed) or 'no package'}: {counts or 'none ran'}"]
    hints = []
    own = []
    killed = not failed and code == KILLED
    if killed:
        lines = [
            f"colcon build was killed (exit code {code}, SIGKILL) before any package failed: {counts or 'none ran'}"
        ]
        hints.append(
            "Something killed its container: `docker kill` or `docker rm -f`, the engine stopping, or the kernel's OOM "
            f"killer for want of memory (`dmesg` says); if that was it, {FEWER_AT_ONCE}."
        )
    for name in failed:
        path, output = logs.get(name, (None, ""))
        log = path if path is not None else "none of its own (colcon's output above says why)"
        missing = missing_dependencies(output)
        if COMPILER_KILLED.search(output):
            lines.append(f"  {name}: its compiler was killed (out of memory?); log: {log}")
            hints.append(
                f"The kernel's OOM killer likely stopped a compiler of {name} for want of memory: {FEWER_AT_ONCE}."
            )
        elif WHEELS_FASTDDS_CMAKE.search(output):
            lines.append(f"  {name}: the wheels image's Fast DDS CMake files failed in its configure; log: {log}")
            hints.append(
                f"{name} links rcl (directly or through rclcpp, rcl_action, ...), whose CMake files on the wheels "
                "image load Fast DDS's, which need OpenSSL and libraries the image does not have: the wheels serve "
                'Python nodes (rclpy) only. Build C and C++ nodes on the official image (ros_image = "official"), '
                f"or leave {name} out (COLCON_IGNORE, `-- --packages-skip {name}`)."
            )
        elif missing:
            lines.append(f"  {name}: could not find {', '.join(missing)}; log: {log}")
            hints.append(_missing_hint(name, missing, *(declared or {}).get(name, (frozenset(), frozenset())), ours))
        elif SYMLINK_OVER_COPY in output:
            # ament_cmake's symlink install cannot replace what a copying install left in the build
            # dir (colcon as well): the package is fine, its build dir is of the other kind.
            lines.append(f"  {name}: its build dir is from a build without --symlink-install; log: {log}")
            hints.append(
                f"Remove {ROS_BUILD_BASE}/{name} (only a cache; colcon cannot switch it to --symlink-install in "
                "place) and build again."
            )
        else:
            lines.append(f"  {name}: its own build failed; log: {log}")
            own.append(name)
    if own:
        hints.insert(0, f"Fix {' and '.join(own)} (the error is in the log above) and run `espdock {command}` again.")
    stopped = by_state.get(PackageState.ABORTED, []) + by_state.get(PackageState.NOT_PROCESSED, [])
    if stopped and "--continue-on-error" not in args and command == "build" and not killed:
        hints.append(
            f"{len(stopped)} package(s) were not built because colcon stopped at the failure; "
            "`espdock build -- --continue-on-error` builds every package that does not depend on a failed one."
        )
    built = [*earlier, *by_state.get(PackageState.BUILT, [])]
    hints.append(
        f"The {len(built)} package(s) that built are kept: the next build starts from them."
        if built
        else "No package was built by this run."
    )
    return ColconFailure("\n".join(lines), " ".join(hints))


def _missing_hint(
    name: str, missing: tuple[str, ...], declared: frozenset[str], test_only: frozenset[str], ours: frozenset[str]
) -> str:
    """What to do about a package that could not find MISSING, given what its package.xml names
    and the workspace's packages (OURS)."""
    shown = ", ".join(missing)
    leave_out = f"leave {name} out (COLCON_IGNORE, `-- --packages-skip {name}`, or select other packages)"
    if all(dep in ours for dep in missing):
        # A package of the workspace that was never built: one this build's options left out.
        return (
            f"{shown} {'is a package' if len(missing) == 1 else 'are packages'} of this workspace that {name} "
            f"depends on and that {'is' if len(missing) == 1 else 'are'} not built (left out by the options after "
            f"`--`?): build {'it' if len(missing) == 1 else 'them'} too (`espdock build {name}` builds what it "
            f"depends on), or {leave_out}."
        )
    if all(dep in test_only for dep in missing):
        return (
            f"{name} needs {shown} only for its tests (test_depend in its package.xml), which this build "
            "configured: build without them (`-- --cmake-args -DBUILD_TESTING=OFF`), or test on an image that "
            'has them (ros_image = "official").'
        )
    if all(dep in declared for dep in missing):
        return (
            f"{name}'s package.xml declares {shown}, but the build image does not provide it: use an image that "
            f'has it (ros_image = "official"), or {leave_out}.'
        )
    return (
        f"{name} needs {shown}, which the build image does not provide: declare it in "
        f"{name}'s package.xml, use an image that has it, or {leave_out}."
    )
