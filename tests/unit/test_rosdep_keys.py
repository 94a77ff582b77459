"""Which packages serve a package.xml's rosdep keys, and which packages' keys are checked: the
reviewed PyPI projects of the wheels image, conditions evaluated for ROS 2, the check of
`run`, `shell`, `--dry-run` and colcon's skip options, one rosdep database per workspace, and
builds with no route to rosdep's sources. The real rosdep on the tests' database of real rules
(tests/rosdep_db); packages written as upstream drivers write theirs (tests/ros_packages)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from espdock.build.stamps import StampFile, listing_digest
from espdock.ros import rosdeps
from espdock.ros.staleness import ROS_STAMPS
from espdock.workspace import Workspace, discover_packages
from tests.conftest import REPO, build_holding, espdock
from tests.rosdep_db import environment

PACKAGES = REPO / "tests" / "ros_packages"
NO_ENGINE = {"DOCKER_HOST": "unix:///nonexistent/docker.sock"}
WHEELS = rosdeps.RosImage("wheels", "jazzy", "debian:bookworm", frozenset({"rclpy", "std_msgs"}))


def make_workspace(root: Path, *names: str) -> Path:
    (root / "src").mkdir(parents=True)
    for name in names:
        shutil.copytree(PACKAGES / name, root / "src" / name)
    (root / "espdock.toml").write_text("[espdock]\n")
    return root


def run(root: Path, tmp_path: Path, *args: str, **extra: str) -> subprocess.CompletedProcess[str]:
    return espdock(*args, cwd=root, env={**NO_ENGINE, **environment(tmp_path), **extra})


def add_depends(manifest: Path, *lines: str) -> None:
    text = manifest.read_text()
    manifest.write_text(
        text.replace("  <test_depend>", "".join(f"  {line}\n" for line in lines) + "  <test_depend>", 1)
    )


def test_python_keys_are_served_by_their_reviewed_pypi_project_or_refused():
    rules = {
        # rosdistro's rules on Debian: apt everywhere, no pip rule for any platform.
        "python3-serial": rosdeps.Rule("apt", ("python3-serial",)),
        "python3-usb": rosdeps.Rule("apt", ("python3-usb",)),
        "python3-websocket": rosdeps.Rule("apt", ("python3-websocket",)),
        "python3-jwt": rosdeps.Rule("apt", ("python3-jwt",)),
        "python3-opencv": rosdeps.Rule("apt", ("python3-opencv",)),
        "python3-gi": rosdeps.Rule("apt", ("python3-gi",)),
        "python3-smbus": rosdeps.Rule("apt", ("python3-smbus",)),
        "python3-dev": rosdeps.Rule("apt", ("python3-dev",)),
        # rosdistro's python3-yaml has a pip rule (osx), python3-pydantic one in short form (buster).
        "python3-yaml": rosdeps.Rule("apt", ("python3-yaml",), pip_elsewhere=("pyyaml",)),
    }
    mapped = rosdeps.for_image(rules, WHEELS, {})
    served = {key: (rule.installer, rule.packages) for key, rule in mapped.items()}
    assert served == {
        "python3-serial": ("pip", ("pyserial",)),  # PyPI's `serial` is a serialization framework
        "python3-usb": ("pip", ("pyusb",)),
        "python3-websocket": ("pip", ("websocket-client",)),
        "python3-jwt": ("pip", ("PyJWT",)),
        "python3-opencv": ("pip", ("opencv-python-headless",)),
        "python3-gi": (None, ()),
        "python3-smbus": (None, ()),
        "python3-dev": ("apt", ("python3-dev",)),  # headers for the venv's own (Debian's) Python
        "python3-yaml": ("pip", ("pyyaml",)),
    }
    assert "PyGObject" in mapped["python3-gi"].why and "pip rule" in mapped["python3-smbus"].why
    assert rosdeps._pip_packages({"debian": {"*": ["python3-pydantic"], "buster": {"pip": ["pydantic"]}}}) == (
        "pydantic",
    )


def test_a_serial_driver_gets_pyserial_and_python3_gi_is_refused_by_name(tmp_path):
    root = make_workspace(tmp_path / "w", "rosdeps_serial_gps")
    manifest = root / "src/rosdeps_serial_gps/package.xml"
    add_depends(manifest, "<depend>python3-opencv</depend>", "<build_depend>python3-dev</build_depend>")
    made = run(root, tmp_path, "lock")
    assert made.returncode == 0, made.stderr
    lock = json.loads((root / "rosdep.lock.json").read_text())
    keys = {key: (entry["installer"], entry.get("packages")) for key, entry in lock["keys"].items()}
    assert keys == {
        "python3-serial": ("pip", ["pyserial"]),
        "python3-opencv": ("pip", ["opencv-python-headless"]),
        "python3-dev": ("apt", ["python3-dev"]),
    }
    pinned = {line.split("==")[0] for line in lock["pip"]}
    assert {"pyserial", "opencv-python-headless", "numpy"} <= pinned and "serial" not in pinned
    assert lock["apt"] == ["python3-dev"]
    assert run(root, tmp_path, "build").returncode == 3  # the check passes: on to the engine
    add_depends(manifest, "<exec_depend>python3-gi</exec_depend>")
    refused = run(root, tmp_path, "build")
    assert refused.returncode == 2, refused.stderr
    assert f"rosdeps_serial_gps ({manifest.parent}): python3-gi: PyGObject" in refused.stderr
    assert "No solution found" not in refused.stderr and "uv could not" not in refused.stderr
    assert "rosdep.lock.json: resolving the workspace's dependencies" in refused.stdout + refused.stderr


def test_a_dual_ros1_ros2_package_is_read_as_ros2_jazzy_sees_it(tmp_path):
    root = make_workspace(tmp_path / "w", "rosdeps_dual_driver", "rosdeps_serial_gps")
    (dual,) = [p for p in discover_packages(Workspace(root).with_layout(None, None)) if p.name.endswith("driver")]
    assert dual.build_type == "ament_cmake"
    assert dual.depends - dual.test_only_depends == {"ament_cmake", "ament_cmake_python", "rclpy", "sensor_msgs"}
    assert dual.test_only_depends == {"ament_cmake_pytest"}
    made = run(root, tmp_path, "lock")
    assert made.returncode == 0, made.stderr
    lock = json.loads((root / "rosdep.lock.json").read_text())
    # catkin and rospy are ROS 1's, python3-usb noetic's: none is asked of rosdep nor refused.
    assert lock["packages"] == {"rosdeps_serial_gps": ["python3-serial"]}
    result = run(root, tmp_path, "build")
    assert result.returncode == 3, result.stderr


def fake_install(root: Path, package: str, executable: str) -> None:
    """What an espdock build left: the executable `espdock run` looks for, and the build's record
    of the install tree (`run` refuses one it did not make)."""
    path = root / "install" / package / "lib" / package / executable
    path.parent.mkdir(parents=True)
    path.write_text("#!/bin/sh\n")
    path.chmod(0o755)
    (root / "build").mkdir(exist_ok=True)
    StampFile(root / "build" / ROS_STAMPS).record(
        {package: "built"}, {package: listing_digest(root / "install" / package)}
    )


def test_run_and_shell_check_only_what_they_run(tmp_path):
    root = make_workspace(tmp_path / "w", "rosdeps_cpp_talker", "rosdeps_xml_count")
    assert run(root, tmp_path, "lock").returncode == 0
    fake_install(root, "rosdeps_xml_count", "xml_count")
    fake_install(root, "rosdeps_cpp_talker", "talker")
    # rosdeps_cpp_talker's rclcpp is none of xml_count's business, nor of a shell's.
    for args in (("run", "rosdeps_xml_count", "xml_count"), ("shell",)):
        result = run(root, tmp_path, *args)
        assert result.returncode == 3, (args, result.stderr)
    refused = run(root, tmp_path, "run", "rosdeps_cpp_talker", "talker")
    assert refused.returncode == 2 and "rclcpp: PyPI has no ros-jazzy-rclcpp" in refused.stderr
    assert "another selection" not in refused.stderr


def test_run_of_a_package_never_built_that_the_image_cannot_build_says_why(tmp_path):
    """`espdock run` of an rclcpp package on the wheels image said it was not built yet and to run
    `espdock build PKG` first, a build this image refuses."""
    root = make_workspace(tmp_path / "w", "rosdeps_cpp_talker")
    assert run(root, tmp_path, "lock").returncode == 0
    refused = run(root, tmp_path, "run", "rosdeps_cpp_talker", "talker")
    assert refused.returncode == 2 and "rclcpp: PyPI has no ros-jazzy-rclcpp" in refused.stderr, refused.stderr
    assert "not built yet" not in refused.stderr and 'ros_image = "official"' in refused.stderr


def test_dry_run_neither_updates_rosdep_nor_writes_the_lock(tmp_path):
    root = make_workspace(tmp_path / "w", "rosdeps_xml_count")
    result = run(root, tmp_path, "build", "--dry-run")
    assert result.returncode == 0, result.stderr
    assert "rosdep.lock.json is missing: a build would make it first" in result.stdout
    assert not (root / "rosdep.lock.json").exists()
    assert not (tmp_path / "cache/espdock/rosdep").exists()  # no `rosdep update`
    # Under --locked (CI's default) the build refuses it before anything: so does its preview.
    for args, extra in ((("--locked",), {}), ((), {"CI": "true"})):
        refused = run(root, tmp_path, "build", "--dry-run", *args, **extra)
        assert refused.returncode == 2, refused.stdout + refused.stderr
        assert "rosdep.lock.json is missing" in refused.stderr and "espdock lock" in refused.stderr


def test_colcons_skip_options_leave_packages_out_of_the_check(tmp_path):
    skips = [
        ("--packages-skip", "rosdeps_cpp_talker"),
        ("--packages-skip-regex", "rosdeps_cpp"),
        ("--packages-ignore=rosdeps_cpp_talker",),
        ("--packages-skip-up-to", "rosdeps_cpp_talker"),
    ]
    root = make_workspace(tmp_path / "w", "rosdeps_cpp_talker", "rosdeps_xml_count")
    # One workspace for all: the first build writes the lock of what it builds; with it there, rclcpp
    # is still checked (and refused) for any selection that keeps rosdeps_cpp_talker, as the last build shows.
    for skip in skips:
        result = run(root, tmp_path, "build", "--", *skip)
        assert result.returncode == 3, (skip, result.stderr)  # the check passes: on to the engine
    assert run(root, tmp_path, "build").returncode == 2  # without an option: refused


def test_each_workspace_has_its_own_rosdep_database_and_the_lock_names_its_sources(tmp_path):
    # A's rosdep is pointed at a private rule as well; B's is not, and must not see it.
    private = tmp_path / "private.yaml"
    private.write_text("acme_lidar_sdk:\n  debian: [libacme-lidar-dev]\n")
    env = environment(tmp_path)
    sources = Path(env["ROSDEP_SOURCE_PATH"])
    with_private = tmp_path / "with-private.list.d"
    shutil.copytree(sources, with_private)
    (with_private / "60-acme.list").write_text(f"yaml {private.as_uri()}\n")
    for name in ("a", "b"):
        root = make_workspace(tmp_path / name, "rosdeps_xml_count")
        manifest = root / "src/rosdeps_xml_count/package.xml"
        manifest.write_text(
            manifest.read_text().replace("<depend>tinyxml2</depend>", "<depend>acme_lidar_sdk</depend>")
        )
    locked = run(tmp_path / "a", tmp_path, "lock", ROSDEP_SOURCE_PATH=str(with_private))
    assert locked.returncode == 0, locked.stderr
    lock = json.loads((tmp_path / "a/rosdep.lock.json").read_text())
    assert lock["apt"] == ["libacme-lidar-dev"]
    assert any(private.as_uri() in source for source in lock["sources"])
    assert any("index-v4.yaml" in source for source in lock["sources"])
    other = run(tmp_path / "b", tmp_path, "build")
    assert other.returncode == 2, other.stderr
    assert "acme_lidar_sdk: no rosdep rule: the key is unknown" in other.stderr

    # B removed: the next `rosdep update` removes its database, and A's stays.
    databases = tmp_path / "cache/espdock/rosdep"
    assert len(list(databases.iterdir())) == 2
    shutil.rmtree(tmp_path / "b")
    again = run(tmp_path / "a", tmp_path, "lock", ROSDEP_SOURCE_PATH=str(with_private))
    assert again.returncode == 0, again.stderr
    assert [(d / "root").read_text() for d in databases.iterdir()] == [str((tmp_path / "a").resolve())]


def offline(root: Path, tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    """espdock with no route to anything (a network namespace of its own): rosdep's default
    sources on GitHub, an empty cache."""
    if subprocess.run(["unshare", "-rn", "true"], capture_output=True, check=False).returncode != 0:
        pytest.skip("unshare cannot make a network namespace here")
    env = {**NO_ENGINE, "XDG_CACHE_HOME": str(tmp_path / "offline-cache"), "CI": ""}
    return espdock(*args, cwd=root, env=env, prefix=("unshare", "-rn", sys.executable, "-m", "espdock"))


def test_offline_what_needs_nothing_from_rosdep_builds_and_the_rest_is_named(tmp_path):
    root = make_workspace(tmp_path / "w", "rosdeps_cpp_talker", "rosdeps_dual_driver")
    served = offline(root, tmp_path, "build", "rosdeps_dual_driver")
    assert served.returncode == 3, served.stdout + served.stderr  # past rosdep, on to the engine
    assert "the packages built need nothing more from rosdep" in served.stdout
    assert not (root / "rosdep.lock.json").exists()
    refused = offline(root, tmp_path, "build")
    assert refused.returncode == 2, refused.stderr
    assert "`rosdep update` failed" in refused.stderr
    assert "<urlopen error" not in refused.stderr, refused.stderr  # rosdep nests urllib's wrappers
    assert "  rosdeps_cpp_talker: rclcpp" in refused.stderr
    assert "`espdock build rosdeps_dual_driver`" in refused.stderr
    # With a current lock (made where rosdep's sources answer), nothing is fetched at all.
    assert run(root, tmp_path, "lock").returncode == 0
    assert offline(root, tmp_path, "build", "--", "--packages-skip", "rosdeps_cpp_talker").returncode == 3


def test_rosdeps_pre_rep137_warning_is_not_shown(tmp_path):
    root = make_workspace(tmp_path / "w", "rosdeps_xml_count")
    env = environment(tmp_path)
    listing = Path(env["ROSDEP_SOURCE_PATH"]) / "50-espdock-tests.list"
    # As rosdep's default list has it: fuerte's gbpdistro file (rosdistro's releases/fuerte.yaml).
    listing.write_text(
        listing.read_text()
        + "gbpdistro https://raw.githubusercontent.com/ros/rosdistro/master/releases/fuerte.yaml fuerte\n"
    )
    result = espdock(
        "lock", cwd=root, env={**NO_ENGINE, **env}, prefix=("unshare", "-rn", sys.executable, "-m", "espdock")
    )
    assert "could not read" in result.stderr  # offline: that source fails, and says so
    assert "PreRep137Warning" not in result.stderr and "deprecated" not in result.stderr


def test_list_does_not_cut_names_without_a_terminal(tmp_path):
    root = make_workspace(tmp_path / "w", "rosdeps_dual_driver")
    long_name = "rosdeps_dual_driver_for_the_time_of_flight_range_sensor_array"
    manifest = root / "src/rosdeps_dual_driver/package.xml"
    manifest.write_text(manifest.read_text().replace("<name>rosdeps_dual_driver</name>", f"<name>{long_name}</name>"))
    result = espdock("list", cwd=root, env=NO_ENGINE)
    assert result.returncode == 0, result.stderr
    assert long_name in result.stdout and "…" not in result.stdout


def test_a_dependency_on_a_workspace_package_an_ignore_marker_leaves_out_names_the_marker(tmp_path):
    """A metapackage's exec_depend on a driver whose directory got a COLCON_IGNORE: "no rosdep
    rule: the key is unknown", with COLCON_IGNORE among the ways out of what it caused."""
    root = make_workspace(tmp_path / "w", "rosdeps_xml_count")
    driver = root / "src/drivers/imu_driver"
    shutil.copytree(PACKAGES / "rosdeps_py_table", driver)
    manifest = driver / "package.xml"
    manifest.write_text(manifest.read_text().replace("<name>rosdeps_py_table</name>", "<name>imu_driver</name>"))
    (root / "src/drivers/COLCON_IGNORE").touch()
    depending = root / "src/rosdeps_xml_count/package.xml"
    depending.write_text(
        depending.read_text().replace("</depend>", "</depend>\n  <exec_depend>imu_driver</exec_depend>")
    )
    built = run(root, tmp_path, "build")
    said = " ".join(built.stderr.split())
    assert built.returncode == 2, said
    assert "imu_driver: a workspace package, which src/drivers/COLCON_IGNORE leaves out" in said
    assert "Remove src/drivers/COLCON_IGNORE; or drop the dependency on it" in said
    assert "rosdep rule" not in said
    named = run(root, tmp_path, "build", "imu_driver")
    assert named.returncode == 2 and "src/drivers/COLCON_IGNORE leaves it out" in named.stderr, named.stderr
    # The refused builds wrote no lock: one naming imu_driver as served by nothing, committed.
    assert not (root / "rosdep.lock.json").exists()
    # With no route to rosdep's sources and no lock: tinyxml2 needs rosdep, imu_driver never does.
    cut_off = offline(root, tmp_path, "build")
    said = " ".join(cut_off.stderr.split())
    assert cut_off.returncode == 2 and "`rosdep update` failed" in said, said
    assert "imu_driver (a workspace package, which src/drivers/COLCON_IGNORE leaves out), tinyxml2" in said
    # Without tinyxml2: nothing needs rosdep's sources, and the marker is the error.
    depending.write_text(depending.read_text().replace("<depend>tinyxml2</depend>", ""))
    alone = offline(root, tmp_path, "build")
    said = " ".join(alone.stderr.split())
    assert alone.returncode == 2 and "imu_driver: a workspace package, which src/drivers/COLCON_IGNORE" in said, said
    assert "rosdep update" not in said


