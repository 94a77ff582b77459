import contextlib
import os
import re
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest

import espdock.workspace
from espdock.errors import WorkspaceError
from espdock.workspace import (
    PackageKind,
    Workspace,
    discover_packages,
    find_workspace,
    order_packages,
    select_up_to,
)

MANIFEST = """<?xml version="1.0"?>
<package format="3">
  <name>{name}</name>
  <version>0.1.0</version>
  <description>test package</description>
  <maintainer email="dev@example.com">dev</maintainer>
  <license>Apache-2.0</license>
  {deps}
  {groups}
  <export><build_type>{build_type}</build_type></export>
</package>
"""


def add_package(base: Path, name: str, depends=(), build_type="ament_cmake", interface=False) -> Path:
    path = base / name
    path.mkdir(parents=True)
    deps = "\n  ".join(f"<depend>{d}</depend>" for d in depends)
    groups = "<member_of_group>rosidl_interface_packages</member_of_group>" if interface else ""
    (path / "package.xml").write_text(MANIFEST.format(name=name, deps=deps, groups=groups, build_type=build_type))
    return path


@pytest.fixture
def ws(tmp_path: Path) -> Workspace:
    (tmp_path / "espdock.toml").write_text("[espdock]\n")
    return Workspace(tmp_path)


def test_finds_the_workspace_from_a_subdirectory(ws):
    deep = ws.root / "ws" / "src" / "a" / "b"
    deep.mkdir(parents=True)
    assert find_workspace(deep) == ws


def test_a_package_linked_in_from_a_checkout_elsewhere_is_in_the_workspace_the_shell_reached_it_in(
    tmp_path, monkeypatch
):
    """`ln -s ~/checkouts/utils src/`, as the docs offer, then `cd src/utils/robot_utils`:
    espdock build said "not inside an espdock workspace", and `espdock init` made the other
    repository a workspace of its own."""
    from espdock.firmware.scaffold import init_workspace

    root = tmp_path / "robot_ws"
    (root / "src").mkdir(parents=True)
    (root / "espdock.toml").write_text("[espdock]\n")
    checkout = tmp_path / "checkouts/utils/robot_utils"
    checkout.mkdir(parents=True)
    (root / "src/utils").symlink_to(tmp_path / "checkouts/utils")
    monkeypatch.chdir(checkout)
    monkeypatch.setenv("PWD", str(root / "src/utils/robot_utils"))  # what the shell's cd keeps
    assert find_workspace() == Workspace(root)
    with pytest.raises(
        WorkspaceError, match=f"^{root}/src/utils/robot_utils \\(through a link, {checkout}\\) is inside"
    ):
        init_workspace(Path("."))
    assert not (checkout / "espdock.toml").exists()
    monkeypatch.setenv("PWD", str(tmp_path / "elsewhere"))  # a stale $PWD names another directory
    with pytest.raises(WorkspaceError, match="not inside an espdock workspace"):
        find_workspace()


def test_outside_a_workspace_says_where_it_looked(tmp_path):
    start = tmp_path / "x"
    start.mkdir()
    with pytest.raises(WorkspaceError) as err:
        find_workspace(start)
    assert str(start) in err.value.message
    assert "espdock.toml" in err.value.message
    assert "`espdock init`" in (err.value.hint or ""), "the command that makes a workspace, not a file to write by hand"


def test_discovers_ros_and_firmware_packages(ws):
    add_package((ws.root / "ws/src"), "msgs", interface=True)
    add_package((ws.root / "ws/src") / "nested", "nodes", depends=["msgs", "rclpy"], build_type="ament_python")
    add_package((ws.root / "firmware"), "cam", depends=["msgs", "std_msgs"], build_type="esp_idf")
    found = {p.name: p for p in discover_packages(ws)}
    assert set(found) == {"msgs", "nodes", "cam"}
    assert found["cam"].kind is PackageKind.FIRMWARE
    assert found["nodes"].kind is PackageKind.ROS
    assert found["nodes"].build_type == "ament_python"
    assert found["msgs"].is_interface and not found["nodes"].is_interface
    assert found["nodes"].depends == {"msgs", "rclpy"}


