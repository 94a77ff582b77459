"""`espdock test` with the real colcon in the real wheels image (and the official image's double):
packages written as `ros2 pkg create` writes them, with pytest, gtest and lint tests, test
dependencies through the tests' rosdep database (tests/rosdep_db).

- tested_py (ament_python): `tests_require=['pytest']`, 4 tests that pass or are skipped, one
  that fails, and ament_flake8's check (test_depend ament_flake8 and python3-pytest, resolved by
  rosdep into the lock's test part);
- tested_cpp (ament_cmake): an ament_cmake_gtest test of a header-only ring buffer, no rclcpp;
- lint_auto_cpp (ament_cmake): the template's `if(BUILD_TESTING) find_package(ament_lint_auto)`;
- linted_cpp (ament_cmake): ament's linters each through its CMake wrapper (`ament_cpplint()`).
"""

from __future__ import annotations

import json
import os
import re
import shutil
from pathlib import Path
from xml.etree import ElementTree

import pytest

from espdock.config import Config, resolve_ca_bundle
from tests.conftest import (
    REPO,
    Started,
    containers_created,
    espdock,
    in_workspace_image,
    leftover_containers,
    reader_exits_at,
)
from tests.ports import free_port
from tests.ros_official_double.build import build_double, settings
from tests.rosdep_db import environment

pytestmark = [pytest.mark.engine, pytest.mark.slow]

SUMMARY = re.compile(r"Summary: (\d+) tests?, (\d+) errors?, (\d+) failures?, (\d+) skipped")


def make_workspace(root: Path, packages: tuple[str, ...]) -> Path:
    (root / "src").mkdir(parents=True)
    for name in packages:
        shutil.copytree(REPO / "tests/ros_packages" / name, root / "src" / name)
    (root / "espdock.toml").write_text("[espdock]\n")
    return root


def junit_counts(directory: Path) -> tuple[int, int, int, int]:
    """tests, failures, errors, skipped over every JUnit file under DIRECTORY, by its suites."""
    totals = [0, 0, 0, 0]
    for path in sorted(directory.rglob("*.xml")):
        root = ElementTree.parse(path).getroot()
        for suite in [root] if root.tag == "testsuite" else root.findall("testsuite"):
            skipped = sum(int(suite.get(a, 0)) for a in ("skip", "skipped", "disabled"))
            for i, value in enumerate((suite.get("tests"), suite.get("failures"), suite.get("errors"), skipped)):
                totals[i] += int(value)
    return tuple(totals)


def colcon_test_result(root: Path, image: str) -> tuple[int, int, int, int]:
    """What `colcon test-result` itself counts in ROOT's build/: tests, failures, errors, skipped."""
    run = in_workspace_image(image, root, "colcon", "test-result", "--all")
    match = SUMMARY.search(run.stdout)
    assert match, run.stdout + run.stderr
    tests, errors, failures, skipped = (int(g) for g in match.groups())
    return tests, failures, errors, skipped


def image_tested_in(output: str) -> str:
    """The test image `espdock test` named in OUTPUT (the build image plus the test dependencies)."""
    return re.search(r"espdock/ros-jazzy(?:-official)?-test:[0-9a-f]{16}", output).group(0)


def depend_on_the_template_package(root: Path) -> None:
    """tested_cpp uses the template-made package, as a driver uses its interface package."""
    for name, old, new in (
        ("package.xml", "  <test_depend>", "  <depend>lint_auto_cpp</depend>\n  <test_depend>"),
        ("CMakeLists.txt", "find_package(ament_cmake REQUIRED)\n", "find_package(ament_cmake REQUIRED)\n"
         "find_package(lint_auto_cpp REQUIRED)\n"),
    ):  # fmt: skip
        path = root / "src/tested_cpp" / name
        path.write_text(path.read_text().replace(old, new, 1))