def test_a_dependency_on_a_package_removed_from_the_sources_says_so_not_that_its_name_is_misspelt(tmp_path):
    """An interface package moved out of the workspace, its install left by the last build: "no
    rosdep rule: the key is unknown to rosdep's database (did you mean rcl_interfaces?)", and
    "correct the name in the package.xml where it is misspelt"."""
    root = make_workspace(tmp_path / "w", "rosdeps_xml_count")
    depending = root / "src/rosdeps_xml_count/package.xml"
    depending.write_text(depending.read_text().replace("</depend>", "</depend>\n  <depend>drv_interfaces</depend>", 1))
    # What colcon's install of it leaves: its prefix, marked as a package's.
    marker = root / "install/drv_interfaces/share/colcon-core/packages/drv_interfaces"
    marker.parent.mkdir(parents=True)
    marker.write_text("rosidl_default_runtime")
    built = run(root, tmp_path, "build")
    said = " ".join(built.stderr.split())
    assert built.returncode == 2, said
    assert (
        "drv_interfaces: install/drv_interfaces is an earlier build's, of a package no longer in the sources "
        "(renamed or removed)" in said
    ), said
    assert "Restore its sources (renamed: depend on its new name); or drop the dependency on it" in said, said
    assert "misspelt" not in said and "did you mean" not in said.lower(), said


