"""`espdock build` against the real engine: real image builds, real colcon, real uids."""

from __future__ import annotations

import grp
import hashlib
import json
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.conftest import (
    REPO,
    as_user,
    containers_created,
    copy_workspace,
    espdock,
    leftover_containers,
    message_package,
    owners,
    python_workspace,
    ros_build_tag,
    user_env,
)

pytestmark = [pytest.mark.engine, pytest.mark.slow]

USER_UID = 4242  # a plain user in the docker group, as most developers are
NOBODY = 65534  # a user who may not use the engine at all


@pytest.fixture(scope="module")
def built(engine, shared_dir: Path, wheel_espdock: Path):
    """A workspace owned by a normal user, built once by that user: an interface package and a
    Python one (what a test about when a build happens edits: it builds in a few seconds)."""
    root = copy_workspace(shared_dir / "user-ws", packages=(), test_packages=("beacon_nodes",), runtime_image=False)
    message_package(root / "ws/src/custom_interface")
    home = shared_dir / "home"
    subprocess.run(["chown", "-R", f"{USER_UID}:{USER_UID}", str(root)], check=True)
    docker_gid = grp.getgrnam("docker").gr_gid
    env = user_env(home)
    subprocess.run(["chown", f"{USER_UID}:{USER_UID}", str(home)], check=True)
    result = espdock("build", cwd=root, env=env, prefix=as_user(USER_UID, USER_UID, [docker_gid], wheel_espdock))
    yield root, result
    engine.remove_containers({"io.espdock.workspace": str(root)})


def test_build_runs_colcon_as_the_invoking_user(built):
    root, result = built
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Finished <<< custom_interface" in result.stdout
    for space in ("build", "install", "log"):
        assert (root / "ws" / space).is_dir()
        assert owners(root / "ws" / space) == {USER_UID}, f"ws/{space} has files not owned by the user"
    assert (root / "ws/install/custom_interface/share/custom_interface/msg/CameraConfig.msg").is_file()


def test_built_interfaces_work_in_the_ros_image(engine, built):
    root, result = built
    assert result.returncode == 0
    image = ros_build_tag(root)
    probe = subprocess.run(
        [
            "docker",
            "run",
            "--rm",
            "-v",
            f"{root / 'ws'}:/workspace/ws:ro",
            "-e",
            "ESPDOCK_WS_INSTALL=/workspace/ws/install",
            image,
            "python3",
            "-c",
            (
                "from custom_interface.msg import CameraConfig as C; c = C(); "
                "c.framesize = 6; print(c.framesize, C().aec_value)"
            ),
        ],
        capture_output=True,
        text=True,
        timeout=120,
        check=False,
    )
    assert probe.returncode == 0, probe.stderr
    assert probe.stdout.split() == ["6", "0"]


def test_old_trees_another_user_s_files_keep_from_removal_are_named(built, shared_dir, wheel_espdock):
    """A `--force` build where a `sudo colcon build` had left root's files in the install: the
    trees it replaced could not be removed, unsaid, and a later `rm -rf build` failed."""
    root, first = built
    assert first.returncode == 0
    subprocess.run(["chown", "-R", "0:0", str(root / "ws/install/beacon_nodes/share/beacon_nodes")], check=True)
    aside = root / "ws/build/espdock-ros/.espdock-afresh"
    user = as_user(USER_UID, USER_UID, [grp.getgrnam("docker").gr_gid], wheel_espdock)
    try:
        result = espdock("build", "beacon_nodes", "--force", cwd=root, env=user_env(shared_dir / "home"), prefix=user)
    finally:
        shutil.rmtree(aside, ignore_errors=True)
        subprocess.run(["chown", "-R", f"{USER_UID}:{USER_UID}", str(root / "ws")], check=True)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr
    said = " ".join((result.stdout + result.stderr).split())
    assert f"warning: could not remove {aside}" in said and f"`sudo rm -rf {aside}`" in said, said[-3000:]


