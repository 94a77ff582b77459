"""`espdock test` without colcon: its options, the refusals before anything runs, reading and
collecting result files, and the test image made from the lock's test part."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from espdock.build.manifest import write_report
from espdock.build.steps import EnsureImage, ImageSpec, Plan
from espdock.errors import ConfigError, DependencyError
from espdock.ros.colcon import NONE_LEFT_OUT
from espdock.ros.plan import ColconBuild
from espdock.ros.testdeps import image_for_tests, with_test_image
from espdock.ros.testing import (
    SOURCED_DUMP,
    SOURCED_ENV,
    ColconTest,
    SourcedEnv,
    check_test_args,
    check_testable,
    collect_results,
    forget_collected,
    host_test_steps,
    host_tests_failed,
    read_results,
)
from espdock.workspace import Workspace

ME = (os.getuid(), os.getgid())
PYTEST_XML = """<?xml version="1.0" encoding="utf-8"?><testsuites><testsuite name="pytest" errors="0" failures="1"
skipped="1" tests="4" time="0.1"><testcase classname="p.test.test_a" name="test_ok" time="0.001"/><testcase
classname="p.test.test_a" name="test_bad" time="0.001"><failure message="assert 1 == 0">x</failure></testcase>
<testcase classname="p.test.test_a" name="test_later"><skipped message="later"/></testcase><testcase
classname="p.test.test_a" name="test_two"/></testsuite></testsuites>"""
GTEST_XML = """<?xml version="1.0" encoding="UTF-8"?><testsuites tests="2" failures="0" disabled="0" errors="0"
name="AllTests"><testsuite name="Ring" tests="2" failures="0" disabled="0" skipped="0" errors="0"><testcase
name="a" status="run" classname="Ring"/><testcase name="b" status="run" classname="Ring"/></testsuite></testsuites>"""


def test_colcon_test_options_follow_builds_rules_and_results_stay_where_espdock_reads_them():
    assert check_test_args(("--pytest-args", "-k", "fast", "--retest-until-fail", "3")) == (
        "--pytest-args", "-k", "fast", "--retest-until-fail", "3",
    )  # fmt: skip
    for refused in ("--test-result-base", "--test-result-b=x", "--build-base", "--packages-select", "--event-handlers"):
        with pytest.raises(ConfigError):
            check_test_args((refused, "x"))
    with pytest.raises(ConfigError, match="nothing after"):
        check_test_args(())


def test_tests_that_need_what_pypi_lacks_are_refused_on_the_wheels_image_only():
    needs = {"cpp": frozenset({"ament_cmake", "ament_lint_auto", "ament_lint_common"}), "py": frozenset({"pytest"})}
    with pytest.raises(DependencyError) as err:
        check_testable(needs, "wheels")
    assert "cpp: ament_lint_auto, ament_lint_common" in err.value.message and "py" not in err.value.message
    assert 'ros_image = "official"' in err.value.hint
    assert "`espdock test -- --packages-skip cpp`" in err.value.hint, err.value.hint
    check_testable(needs, "official")
    check_testable({"py": frozenset({"ament_flake8", "ament_cmake_gtest"})}, "wheels")


def test_colcon_test_is_not_told_to_skip_what_espdock_already_left_out():
    """`espdock test -- --packages-skip tmpl_py cpp_pkg`: colcon, given only the packages espdock
    chose, warned "ignoring unknown package" of each one it was told to skip."""
    told = ("--packages-skip", "b", "c", "--retest-until-fail", "2", "--packages-skip-test-p")
    step = ColconTest(image="i", packages=("a",), sources=(("a", "src/a"),), colcon_args=told)
    argv = step.argv(source=False)
    assert argv[argv.index("--packages-select") :] == (
        "--packages-select", "a", "--retest-until-fail", "2", *NONE_LEFT_OUT,
    )  # fmt: skip
    # Each given with no names: a defaults file's are not passed on either (espdock applied them).
    assert "--packages-skip" in NONE_LEFT_OUT and "--packages-skip-test-passed" not in NONE_LEFT_OUT


def test_colcon_test_gets_the_options_as_arguments_not_shell_text():
    step = ColconTest(image="i", packages=("a", "b"), sources=(("a", "src/a"), ("b", "src/b")),
                      colcon_args=("--pytest-args", "-k", "x; rm -rf /"))  # fmt: skip
    argv = step.argv()
    assert argv[:2] == ("sh", "-c") and "x; rm" not in argv[2]
    assert argv[argv.index("--packages-select") :] == (
        "--packages-select",
        "a",
        "b",
        "--pytest-args",
        "-k",
        "x; rm -rf /",
        *NONE_LEFT_OUT,
    )

    # With the sourced environment given: colcon itself, no shell.
    assert step.argv(source=False)[:2] == ("colcon", "test")
    assert step.argv(source=False)[2:] == argv[4:]


def test_the_sourced_environment_is_reused_only_for_the_install_tree_image_and_settings_it_came_from(tmp_path):
    install = tmp_path / "install"
    (install / "pkg").mkdir(parents=True)
    (install / "local_setup.sh").write_text("# colcon's\n")
    (tmp_path / "build").mkdir()
    sourced = SourcedEnv(tmp_path, "espdock/ros-jazzy-test:1", (("HOME", "/tmp"),))
    key = sourced.key()
    assert sourced.recorded(key) is None, "nothing recorded yet: the container sources"
    dump = b"HOME=/tmp\0HOSTNAME=c0ffee\0COLCON_PREFIX_PATH=/workspace/install\0NOTE=a\nb=c\0PWD=/workspace\0"
    (tmp_path / SOURCED_DUMP).write_bytes(dump)
    assert sourced.record(key) == tmp_path / SOURCED_ENV
    assert not (tmp_path / SOURCED_DUMP).exists()
    assert sourced.recorded(key) == (
        ("HOME", "/tmp"), ("COLCON_PREFIX_PATH", "/workspace/install"), ("NOTE", "a\nb=c"),
    )  # fmt: skip
    # Another image or other settings: sourced again.
    for other in (
        SourcedEnv(tmp_path, "espdock/ros-jazzy-test:2", (("HOME", "/tmp"),)),
        SourcedEnv(tmp_path, "espdock/ros-jazzy-test:1", (("HOME", "/tmp"), ("COLCON_DEFAULTS_FILE", "/d"))),
    ):
        assert other.recorded(other.key()) is None
    # A package installed or changed since: sourced again.
    (install / "pkg" / "package.dsv").write_text("prepend-non-duplicate;AMENT_PREFIX_PATH;\n")
    assert sourced.recorded(sourced.key()) is None
    # Before a run that sources, the record and an earlier run's dump go; a dump cut short
    # records nothing; nothing to source, no key.
    (tmp_path / SOURCED_DUMP).write_bytes(dump)
    sourced.forget()
    assert sourced.recorded(key) is None and sourced.record(key) is None
    (tmp_path / SOURCED_DUMP).write_bytes(b"HOME=/tmp\0")
    assert sourced.record(key) is None and sourced.recorded(key) is None
    (install / "local_setup.sh").unlink()
    assert sourced.key() is None


def test_results_are_counted_as_colcon_test_result_counts_and_collected_by_package(tmp_path):
    build = tmp_path / "build"
    (build / "p").mkdir(parents=True)
    (build / "p" / "pytest.xml").write_text(PYTEST_XML)
    gtests = build / "c" / "test_results" / "c"
    gtests.mkdir(parents=True)
    (gtests / "test_ring.gtest.xml").write_text(GTEST_XML)
    (build / "c" / "CMakeFiles").mkdir()
    (build / "c" / "CMakeFiles" / "other.xml").write_text("<project/>")  # not xUnit: left out
    (build / "c" / ".hidden").mkdir()
    (build / "c" / ".hidden" / "old.xml").write_text(GTEST_XML)  # dot dirs: skipped, as colcon does
    found = read_results(build, ("p", "c", "none"))
    p, c = found["p"], found["c"]
    assert (p.tests, p.passed, p.failed, p.errored, p.skipped) == (4, 2, 1, 0, 1)
    assert p.failing == ["p.test.test_a.test_bad"] and not p.ok
    assert (c.tests, c.passed, c.ok) == (2, 2, True) and [f.name for f in c.files] == ["test_ring.gtest.xml"]
    assert found["none"].files == [] and found["none"].tests == 0
    written = collect_results(found, build, tmp_path / "results", ME)
    assert sorted(w.relative_to(tmp_path / "results").as_posix() for w in written) == [
        "c/test_results-c-test_ring.gtest.xml",
        "p/pytest.xml",
    ]


def test_a_run_s_results_replace_the_last_run_s_and_leave_what_espdock_did_not_copy(tmp_path):
    """A CI runner that keeps its directories: the second run tests only p, and a JUnit reporter
    reading DIR must not find c's results from the first as this run's."""
    build, results = tmp_path / "build", tmp_path / "results"
    (build / "p").mkdir(parents=True)
    (build / "p" / "pytest.xml").write_text(PYTEST_XML)
    (build / "c" / "test_results" / "c").mkdir(parents=True)
    (build / "c" / "test_results" / "c" / "test_ring.gtest.xml").write_text(GTEST_XML)
    collect_results(read_results(build, ("p", "c")), build, results, ME)
    (results / "c" / "mine.xml").write_text("<testsuite/>")  # the user's, or another tool's
    (results / "notes.txt").write_text("kept")
    forget_collected(results)
    collect_results(read_results(build, ("p",)), build, results, ME)
    left = sorted(p.relative_to(results).as_posix() for p in results.rglob("*") if p.is_file())
    assert left == [".espdock-results", "c/mine.xml", "notes.txt", "p/pytest.xml"]
    forget_collected(results)
    assert not (results / "p").exists(), "a package directory it emptied goes"
    forget_collected(results)  # nothing recorded: nothing to do


@pytest.mark.skipif(os.geteuid() != 0, reason="only root hands files to another user")
def test_results_and_a_report_written_as_root_belong_to_the_user_it_stands_for(tmp_path):
    """`sudo espdock test --results DIR` and `sudo espdock build --report FILE`: the user could
    not remove their own results, which root had made."""
    build = tmp_path / "build"
    (build / "p").mkdir(parents=True)
    (build / "p" / "pytest.xml").write_text(PYTEST_XML)
    user = (4242, 4243)
    written = collect_results(read_results(build, ("p",)), build, tmp_path / "ci/results", user)
    made = [tmp_path / "ci", tmp_path / "ci/results", tmp_path / "ci/results/p", *written]
    assert {(p.stat().st_uid, p.stat().st_gid) for p in made} == {user}
    assert tmp_path.stat().st_uid == 0, "a directory it did not make stays whose it was"
    report = tmp_path / "report.json"
    write_report(report, [], None, 1.0, user)
    assert (report.stat().st_uid, report.stat().st_gid) == user
    theirs = tmp_path / "theirs.json"
    theirs.write_text("{}")
    write_report(theirs, [], None, 1.0, user)
    assert theirs.stat().st_uid == 0, "a file that was there keeps its owner"


def spec(repository: str, key: str) -> ImageSpec:
    return ImageSpec(repository=repository, key=key, dockerfile="Dockerfile.ros", target="build", build_args=())


def test_the_test_dependencies_go_into_an_image_of_their_own_over_the_build_image(tmp_path):
    build = spec("espdock/ros-jazzy-build", "b" * 64)
    lock = {"test": {"apt": [], "pip": ["ros-jazzy-ament-flake8==0.17.3 --hash=sha256:00"], "keys": {}}}
    image = image_for_tests(build, lock, official=False)
    assert image.repository == "espdock/ros-jazzy-test"
    dockerfile = dict(image.context)["Dockerfile"].decode()
    assert dockerfile.startswith(f"FROM {build.tag} AS test") and "--break-system-packages" not in dockerfile
    assert b"ros-jazzy-ament-flake8" in dict(image.context)["rosdep-test/pip.txt"]
    assert image_for_tests(spec("espdock/ros-jazzy-build", "c" * 64), lock, False).key != image.key, "keyed by the base"
    assert image_for_tests(build, {"test": {"apt": [], "pip": []}}, False) is None, "nothing to add: the build image"
    assert image_for_tests(build, None, False) is None
    official = image_for_tests(build, {"test": {"apt": ["python3-pytest"], "pip": []}}, official=True)
    assert (
        "apt.txt" in str(official.context)
        and "--break-system-packages" in dict(official.context)["Dockerfile"].decode()
    )
    colcon = ColconBuild(image=build.tag, packages=("p",))
    plan = Plan(Workspace(tmp_path), (EnsureImage(build), colcon))
    tested = with_test_image(plan, lock, official=False)
    assert [type(s).__name__ for s in tested.steps] == ["EnsureImage", "EnsureImage", "ColconBuild"]
    assert tested.steps[-1].image == image.tag and tested.steps[1].spec == image
    assert with_test_image(plan, None, official=False) == plan


CTEST_XML = """<?xml version="1.0" encoding="UTF-8"?><Site Name="x"><Testing><TestList/><Test Status="passed">
<Name>test_ring</Name></Test><Test Status="failed"><Name>cppcheck</Name></Test></Testing></Site>"""


def test_the_latest_ctest_file_counts_as_colcon_cmake_counts_it_but_is_not_collected(tmp_path):
    build = tmp_path / "build"
    testing = build / "c" / "Testing"
    (testing / "20260101-0000").mkdir(parents=True)
    (testing / "20260101-0000" / "Test.xml").write_text(CTEST_XML)
    (testing / "19990101-0000").mkdir()
    (testing / "19990101-0000" / "Test.xml").write_text(CTEST_XML.replace('"failed"', '"passed"'))
    (testing / "TAG").write_text("20260101-0000\nExperimental\n")
    c = read_results(build, ("c",))["c"]
    assert (c.tests, c.passed, c.failed, c.ctest_tests) == (2, 1, 1, 2)
    assert c.failing == ["ctest cppcheck"] and c.files == [], "the latest only, and not a JUnit file"
    assert collect_results({"c": c}, build, tmp_path / "results", ME) == []


def test_a_package_whose_tests_were_all_removed_no_longer_fails_on_the_last_run_s(tmp_path):
    """colcon runs no CTest where none is left ("No ctests found"), so Testing/TAG still named the
    last run's Test.xml: a package whose failing test was removed failed `espdock test` again."""
    from espdock.ros.testing import clear_results

    build = tmp_path / "build"
    testing = build / "c" / "Testing"
    (testing / "20260101-0000").mkdir(parents=True)
    (testing / "20260101-0000" / "Test.xml").write_text(CTEST_XML)
    (testing / "TAG").write_text("20260101-0000\nExperimental\n")
    assert read_results(build, ("c",))["c"].failed == 1
    clear_results(build, ("c",))  # before a run that then runs no CTest
    c = read_results(build, ("c",))["c"]
    assert (c.tests, c.failed, c.failing) == (0, 0, [])
    (testing / "TAG").write_text("20260101-0000\nExperimental\n")  # a run that did: CTest writes it
    assert read_results(build, ("c",))["c"].tests == 2