def test_a_dependency_on_a_vendored_cmake_project_without_a_package_xml_names_the_project(tmp_path):
    """A plain CMake library vendored into src/ (colcon builds it as a `cmake` package): a
    package depending on it was "no rosdep rule" for its name, or, without rosdep's sources,
    "need rosdep for keys", where no rosdep rule could ever serve it."""
    root = make_workspace(tmp_path / "w", "rosdeps_xml_count")
    vendored = root / "src/third_party/tinylib"
    vendored.mkdir(parents=True)
    (vendored / "CMakeLists.txt").write_text(
        "cmake_minimum_required(VERSION 3.16)\nproject(tinylib VERSION 1.0 LANGUAGES C)\n"
        "add_library(tinylib STATIC tiny.c)\ninstall(TARGETS tinylib ARCHIVE DESTINATION lib)\n"
    )
    manifest = root / "src/rosdeps_xml_count/package.xml"
    manifest.write_text(manifest.read_text().replace("<depend>tinyxml2</depend>", "<depend>tinylib</depend>"))
    cut_off = offline(root, tmp_path, "build")
    said = " ".join(cut_off.stderr.split())
    assert cut_off.returncode == 2, said
    assert "tinylib: src/third_party/tinylib, a CMake project with no package.xml" in said
    assert "Add a package.xml to src/third_party/tinylib (<build_type>cmake</build_type>)" in said
    assert "rosdep rule" not in said and "rosdep update" not in said
    named = offline(root, tmp_path, "build", "tinylib")
    assert named.returncode == 2, named.stderr
    assert "src/third_party/tinylib is a CMake project with no package.xml" in named.stderr
    # Nothing depending on it: each build says what it leaves unbuilt that colcon would build.
    manifest.write_text(manifest.read_text().replace("<depend>tinylib</depend>", ""))
    planned = run(root, tmp_path, "build", "--dry-run")
    said = " ".join(planned.stderr.split() + planned.stdout.split())
    assert planned.returncode == 0, said
    assert "warning: src/third_party/tinylib is not built: a CMake project with no package.xml" in said
    listed = run(root, tmp_path, "list")  # where a user looks for what the workspace builds
    said = " ".join(listed.stderr.split() + listed.stdout.split())
    assert listed.returncode == 0 and "src/third_party/tinylib is not built" in said, said
    (vendored / "COLCON_IGNORE").touch()
    ignored = run(root, tmp_path, "build", "--dry-run")
    assert ignored.returncode == 0 and "not built" not in ignored.stdout + ignored.stderr