def test_second_build_reuses_the_image_and_keeps_ownership(engine, built):
    root, first = built
    assert first.returncode == 0
    # Root builds in the user's workspace must still leave files the user owns.
    again = espdock("build", cwd=root)
    assert again.returncode == 0, again.stdout + again.stderr
    assert "cache hit" in again.stdout
    assert "cache miss" not in again.stdout
    assert owners(root / "ws") == {USER_UID}
    assert leftover_containers(engine, root) == []


def test_a_build_builds_again_exactly_when_something_changed(engine, built):
    root, first = built
    assert first.returncode == 0
    package, interfaces = root / "ws/src/beacon_nodes", root / "ws/src/custom_interface"

    def build(*args: str) -> tuple[set[str], subprocess.CompletedProcess]:
        with containers_created(root) as created:
            result = espdock("build", *args, cwd=root)
        assert result.returncode == 0, result.stdout[-3000:] + result.stderr
        finished = set(re.findall(r"^Finished <<< (\w+)", result.stdout, flags=re.M))
        assert bool(created) == bool(finished), (created, result.stdout[-2000:])
        return finished, result

    espdock("build", cwd=root)  # whatever earlier tests left: settle
    ran, noop = build()
    assert not ran and "up to date" in noop.stdout
    assert len(noop.stdout.splitlines()) < 30, noop.stdout
    # Any file of the package counts, not only what its build reads (setup.py's data files, CMake's
    # install rules): a file beside them builds the package, and only it.
    extra = package / "NOTES.txt"
    extra.write_text("an added file\n")
    planned = espdock("build", "--dry-run", cwd=root, env={"COLUMNS": "400"})
    assert re.search(r"^\d\. colcon build\n(   .*\n)*   now: would build 1 of 2 package\(s\): beacon_nodes$",
                     planned.stdout, flags=re.M), planned.stdout  # fmt: skip
    assert re.search(r"^\d\. image espdock/ros-jazzy-build\n(   .*\n)*   now: present$", planned.stdout, flags=re.M)
    assert build()[0] == {"beacon_nodes"}, "an added file must build"
    assert "now: up to date (2 package(s))" in espdock("build", "--dry-run", cwd=root).stdout
    assert not build()[0]
    extra.write_text("an edited file\n")
    assert build()[0] == {"beacon_nodes"}, "an edited file must build"
    extra.unlink()
    assert build()[0] == {"beacon_nodes"}, "a removed file must build"
    # An interface taken out of rosidl_generate_interfaces, its file kept (retired, or moving to
    # another package): rosidl's code of it stayed in the build dir, installed again, importable.
    cmake, installed = interfaces / "CMakeLists.txt", root / "ws/install/custom_interface"
    listed = cmake.read_text()
    (interfaces / "msg/Retired.msg").write_text("int32 value\n")
    cmake.write_text(listed.replace('"msg/CameraConfig.msg"', '"msg/CameraConfig.msg"\n  "msg/Retired.msg"'))
    assert build()[0] == {"custom_interface"} and list(installed.rglob("_retired.py"))
    cmake.write_text(listed)
    (interfaces / "msg/Retired.msg").unlink()
    assert build()[0] == {"custom_interface"}
    assert [p for p in installed.rglob("*") if "retired" in p.name.lower()] == []
    shutil.rmtree(root / "ws/install/beacon_nodes")
    assert build()[0] == {"beacon_nodes"}, "a deleted install tree must build"
    assert build("--force", "beacon_nodes")[0] == {"beacon_nodes"}, "--force must build"
    assert not build()[0]
    assert owners(root / "ws") == {USER_UID}