def test_tests_in_the_workspace_volume_are_refused_before_the_rosdep_lock_and_any_engine(tmp_path):
    """workspace_mode = "volume": the results would stay on the engine's volume. The refusal came
    after the rosdep lock, whose `rosdep update` failed first where rosdep's sources were out of reach."""
    from tests.conftest import copy_workspace, espdock
    from tests.robot_packages import write_python_package

    root = copy_workspace(tmp_path / "w", packages=(), test_packages=("tested_py",))
    manifest = write_python_package(root / "ws/src", "serial_py") / "package.xml"
    manifest.write_text(manifest.read_text().replace("<export>", "<exec_depend>python3-serial</exec_depend>\n<export>"))
    away = {
        "DOCKER_HOST": "unix:///nonexistent/docker.sock",
        "ESPDOCK_WORKSPACE_MODE": "volume",
        "ROSDISTRO_INDEX_URL": "http://127.0.0.1:9/index.yaml",
        "XDG_CACHE_HOME": str(tmp_path / "cache"),
    }
    refused = espdock("test", cwd=root, env=away)
    assert refused.returncode == 8, refused.stdout + refused.stderr
    assert "the test results `espdock test` reads must be on this machine" in refused.stderr
    assert not (root / "rosdep.lock.json").exists()


def test_cli_refuses_bad_input_before_any_engine(tmp_path):
    from tests.conftest import copy_workspace, espdock

    root = copy_workspace(tmp_path / "w", packages=(), test_packages=("tested_py", "lint_auto_cpp"))
    no_engine = {"DOCKER_HOST": "unix:///nonexistent/docker.sock"}
    for args, said in (
        (("test", "nosuch"), "no package named 'nosuch'"),
        (("test", "tested_py", "--", "--test-result-base", "x"), "--test-result-base"),
        (("test", "tested_py", "--"), "nothing after `--`"),
        # A package named after `--` went into espdock's --packages-select: only tested_py tested, exit 0.
        (("test", "tested_py", "--", "lint_auto_cpp"), "'lint_auto_cpp' after `--` is no colcon option"),
        (("test",), "lint_auto_cpp: ament_lint_auto, ament_lint_common"),
        (("test", "tested_py", "--push-cache"), "--push-cache needs a cache registry"),
    ):
        result = espdock(*args, cwd=root, env=no_engine)
        assert result.returncode == 2, (args, result.stdout, result.stderr)
        assert said in result.stderr and "Traceback" not in result.stderr
    # test-result-base in a defaults file, a CI habit: colcon wrote the results where espdock never
    # looked, and a run whose test failed passed (0 tests, exit 0).
    (root / "ws/colcon_defaults.yaml").write_text("test:\n  test-result-base: results\n")
    from tests.rosdep_db import environment

    for args in (("test", "tested_py"), ("build", "--dry-run")):
        result = espdock(*args, cwd=root, env={**environment(tmp_path), **no_engine})
        assert result.returncode == 2, (args, result.stdout, result.stderr)
        assert "colcon_defaults.yaml sets test-result-base, which espdock controls" in result.stderr, result.stderr
    (root / "ws/colcon_defaults.yaml").unlink()
    # Valid input: the last run's results go before the run, so a run that fails (here before any test)
    # leaves none of them for CI to report as its own.
    build, results = tmp_path / "build", tmp_path / "results"
    (build / "tested_py").mkdir(parents=True)
    (build / "tested_py" / "pytest.xml").write_text(PYTEST_XML)
    collect_results(read_results(build, ("tested_py",)), build, results, ME)
    result = espdock("test", "tested_py", "--results", str(results), cwd=root, env=no_engine)
    assert result.returncode != 0, result.stdout + result.stderr
    assert not (results / "tested_py").exists()
    # Results written into a package's sources (`--results out` run from the package's directory)
    # were its sources at its next build, which built it again without a word.
    package = root / "ws/src/tested_py"
    inside = espdock("test", "tested_py", "--results", "out", cwd=package, env=no_engine)
    said = " ".join((inside.stdout + inside.stderr).split())
    assert "--results out is in tested_py's sources" in said and "builds tested_py again" in said, said


