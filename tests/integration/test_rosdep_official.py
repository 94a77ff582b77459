"""The official flavour's rosdep installs beside what its apt installed: the pip lock keeps the
image's own Python packages (noble's numpy 1.26) at their versions, apt adds what is missing
without upgrading what the image has, and a missing official image is not "fixed" with a
Debian one. Against the official image's double (tests/ros_official_double) and real apt."""

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


def make_workspace(root: Path, *names: str) -> Path:
    (root / "src").mkdir(parents=True)
    for name in names:
        shutil.copytree(REPO / "tests/ros_packages" / name, root / "src" / name)
    (root / "espdock.toml").write_text("[espdock]\n")
    return root


def test_the_pip_lock_keeps_what_the_official_images_apt_installed(tmp_path, engine):
    tag = build_double(engine, resolve_ca_bundle(Config(), os.environ), lambda line: None)
    root = make_workspace(tmp_path / "w", "rosdeps_imu_filter")
    env = {**environment(tmp_path), **settings(tag)}
    build = espdock("build", "--report", str(tmp_path / "report.json"), cwd=root, env=env)
    assert build.returncode == 0, build.stdout[-3000:] + build.stderr
    lock = json.loads((root / "rosdep.lock.json").read_text())
    pins = dict(line.split(" ")[0].split("==") for line in lock["pip"])
    # ahrs needs numpy: the image's (1.26.4, as noble's apt has it), not PyPI's newest.
    assert pins["numpy"] == "1.26.4" and "ahrs" in pins
    # And ahrs's docutils is the one apt installed with colcon (Debian's python3-docutils 0.19).
    assert lock["system_python"] == {"version": "3.11", "kept_as_installed": {"docutils": "0.19", "numpy": "1.26.4"}}
    images = json.loads((tmp_path / "report.json").read_text())["manifest"]["images"]
    (image,) = [name for name in images if "-build:" in name]
    check = "import ahrs, numpy; from rosdeps_imu_filter.imu_filter import OrientationFilter; print(numpy.__version__)"
    run = in_workspace_image(image, root, "bash", "-c", f". install/setup.bash && python3 -c '{check}'")
    assert run.returncode == 0 and run.stdout.splitlines()[-1] == "1.26.4", run.stdout + run.stderr


# Real apt in a Debian container: a local archive holds a newer ros-jazzy-demo-nodes-py than the
# one installed (as packages.ros.org does a month after an image is released) and a package the
# image lacks; espdock's installer stages the lock's apt list as the image build does.
APT_SCENARIO = r"""
set -eu
mkdir -p /repo /tmp/debs /staged
deb() {
  dir=/tmp/debs/$1-$2; mkdir -p "$dir/DEBIAN"
  printf 'Package: %s\nVersion: %s\nArchitecture: all\nMaintainer: t <t@example.org>\nDescription: %s\n' \
    "$1" "$2" "$1" > "$dir/DEBIAN/control"
  dpkg-deb --build --root-owner-group "$dir" "/repo/$1_$2_all.deb" > /dev/null
}
deb ros-jazzy-demo-nodes-py 0.33.1-1noble.20240601
deb ros-jazzy-demo-nodes-py 0.33.5-1noble.20250101
deb ros-jazzy-teleop-twist-keyboard 2.4.0-1noble.20250101
dpkg -i /repo/ros-jazzy-demo-nodes-py_0.33.1-1noble.20240601_all.deb > /dev/null
cd /repo
for f in *.deb; do
  dpkg-deb -f "$f" Package Version Architecture Maintainer Description
  printf 'Filename: ./%s\nSize: %s\nSHA256: %s\n\n' "$f" "$(stat -c %s "$f")" "$(sha256sum "$f" | cut -d' ' -f1)"
done > Packages
rm -f /etc/apt/sources.list /etc/apt/sources.list.d/*
echo 'deb [trusted=yes] file:/repo ./' > /etc/apt/sources.list
printf '# staged\nros-jazzy-demo-nodes-py\nros-jazzy-teleop-twist-keyboard\n' > /staged/apt.txt
printf '# staged\n' > /staged/pip.txt
sh /rosdep-install.sh /staged python3 > /dev/null
dpkg-query -W ros-jazzy-demo-nodes-py ros-jazzy-teleop-twist-keyboard
"""


def test_apt_adds_what_the_image_lacks_and_upgrades_nothing_it_has(engine):
    run = subprocess.run(
        ["docker", "run", "--rm", "--network", "none",
         "-v", f"{REPO / 'docker/rosdep-install.sh'}:/rosdep-install.sh:ro",
         "debian:bookworm-slim", "sh", "-c", APT_SCENARIO],
        capture_output=True, text=True, check=False, timeout=300,
    )  # fmt: skip
    assert run.returncode == 0, run.stdout + run.stderr
    assert run.stdout.splitlines() == [
        "ros-jazzy-demo-nodes-py\t0.33.1-1noble.20240601",
        "ros-jazzy-teleop-twist-keyboard\t2.4.0-1noble.20250101",
    ]


def test_a_missing_official_image_is_not_pointed_at_a_debian_one(tmp_path, engine):
    root = make_workspace(tmp_path / "w", "rosdeps_xml_count")
    missing = "espdock-test/no-such-ros:jazzy-ros-base"
    env = {**environment(tmp_path), "ESPDOCK_ROS_IMAGE": "official", "ESPDOCK_BASE_IMAGE": missing}
    result = espdock("build", cwd=root, env=env)
    assert result.returncode == 4, result.stdout[-2000:] + result.stderr
    assert f"the official ROS image {missing} is not here" in result.stderr
    assert "docker load" in result.stderr and "Debian" not in result.stderr