def test_a_rosdep_lock_an_older_espdock_made_is_stale_not_trusted(tmp_path):
    """Format 1 recorded a rule that installs nothing (rosdep's "satisfied") as unserved: after an
    upgrade that lock, trusted as it was, refused the build with "add a rosdep rule" for a key
    that had one."""
    root = make_workspace(tmp_path / "w", "rosdeps_xml_count")
    assert run(root, tmp_path, "build").returncode == 3  # locked, then at the engine
    path = root / "rosdep.lock.json"
    lock = json.loads(path.read_text())
    path.write_text(json.dumps({**lock, "format": 1}))
    refused = run(root, tmp_path, "build", "--locked", CI="true")
    said = " ".join(refused.stderr.split())
    assert refused.returncode == 2, said
    assert "rosdep.lock.json was made by an older espdock (format 1)" in said and "espdock lock" in said
    assert run(root, tmp_path, "build").returncode == 3
    assert json.loads(path.read_text())["format"] == rosdeps.FORMAT
    path.write_text(json.dumps({**lock, "format": rosdeps.FORMAT + 1}))
    newer = run(root, tmp_path, "build")
    assert newer.returncode == 2 and "made by a newer espdock" in newer.stderr, newer.stderr
    # The way out it names works: `espdock lock` alone refuses that file too.
    assert "delete rosdep.lock.json and run `espdock lock`" in " ".join(newer.stderr.split())
    path.unlink()
    assert run(root, tmp_path, "lock").returncode == 0
    assert json.loads(path.read_text())["format"] == rosdeps.FORMAT