def test_a_firmware_package_without_host_tests_has_nothing_to_run_and_needs_no_engine(tmp_path):
    import shutil

    from tests.conftest import REPO, copy_workspace, espdock

    root = copy_workspace(tmp_path / "w", packages=())
    shutil.copytree(REPO / "firmware/led_strip_node", root / "firmware/led_strip_node")
    result = espdock("test", "led_strip_node", cwd=root, env={"DOCKER_HOST": "unix:///nonexistent"})
    assert result.returncode == 0, result.stdout + result.stderr
    assert "led_strip_node: firmware package, nothing to run in the ROS image; it declares no host tests" in (
        result.stdout
    )


def test_host_tests_declared_in_a_misspelt_directory_are_named_not_taken_for_a_missing_cmake(tmp_path):
    """<espdock_host_tests>test/hots</espdock_host_tests>: `espdock test` said "cmake is not
    installed" (the missing directory was CMake's cwd), sending the user to apt."""
    from tests.conftest import copy_workspace, espdock

    root = copy_workspace(tmp_path / "w", packages=())
    package = host_tested(root / "firmware/probe_fw", "")
    manifest = package / "package.xml"
    manifest.write_text(manifest.read_text().replace(">test/host<", ">test/hots<").replace(">espidf<", ">esp_idf<"))
    result = espdock("test", "probe_fw", cwd=root, env={"DOCKER_HOST": "unix:///nonexistent"})
    said = " ".join((result.stdout + result.stderr).split())
    assert result.returncode == 2, said
    assert "declares its host tests in test/hots (<espdock_host_tests>), which is not a directory" in said, said
    assert "not installed" not in said
    (package / "test/hots").mkdir()  # there, but no CMake project: CMake's failure counted as the tests' (exit 10)
    empty = espdock("test", "probe_fw", cwd=root, env={"DOCKER_HOST": "unix:///nonexistent"})
    said = " ".join((empty.stdout + empty.stderr).split())
    assert empty.returncode == 2 and "(<espdock_host_tests>), which holds no CMakeLists.txt" in said, said


