"""rosdep keys from package.xml installed into the ROS build image, in either flavour: the
wheels image (real) and the official ros:jazzy-ros-base image (its contract double,
tests/ros_official_double). The tests' rosdep database holds real rules (tests/rosdep_db).

Both build the same two packages: rosdeps_py_table (ament_python, a pip key and a Python
key) and rosdeps_xml_count (ament_cmake C++, no rclcpp, an apt library key).
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

from espdock.config import Config, resolve_ca_bundle
from tests.conftest import REPO, espdock, in_workspace_image
from tests.ros_official_double.build import build_double, settings
from tests.rosdep_db import environment

pytestmark = [pytest.mark.engine, pytest.mark.slow]

PACKAGES = ("rosdeps_py_table", "rosdeps_xml_count")
# The workspace's name, and so its runtime image's: its own, where other tests' workspaces named
# `w` made espdock/w:latest at the same time on other workers, and the check ran one of theirs.
NAME = "rosdeps-ws"
# Run in the build image with the workspace's install sourced: the apt library is linked and
# the pip and Python keys import, as the nodes would at run time.
CHECK = (
    "set -e; . install/setup.sh; "
    "install/rosdeps_xml_count/lib/rosdeps_xml_count/xml_count robot.xml; "
    "python3 -m rosdeps_py_table.table; "
    'python3 -c "import numpy, tabulate; print(tabulate.__file__)"'
)


def make_workspace(root: Path) -> Path:
    (root / "src").mkdir(parents=True)
    for name in PACKAGES:
        shutil.copytree(REPO / "tests/ros_packages" / name, root / "src" / name)
    (root / "espdock.toml").write_text("[espdock]\n")
    (root / "robot.xml").write_text("<robot><link/><link/><joint><parent/></joint></robot>\n")
    return root


def build_and_check(root: Path, tmp_path: Path, extra: dict[str, str]) -> tuple[dict, list[str]]:
    """espdock build of ROOT with EXTRA settings; the lock it made, and CHECK's output in its image."""
    env = {**environment(tmp_path), **extra}
    build = espdock("build", "--runtime-image", "--report", str(tmp_path / "report.json"), cwd=root, env=env)
    assert build.returncode == 0, build.stdout[-3000:] + build.stderr
    lock = json.loads((root / "rosdep.lock.json").read_text())
    manifest = json.loads((tmp_path / "report.json").read_text())["manifest"]
    (tag,) = [image for image in manifest["images"] if "-build:" in image]
    run = in_workspace_image(tag, root, "sh", "-c", CHECK)
    assert run.returncode == 0, run.stdout + run.stderr
    # The runtime image of the workspace (espdock/<NAME>:latest), of either flavour: the node's
    # package, its rosdep keys and rclpy import there, with no workspace mounted.
    # setuptools too, a declared dependency (pkg_resources) the runtime image's slimming removed.
    imports = "import rclpy, numpy, setuptools, tabulate, rosdeps_py_table.table; print('runtime ok')"
    runtime = subprocess.run(
        ["docker", "run", "--rm", f"espdock/{NAME}:latest", "python3", "-c", imports],
        capture_output=True, text=True, check=False, timeout=120,
    )  # fmt: skip
    assert runtime.stdout.strip().endswith("runtime ok"), runtime.stdout + runtime.stderr
    again = espdock("build", cwd=root, env=env)
    assert again.returncode == 0 and "up to date" in again.stdout, again.stdout[-2000:]
    return lock, run.stdout.splitlines()


def test_the_wheels_image_installs_the_pip_python_and_apt_keys(tmp_path):
    root = make_workspace(tmp_path / NAME)
    lock, output = build_and_check(root, tmp_path, {})
    assert lock["ros_image"] == "wheels" and lock["os"] == "debian:bookworm"
    assert lock["apt"] == ["libtinyxml2-dev"]
    # The venv cannot see apt's python3-numpy: the lock serves it from PyPI, beside tabulate.
    assert lock["keys"]["python3-numpy"]["installer"] == "pip"
    assert sorted(line.split("==")[0] for line in lock["pip"]) == ["numpy", "setuptools", "tabulate"]
    assert all("--hash=sha256:" in line for line in lock["pip"])
    assert output[0] == "5 elements"
    assert output[-1].startswith("/opt/espdock/venv/")  # tabulate in the nodes' venv


def test_the_official_flavour_builds_through_the_same_plumbing_against_its_double(tmp_path, engine):
    tag = build_double(engine, resolve_ca_bundle(Config(), os.environ), lambda line: None)
    root = make_workspace(tmp_path / NAME)
    lock, output = build_and_check(root, tmp_path, settings(tag))
    assert lock["ros_image"] == "official" and lock["os"] == "ubuntu:noble"
    # Every ROS package goes through rosdep as apt's ros-jazzy-*, the image's own (installed).
    assert {"ros-jazzy-rclpy", "ros-jazzy-std-msgs", "ros-jazzy-ament-cmake"} <= set(lock["apt"])
    assert {"libtinyxml2-dev", "python3-numpy"} <= set(lock["apt"])  # system Python sees apt's numpy
    assert [line.split("==")[0] for line in lock["pip"]] == ["tabulate"]
    assert output[0] == "5 elements"
    assert not output[-1].startswith("/opt/espdock/")  # the image's system Python, no venv
