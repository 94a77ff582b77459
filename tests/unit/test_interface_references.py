"""Which other packages an interface package's files use types of, as rosidl reads them."""

from __future__ import annotations

from pathlib import Path

from espdock.ros.interfaces import references, undeclared
from espdock.workspace import Package, PackageKind

FILES = {
    "msg/State.msg": (
        b"# geometry_msgs/Pose in a comment is no field\n"
        b"std_msgs/Header header\n"
        b"robot_msgs/msg/WheelSpeeds[] wheels   # the package's msg/ spelled out, an unbounded array\n"
        b"nav_msgs/Odometry[<=3] recent\n"
        b"State previous_is_own\n"
        b"int32 LIMIT=3\n"
        b"string<=8 name\n"
    ),
    "srv/Plan.srv": b"geometry_msgs/PoseStamped goal\n---\nrobot_state_msgs/State result\n",
    "action/Dock.action": b"float64 distance\n---\nbool docked\n---\nsensor_msgs/BatteryState battery\n",
    "msg/Extra.idl": b'#include "shape_msgs/msg/Mesh.idl"\nmodule robot_state_msgs { };\n',
    "CMakeLists.txt": b"tf2_msgs/TFMessage is not an interface file\n",
}


def test_field_types_and_idl_includes_name_the_packages_they_come_from():
    assert references(FILES) == {
        "std_msgs": ("std_msgs/Header", "msg/State.msg"),
        "robot_msgs": ("robot_msgs/WheelSpeeds", "msg/State.msg"),
        "nav_msgs": ("nav_msgs/Odometry", "msg/State.msg"),
        "geometry_msgs": ("geometry_msgs/PoseStamped", "srv/Plan.srv"),
        "robot_state_msgs": ("robot_state_msgs/State", "srv/Plan.srv"),
        "sensor_msgs": ("sensor_msgs/BatteryState", "action/Dock.action"),
        "shape_msgs": ("shape_msgs/Mesh", "msg/Extra.idl"),
    }


def test_a_used_package_only_a_test_depend_names_is_undeclared():
    package = Package(
        name="robot_state_msgs", path=Path("/w/src/robot_state_msgs"), kind=PackageKind.ROS,
        build_type="ament_cmake", is_interface=True,
        depends=frozenset({"std_msgs", "nav_msgs", "geometry_msgs", "sensor_msgs", "shape_msgs", "robot_msgs"}),
        test_only_depends=frozenset({"robot_msgs"}),
    )  # fmt: skip
    (line,) = undeclared(package, FILES)
    assert line.startswith("robot_state_msgs uses robot_msgs/WheelSpeeds (msg/State.msg), but its package.xml")
    assert line.endswith("Add <depend>robot_msgs</depend> to /w/src/robot_state_msgs/package.xml")
