"""The CLI's answers to bad input; none of these may need (or touch) a container engine."""

import contextlib
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from espdock.layout import firmware_install_dir
from tests.conftest import REPO, build_holding, copy_workspace, espdock, locale_env
from tests.robot_packages import write_interface_package
from tests.rosdep_db import environment

# Any engine use would fail loudly against this address.
NO_ENGINE = {"DOCKER_HOST": "unix:///nonexistent/docker.sock"}


def test_outside_a_workspace_says_where_it_looked(tmp_path):
    result = espdock("build", cwd=tmp_path, env=NO_ENGINE)
    assert result.returncode == 2
    assert f"no espdock.toml in {tmp_path}" in result.stderr
    assert "Traceback" not in result.stderr


def test_a_colcon_option_before_the_double_dash_says_where_it_goes(tmp_path):
    """`espdock build --symlink-install`, `--cmake-args ...`, `espdock test --packages-up-to X`: a
    ROS developer's habits got click's bare "No such option", where after `--` they got the way."""
    env = {"COLUMNS": "200", "NO_COLOR": "1"}
    placed = espdock("build", "--symlink-install", cwd=tmp_path, env=env)
    said = " ".join(placed.stderr.replace("│", " ").split())
    assert placed.returncode == 2, said
    assert "--symlink-install is colcon's option, not espdock build's: give it after `--`" in said, said
    assert "(`espdock build [PKG...] -- --symlink-install`)" in said and "No such option" not in said, said
    joined = espdock("build", "--cmake-args=-DX=1", cwd=tmp_path, env=env)
    assert "`espdock build [PKG...] -- --cmake-args ...`" in " ".join(joined.stderr.replace("│", " ").split())
    selecting = espdock("test", "--packages-up-to", "driver", cwd=tmp_path, env=env)
    said = " ".join(selecting.stderr.replace("│", " ").split())
    assert selecting.returncode == 2, said
    assert "--packages-up-to is colcon's option, which espdock test does not pass on: espdock selects" in said, said
    # espdock's own options misspelt are click's to answer, with its guess.
    misspelt = espdock("build", "--forse", cwd=tmp_path, env=env)
    assert misspelt.returncode == 2 and "(Possible options: --force" in misspelt.stderr, misspelt.stderr


def test_unparseable_package_xml_names_the_file(tmp_path):
    root = copy_workspace(tmp_path / "w")
    manifest = root / "ws/src/custom_interface/package.xml"
    manifest.write_text(manifest.read_text().replace("</package>", ""))
    result = espdock("build", cwd=root, env=NO_ENGINE)
    assert result.returncode == 2
    assert str(manifest) in result.stderr
    assert "Traceback" not in result.stderr


def test_dry_run_prints_the_plan_without_an_engine(tmp_path):
    root = copy_workspace(tmp_path / "w")
    result = espdock("build", "--dry-run", cwd=root, env=NO_ENGINE)
    assert result.returncode == 0, result.stderr
    for expected in ("base image debian:bookworm-slim", "espdock/ros-jazzy-build:", "colcon build", "custom_interface"):
        assert expected in result.stdout
    assert not (root / "ws/build").exists()


def test_unknown_package_suggests_one(tmp_path):
    root = copy_workspace(tmp_path / "w")
    result = espdock("build", "custom_interfaces", cwd=root, env=NO_ENGINE)
    assert result.returncode == 2
    assert "no package named 'custom_interfaces'" in result.stderr
    assert "Did you mean 'custom_interface'?" in result.stderr


def test_a_firmware_command_offers_only_firmware_packages(tmp_path):
    """`espdock flash walk_board` after walk_board was renamed offered an ament_python package,
    which flash then refused as "not a firmware package"."""
    root = copy_workspace(tmp_path / "w")
    shutil.copytree(REPO / "firmware/led_strip_node", root / "firmware/led_strip_node")
    result = espdock("flash", "custom_interfaces", "--port", "socket://127.0.0.1:1", cwd=root, env=NO_ENGINE)
    assert result.returncode == 2, result.stderr
    assert "no package named 'custom_interfaces'" in result.stderr and "custom_interface'" not in result.stderr
    assert "Firmware packages: led_strip_node." in result.stderr, result.stderr
    offered = espdock("flash", "led_strip_nod", "--port", "socket://127.0.0.1:1", cwd=root, env=NO_ENGINE)
    assert "Did you mean 'led_strip_node'?" in offered.stderr, offered.stderr


def test_no_engine_at_docker_host_is_a_clear_error(tmp_path):
    root = copy_workspace(tmp_path / "w")
    result = espdock("build", cwd=root, env=NO_ENGINE)
    assert result.returncode == 3
    assert "no Docker engine answers at unix:///nonexistent/docker.sock" in result.stderr
    assert not (root / "ws/build").exists()


def test_list_shows_packages_in_build_order(tmp_path):
    # espdock_demo depends on custom_interface, and sorts after it by name too: rename the
    # dependency so that only the dependency order puts it first.
    root = copy_workspace(tmp_path / "w", packages=("custom_interface", "espdock_demo"))
    for manifest in (root / "ws/src").glob("*/package.xml"):
        manifest.write_text(manifest.read_text().replace("custom_interface", "zz_interface"))
    (root / "ws/src/custom_interface").rename(root / "ws/src/zz_interface")
    result = espdock("list", cwd=Path(root, "ws/src"), env=NO_ENGINE)
    assert result.returncode == 0, result.stderr
    names = [line.split("│")[1].strip() for line in result.stdout.splitlines() if "│" in line]
    assert names.index("zz_interface") < names.index("espdock_demo"), result.stdout
    # For a script: the names alone, in that order, and what espdock warns of on stderr (a box
    # table with a title was all there was to parse).
    (root / "ws/src/vendored").mkdir()
    (root / "ws/src/vendored/CMakeLists.txt").write_text("cmake_minimum_required(VERSION 3.8)\n")
    # A misspelt variable's warning, which every command gives, among them (`for p in $(...)` took
    # "warning:" and "ESPDOCK_TARGETT" for packages).
    bare = espdock("list", "-n", cwd=root, env={**NO_ENGINE, "ESPDOCK_TARGETT": "esp32"})
    assert bare.returncode == 0, bare.stderr
    assert bare.stdout == "zz_interface\nespdock_demo\n"
    assert "ws/src/vendored is not built" in bare.stderr
    assert "warning: ESPDOCK_TARGETT is no espdock setting" in " ".join(bare.stderr.split())


def test_list_shows_each_firmware_package_s_chip(tmp_path):
    """Two chips in one workspace: `micro-ros status` was the only place a firmware's chip showed."""
    root = copy_workspace(tmp_path / "w")
    shutil.copytree(REPO / "firmware", root / "firmware")
    listed = espdock("list", cwd=root, env={**NO_ENGINE, "COLUMNS": "200"})
    assert listed.returncode == 0, listed.stderr
    rows = {
        cells[0]: cells[1:]
        for line in listed.stdout.splitlines()
        if len(cells := [c.strip() for c in line.split("│")[1:-1]]) == 4
    }
    assert rows["led_strip_node"][1] == "esp_idf (esp32c3)", listed.stdout  # its CONFIG_IDF_TARGET
    assert rows["camera_node"][1] == "esp_idf (esp32)", listed.stdout  # espdock.toml's target
    assert rows["custom_interface"][1] == "ament_cmake", listed.stdout


def test_list_at_a_narrow_terminal_folds_the_names_it_cannot_fit(tmp_path):
    """At 40 columns every name was cut with an ellipsis (`custom…`, `camera…`): no package's name."""
    root = copy_workspace(tmp_path / "w", packages=("custom_interface", "espdock_demo", "espdock_demo_testing"))
    narrow = espdock("list", cwd=root, env={"FORCE_COLOR": "1", "NO_COLOR": "1", "COLUMNS": "40", **NO_ENGINE})
    assert narrow.returncode == 0, narrow.stderr
    text = re.sub(r"\x1b\[[0-9;]*m", "", narrow.stdout)
    assert "…" not in text and max(len(line) for line in text.splitlines()[1:]) <= 40, text  # under the title
    first = "".join(line.split("│")[1].strip() for line in text.splitlines() if line.startswith("│"))
    names = espdock("list", "-n", cwd=root, env=NO_ENGINE).stdout.split()
    assert first == "".join(names), text


def test_monitor_needs_a_terminal_and_says_so(tmp_path):
    root = copy_workspace(tmp_path / "w")
    result = espdock("monitor", "anything", "--port", "socket://127.0.0.1:1", cwd=root, env=NO_ENGINE)
    assert result.returncode == 2
    assert "needs a terminal" in result.stderr


def monitor_at_a_terminal(root: Path, package: str) -> tuple[int, str]:
    """`espdock monitor PACKAGE` at a pseudo-terminal (it needs one), no engine, on a port that
    answers as a board's does: its exit code and what it printed."""
    import pty
    import socket

    with socket.create_server(("127.0.0.1", 0)) as board:
        port = f"socket://127.0.0.1:{board.getsockname()[1]}"
        pid, terminal = pty.fork()
        if pid == 0:
            os.chdir(root)
            argv = [sys.executable, "-m", "espdock", "monitor", package, "--port", port]
            os.execve(sys.executable, argv, {**os.environ, **NO_ENGINE})
        said = b""
        with contextlib.suppress(OSError):
            while chunk := os.read(terminal, 4096):
                said += chunk
        _, status = os.waitpid(pid, 0)
    return os.waitstatus_to_exitcode(status), said.decode(errors="replace")


def test_monitor_of_a_package_never_built_says_so_as_flash_does(tmp_path):
    """It said the installed firmware was "not what its sources build now" (there was none), then
    failed in idf.py ("Cannot load .../project_description.json")."""
    root = copy_workspace(tmp_path / "w")
    shutil.copytree(REPO / "firmware/led_strip_node", root / "firmware/led_strip_node")
    code, text = monitor_at_a_terminal(root, "led_strip_node")
    assert code == 2, text
    assert "led_strip_node has no installed firmware" in text and "espdock build led_strip_node" in text, text
    assert "not what its sources build now" not in text, text
    # Installed, its build dir emptied (`espdock idf led_strip_node -- fullclean`): the monitor, which
    # decodes with the build dir's ELF, said "Cannot load .../project_description.json" in idf.py.
    firmware = root / "ws/install/led_strip_node/share/led_strip_node/firmware"
    firmware.mkdir(parents=True)
    (firmware / "flasher_args.json").write_text('{"flash_files": {}, "extra_esptool_args": {"chip": "esp32"}}\n')
    code, text = monitor_at_a_terminal(root, "led_strip_node")
    assert code == 2, text
    assert "holds no build" in text and "espdock build led_strip_node" in text, text


def test_flash_refuses_a_port_that_is_not_one(tmp_path):
    root = copy_workspace(tmp_path / "w")
    result = espdock("flash", "anything", "--port", "ttyUSB0", cwd=root, env=NO_ENGINE)
    assert result.returncode == 2
    assert "not a device path" in result.stderr


def firmware_workspace(tmp_path: Path, packages: tuple[str, ...] = ("led_strip_node",)) -> Path:
    """A workspace with the repo's firmware PACKAGES, their micro-ROS inputs, and no build."""
    from tests.conftest import REPO

    root = copy_workspace(tmp_path / "w")
    shutil.copy2(REPO / "Dockerfile.idf", root / "Dockerfile.idf")
    for package in (*packages, "components"):
        shutil.copytree(REPO / "firmware" / package, root / "firmware" / package)
    return root


def no_traceback(result) -> None:
    assert "Traceback" not in result.stderr + result.stdout


def test_flash_refuses_a_port_number_out_of_range(tmp_path):
    root = copy_workspace(tmp_path / "w")
    result = espdock("flash", "anything", "--port", "socket://127.0.0.1:99999", cwd=root, env=NO_ENGINE)
    assert result.returncode == 2 and "is not a port espdock can use" in result.stderr
    no_traceback(result)


def installed_firmware(tmp_path: Path, flasher_args: str) -> Path:
    """firmware_workspace with led_strip_node 'installed': only its flasher_args.json, as given."""
    root = firmware_workspace(tmp_path)
    installed = root / "ws" / firmware_install_dir("led_strip_node")
    installed.mkdir(parents=True)
    (installed / "flasher_args.json").write_text(flasher_args)
    return root


def test_flash_with_damaged_installed_firmware_says_rebuild(tmp_path):
    root = installed_firmware(tmp_path, '{"flash_files": {"0x1000": ')
    result = espdock("flash", "led_strip_node", "--port", "socket://127.0.0.1:1", cwd=root, env=NO_ENGINE)
    assert result.returncode == 2, result.stderr
    assert "flasher_args.json is not valid JSON" in result.stderr and "espdock build led_strip_node" in result.stderr
    no_traceback(result)


def test_flash_refuses_a_device_that_is_not_a_serial_port(tmp_path):
    root = installed_firmware(tmp_path, '{"flash_files": {}}')
    result = espdock("flash", "led_strip_node", "--port", "/dev/null", cwd=root, env=NO_ENGINE)
    assert result.returncode == 6, result.stderr
    assert "/dev/null is not a serial port" in result.stderr


