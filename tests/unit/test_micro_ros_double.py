"""The micro-ROS side of the IDF contract double (tests/idf_contract_double), run on the host: it
must refuse, and leave out, what the real library build (colcon running rosidl on each interface
package) refuses and leaves out."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

from tests.conftest import REPO

COMPONENT = REPO / "tests/idf_contract_double/micro_ros_component"


def generate(src: Path, out: Path) -> subprocess.CompletedProcess[str]:
    argv = [sys.executable, str(COMPONENT / "double/generate.py"), "--src", str(src), "--headers",
            str(COMPONENT / "double/headers"), "--out", str(out / "out"), "--gen", str(out / "gen"),
            "--colcon-meta", str(COMPONENT / "colcon.meta"), "--target", "esp32"]  # fmt: skip
    return subprocess.run(argv, capture_output=True, text=True, check=False, timeout=120)


def test_only_the_interfaces_the_cmakelists_names_get_headers_as_rosidl_makes_them(tmp_path):
    """A .msg in msg/ that rosidl_generate_interfaces does not name gets no header from rosidl; the
    double made one, so a firmware including it built here and not with the real library."""
    package = tmp_path / "src/custom_interface"
    shutil.copytree(REPO / "ws/src/custom_interface", package)
    (package / "msg/Draft.msg").write_text("int32 not_listed_yet\n")
    made = generate(tmp_path / "src", tmp_path / "a")
    assert made.returncode == 0, made.stderr
    headers = {p.name for p in (tmp_path / "a/out/include/custom_interface/custom_interface/msg").glob("*.h")}
    assert "camera_config.h" in headers and "draft.h" not in headers

    cmake = package / "CMakeLists.txt"
    cmake.write_text(cmake.read_text().replace('"msg/CameraConfig.msg"', '"msg/CameraConfig.msg"\n  "msg/Gone.msg"'))
    refused = generate(tmp_path / "src", tmp_path / "b")
    assert refused.returncode == 1
    assert "rosidl_generate_interfaces() the passed file 'msg/Gone.msg' doesn't exist" in refused.stderr
    assert not (tmp_path / "b/out").exists(), "a refused build leaves nothing"


def test_a_bounded_string_constant_is_refused_as_rosidl_refuses_it(tmp_path):
    """rosidl_adapter takes only primitive types as constants, and `string<=8` is none: the ROS
    side refused it, the double built a library and firmware with it."""
    package = tmp_path / "src/custom_interface"
    shutil.copytree(REPO / "ws/src/custom_interface", package)
    message = package / "msg/CameraConfig.msg"
    message.write_text(message.read_text() + 'string<=8 LABEL="probe"\nstring PLAIN="ok"\n')
    refused = generate(tmp_path / "src", tmp_path / "a")
    assert refused.returncode == 1
    assert "error: the constant type 'string<=8' must be a primitive type" in refused.stderr
    message.write_text(message.read_text().replace('string<=8 LABEL="probe"\n', ""))
    assert generate(tmp_path / "src", tmp_path / "b").returncode == 0, "an unbounded string constant is one"


def test_a_package_requiring_what_the_upstream_tree_lacks_fails_as_cmake_fails_there(tmp_path):
    """An interface package with a node beside its interfaces (rclcpp): upstream's colcon runs its
    whole CMakeLists.txt, with no rclcpp in the tree and no *_cpp package built, and CMake fails;
    the double read only the interface names and built the library."""
    package = tmp_path / "src/custom_interface"
    shutil.copytree(REPO / "ws/src/custom_interface", package)
    cmake = package / "CMakeLists.txt"
    plain = cmake.read_text()
    cmake.write_text(
        plain + "if(BUILD_TESTING)\n  find_package(rclcpp REQUIRED)\nendif()\nfind_package(rclc REQUIRED)\n"
    )
    assert generate(tmp_path / "src", tmp_path / "a").returncode == 0, "BUILD_TESTING is OFF there; rclc is in the tree"
    cmake.write_text(plain + "find_package(rclcpp REQUIRED)\n")
    refused = generate(tmp_path / "src", tmp_path / "b")
    assert refused.returncode == 1
    assert 'asked CMake to find a package configuration file provided by "rclcpp", but CMake did not find one' in (
        refused.stderr
    )
    assert not (tmp_path / "b/out").exists(), "a refused build leaves nothing"