def test_build_skips_test_needs_then_test_builds_runs_and_reports_them(tmp_path, engine):
    root = make_workspace(tmp_path / "w", ("tested_py", "tested_cpp", "lint_auto_cpp"))
    env = {**environment(tmp_path), "ESPDOCK_STATE_DIR": str(tmp_path / "state")}
    depend_on_the_template_package(root)

    # A plain build of the template's package on the wheels image: its ament_lint_auto is not
    # needed (issue 31.4). The other two build once, below, with their tests.
    build = espdock("build", "lint_auto_cpp", cwd=root, env=env)
    assert build.returncode == 0, build.stdout[-3000:] + build.stderr
    assert build.stdout.count("BUILD_TESTING=OFF") == 1, "said once"

    # Its tests need what PyPI lacks: refused before anything runs, the official image named.
    with containers_created(root) as created:
        refused = espdock("test", cwd=root, env=env)
    assert refused.returncode == 2, refused.stdout[-2000:] + refused.stderr
    assert "lint_auto_cpp: ament_lint_auto, ament_lint_common" in refused.stderr
    assert 'ros_image = "official"' in refused.stderr
    assert created == []

    # The others: built again with their tests, tested; a failing pytest test is exit code 10.
    # lint_auto_cpp is built, not tested: as the plain build left it (its tests' ament_lint_auto
    # stopped espdock before).
    # A vendored CMake project without a package.xml: warned of once, not once per plan.
    (root / "src/vendored").mkdir()
    (root / "src/vendored/CMakeLists.txt").write_text("cmake_minimum_required(VERSION 3.8)\n")
    results = tmp_path / "results"
    tested = espdock("test", "tested_py", "tested_cpp", "--results", str(results), cwd=root, env=env)
    out = tested.stdout
    assert (out + tested.stderr).count("src/vendored is not built") == 1, out[:3000]
    assert tested.returncode == 10, out[-4000:] + tested.stderr
    events = (root / "log/latest_build/events.log").read_text()
    assert "(tested_cpp) JobEnded" in events and "(lint_auto_cpp)" not in events, "up to date, not rebuilt"
    assert "test_limits.test_nan_is_clamped_to_zero" in tested.stderr
    assert "failed: tested_py.test.test_limits.test_nan_is_clamped_to_zero" in out
    assert "tested_py  6 tests: 4 passed, 1 failed, 0 errored, 1 skipped" in out, out[-3000:]
    # colcon counts the gtest executable as a CTest test too, besides its 2 gtest cases.
    assert "tested_cpp  3 tests: 3 passed, 0 failed, 0 errored, 0 skipped" in out, out[-3000:]
    assert "Summary: 9 tests, 7 passed, 1 failed, 0 errored, 1 skipped" in out
    # The test dependencies went through rosdep into the lock's own part, not the build's.
    lock = json.loads((root / "rosdep.lock.json").read_text())
    assert lock["test"]["keys"]["ament_flake8"]["packages"] == ["ros-jazzy-ament-flake8"]
    assert lock["test"]["keys"]["python3-pytest"]["installer"] == "pip"
    # ament_lint, which the wheel leaves out, registers the linter tests' mark.
    assert lock["test"]["keys"]["ament_lint"]["packages"] == ["ros-jazzy-ament-lint"]
    assert "Unknown pytest.mark.linter" not in (root / "log/latest_test/tested_py/stdout_stderr.log").read_text()
    assert "ament_flake8" not in lock["keys"] and not any("flake8" in line for line in lock["pip"])
    # The JUnit files: one per test task, named by package; they count what colcon counts.
    files = sorted(p.relative_to(results).as_posix() for p in results.rglob("*.xml"))
    assert files == ["tested_cpp/test_results-tested_cpp-test_ring_buffer.gtest.xml", "tested_py/pytest.xml"]
    # colcon test-result's own count is the summary's; the JUnit files count it less CTest's entry.
    assert colcon_test_result(root, image_tested_in(out)) == (9, 1, 0, 1)
    assert junit_counts(results) == (8, 1, 0, 1)
    # CI uploads install/'s manifest after the tests: it describes install/ as their build left it (it
    # listed only what the plain build above had installed).
    verified = espdock("verify", "install/espdock-manifest.json", cwd=root, env=env)
    assert verified.returncode == 0, verified.stdout[-2000:] + verified.stderr
    # The test image is recorded as the workspace's and prune keeps it while the inputs use it.
    pruned = espdock("prune", "--keep", "0", "--dry-run", cwd=root, env=env)
    assert f"kept {image_tested_in(out)} (used by the current inputs)" in pruned.stdout, pruned.stdout

    # Options after `--` reach colcon test; no failure is exit code 0 and no rebuild. A defaults
    # file's skip of a package not tested: colcon, shown only tested_py, warned "ignoring unknown
    # package 'tested_cpp' in --packages-skip".
    (root / "colcon_defaults.yaml").write_text("test:\n  packages-skip:\n    - tested_cpp\n")
    again = espdock("test", "tested_py", "--", "--pytest-args", "-k", "not nan", cwd=root, env=env)
    assert again.returncode == 0, again.stdout[-3000:] + again.stderr
    assert "ignoring unknown package" not in again.stdout + again.stderr, again.stdout[-3000:]
    (root / "colcon_defaults.yaml").unlink()
    assert "tested_py  5 tests: 4 passed, 0 failed, 0 errored, 1 skipped" in again.stdout
    assert "up to date" in again.stdout

    # A plain build after them rebuilds nothing: a test build installs what it would (tests are
    # built, not installed). It rebuilt both, on every `espdock test` in turn.
    plain = espdock("build", cwd=root, env=env)
    assert plain.returncode == 0, plain.stdout[-3000:] + plain.stderr
    assert re.search(r"colcon build +cached .*up to date \(3 package\(s\)\)", plain.stdout), plain.stdout[-3000:]
    assert leftover_containers(engine, root) == []