def test_host_test_steps_are_cmake_then_ctest_and_only_a_failing_ctest_with_results_is_a_result(tmp_path):
    source, build, junit = tmp_path / "host", tmp_path / "b", tmp_path / "r" / "host_tests.xml"
    steps = host_test_steps(source, build, junit)
    assert [argv[:2] for argv in steps] == [("cmake", "-S"), ("cmake", "--build"), ("ctest", "--test-dir")]
    assert steps[2][-2:] == ("--output-junit", str(junit))
    assert host_tests_failed(steps[0], 0, junit) is None
    assert host_tests_failed(steps[0], 1, junit) is True
    assert host_tests_failed(steps[2], 8, junit) is True, "ctest wrote no results: the tests did not run"
    junit.parent.mkdir()
    junit.write_text("<testsuite tests='1' failures='1'/>")
    assert host_tests_failed(steps[2], 8, junit) is False, "a failing test is a result"


def test_a_test_that_errored_is_named_as_errored_not_failed(tmp_path):
    """A fixture's exception is an error in JUnit and colcon test-result counts it as one; the
    summary counted it so, then listed it under "failed:"."""
    from espdock.cli.testing import _render

    build = tmp_path / "build"
    (build / "p").mkdir(parents=True)
    errored = PYTEST_XML.replace('errors="0"', 'errors="1"').replace(
        'name="test_two"/>', 'name="test_two"><error message="fixture">x</error></testcase>'
    )
    (build / "p" / "pytest.xml").write_text(errored)
    found = read_results(build, ("p",))
    lines: list[str] = []
    _render(found, tmp_path, {"p": tmp_path / "log"}, lambda text: lines.append(str(text)))
    assert "    failed: p.test.test_a.test_bad" in lines and "    errored: p.test.test_a.test_two" in lines, lines