def test_idf_without_arguments_says_what_to_give_before_touching_anything(tmp_path):
    root = firmware_workspace(tmp_path)
    result = espdock("idf", "led_strip_node", cwd=root, env=NO_ENGINE)
    assert result.returncode == 2 and "no idf.py arguments given" in result.stderr
    assert "espdock idf led_strip_node -- menuconfig" in result.stderr
    # ESPPORT names the port as it does for idf.py: checked, and the only device passed in.
    env = {**NO_ENGINE, "ESPPORT": "/dev/null"}
    result = espdock("idf", "led_strip_node", "--", "flash", cwd=root, env=env)
    assert result.returncode == 6 and "/dev/null is not a serial port" in result.stderr, result.stderr
    # The real menuconfig (curses) fails without one, after the image is made; as `monitor` does.
    for screen in ("menuconfig", "monitor"):
        result = espdock("idf", "led_strip_node", "--", screen, cwd=root, env=NO_ENGINE)
        assert result.returncode == 2 and f"idf.py {screen} needs a terminal" in result.stderr, result.stderr


def test_new_refuses_an_overlong_name_and_a_firmware_file(tmp_path):
    root = copy_workspace(tmp_path / "w")
    long = espdock("new", "a" * 300, cwd=root, env=NO_ENGINE)
    assert long.returncode == 2 and "at most 64 characters" in long.stderr
    no_traceback(long)
    (root / "firmware").write_text("not a directory\n")
    blocked = espdock("new", "foo", cwd=root, env=NO_ENGINE)
    assert blocked.returncode == 2 and "cannot create" in blocked.stderr and "must be a directory" in blocked.stderr
    no_traceback(blocked)
    assert (root / "firmware").read_text() == "not a directory\n"


def test_an_unexpected_error_is_reported_as_a_bug_with_a_traceback_log(capsys):
    import pytest

    from espdock.cli import command as _command

    @_command
    def broken() -> None:
        raise RuntimeError("a thing espdock did not foresee")

    with pytest.raises(SystemExit) as exit_info:
        broken()
    assert exit_info.value.code == 70
    err = capsys.readouterr().err
    assert "a thing espdock did not foresee" in err and "this is a bug in espdock" in err
    assert "interrupted" not in err
    log = Path(err.split("traceback in ")[1].split()[0].rstrip("."))
    assert "Traceback" in log.read_text() and "RuntimeError" in log.read_text()
    log.unlink()


def test_a_broken_pipe_of_a_process_espdock_feeds_is_still_a_bug_while_its_own_output_is_read(capsys):
    import pytest

    from espdock.cli import command as _command

    @_command
    def feeds_a_dead_process() -> None:
        raise BrokenPipeError(32, "Broken pipe")

    with pytest.raises(SystemExit) as exit_info:
        feeds_a_dead_process()
    assert exit_info.value.code == 70
    err = capsys.readouterr().err
    assert "this is a bug in espdock" in err
    Path(err.split("traceback in ")[1].split()[0].rstrip(".")).unlink()


def test_new_refuses_taken_and_reserved_names_and_unknown_dependencies(tmp_path):
    root = copy_workspace(tmp_path / "w")
    taken = espdock("new", "custom_interface", cwd=root, env=NO_ENGINE)
    assert taken.returncode == 2 and "a package named 'custom_interface' already exists" in taken.stderr
    for reserved in ("build", "install", "log"):
        result = espdock("new", reserved, cwd=root, env=NO_ENGINE)
        assert result.returncode == 2 and f"'{reserved}' is reserved" in result.stderr
    # Its package.xml would depend on itself, and no package of the workspace would then resolve.
    standard = espdock("new", "std_msgs", cwd=root, env=NO_ENGINE)
    assert standard.returncode == 2 and "'std_msgs' is one of ROS's standard interface packages" in standard.stderr
    unknown = espdock("new", "blinky", "--depends", "custom_interfaces", cwd=root, env=NO_ENGINE)
    assert unknown.returncode == 2
    assert "--depends custom_interfaces" in unknown.stderr and "Did you mean custom_interface" in unknown.stderr
    assert not (root / "firmware").exists(), "nothing written for refused input"


def test_new_gives_each_package_its_own_chip(tmp_path):
    root = copy_workspace(tmp_path / "w")
    toml = '# mine\n[espdock]\nros_distro = "jazzy"\n'
    (root / "espdock.toml").write_text(toml)
    created = espdock("new", "blinky", "--target", "esp32s3", cwd=root, env=NO_ENGINE)
    assert created.returncode == 0, created.stderr
    assert "chip target esp32s3 (CONFIG_IDF_TARGET in blinky/sdkconfig.defaults)" in created.stdout
    assert 'CONFIG_IDF_TARGET="esp32s3"' in (root / "firmware/blinky/sdkconfig.defaults").read_text()
    other = espdock("new", "blinky2", "--target", "esp32c3", cwd=root, env=NO_ENGINE)
    assert other.returncode == 0, other.stderr
    assert (root / "espdock.toml").read_text() == toml
    plan = espdock("build", "--dry-run", cwd=root, env=NO_ENGINE)
    assert "(target esp32s3)" in plan.stdout and "(target esp32c3)" in plan.stdout
    assert "espdock/idf-micro-ros-jazzy-esp32s3:" in plan.stdout
    assert "espdock/idf-micro-ros-jazzy-esp32c3:" in plan.stdout
    bad = espdock("new", "blinky3", "--target", "esp32c9", cwd=root, env=NO_ENGINE)
    assert bad.returncode == 2 and "unknown --target 'esp32c9'" in bad.stderr
    # A chip IDF knows that micro-ROS cannot be built for: the package would stop every build.
    c6 = espdock("new", "blinky3", "--target", "esp32c6", cwd=root, env=NO_ENGINE)
    assert c6.returncode == 2 and "micro-ROS cannot be built for esp32c6" in c6.stderr, c6.stderr
    assert "Give it --target esp32" in c6.stderr
    assert not (root / "firmware/blinky3").exists()


def test_the_repository_builds_the_camera_for_esp32_and_the_strip_for_esp32c3(tmp_path):
    from tests.conftest import REPO

    root = copy_workspace(tmp_path / "w")
    shutil.copytree(REPO / "firmware", root / "firmware")
    shutil.copy2(REPO / "Dockerfile.idf", root / "Dockerfile.idf")
    plan = espdock("build", "--dry-run", cwd=root, env=NO_ENGINE)
    assert plan.returncode == 0, plan.stderr
    steps = " ".join(plan.stdout.split())
    assert re.search(r"idf\.py build camera_node\S* in espdock/idf-micro-ros-jazzy-esp32:\S+ \(target esp32\)", steps)
    assert re.search(r"led_strip_node\S* in espdock/idf-micro-ros-jazzy-esp32c3:\S+ \(target esp32c3\)", steps)
    # camera_node lists esp32 and esp32s3: another chip is refused before anything builds.
    refused = espdock("build", "camera_node", "--target", "esp32c3", cwd=root, env=NO_ENGINE)
    assert refused.returncode == 2
    assert "camera_node does not support esp32c3: it supports esp32, esp32s3" in refused.stderr
    s3 = espdock("build", "camera_node", "--target", "esp32s3", "--dry-run", cwd=root, env=NO_ENGINE)
    assert s3.returncode == 0 and "(target esp32s3)" in s3.stdout
    c6 = espdock("build", "led_strip_node", "--target", "esp32c6", cwd=root, env=NO_ENGINE)
    assert c6.returncode == 2 and "-mlongcalls" in c6.stderr


def test_a_workspace_dockerfile_wins_over_the_default_and_changes_the_key(tmp_path):
    root = copy_workspace(tmp_path / "w")
    (root / "Dockerfile.ros").unlink()
    default = espdock("build", "--dry-run", cwd=root, env=NO_ENGINE)
    assert "Dockerfile.ros: espdock's default (the workspace has none of its own)" in default.stdout
    from tests.conftest import REPO

    (root / "Dockerfile.ros").write_text((REPO / "Dockerfile.ros").read_text() + "\n# my own\n")
    own = espdock("build", "--dry-run", cwd=root, env=NO_ENGINE)
    assert "Dockerfile.ros: the workspace's own" in own.stdout

    def tag(out: str) -> str:
        return next(w for w in out.split() if w.startswith("espdock/ros-jazzy-build:"))

    assert tag(own.stdout) != tag(default.stdout)


def test_init_adopts_a_colcon_workspace_and_never_overwrites(tmp_path):
    ws = tmp_path / "ros2_ws"
    (ws / "src/pkg").mkdir(parents=True)
    (ws / "src/pkg/package.xml").write_text(
        (Path(__file__).resolve().parents[2] / "ws/src/custom_interface/package.xml").read_text()
    )
    result = espdock("init", cwd=ws, env=NO_ENGINE)
    assert result.returncode == 0, result.stderr
    assert "found 1 ROS package(s): custom_interface" in result.stdout
    assert 'package_paths = ["src"]' in (ws / "espdock.toml").read_text()
    (ws / "espdock.toml").write_text("[espdock]\n# mine\n")
    again = espdock("init", str(ws), cwd=tmp_path, env=NO_ENGINE)
    assert again.returncode == 0 and "nothing changed" in again.stdout
    # espdock.toml there and compose.yaml not: it is written, and "nothing changed" would be false.
    (ws / "compose.yaml").unlink()
    third = espdock("init", str(ws), cwd=tmp_path, env=NO_ENGINE)
    assert "wrote compose.yaml" in third.stdout and "nothing changed" not in third.stdout, third.stdout
    assert (ws / "espdock.toml").read_text() == "[espdock]\n# mine\n"


def test_init_has_git_ignore_the_build_outputs_and_keeps_an_ignore_file_of_its_own(tmp_path):
    """With no .gitignore, `git stash -u` in a built workspace took build/, install/ and log/ along,
    and the pop failed on every file the next build had made again."""
    made = espdock("init", "robot", cwd=tmp_path, env=NO_ENGINE)
    assert made.returncode == 0 and ".gitignore" in made.stdout, made.stdout + made.stderr
    robot = tmp_path / "robot"
    for directory in ("build", "install", "log", "src/pkg"):
        (robot / directory).mkdir(parents=True, exist_ok=True)
        (robot / directory / "file").write_text("x")
    subprocess.run(["git", "init", "-q", str(robot)], check=True)
    status = ["git", "-C", str(robot), "status", "--porcelain", "-uall"]
    listed = subprocess.run(status, capture_output=True, text=True, check=True)
    assert sorted(listed.stdout.split()[1::2]) == [
        ".gitattributes",
        ".gitignore",
        "compose.yaml",
        "espdock.toml",
        "src/pkg/file",
    ]
    (tmp_path / "mine").mkdir()
    (tmp_path / "mine/.gitignore").write_text("secrets/\n")
    (tmp_path / "mine/.gitattributes").write_text("*.png binary\n")
    # In a repository, its own ignore file, which leaves the outputs in: said, with the lines to add
    # (a team's first `git add -A` committed them without a word).
    subprocess.run(["git", "init", "-q", str(tmp_path / "mine")], check=True)
    kept = espdock("init", "mine", cwd=tmp_path, env=NO_ENGINE)
    assert kept.returncode == 0, kept.stderr
    assert (tmp_path / "mine/.gitignore").read_text() == "secrets/\n"
    assert (tmp_path / "mine/.gitattributes").read_text() == "*.png binary\n"
    said = " ".join(kept.stdout.split())
    assert "note: git does not leave colcon's outputs out of this repository" in said, kept.stdout
    assert said.count("add these lines to it: /build/ /install/ /log/") == 1, kept.stdout
    (tmp_path / "mine/.gitignore").write_text("secrets/\nbuild/\n")
    partly = espdock("init", "mine", cwd=tmp_path, env=NO_ENGINE)
    # One a line: a colcon root with spaces in its name made one line look like two.
    assert "add these lines to it:\n  /install/\n  /log/\n" in partly.stdout, partly.stdout
    (tmp_path / "mine/.gitignore").write_text("secrets/\nbuild/\ninstall/\nlog/\n")
    again = espdock("init", "mine", cwd=tmp_path, env=NO_ENGINE)
    assert again.returncode == 0 and "colcon's outputs" not in again.stdout, again.stdout
    if os.geteuid() == 0:
        # Another user's repository, which git will not read for this one (its safe.directory):
        # nothing was said, as if the outputs were ignored.
        theirs = tmp_path / "theirs"
        theirs.mkdir()
        subprocess.run(["git", "init", "-q", str(theirs)], check=True)
        (theirs / ".gitignore").write_text("secrets/\n")
        subprocess.run(["chown", "-R", "12345:12345", str(theirs)], check=True)
        refused = espdock("init", "theirs", cwd=tmp_path, env=NO_ENGINE)
        assert "git refuses to read this repository as this user" in " ".join(refused.stdout.split()), refused.stdout


def test_the_ignore_lines_init_suggests_leave_a_colcon_root_with_glob_characters_out(tmp_path):
    """A colcon root `ws[1]` was suggested as `/ws[1]/build/`, which .gitignore reads as a pattern
    (ws1/build/), not that directory."""
    from espdock.firmware.scaffold import unignored_outputs

    subprocess.run(["git", "init", "-q", str(tmp_path)], check=True)
    lines = unignored_outputs(tmp_path, "ws[1]")
    assert lines == ["/ws\\[1]/build/", "/ws\\[1]/install/", "/ws\\[1]/log/"], lines
    (tmp_path / ".gitignore").write_text("".join(f"{line}\n" for line in lines))
    assert unignored_outputs(tmp_path, "ws[1]") == []