def test_a_build_or_test_during_another_build_is_refused_before_it_writes_the_lock(tmp_path):
    """`espdock test` while a build held the workspace wrote rosdep.lock.json into it, then said
    another build was running."""
    root = make_workspace(tmp_path / "w", "rosdeps_xml_count")
    with build_holding(root) as process:
        previewed = run(root, tmp_path, "build", "--dry-run")
        said = " ".join(previewed.stdout.split() + previewed.stderr.split())
        assert previewed.returncode == 0 and f"(pid {process.pid}: espdock build): a build now is refused" in said
        for command in ("build", "test"):
            refused = run(root, tmp_path, command)
            assert refused.returncode == 2, refused.stdout + refused.stderr
            assert f"another espdock build is running in {root} (pid {process.pid}: espdock build)" in refused.stderr
            assert not (root / "rosdep.lock.json").exists(), command


def test_a_test_key_nothing_serves_is_refused_by_espdock_test_without_writing_the_lock(tmp_path):
    """`espdock test` refreshed a stale lock's test part with a key rosdep cannot serve and wrote
    it, then refused the run: the committed file named the key as served by nothing, which a
    build does not write."""
    root = make_workspace(tmp_path / "w", "tested_py")
    locked = run(root, tmp_path, "lock")
    assert locked.returncode == 0, locked.stderr
    before = (root / "rosdep.lock.json").read_bytes()
    add_depends(root / "src/tested_py/package.xml", "<test_depend>launch_testing_ros</test_depend>")
    result = run(root, tmp_path, "test")
    assert result.returncode == 2, result.stdout + result.stderr
    assert "tested_py" in result.stderr and "launch_testing_ros" in result.stderr
    assert "rosdep.lock.json not written (it would leave launch_testing_ros unresolved;" in result.stdout
    assert (root / "rosdep.lock.json").read_bytes() == before