def test_the_cmake_args_of_the_users_colcon_defaults_file_reach_cmake(built, tmp_path):
    """espdock's own --cmake-args -DBUILD_TESTING=OFF on the command line replaced the defaults
    file's cmake-args, silently: no compile_commands.json for the editor."""
    root, first = built
    assert first.returncode == 0
    defaults = tmp_path / "defaults.yaml"
    defaults.write_text("build:\n  cmake-args:\n    - -DCMAKE_EXPORT_COMPILE_COMMANDS=ON\n")
    result = espdock("build", cwd=root, env={"COLCON_DEFAULTS_FILE": str(defaults)})
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr
    cache = (root / "ws/build/espdock-ros/custom_interface/CMakeCache.txt").read_text()
    assert "CMAKE_EXPORT_COMPILE_COMMANDS:UNINITIALIZED=ON" in cache and "BUILD_TESTING:BOOL=OFF" in cache
    assert (root / "ws/build/espdock-ros/custom_interface/compile_commands.json").is_file()


def test_the_build_records_what_it_produced_and_verify_checks_it(engine, built, tmp_path):
    root, first = built
    assert first.returncode == 0
    manifest = root / "ws/install/espdock-manifest.json"
    data = json.loads(manifest.read_text())
    assert data["target"] == "esp32" and data["espdock"]
    assert any(tag.startswith("espdock/ros-jazzy-build:") for tag in data["images"])
    msg = "custom_interface/share/custom_interface/msg/CameraConfig.msg"
    assert data["files"][msg] == hashlib.sha256((root / "ws/install" / msg).read_bytes()).hexdigest()
    assert manifest.stat().st_uid == USER_UID

    ok = espdock("verify", str(manifest), cwd=root)
    assert ok.returncode == 0 and f"matches {manifest}" in ok.stdout
    installed = root / "ws/install" / msg
    original = installed.read_bytes()
    installed.write_bytes(original + b"# tampered\n")
    try:
        bad = espdock("verify", str(manifest), cwd=root)
    finally:
        installed.write_bytes(original)
    assert bad.returncode == 1 and f"changed  {msg}" in bad.stdout
    # A file put into an install prefix: the next build rebuilt the package into it and recorded the
    # file as its own, and verify passed.
    stray = "beacon_nodes/share/beacon_nodes/stray.yaml"
    (root / "ws/install" / stray).write_text("put here by hand\n")
    assert stray in espdock("verify", str(manifest), cwd=root).stdout

    report = tmp_path / "report.json"
    again = espdock("build", "--runtime-image", "--report", str(report), cwd=root)
    assert again.returncode == 0, again.stdout[-2000:] + again.stderr
    said = " ".join(again.stdout.split())
    assert "installing afresh what changed in install/ since its last build: beacon_nodes, custom_interface" in said
    assert not (root / "ws/install" / stray).exists()
    summary = json.loads(report.read_text())
    assert summary["outcome"] == "succeeded" and summary["manifest"]["files"][msg] == data["files"][msg]
    assert stray not in summary["manifest"]["files"]
    assert espdock("verify", str(manifest), cwd=root).returncode == 0
    assert [s["step"] for s in summary["steps"]] == ["base image debian:bookworm-slim", "image espdock/ros-jazzy-build",
                                                     "colcon build", "image espdock/ros-jazzy-runtime",
                                                     "runtime image"]  # fmt: skip


def test_changed_image_input_rebuilds_under_a_new_tag(engine, built):
    root, _ = built
    dockerfile = root / "Dockerfile.ros"
    original = dockerfile.read_text()
    dockerfile.write_text(original + "\n# a change that must invalidate the cached image\n")
    try:
        new_tag = ros_build_tag(root)
        assert new_tag in espdock("build", "--dry-run", cwd=root).stdout
        assert engine.image(new_tag) is None
        result = espdock("build", cwd=root)
        assert result.returncode == 0, result.stdout + result.stderr
        # Since which image, and what changed: a bare "cache miss" after an upgrade of espdock (its
        # own Dockerfiles and scripts changed) left the user wondering what they had done.
        said = " ".join(result.stdout.split())
        assert f"{new_tag}: cache miss" in said and "Dockerfile.ros changed)" in said, said
        assert re.search(r"cache miss \(key \w+; since espdock/ros-jazzy-build:\w+: Dockerfile.ros changed\)", said)
        info = engine.image(new_tag)
        assert info is not None and info.labels["io.espdock.key"].startswith(new_tag.split(":")[1])
    finally:
        dockerfile.write_text(original)
        subprocess.run(["docker", "rmi", "-f", new_tag], capture_output=True, check=False)