def test_a_git_submodule_that_is_not_checked_out_is_named_where_its_packages_are_missing(tmp_path):
    """A clone made without --recurse-submodules (or a new git worktree): the submodule's package
    was just absent from list and build, and a package depending on it was refused as wanting
    rosdep's sources."""
    root = copy_workspace(tmp_path / "robot", packages=(), test_packages=("beacon_nodes",))
    subprocess.run(["git", "init", "-q", str(root)], check=True)
    (root / ".gitmodules").write_text('[submodule "extra"]\n\tpath = ws/src/robot_extra\n\turl = ../extra.git\n')
    (root / "ws/src/robot_extra").mkdir(parents=True)
    warning = (
        "warning: ws/src/robot_extra is a git submodule that is not checked out (empty): no package in it is "
        "found; `git submodule update --init` checks it out"
    )
    for args in (("list",), ("build", "--dry-run")):
        said = espdock(*args, cwd=root, env=NO_ENGINE)
        assert warning in " ".join((said.stdout + said.stderr).split()), said.stdout + said.stderr
    (root / "ws/src/robot_extra/README.md").write_text("checked out\n")
    said = espdock("list", cwd=root, env=NO_ENGINE)
    assert "is a git submodule" not in said.stdout + said.stderr


def test_a_workspace_from_init_checks_its_scripts_out_with_lf_on_windows(tmp_path):
    """Git for Windows' core.autocrlf=true checked a node script out as `#!/usr/bin/env python3\\r\\n`:
    in the container env looked for `python3\\r` and the node did not start."""
    assert espdock("init", "robot", cwd=tmp_path, env=NO_ENGINE).returncode == 0
    robot = tmp_path / "robot"
    script = robot / "src/talker/scripts/talker"
    script.parent.mkdir(parents=True)
    script.write_text("#!/usr/bin/env python3\nprint('hello')\n")
    git = ["git", "-c", "user.name=u", "-c", "user.email=u@example.com"]
    subprocess.run([*git, "init", "-q", str(robot)], check=True)
    subprocess.run([*git, "-C", str(robot), "add", "-A"], check=True)
    subprocess.run([*git, "-C", str(robot), "commit", "-q", "-m", "robot"], check=True)
    windows = tmp_path / "windows"
    subprocess.run([*git, "-c", "core.autocrlf=true", "clone", "-q", str(robot), str(windows)], check=True)
    assert (windows / "src/talker/scripts/talker").read_bytes() == b"#!/usr/bin/env python3\nprint('hello')\n"
    # In a repository that says how its files are checked out, its rules stay in force (a deeper
    # file would win over them: a .bat's CRLF); a link in the way is not written through.
    (tmp_path / "repo").mkdir()
    (tmp_path / "repo/.gitattributes").write_text("*.bat text eol=crlf\n")
    assert espdock("init", "repo/robot", cwd=tmp_path, env=NO_ENGINE).returncode == 0
    assert not (tmp_path / "repo/robot/.gitattributes").exists()
    (tmp_path / "linked").mkdir()
    (tmp_path / "linked/.gitattributes").symlink_to(tmp_path / "shared/.gitattributes")
    (tmp_path / "shared").mkdir()
    assert espdock("init", "linked", cwd=tmp_path, env=NO_ENGINE).returncode == 0
    assert not (tmp_path / "shared/.gitattributes").exists()
    # One above the repository's top is not its (Git reads none there): written.
    (tmp_path / "home").mkdir()
    (tmp_path / "home/.gitattributes").write_text("*.x text\n")
    subprocess.run(["git", "init", "-q", str(tmp_path / "home/ws")], check=True)
    assert espdock("init", "home/ws", cwd=tmp_path, env=NO_ENGINE).returncode == 0
    assert (tmp_path / "home/ws/.gitattributes").is_file()


def test_init_in_the_src_of_a_workspace_or_inside_one_is_refused_leaving_nothing(tmp_path):
    """`cd ~/ros2_ws/src && espdock init` made src/ a workspace of its own (src/src/, found 0
    packages), which every later command below it then took for the workspace."""
    ws = tmp_path / "ros2_ws"
    (ws / "src/pkg").mkdir(parents=True)
    (ws / "src/pkg/package.xml").write_text((REPO / "ws/src/custom_interface/package.xml").read_text())
    refused = espdock("init", cwd=ws / "src", env=NO_ENGINE)
    assert refused.returncode == 2, refused.stdout + refused.stderr
    assert "holds packages (pkg): it is the src/ of a colcon workspace" in refused.stderr
    assert f"espdock init {ws}" in refused.stderr
    assert sorted(p.name for p in (ws / "src").iterdir()) == ["pkg"]
    assert espdock("init", cwd=ws, env=NO_ENGINE).returncode == 0
    nested = espdock("init", "src/pkg", cwd=ws, env=NO_ENGINE)
    assert nested.returncode == 2 and f"is inside the espdock workspace {ws}" in nested.stderr
    assert not (ws / "src/pkg/espdock.toml").exists()


def test_init_refused_after_looking_leaves_the_directory_as_it_was(tmp_path):
    """An invalid package.xml: init said "created espdock.toml", exited 2, and left it (and src/),
    so the next init said the directory was a workspace already; --force without --compose wrote
    a whole workspace before refusing."""
    ws = tmp_path / "ros2_ws"
    (ws / "src/p").mkdir(parents=True)
    (ws / "src/p/package.xml").write_text('<package format="3"><name>p</name>\n')
    refused = espdock("init", cwd=ws, env=NO_ENGINE)
    assert refused.returncode == 2 and "is not a valid package.xml" in refused.stderr, refused.stderr
    assert "created" not in refused.stdout and sorted(p.name for p in ws.iterdir()) == ["src"]
    forced = espdock("init", "new_ws", "--force", cwd=tmp_path, env=NO_ENGINE)
    assert forced.returncode == 2 and "--force goes with --compose" in forced.stderr, forced.stderr
    assert not (tmp_path / "new_ws").exists()


def test_run_refuses_a_params_file_of_this_machine_the_node_cannot_see(tmp_path):
    """`espdock run PKG EXE --ros-args --params-file install/.../params.yaml`, as one types it for
    `ros2 run`: the node's container has no such file, and rcl's "Couldn't parse params file" said
    nothing of why. Refused before any engine or image, with the path the runtime image has."""
    (tmp_path / "src").mkdir()
    (tmp_path / "espdock.toml").write_text("[espdock]\n")
    installed = tmp_path / "install/talker/share/talker/config/params.yaml"
    installed.parent.mkdir(parents=True)
    installed.write_text("talker: {}\n")
    (tmp_path / "mine.yaml").write_text("talker: {}\n")
    run = ("run", "talker", "talk", "--ros-args", "--params-file")
    result = espdock(*run, "install/talker/share/talker/config/params.yaml", cwd=tmp_path, env=NO_ENGINE)
    assert result.returncode == 2, result.stdout + result.stderr
    said = " ".join(result.stderr.split())
    assert "the node runs in a container, which has no" in said, said
    assert "--params-file /opt/espdock/ws/install/talker/share/talker/config/params.yaml" in said, said
    (installed.parent / "linked.yaml").symlink_to(tmp_path / "mine.yaml")  # as a native --symlink-install leaves it
    # espdock's --symlink-install links to the build containers' path: nowhere, here.
    (installed.parent / "dangling.yaml").symlink_to("/workspace/src/talker/config/params.yaml")
    for name in ("linked.yaml", "dangling.yaml"):
        linked = espdock(*run, f"install/talker/share/talker/config/{name}", cwd=tmp_path, env=NO_ENGINE)
        said = " ".join(linked.stderr.split())
        assert f"--params-file /opt/espdock/ws/install/talker/share/talker/config/{name}" in said, said
    mine = espdock(*run, str(tmp_path / "mine.yaml"), cwd=tmp_path / "src", env=NO_ENGINE)
    assert mine.returncode == 2 and "-v " in mine.stderr and "/params/mine.yaml" in mine.stderr, mine.stderr
    # Through a link to the workspace (where the user keeps it): rcl's error, exit 1, before.
    alias = tmp_path.parent / f"{tmp_path.name}-alias"
    alias.symlink_to(tmp_path)
    try:
        linked = espdock(*run, str(alias / "mine.yaml"), cwd=alias / "src", env=NO_ENGINE)
    finally:
        alias.unlink()
    assert linked.returncode == 2 and "/params/mine.yaml" in linked.stderr, linked.stderr
    # The mount to paste, quoted: a path with a space split in two.
    (tmp_path / "my params.yaml").write_text("talker: {}\n")
    spaced = espdock(*run, "my params.yaml", cwd=tmp_path, env=NO_ENGINE)
    said = " ".join(spaced.stderr.split())
    assert (
        "espdock run -v 'my params.yaml:/params/my params.yaml:ro' ... --params-file '/params/my params.yaml'" in said
    )
    # Mounted, in the image, or no file here: past the check (to the package, which is not there).
    mounted = ("run", "-v", "mine.yaml:/p/mine.yaml", *run[1:], "/p/mine.yaml")
    # A file of this machine outside the workspace and home may be the image's too (/opt/ros/... of a
    # ROS installed here, on the official image): rcl says whether it is.
    for given in (mounted, (*run, "/opt/ros/jazzy/x.yaml"), (*run, "/etc/hostname")):
        passed = espdock(*given, cwd=tmp_path, env=NO_ENGINE)
        assert "no ROS package 'talker'" in passed.stderr and "which has no" not in passed.stderr, passed.stderr


def test_a_copy_of_micro_ros_espidf_component_in_a_project_is_refused_naming_it(tmp_path):
    """Upstream's README clones the component into the app's components/: the copy replaced the
    library the IDF image keeps (IDF takes a project's own component of a name first), without a
    word; in a project without package.xml, colcon took its package.xml for a ROS package and
    failed on idf_component_register."""
    (tmp_path / "espdock.toml").write_text("[espdock]\n")
    app = tmp_path / "src/counter"
    shutil.copytree(REPO / "tests/firmware_packages/blink_fw", app)
    copy = app / "components/micro_ros_espidf_component"
    copy.mkdir(parents=True)
    (copy / "libmicroros.mk").write_text("all:\n")
    (copy / "CMakeLists.txt").write_text('idf_component_register(SRCS "x.c")\n')
    (copy / "package.xml").write_text(
        '<package format="3"><name>micro_ros_espidf</name><version>0.0.0</version><description>d</description>'
        '<maintainer email="m@example.com">m</maintainer><license>Apache-2.0</license></package>\n'
    )
    for manifest in (True, False):
        if not manifest:
            (app / "package.xml").unlink()
        result = espdock("build", "--dry-run", cwd=tmp_path, env=NO_ENGINE)
        said = " ".join(result.stderr.split())
        assert result.returncode == 2, result.stdout + result.stderr
        assert "src/counter/components/micro_ros_espidf_component is a copy of micro_ros_espidf_component" in said
        # Removed, the app must still name the image's: upstream's layout needed no line for it.
        assert "list(APPEND EXTRA_COMPONENT_DIRS $ENV{UROS_COMPONENT_DIR})" in said
    # In the components/ the projects share (where `espdock new` puts espdock_uros), IDF takes it too.
    shutil.copy2(REPO / "tests/firmware_packages/blink_fw/package.xml", app)
    shutil.move(copy, tmp_path / "src/components/uros")
    result = espdock("build", "blink_fw", "--dry-run", cwd=tmp_path, env=NO_ENGINE)
    assert result.returncode == 2 and "src/components/uros is a copy of micro_ros_espidf_component" in result.stderr


def test_an_idf_project_whose_package_xml_says_cmake_is_refused_with_the_build_type_to_set(tmp_path):
    """colcon ran CMake on it, which failed on `include($ENV{IDF_PATH}/...)` and said "Fix blink_fw"."""
    (tmp_path / "espdock.toml").write_text("[espdock]\n")
    app = tmp_path / "src/blink_fw"
    shutil.copytree(REPO / "tests/firmware_packages/blink_fw", app)
    manifest = app / "package.xml"
    manifest.write_text(
        manifest.read_text().replace("<build_type>esp_idf</build_type>", "<build_type>cmake</build_type>")
    )
    result = espdock("build", "--dry-run", cwd=tmp_path, env=NO_ENGINE)
    said = " ".join(result.stderr.split())
    assert result.returncode == 2 and "blink_fw (src/blink_fw) is an ESP-IDF project" in said, said
    assert "says build type cmake (or names none), which colcon builds with CMake alone" in said, said
    assert "<build_type>esp_idf</build_type>" in said
    # Misspelt, it is no build type colcon knows either: it was said to be built "with CMake alone".
    manifest.write_text(manifest.read_text().replace("<build_type>cmake<", "<build_type>esp-idf<"))
    said = " ".join(espdock("build", "--dry-run", cwd=tmp_path, env=NO_ENGINE).stderr.split())
    assert "its package.xml says build type esp-idf, not esp_idf" in said and "CMake alone" not in said, said