def test_packages_the_options_after_the_double_dash_skip_are_not_tested_nor_asked_for(tmp_path):
    """`espdock test PKG -- --packages-skip PKG` passed with "0 tests" where PKG has seven (a green
    CI job that ran nothing); `-- --packages-skip` of a package with ament_lint test dependencies
    was still refused for them."""
    import shutil

    from tests.conftest import REPO, copy_workspace, espdock
    from tests.robot_packages import write_python_package

    root = copy_workspace(tmp_path / "w")
    linted = write_python_package(root / "ws/src", "linted")
    manifest = linted / "package.xml"
    manifest.write_text(manifest.read_text().replace("</package>", "").replace(
        "<export>", "<test_depend>ament_lint_auto</test_depend>\n  <export>"
    ) + "</package>\n")  # fmt: skip
    no_engine = {"DOCKER_HOST": "unix:///nonexistent/docker.sock"}
    refused = espdock("test", cwd=root, env=no_engine)
    assert refused.returncode == 2 and "ament_lint_auto" in refused.stderr, refused.stderr
    skipped = espdock("test", "--", "--packages-skip", "linted", cwd=root, env=no_engine)
    said = " ".join((skipped.stdout + skipped.stderr).split())
    assert "not tested (the colcon options, after `--` or a defaults file's, skip them): linted" in said, said
    assert skipped.returncode == 3 and "ament_lint_auto" not in said  # on to the engine, which is not there
    # The last run's results (as its --results copy recorded them) go before the refusal: a CI
    # runner reported them as this run's.
    results = tmp_path / "results"
    (results / "linted").mkdir(parents=True)
    (results / "linted/pytest.xml").write_text("<testsuite tests='1'/>\n")
    (results / ".espdock-results").write_text("linted/pytest.xml\n")
    nothing = espdock(
        "test", "linted", "--results", str(results), "--", "--packages-skip", "linted", cwd=root, env=no_engine
    )
    assert (
        nothing.returncode == 2
        and "nothing to test: the colcon options (after `--`, or a defaults file's) skip linted" in nothing.stderr
    )
    assert not (results / "linted/pytest.xml").exists()
    # A firmware package beside them that declares no host tests tests nothing either: every ROS
    # package skipped passed, exit 0, with no result file.
    shutil.copytree(REPO / "firmware/led_strip_node", root / "firmware/led_strip_node")
    everything = ("--packages-skip", "linted", "custom_interface")
    beside = espdock("test", "--", *everything, cwd=root, env=no_engine)
    assert beside.returncode == 2, beside.stdout + beside.stderr
    assert "nothing to test: the colcon options (after `--`, or a defaults file's) skip" in beside.stderr
    # Skipped by the workspace's colcon defaults file, which colcon reads: `espdock test linted`
    # passed nothing (exit 0), and a run of them all was refused for what linted's tests need.
    (root / "ws/colcon_defaults.yaml").write_text("test:\n  packages-skip:\n    - linted\n")
    from_file = espdock("test", "linted", cwd=root, env=no_engine)
    assert from_file.returncode == 2 and "skip linted" in from_file.stderr, from_file.stdout + from_file.stderr
    every = espdock("test", cwd=root, env=no_engine)
    said = " ".join((every.stdout + every.stderr).split())
    assert "not tested (the colcon options, after `--` or a defaults file's, skip them): linted" in said, said
    assert every.returncode == 3 and "ament_lint_auto" not in said
    (root / "ws/colcon_defaults.yaml").unlink()
    # A package name espdock does not know: refused, and the last run's results gone as well.
    (results / "linted").mkdir()
    (results / "linted/pytest.xml").write_text("<testsuite tests='1'/>\n")
    (results / ".espdock-results").write_text("linted/pytest.xml\n")
    unknown = espdock("test", "nosuch", "--results", str(results), cwd=root, env=no_engine)
    assert unknown.returncode == 2 and "no package named 'nosuch'" in unknown.stderr, unknown.stderr
    assert not (results / "linted/pytest.xml").exists()