def test_a_failing_package_is_named_with_its_log(engine, tmp_path):
    root = copy_workspace(tmp_path / "ws-root", packages=())
    broken = root / "ws/src/broken_pkg"
    shutil.copytree(REPO / "ws/src/custom_interface", broken)
    manifest = broken / "package.xml"
    manifest.write_text(manifest.read_text().replace("<name>custom_interface</name>", "<name>broken_pkg</name>"))
    (broken / "CMakeLists.txt").write_text(
        "cmake_minimum_required(VERSION 3.16)\nproject(broken_pkg C)\nadd_executable(broken src/broken.c)\n"
    )
    (broken / "src").mkdir()
    (broken / "src/broken.c").write_text("#error deliberately broken\nint main(void) { return 0; }\n")
    result = espdock("build", cwd=root)
    assert result.returncode == 5, result.stdout + result.stderr
    assert "broken_pkg" in result.stderr
    # The error's file as the user opens it, not where the container had the workspace mounted.
    assert f"{root}/ws/src/broken_pkg/src/broken.c:1:2: error: #error deliberately broken" in result.stdout, (
        result.stdout
    )
    log = root / "ws/log/latest_build/broken_pkg/stdout_stderr.log"
    assert str(log) in result.stderr
    assert "deliberately broken" in log.read_text()
    assert leftover_containers(engine, root) == []


def test_a_package_renamed_since_its_build_is_named_with_what_removes_its_install(engine, tmp_path):
    """colcon leaves the install prefix of a package renamed or removed, and its setup scripts and
    `ros2 run` still find it (a firmware package's `flash` script then fails); nothing said so."""
    from tests.integration.test_faults import add_package

    root = copy_workspace(tmp_path / "w", packages=())
    add_package(root, "old_name", "install(FILES package.xml DESTINATION share/${PROJECT_NAME})\n")
    add_package(root, "kept_pkg", "install(FILES package.xml DESTINATION share/${PROJECT_NAME})\n")
    assert espdock("build", cwd=root).returncode == 0
    renamed = root / "ws/src/new_name"
    (root / "ws/src/old_name").rename(renamed)
    manifest = renamed / "package.xml"
    manifest.write_text(manifest.read_text().replace("old_name", "new_name"))
    (renamed / "CMakeLists.txt").write_text((renamed / "CMakeLists.txt").read_text().replace("old_name", "new_name"))
    built = espdock("build", cwd=root)
    assert built.returncode == 0, built.stdout + built.stderr
    said = " ".join(built.stdout.split())
    assert "install/ holds old_name, of no package in this workspace any more" in said, built.stdout
    assert "`rm -r install/old_name build/espdock-ros/old_name`" in said and "kept_pkg" not in said
    subprocess.run(["rm", "-r", "install/old_name", "build/espdock-ros/old_name"], cwd=root / "ws", check=True)
    again = espdock("build", cwd=root)
    assert again.returncode == 0 and "old_name" not in again.stdout, again.stdout + again.stderr


def test_another_user_s_file_in_install_is_named_with_its_owner_not_blamed_on_the_package(engine, tmp_path):
    """After a `sudo colcon build`, install/ holds root's files: the build failed with "Fix
    beacon_nodes (the error is in the log above)", where the firmware side named the path."""
    root = python_workspace(tmp_path / "w")
    subprocess.run(["chown", "-R", f"{USER_UID}:{USER_UID}", str(root)], check=True)
    assert espdock("build", cwd=root).returncode == 0
    prefix = root / "ws/install/beacon_nodes"
    subprocess.run(["chown", "-R", "0:0", str(prefix)], check=True)
    node = root / "ws/src/beacon_nodes/beacon_nodes/beacon.py"
    node.write_text(node.read_text() + "# an edit\n")  # a rebuild into it (--force builds afresh)
    result = espdock("build", cwd=root)
    assert result.returncode == 2, result.stdout[-3000:] + result.stderr
    said = " ".join(result.stderr.split())
    assert f"permission denied on {prefix}/" in said and "(owner uid 0," in said, result.stderr
    # The build wrote as the workspace's owner, not as root: root's chown would change nothing. The
    # chown takes all root left (it named one file, another on the next run, and so on).
    assert f"the build writes as uid {USER_UID}" in said, result.stderr
    assert f"`sudo chown -R {USER_UID}:{USER_UID} {prefix}`" in said, result.stderr
    subprocess.run(["chown", "-R", f"{USER_UID}:{USER_UID}", str(prefix)], check=True)
    assert espdock("build", "--force", cwd=root).returncode == 0
    assert "Fix beacon_nodes" not in said