def test_init_says_how_an_esp_idf_project_it_finds_becomes_a_firmware_package(tmp_path):
    """init said "found 0 firmware package(s)" of an ESP-IDF project brought into src/, and nothing
    in a project's own directory, where it made src/ and the next build found nothing to build."""
    idf = "cmake_minimum_required(VERSION 3.16)\ninclude($ENV{IDF_PATH}/tools/cmake/project.cmake)\nproject(blinky)\n"
    (tmp_path / "ws/src/blinky").mkdir(parents=True)
    (tmp_path / "ws/src/blinky/CMakeLists.txt").write_text(idf)
    brought = espdock("init", cwd=tmp_path / "ws", env=NO_ENGINE)
    said = " ".join((brought.stdout + brought.stderr).split())
    assert brought.returncode == 0 and "src/blinky is not built: an ESP-IDF project with no package.xml" in said, said
    (tmp_path / "blinky").mkdir()
    (tmp_path / "blinky/CMakeLists.txt").write_text(idf)
    own = espdock("init", cwd=tmp_path / "blinky", env=NO_ENGINE)
    said = " ".join((own.stdout + own.stderr).split())
    assert own.returncode == 0 and "is an ESP-IDF project itself" in said and 'package_paths = ["."]' in said, said


def test_a_build_with_no_packages_says_where_it_looked(tmp_path):
    """A mistyped package_paths built nothing, said nothing and exited 0; --dry-run named ws/src,
    whatever the layout."""
    (tmp_path / "src").mkdir()
    (tmp_path / "espdock.toml").write_text('[espdock]\npackage_paths = ["scr"]\n')
    for args in (("build",), ("build", "--dry-run")):
        result = espdock(*args, cwd=tmp_path, env=NO_ENGINE)
        assert result.returncode == 0, result.stdout + result.stderr
        said = f"nothing to build: no packages in scr (package_paths); scr does not exist in {tmp_path}"
        assert said in " ".join(result.stdout.split()), result.stdout
    # A CI job's report too: its artefact step found no file.
    assert espdock("build", "--report", "report.json", cwd=tmp_path, env=NO_ENGINE).returncode == 0
    report = json.loads((tmp_path / "report.json").read_text())
    assert (report["outcome"], report["steps"], report["manifest"]) == ("succeeded", [], {})


def test_paths_that_are_not_utf_8_or_gone_are_bad_input_not_espdock_bugs(tmp_path):
    """A workspace path with a byte that is not UTF-8 was exit 70 ("a bug in espdock"), after
    init had made half a workspace; so was a current directory removed under the shell."""
    import os

    odd = Path(os.fsdecode(bytes(tmp_path) + b"/caf\xe9"))
    odd.mkdir()
    refused = espdock("init", cwd=odd, env=NO_ENGINE)
    assert refused.returncode == 2 and "the workspace's path is not UTF-8" in refused.stderr, refused.stderr
    assert list(odd.iterdir()) == []
    gone = tmp_path / "gone"
    gone.mkdir()
    listing = subprocess.run(
        ["sh", "-c", f'cd "{gone}" && rmdir "{gone}" && exec "$0" -m espdock list', sys.executable],
        capture_output=True, text=True, check=False, env={**os.environ, **NO_ENGINE},
    )  # fmt: skip
    assert listing.returncode == 2 and "the current directory no longer exists" in listing.stderr, listing.stderr

    def from_gone(*args: str) -> subprocess.CompletedProcess:
        gone.mkdir()
        return subprocess.run(
            ["sh", "-c", f'cd "{gone}" && rmdir "{gone}" && exec "$0" -m espdock "$@"', sys.executable, *args],
            capture_output=True, text=True, check=False, env={**os.environ, **NO_ENGINE}, stdin=subprocess.DEVNULL,
        )  # fmt: skip

    # Given where, init makes the workspace and ends 0: it crashed after writing it all.
    made = from_gone("init", str(tmp_path / "robot"))
    assert made.returncode == 0, made.stderr
    assert f"  cd {tmp_path / 'robot'}\n" in made.stdout, made.stdout
    relative = from_gone("init", "other")
    assert relative.returncode == 2 and "the current directory no longer exists" in relative.stderr, relative.stderr
    # With --workspace, as build and the others: on to the engine (none here), not a crash.
    root = copy_workspace(tmp_path / "w")
    for args in (("run", "-w", str(root), "espdock_demo", "camera_sim"), ("shell", "-w", str(root))):
        ran = from_gone(*args)
        assert ran.returncode not in (0, 70) and "bug in espdock" not in ran.stderr, (args, ran.stderr)
        assert "no longer exists" not in ran.stderr, (args, ran.stderr)


def test_idf_fullclean_is_espdock_s_reset_that_keeps_the_sdkconfig(tmp_path):
    from tests.conftest import REPO

    root = copy_workspace(tmp_path / "w")
    shutil.copytree(REPO / "firmware", root / "firmware")
    shutil.copy2(REPO / "Dockerfile.idf", root / "Dockerfile.idf")
    build = root / "ws/build/led_strip_node"
    (build / "managed_components/espressif__led_strip").mkdir(parents=True)
    (build / "CMakeCache.txt").write_text("IDF_TARGET:STRING=esp32c3\n")
    (build / "sdkconfig").write_text("CONFIG_FREERTOS_HZ=1000\n")
    # Set aside by a build whose defaults changed, with menuconfig's changes: the note names it.
    (build / "sdkconfig.old").write_text("CONFIG_FREERTOS_HZ=500\n")
    result = espdock("idf", "led_strip_node", "--", "fullclean", cwd=root, env=NO_ENGINE)
    assert result.returncode == 0, result.stderr
    assert "espdock's reset" in result.stdout
    assert sorted(p.name for p in build.iterdir()) == ["sdkconfig", "sdkconfig.old"]
    assert (build / "sdkconfig").read_text() == "CONFIG_FREERTOS_HZ=1000\n"
    assert (build / "sdkconfig.old").read_text() == "CONFIG_FREERTOS_HZ=500\n"


def test_each_command_is_registered_by_the_module_espdock_imports_for_it():
    # `espdock CMD` imports only COMMANDS[CMD]: a command missing there, or registered by
    # another module, would be "No such command" for the user.
    from espdock import cli

    app = cli.register()
    registered = {c.name or c.callback.__name__: c.callback.__module__ for c in app.registered_commands}
    for group in app.registered_groups:
        (module,) = {c.callback.__module__ for c in group.typer_instance.registered_commands}
        registered[group.name] = module
    assert {name: module.rsplit(".", 1)[1] for name, module in registered.items()} == cli.COMMANDS


def test_a_command_starts_without_the_other_commands_modules(tmp_path):
    import subprocess
    import sys

    script = (
        "import sys\nfrom espdock import cli\ncli.register(sys.argv[1:])\n"
        "print(' '.join(sorted(m for m in sys.modules if m.startswith('espdock.cli.'))))"
    )
    loaded = subprocess.run(
        [sys.executable, "-c", script, "test", "--help"], capture_output=True, text=True, check=True
    )
    assert loaded.stdout.split() == [
        "espdock.cli.complete",
        "espdock.cli.core",
        "espdock.cli.home",
        "espdock.cli.prune",
        "espdock.cli.testing",
        "espdock.cli.ui",
    ]
    everything = subprocess.run(
        [sys.executable, "-c", script, "--help", "test"], capture_output=True, text=True, check=True
    )
    assert "espdock.cli.firmware" in everything.stdout.split()
    # And the command itself works from its own module alone.
    result = espdock("flash", "--help", cwd=tmp_path, env=NO_ENGINE)
    assert result.returncode == 0 and "--port" in result.stdout, result.stderr


def imported(cwd: Path, *argv: str) -> set[str]:
    """The modules `espdock ARGV` in CWD imports (by `python -X importtime`), with no engine to reach."""
    started = subprocess.run(
        [sys.executable, "-X", "importtime", "-m", "espdock", *argv],
        cwd=cwd,
        check=False,
        capture_output=True,
        text=True,
        env={**os.environ, **NO_ENGINE},
    )
    return {line.rsplit("|", 1)[-1].strip() for line in started.stderr.splitlines()}


def test_commands_that_talk_to_no_engine_and_read_no_compose_file_load_neither_client(tmp_path):
    """http.client (with email's parser) and PyYAML were imported by every start: a ninth of
    `espdock list`'s CPU, a fifth of `--version`'s. Now the first call to the engine and
    compose.yaml's checks import them; a refusal of bad input, `list` and `verify` make neither."""
    root = copy_workspace(tmp_path / "w", packages=("custom_interface",))
    for argv in (("list",), ("build", "no_such_package"), ("verify",), ("--version",)):
        modules = imported(root, *argv)
        assert "espdock.cli" in modules and not {"http.client", "yaml"} & modules, argv


def test_only_help_and_usage_errors_load_typer_s_help_drawing(tmp_path):
    """Typer's rich help module (rich's Markdown, tracebacks) was imported by every start for
    espdock's patch of its console: a fifth of a no-change build's CPU. Help still gets it."""

    def loads_help_drawing(*argv: str) -> bool:
        return "typer.rich_utils" in imported(tmp_path, *argv)

    assert not loads_help_drawing("--version")
    assert not loads_help_drawing("list")  # no workspace here: espdock's own error
    assert loads_help_drawing("build", "--help")
    assert loads_help_drawing("build", "--no-such-option")


def test_typer_from_a_zip_keeps_its_other_modules_as_they_are(tmp_path):
    """Typer in a zip (a zipapp, a frozen espdock): the zip's importer is one loader for all its
    modules, and patching it for the help console patched every Typer module loaded after."""
    import zipfile

    import typer

    package = Path(typer.__file__).parent
    bundle = tmp_path / "bundle.zip"
    with zipfile.ZipFile(bundle, "w") as archive:
        for path in package.rglob("*.py"):
            archive.write(path, path.relative_to(package.parent))
    script = (
        f"import sys; sys.path.insert(0, {str(bundle)!r})\n"
        "import espdock.cli.core, typer.rich_utils, typer.cli\n"
        "assert typer.__file__.startswith(sys.path[0]), typer.__file__\n"
        "print(typer.rich_utils._get_rich_console.__qualname__)\n"
    )
    done = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=False)
    assert done.returncode == 0, done.stderr
    assert done.stdout.startswith("_help_console."), done.stdout


def test_tab_completes_the_workspace_s_packages_and_a_built_package_s_executables(tmp_path):
    """`espdock run <TAB>` offered nothing (nor did build, test or flash), where `ros2 run <TAB>`
    offers a native workspace's packages and then the package's executables."""
    root = copy_workspace(tmp_path / "w", test_packages=("beacon_nodes",))
    shutil.copytree(REPO / "firmware/led_strip_node", root / "firmware/led_strip_node")
    # What colcon installs for them: an executable beside one that is not, and the interface package.
    lib = root / "ws/install/beacon_nodes/lib/beacon_nodes"
    lib.mkdir(parents=True)
    for name, mode in (("beacon", 0o755), ("beacon_log", 0o755), ("README", 0o644)):
        (lib / name).write_text("#!/bin/sh\n")
        (lib / name).chmod(mode)
    (root / "ws/install/custom_interface/share").mkdir(parents=True)
    script = subprocess.run(
        [sys.executable, "-m", "espdock", "--show-completion", "bash"],
        capture_output=True,
        text=True,
        check=True,
        env={**os.environ, **NO_ENGINE},
    ).stdout
    bin_dir = tmp_path / "bin"
    bin_dir.mkdir()
    (bin_dir / "espdock").write_text(f'#!/bin/sh\nexec {sys.executable} -m espdock "$@"\n')
    (bin_dir / "espdock").chmod(0o755)

    def offered(line: str, cwd: Path = root) -> list[str]:
        """What bash's completion, as `espdock --install-completion` sets it up, offers after LINE."""
        words = line.split(" ")
        driver = (
            f"{script}\nCOMP_WORDS=({' '.join(repr(w) for w in words)}); COMP_CWORD={len(words) - 1}\n"
            "_espdock_completion espdock; printf '%s\\n' \"${COMPREPLY[@]}\"\n"
        )
        env = {**os.environ, **NO_ENGINE, "PATH": f"{bin_dir}:{os.environ['PATH']}", "HOME": str(tmp_path)}
        done = subprocess.run(["bash", "-c", driver], cwd=cwd, capture_output=True, text=True, env=env, check=True)
        assert done.stderr == "", done.stderr  # it would land in the line being typed
        return done.stdout.split()

    assert offered("espdock build ") == ["beacon_nodes", "custom_interface", "led_strip_node"]
    assert offered("espdock build beacon_nodes c") == ["custom_interface"]
    assert offered("espdock test beacon_nodes ") == ["custom_interface", "led_strip_node"]
    assert offered("espdock flash ") == ["led_strip_node"]
    assert offered("espdock run ") == ["beacon_nodes"]
    assert offered("espdock run beacon_nodes ") == ["beacon", "beacon_log"]
    assert offered("espdock run beacon_nodes beacon_") == ["beacon_log"]
    # From elsewhere, with the workspace named; outside any workspace, nothing and no error.
    assert offered(f"espdock run -w {root} beacon_nodes b", cwd=tmp_path) == ["beacon", "beacon_log"]
    assert offered("espdock build ", cwd=tmp_path) == []
    # The directory as typed, before the shell expands it; one that is not there is no workspace
    # (looked for above it, the one the user is in would answer).
    assert offered("espdock build -w ~/w b", cwd=tmp_path) == ["beacon_nodes"]
    assert offered("espdock build -w $HOME/w b", cwd=tmp_path) == ["beacon_nodes"]
    assert offered("espdock build -w typo ") == []
    # A name the file system refuses (too long): nothing, not a traceback.
    assert offered(f"espdock run {'x' * 300} ") == []


