"""Packages written as upstream drivers write theirs, built by the real colcon in the wheels
image: a dual ROS 1/ROS 2 driver (conditions on its dependencies and build type, CMake that
reads ROS_VERSION) and a serial GPS driver whose python3-serial key must be pyserial."""

from __future__ import annotations

import json
import shutil

import pytest

from tests.conftest import REPO, espdock, in_workspace_image
from tests.rosdep_db import environment

pytestmark = [pytest.mark.engine, pytest.mark.slow]

# The textbook GGA sentence (checksum 47): 48°07.038' N, 11°31.000' E, 545.4 m.
GGA = "$GPGGA,123519,4807.038,N,01131.000,E,1,08,0.9,545.4,M,46.9,M,,*47"
CHECK = (
    "set -e; . install/setup.sh; "
    "colcon list --base-paths src; "
    "echo R1234 | install/rosdeps_dual_driver/lib/rosdeps_dual_driver/range_driver; "
    'python3 -c "import serial, sys; from rosdeps_serial_gps.serial_gps import read_fixes; '
    "port = serial.serial_for_url('loop://', timeout=1); port.write(sys.argv[1].encode() + b'\\r\\n'); "
    "print(read_fixes(port, 1))\" '" + GGA + "'"
)


def test_a_dual_ros1_ros2_driver_and_a_serial_driver_build_and_run_in_the_wheels_image(tmp_path):
    root = tmp_path / "w"
    (root / "src").mkdir(parents=True)
    for name in ("rosdeps_dual_driver", "rosdeps_serial_gps"):
        shutil.copytree(REPO / "tests/ros_packages" / name, root / "src" / name)
    (root / "espdock.toml").write_text("[espdock]\n")
    env = environment(tmp_path)
    build = espdock("build", "--report", str(tmp_path / "report.json"), cwd=root, env=env)
    assert build.returncode == 0, build.stdout[-3000:] + build.stderr
    images = json.loads((tmp_path / "report.json").read_text())["manifest"]["images"]
    (tag,) = [image for image in images if "-build:" in image]
    run = in_workspace_image(tag, root, "sh", "-c", CHECK)
    assert run.returncode == 0, run.stdout + run.stderr
    lines = run.stdout.splitlines()
    # colcon-ros evaluates the conditions with the image's ROS_VERSION: ament_cmake, not catkin.
    assert "rosdeps_dual_driver\tsrc/rosdeps_dual_driver\t(ros.ament_cmake)" in lines
    assert "range 1.234 m" in lines
    # pyserial's serial module (PyPI's `serial` has no serial_for_url): the fix, parsed.
    (fix,) = [line for line in lines if line.startswith("[(")]
    latitude, longitude, altitude = (float(v) for v in fix.strip("[()]").split(","))
    assert (round(latitude, 4), round(longitude, 4), altitude) == (48.1173, 11.5167, 545.4)
    # An option colcon does not know: named, and the packages stay built.
    unknown = espdock("build", "--", "--frobnicate", cwd=root, env=env)
    assert unknown.returncode == 2 and "colcon build does not accept --frobnicate" in unknown.stderr, unknown.stderr
    again = espdock("build", cwd=root, env=env)
    assert again.returncode == 0 and "up to date" in again.stdout, again.stdout[-2000:]