def test_the_linters_a_package_calls_through_their_cmake_wrappers_run_on_the_wheels_image(tmp_path, engine):
    """A package naming only ament_cmake_cpplint (and the other wrappers) as test_depend failed its
    configure on the wheels image: "ament_cpplint() could not find program 'ament_cpplint'". The
    image has the wrappers' wheels (the message wheels bring them), which bring no linter."""
    root = make_workspace(tmp_path / "w", ("linted_cpp",))
    env = {**environment(tmp_path), "ESPDOCK_STATE_DIR": str(tmp_path / "state")}
    tested = espdock("test", cwd=root, env=env)
    out = " ".join(tested.stdout.split())
    assert tested.returncode == 0, tested.stdout[-4000:] + tested.stderr
    assert "linted_cpp 10 tests: 9 passed, 0 failed, 0 errored, 1 skipped" in out, out[-3000:]
    for linter in ("cppcheck", "cpplint", "flake8", "pep257", "uncrustify"):
        assert f"test_results/linted_cpp/{linter}.xunit.xml" in out, linter
    # And they check: a docstring and spaces ament's style does not have.
    script = root / "src/linted_cpp/scripts/pulse_report.py"
    script.write_text(script.read_text() + '\n\ndef words( given ):\n    """return them"""\n    return given\n')
    source = root / "src/linted_cpp/src/pulse_count.cpp"
    source.write_text(source.read_text().replace("int pulses = 0;", "int pulses=0;"))
    failed = espdock("test", cwd=root, env=env)
    said = " ".join(failed.stdout.split())
    assert failed.returncode == 10, failed.stdout[-4000:] + failed.stderr
    for linter in ("cpplint", "flake8", "pep257", "uncrustify"):
        assert f"failed: ctest {linter}" in said, said[-3000:]
    # A case named by its file names it as the user opens it, not as the container saw it.
    assert f"failed: linted_cpp.cpplint.whitespace/operators [4] ({root}/src/linted_cpp/src/pulse_count.cpp:20)" in said


def test_the_tests_build_keeps_the_symlink_install_the_last_build_made(tmp_path, engine):
    """`espdock build -- --symlink-install`, then `espdock test`: the test's builds were plain
    ones, so the dependencies were built again and install/ became copies (source edits no longer
    reached the nodes), where `colcon test` leaves install/ alone. Its `--packages-skip` is not
    kept: a package it skipped stayed unconfigured for tests, and its 3 tests ran as 0, green."""
    root = make_workspace(tmp_path / "w", ("tested_py", "tested_cpp", "lint_auto_cpp"))
    env = {**environment(tmp_path), "ESPDOCK_STATE_DIR": str(tmp_path / "state")}
    depend_on_the_template_package(root)
    built = espdock("build", "--", "--symlink-install", "--packages-skip", "tested_cpp", cwd=root, env=env)
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr
    linked = [root / f"install/{name}/share/{name}/package.xml" for name in ("lint_auto_cpp", "tested_py")]
    assert all(path.is_symlink() for path in linked)

    tested = espdock("test", "tested_py", "tested_cpp", cwd=root, env=env)
    assert tested.returncode == 10, tested.stdout[-3000:] + tested.stderr  # tested_py's failing test
    said = tested.stdout + tested.stderr
    assert "building with the options of the last espdock build: --symlink-install" in said
    assert "not with its --packages-skip tested_cpp: the packages tested are built with their tests" in said
    assert re.search(r"colcon build: dependencies +cached .*up to date", tested.stdout), tested.stdout[-3000:]
    assert "tested_cpp  3 tests: 3 passed" in tested.stdout, tested.stdout[-3000:]
    assert all(path.is_symlink() for path in linked), "install/ is as the last build made it"
    assert leftover_containers(engine, root) == []


