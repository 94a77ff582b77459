"""colcon options, settings and partial rebuilds against the real engine, real colcon and real
ROS 2 packages (an interface package and ament_python nodes depending on it). Which packages
colcon ran is read from colcon's own event log, not from espdock's output."""

from __future__ import annotations

import json
import re
import shutil
import time
from pathlib import Path

import pytest

from tests.conftest import containers_created, copy_workspace, espdock, leftover_containers
from tests.robot_packages import write_interface_package, write_robot

pytestmark = [pytest.mark.engine, pytest.mark.slow]

_JOB = re.compile(r"^\[[0-9.]+\] \((?P<job>[^)-][^)]*)\) (?P<event>JobQueued|JobEnded|JobSkipped): (?P<data>.*)$")


def colcon_ran(root: Path) -> dict[str, str]:
    """Package -> 'built', 'failed <rc>' or 'skipped' in colcon's last run (log/latest_build/events.log)."""
    ran: dict[str, str] = {}
    for line in (root / "ws/log/latest_build/events.log").read_text().splitlines():
        match = _JOB.match(line)
        if not match:
            continue
        job, event = match.group("job"), match.group("event")
        if event == "JobQueued":
            ran.setdefault(job, "queued")
        elif event == "JobSkipped":
            ran[job] = "skipped"
        else:
            rc = re.search(r"'rc': ([^}]+)\}", match.group("data")).group(1)
            ran[job] = "built" if rc == "0" else f"failed {rc}"
    return ran


def build(root: Path, *args: str, code: int = 0):
    result = espdock("build", *args, cwd=root)
    assert result.returncode == code, result.stdout[-4000:] + result.stderr
    return result


def edit(package: Path) -> None:
    node = next(package.glob(f"{package.name}/*_node.py"))
    node.write_text(node.read_text() + f"\n# edited {time.time()}\n")


@pytest.fixture(scope="module")
def robot(engine, tmp_path_factory):
    """A workspace of robot_msgs, driver_0 and driver_1 on it, behaviour_0..3 on the drivers
    (0 and 2 on driver_0, 1 and 3 on driver_1), built once. robot_msgs has no service: what is
    tested here is which packages colcon runs, not what rosidl makes of a service, and each
    rosidl run of robot_msgs then compiles one message instead of four."""
    root = copy_workspace(tmp_path_factory.mktemp("colcon") / "robot", packages=(), runtime_image=False)
    graph = write_robot(root / "ws/src", 7, service=False)
    assert graph["behaviour_1"] == ("driver_1",) and graph["behaviour_3"] == ("driver_1",)
    build(root)
    assert colcon_ran(root) == dict.fromkeys(graph, "built")
    yield root
    engine.remove_containers({"io.espdock.workspace": str(root)})


def test_an_edit_rebuilds_only_the_package_and_what_depends_on_it(robot):
    edit(robot / "ws/src/driver_1")
    build(robot)
    assert colcon_ran(robot) == dict.fromkeys(("driver_1", "behaviour_1", "behaviour_3"), "built")
    edit(robot / "ws/src/behaviour_2")
    build(robot)
    assert colcon_ran(robot) == {"behaviour_2": "built"}
    # The unchanged dependencies were found in install/: the rebuilt node imports them.
    assert (robot / "ws/install/behaviour_2/lib/behaviour_2/behaviour_2_node").is_file()
    with containers_created(robot) as created:
        noop = build(robot)
    assert "up to date" in noop.stdout and created == []