def test_packages_whose_tests_passed_last_time_are_left_out_with_their_results_kept(tmp_path):
    """`espdock test -- --packages-skip-test-passed` (colcon's retest of what failed): espdock
    deleted the passed packages' result files, then called them packages with no tests."""
    from espdock.ros.testing import not_left_out
    from tests.unit.test_rosdeps import package

    every = (package("passed", set()), package("failed", set()), package("new", set()))
    base = tmp_path / "build/espdock-ros"
    for name, result in (("passed", "0"), ("failed", "test failures")):
        (base / name).mkdir(parents=True)
        (base / name / "colcon_test.rc").write_text(result + "\n")  # colcon-package-selection's record
    tested, skipped = not_left_out(list(every), every, ("--packages-skip-test-passed",), base)
    assert [p.name for p in tested] == ["failed", "new"] and skipped == ["passed"]
    tested, skipped = not_left_out(list(every), every, ("--packages-skip-test-p", "--pytest-args", "-x"), base)
    assert skipped == ["passed"], "an abbreviation, followed by other options"
    assert not_left_out(list(every), every, ("--pytest-args", "-x"), base)[1] == []


def test_what_espdock_test_refuses_or_fails_on_says_what_to_do_with_espdock_test():
    """Each hint followed from `espdock test` led to `espdock build`: a gtest file that does not
    compile was "run `espdock build` again" (which passes: it builds without the tests), a refused
    option was "e.g. `--cmake-args ...`" (which colcon test refuses)."""
    from pathlib import Path

    from espdock.ros import rosdeps
    from espdock.ros.colcon_log import PackageState, explain_failure
    from espdock.ros.testing import check_test_args
    from tests.unit.test_rosdeps import WHEELS, package

    with pytest.raises(ConfigError) as empty:
        check_test_args(())
    assert "`colcon test`" in empty.value.message and "`espdock test -- --pytest-args" in (empty.value.hint or "")
    with pytest.raises(ConfigError) as refused:
        check_test_args(("--event-handlers", "console_direct-"))
    assert "--pytest-args" in (refused.value.hint or "") and "--cmake-args" not in (refused.value.hint or "")
    assert "--continue-on-error" not in (refused.value.hint or ""), "colcon test has no such option"
    # colcon build's options: refused before the build with tests, not by colcon test after it.
    for option, way in (("--cmake-args", "`espdock build -- --cmake-args ...`"),
                        ("--cmake-target", "`espdock build -- --cmake-target ...`"),
                        ("--symlink-inst", "`espdock build -- --symlink-install ...`"),
                        ("--continue-on-error", "--abort-on-error")):  # fmt: skip
        with pytest.raises(ConfigError, match="one of colcon build's") as building:
            check_test_args((option, "x"))
        assert way in (building.value.hint or ""), building.value.hint
    check_test_args(("--abort-on-error", "--ctest-args", "-R", "ring"))
    states = {"cpp_pkg": PackageState.FAILED, "later": PackageState.ABORTED}
    logs = {"cpp_pkg": (Path("log/cpp_pkg.log"), "error: expected ';' before '}' token")}
    failed = explain_failure(2, states, logs, (), command="test")
    assert "run `espdock test` again" in failed.hint and "espdock build" not in failed.hint
    lock = {"keys": {"launch_testing": {"installer": None, "why": rosdeps.UNKNOWN_KEY}}}
    with pytest.raises(DependencyError) as missing:
        rosdeps.check_dependencies([package("a", set())], {"a": ("launch_testing",)}, lock, WHEELS, command="test")
    assert "`espdock test PKG...`" in (missing.value.hint or "") and "espdock build" not in (missing.value.hint or "")