def _cmake_package(root: Path, name: str, rules: str) -> Path:
    """ws/src/NAME in ROOT: an ament_cmake package.xml and a CMakeLists.txt of RULES (no compiler)."""
    package = root / "ws/src" / name
    package.mkdir()
    (package / "package.xml").write_text(
        (REPO / "ws/src/custom_interface/package.xml")
        .read_text()
        .replace("<name>custom_interface</name>", f"<name>{name}</name>")
        .replace("<member_of_group>rosidl_interface_packages</member_of_group>", "")
    )
    (package / "CMakeLists.txt").write_text(f"cmake_minimum_required(VERSION 3.16)\nproject({name} NONE)\n{rules}")
    return package


def _slow_workspace(tmp_path: Path) -> Path:
    """A workspace whose slow_pkg keeps colcon busy for five minutes."""
    root = python_workspace(tmp_path / "ws-root")
    _cmake_package(root, "slow_pkg", "execute_process(COMMAND sleep 300)\n")
    return root


def _start_build_until_colcon_runs(engine, root: Path, *args: str) -> subprocess.Popen:
    """`espdock build ARGS` in ROOT, started as a shell without job control starts a background
    command: with SIGINT ignored (Python then never raises KeyboardInterrupt by itself)."""
    process = subprocess.Popen(
        [sys.executable, "-m", "espdock", "build", *args],
        cwd=root,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),  # noqa: PLW1509 (no threads here)
    )
    deadline = time.monotonic() + 300
    while not leftover_containers(engine, root):
        assert process.poll() is None, process.communicate()
        assert time.monotonic() < deadline, "the build container never started"
        time.sleep(0.2)
    time.sleep(3)  # let colcon get into the slow package
    return process


def test_ctrl_c_stops_and_removes_the_container_and_the_next_build_works(engine, tmp_path):
    root = _slow_workspace(tmp_path)
    report = tmp_path / "report.json"
    # beacon_nodes last built as a symlink install: the interrupted build switches it, and finishes it.
    linked = espdock("build", "beacon_nodes", "--", "--symlink-install", cwd=root)
    assert linked.returncode == 0, linked.stdout + linked.stderr
    process = _start_build_until_colcon_runs(engine, root, "--report", str(report))
    try:
        events, deadline = root / "ws/log/latest_build/events.log", time.monotonic() + 120
        while "(beacon_nodes) JobEnded" not in (events.read_text() if events.is_file() else ""):
            assert time.monotonic() < deadline and process.poll() is None, "beacon_nodes never finished"
            time.sleep(0.2)
        sent = time.monotonic()
        process.send_signal(signal.SIGINT)
        out, err = process.communicate(timeout=60)
        took = time.monotonic() - sent
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == 130, out + err
    assert took < 10, f"Ctrl-C took {took:.1f} s"
    assert "interrupted" in err
    assert leftover_containers(engine, root) == []
    # A CI job's report tells a cancelled build from a failed one (it said "failed", no error).
    data = json.loads(report.read_text())
    assert (data["outcome"], data["error"]) == ("interrupted", "interrupted"), data
    # What colcon finished before the Ctrl-C is built: the next build goes on from there (it
    # built every package again, on a large workspace minutes of work thrown away).
    planned = espdock("build", "--dry-run", cwd=root)
    assert "would build 1 of 2 package(s): slow_pkg" in " ".join(planned.stdout.split()), planned.stdout

    shutil.rmtree(root / "ws/src/slow_pkg")
    result = espdock("build", cwd=root)
    assert result.returncode == 0, result.stdout + result.stderr
    assert (root / "ws/install/beacon_nodes/share/beacon_nodes/package.xml").is_file()
    # Its next edit builds it as the copy it is: it was taken for the symlink install it had been,
    # and rebuilt afresh, "--symlink-install off since their last build".
    source = root / "ws/src/beacon_nodes/beacon_nodes/beacon.py"
    source.write_text(source.read_text() + "# edited\n")
    edited = espdock("build", cwd=root)
    said = " ".join((edited.stdout + edited.stderr).split())
    assert edited.returncode == 0 and "1 package(s) built" in said, said
    assert "since their last build" not in said, said