def test_the_list_of_commands_gives_each_summary_as_one_paragraph(tmp_path):
    """`espdock --help` broke each summary where its docstring's source line ended: "keeping the
    last few of" on one line, "each kind; never ..." on the next, at any width."""
    listed = espdock("--help", cwd=tmp_path, env={**NO_ENGINE, "COLUMNS": "400"})
    assert listed.returncode == 0, listed.stderr
    (prune,) = [line for line in listed.stdout.splitlines() if line.startswith("│ prune ")]
    assert "keeping the last few of each kind; never an image" in prune, listed.stdout
    group = espdock("micro-ros", "--help", cwd=tmp_path, env={**NO_ENGINE, "COLUMNS": "400"})
    rows = [line for line in group.stdout.splitlines() if line.startswith("│ ")]
    assert rows and all(not line[2:20].isspace() for line in rows), group.stdout  # no continued rows


def test_a_build_stopped_before_any_step_still_writes_its_report(tmp_path):
    """A CI job's `--report`: a missing engine or a stale lock stopped the build before the report
    was written, and the job's artefact step found nothing."""
    root = copy_workspace(tmp_path / "w")
    report = tmp_path / "report.json"
    result = espdock("build", "--no-locked", "--report", str(report), cwd=root, env=NO_ENGINE)
    assert result.returncode == 3, result.stderr
    data = json.loads(report.read_text())
    assert data["outcome"] == "failed" and data["steps"] == [] and data["manifest"] is None
    assert data["error"].startswith("no Docker engine answers at unix:///nonexistent/docker.sock")


def test_output_that_finds_no_room_is_a_full_disk_not_an_espdock_bug(tmp_path):
    """`espdock list > listing.txt` on a full disk (here /dev/full, which refuses every byte) was
    exit 70, "a bug in espdock", with a bug log to report; `--version` a raw traceback."""
    import os

    root = copy_workspace(tmp_path / "w", packages=())
    for args in (("list",), ("--version",), ("build", "--dry-run")):
        with open("/dev/full", "w") as full:
            result = subprocess.run(
                [sys.executable, "-m", "espdock", *args], cwd=root, stdout=full, stderr=subprocess.PIPE,
                text=True, check=False, env={**os.environ, **NO_ENGINE},
            )  # fmt: skip
        assert result.returncode == 7, (args, result.stderr)
        assert "could not write its output to /dev/full: No space left on device" in result.stderr
        assert "Traceback" not in result.stderr and "bug" not in result.stderr


def test_a_report_or_results_path_is_checked_before_the_build_and_its_directories_made(tmp_path):
    """A CI job's `--report out/report.json` (no out/ yet) or a file in the way was exit 70, "a
    bug in espdock", after the build had run, and its real exit code was lost."""
    root = copy_workspace(tmp_path / "w")
    (root / "afile").write_text("")
    for args, said in (
        (("build", "--report", "afile/report.json"), "--report afile/report.json: a file is in the way"),
        (("build", "--report", "ws"), "--report ws: that is a directory"),
        (("test", "--results", "afile"), "--results afile: that is a file"),
        # A system directory: it was exit 70, "a bug in espdock" (FileNotFoundError).
        (("test", "--results", "/proc/espdock-results"), "--results /proc/espdock-results: espdock (uid 0) cannot"),
        (("build", "--report", "/proc/espdock/r.json"), "--report /proc/espdock/r.json: espdock (uid 0) cannot"),
    ):
        result = espdock(*args, cwd=root, env=NO_ENGINE)
        assert result.returncode == 2 and said in result.stderr, (args, result.stderr)
        assert "bug" not in result.stderr
    stopped = espdock("build", "--report", "out/ci/report.json", cwd=root, env=NO_ENGINE)
    assert stopped.returncode == 3, stopped.stderr  # no engine: the build's own exit code
    assert json.loads((root / "out/ci/report.json").read_text())["outcome"] == "failed"


def test_an_error_nobody_reads_keeps_its_exit_code(tmp_path):
    """`espdock new Bad-Name 2>&1 | head -1`: the reader gone, rich made the exit code 1 where the
    error's is 2 (bad input), which a script checking for 2 took as another failure."""
    import os

    root = copy_workspace(tmp_path / "w", packages=())
    read_end, write_end = os.pipe()
    os.close(read_end)  # the reader is gone before espdock writes a byte
    try:
        result = subprocess.run(
            [sys.executable, "-m", "espdock", "new", "Bad-Name"], cwd=root, stdout=write_end, stderr=write_end,
            stdin=subprocess.DEVNULL, check=False, env={**os.environ, **NO_ENGINE},
        )  # fmt: skip
    finally:
        os.close(write_end)
    assert result.returncode == 2


def dry_run_says(root: Path) -> str:
    """What `espdock build --dry-run` in ROOT prints, whitespace folded (it must succeed)."""
    planned = espdock("build", "--dry-run", cwd=root, env=NO_ENGINE)
    said = " ".join((planned.stdout + planned.stderr).split())
    assert planned.returncode == 0, said
    return said


def test_a_firmware_dependency_micro_ros_has_no_headers_of_is_named_before_the_build(tmp_path):
    """<depend>nav2_msgs</depend> in a firmware package: nothing said so until the firmware's
    compile failed on a missing header, with the hint to fix the firmware."""
    root = copy_workspace(tmp_path / "w")
    shutil.copytree(REPO / "firmware", root / "firmware")
    assert "warning" not in dry_run_says(root)
    manifest = root / "firmware/led_strip_node/package.xml"
    manifest.write_text(manifest.read_text().replace("<depend>std_msgs</depend>", "<depend>nav2_msgs</depend>"))
    said = dry_run_says(root)
    assert "warning: led_strip_node depends on nav2_msgs: in no package" in said, said
    assert "underlay" not in said
    # One the caller's sourced underlay holds (a ROS team's overlay habit): the way that works is said.
    underlay = tmp_path / "under/install/nav2_msgs"
    (underlay / "share/nav2_msgs").mkdir(parents=True)
    (underlay / "share/nav2_msgs/package.xml").write_text("<package><name>nav2_msgs</name></package>\n")
    sourced = espdock(
        "build", "--dry-run", cwd=root, env={**NO_ENGINE, "AMENT_PREFIX_PATH": f"{underlay}:/opt/ros/jazzy"}
    )
    said = " ".join((sourced.stdout + sourced.stderr).split())
    assert f"The underlay you sourced has nav2_msgs in {underlay}" in said and "ln -s" in said, said


def test_a_dependency_rosdep_cannot_serve_that_a_sourced_underlay_holds_is_named_with_the_way_that_works(tmp_path):
    """An overlay workspace whose package depends on the underlay's (sourced, as colcon overlays
    are used): the refusal offered a rosdep rule, COLCON_IGNORE or another selection."""
    from espdock.build.prepare import _underlay_named
    from espdock.errors import DependencyError, LockError
    from espdock.workspace import Workspace

    prefix = tmp_path / "under/install/ovl_common"
    (prefix / "share/ovl_common").mkdir(parents=True)
    (prefix / "share/ovl_common/package.xml").write_text("<package><name>ovl_common</name></package>\n")

    @_underlay_named
    def refused(ws, *, env):
        raise DependencyError("1 package(s) depend on ...", "Ways out: ...", ("ovl_common", "python3-nope"))

    with pytest.raises(DependencyError) as caught:
        refused(Workspace(tmp_path / "over"), env={"AMENT_PREFIX_PATH": f"{prefix}:/opt/ros/jazzy"})
    assert caught.value.hint.startswith(f"The underlay you sourced has ovl_common in {prefix}: "), caught.value.hint
    assert caught.value.hint.endswith("Ways out: ...")
    with pytest.raises(DependencyError) as plain:
        refused(Workspace(tmp_path / "over"), env={"AMENT_PREFIX_PATH": "/opt/ros/jazzy"})
    assert plain.value.hint == "Ways out: ..."

    # Where rosdep could not even be asked (no lock, its sources out of reach): the same.
    @_underlay_named
    def unlocked(ws, *, env):
        refused = LockError("rosdep.lock.json is missing, and `rosdep update` failed ...", "Reach rosdep's sources")
        refused.keys = ("ovl_common",)
        raise refused

    with pytest.raises(LockError) as caught:
        unlocked(Workspace(tmp_path / "over"), env={"AMENT_PREFIX_PATH": str(prefix)})
    assert caught.value.hint.startswith("The underlay you sourced has ovl_common"), caught.value.hint


def test_the_dry_run_leaves_out_what_the_options_after_the_double_dash_skip(tmp_path):
    """`--dry-run -- --packages-skip-by-dep custom_interface` listed all three packages as to build."""
    root = copy_workspace(tmp_path / "w", packages=("custom_interface", "espdock_demo"))
    planned = espdock("build", "--dry-run", "--", "--packages-skip-by-dep", "custom_interface", cwd=root, env=NO_ENGINE)
    said = " ".join(planned.stdout.split())
    assert planned.returncode == 0, said + planned.stderr
    assert (
        "now: would build 1 of 2 package(s): custom_interface; the options after `--` leave out espdock_demo" in said
    ), said


def test_timestamps_reach_the_error_that_ends_the_command_and_the_notes_before_it(tmp_path):
    """`espdock build --timestamps` in CI: every line was timed but the error and its hint, and the
    notes and warnings said outside the steps (a misspelt variable's, the runtime image's)."""
    root = copy_workspace(tmp_path / "w")
    result = espdock("build", "--timestamps", cwd=root, env={**NO_ENGINE, "ESPDOCK_RUNTIME_IMAGES": "1"})
    lines = [line for line in result.stderr.splitlines() if line.strip()]
    assert result.returncode == 3 and lines, result.stderr
    assert all(re.match(r"\d\d:\d\d:\d\d (error|hint|warning): ", line) for line in lines), lines
    assert any(" warning: ESPDOCK_RUNTIME_IMAGES is no espdock setting" in line for line in lines), lines


def test_a_firmware_project_linked_from_outside_is_refused_when_planned(tmp_path):
    """It was refused only at its idf.py step, after its micro-ROS image (minutes when not cached),
    and `build --dry-run` showed nothing wrong."""
    root = copy_workspace(tmp_path / "w")
    shutil.copytree(REPO / "firmware", root / "firmware")
    outside = tmp_path / "elsewhere"
    shutil.move(root / "firmware/led_strip_node", outside)
    (root / "firmware/led_strip_node").symlink_to(outside)
    for args in (("build", "--dry-run"), ("build",)):
        result = espdock(*args, cwd=root, env=NO_ENGINE)
        assert result.returncode == 2, (args, result.stderr)
        assert "firmware package led_strip_node is linked from outside the workspace" in result.stderr


def test_an_interface_package_using_a_type_of_one_it_does_not_depend_on_is_named_before_the_build(tmp_path):
    """robot_state_msgs's message holds a robot_msgs/WheelSpeeds without <depend>robot_msgs</depend>:
    builds passed on the old install of robot_msgs, and micro-ROS's library build failed on it."""
    root = copy_workspace(tmp_path / "w", packages=())
    write_interface_package(root / "ws/src", "robot_msgs", service=False)
    state = write_interface_package(root / "ws/src", "robot_state_msgs", service=False, uses="robot_msgs")
    assert "warning" not in dry_run_says(root)
    manifest = state / "package.xml"
    manifest.write_text(manifest.read_text().replace("<depend>robot_msgs</depend>", ""))
    said = dry_run_says(root)
    assert (
        "warning: robot_state_msgs uses robot_msgs/WheelSpeeds (msg/RobotState.msg), but its package.xml does not "
        "depend on robot_msgs" in said
    ), said
    assert f"Add <depend>robot_msgs</depend> to {manifest}" in said


def test_an_output_path_in_root_s_directory_is_refused_as_bad_input_without_a_chown_hint(tmp_path, monkeypatch):
    """`--results /root/x` as a user: asking whether it exists raised PermissionError, exit 70,
    "a bug in espdock"."""
    from espdock.errors import ConfigError
    from espdock.images.containers import prepare_output

    private = tmp_path / "root-only"
    private.mkdir(mode=0o700)

    def refused(self, *args, **kwargs):
        raise PermissionError(13, "Permission denied", str(self))

    monkeypatch.setattr(Path, "exists", refused)  # as for a user: root reads any directory
    with pytest.raises(ConfigError, match="cannot write there") as err:
        prepare_output(private / "x", (4242, 4242), "--results", directory=True)
    assert err.value.exit_code == 2 and "chown" not in (err.value.hint or "")