def test_a_build_locks_a_new_dependency_beside_a_test_key_the_lock_already_leaves_unresolved(tmp_path):
    """A test-only key nothing serves (launch_testing, which `espdock lock` wrote as unresolved):
    every later dependency edit was "not written (it would leave launch_testing unresolved ...)",
    and `espdock run` refused the lock as older than the package.xml files."""
    root = make_workspace(tmp_path / "w", "tested_py")
    add_depends(root / "src/tested_py/package.xml", "<test_depend>launch_testing_ros</test_depend>")
    assert run(root, tmp_path, "lock").returncode == 0
    add_depends(root / "src/tested_py/package.xml", "<depend>tinyxml2</depend>")
    built = run(root, tmp_path, "build")
    assert "not written" not in built.stdout, built.stdout
    lock = json.loads((root / "rosdep.lock.json").read_text())
    assert lock["keys"]["tinyxml2"]["installer"] == "apt", lock["keys"]
    # A key the edit leaves unresolved is still not written by a build.
    add_depends(root / "src/tested_py/package.xml", "<depend>rclcpp</depend>")
    refused = run(root, tmp_path, "build")
    assert "rosdep.lock.json not written (it would leave rclcpp unresolved" in " ".join(refused.stdout.split())


def test_espdock_test_names_what_the_build_and_the_tests_lack_at_once(tmp_path):
    """It named the tests' missing keys alone; once a rule served them, the next run named the build's
    (rclcpp, which only the official image has): two rounds of fixes for what one message can say."""
    root = make_workspace(tmp_path / "w", "tested_py")
    add_depends(
        root / "src/tested_py/package.xml", "<depend>rclcpp</depend>", "<test_depend>launch_testing_ros</test_depend>"
    )
    assert run(root, tmp_path, "lock").returncode == 0
    result = run(root, tmp_path, "test")
    said = " ".join(result.stderr.split())
    assert result.returncode == 2, result.stdout + result.stderr
    assert "rclcpp: PyPI has no ros-jazzy-rclcpp" in said and "launch_testing_ros" in said, said
    assert "and for their tests, 1 package(s) depend on" in said and 'ros_image = "official"' in said, said


