"""The test command: build with tests, colcon test, a summary per package, results for CI."""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Annotated

import typer
from rich.text import Text

from espdock.build.manifest import record_build
from espdock.build.prepare import plan_tests
from espdock.build.prepare import workspace_packages as discover
from espdock.build.runner import Runner, stamp_files
from espdock.build.steps import Plan
from espdock.cli import complete
from espdock.cli.core import PASSED, PassThrough, WorkspaceOption, app, command, console, load, notify
from espdock.cli.prune import record_images
from espdock.cli.ui import STAMPED, Reporter
from espdock.config import in_ci, invoking_user, no_cache_registry
from espdock.errors import ConfigError, EspdockError, TestsFailed
from espdock.events import Outcome
from espdock.images.containers import volume_mode_refused
from espdock.images.keyed import unpushed_error
from espdock.images.visibility import checked_unseen
from espdock.layout import ROS_BUILD_BASE
from espdock.ros.colcon import defaults_leaving_out, passed_last_time
from espdock.ros.plan import PYTHON_BUILD_TYPES, ColconBuild
from espdock.ros.steps import TEST_RESULTS
from espdock.ros.testing import (
    HOST_TESTS_BASE,
    HOST_TESTS_TAG,
    PackageResults,
    check_test_args,
    check_testable,
    copy_results,
    host_tests_dir,
    not_left_out,
    prepare_results,
    pytest_not_asked_for,
    read_results,
    run_host_tests,
)
from espdock.workspace import Package, PackageKind, check_not_building, unknown_package


