"""A ROS developer's habits with the real colcon in the real ROS image: `--symlink-install`, and a
workspace also built with colcon outside espdock (a "native" build: colcon in the same image, but
with the workspace at its host path, as colcon on the host records it).

Packages: beacon_nodes (ament_python) and uptime_tools (ament_cmake: a compiled executable and
an installed script), both under tests/ros_packages.
"""

from __future__ import annotations

import json
import os
import random
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from espdock.build.prepare import build_plan
from espdock.build.stamps import listing_digest
from espdock.config import Config, load_config, resolve_ca_bundle
from espdock.ros.plan import ColconBuild
from espdock.ros.staleness import colcon_rebuild
from espdock.workspace import PackageKind, find_workspace
from tests.conftest import REPO, Started, copy_workspace, espdock, ros_build_tag
from tests.ros_official_double.build import build_double, settings
from tests.rosdep_db import environment

pytestmark = [pytest.mark.engine, pytest.mark.slow]

PACKAGES = ("beacon_nodes", "uptime_tools")


def built(root: Path, *args: str, env: dict[str, str] | None = None) -> None:
    result = espdock("build", "--only", "ros", *args, cwd=root, env=env)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]


def run_once(
    root: Path, package: str, executable: str, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    return espdock("run", package, executable, cwd=root, timeout=300, env=env)


def beacon_says(root: Path, text: str, env: dict[str, str] | None = None) -> None:
    domain = {"ROS_DOMAIN_ID": str(random.randrange(100, 200))}
    node = Started(root, "run", "beacon_nodes", "beacon", env={**(env or {}), **domain})
    try:
        node.wait_for(text)
        assert node.interrupt() == 130
    finally:
        node.stop()


def native_colcon(
    root: Path, *args: str, at: str | None = None, underlay: Path | None = None
) -> subprocess.CompletedProcess[str]:
    """`colcon build` with the workspace at its own path, as on the developer's machine (AT: at
    another path in the container; UNDERLAY: a workspace sourced before, as /opt/ros/jazzy is)."""
    ws = str(root / "ws")
    inside = at or ws
    chain = ["-v", f"{underlay}:{underlay}:ro", "-e", f"COLCON_PREFIX_PATH={underlay}"] if underlay else []
    return subprocess.run(
        ["docker", "run", "--rm", "-u", f"{os.getuid()}:{os.getgid()}", "-e", "HOME=/tmp", *chain,
         "-v", f"{ws}:{inside}", "-w", inside, ros_build_tag(root), "colcon", "build", *args],
        capture_output=True, text=True, timeout=900, check=False,
    )  # fmt: skip


def test_symlink_install_builds_runs_and_shows_a_source_edit_without_a_rebuild(engine, tmp_path):
    """After a plain build, as a workspace is before the developer turns it on: colcon does not
    switch a build dir in place (an interface package failed, one per run), so espdock builds
    each package afresh when the option changes."""
    root = copy_workspace(tmp_path / "symlinks", packages=(), test_packages=PACKAGES)
    built(root)
    switched = espdock("build", "--only", "ros", "--", "--symlink-install", cwd=root)
    assert switched.returncode == 0, switched.stdout[-3000:] + switched.stderr[-3000:]
    assert "--symlink-install on since their last build: removed the build dirs and install prefixes of 2" in " ".join(
        switched.stdout.split()
    )
    install = root / "ws" / "install"
    # colcon really installed links: into build/ for the compiled tool, into src/ for the script.
    assert (install / "uptime_tools" / "lib" / "uptime_tools" / "uptime_report").is_symlink()
    assert (install / "uptime_tools" / "lib" / "uptime_tools" / "tools_banner").is_symlink()
    assert list((install / "beacon_nodes").rglob("*.egg-link")), "ament_python in develop mode"

    report = run_once(root, "uptime_tools", "uptime_report")
    assert report.returncode == 0 and "uptime_report: up" in report.stdout, report.stdout + report.stderr
    banner = run_once(root, "uptime_tools", "tools_banner")
    assert banner.returncode == 0 and "tools_banner: uptime_tools 0.1.0" in banner.stdout, banner.stderr
    # `#!/usr/bin/python3`, as many install(PROGRAMS) scripts have it: Debian's Python had no
    # rclpy in the wheels image ("No module named 'rclpy'"); it runs in the venv, where ROS is.
    python = run_once(root, "uptime_tools", "rclpy_banner")
    assert python.returncode == 0 and "rclpy_banner: rclpy from /opt/espdock/venv" in python.stdout, python.stderr
    beacon_says(root, "beacon up")

    # The same option from ~/.colcon/defaults.yaml, the tutorials' habit, builds nothing again (each
    # switch between the two configured every CMake package afresh and rebuilt it).
    home = tmp_path / "home"
    (home / ".colcon").mkdir(parents=True)
    (home / ".colcon/defaults.yaml").write_text("build:\n  symlink-install: true\n")
    from_defaults = espdock("build", "--only", "ros", cwd=root, env={**os.environ, "HOME": str(home)})
    said = " ".join(from_defaults.stdout.split())
    assert from_defaults.returncode == 0 and "afresh" not in said and "package(s) built" not in said, said[-3000:]

    # What a symlink install gives: an edited Python source runs without `colcon build`.
    source = root / "ws" / "src" / "beacon_nodes" / "beacon_nodes" / "beacon.py"
    source.write_text(source.read_text().replace('"beacon up"', '"beacon up, edited"'))
    beacon_says(root, "beacon up, edited")

    # And off again: copies, the sources untouched.
    sources = {p: p.read_bytes() for p in (root / "ws" / "src").rglob("*") if p.is_file()}
    built(root)
    assert not (install / "uptime_tools" / "lib" / "uptime_tools" / "tools_banner").is_symlink()
    assert {p: p.read_bytes() for p in (root / "ws" / "src").rglob("*") if p.is_file()} == sources
    beacon_says(root, "beacon up, edited")

    # A symlink build in `espdock shell` (its colcon builds in espdock's build base, and keeps no
    # record of the kind): its CMake cache keeps the option on, and every plain build after it was
    # a symlink install too (or failed on the directories the copying one had left, every time).
    shell = subprocess.run(
        [sys.executable, "-m", "espdock", "shell"], cwd=root, capture_output=True, text=True, timeout=600, check=False,
        input="colcon build --symlink-install --packages-select uptime_tools >/dev/null 2>&1; echo built: $?\n",
    )  # fmt: skip
    assert "built: " in shell.stdout, shell.stdout + shell.stderr
    built(root)
    assert not (install / "uptime_tools" / "lib" / "uptime_tools" / "tools_banner").is_symlink()


def test_a_cmake_package_installs_what_its_globs_and_its_rules_say_now(engine, tmp_path):
    """A script removed beside an edit (a branch switch) in a package that installs `file(GLOB)`'s
    list: CMake kept the list it was configured with, and every build failed on the removed file
    until --force; switched back, the file came back but was not installed. A target renamed in
    CMakeLists.txt, or an install rule taken out: what they had installed stayed, and `espdock
    run` ran the old executable (as colcon leaves it)."""
    root = copy_workspace(tmp_path / "globs", packages=(), test_packages=("uptime_tools",), runtime_image=False)
    package = root / "ws/src/uptime_tools"
    cmake = package / "CMakeLists.txt"
    cmake.write_text(
        cmake.read_text().replace(
            "install(PROGRAMS scripts/tools_banner DESTINATION lib/${PROJECT_NAME})",
            'file(GLOB SCRIPTS "${CMAKE_CURRENT_SOURCE_DIR}/scripts/*")\n'
            "install(PROGRAMS ${SCRIPTS} DESTINATION lib/${PROJECT_NAME})",
        )
    )
    lib = root / "ws/install/uptime_tools/lib/uptime_tools"
    extra = package / "scripts/extra_banner"
    extra.write_text("#!/bin/sh\necho extra\n")
    extra.chmod(0o755)
    built(root)
    assert (lib / "extra_banner").is_file()
    kept = extra.read_bytes()
    extra.unlink()
    (package / "src/uptime_report.c").write_text((package / "src/uptime_report.c").read_text() + "\n/* branch */\n")
    switched = espdock("build", "--only", "ros", cwd=root)
    assert switched.returncode == 0, switched.stdout[-3000:] + switched.stderr[-3000:]
    said = " ".join(switched.stdout.split())
    assert "configuring uptime_tools again" in said, said[-3000:]
    assert not (lib / "extra_banner").exists() and (lib / "tools_banner").is_file()
    extra.write_bytes(kept)
    extra.chmod(0o755)
    built(root)
    assert (lib / "extra_banner").is_file(), "a file back in the glob's directory is installed again"
    cmake.write_text(
        cmake.read_text()
        .replace("uptime_report src/uptime_report.c", "uptime_summary src/uptime_report.c")
        .replace("install(TARGETS uptime_report", "install(TARGETS uptime_summary")
    )
    renamed = espdock("build", "--only", "ros", cwd=root)
    assert renamed.returncode == 0, renamed.stdout[-3000:] + renamed.stderr[-3000:]
    said = " ".join(renamed.stdout.split())
    assert "installing afresh what changed its CMake files (or whose last build did not record" in said
    assert "them): uptime_tools" in said
    assert sorted(p.name for p in lib.iterdir()) == ["extra_banner", "rclpy_banner", "tools_banner", "uptime_summary"]
    gone = espdock("run", "uptime_tools", "uptime_report", cwd=root)
    assert gone.returncode == 2 and "uptime_summary" in gone.stderr, gone.stdout + gone.stderr
    # Skipped by the options after `--`, it keeps its install: colcon would not install it again.
    cmake.write_text(cmake.read_text() + "# skipped\n")
    skipped = espdock("build", "--only", "ros", "--", "--packages-skip", "uptime_tools", cwd=root)
    assert skipped.returncode == 0, skipped.stdout[-3000:] + skipped.stderr[-3000:]
    assert "installing afresh" not in skipped.stdout and (lib / "uptime_summary").is_file()
    # Built by an espdock that recorded no digest of its CMake files, whose leftovers of a rule taken
    # out stayed (as this one's before the rule above): its first build, nothing changed since,
    # installs it afresh once. An upgrade's build said "up to date", the leftover installed.
    built(root)  # the edit the skipped build left
    (lib / "uptime_report").write_text("#!/bin/sh\necho the old executable\n")
    stamps = root / "ws/build/.espdock-colcon-stamps.json"
    records = json.loads(stamps.read_text())
    records["uptime_tools"]["declares"] = ""
    # As the older espdock's build recorded it: with the file its install kept.
    records["uptime_tools"]["installed"] = listing_digest(root / "ws/install/uptime_tools")
    stamps.write_text(json.dumps(records))
    assert (
        "would build 1 of 1 package(s): uptime_tools" in espdock("build", "--only", "ros", "--dry-run", cwd=root).stdout
    )
    upgraded = espdock("build", "--only", "ros", cwd=root)
    assert upgraded.returncode == 0, upgraded.stdout[-3000:] + upgraded.stderr[-3000:]
    assert "whose last build did not record them): uptime_tools" in " ".join(upgraded.stdout.split())
    assert sorted(p.name for p in lib.iterdir()) == ["extra_banner", "rclpy_banner", "tools_banner", "uptime_summary"]
    assert "up to date" in espdock("build", "--only", "ros", "--dry-run", cwd=root).stdout  # once
    # And a rename after such a build is installed afresh too.
    records = json.loads(stamps.read_text())
    records["uptime_tools"]["declares"] = ""
    stamps.write_text(json.dumps(records))
    cmake.write_text(cmake.read_text().replace("uptime_summary", "uptime_digest"))
    built(root)
    assert sorted(p.name for p in lib.iterdir()) == ["extra_banner", "rclpy_banner", "tools_banner", "uptime_digest"]


WRAPPER_PACKAGE = """<?xml version="1.0"?>
<package format="3">
  <name>uptime_wrapper</name>
  <version>0.1.0</version>
  <description>Runs the monorepo's uptime report.</description>
  <maintainer email="dev@example.com">dev</maintainer>
  <license>Apache-2.0</license>
  <buildtool_depend>ament_cmake</buildtool_depend>
  <exec_depend>uptime_tools</exec_depend>
  <export><build_type>ament_cmake</build_type></export>
</package>
"""


def test_a_monorepo_s_shared_cmake_module_and_header_outside_the_package_rebuild_it(engine, tmp_path):
    """A repository of packages beside what they share (`include(../cmake/label.cmake)`, a
    `../include` of headers, a `../config` file installed): an edit of one was no change of the
    package's stamp, and espdock's build called it up to date and kept the old binary, where a
    native colcon build runs make, which rebuilds."""
    root = copy_workspace(tmp_path / "monorepo", packages=(), runtime_image=False)
    repo = root / "ws/src/robot_repo"
    package = repo / "uptime_tools"
    shutil.copytree(REPO / "tests/ros_packages/uptime_tools", package)
    for directory in ("cmake", "include/robot", "config", "tools", "uptime_wrapper"):
        (repo / directory).mkdir(parents=True)
    (repo / "cmake/label.cmake").write_text('set(REPORT_LABEL "first")\n')
    header = repo / "include/robot/unit.h"
    header.write_text('#define REPORT_UNIT "s"\n#include "vendor_limits.h"\n')
    # A vendor SDK linked in beside the packages, from outside the workspace: colcon and CMake
    # follow the link, and the build container found nothing there ("No such file or directory").
    sdk = tmp_path / "vendor-sdk"
    (sdk / "include").mkdir(parents=True)
    (sdk / "include/vendor_limits.h").write_text("#define VENDOR_LIMIT 3\n")
    (repo / "vendor").symlink_to(sdk)
    (repo / "config/report.yaml").write_text("period: 1\n")
    retired = repo / "tools/retired.c"
    retired.write_text("int main(void) { return 0; }\n")
    cmake = package / "CMakeLists.txt"
    cmake.write_text(
        cmake.read_text()
        .replace("find_package(ament_cmake REQUIRED)", "find_package(ament_cmake REQUIRED)\n"
                 "include(${CMAKE_CURRENT_SOURCE_DIR}/../cmake/label.cmake)")
        .replace("install(TARGETS",
                 "target_include_directories(uptime_report PRIVATE ${CMAKE_CURRENT_SOURCE_DIR}/../include\n"
                 "                           ${CMAKE_CURRENT_SOURCE_DIR}/../vendor/include)\n"
                 'target_compile_definitions(uptime_report PRIVATE "REPORT_LABEL=\\"${REPORT_LABEL}\\"")\n'
                 "add_executable(retired ${CMAKE_CURRENT_SOURCE_DIR}/../tools/retired.c)\n"
                 "install(DIRECTORY ${CMAKE_CURRENT_SOURCE_DIR}/../config DESTINATION share/${PROJECT_NAME})\n"
                 "install(TARGETS")
    )  # fmt: skip
    source = package / "src/uptime_report.c"
    source.write_text(
        '#include "robot/unit.h"\n'
        + source.read_text().replace(
            '"uptime_report: up %.0f s\\n", up', '"uptime_report: up %.0f %s (%s)\\n", up, REPORT_UNIT, REPORT_LABEL'
        )
    )  # fmt: skip
    wrapper = repo / "uptime_wrapper"
    (wrapper / "package.xml").write_text(WRAPPER_PACKAGE)
    (wrapper / "CMakeLists.txt").write_text(
        "cmake_minimum_required(VERSION 3.8)\nproject(uptime_wrapper NONE)\nfind_package(ament_cmake REQUIRED)\n"
        "install(PROGRAMS wrapper DESTINATION lib/${PROJECT_NAME})\nament_package()\n"
    )
    (wrapper / "wrapper").write_text(
        "#!/bin/sh\nexec /opt/espdock/ws/install/uptime_tools/lib/uptime_tools/uptime_report\n"
    )
    (wrapper / "wrapper").chmod(0o755)

    def reports(text: str) -> None:
        report = run_once(root, "uptime_tools", "uptime_report")
        assert report.returncode == 0 and text in report.stdout, report.stdout + report.stderr

    def builds(count: str) -> None:
        result = espdock("build", "--only", "ros", cwd=root)
        assert result.returncode == 0 and count in result.stdout, result.stdout[-3000:] + result.stderr[-2000:]

    built(root)
    reports(" s (first)")
    header.write_text('#define REPORT_UNIT "seconds"\n#include "vendor_limits.h"\n')
    stale = run_once(root, "uptime_tools", "uptime_report")
    warned = " ".join((stale.stdout + stale.stderr).split())
    assert "uptime_tools's sources changed since its last build" in warned, warned
    assert "what that build made of ws/src/robot_repo/include/robot/unit.h as it was then" in warned, warned
    # What depends on it is warned of as well: built on other sources of uptime_tools.
    through = run_once(root, "uptime_wrapper", "wrapper")
    warned = " ".join((through.stdout + through.stderr).split())
    assert "uptime_wrapper was built on other sources of the workspace packages it depends on" in warned, warned
    builds("2 package(s) built")
    reports(" seconds (first)")
    (repo / "cmake/label.cmake").write_text('set(REPORT_LABEL "second")\n')
    builds("2 package(s) built")
    reports(" seconds (second)")
    (repo / "config/report.yaml").write_text("period: 2\n")
    builds("2 package(s) built")
    config = root / "ws/install/uptime_tools/share/uptime_tools/config"
    assert (config / "report.yaml").read_text() == "period: 2\n"
    (repo / "config/limits.yaml").write_text("max: 3\n")  # one more file in the directory it installs
    builds("2 package(s) built")
    assert (config / "limits.yaml").read_text() == "max: 3\n"
    # A source no target compiles any more (its object's depfile stays in the build dir) is no input.
    cmake.write_text(
        cmake.read_text().replace("add_executable(retired ${CMAKE_CURRENT_SOURCE_DIR}/../tools/retired.c)\n", "")
    )
    builds("2 package(s) built")
    retired.write_text("int main(void) { return 1; }\n")
    builds("up to date (2 package(s))")
    # Built by an espdock before these lists (records without them, stamps of the directories
    # alone): a shared file edited since is found from the build dir, and builds once.
    stamps = root / "ws/build/.espdock-colcon-stamps.json"
    records = json.loads(stamps.read_text())
    for entry in records.values():
        entry["outside"] = {}
    stamps.write_text(json.dumps(records))
    config = load_config(root, {})
    ws = find_workspace(root).with_layout(config.package_paths, config.colcon_root)
    plan = build_plan(ws, config, [], PackageKind.ROS, env=os.environ, notify=lambda text: None)
    step = next(step for step in plan.steps if isinstance(step, ColconBuild))
    for name, stamp in colcon_rebuild(ws, step).stamps.items():
        records[name] = {key: value for key, value in records[name].items() if key != "outside"} | {"stamp": stamp}
    stamps.write_text(json.dumps(records))
    header.write_text('#define REPORT_UNIT "sec"\n#include "vendor_limits.h"\n')
    # `espdock run` warns of it as the build builds it: it said nothing, and ran the old header's code.
    stale = run_once(root, "uptime_tools", "uptime_report")
    warned = " ".join((stale.stdout + stale.stderr).split())
    assert "this runs what an older espdock's build made of " in warned, warned
    assert "ws/src/robot_repo/include/robot/unit.h" in warned, warned
    builds("2 package(s) built")
    reports(" sec (second)")
    builds("up to date (2 package(s))")


def test_symlink_install_on_the_official_flavour_runs_from_a_runtime_image_without_build(engine, tmp_path):
    """The official image (through its double: apt's setuptools, which still has develop --editable)."""
    tag = build_double(engine, resolve_ca_bundle(Config(), os.environ), lambda line: None)
    env = {**environment(tmp_path), **settings(tag)}
    root = copy_workspace(tmp_path / "official", packages=(), test_packages=PACKAGES)
    built(root, "--", "--symlink-install", env=env)
    assert (root / "ws/install/uptime_tools/lib/uptime_tools/uptime_report").is_symlink()
    report = run_once(root, "uptime_tools", "uptime_report", env=env)
    assert report.returncode == 0 and "uptime_report: up" in report.stdout, report.stdout + report.stderr
    beacon_says(root, "beacon up", env=env)


def test_espdock_builds_over_a_native_symlink_install(engine, tmp_path):
    """The ROS tutorials' `colcon build --symlink-install` first, then espdock's: colcon in the
    container failed on the links to this machine's paths ("[Errno 17] File exists"), and the
    error said to fix the package."""
    root = copy_workspace(tmp_path / "native-links", packages=(), test_packages=PACKAGES)
    native = native_colcon(root, "--symlink-install")
    assert native.returncode == 0, native.stdout[-3000:] + native.stderr[-3000:]
    result = espdock("build", "--only", "ros", "--", "--symlink-install", cwd=root)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    said = " ".join(result.stdout.split())
    assert "removed the install prefixes of beacon_nodes" in said and "native `colcon build --symlink-install`" in said
    report = run_once(root, "uptime_tools", "uptime_report")
    assert report.returncode == 0 and "uptime_report: up" in report.stdout, report.stdout + report.stderr


def test_espdock_s_symlink_install_builds_over_a_native_copying_install(engine, tmp_path):
    """A workspace built with plain `colcon build`, then `espdock init` and `espdock build -- --symlink-install`
    (or symlink-install in ~/.colcon/defaults.yaml): colcon failed on the native copies ("[Errno 17] File
    exists"), and the error said to fix the package, every run."""
    root = copy_workspace(tmp_path / "native-copies", packages=(), test_packages=PACKAGES)
    native = native_colcon(root)
    assert native.returncode == 0, native.stdout[-3000:] + native.stderr[-3000:]
    result = espdock("build", "--only", "ros", "--", "--symlink-install", cwd=root)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    said = " ".join(result.stdout.split())
    assert "--symlink-install on since their last build: removed the build dirs and install prefixes" in said, said
    assert (root / "ws/install/uptime_tools/lib/uptime_tools/uptime_report").is_symlink()
    beacon_says(root, "beacon up")


def test_native_and_espdock_builds_take_turns_in_one_workspace(engine, tmp_path):
    root = copy_workspace(tmp_path / "native", packages=(), test_packages=PACKAGES)
    built(root)  # the images; then the developer builds natively and with espdock, in turns
    # What espdock itself left in build/ before it had a build base of its own: caches made at
    # /workspace. The next espdock build retires them, so the native build can configure afresh.
    old = native_colcon(root, at="/workspace/ws")
    assert old.returncode == 0, old.stdout[-3000:] + old.stderr[-3000:]
    retiring = espdock("build", "--only", "ros", cwd=root)
    assert retiring.returncode == 0 and "removed build/uptime_tools" in retiring.stdout + retiring.stderr
    underlay = tmp_path / "underlay"  # the developer's ROS, sourced before their colcon build
    underlay.mkdir()
    (underlay / "local_setup.bash").write_text("export ESPDOCK_TEST_UNDERLAY=sourced\n")
    first = native_colcon(root, underlay=underlay)
    assert first.returncode == 0, first.stdout[-3000:] + first.stderr[-3000:]
    install = root / "ws/install"
    scripts = {name: (install / name).read_bytes() for name in ("setup.bash", "setup.sh")}

    refused = run_once(root, "uptime_tools", "uptime_report")
    assert refused.returncode == 2, refused.stdout + refused.stderr
    assert "install/uptime_tools was not built by espdock" in refused.stderr
    assert "espdock build uptime_tools" in refused.stderr

    built(root)  # CMake caches of the native build stay where they are, and stay valid
    # The native build's setup scripts, which chain the developer's ROS, stay: a container's chain
    # the image's underlay, and `source install/setup.bash` lost theirs.
    assert {name: (install / name).read_bytes() for name in scripts} == scripts
    sourced = subprocess.run(["bash", "-c", f"source {install}/setup.bash; echo $ESPDOCK_TEST_UNDERLAY"],
                             capture_output=True, text=True, check=False)  # fmt: skip
    assert sourced.stdout.strip() == "sourced", sourced.stdout + sourced.stderr
    again = native_colcon(root)
    assert again.returncode == 0, again.stdout[-3000:] + again.stderr[-3000:]
    built(root)
    report = run_once(root, "uptime_tools", "uptime_report")
    assert report.returncode == 0 and "uptime_report: up" in report.stdout, report.stdout + report.stderr