def test_offline_with_rosdep_s_database_at_hand_a_package_the_lock_answers_for_builds(tmp_path):
    """A lab without network, rosdep's database cached (or a local mirror): a new package needing
    only what the lock already pins (pyserial) was stopped by uv's "Failed to fetch" of the index,
    and so was every other build, with the hint to run `espdock lock`, which fails the same way."""
    if subprocess.run(["unshare", "-rn", "true"], capture_output=True, check=False).returncode != 0:
        pytest.skip("unshare cannot make a network namespace here")
    root = make_workspace(tmp_path / "w", "rosdeps_serial_gps")
    assert run(root, tmp_path, "lock").returncode == 0
    before = (root / "rosdep.lock.json").read_bytes()
    spare = root / "src/gps_spare"
    shutil.copytree(root / "src/rosdeps_serial_gps", spare)
    manifest = spare / "package.xml"
    manifest.write_text(manifest.read_text().replace("<name>rosdeps_serial_gps</name>", "<name>gps_spare</name>"))
    cut = ("unshare", "-rn", sys.executable, "-m", "espdock")
    env = {**NO_ENGINE, **environment(tmp_path), "UV_HTTP_RETRIES": "0"}  # no network: no retry can help
    built = espdock("build", "gps_spare", cwd=root, env=env, prefix=cut)
    assert built.returncode == 3, built.stdout + built.stderr  # past rosdep, on to the engine
    said = " ".join(built.stdout.split())
    assert "uv could not reach the package index" in said and "need nothing more from rosdep" in said, said
    assert (root / "rosdep.lock.json").read_bytes() == before
    locked = espdock("lock", cwd=root, env=env, prefix=cut)
    assert locked.returncode == 2 and "Reach the package index" in locked.stderr, locked.stderr