def test_a_retest_of_what_failed_once_everything_passed_is_a_pass(tmp_path):
    """`espdock test -- --packages-skip-test-passed` in a CI loop, after the last failure was
    fixed: exit 2, "nothing to test", where colcon passes."""
    from tests.conftest import copy_workspace, espdock

    root = copy_workspace(tmp_path / "w", packages=(), test_packages=("beacon_nodes",))
    (root / "ws/build/espdock-ros/beacon_nodes").mkdir(parents=True)
    (root / "ws/build/espdock-ros/beacon_nodes/colcon_test.rc").write_text("0\n")
    no_engine = {"DOCKER_HOST": "unix:///nonexistent/docker.sock"}
    again = espdock("test", "--", "--packages-skip-test-passed", cwd=root, env=no_engine)
    said = " ".join((again.stdout + again.stderr).split())
    assert again.returncode == 0 and "the tests of beacon_nodes passed last time" in said, said
    (root / "ws/build/espdock-ros/beacon_nodes/colcon_test.rc").write_text("test failures\n")
    failed = espdock("test", "--", "--packages-skip-test-passed", cwd=root, env=no_engine)
    assert failed.returncode == 3, failed.stderr  # on to the engine, which is not there


def test_a_package_whose_tests_depend_on_a_workspace_package_is_tested_alone(tmp_path):
    """`<test_depend>test_utils</test_depend>`, test_utils a package of the workspace: `espdock
    test py_talker` was refused ("test_utils: not in the lock"), which `espdock lock` never added;
    `espdock test` of every package passed the check."""
    from tests.conftest import copy_workspace, espdock
    from tests.robot_packages import write_python_package
    from tests.rosdep_db import environment

    root = copy_workspace(tmp_path / "w", packages=())
    write_python_package(root / "ws/src", "test_utils")
    talker = write_python_package(root / "ws/src", "py_talker")
    manifest = talker / "package.xml"
    manifest.write_text(manifest.read_text().replace("<export>", "<test_depend>test_utils</test_depend>\n  <export>"))
    env = {**environment(tmp_path), "DOCKER_HOST": "unix:///nonexistent/docker.sock"}
    assert espdock("lock", cwd=root, env=env).returncode == 0
    alone = espdock("test", "py_talker", cwd=root, env=env)
    assert alone.returncode == 3, alone.stdout + alone.stderr  # on to the engine, which is not there
    assert "not in the lock" not in alone.stderr