@app.command(cls=PassThrough)
@command
def test(
    ctx: typer.Context,
    packages: Annotated[
        list[str] | None,
        typer.Argument(
            help="Test only these packages (what they depend on is built too).", autocompletion=complete.packages
        ),
    ] = None,
    results: Annotated[
        Path | None,
        typer.Option(
            "--results",
            help="Copy every JUnit XML file the tests wrote here, as DIR/<package>/<file>,"
            " in place of those the last --results DIR copied.",
        ),
    ] = None,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="Show image build logs in full.")] = False,
    timestamps: Annotated[
        bool, typer.Option("--timestamps", help="Start every output line with the UTC time (for CI logs).")
    ] = False,
    locked: Annotated[
        bool | None,
        typer.Option(
            "--locked/--no-locked",
            help="Refuse to test when the rosdep lock is missing or stale (default: on in CI, CI set).",
            show_default=False,
        ),
    ] = None,
    push_cache: Annotated[
        bool,
        typer.Option(
            "--push-cache",
            help="Push keyed images the cache registry lacks, the test image too (cache_registry; CI on main).",
        ),
    ] = False,
    workspace: WorkspaceOption = None,
) -> None:
    """Build what needs building with the packages' tests, run `colcon test` in the build image and
    the host tests firmware packages declare, and summarise the results per package. Exit code 10
    when a test fails or errors.

    Options after `--` go to `colcon test` (e.g. `espdock test -- --pytest-args -k fast`)."""
    STAMPED["lines"] = timestamps
    ws, config = load(workspace)
    check_not_building(ws)
    colcon_args = check_test_args(ctx.meta.get(PASSED))
    locked = locked if locked is not None else in_ci(os.environ)
    every = discover(ws, config.ros_distro)
    by_name = {p.name: p for p in every}
    if unknown := [n for n in packages or () if n not in by_name]:
        if results is not None:  # the last run's results go as for any run refused
            prepare_results(results, invoking_user(os.environ, ws.root), [])
        raise unknown_package(unknown[0], by_name, ws)
    chosen = [by_name[n] for n in packages] if packages else list(every)
    base = ws.ws_dir / ROS_BUILD_BASE
    leaving_out = (*colcon_args, *defaults_leaving_out(ws.ws_dir, os.environ, "test", colcon_args))
    ros, skipped = not_left_out([p for p in chosen if p.kind is PackageKind.ROS], every, leaving_out, base)
    firmware = [p for p in chosen if p.kind is PackageKind.FIRMWARE]
    # Firmware packages without host tests test nothing either: a run of only them passed, with
    # no result file.
    hosted = [p for p in firmware if host_tests_dir(p.path) is not None]
    if skipped and not ros and not hosted and set(skipped) <= passed_last_time(colcon_args, skipped, base):
        # colcon's retest of what failed, once nothing did: a pass, as plain colcon's.
        console.print(
            f"nothing to test: the tests of {', '.join(skipped)} passed last time (--packages-skip-test-passed)"
        )
        return
    if results is not None:
        # Before anything refuses the run: a CI runner then never reports the last run's results.
        prepare_results(results, invoking_user(os.environ, ws.root), [p.name for p in chosen])
        if inside := next((p for p in every if results.resolve().is_relative_to(p.path.resolve())), None):
            notify(
                f"note: --results {results} is in {inside.name}'s sources: the files copied there are its sources "
                f"too, so the next `espdock build` builds {inside.name} again (a directory outside the package "
                "paths keeps them apart)"
            )
    if skipped and not ros and not hosted:
        raise ConfigError(
            f"nothing to test: the colcon options (after `--`, or a defaults file's) skip {', '.join(skipped)}",
            "Name the packages to test (`espdock test PKG...`) or skip fewer; a run that tests nothing passes nothing.",
        )
    if skipped:
        notify(f"not tested (the colcon options, after `--` or a defaults file's, skip them): {', '.join(skipped)}")
    official = config.ros_image == "official"
    check_testable({p.name: p.depends for p in ros}, "official" if official else "wheels")
    if push_cache and not config.cache_registry:
        raise no_cache_registry(os.environ)
    found: dict[str, PackageResults] = {}
    logs: dict[str, Path] = {}
    code = 0
    unpushed: list[tuple[str, str]] = []
    reporter = Reporter(console, verbose=verbose, timestamps=timestamps)
    say = reporter.line
    if ros:
        found, code, unpushed = _test_ros(ws, config, every, ros, colcon_args, locked, official, push_cache, reporter)
        logs = {name: ws.ws_dir / "log" / "latest_test" / name for name in found}
    host_base = ws.ws_dir / HOST_TESTS_BASE
    for package in firmware:
        if host_tests_dir(package.path) is None:
            continue
        say(Text(f"host tests: {package.name}", style="bold"))
        # Run by root, as the workspace's user: what they write is the user's (run_host_tests).
        failed = run_host_tests(package.name, package.path, host_base, say, invoking_user(os.environ, ws.root))
        if failed:
            raise TestsFailed(
                f"the host tests of {package.name} did not build or run (exit code {failed}); their output is above",
                f"Fix {host_tests_dir(package.path).relative_to(package.path)} and run `espdock test` again.",
            )
        found |= read_results(host_base, [package.name])
        logs[package.name] = host_base / package.name / "host_tests" / "Testing" / "Temporary" / "LastTest.log"
    if found:
        unasked = {p.name for p in ros if p.build_type in PYTHON_BUILD_TYPES and pytest_not_asked_for(p.path)}
        _render(found, ws.root, logs, say, unasked)
    _say_firmware(firmware, say)
    unwritten: EspdockError | None = None
    if results is not None:
        on_host = {p.name for p in firmware}
        bases = {n: host_base if n in on_host else ws.ws_dir / ROS_BUILD_BASE for n in found}
        written, unwritten = copy_results(found, bases, results, invoking_user(os.environ, ws.root))
        if unwritten is None:
            say(f"{written} result file(s) copied to {results}")
        else:  # the tests' outcome still decides the exit code
            say(Text.assemble(("results not copied: ", "yellow"), unwritten.message))
    # The tests' failure decides the exit code; a cache it could not publish is said with it, not
    # left to two warnings above (a main branch's job lost its cache without an error line).
    also = f" Also {unpushed_error(unpushed, config.cache_registry, '').message}." if unpushed else ""
    failing = [r for r in found.values() if not r.ok]
    if failing:
        raise TestsFailed(
            f"tests failed in {', '.join(r.package for r in failing)}: "
            + "; ".join(", ".join(r.failing[:5]) + (" ..." if len(r.failing) > 5 else "") for r in failing),
            "Each package's output and result files are listed above; fix the tests and run `espdock test` again."
            + also,
        )
    if code != 0:
        raise TestsFailed(f"colcon test failed (exit code {code})", "Its output is above." + also)
    if unwritten is not None:
        raise unwritten
    if unpushed:
        raise unpushed_error(unpushed, config.cache_registry, "The tests ran and passed")