def test_ignored_and_output_directories_are_skipped(ws):
    add_package((ws.root / "ws/src"), "kept")
    skipped = add_package((ws.root / "ws/src"), "skipped")
    (skipped / "COLCON_IGNORE").touch()
    # colcon's outputs in the colcon root, reached here because the package path holds it.
    add_package(ws.root / "ws/build", "stale_copy")
    add_package(ws.root / "ws/install", "installed_copy")
    add_package(ws.root / "ws/src/fw/managed_components", "micro_ros_internal")
    assert [p.name for p in discover_packages(Workspace(ws.root, ("ws",), "ws"))] == ["kept"]


def test_a_repository_named_like_colcon_s_outputs_is_searched_as_colcon_searches_it(ws):
    # `vcs import` of a repository into src/log: colcon builds its packages (it skips only
    # what it marked COLCON_IGNORE), so leaving them out would build nothing and say nothing.
    add_package(ws.root / "ws/src/log", "log_utils")
    add_package(ws.root / "ws/src/tools/build", "build_helpers")
    add_package(ws.root / "ws/src/tools/install", "install_scripts")
    assert [p.name for p in discover_packages(ws)] == ["build_helpers", "install_scripts", "log_utils"]


def test_broken_manifest_names_the_file_and_the_error(ws):
    path = add_package((ws.root / "ws/src"), "broken")
    (path / "package.xml").write_text("<package format='3'><name>broken</name>")
    with pytest.raises(WorkspaceError) as err:
        discover_packages(ws)
    assert str(path / "package.xml") in err.value.message


def test_invalid_manifest_content_is_reported(ws):
    path = add_package((ws.root / "ws/src"), "unlicensed")
    manifest = path / "package.xml"
    manifest.write_text(manifest.read_text().replace("<license>Apache-2.0</license>", ""))
    with pytest.raises(WorkspaceError) as err:
        discover_packages(ws)
    assert str(manifest) in err.value.message
    assert "license" in err.value.message


def test_duplicate_names_are_refused(ws):
    add_package((ws.root / "ws/src"), "twin")
    add_package((ws.root / "firmware"), "twin", build_type="esp_idf")
    with pytest.raises(WorkspaceError, match="two packages are named 'twin'") as refused:
        discover_packages(ws)
    # An overlay's own copy of a package of an underlay linked in whole: what colcon users do instead.
    assert "link its other packages one by one" in (refused.value.hint or "")


def test_order_puts_dependencies_first(ws):
    add_package((ws.root / "ws/src"), "app", depends=["lib", "msgs"])
    add_package((ws.root / "ws/src"), "lib", depends=["msgs"])
    add_package((ws.root / "ws/src"), "msgs")
    add_package((ws.root / "ws/src"), "alone")
    order = [p.name for p in order_packages(discover_packages(ws))]
    assert order.index("msgs") < order.index("lib") < order.index("app")
    assert sorted(order) == ["alone", "app", "lib", "msgs"]


def test_cycles_are_reported_with_their_path(ws):
    add_package((ws.root / "ws/src"), "a", depends=["b"])
    add_package((ws.root / "ws/src"), "b", depends=["a"])
    with pytest.raises(WorkspaceError, match="cycle: a -> b -> a"):
        order_packages(discover_packages(ws))


def test_select_up_to_takes_dependencies_transitively(ws):
    add_package((ws.root / "ws/src"), "app", depends=["lib"])
    add_package((ws.root / "ws/src"), "lib", depends=["msgs"])
    add_package((ws.root / "ws/src"), "msgs")
    add_package((ws.root / "ws/src"), "other")
    packages = order_packages(discover_packages(ws))
    assert [p.name for p in select_up_to(packages, ["app"])] == ["msgs", "lib", "app"]
    assert [p.name for p in select_up_to(packages, ["msgs"])] == ["msgs"]


def test_select_unknown_package_suggests_a_name(ws):
    add_package((ws.root / "ws/src"), "camera_ui")
    with pytest.raises(WorkspaceError) as err:
        select_up_to(discover_packages(ws), ["camera_iu"])
    assert "camera_iu" in err.value.message
    assert "camera_ui" in err.value.hint