def host_tested(package: Path, cmake: str) -> Path:
    """A firmware package at PACKAGE declaring host tests whose CMakeLists (a project with no
    compiler) goes on with CMAKE."""
    (package / "test/host").mkdir(parents=True)
    (package / "package.xml").write_text(
        f'<package format="3"><name>{package.name}</name><version>0.0.0</version><description>x</description>'
        "<maintainer email='a@example.com'>a</maintainer><license>MIT</license>"
        "<export><build_type>espidf</build_type><espdock_host_tests>test/host</espdock_host_tests></export></package>"
    )
    (package / "test/host/CMakeLists.txt").write_text("cmake_minimum_required(VERSION 3.16)\nproject(t NONE)\n" + cmake)
    return package


def test_root_s_host_tests_run_as_the_workspace_s_user(shared_dir):
    """`sudo espdock test` ran a package's host tests (its own CMake code, outside any container)
    as root, where every build container runs as the workspace's user."""
    from espdock.ros.testing import run_host_tests

    if os.geteuid() != 0:
        pytest.skip("only root runs them as another user")
    package = host_tested(
        shared_dir / "who_fw",
        "enable_testing()\nexecute_process(COMMAND id -u OUTPUT_VARIABLE uid OUTPUT_STRIP_TRAILING_WHITESPACE)\n"
        'message(STATUS "configured as uid ${uid}")\n'
        'add_test(NAME as_the_user COMMAND sh -c "test $(id -u):$(id -g) = 4242:4243")\n',
    )
    base = shared_dir / "ws/build"
    lines: list[str] = []
    assert run_host_tests("who_fw", package, base, lines.append, (4242, 4243)) == 0, lines
    assert "-- configured as uid 4242" in lines
    junit = base / "who_fw/test_results/who_fw/host_tests.xml"
    assert 'failures="0"' in junit.read_text() and 'tests="1"' in junit.read_text(), junit.read_text()
    assert {p.lstat().st_uid for p in (base, *base.rglob("*"))} == {4242}


def test_root_s_host_tests_run_with_the_user_s_home(shared_dir):
    """Run as the user, with root's HOME: a test that keeps a cache under $HOME failed where it had
    passed as root."""
    import pwd

    from espdock.ros.testing import run_host_tests

    users = [u for u in pwd.getpwall() if u.pw_uid >= 1000 and Path(u.pw_dir).is_dir() and u.pw_uid < 60000]
    if os.geteuid() != 0 or not users:
        pytest.skip("needs root and a user with a home")
    user = users[0]
    package = host_tested(shared_dir / "home_fw", 'message(STATUS "home is $ENV{HOME}")\n')
    lines: list[str] = []
    run_host_tests("home_fw", package, shared_dir / "ws/build", lines.append, (user.pw_uid, user.pw_gid))
    assert f"-- home is {user.pw_dir}" in lines, lines


def test_pytest_files_colcon_ran_with_unittest_are_named_not_called_no_tests(tmp_path):
    """An ament_python package with test/test_x.py but no `tests_require=['pytest']` in its setup.py:
    colcon ran unittest, which found nothing, and `espdock test` said "the package has no tests
    colcon could find" of a package with a failing test."""
    from rich.console import Console

    from espdock.cli.testing import _render
    from espdock.ros.testing import PackageResults, pytest_not_asked_for

    package = tmp_path / "ws/src/py_pkg"
    (package / "test").mkdir(parents=True)
    (package / "test/test_math.py").write_text("def test_add():\n    assert 1 + 1 == 3\n")
    (package / "setup.py").write_text("from setuptools import setup\nsetup(name='py_pkg', packages=['py_pkg'])\n")
    assert pytest_not_asked_for(package)
    lines: list[str] = []
    console = Console(width=300)
    logs = {"py_pkg": tmp_path / "ws/log/latest_test/py_pkg"}
    with console.capture() as captured:
        _render({"py_pkg": PackageResults("py_pkg")}, tmp_path, logs, console.print, {"py_pkg"})
    lines = captured.get().splitlines()
    assert any("colcon runs pytest only where setup.py names it, `tests_require=['pytest']`" in line for line in lines)
    assert not any("no tests colcon could find" in line for line in lines), lines
    (package / "setup.py").write_text("from setuptools import setup\nsetup(name='py_pkg', tests_require=['pytest'])\n")
    assert not pytest_not_asked_for(package)
    (package / "setup.py").write_text("from setuptools import setup\nsetup(name='py_pkg')\n")
    (package / "test/test_math.py").unlink()
    assert not pytest_not_asked_for(package), "no pytest file: nothing left unrun"