def test_a_changed_interface_package_rebuilds_its_dependents(robot):
    """Interface packages on it too: rosidl's incremental build kept their type descriptions, and
    so their hash of its message, from before the change (a node then aborts on a hash assertion)."""
    state = write_interface_package(robot / "ws/src", "robot_state_msgs", service=False, uses="robot_msgs")
    try:
        build(robot)
        message = robot / "ws/src/robot_msgs/msg/WheelSpeeds.msg"
        message.write_text(message.read_text() + "float64 battery_voltage\n")
        built = build(robot)
        # Not the Python drivers, which only run with it (exec_depend): their setup.py reads nothing
        # of it. But the nodes built on the drivers (a `depend`): colcon's environment for their
        # builds holds what the drivers run with, and a build may run a driver's code.
        behaviours = [p.name for p in (robot / "ws/src").iterdir() if p.name.startswith("behaviour_")]
        assert colcon_ran(robot) == dict.fromkeys(("robot_msgs", "robot_state_msgs", *behaviours), "built")
        assert "up to date" in espdock("build", "--dry-run", cwd=robot).stdout
        generated = robot / "ws/install/robot_msgs/share/robot_msgs/msg/WheelSpeeds.msg"
        assert "battery_voltage" in generated.read_text()
        description = json.loads((robot / "ws/install/robot_state_msgs/share/robot_state_msgs/msg/RobotState.json")
                                 .read_text())  # fmt: skip
        referenced = description["type_description_msg"]["referenced_type_descriptions"]
        (wheels,) = [t for t in referenced if t["type_name"].endswith("WheelSpeeds")]
        assert "battery_voltage" in {field["name"] for field in wheels["fields"]}, wheels
        assert "building robot_state_msgs afresh" in " ".join(built.stdout.split())
    finally:
        for tree in (state, *(robot / "ws" / rel / "robot_state_msgs" for rel in ("install", "build/espdock-ros"))):
            shutil.rmtree(tree, ignore_errors=True)


def test_colcon_meta_and_options_after_the_double_dash_reach_colcon_and_decide_the_stamps(robot):
    meta = robot / "ws/colcon.meta"
    meta.write_text('{"names": {"behaviour_0": {"cmake-args": []}}}\n')
    try:
        build(robot)
        assert colcon_ran(robot) == {"behaviour_0": "built"}, "what colcon.meta says about one package rebuilds it"
        meta.write_text('{"names": {"robot_msgs": {"cmake-args": ["-DESPDOCK_TEST_MARK=from_meta"]}}}\n')
        build(robot, "robot_msgs")
        assert colcon_ran(robot) == {"robot_msgs": "built"}
        cache = robot / "ws/build/espdock-ros/robot_msgs/CMakeCache.txt"
        assert "ESPDOCK_TEST_MARK:UNINITIALIZED=from_meta" in cache.read_text(), "colcon itself read colcon.meta"
    finally:
        meta.unlink()
    build(robot, "robot_msgs", "--", "--cmake-args", "-DESPDOCK_TEST_MARK=from_args")
    assert colcon_ran(robot) == {"robot_msgs": "built"}, "a changed colcon.meta and changed options rebuild"
    assert "ESPDOCK_TEST_MARK:UNINITIALIZED=from_args" in cache.read_text()
    build(robot, "robot_msgs")  # back to the settings its dependents were built against
    assert colcon_ran(robot) == {"robot_msgs": "built"}
    # As a fresh build makes it: the option taken out stayed in CMake's cache.
    assert "ESPDOCK_TEST_MARK" not in cache.read_text()
    edit(robot / "ws/src/behaviour_0")
    edit(robot / "ws/src/behaviour_2")
    result = build(robot, "behaviour_0", "behaviour_2", "--", "--packages-skip", "behaviour_2")
    assert colcon_ran(robot) == {"behaviour_0": "built"}, "--packages-skip really skipped behaviour_2"
    assert "1 not built (behaviour_2)" in result.stdout
    build(robot, "behaviour_0", "behaviour_2", "--", "--parallel-workers", "1")
    assert colcon_ran(robot) == {"behaviour_2": "built"}, "a skipped package is not stamped as built"
    # The workspace's defaults file skips a package a selection leaves out: colcon, shown only the
    # selection, warned "ignoring unknown package 'behaviour_2' in --packages-skip".
    defaults = robot / "ws/colcon_defaults.yaml"
    defaults.write_text("build:\n  packages-skip:\n    - behaviour_2\n")
    try:
        edit(robot / "ws/src/behaviour_0")
        selected = build(robot, "behaviour_0")
    finally:
        defaults.unlink()
    assert colcon_ran(robot) == {"behaviour_0": "built"}
    assert "ignoring unknown package" not in selected.stdout + selected.stderr, selected.stdout[-3000:]