def test_offline_espdock_test_goes_on_with_the_lock_as_it_is_where_it_answers(tmp_path):
    """`espdock build` of a package the lock answers for went on without rosdep's sources;
    `espdock test` of it stopped at "`rosdep update` failed", the lock's test part covering it."""
    root = make_workspace(tmp_path / "w", "tested_py", "rosdeps_serial_gps")
    assert run(root, tmp_path, "lock").returncode == 0
    spare = root / "src/gps_spare"  # added since the lock was made: it is stale
    shutil.copytree(root / "src/rosdeps_serial_gps", spare)
    manifest = spare / "package.xml"
    manifest.write_text(manifest.read_text().replace("<name>rosdeps_serial_gps</name>", "<name>gps_spare</name>"))
    before = (root / "rosdep.lock.json").read_bytes()
    tested = offline(root, tmp_path, "test", "tested_py")
    assert tested.returncode == 3, tested.stdout + tested.stderr  # past rosdep, on to the engine
    assert "the packages built need nothing more from rosdep" in " ".join(tested.stdout.split())
    assert (root / "rosdep.lock.json").read_bytes() == before

    # No lock at all: its test keys need one, which only `espdock lock` makes. It said the lock
    # was "older than the package.xml files", and to run `espdock build`, which wrote none.
    (root / "rosdep.lock.json").unlink()
    shutil.rmtree(spare)
    refused = offline(root, tmp_path, "test", "tested_py")
    said = " ".join((refused.stdout + refused.stderr).split())
    assert refused.returncode == 2, said
    assert "1 package(s) built need rosdep for keys the wheels ROS image lacks" in said, said
    assert "tested_py: ament_flake8," in said and "older" not in said
    # Both of rosdep's sources: a copy of its rules alone still sent `rosdep update` to GitHub.
    assert "ROSDEP_SOURCE_PATH for its rules, ROSDISTRO_INDEX_URL for the rosdistro index" in said, said
    # Said once: not first that "the packages built need nothing more from rosdep", nor that tested_py could be tested.
    assert "need nothing more from rosdep" not in said and "Meanwhile" not in said


def test_a_build_says_when_the_lock_s_test_part_is_stale(tmp_path):
    """A package renamed, then `espdock build` (the lock's build part current: nothing in it named
    the package) and the lock committed: CI's `espdock test --locked` refused its test part, still
    naming the old name, of which the build had said nothing."""
    root = make_workspace(tmp_path / "w", "tested_py")
    assert run(root, tmp_path, "lock").returncode == 0
    manifest = root / "src/tested_py/package.xml"
    manifest.write_text(manifest.read_text().replace("<name>tested_py</name>", "<name>probe_py</name>"))
    built = run(root, tmp_path, "build")
    said = " ".join((built.stdout + built.stderr).split())
    assert built.returncode == 3, said  # past the plan, on to the engine
    assert "rosdep.lock.json (its test part) is stale" in said and "probe_py" in said, said
    assert "`espdock lock` (or `espdock test`) refreshes it before you commit it" in said, said


def test_rosdep_s_sources_behind_a_tls_intercepting_proxy_are_read_with_the_ca_bundle(tmp_path):
    """The company's proxy re-signs GitHub with its own CA, which ca_bundle (ESPDOCK_CA_BUNDLE)
    names as the docs say: uv took it, and `rosdep update` did not (its urllib checks against the
    system's CAs), so `espdock lock` failed every time, its hint saying "reach it". Here an HTTPS
    server of a CA no system store holds serves the tests' database, as such a proxy would."""
    import functools
    import http.server
    import threading

    from tests.rosdep_db import HERE
    from tests.tls import make_certificates

    context = make_certificates(tmp_path, client=False)
    handler = functools.partial(http.server.SimpleHTTPRequestHandler, directory=str(HERE))
    server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    server.socket = context.wrap_socket(server.socket, server_side=True)
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        url = f"https://127.0.0.1:{server.server_address[1]}"
        env = environment(tmp_path)
        (Path(env["ROSDEP_SOURCE_PATH"]) / "50-espdock-tests.list").write_text(
            f"yaml {url}/base.yaml\nyaml {url}/python.yaml\n"
        )
        env["ROSDISTRO_INDEX_URL"] = f"{url}/rosdistro/index-v4.yaml"
        root = make_workspace(tmp_path / "w", "rosdeps_xml_count")
        untrusted = espdock("lock", cwd=root, env={**NO_ENGINE, **env})
        said = " ".join(untrusted.stderr.split())
        assert untrusted.returncode == 2 and "CERTIFICATE_VERIFY_FAILED" in said, said
        assert "give its CA (ca_bundle in espdock.toml, or ESPDOCK_CA_BUNDLE)" in said, said
        trusted = espdock(
            "lock", cwd=root, env={**NO_ENGINE, **env, "ESPDOCK_CA_BUNDLE": str(tmp_path / "client/ca.pem")}
        )
        assert trusted.returncode == 0, trusted.stdout + trusted.stderr
        assert "tinyxml2" in (root / "rosdep.lock.json").read_text()
    finally:
        server.shutdown()
        server.server_close()