def test_a_changed_manifest_is_read_again_however_it_was_cached(ws, monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    path = add_package(ws.root / "ws/src", "nodes", depends=["rclpy"])
    (first,) = discover_packages(ws)
    assert first.depends == {"rclpy"}
    (again,) = discover_packages(ws)  # from the cache: the same answer
    assert again == first
    manifest = path / "package.xml"
    manifest.write_text(
        manifest.read_text().replace("<depend>rclpy</depend>", "<depend>rclpy</depend><depend>x</depend>")
    )
    (changed,) = discover_packages(ws)
    assert changed.depends == {"rclpy", "x"}
    # `cp -p` of another manifest of the same size: its size and modification time are the old ones.
    before = manifest.stat()
    manifest.write_text(manifest.read_text().replace("<depend>x</depend>", "<depend>y</depend>"))
    os.utime(manifest, ns=(before.st_atime_ns, before.st_mtime_ns))
    (copied,) = discover_packages(ws)
    assert copied.depends == {"rclpy", "y"}


def test_an_unreadable_cache_only_means_parsing(ws, monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    add_package(ws.root / "ws/src", "nodes")
    discover_packages(ws)
    (cached,) = (tmp_path / "cache/espdock/manifests").iterdir()
    cached.write_text("{not json")
    assert [p.name for p in discover_packages(ws)] == ["nodes"]


def cache_files(cache: Path) -> dict[str, str]:
    """The manifest cache's files under CACHE (XDG_CACHE_HOME), each with the text it holds."""
    return {f.name: f.read_text() for f in (cache / "espdock/manifests").iterdir()}


def test_the_manifest_cache_holds_what_the_workspaces_have_now(monkeypatch, tmp_path):
    cache = tmp_path / "cache"
    monkeypatch.setenv("XDG_CACHE_HOME", str(cache))
    # The one file espdock kept for every workspace before, here as it grew on a busy machine.
    (cache / "espdock").mkdir(parents=True)
    (cache / "espdock/manifests.json").write_text('{"format": 3, "entries": {}}' + " " * 3_000_000)
    spaces = {}
    for name in ("robot", "scratch", "clone"):
        (tmp_path / name).mkdir()
        (tmp_path / name / "espdock.toml").write_text("[espdock]\n")
        spaces[name] = Workspace(tmp_path / name)
        add_package(tmp_path / name / "ws/src", f"{name}_nodes")
        add_package(tmp_path / name / "ws/src", f"{name}_msgs", interface=True)
    discover_packages(spaces["robot"])
    discover_packages(spaces["scratch"])
    assert not (cache / "espdock/manifests.json").exists()
    # Each workspace reads only its own packages at a start.
    (robot_file,) = [text for text in cache_files(cache).values() if "robot_nodes" in text]
    assert "scratch" not in robot_file

    # A removed package drops out, and a workspace removed since goes with the next new one.
    shutil.rmtree(tmp_path / "robot/ws/src/robot_msgs")
    assert [p.name for p in discover_packages(spaces["robot"])] == ["robot_nodes"]
    shutil.rmtree(tmp_path / "scratch")
    discover_packages(spaces["clone"])
    texts = "".join(cache_files(cache).values())
    assert len(cache_files(cache)) == 2
    assert "robot_msgs" not in texts and "scratch" not in texts and "clone_msgs" in texts


def test_an_unchanged_workspace_parses_no_manifest(ws, monkeypatch, tmp_path):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    add_package(ws.root / "ws/src", "nodes", depends=["rclpy"])
    first = discover_packages(ws)

    def parse(manifest, ros_distro):
        raise AssertionError(f"parsed {manifest}")

    monkeypatch.setattr(espdock.workspace, "_read_manifest", parse)
    assert discover_packages(ws) == first


def test_packages_behind_links_are_found_as_colcon_finds_them_each_once(tmp_path):
    """`ln -s ~/repos/driver src/`, a link to a folder of packages, a second link to one of them
    and a loop: colcon follows links to directories, so espdock does, visiting each once."""
    ws = Workspace(tmp_path / "ws")
    (ws.ws_dir / "src").mkdir(parents=True)
    repos = tmp_path / "repos"
    add_package(repos, "driver")
    add_package(repos / "stack", "inner")
    add_package(ws.ws_dir / "src", "local")
    src = ws.ws_dir / "src"
    (src / "driver").symlink_to(repos / "driver")
    (src / "stack").symlink_to(repos / "stack")
    (src / "again").symlink_to(repos / "stack")
    (src / "loop").symlink_to(".")
    found = discover_packages(ws)
    assert [p.name for p in found] == ["driver", "inner", "local"]
    assert {p.name: p.path for p in found}["driver"] == src / "driver"  # the path in the workspace, as colcon has it


def test_an_interface_package_s_editor_leftovers_are_not_library_inputs(tmp_path):
    """An Emacs backup (BoardStatus.msg~) went into the micro-ROS library's inputs: a new key,
    a library built again (minutes with the real toolchain) for nothing."""
    from espdock.workspace import Workspace, discover_packages, read_build_inputs

    package = add_package(tmp_path / "src", "robo_interfaces", interface=True)
    (package / "msg").mkdir(exist_ok=True)
    (package / "msg/BoardStatus.msg").write_text("uint8 level\n")
    workspace = Workspace(tmp_path, ("src",), ".")
    packages = discover_packages(workspace)
    before = read_build_inputs(workspace, packages).package_files["robo_interfaces"]
    for leftover in ("msg/BoardStatus.msg~", "msg/#BoardStatus.msg#", "CMakeLists.txt.orig", "msg/x.rej"):
        (package / leftover).write_text("old\n")
    assert read_build_inputs(workspace, packages).package_files["robo_interfaces"] == before
    assert "msg/BoardStatus.msg" in before


@pytest.mark.parametrize(
    "text",
    [
        "targets:\n  - esp32\n  - esp32s3\n",
        "targets:\n- esp32\n- esp32s3\n",  # a block list at the key's indent: valid YAML
        "targets: [\n  esp32,\n  esp32s3\n]\n",  # a flow list over several lines
        "dependencies:\n  idf: '>=5.1'\ntargets: ['esp32', \"esp32s3\"]  # the chips\n",
    ],
)
def test_an_idf_component_manifest_s_targets_are_read_in_every_yaml_list_form(tmp_path, text):
    """An unindented block list or a multi-line flow list read as "any chip": a build for another
    chip went ahead, where the component manager would have refused it."""
    from espdock.workspace import component_targets

    manifest = tmp_path / "idf_component.yml"
    manifest.write_text(text)
    assert component_targets(manifest) == ("esp32", "esp32s3")


@pytest.mark.parametrize(
    "text, said",
    [
        ("targets: esp32c3\n", "`targets` is not a list of chip names"),
        ("- esp32\n- esp32c3\n", "is a list, not a mapping of fields"),
        ("targets: [esp32,\n  esp32c3\ndependencies: {}\n", "(line 3, column 13)"),
    ],
)
def test_an_idf_component_manifest_the_component_manager_refuses_is_refused_not_read_as_any_chip(tmp_path, text, said):
    """`targets: esp32c3` (a string, where the component manager wants a list) and a manifest that
    is a list read as "any chip"; invalid YAML was named without where in the file it broke."""
    from espdock.workspace import component_targets

    manifest = tmp_path / "idf_component.yml"
    manifest.write_text(text)
    with pytest.raises(WorkspaceError) as err:
        component_targets(manifest)
    assert said in err.value.message, err.value.message


def test_an_invalid_third_party_manifest_names_the_way_to_leave_it_out(ws):
    """A vendored repository's `maintainer email="dev@robot"` stopped every command, with only
    "Fix the manifest" to go on; colcon warns of such a package and leaves it out."""
    add_package(ws.root / "ws/src", "status_probe")
    vendor = add_package(ws.root / "ws/src/vendor", "imu_driver")
    manifest = vendor / "package.xml"
    manifest.write_text(re.sub(r'email="[^"]*"', 'email="dev@robot"', manifest.read_text()))
    with pytest.raises(WorkspaceError) as err:
        discover_packages(ws)
    assert "is not a valid package.xml" in err.value.message and "COLCON_IGNORE" in (err.value.hint or "")
    (ws.root / "ws/src/vendor/COLCON_IGNORE").touch()
    assert [p.name for p in discover_packages(ws)] == ["status_probe"]


def test_projects_colcon_would_build_without_a_package_xml_are_named_as_colcon_names_them(ws):
    src = ws.root / "ws/src"
    add_package(src, "kept")
    for rel, name, text in (
        ("vendor/tinylib", "CMakeLists.txt", "cmake_minimum_required(VERSION 3.16)\nproject(tiny_lib C)\n"),
        ("vendor/pylib", "setup.py", "from setuptools import setup\nsetup(\n    name='py_lib',\n)\n"),
        ("vendor/cfglib", "setup.cfg", "[metadata]\nname = cfg_lib\n"),
        ("vendor/described", "colcon.pkg", "name: described_lib\ntype: cmake\n"),
        # A repository's CMakeLists.txt beside its packages, an IDF component, an ignored project.
        ("repo", "CMakeLists.txt", "project(whole_repo)\n"),
        ("vendor/comp", "CMakeLists.txt", "idf_component_register(SRCS x.c)\n"),
        ("vendor/gone", "CMakeLists.txt", "project(gone)\n"),
    ):
        (src / rel).mkdir(parents=True, exist_ok=True)
        (src / rel / name).write_text(text)
    add_package(src / "repo", "repo_pkg")
    (src / "vendor/gone/COLCON_IGNORE").touch()
    (ws.root / "firmware/blink").mkdir(parents=True)
    (ws.root / "firmware/blink/CMakeLists.txt").write_text(
        "cmake_minimum_required(VERSION 3.16)\ninclude($ENV{IDF_PATH}/tools/cmake/project.cmake)\nproject(blink)\n"
    )
    found = espdock.workspace.unmanifested(ws)
    assert {name: (p.where, p.build_type) for name, p in found.items()} == {
        "tiny_lib": ("ws/src/vendor/tinylib", "cmake"),
        "py_lib": ("ws/src/vendor/pylib", "ament_python"),
        "cfg_lib": ("ws/src/vendor/cfglib", "ament_python"),
        "described_lib": ("ws/src/vendor/described", "cmake"),
        "blink": ("firmware/blink", "esp_idf"),
    }
    assert [p.name for p in discover_packages(ws)] == ["kept", "repo_pkg"]
    assert "no package.xml" in str(espdock.workspace.unknown_package("py_lib", ["kept"], ws))


def test_a_lock_s_holder_note_is_not_written_through_a_link_planted_at_a_name_it_would_use(tmp_path):
    """The note naming a lock's holder is written in /tmp beside the lock, which every user may
    write into: another user's link at the name the note took its pid from had root's espdock
    write through it, into the file it led to."""
    from espdock.workspace import holder_text, write_holder

    holder = tmp_path / "espdock-image-x.holder"
    victim = tmp_path / "victim"
    victim.write_text("root's file\n")
    (tmp_path / f".{holder.name}.{os.getpid()}").symlink_to(victim)
    write_holder(holder)
    assert victim.read_text() == "root's file\n"
    assert not holder.is_symlink() and holder_text(holder).startswith(f" (pid {os.getpid()}: ")
    assert oct(holder.stat().st_mode & 0o777) == oct(0o644), "another user's espdock, waiting, says who holds it"


@contextlib.contextmanager
def running(*argv: str):
    """A process running ARGV for the block (a lock's holder, or what got its pid since)."""
    process = subprocess.Popen(argv)
    try:
        # Until it has exec'd: just forked, its command line is still this process's.
        wanted = [a.encode() for a in argv]
        while Path(f"/proc/{process.pid}/cmdline").read_bytes().split(b"\0")[: len(argv)] != wanted:
            time.sleep(0.01)
        yield process
    finally:
        process.kill()
        process.wait()


def gone_pid() -> int:
    """The pid of a process that has ended (a killed espdock's)."""
    process = subprocess.Popen([sys.executable, "-c", "pass"])
    process.wait()
    return process.pid


def test_a_lock_s_holder_is_named_only_while_that_process_runs_that_command(tmp_path):
    """Another user's killed espdock left its note, which the next holder could not replace in a
    sticky /tmp: every waiter was told "busy: another espdock has it (pid N: ...)" of a dead pid."""
    from espdock.workspace import holder_text, write_holder

    holder = tmp_path / "espdock-port-x.holder"
    write_holder(holder)
    assert holder_text(holder).startswith(f" (pid {os.getpid()}: "), "this process, running what it wrote"
    holder.write_text(f"{gone_pid()}\nespdock monitor wifi --port socket://127.0.0.1:1\n")
    assert holder_text(holder) == ""
    # A live process that got the pid since, running something else.
    with running("sleep", "30") as other:
        holder.write_text(f"{other.pid}\nespdock monitor wifi --port socket://127.0.0.1:1\n")
        assert holder_text(holder) == ""
        holder.write_text(f"{other.pid}\nsleep 30\n")
        assert holder_text(holder) == f" (pid {other.pid}: sleep 30)"


def test_a_holder_that_cannot_replace_another_user_s_note_is_named_from_its_own(tmp_path, monkeypatch):
    """A killed espdock's note, another user's in a sticky /tmp: the next holder could not replace
    it, and every waiter was told no one (or the dead pid) held the port, for as long as it stayed."""
    from espdock.workspace import holder_text, remove_holder, write_holder

    holder = tmp_path / "espdock-port-x.holder"
    holder.write_text(f"{gone_pid()}\nespdock monitor wifi --port socket://127.0.0.1:1\n")
    replace = os.replace

    def refused(source, target):  # as the sticky bit refuses another user's file to this one
        if Path(target) == holder:
            raise PermissionError(1, "Operation not permitted")
        replace(source, target)

    monkeypatch.setattr(os, "replace", refused)
    write_holder(holder)
    assert holder_text(holder).startswith(f" (pid {os.getpid()}: "), "named from this user's own note"
    remove_holder(holder)
    assert holder_text(holder) == "" and [p.name for p in tmp_path.iterdir()] == [holder.name]


def test_a_holder_hidden_by_proc_s_hidepid_is_named_at_its_word(tmp_path, monkeypatch):
    """/proc mounted hidepid=2 hides another user's processes: their command lines read as missing,
    and a live holder went unnamed as if gone."""
    from espdock.workspace import holder_text

    read_bytes = Path.read_bytes

    def hidden(path):
        if str(path).startswith("/proc/"):
            raise FileNotFoundError(2, "No such file or directory", str(path))
        return read_bytes(path)

    with running("sleep", "30") as other:
        holder = tmp_path / "espdock-port-x.holder"
        holder.write_text(f"{other.pid}\nespdock monitor wifi --port socket://127.0.0.1:1 \n")
        monkeypatch.setattr(Path, "read_bytes", hidden)
        assert holder_text(holder) == f" (pid {other.pid}: espdock monitor wifi --port socket://127.0.0.1:1)"


def test_a_holder_whose_last_argument_ends_in_a_space_is_named(tmp_path):
    """`espdock build -- --cmake-args "-DFOO=a b "`: the note's line lost its last space, and the
    command line no longer matched it."""
    from espdock.workspace import holder_text

    with running(sys.executable, "-c", "import time; time.sleep(30)", "-DFOO=a b ") as ending:
        holder = tmp_path / "espdock-build-x.holder"
        holder.write_text(f"{ending.pid}\nespdock -DFOO=a b \n")
        assert holder_text(holder) == f" (pid {ending.pid}: espdock -DFOO=a b)"


def test_an_interface_package_read_while_an_editor_saves_is_read_without_its_save_files(tmp_path, monkeypatch):
    """Every build reads each interface package's files (the micro-ROS image's inputs): vim's 4913,
    made and removed while saving, ended the build as "a bug in espdock" (FileNotFoundError)."""
    from pathlib import Path

    from espdock.workspace import read_tree

    (tmp_path / "msg").mkdir()
    for name in ("Pose.msg", "4913", ".Pose.msg.swp", "Pose.msg~", "Gone.msg"):
        (tmp_path / "msg" / name).write_text("int32 x\n")
    reading = Path.read_bytes

    def vanishing(path: Path) -> bytes:
        if path.name in ("4913", "Gone.msg"):
            path.unlink()  # removed between the listing and the reading
        return reading(path)

    monkeypatch.setattr(Path, "read_bytes", vanishing)
    assert read_tree(tmp_path) == {"msg/Pose.msg": b"int32 x\n"}
