"""Two builds of one commit, in two clones at different paths, install bit-identical files.

ROS packages (colcon in the real ROS image) and firmware (the IDF contract double standing
in for ESP-IDF; see tests/idf_contract_double/README.md). The double models what decides
reproducibility in a real IDF build: build date and time, and source paths in debug info.
"""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path

import pytest

from espdock.build.manifest import MANIFEST_NAME, file_hashes, read_manifest
from espdock.config import Config, resolve_ca_bundle
from tests.conftest import REPO, copy_workspace, espdock, message_package
from tests.idf_contract_double.build import use_double

pytestmark = [pytest.mark.engine, pytest.mark.slow]

USER_UID = 4244
COMMIT_DATE = "2026-01-02T03:04:05+00:00"


def git(*args: str, cwd: Path) -> str:
    env = {
        **os.environ,
        "GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@example.invalid", "GIT_AUTHOR_DATE": COMMIT_DATE,
        "GIT_COMMITTER_NAME": "t", "GIT_COMMITTER_EMAIL": "t@example.invalid", "GIT_COMMITTER_DATE": COMMIT_DATE,
    }  # fmt: skip
    result = subprocess.run(["git", *args], cwd=cwd, env=env, capture_output=True, text=True, check=True)
    return result.stdout


@pytest.fixture(scope="module")
def commit(tmp_path_factory, engine) -> tuple[Path, dict[str, str]]:
    """A git repository holding one commit of a workspace: interfaces, a Python package, firmware.

    One of each kind, each small: the LED strip firmware (the camera's needs a library with
    the demo's interfaces compiled in), an interface package of a message and a service, beacon_nodes."""
    origin = copy_workspace(tmp_path_factory.mktemp("origin") / "repo", (), ("beacon_nodes",))
    # A service answering with the package's own message: rosidl writes the includes of its type
    # description in set order, so a hash seed left to chance shows in its __description.c.
    message_package(origin / "ws/src/custom_interface", services=("GetCameraConfig",))
    same_name_package(origin / "ws/src/same_name_installs")
    shutil.copy2(REPO / "Dockerfile.idf", origin / "Dockerfile.idf")
    shutil.copytree(REPO / "firmware", origin / "firmware", ignore=shutil.ignore_patterns("camera_node"))
    double_env = use_double(engine, resolve_ca_bundle(Config(), os.environ), lambda line: None, origin)
    git("init", "-q", cwd=origin)
    git("add", "-A", cwd=origin)
    git("commit", "-q", "-m", "one commit", cwd=origin)
    return origin, double_env


def same_name_package(path: Path) -> None:
    """An ament_cmake package installing two files of one name to one place, as an interface package
    installs rosidl_generator_c's and rosidl_typesupport_introspection_c's detail/X__type_support.c."""
    for part in ("first", "second"):
        (path / part).mkdir(parents=True)
        (path / part / "x__type_support.c").write_text(f"/* {part} generator */\n")
    (path / "CMakeLists.txt").write_text(
        "cmake_minimum_required(VERSION 3.16)\nproject(same_name_installs NONE)\nfind_package(ament_cmake REQUIRED)\n"
        "install(FILES first/x__type_support.c DESTINATION share/${PROJECT_NAME})\n"
        "install(FILES second/x__type_support.c DESTINATION share/${PROJECT_NAME})\nament_package()\n"
    )
    (path / "package.xml").write_text(
        '<?xml version="1.0"?>\n<package format="3"><name>same_name_installs</name><version>0.1.0</version>'
        '<description>Two files, one path</description><maintainer email="t@example.invalid">t</maintainer>'
        "<license>MIT</license><buildtool_depend>ament_cmake</buildtool_depend>"
        "<export><build_type>ament_cmake</build_type></export></package>\n"
    )


def clone_and_build(origin: Path, where: Path, env: dict[str, str]) -> Path:
    where.parent.mkdir(parents=True)
    git("clone", "-q", str(origin), str(where), cwd=where.parent)
    # Generated in the same second, as two generators of one build mostly are.
    for generated in (where / "ws/src/same_name_installs").glob("*/x__type_support.c"):
        os.utime(generated, (1767225600, 1767225600))
    subprocess.run(["chown", "-R", f"{USER_UID}:{USER_UID}", str(where)], check=True)
    result = espdock("build", cwd=where, env=env)
    assert result.returncode == 0, result.stdout[-4000:] + result.stderr
    return where / "ws" / "install"


def test_two_clones_of_a_commit_install_identical_files(commit, tmp_path):
    origin, double_env = commit
    first = clone_and_build(origin, tmp_path / "a" / "clone", double_env)
    second = clone_and_build(origin, tmp_path / "b" / "somewhere" / "deeper" / "other-name", double_env)

    one, two = file_hashes(first), file_hashes(second)
    assert any(name.endswith(".pyc") for name in one), "the Python package's bytecode is part of the check"
    assert any(name.endswith(".so") for name in one), "so are the interfaces' compiled libraries"
    assert any(name.endswith("/led_strip_node.bin") for name in one), "and the firmware"
    assert any(name.endswith("/led_strip_node.elf") for name in one)
    # `ros2 run` commands find the workspace from their own place, so they hold no clone's path.
    assert any(name.endswith("led_strip_node/lib/led_strip_node/flash") for name in one)
    # The interfaces' egg-info lists the modules rosidl generates: whether it did was up to make -j's
    # timing (ament_cmake_python copied the package for `setup.py egg_info` whenever it came to it).
    for install in (first, second):
        (sources,) = install.glob("custom_interface/lib/python3*/site-packages/custom_interface-*.egg-info/SOURCES.txt")
        assert "custom_interface/msg/_camera_config.py" in sources.read_text().split(), sources.read_text()
    # The file of one path installed twice is the last one installed, whatever the two files' times.
    for install in (first, second):
        installed = install / "same_name_installs/share/same_name_installs/x__type_support.c"
        assert installed.read_text() == "/* second generator */\n", "CMake kept the first: its time was the same"
    differing = sorted(name for name in one.keys() | two.keys() if one.get(name) != two.get(name))
    assert differing == [], f"{len(differing)} of {len(one)} installed files differ, e.g. {differing[:10]}"
    assert read_manifest(first / MANIFEST_NAME) == read_manifest(second / MANIFEST_NAME)