def test_a_locale_that_cannot_write_a_character_gets_a_question_mark_not_a_crash(tmp_path):
    """LANG=en_US.ISO-8859-1 (or PYTHONIOENCODING=ascii) and a workspace called röbot: exit 70,
    "a bug in espdock" (UnicodeEncodeError) on the first bullet or on the path."""
    root = copy_workspace(tmp_path / "röbot")
    listed = espdock("list", cwd=root, env={"PYTHONIOENCODING": "ascii"})
    assert listed.returncode == 0 and "r?bot" in listed.stdout, listed.stderr
    planned = espdock("build", "--dry-run", cwd=root, env={"PYTHONIOENCODING": "ascii", **NO_ENGINE})
    assert planned.returncode == 0 and "custom_interface" in planned.stdout, planned.stderr


def test_a_utf8_workspace_path_is_read_as_utf8_whatever_the_locale(tmp_path):
    """LC_ALL=ja_JP.EUC-JP and a workspace called 机器人: every command said "the workspace's path
    is not UTF-8" (EUC-JP cannot read it); the path is UTF-8, as the engine takes it."""
    env = {**locale_env(tmp_path, "ja_JP", "EUC-JP"), **NO_ENGINE}
    root = copy_workspace(tmp_path / "机器人")
    # The command (`python -m espdock` stops in Python's own search for the module there).
    command = (str(Path(sys.executable).with_name("espdock")),)
    listed = espdock("list", cwd=root, env=env, prefix=command)
    assert listed.returncode == 0 and "custom_interface" in listed.stdout, listed.stderr
    planned = espdock("build", "--dry-run", cwd=root, env=env, prefix=command)
    assert planned.returncode == 0 and "custom_interface" in planned.stdout, planned.stderr


def test_sudo_keeping_the_user_s_home_leaves_nothing_of_root_s_in_it(tmp_path):
    """`sudo -E espdock list` (root, with the user's HOME): ~/.cache and espdock's cache in it were
    root's; the user's pip then could not make ~/.cache/pip."""
    home = tmp_path / "home"
    home.mkdir()
    os.chown(home, 4242, 4243)
    root = copy_workspace(tmp_path / "w", test_packages=("rosdeps_xml_count",))  # tinyxml2: rosdep runs
    env = {"HOME": str(home), "XDG_CACHE_HOME": "", "XDG_STATE_HOME": "", "ESPDOCK_STATE_DIR": "", **NO_ENGINE}
    listed = espdock("list", cwd=root, env=env)
    assert listed.returncode == 0, listed.stderr
    assert (home / ".cache/espdock").is_dir(), "nothing was written there: the test tests nothing"
    # `sudo -E espdock lock`: rosdep's meta cache in ~/.ros was root's, and the user's next lock
    # failed on it ("Permission denied", blamed on the network).
    locked = espdock("lock", cwd=root, env={**environment(tmp_path), **env})
    assert locked.returncode == 0, locked.stderr
    assert (home / ".ros/rosdep").is_dir(), "rosdep wrote nothing there: the test tests nothing"
    # An image build under `sudo -E` (Compose's buildx) left ~/.docker/buildx/current root's: the
    # user's next image build failed on it ("permission denied").
    (home / ".docker/buildx").mkdir(parents=True)
    os.chown(home / ".docker", 4242, 4243)
    (home / ".docker/buildx/current").write_text("{}")
    assert espdock("list", cwd=root, env=env).returncode == 0
    owners = {(p.relative_to(home).as_posix(), p.lstat().st_uid) for p in home.rglob("*")}
    assert {(rel, uid) for rel, uid in owners if uid != 4242} == set()


def test_sudo_keeping_the_user_s_cache_outside_the_home_hands_it_back(tmp_path):
    """XDG_CACHE_HOME and XDG_STATE_HOME on a scratch disk (a home quota's habit): `sudo -E espdock`
    left them root's, and every later espdock of the user's warned it could not record its images
    (so `espdock prune` never freed the workspace's old ones). Where the directory above is root's,
    what espdock made there stays root's."""
    home, scratch, other = tmp_path / "home", tmp_path / "scratch", tmp_path / "roots"
    for path in (home, scratch, other):
        path.mkdir()
    for path in (home, scratch):
        os.chown(path, 4242, 4243)
    root = copy_workspace(tmp_path / "w")
    env = {"HOME": str(home), "XDG_CACHE_HOME": str(scratch / "cache"), "XDG_STATE_HOME": str(scratch / "state"),
           "ESPDOCK_STATE_DIR": "", **NO_ENGINE}  # fmt: skip
    listed = espdock("list", cwd=root, env=env)
    assert listed.returncode == 0, listed.stderr
    assert (scratch / "cache/espdock").is_dir(), "nothing was written there: the test tests nothing"
    assert {p.relative_to(scratch).as_posix() for p in scratch.rglob("*") if p.lstat().st_uid != 4242} == set()
    listed = espdock("list", cwd=root, env={**env, "XDG_CACHE_HOME": str(other / "cache")})
    assert listed.returncode == 0, listed.stderr
    assert (other / "cache/espdock").is_dir(), "nothing was written there: the test tests nothing"
    assert {p.lstat().st_uid for p in (other, *other.rglob("*"))} == {0}
    # Written as under the home, there by `..`: root's directory, and what root made there, stay root's.
    shutil.rmtree(other / "cache")
    listed = espdock("list", cwd=root, env={**env, "XDG_CACHE_HOME": f"{home}/../{other.name}/cache"})
    assert listed.returncode == 0, listed.stderr
    assert (other / "cache/espdock").is_dir(), "nothing was written there: the test tests nothing"
    assert {p.lstat().st_uid for p in (other, *other.rglob("*"))} == {0}


def test_sudo_keeping_the_user_s_home_hands_back_nothing_a_link_there_leads_to_of_root_s(tmp_path):
    """A ~/.cache/espdock that links to a directory of root's: `sudo -E espdock list` handed every
    root-owned file there to the home's owner (with a link to /etc, /etc/shadow)."""
    home = tmp_path / "home"
    (home / ".cache").mkdir(parents=True)
    rootdir = tmp_path / "root-only"
    (rootdir / "sub").mkdir(parents=True)
    (rootdir / "sub/secret").write_text("root's\n")
    (home / ".cache/espdock").symlink_to(rootdir)
    for path in (home, home / ".cache"):
        os.chown(path, 4242, 4243)
    os.chown(home / ".cache/espdock", 4242, 4243, follow_symlinks=False)
    root = copy_workspace(tmp_path / "w")
    env = {"HOME": str(home), "XDG_CACHE_HOME": "", "XDG_STATE_HOME": "", "ESPDOCK_STATE_DIR": "", **NO_ENGINE}
    listed = espdock("list", cwd=root, env=env)
    assert listed.returncode == 0, listed.stderr
    written = {p.name for p in rootdir.iterdir()} - {"sub"}
    assert written, "espdock wrote nothing through the link: the test tests nothing"
    assert {p.lstat().st_uid for p in (rootdir, *rootdir.rglob("*"))} == {0}


def test_a_relative_state_dir_is_refused_before_any_work(tmp_path):
    """`ESPDOCK_STATE_DIR=relstate espdock build` from src/ made src/relstate, in the sources."""
    root = copy_workspace(tmp_path / "w")
    refused = espdock("build", "--dry-run", cwd=root / "ws/src", env={"ESPDOCK_STATE_DIR": "relstate", **NO_ENGINE})
    assert refused.returncode == 2, refused.stdout + refused.stderr
    assert "ESPDOCK_STATE_DIR must be an absolute path, got 'relstate'" in refused.stderr
    assert not (root / "ws/src/relstate").exists()
    # A `~` no shell expanded (a CI file's, a .env's): the way out is $HOME's, not a dir called ~.
    tilde = espdock("list", cwd=root, env={"ESPDOCK_STATE_DIR": "~/state", **NO_ENGINE})
    assert tilde.returncode == 2 and '(`"$HOME/state"`)' in tilde.stderr, tilde.stderr
    home = espdock("list", cwd=root, env={"ESPDOCK_STATE_DIR": "~", **NO_ENGINE})
    assert home.returncode == 2 and '(`"$HOME"`)' in home.stderr, home.stderr