def test_ctrl_c_as_colcon_starts_a_package_leaves_it_to_the_next_build(engine, tmp_path):
    """Ctrl-C in the first moments of a package's build (colcon in its own Python code, writing
    hooks and its command environment) ends the job with "JobEnded rc 0" in colcon's event log.
    Taken for built: a package built afresh (a setup.py edit) was left with no install, and the
    next build said "up to date" over it."""
    root = python_workspace(tmp_path / "ws-root")
    assert espdock("build", "--only", "ros", cwd=root).returncode == 0
    setup = root / "ws/src/beacon_nodes/setup.py"
    setup.write_text(setup.read_text() + "# edited\n")
    argv = [sys.executable, "-m", "espdock", "build", "--only", "ros"]
    with subprocess.Popen(argv, cwd=root, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) as build:
        try:
            for line in build.stdout:
                if "Starting >>> beacon_nodes" in line:
                    build.send_signal(signal.SIGINT)
                    break
            assert build.wait(timeout=60) == 130, build.stderr.read()
        finally:
            build.kill()
    assert (root / "ws/install/beacon_nodes/lib/beacon_nodes/beacon").is_file(), "the old install is gone"
    again = espdock("build", "--only", "ros", cwd=root)
    said = " ".join(again.stdout.split())
    assert again.returncode == 0 and "1 package(s) built" in said, said[-2000:] + again.stderr


@pytest.mark.parametrize(("stop", "code"), [(signal.SIGINT, 130), (signal.SIGKILL, -9)], ids=["ctrl-c", "kill-9"])
def test_a_stop_mid_write_leaves_no_half_written_file_the_next_build_installs(engine, tmp_path, stop, code):
    """Ctrl-C as make writes a generated file: the container's stop reached only colcon, whose
    death took make down before make could delete the file it was writing, so the next build
    found it newer than its input and installed it half written ("built", exit 0). A terminal's
    Ctrl-C reaches make as well, which deletes it. espdock killed outright: the next build's sweep
    removed its container outright, with the same result."""
    root = python_workspace(tmp_path / "ws-root")
    gen = _cmake_package(
        root,
        "gen_pkg",
        "add_custom_command(OUTPUT ${CMAKE_CURRENT_BINARY_DIR}/data.txt\n"
        "  COMMAND sh ${CMAKE_CURRENT_SOURCE_DIR}/gen.sh ${CMAKE_CURRENT_BINARY_DIR}/data.txt "
        "${CMAKE_CURRENT_SOURCE_DIR}/input.txt ${CMAKE_CURRENT_SOURCE_DIR}/hold\n"
        "  DEPENDS ${CMAKE_CURRENT_SOURCE_DIR}/input.txt VERBATIM)\n"
        "add_custom_target(data ALL DEPENDS ${CMAKE_CURRENT_BINARY_DIR}/data.txt)\n"
        "install(FILES ${CMAKE_CURRENT_BINARY_DIR}/data.txt DESTINATION share/gen_pkg)\n",
    )
    # The generator writes its output in two goes, holding between them where it finds the hold
    # file, which it takes: the build after the stop finds none.
    (gen / "gen.sh").write_text(
        'printf PARTIAL > "$1"\nif [ -e "$3" ]; then rm "$3"; sleep 600; fi\n'
        'printf "COMPLETE %s" "$(cat "$2")" > "$1"\n'
    )
    (gen / "input.txt").write_text("one")
    assert espdock("build", cwd=root).returncode == 0
    installed, written = (
        root / "ws/install/gen_pkg/share/gen_pkg/data.txt",
        root / "ws/build/espdock-ros/gen_pkg/data.txt",
    )
    assert installed.read_text() == "COMPLETE one"

    (gen / "input.txt").write_text("two")
    (gen / "hold").touch()
    process = _start_build_until_colcon_runs(engine, root)
    try:
        deadline = time.monotonic() + 120
        while not (written.is_file() and written.read_text() == "PARTIAL"):
            assert time.monotonic() < deadline and process.poll() is None, "the generator never started"
            time.sleep(0.1)
        process.send_signal(stop)
        out, err = process.communicate(timeout=60)
    finally:
        if process.poll() is None:
            process.kill()
    assert process.returncode == code, out + err
    rebuilt = espdock("build", cwd=root)
    assert rebuilt.returncode == 0, rebuilt.stdout[-3000:] + rebuilt.stderr
    assert installed.read_text() == "COMPLETE two"