def _test_ros(ws, config, every, ros, colcon_args, locked, official, push_cache, reporter: Reporter):
    """Build ROS packages with their tests and run colcon test: their results, colcon's exit code
    and the images --push-cache could not push."""
    # Refused in the workspace volume before the rosdep lock, which may need the network (a failed
    # `rosdep update` was said first): where the volume is chosen, or the engine last asked
    # could not see the workspace.
    if config.workspace_mode == "volume":
        raise volume_mode_refused(TEST_RESULTS, firmware=False)
    early = config.workspace_mode == "auto" and checked_unseen(ws)
    runner = _test_runner(ws, config, push_cache, reporter) if early else None
    plan, step = plan_tests(ws, config, every, ros, colcon_args, locked, official, env=os.environ, notify=notify)
    runner = runner or _test_runner(ws, config, push_cache, reporter)
    builds = tuple(s for s in plan.steps if isinstance(s, ColconBuild))
    try:
        runner.run(Plan(plan.workspace, tuple(s for s in plan.steps if s not in builds), plan.idf_images))
        # Refused before any build in the workspace volume, which the results would not leave.
        runner.containers.needs_this_machine(ws, step.image, TEST_RESULTS, firmware=False)
        results = runner.run(Plan(plan.workspace, builds, plan.idf_images))
        # The tests' build reinstalls what it rebuilds (and what a package installs only with
        # BUILD_TESTING): install/'s manifest, which CI uploads after the tests, still described the last
        # `espdock build`'s install/.
        built = any(result.outcome is not Outcome.CACHED for result in results)
        chown = runner.containers.owner if os.geteuid() == 0 else None
        record_build(plan, config.target, ws.ws_dir / "install", built, stamp_files(ws), chown)
    finally:
        reporter.close()
        record_images(ws, runner)  # a failed build's images too: they are its inputs' as they are
    reporter.line(Text(f"colcon test: {' '.join(step.packages)}", style="bold"))
    return (*runner.ros.test_packages(ws, step, reporter.line), runner.unpushed)


def _test_runner(ws, config, push_cache, reporter: Reporter) -> Runner:
    """The runner of the tests' build, on an engine that sees the workspace where that is known
    without a container (before the test image: Containers.known_to_need_this_machine)."""
    from espdock.images import bootstrap

    engine = bootstrap.ensure_engine(os.environ, notify)
    runner = Runner(engine, config, os.environ, reporter, invoking_user(os.environ, ws.root), push_cache=push_cache)
    runner.containers.known_to_need_this_machine(ws, TEST_RESULTS, firmware=False)
    return runner


def _render(
    found: dict[str, PackageResults],
    root: Path,
    logs: dict[str, Path],
    say: Callable[[str | Text], None],
    unasked: Iterable[str] = (),
) -> None:
    """The results per package; UNASKED: ament_python packages whose pytest files colcon did not
    run (pytest_not_asked_for)."""
    total = PackageResults("")
    say(Text("test results", style="bold"))
    for result in found.values():
        colour = "green" if result.ok and result.tests else "red" if not result.ok else "yellow"
        counts = (
            f"{result.tests} tests: {result.passed} passed, {result.failed} failed, "
            f"{result.errored} errored, {result.skipped} skipped"
        )
        say(Text.assemble((f"  {result.package}", "bold"), "  ", (counts, colour)))
        for name in result.failing:
            say(Text(f"    {'errored' if name in result.erroring else 'failed'}: {name}", style="red"))
        say(Text(f"    log: {logs[result.package].relative_to(root)}", style="dim"))
        for path in result.files:
            say(Text(f"    result: {path.relative_to(root)}", style="dim"))
        if result.ctest_file is not None:
            where = result.ctest_file.relative_to(root)
            say(Text(f"    ctest: {where} ({result.ctest_tests} of the tests)", style="dim"))
        if not result.files and result.ctest_file is None and result.package in unasked:
            say(
                Text(
                    "    no result files: colcon ran its test/ with unittest, which finds no pytest test: colcon runs "
                    "pytest only where setup.py names it, `tests_require=['pytest']` (as `ros2 pkg create` writes it)",
                    style="yellow",
                )
            )
        elif not result.files and result.ctest_file is None:
            say(Text("    no result files: the package has no tests colcon could find", style="dim"))
        total.tests += result.tests
        total.failed += result.failed
        total.errored += result.errored
        total.skipped += result.skipped
    say(
        f"Summary: {total.tests} tests, {total.passed} passed, {total.failed} failed, "
        f"{total.errored} errored, {total.skipped} skipped"
    )


def _say_firmware(packages: list[Package], say: Callable[[str | Text], None]) -> None:
    for package in packages:
        host = host_tests_dir(package.path)
        said = (
            f"its host tests ({host.relative_to(package.path)}) ran with the host's CMake and compiler, as "
            "plain `colcon test` runs them"
            if host is not None
            else f"it declares no host tests ({HOST_TESTS_TAG})"
        )
        say(Text(f"  {package.name}: firmware package, nothing to run in the ROS image; {said}"))