def test_the_tests_build_keeps_a_selection_s_own_symlink_install(tmp_path, engine):
    """`espdock build P -- --symlink-install` after a plain whole build (a selection, as espdock's
    own hint gives one where a package cannot build): `espdock test P` took the whole build's
    options, removed P's build dir and install prefix, and made it copies again."""
    root = make_workspace(tmp_path / "w", ("tested_py", "beacon_nodes"))
    env = {**environment(tmp_path), "ESPDOCK_STATE_DIR": str(tmp_path / "state")}
    assert espdock("build", cwd=root, env=env).returncode == 0
    linked = root / "install/tested_py/share/tested_py/package.xml"
    selected = espdock("build", "tested_py", "--", "--symlink-install", cwd=root, env=env)
    assert selected.returncode == 0 and linked.is_symlink(), selected.stdout[-3000:] + selected.stderr
    # A main branch's job, its cache registry down: the failed tests decide the exit code, and the
    # error says the cache went unpublished as well (it was two warnings among the build's lines).
    registry = f"127.0.0.1:{free_port()}"
    tested = espdock("test", "tested_py", "--push-cache", cwd=root, env={**env, "ESPDOCK_CACHE_REGISTRY": registry})
    assert tested.returncode == 10, tested.stdout[-3000:] + tested.stderr  # tested_py's failing test
    said = " ".join((tested.stdout + tested.stderr).split())
    assert "building with --symlink-install, as the last builds of the packages tested were" in said, said
    assert linked.is_symlink(), "install/ is as the last build of the package made it"
    assert "removed the build dirs" not in said
    failed = " ".join(tested.stderr.split())
    assert re.search(rf"Also --push-cache: \d+ image\(s\) not pushed to {re.escape(registry)}: ", failed), failed


def test_a_symlink_install_the_defaults_file_turns_on_leaves_the_plain_build_up_to_date_after_the_tests(
    tmp_path, engine
):
    """symlink-install in the user's colcon defaults file: `espdock test` gave the last build's
    --symlink-install on the command line too, which made its stamps another build's, and each of
    `espdock test` and `espdock build` rebuilt what the other had built."""
    root = make_workspace(tmp_path / "w", ("tested_py",))
    defaults = tmp_path / "defaults.yaml"
    defaults.write_text("build:\n  symlink-install: true\n")
    env = {**environment(tmp_path), "ESPDOCK_STATE_DIR": str(tmp_path / "state"), "COLCON_DEFAULTS_FILE": str(defaults)}
    built = espdock("build", cwd=root, env=env)
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr
    assert (root / "install/tested_py/share/tested_py/package.xml").is_symlink()
    tested = espdock("test", cwd=root, env=env)
    assert tested.returncode == 10, tested.stdout[-3000:] + tested.stderr  # tested_py's failing test
    planned = espdock("build", "--dry-run", cwd=root, env=env)
    assert planned.returncode == 0, planned.stdout[-3000:] + planned.stderr
    assert "now: up to date (1 package(s))" in planned.stdout, planned.stdout[-3000:]
    again = espdock("test", cwd=root, env=env)
    assert re.search(r"colcon build: with tests +cached", again.stdout), again.stdout[-3000:]
    # Given on the command line as well: the test builds with it too, as the build did.
    both = espdock("build", "--", "--symlink-install", cwd=root, env=env)
    assert both.returncode == 0, both.stdout[-3000:] + both.stderr
    espdock("test", cwd=root, env=env)
    planned = espdock("build", "--dry-run", "--", "--symlink-install", cwd=root, env=env)
    assert "now: up to date (1 package(s))" in planned.stdout, planned.stdout[-3000:]
    assert leftover_containers(engine, root) == []


def test_ctrl_c_or_a_closed_output_during_the_tests_ends_them_and_leaves_no_container(tmp_path, engine):
    root = make_workspace(tmp_path / "w", ("tested_py",))
    env = environment(tmp_path)
    # Rerun until a failure that never comes: the tests keep running until interrupted. The
    # build before them prints its own lines; "colcon test:" comes once it is done.
    until = ("--", "--pytest-args", "-k", "not nan", "--retest-until-fail", "500")
    run = Started(root, "test", *until, env=env)
    code, took = run.interrupt_on("colcon test: tested_py", timeout=300)
    assert code == 130, run.output()
    assert took < 15, took
    assert leftover_containers(engine, root) == []

    # `espdock test | grep -m1 ...`: the reader exits at its first match. espdock ends quietly,
    # as a closed pipe ends a command (128 + SIGPIPE), not as a bug of its own.
    code, err = reader_exits_at(root, "colcon test: tested_py", "test", *until, env={**env, "TMPDIR": str(tmp_path)})
    assert code == 141, err
    assert "bug" not in err and not list(tmp_path.glob("espdock-bug-*")), err
    assert leftover_containers(engine, root) == []