def test_help_whose_reader_went_away_ends_as_a_closed_output_does(tmp_path):
    """`set -o pipefail; espdock build --help | grep -q -- --force`: exit 1 (rich's own) where the
    reader closed the pipe first, where espdock's own output gives 141 as SIGPIPE would."""
    process = subprocess.Popen(
        [sys.executable, "-m", "espdock", "build", "--help"],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    process.stdout.close()  # before Python has started: its first write finds no reader
    code = process.wait(timeout=60)
    assert code == 141, process.stderr.read()


def test_init_s_next_step_is_a_command_line_that_works_when_pasted(tmp_path):
    """`espdock init "my röbot ws"` said `cd my röbot ws && espdock new my_board`: cd: too many arguments."""
    made = espdock("init", "my röbot ws", cwd=tmp_path)
    assert made.returncode == 0, made.stderr
    steps = made.stdout.split("next:\n", 1)[1].splitlines()
    assert steps[0].strip() == "cd 'my röbot ws'", made.stdout
    # Pasted in order, as a user does (each line once had its own `cd DIR &&`: the second cd failed).
    pasted = "set -e\n" + "\n".join(line.split("#")[0] for line in steps if "espdock build" not in line)
    path = f"{Path(sys.executable).parent}:{os.environ['PATH']}"
    ran = subprocess.run(["bash", "-c", pasted], cwd=tmp_path, env={**os.environ, "PATH": path, **NO_ENGINE},
                         capture_output=True, text=True, check=False)  # fmt: skip
    assert ran.returncode == 0 and (tmp_path / "my röbot ws/src/my_board/package.xml").is_file(), ran.stderr
    # A name that starts with a dash: `cd -my-robot` said "cd: -m: invalid option".
    made = espdock("init", "--", "-my-robot", cwd=tmp_path)
    assert made.returncode == 0, made.stderr
    assert "  cd ./-my-robot\n" in made.stdout, made.stdout


def test_a_project_s_own_sdkconfig_which_the_build_does_not_read_is_named_before_it(tmp_path):
    """An existing IDF project moved in with its committed sdkconfig: espdock built from
    sdkconfig.defaults into ws/build/PKG/sdkconfig, and the firmware differed, unsaid."""
    root = copy_workspace(tmp_path / "w")
    shutil.copytree(REPO / "firmware", root / "firmware")
    (root / "firmware/led_strip_node/sdkconfig").write_text("CONFIG_FREERTOS_HZ=200\n")
    said = dry_run_says(root)
    assert (
        "warning: firmware/led_strip_node/sdkconfig is not read: the build's sdkconfig is "
        "ws/build/led_strip_node/sdkconfig" in said
    )
    assert "CONFIG_IDF_TARGET" not in said
    # `idf.py set-target esp32s3` wrote the project's chip there alone.
    (root / "firmware/led_strip_node/sdkconfig").write_text('CONFIG_IDF_TARGET="esp32s3"\nCONFIG_FREERTOS_HZ=200\n')
    assert 'and remove it; its chip too: CONFIG_IDF_TARGET="esp32s3"' in dry_run_says(root)


def test_compose_up_during_a_build_is_refused_before_it_makes_an_image_of_install(tmp_path):
    """`espdock compose run` 8 s into a build made the runtime image of a half rebuilt install/
    and moved `:latest` to it, where `espdock run` refuses. During `espdock build --force` (every
    package's install moved aside) `compose up` was not refused: it started the last build's
    `:latest`, warning that nothing was built yet."""
    root = copy_workspace(tmp_path / "w")
    installed = root / "ws/install/custom_interface"
    installed.mkdir(parents=True)
    with build_holding(root) as process:
        for subcommand in ("up", "run"):
            refused = espdock("compose", subcommand, cwd=root, env=NO_ENGINE)
            assert refused.returncode == 2, refused.stdout + refused.stderr
            assert f"an espdock build is running in {root} (pid {process.pid}: espdock build)" in refused.stderr
        installed.rename(installed.with_name("custom_interface.aside"))  # as the build rebuilding it afresh does
        for subcommand in ("up", "run", "create"):
            refused = espdock("compose", subcommand, cwd=root, env=NO_ENGINE)
            assert refused.returncode == 2, refused.stdout + refused.stderr
            assert f"an espdock build is running in {root} (pid {process.pid}: espdock build)" in refused.stderr
            assert "nothing is built" not in refused.stdout + refused.stderr
        installed.with_name("custom_interface.aside").rename(installed)
        assert espdock("compose", "ps", cwd=root, env=NO_ENGINE).returncode == 3  # not one that makes containers
        # A shell opens (its colcon would collide with the build's, in the same build dirs), and says so.
        shell = espdock("shell", cwd=root, env=NO_ENGINE)
        assert "warning: an espdock build is running" in shell.stdout + shell.stderr, shell.stdout + shell.stderr
    # The lock free again: on to the engine (none here).
    assert espdock("compose", "up", cwd=root, env=NO_ENGINE).returncode == 3


def test_compose_up_says_when_the_compose_file_lags_what_the_runtime_image_holds(tmp_path):
    """The compose file `espdock init` wrote before the first build has no service: `compose up`
    after the build ended in Compose's bare "no service selected". And one whose service runs a
    package gone from the branch started a container that died at once ("not found")."""
    from espdock.ros.compose import starter_compose

    root = copy_workspace(tmp_path / "lag", packages=(), test_packages=("beacon_nodes", "uptime_tools"))
    assert espdock("init", cwd=root, env=NO_ENGINE).returncode == 0  # compose.yaml, before any build
    before = espdock("compose", "up", cwd=root, env=NO_ENGINE)
    assert "note: compose.yaml has no node to run yet (espdock wrote it before anything was built): `espdock " \
        "build`, then `espdock init --compose`" in " ".join((before.stdout + before.stderr).split())  # fmt: skip
    for package, exes in (("beacon_nodes", ("beacon", "beacon_log")), ("uptime_tools", ("tools_banner",))):
        lib = root / "ws/install" / package / "lib" / package
        lib.mkdir(parents=True)
        for exe in exes:
            (lib / exe).write_text("#!/bin/sh\n")
            (lib / exe).chmod(0o755)

    def said_by_up(*options: str, env: dict[str, str] | None = None) -> str:
        up = espdock("compose", *options, "up", cwd=root, env={**NO_ENGINE, **(env or {})})
        assert up.returncode == 3, up.stdout + up.stderr  # on to the engine (none here)
        return " ".join((up.stdout + up.stderr).split())

    assert "note: compose.yaml runs none of beacon, beacon_log, tools_banner, built since espdock wrote it: " \
        "`espdock init --compose` writes the built executables as services" in said_by_up()  # fmt: skip
    assert espdock("init", "--compose", cwd=root, env=NO_ENGINE).returncode == 0
    assert "compose.yaml" not in said_by_up()
    shutil.rmtree(root / "ws/src/uptime_tools")  # a branch without it: install/ keeps it, the image does not
    assert "warning: compose.yaml: tools_banner (uptime_tools tools_banner) run what the runtime image lacks " \
        "(not built, or a package no longer in the workspace): their containers fail at start; `espdock init " \
        "--compose` writes it afresh" in said_by_up()  # fmt: skip
    compose = root / "compose.yaml"
    compose.write_text(compose.read_text() + "# the team's\n")
    assert "tools_banner (uptime_tools tools_banner) run what the runtime image lacks" in said_by_up()
    assert "edit or remove them in compose.yaml" in said_by_up()
    # Not of a service on another image (its own install tree), nor of one only a profile this run
    # does not turn on starts, nor where Compose merges an override into the file, nor where the
    # user chose another file (COMPOSE_FILE, here in the .env Compose reads).
    service = "  tools_banner:\n    <<: *ros-node\n"
    text = compose.read_text()
    # A tag of this workspace's image pinned in the file holds what it was made of, not install/.
    pinned = "    image: espdock/lag:0123456789abcdef\n"
    for added in (pinned, "    image: espdock/demo:latest\n", "    profiles: [legacy]\n"):
        compose.write_text(text.replace(service, service + added))
        assert "run what the runtime image lacks" not in said_by_up(), compose.read_text()
    lacks = "tools_banner (uptime_tools tools_banner) run what the runtime image lacks"
    assert lacks in said_by_up("--profile", "legacy") and lacks in said_by_up(env={"COMPOSE_PROFILES": "x,legacy"})
    compose.write_text(text)
    (root / "compose.override.yaml").write_text("services:\n  tools_banner:\n    command: [/bin/true]\n")
    assert "run what the runtime image lacks" not in said_by_up()
    (root / "compose.override.yaml").unlink()
    (root / ".env").write_text("COMPOSE_FILE=other.yaml\n")
    assert "run what the runtime image lacks" not in said_by_up()
    (root / ".env").unlink()
    # `ros2 launch` as a service's command: the container ended at once, "exec: ros2: not found".
    launch = "  bringup:\n    <<: *ros-node\n    command: [ros2, launch, beacon_nodes, robot.launch.py]\n"
    compose.write_text(text.replace("services:\n", "services:\n" + launch))
    assert "compose.yaml: bringup run `ros2`, which the runtime image lacks" in said_by_up()
    compose.write_text(
        text.replace("services:\n", "services:\n" + launch.replace("ros-node", "ros-node\n    profiles: [x]"))
    )
    assert "`ros2`" not in said_by_up()
    # Another workspace's file as espdock wrote it (a clone's): it runs none of this one's nodes,
    # which is not "built since", and its services come back after a build, not before one.
    compose.write_text(starter_compose("robot", "espdock/robot:latest", {"beacon_nodes": ["beacon"]}))
    said = said_by_up()
    assert "compose.yaml runs espdock/robot:latest, another workspace's runtime image" in said, said
    assert "`espdock build`, then `espdock init --compose`, writes it afresh for this workspace" in said, said
    assert "runs none of" not in said and "no node to run yet" not in said, said


def test_compose_up_refuses_a_service_mounting_a_path_that_is_not_there(tmp_path):
    """A mistyped params file (`./src/bringup/config/param.yaml:/params/params.yaml:ro`): Docker
    made a root-owned directory of that name in the sources, and the node died on it."""
    root = copy_workspace(tmp_path / "binds", packages=())
    assert espdock("init", cwd=root, env=NO_ENGINE).returncode == 0
    compose = root / "compose.yaml"
    written = compose.read_text()
    (root / "src/config").mkdir(parents=True)
    (root / "src/config/params.yaml").write_text("{}\n")

    def up_with(volumes: str, profiles: str = "") -> subprocess.CompletedProcess:
        service = f"  node:\n    image: busybox\n{profiles}    volumes:\n{volumes}"
        compose.write_text(written.replace("services:\n", "services:\n" + service))
        return espdock("compose", "up", cwd=root, env=NO_ENGINE)

    refused = up_with("      - ./src/config/param.yaml:/params/params.yaml:ro\n")
    said = " ".join(refused.stderr.split())
    assert refused.returncode == 2, refused.stdout + refused.stderr
    assert "compose.yaml: node mounts ./src/config/param.yaml, which is not there" in said, said
    assert not (root / "src/config/param.yaml").exists()
    # What is there, a named volume, an interpolated path, a service this run does not start: on
    # to the engine (none here).
    for volumes, profiles in (
        ("      - ./src/config/params.yaml:/params/params.yaml:ro\n      - data:/data\n", ""),
        ("      - ${CONFIG_DIR}/param.yaml:/params/params.yaml\n", ""),
        ("      - ./src/config/param.yaml:/params/params.yaml:ro\n", "    profiles: [typo]\n"),
        ("      - /var/lib/node_cache\n", ""),  # an anonymous volume: no path of the host's
    ):
        went_on = up_with(volumes, profiles)
        assert went_on.returncode == 3, went_on.stdout + went_on.stderr
    # Another service named: this one does not start.
    up_with("      - ./src/config/param.yaml:/params/params.yaml:ro\n")
    compose.write_text(compose.read_text().replace("services:\n", "services:\n  other:\n    image: busybox\n"))
    assert espdock("compose", "up", "-d", "other", cwd=root, env=NO_ENGINE).returncode == 3
    assert espdock("compose", "up", "-d", "node", cwd=root, env=NO_ENGINE).returncode == 2


def test_a_clone_or_worktree_runs_its_own_nodes_from_the_committed_compose_file(tmp_path):
    """The file `espdock init --compose` writes is committed: a git worktree or clone of another
    name ran the original's runtime image in the original's project (its `compose down` removed
    the original's running services), and espdock's fix was an edit of the committed file."""
    robot = copy_workspace(tmp_path / "robot", packages=(), test_packages=("beacon_nodes",))
    lib = robot / "ws/install/beacon_nodes/lib/beacon_nodes"
    lib.mkdir(parents=True)
    for exe in ("beacon", "beacon_log"):
        (lib / exe).write_text("#!/bin/sh\n")
        (lib / exe).chmod(0o755)
    assert espdock("init", "--compose", cwd=robot, env=NO_ENGINE).returncode == 0
    assert "espdock/robot:latest" not in (robot / "compose.yaml").read_text()
    feat = tmp_path / "robot-feat"
    shutil.copytree(robot, feat, symlinks=True)
    up = espdock("compose", "up", cwd=feat, env=NO_ENGINE)
    assert up.returncode == 3, up.stdout + up.stderr  # on to the engine (none here)
    assert "compose.yaml" not in up.stdout + up.stderr, up.stdout + up.stderr
    # A refresh there keeps the committed file's name to fall back on: the original's plain
    # `docker compose` ran the worktree's image once the refreshed file was merged.
    (lib / "beacon").unlink()
    shutil.copytree(robot / "ws/install", feat / "ws/install", dirs_exist_ok=True)
    (feat / "ws/install/beacon_nodes/lib/beacon_nodes/beacon").unlink()
    assert espdock("init", "--compose", cwd=feat, env=NO_ENGINE).returncode == 0
    refreshed = (feat / "compose.yaml").read_text()
    assert "name: ${ESPDOCK_NAME:-robot}\n" in refreshed and "/beacon]" not in refreshed, refreshed
    # A name set in espdock.toml, which every worktree shares: the file falls back to it from then on
    # (it kept the directory's, and plain `docker compose up` pulled espdock/robot-feat from Docker Hub).
    config = feat / "espdock.toml"
    config.write_text(config.read_text().replace("[espdock]\n", '[espdock]\nname = "fleet"\n', 1))
    named = espdock("init", "--compose", cwd=feat, env=NO_ENGINE)
    assert named.returncode == 0 and "nothing changed" not in named.stdout, named.stdout + named.stderr
    assert "name: ${ESPDOCK_NAME:-fleet}\n" in (feat / "compose.yaml").read_text()
    # Nothing built yet (a fresh worktree): a build first, not a refresh that writes no service.
    shutil.rmtree(feat / "ws/install")
    said = " ".join(espdock("compose", "up", cwd=feat, env=NO_ENGINE).stdout.split())
    assert "compose.yaml: nothing is built in this workspace yet" in said and "init --compose" not in said, said
    # A file an earlier espdock wrote, its name literal: `down` there removed the original's services.
    from espdock.ros.compose import starter_compose

    (feat / "compose.yaml").write_text(starter_compose("robot", "espdock/robot:latest", {"beacon_nodes": ["beacon"]}))
    down = espdock("compose", "down", cwd=feat, env=NO_ENGINE)
    said = " ".join(down.stderr.split())
    assert down.returncode == 2, down.stdout + down.stderr
    assert "compose.yaml names its project robot, another workspace's (it runs espdock/robot:latest)" in said, said
    knowingly = espdock("compose", "-p", "robot", "down", cwd=feat, env=NO_ENGINE)
    assert knowingly.returncode == 3, knowingly.stdout + knowingly.stderr  # on to the engine (none here)
    # ESPDOCK_NAME in the .env, which plain `docker compose` takes and `espdock compose` overrides.
    (feat / "compose.yaml").write_text((robot / "compose.yaml").read_text())
    for named, noted in (("elsewhere", True), ("robot-feat", False)):
        (feat / ".env").write_text(f"ESPDOCK_NAME={named}\n")
        ps = espdock("compose", "ps", cwd=feat, env=NO_ENGINE)
        assert ("ESPDOCK_NAME=elsewhere in the env file is not this workspace's name" in ps.stdout) is noted, ps.stdout
    (feat / ".env").unlink()
    # Its services are still checked against this workspace's install/.
    shutil.copytree(robot / "ws/install", feat / "ws/install")
    (feat / "compose.yaml").write_text((robot / "compose.yaml").read_text())
    shutil.rmtree(feat / "ws/src/beacon_nodes")
    again = espdock("compose", "up", cwd=feat, env=NO_ENGINE)
    said = " ".join((again.stdout + again.stderr).split())
    assert "compose.yaml: beacon (beacon_nodes beacon), beacon_log (beacon_nodes beacon_log) run what" in said, said


# The repository's boards: camera_node depends on custom_interface, led_strip_node does not.
BOTH_BOARDS = ("camera_node", "led_strip_node")


def firmware_plan_said(root: Path) -> str:
    """What `espdock build --dry-run --only firmware` says in ROOT (no engine), its whitespace folded;
    the plan must succeed."""
    plan = espdock("build", "--dry-run", "--only", "firmware", cwd=root, env=NO_ENGINE)
    said = " ".join((plan.stdout + plan.stderr).split())
    assert plan.returncode == 0, said
    return said


def test_a_node_beside_the_interfaces_of_the_firmware_s_library_is_warned_of(tmp_path):
    """custom_interface with a C++ node of its own (rclcpp beside rosidl_generate_interfaces, as many
    real packages are): the ROS side built it, and micro-ROS's library build, which runs its whole
    CMakeLists.txt with no rclcpp, would fail on it minutes in, without a word before."""
    root = firmware_workspace(tmp_path, BOTH_BOARDS)
    cmake = root / "ws/src/custom_interface/CMakeLists.txt"
    plain = cmake.read_text()
    tests = "if(BUILD_TESTING)\n  find_package(rclcpp REQUIRED)\n  if(UNIX)\n  endif()\nendif()\n"
    cmake.write_text(plain + tests)
    assert "requires" not in firmware_plan_said(root)  # BUILD_TESTING is OFF there
    cmake.write_text(
        plain + "find_package(rclcpp REQUIRED)  # the node\nfind_package(rosidl_typesupport_cpp REQUIRED)\n"
    )
    said = firmware_plan_said(root)
    assert (
        "warning: camera_node's micro-ROS library holds custom_interface, whose CMakeLists.txt requires rclcpp, "
        "rosidl_typesupport_cpp: micro-ROS's library build runs the whole of it" in said
    ), said
    assert "led_strip_node's micro-ROS library holds custom_interface" not in said  # it does not depend on it
    # Another interface package of the workspace, its <depend> left out of custom_interface's
    # package.xml: that is what to mend, not a node's requirement to move out of the package.
    write_interface_package(root / "ws/src", "base_msgs", service=False)
    cmake.write_text(
        plain.replace(
            "find_package(rosidl_default_generators",
            "find_package(base_msgs REQUIRED)\nfind_package(rosidl_default_generators",
            1,
        )
    )
    assert "requires base_msgs" not in firmware_plan_said(root)


def test_a_type_micro_ros_cannot_build_in_an_interface_package_of_the_firmware_s_library_is_warned_of(tmp_path):
    """custom_interface, which camera_node depends on, used nav2_msgs/Costmap: rosdep gives the ROS
    side nav2_msgs, micro-ROS's library build has no such package and failed (minutes into a real
    one), and no warning came before, where the firmware's own unknown <depend>s get one."""
    root = firmware_workspace(tmp_path, BOTH_BOARDS)
    msg = root / "ws/src/custom_interface/msg/CameraConfig.msg"
    msg.write_text(msg.read_text() + "nav2_msgs/Costmap map\n")
    said = firmware_plan_said(root)
    assert (
        "warning: camera_node's micro-ROS library holds custom_interface, whose msg/CameraConfig.msg uses "
        "nav2_msgs/Costmap: nav2_msgs is in no package of this workspace" in said
    ), said
    assert "led_strip_node's micro-ROS library holds custom_interface" not in said  # it does not depend on it


def test_a_workspace_option_naming_no_directory_is_refused(tmp_path):
    """`espdock compose exec -w src ...` took Compose's -w for espdock's --workspace, and `src`,
    which is not there, found the workspace above it: the command ran, elsewhere than asked."""
    root = copy_workspace(tmp_path / "w", packages=())
    result = espdock("list", "--workspace", "src", cwd=root)
    assert result.returncode == 2, result.stdout + result.stderr
    assert "--workspace src: no such directory" in result.stderr, result.stderr


def test_the_shell_completes_commands_and_options(tmp_path):
    """`espdock --install-completion` was "No such option", and there was no completion at all."""
    env = {**os.environ, "_ESPDOCK_COMPLETE": "complete_bash", "COMP_CWORD": "2"}
    completed = subprocess.run([sys.executable, "-m", "espdock"], cwd=tmp_path, capture_output=True, text=True,
                               env={**env, "COMP_WORDS": "espdock build --dr"}, check=False)  # fmt: skip
    assert completed.returncode == 0 and completed.stdout.split() == ["--dry-run"], completed.stdout + completed.stderr
    shown = subprocess.run([sys.executable, "-m", "espdock", "--show-completion", "bash"], cwd=tmp_path,
                           capture_output=True, text=True, check=False)  # fmt: skip
    assert shown.returncode == 0 and "complete -o default -F _espdock_completion espdock" in shown.stdout, shown.stdout


def test_a_read_only_directory_espdock_must_write_is_named_not_called_a_bug(tmp_path):
    """A workspace on a read-only mount (a CI cache, a bind mount with :ro): `espdock new` and an
    up-to-date build were exit 70, "a bug in espdock", on the first file they wrote."""
    import os

    made = espdock("init", "ws", cwd=tmp_path)
    assert made.returncode == 0, made.stderr
    shared = tmp_path / "ws/src/components"
    shared.mkdir()
    espdock_argv = f'"{sys.executable}" -m espdock new ro_board'
    # A private mount namespace: the read-only bind mount is this command's alone.
    script = f'mount --bind "{shared}" "{shared}" && mount -o remount,bind,ro "{shared}" && exec {espdock_argv}'
    if subprocess.run(["unshare", "-m", "true"], capture_output=True, check=False).returncode != 0:
        pytest.skip("no mount namespace here (unshare -m needs CAP_SYS_ADMIN)")
    refused = subprocess.run(
        ["unshare", "-m", "sh", "-c", script], cwd=tmp_path / "ws", capture_output=True, text=True, check=False,
        env={**os.environ, **NO_ENGINE},
    )  # fmt: skip
    assert refused.returncode == 2, refused.stderr
    assert f"espdock cannot use {shared}/COLCON_IGNORE: Read-only file system" in refused.stderr, refused.stderr
    assert "bug in espdock" not in refused.stderr


def test_a_baud_rate_a_raw_socket_cannot_use_is_said_unused(tmp_path):
    """`espdock flash PKG --port socket://... --baud 921600` (or ESPBAUD) flashed at the server's
    rate without a word; `idf.py -b` through `espdock idf` passes it on."""
    from tests.conftest import REPO

    root = copy_workspace(tmp_path / "w")
    shutil.copytree(REPO / "firmware", root / "firmware")
    shutil.copy2(REPO / "Dockerfile.idf", root / "Dockerfile.idf")
    port = ("--port", "socket://127.0.0.1:9")
    asked = espdock("flash", "led_strip_node", *port, "--baud", "921600", cwd=root, env=NO_ENGINE)
    said = " ".join(asked.stdout.split())
    assert "note: --baud 921600 is not used on socket://127.0.0.1:9: a raw socket has no baud rate" in said, said
    from_env = espdock("provision", "led_strip_node", *port, cwd=root, env={**NO_ENGINE, "ESPBAUD": "115200"})
    assert "note: --baud 115200 is not used" in " ".join(from_env.stdout.split()), from_env.stdout
    plain = espdock("flash", "led_strip_node", *port, cwd=root, env=NO_ENGINE)
    assert "is not used" not in plain.stdout, plain.stdout
    serial = espdock(
        "flash", "led_strip_node", "--port", "rfc2217://127.0.0.1:9", "-b", "921600", cwd=root, env=NO_ENGINE
    )
    assert "is not used" not in serial.stdout, serial.stdout


def test_init_compose_from_inside_a_workspace_refreshes_that_workspace_s_file(tmp_path):
    """`espdock init --compose` from src/pkg/launch, where every other command finds the workspace:
    refused as a new workspace inside the workspace."""
    assert espdock("init", "ws", cwd=tmp_path, env=NO_ENGINE).returncode == 0
    inner = tmp_path / "ws/src/pkg/launch"
    inner.mkdir(parents=True)
    refreshed = espdock("init", "--compose", cwd=inner, env=NO_ENGINE)
    assert refreshed.returncode == 0, refreshed.stderr
    assert "compose.yaml is up to date with install/" in refreshed.stdout, refreshed.stdout
    assert sorted(p.name for p in inner.iterdir()) == []
    # A new workspace there is still refused, naming the one around it.
    refused = espdock("init", cwd=inner, env=NO_ENGINE)
    assert refused.returncode == 2 and f"inside the espdock workspace {tmp_path / 'ws'}" in refused.stderr


def test_new_firmware_where_src_links_out_of_the_workspace_is_refused_before_writing(tmp_path):
    """`ln -s ~/store src`: `espdock new` wrote a firmware package the build then refused ("linked
    from outside the workspace"), blaming the package."""
    store = tmp_path / "store"
    store.mkdir()
    (tmp_path / "ws").mkdir()
    (tmp_path / "ws/src").symlink_to(store)
    assert espdock("init", cwd=tmp_path / "ws", env=NO_ENGINE).returncode == 0
    made = espdock("new", "lnk_board", cwd=tmp_path / "ws", env=NO_ENGINE)
    assert made.returncode == 2, made.stdout + made.stderr
    said = " ".join(made.stderr.split())
    assert f"{tmp_path / 'ws/src'} leads outside the workspace ({store})" in said, said
    assert list(store.iterdir()) == []


def test_a_link_under_the_package_paths_that_leads_nowhere_is_named(tmp_path):
    """`ln -s ../../underlay_checkout/src src/under_ws` on a clone where that checkout lies elsewhere:
    list showed the other packages and said nothing; the build failed on a dependency of what it held."""
    root = copy_workspace(tmp_path / "w")
    (root / "ws/src/under_ws").symlink_to("../../underlay_checkout/src")
    listed = espdock("list", cwd=root, env=NO_ENGINE)
    said = " ".join((listed.stdout + listed.stderr).split())
    assert listed.returncode == 0, said
    assert "warning: ws/src/under_ws is a link that leads nowhere (../../underlay_checkout/src)" in said, said
    assert "ws/src/under_ws is a link that leads nowhere" in dry_run_says(root)
    names = espdock("list", "--names", cwd=root, env=NO_ENGINE)
    assert names.stdout.split() == ["custom_interface"] and "leads nowhere" in names.stderr, names.stdout
    # Inside a package no package is looked for: a doc's broken link there hides none.
    (root / "ws/src/under_ws").unlink()
    (root / "ws/src/custom_interface/NOTES.md").symlink_to("missing.md")
    assert "leads nowhere" not in dry_run_says(root)


def test_save_defconfig_of_a_one_off_chip_s_build_dir_is_refused_before_it_writes(tmp_path):
    """`espdock build PKG --target esp32s3`, then `espdock idf PKG -- save-defconfig`: IDF wrote
    CONFIG_IDF_TARGET="esp32s3" into sdkconfig.defaults, and every later build was for esp32s3."""
    root = copy_workspace(tmp_path / "w")
    shutil.copytree(REPO / "firmware", root / "firmware")
    shutil.copy2(REPO / "Dockerfile.idf", root / "Dockerfile.idf")
    defaults = root / "firmware/led_strip_node/sdkconfig.defaults"
    before = defaults.read_bytes()
    marker = root / "ws/build/led_strip_node/.espdock-target"
    marker.parent.mkdir(parents=True)
    marker.write_text("esp32s3\n\n0123456789abcdef\n")
    saved = espdock("idf", "led_strip_node", "--", "save-defconfig", cwd=root, env=NO_ENGINE)
    said = " ".join(saved.stderr.split())
    assert saved.returncode == 2, saved.stdout + saved.stderr
    assert "build/led_strip_node is a one-off esp32s3 build" in said and "Nothing was written" in said, said
    assert "in firmware/led_strip_node/sdkconfig.defaults.esp32s3 by hand" in said, said
    assert defaults.read_bytes() == before
    # The files a CMakeLists' SDKCONFIG_DEFAULTS names are the ones to edit: the hint named two no
    # build of it reads.
    cmake = root / "firmware/led_strip_node/CMakeLists.txt"
    cmake.write_text('set(SDKCONFIG_DEFAULTS "sdkconfig.defaults.local")\n' + cmake.read_text())
    listed = espdock("idf", "led_strip_node", "--", "save-defconfig", cwd=root, env=NO_ENGINE)
    said = " ".join(listed.stderr.split())
    assert listed.returncode == 2, listed.stdout + listed.stderr
    assert "in firmware/led_strip_node/sdkconfig.defaults.local.esp32s3 by hand" in said, said
    assert 'CONFIG_IDF_TARGET="esp32s3" in its sdkconfig.defaults.local to make' in said, said


def test_notes_go_to_stderr_where_stdout_is_a_node_s(capsys):
    """`espdock run` and `shell` set it: `espdock run pkg dump > data` took espdock's warnings into the data."""
    from espdock.cli import core

    core.notify("note: on stdout")
    core.NOTES["stderr"] = True
    try:
        core.notify("warning: on stderr")
    finally:
        core.NOTES["stderr"] = False
    captured = capsys.readouterr()
    assert "note: on stdout" in captured.out and "warning: on stderr" in captured.err
    assert "warning" not in captured.out


def test_compose_commands_that_start_nothing_do_not_wait_for_a_package_xml_being_edited(tmp_path):
    """`espdock compose down` while a package.xml was half typed: exit 2 on the manifest, and the
    services kept running (plain `docker compose down` may name another project)."""
    root = copy_workspace(tmp_path / "w", packages=(), test_packages=("beacon_nodes",))
    manifest = root / "ws/src/beacon_nodes/package.xml"
    manifest.write_text(manifest.read_text().replace("</package>", "</packag"))
    for subcommand in ("down", "stop", "ps"):
        ended = espdock("compose", subcommand, cwd=root, env=NO_ENGINE)
        assert ended.returncode == 3, (subcommand, ended.stdout + ended.stderr)  # on to the engine (none here)
    started = espdock("compose", "up", cwd=root, env=NO_ENGINE)
    assert started.returncode == 2 and "is not a valid package.xml" in started.stderr, started.stderr


def test_run_before_the_first_build_says_to_build_not_to_lock(tmp_path):
    """`espdock run PKG EXE` in a new workspace said "rosdep.lock.json is missing", which the build it
    should have named makes itself."""
    root = copy_workspace(tmp_path / "w", packages=(), test_packages=("beacon_nodes",))
    (root / "rosdep.lock.json").unlink(missing_ok=True)
    manifest = root / "ws/src/beacon_nodes/package.xml"  # a key the image lacks: the lock must answer for it
    manifest.write_text(
        manifest.read_text()
        .replace("</export>", "</export>", 1)
        .replace("<export>", "<exec_depend>python3-serial</exec_depend>\n  <export>", 1)
    )
    result = espdock("run", "beacon_nodes", "beacon", cwd=root, env=NO_ENGINE)
    said = " ".join(result.stderr.split())
    assert result.returncode == 2 and "rosdep.lock.json" not in said, said
    assert "espdock build beacon_nodes" in said, said