def test_a_killed_build_leaves_a_container_the_next_build_removes(engine, tmp_path):
    root = _slow_workspace(tmp_path)
    process = _start_build_until_colcon_runs(engine, root)
    process.kill()
    process.communicate()
    (left,) = leftover_containers(engine, root)

    shutil.rmtree(root / "ws/src/slow_pkg")
    result = espdock("build", cwd=root)
    assert result.returncode == 0, result.stdout + result.stderr
    assert left not in leftover_containers(engine, root)
    assert leftover_containers(engine, root) == []


def test_a_user_without_engine_access_gets_a_clear_message(engine, shared_dir, wheel_espdock):
    root = copy_workspace(shared_dir / "nobody-ws")
    result = espdock(
        "build",
        cwd=root,
        env=user_env(shared_dir / "nobody-home"),
        prefix=as_user(NOBODY, NOBODY, [], wheel_espdock),
        timeout=120,
    )
    assert result.returncode == 3, result.stdout + result.stderr
    assert "permission denied" in result.stderr
    assert "docker group" in result.stderr
    assert not (root / "ws/build").exists()


def test_a_kept_build_container_is_replaced_by_the_next_build_s_not_blamed_on_a_crash(engine, tmp_path):
    """keep_containers: the next build removed the last one's kept container, saying that an
    espdock killed earlier had left it running. Each step keeps its last container."""
    root = python_workspace(tmp_path / "w")
    kept = {"ESPDOCK_KEEP_CONTAINERS": "true"}
    try:
        assert espdock("build", cwd=root, env=kept).returncode == 0
        (first,) = leftover_containers(engine, root)
        again = espdock("build", "--force", cwd=root, env=kept)
        assert again.returncode == 0, again.stdout + again.stderr
        assert "before its cleanup" not in again.stdout
        (second,) = leftover_containers(engine, root)
        assert second != first
    finally:
        engine.remove_containers({"io.espdock.workspace": str(root)})


def test_a_build_under_umask_002_leaves_trees_the_group_can_rebuild(engine, tmp_path):
    """A workspace a group shares (umask 002, as a lab's machine sets it): colcon's containers
    wrote 0755 dirs into build/, install/ and log/, and a teammate's build was refused."""
    root = python_workspace(tmp_path / "w")
    shared = ("sh", "-c", 'umask 002 && exec "$@"', "sh", sys.executable, "-m", "espdock")
    built = espdock("build", "--only", "ros", cwd=root, prefix=shared)
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr
    for tree in ("build", "install", "log"):
        closed = [
            p.relative_to(root).as_posix()
            for p in (root / "ws" / tree).rglob("*")
            if p.is_dir() and not p.is_symlink() and not p.stat().st_mode & 0o020
        ]
        assert closed == [], closed[:10]