@pytest.fixture(scope="module")
def official_double(engine) -> dict[str, str]:
    config = Config()
    tag = build_double(engine, resolve_ca_bundle(config, os.environ), lambda line: None)
    return settings(tag)


def test_the_official_image_runs_the_lint_and_pytest_tests_as_colcon_does(tmp_path, engine, official_double):
    """After a build on the wheels image, as a user who switches does: CMake kept that image's
    caches (BUILD_TESTING=OFF, its gtest sources' paths), and the tests failed to build."""
    root = make_workspace(tmp_path / "w", ("tested_py", "tested_cpp"))
    wheels = espdock("build", cwd=root, env=environment(tmp_path))
    assert wheels.returncode == 0, wheels.stdout[-3000:] + wheels.stderr
    env = {**environment(tmp_path), **official_double}
    build = espdock("build", cwd=root, env=env)
    assert build.returncode == 0, build.stdout[-3000:] + build.stderr
    assert "BUILD_TESTING=OFF" not in build.stdout, "the official image builds as colcon does"
    cache = (root / "build/espdock-ros/tested_cpp/CMakeCache.txt").read_text()
    assert "BUILD_TESTING:BOOL=ON" in cache and "/opt/espdock/venv" not in cache
    assert "removed the build dirs of tested_cpp, tested_py in build/espdock-ros" in build.stdout
    tested = espdock("test", "--", "--pytest-args", "-k", "not nan", cwd=root, env=env)
    assert tested.returncode == 0, tested.stdout[-4000:] + tested.stderr
    assert "tested_py  5 tests: 4 passed, 0 failed, 0 errored, 1 skipped" in tested.stdout
    assert "tested_cpp  3 tests: 3 passed" in tested.stdout
    lock = json.loads((root / "rosdep.lock.json").read_text())
    assert lock["test"]["keys"]["ament_flake8"] == {"installer": "apt", "packages": ["ros-jazzy-ament-flake8"]}


def test_firmware_host_tests_run_and_count_in_the_summary_exit_code_and_results(tmp_path):
    """A firmware package's declared host tests run under `espdock test` as under plain `colcon
    test`; one without host tests has nothing to run. Firmware only: no ROS package is needed."""
    root = tmp_path / "w"
    for package in (REPO / "tests/firmware_packages/blink_fw", REPO / "firmware/led_strip_node"):
        shutil.copytree(package, root / "src" / package.name)
    (root / "espdock.toml").write_text("[espdock]\n")
    host = root / "src/blink_fw/test/host/CMakeLists.txt"
    passing = host.read_text()
    # A test the program does not know: it exits 2, a failing CTest test.
    host.write_text(passing + "add_test(NAME blinks_forever COMMAND test_blink_pattern blinks_forever)\n")
    results = tmp_path / "results"

    tested = espdock("test", "--results", str(results), cwd=root)
    out = tested.stdout
    assert tested.returncode == 10, out[-3000:] + tested.stderr
    assert "blink_fw  3 tests: 2 passed, 1 failed, 0 errored, 0 skipped" in out, out[-3000:]
    assert "failed: blinks_forever" in out
    assert "Summary: 3 tests, 2 passed, 1 failed, 0 errored, 0 skipped" in out
    assert "blinks_forever" in tested.stderr
    assert "led_strip_node: firmware package" in out and "declares no host tests (espdock_host_tests)" in out
    files = sorted(p.relative_to(results).as_posix() for p in results.rglob("*.xml"))
    assert files == ["blink_fw/test_results-blink_fw-host_tests.xml"]
    suite = ElementTree.parse(results / files[0]).getroot()
    assert (suite.tag, suite.get("tests"), suite.get("failures")) == ("testsuite", "3", "1")

    host.write_text(passing)
    again = espdock("test", "blink_fw", "--timestamps", cwd=root)
    assert again.returncode == 0, again.stdout[-3000:] + again.stderr
    assert "Summary: 2 tests, 2 passed, 0 failed, 0 errored, 0 skipped" in again.stdout
    # For CI logs every line is timed: the tests' own output and the summary too.
    untimed = [line for line in again.stdout.splitlines() if not re.match(r"\d\d:\d\d:\d\d ", line)]
    assert not untimed, untimed[:5]