def test_a_failing_package_is_named_and_continue_on_error_builds_the_others(engine, robot):
    setup = robot / "ws/src/driver_0/setup.py"
    original = setup.read_text()
    # Discovery still reads setup.py; the build cannot copy a data file that is not there.
    setup.write_text(original.replace("['resource/' + package_name]", "['resource/' + package_name, 'resource/gone']"))
    edit(robot / "ws/src/driver_1")
    try:
        failed = build(robot, code=5)
        assert "colcon build failed (exit code 1) in driver_0" in failed.stderr
        assert "driver_0: its own build failed; log: " in failed.stderr
        assert "Fix driver_0" in failed.stderr
        ran = colcon_ran(robot)
        assert ran["driver_0"].startswith("failed")
        if all(state != "built" for state in ran.values()):
            assert "No package was built" in failed.stderr and "kept" not in failed.stderr
        kept_going = build(robot, "--", "--continue-on-error", code=5)
        ran = colcon_ran(robot)
        assert ran["driver_0"].startswith("failed")
        # What the first run built before it stopped is kept, so it need not run again here.
        assert all(ran.get(name, "built") == "built" for name in ("driver_1", "behaviour_1", "behaviour_3")), ran
        assert "behaviour_0" not in ran or ran["behaviour_0"] == "skipped"
        if "built" in ran.values():
            assert "that built are kept" in kept_going.stderr
    finally:
        setup.write_text(original)
    final = build(robot, "--", "--continue-on-error")
    # What built was kept; driver_0, built afresh for its setup.py edit, got its install back when
    # that failed, and behaviours 0 and 2, never started, kept theirs: with setup.py as it was,
    # nothing is left to build.
    assert "up to date (7 package(s))" in final.stdout, final.stdout[-2000:]
    assert leftover_containers(engine, robot) == []


def test_a_dependency_the_options_left_unbuilt_is_named_not_the_package_that_needs_it(engine, tmp_path):
    """`-- --packages-skip robot_msgs` where robot_msgs was never built: colcon fails driver_0
    before its build begins ("Check that the following packages have been built: robot_msgs"),
    and espdock said driver_0's own build failed, naming a log colcon never wrote."""
    root = copy_workspace(tmp_path / "ws-root", packages=(), runtime_image=False)
    write_robot(root / "ws/src", 3, service=False)
    try:
        failed = build(root, "--", "--packages-skip", "robot_msgs", code=5)
    finally:
        engine.remove_containers({"io.espdock.workspace": str(root)})
    said = " ".join(failed.stderr.split())
    assert "driver_0: could not find robot_msgs" in said, said
    assert "its own build failed" not in said and "Fix driver_0" not in said, said
    assert "robot_msgs is a package of this workspace that driver_0 depends on and that is not built" in said, said
    assert "log/latest_build/driver_0" not in said, "a log colcon never wrote"


def test_a_malformed_colcon_meta_and_an_empty_double_dash_build_nothing(robot):
    latest = (robot / "ws/log/latest_build").resolve()
    edit(robot / "ws/src/behaviour_3")
    meta = robot / "ws/colcon.meta"
    meta.write_text('{"names": {"behaviour_3": ')
    try:
        with containers_created(robot) as created:
            result = build(robot, code=2)
            empty = build(robot, "--", code=2)
        assert "colcon.meta is not a valid colcon.meta" in result.stderr
        assert "nothing after `--`" in empty.stderr
        assert created == []
        assert (robot / "ws/log/latest_build").resolve() == latest, "colcon did not run"
    finally:
        meta.unlink()
    build(robot)
    assert colcon_ran(robot) == {"behaviour_3": "built"}


def test_a_c_node_on_rcl_on_the_wheels_image_is_told_to_use_the_official_one(engine, tmp_path):
    """rcl is on the wheels image (rclpy's), so the dependency check passed it; CMake then failed
    in the image's own Fast DDS files (OpenSSL), and the hint said to fix the package."""
    root = copy_workspace(tmp_path / "w", packages=(), test_packages=("rcl_heartbeat",), runtime_image=False)
    try:
        failed = build(root, code=5)
        said = " ".join(failed.stderr.split())
        assert "rcl_heartbeat: the wheels image's Fast DDS CMake files failed in its configure" in said, said
        assert 'Build C and C++ nodes on the official image (ros_image = "official")' in said
        assert "Fix rcl_heartbeat" not in said
    finally:
        engine.remove_containers({"io.espdock.workspace": str(root)})
