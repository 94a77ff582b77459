"""`espdock run`'s and `init`'s pure parts: finding executables, the node's environment, what a
runtime image is keyed by and made of, the starter compose file."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest
import yaml

from espdock.build.stamps import StampFile, listing_digest
from espdock.config import Config
from espdock.errors import ConfigError, WorkspaceError
from espdock.images.specs import Mount
from espdock.ros.compose import compose_subcommand, init_compose, plain_compose_note, starter_compose
from espdock.ros.nodes import (
    device,
    find_executable,
    node_env,
    node_spec,
    shell_spec,
    variable,
    volume,
)
from espdock.ros.plan import RuntimeImage, ros_build_image, runtime_base_image, runtime_image_spec
from espdock.ros.runtime_tree import runtime_context, runtime_install_digest
from espdock.ros.staleness import ROS_STAMPS
from espdock.workspace import Package, PackageKind, Workspace


def installed(root: Path, package: str, *executables: str) -> None:
    lib = root / "install" / package / "lib" / package
    lib.mkdir(parents=True)
    for name in executables:
        (lib / name).write_text("#!/bin/sh\n")
        (lib / name).chmod(0o755)
    (lib / "not_executable.txt").write_text("data")


@pytest.fixture
def ws(tmp_path) -> tuple[Workspace, tuple[Package, ...]]:
    workspace = Workspace(tmp_path, ("src",), ".")
    packages = tuple(
        Package(name, tmp_path / "src" / name, kind, "ament_python", frozenset())
        for name, kind in (("talk", PackageKind.ROS), ("quiet", PackageKind.ROS), ("board", PackageKind.FIRMWARE))
    )
    installed(tmp_path, "talk", "talker", "listener")
    record_build(workspace, "talk")
    return workspace, packages


def record_build(workspace: Workspace, package: str) -> None:
    """What `espdock build` records after colcon built PACKAGE: its install tree's listing."""
    listing = listing_digest(workspace.ws_dir / "install" / package)
    StampFile(workspace.ws_dir / "build" / ROS_STAMPS).record({package: "stamp"}, {package: listing})


def test_an_executable_is_found_where_the_runtime_image_holds_it(ws):
    workspace, packages = ws
    assert find_executable(workspace, packages, "talk", "talker") == "/opt/espdock/ws/install/talk/lib/talk/talker"


def test_another_package_s_install_this_user_may_not_read_is_no_crash(ws, monkeypatch):
    """`espdock run talk talker` beside another user's install/quiet (mode 0700): "espdock failed
    unexpectedly (PermissionError ...)", where that package has nothing this user can run."""
    workspace, packages = ws
    installed(workspace.root, "quiet", "hidden")
    unreadable = workspace.root / "install/quiet/lib/quiet"
    listed = Path.iterdir

    def iterdir(path: Path):
        if path == unreadable:  # root reads every directory: as another user would find it
            raise PermissionError(13, "Permission denied", str(path))
        return listed(path)

    monkeypatch.setattr(Path, "iterdir", iterdir)
    assert find_executable(workspace, packages, "talk", "talker").endswith("/talk/lib/talk/talker")


def test_an_install_tree_a_native_colcon_build_rewrote_is_refused_with_what_to_do(ws):
    workspace, packages = ws
    talker = workspace.root / "install" / "talk" / "lib" / "talk" / "talker"
    talker.write_text("#!/home/alice/venv/bin/python3\n")  # a native build: the host's Python
    with pytest.raises(WorkspaceError) as caught:
        find_executable(workspace, packages, "talk", "talker")
    assert caught.value.exit_code == 2 and "install/talk was not built by espdock" in caught.value.message
    assert "espdock build talk" in caught.value.hint
    record_build(workspace, "talk")  # espdock build rebuilt it
    assert find_executable(workspace, packages, "talk", "talker").endswith("/talk/lib/talk/talker")


def test_a_dependency_s_install_tree_a_native_colcon_build_rewrote_is_refused_with_what_to_do(tmp_path):
    """`colcon build --packages-select utils` natively, then `espdock run nodes talker`: the runtime
    image was made of the host's build of utils without a word, and the node died importing it."""
    workspace = Workspace(tmp_path, ("src",), ".")
    packages = tuple(
        Package(name, tmp_path / "src" / name, PackageKind.ROS, "ament_python", frozenset(depends))
        for name, depends in (("utils", ()), ("nodes", ("utils", "rclpy")), ("other", ()))
    )
    for name in ("utils", "nodes", "other"):
        installed(tmp_path, name, "talker" if name == "nodes" else "stats")
        record_build(workspace, name)
    assert find_executable(workspace, packages, "nodes", "talker").endswith("/nodes/lib/nodes/talker")
    for name in ("utils", "other"):  # what the node depends on, and what it does not
        (tmp_path / "install" / name / "lib" / name / "stats").write_text("#!/home/alice/venv/bin/python3\n")
    with pytest.raises(WorkspaceError) as caught:
        find_executable(workspace, packages, "nodes", "talker")
    assert caught.value.exit_code == 2, caught.value.message
    assert caught.value.message.startswith("install/utils, which nodes depends on, was not built by espdock")
    assert "espdock build utils" in caught.value.hint
    record_build(workspace, "utils")  # espdock build rebuilt it; `other` is no business of this node
    assert find_executable(workspace, packages, "nodes", "talker").endswith("/nodes/lib/nodes/talker")


def test_run_during_a_build_or_after_one_that_did_not_finish_says_so_not_native_colcon(ws):
    """Both were refused as "not built by espdock (a native colcon build?)"."""
    import fcntl

    from espdock.workspace import workspace_lock

    workspace, packages = ws
    StampFile(workspace.ws_dir / "build" / ROS_STAMPS).forget(["talk"])  # as a build does before colcon
    (workspace.ws_dir / "build/espdock-ros/talk").mkdir(parents=True)
    with pytest.raises(WorkspaceError) as caught:
        find_executable(workspace, packages, "talk", "talker")
    assert "the last espdock build of talk did not finish" in caught.value.message
    with workspace_lock(workspace), pytest.raises(WorkspaceError) as caught:
        find_executable(workspace, packages, "talk", "talker")
    assert caught.value.message.startswith(f"an espdock build is running in {workspace.root} (pid ")
    # The lock is free again once the build is over.
    fd = os.open(workspace.root, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    finally:
        os.close(fd)


def test_run_after_an_interrupted_first_build_says_it_did_not_finish_not_no_executable(ws):
    """A first build of an ament_python package interrupted after colcon made install/quiet but
    before setup.py installed its scripts in lib/: "has no executable 'node'" sent the user to
    check the entry points in a setup.py that was fine."""
    workspace, packages = ws
    (workspace.ws_dir / "install/quiet/share/quiet").mkdir(parents=True)
    (workspace.ws_dir / "build/espdock-ros/quiet").mkdir(parents=True)
    with pytest.raises(WorkspaceError) as caught:
        find_executable(workspace, packages, "quiet", "node")
    assert caught.value.message.startswith("the last espdock build of quiet did not finish"), caught.value.message
    assert "espdock build quiet" in caught.value.hint


@pytest.mark.parametrize(
    ("package", "executable", "said"),
    [
        ("talks", "talker", "no ROS package 'talks'"),
        ("quiet", "x", "'quiet' is not built yet"),
        ("talk", "not_executable.txt", "no executable 'not_executable.txt'"),
    ],
)
def test_unknown_names_are_user_errors_that_list_what_exists(ws, package, executable, said):
    workspace, packages = ws
    with pytest.raises(WorkspaceError) as caught:
        find_executable(workspace, packages, package, executable)
    assert caught.value.exit_code == 2 and said in caught.value.message
    if "not built" not in said:
        assert "talk: listener, talker" in caught.value.hint


def test_a_misspelt_name_in_a_large_workspace_is_suggested_in_a_short_hint(ws):
    """`espdock run acme_cor ...` in a workspace of 58 executables: no suggestion, where `build`
    and `test` give one, and a hint of 2,000 characters listing every executable."""
    workspace, packages = ws
    names = [f"acme_driver_{i}" for i in range(12)]
    for name in names:
        installed(workspace.root, name, f"{name}_node", f"{name}_diagnostics")
    packages += tuple(
        Package(n, workspace.root / "src" / n, PackageKind.ROS, "ament_python", frozenset()) for n in names
    )
    with pytest.raises(WorkspaceError) as caught:
        find_executable(workspace, packages, "acme_drver_3", "x")
    assert (
        caught.value.hint
        == "Did you mean 'acme_driver_3'? acme_driver_3: acme_driver_3_diagnostics, acme_driver_3_node."
    )
    with pytest.raises(WorkspaceError) as caught:
        find_executable(workspace, packages, "talk", "talkr")
    assert caught.value.hint == "Did you mean 'talker'? talk: listener, talker."
    with pytest.raises(WorkspaceError) as caught:
        find_executable(workspace, packages, "nothing_like_it", "x")
    assert "13 packages: acme_driver_0, acme_driver_1," in caught.value.hint and "_node" not in caught.value.hint


def test_a_misspelt_name_is_offered_only_a_package_it_could_run(ws):
    """A package renamed since: `espdock run walk_py talker` offered walk_msgs, an interface package
    ("walk_msgs: no executable"), where the one it could run was listed nowhere."""
    workspace, packages = ws
    installed(workspace.root, "walk_msgs")  # built, nothing to run
    packages += (Package("walk_msgs", workspace.root / "src/walk_msgs", PackageKind.ROS, "ament_cmake", frozenset()),)
    with pytest.raises(WorkspaceError) as caught:
        find_executable(workspace, packages, "walk_py", "talker")
    assert "Did you mean" not in caught.value.hint and "talk: listener, talker" in caught.value.hint
    # One not built yet may be the one: said so, not "no executable".
    with pytest.raises(WorkspaceError) as caught:
        find_executable(workspace, packages, "quiett", "x")
    assert caught.value.hint == "Did you mean 'quiet'? quiet: not built yet (`espdock build quiet`)."


def test_run_of_a_package_espdock_leaves_out_says_what_leaves_it_out(ws):
    """Both were "no ROS package 'NAME' in this workspace", as for a misspelt name."""
    workspace, packages = ws
    vendored = workspace.root / "src/vendored"
    vendored.mkdir(parents=True)
    (vendored / "CMakeLists.txt").write_text("cmake_minimum_required(VERSION 3.8)\nproject(vendored)\n")
    ignored = workspace.root / "src/old_driver"
    ignored.mkdir()
    (ignored / "package.xml").write_text("<package format='3'><name>old_driver</name></package>")
    (ignored / "COLCON_IGNORE").touch()
    for name, said in (
        ("vendored", "src/vendored, a CMake project with no package.xml, which espdock does not build"),
        ("old_driver", "a workspace package, which src/old_driver/COLCON_IGNORE leaves out"),
        # Renamed or removed on a branch, its install left: "Did you mean" another by its letters.
        (
            "talk_old",
            "install/talk_old is an earlier build's, of a package no longer in the sources (renamed or removed)",
        ),
    ):
        (workspace.ws_dir / "install/talk_old/lib/talk_old").mkdir(parents=True, exist_ok=True)
        marker = workspace.ws_dir / "install/talk_old/share/colcon-core/packages/talk_old"  # colcon's, per prefix
        marker.parent.mkdir(parents=True, exist_ok=True)
        marker.write_text("")
        with pytest.raises(WorkspaceError) as caught:
            find_executable(workspace, packages, name, "x")
        assert caught.value.message == f"no ROS package '{name}' in this workspace: {said}"


def test_a_launch_file_given_to_run_says_how_to_launch_it(ws):
    """`espdock run talk talk.launch.py` said only "no executable", listing executables."""
    workspace, packages = ws
    with pytest.raises(WorkspaceError) as caught:
        find_executable(workspace, packages, "talk", "talk.launch.py")
    assert "'talk.launch.py' is a launch file" in caught.value.message and "listener, talker" in caught.value.message
    assert "`ros2 launch talk talk.launch.py` in `espdock shell`" in caught.value.hint
    with pytest.raises(WorkspaceError) as caught:  # named by its path in the package: ros2 launch takes its name
        find_executable(workspace, packages, "talk", "launch/talk.launch.py")
    assert "`ros2 launch talk talk.launch.py` in `espdock shell`" in caught.value.hint


def test_a_firmware_package_is_not_run_but_its_commands_are_named(ws):
    workspace, packages = ws
    with pytest.raises(WorkspaceError) as caught:
        find_executable(workspace, packages, "board", "flash")
    assert caught.value.exit_code == 2 and "'board' is a firmware package" in caught.value.message
    assert "espdock flash board --port PORT" in caught.value.hint


def test_the_node_gets_the_ros_settings_and_udp_only_dds_unless_told_otherwise():
    env = dict(node_env({"ROS_DOMAIN_ID": "7", "HOME": "/root", "PATH": "/bin"}))
    assert env == {"ROS_DOMAIN_ID": "7", "FASTDDS_BUILTIN_TRANSPORTS": "UDPv4"}
    assert dict(node_env({"FASTDDS_BUILTIN_TRANSPORTS": "SHM"}))["FASTDDS_BUILTIN_TRANSPORTS"] == "SHM"


def test_the_runtime_image_key_follows_the_ros_install_trees_only(tmp_path):
    install = tmp_path / "install"
    installed(tmp_path, "talk", "talker")
    (install / "board" / "share" / "board" / "firmware").mkdir(parents=True)
    (install / "local_setup.sh").write_text("# colcon\n")
    (install / "espdock-manifest.json").write_text("{}")
    spec = ros_build_image(Config(), "FROM x AS build\nFROM x AS runtime\n", {})
    step = RuntimeImage(runtime_base_image(spec), "espdock/w", ("talk",))
    digest = runtime_install_digest(install, ("talk",))
    assert set(runtime_context(install, step)) == {
        "install/local_setup.sh", "install/talk/lib/talk/talker", "install/talk/lib/talk/not_executable.txt",
    }  # fmt: skip
    (install / "espdock-manifest.json").write_text('{"changed": 1}')
    (install / "board" / "share" / "board" / "firmware" / "app.bin").write_bytes(b"\0")
    assert runtime_install_digest(install, ("talk",)) == digest
    (install / "talk" / "lib" / "talk" / "talker").chmod(0o644)
    assert runtime_install_digest(install, ("talk",)) != digest
    one, two = runtime_image_spec(step, "a"), runtime_image_spec(step, "b")
    assert one.tag.startswith("espdock/w:") and one.key != two.key
    assert dict(one.context)["Dockerfile"].decode().startswith(f"FROM {step.base.tag} ")


def test_the_starter_compose_file_has_a_service_per_node_and_the_agent_under_hardware():
    text = starter_compose("robot", "espdock/robot:latest", {"talk": ["talker", "listener"], "other": ["talker"]})
    data = yaml.safe_load(text)
    services = data["services"]
    assert set(services) == {"listener", "talk-talker", "other-talker", "micro_ros_agent", "micro_ros_agent_serial"}
    assert services["listener"]["command"] == ["/opt/espdock/ws/install/talk/lib/talk/listener"]
    assert services["listener"]["image"] == "espdock/robot:latest"
    assert services["listener"]["environment"]["FASTDDS_BUILTIN_TRANSPORTS"] == "UDPv4"
    assert services["micro_ros_agent"]["profiles"] == ["hardware"]
    assert services["micro_ros_agent"]["image"] == "microros/micro-ros-agent:jazzy"
    # One-shot clients and tools would start again forever under a restart policy.
    assert services["listener"]["restart"] == "no"


def test_a_refresh_rewrites_espdocks_own_compose_file_but_not_an_edited_one(ws):
    workspace, packages = ws
    repository = "espdock/robot"
    assert init_compose(workspace, repository, packages) == "wrote"
    assert init_compose(workspace, repository, packages) is None  # plain init never overwrites
    installed(workspace.root, "quiet", "once")
    assert init_compose(workspace, repository, packages, refresh=True) == "refreshed"
    compose = workspace.root / "compose.yaml"
    assert set(yaml.safe_load(compose.read_text())["services"]) == {
        "talker",
        "listener",
        "once",
        "micro_ros_agent",
        "micro_ros_agent_serial",
    }
    assert init_compose(workspace, repository, packages, refresh=True) == "unchanged"
    edited = compose.read_text().replace("UDPv4", "SHM")
    compose.write_text(edited)
    (workspace.root / "install/quiet/lib/quiet/twice").write_text("#!/bin/sh\n")
    (workspace.root / "install/quiet/lib/quiet/twice").chmod(0o755)
    with pytest.raises(WorkspaceError) as caught:
        init_compose(workspace, repository, packages, refresh=True)
    assert caught.value.exit_code == 2 and "--force" in caught.value.hint
    assert compose.read_text() == edited
    assert init_compose(workspace, repository, packages, refresh=True, force=True) == "replaced"
    assert (workspace.root / "compose.yaml.orig").read_text() == edited
    assert "twice" in yaml.safe_load(compose.read_text())["services"]


def test_volumes_and_devices_are_checked_and_reach_the_nodes_container(ws, tmp_path):
    workspace, _ = ws
    params = tmp_path / "joy.yaml"
    params.write_text("joy: {}\n")
    mount = volume("joy.yaml:/params/joy.yaml:ro", tmp_path)
    assert (mount.source, mount.target, mount.read_only) == (params, "/params/joy.yaml", True)
    assert not volume(f"{tmp_path}:/data", Path("/")).read_only
    for bad, said in (
        ("missing.yaml:/p.yaml", "does not exist"),
        ("joy.yaml:params.yaml", "must be absolute"),
        ("joy.yaml", "expected HOST:CONTAINER"),
        ("joy.yaml:/p:rw:x", "expected HOST:CONTAINER"),
        ("joy.yaml:/p:ro;rm", "expected HOST:CONTAINER"),
    ):
        with pytest.raises(ConfigError) as caught:
            volume(bad, tmp_path)
        assert caught.value.exit_code == 2 and said in caught.value.message, bad
    assert device("/dev/null:/dev/ttyUSB0") == ("/dev/null", "/dev/ttyUSB0")
    assert device("/dev/null") == ("/dev/null", "/dev/null")
    for bad, said in (("/dev/ttyNOPE9", "does not exist"), (str(params), "is not a device"), ("ttyUSB0", "absolute")):
        with pytest.raises(ConfigError) as caught:
            device(bad)
        assert caught.value.exit_code == 2 and said in caught.value.message, bad
    spec = node_spec(workspace, "img", "/n", (), (1000, 1000), {}, "host", False, (mount,), (("/dev/null", "/dev/x"),))
    assert spec.mounts == (mount,) and spec.devices == ("/dev/null:/dev/x",)
    assert spec.group_add == (Path("/dev/null").stat().st_gid,)


def test_the_shell_sources_the_install_tree_itself_on_the_official_image(ws):
    workspace, _ = ws
    wheels = shell_spec(workspace, "img", (1, 1), {}, False, "Dockerfile.ros")
    assert wheels.argv == ("bash",) and ("ESPDOCK_WS_INSTALL", "/workspace/install") in wheels.env
    official = shell_spec(workspace, "img", (1, 1), {}, False, "Dockerfile.ros-official")
    assert official.argv[:2] == ("bash", "-c") and official.argv[-1] == "/workspace/install"
    assert "local_setup.bash" in official.argv[2] and "/workspace" not in official.argv[2]


def test_the_shell_gets_the_directories_linked_packages_lead_to_as_a_build_does(ws, tmp_path):
    workspace, packages = ws
    outside = tmp_path.parent / f"{tmp_path.name}-driver"
    outside.mkdir()
    (tmp_path / "src").mkdir(exist_ok=True)
    (tmp_path / "src/driver").symlink_to(outside)
    linked = (*packages, Package("driver", tmp_path / "src/driver", PackageKind.ROS, "ament_python", frozenset()))
    spec = shell_spec(workspace, "img", (1, 1), {}, False, "Dockerfile.ros", None, linked)
    assert [(str(m.source), m.target) for m in spec.mounts] == [
        (str(tmp_path), "/workspace"),
        (str(outside), str(outside)),
    ]
    in_volume = Mount("espdock-ws-x", "/workspace", volume=True)
    assert shell_spec(workspace, "img", (1, 1), {}, False, "Dockerfile.ros", in_volume, linked).mounts == (in_volume,)


@pytest.mark.parametrize(
    ("args", "subcommand"),
    [
        (["up"], "up"),
        (["-p", "x", "--profile", "sim", "up", "-d"], "up"),
        (["--file=c.yaml", "-f", "d.yaml", "run", "--rm", "probe"], "run"),
        (["--profile", "*", "down"], "down"),
        (["--dry-run", "create"], "create"),
        (["--help"], None),
    ],
)
def test_the_compose_subcommand_is_found_after_composes_own_options(args, subcommand):
    assert compose_subcommand(args) == subcommand


def test_the_shell_opens_where_it_was_started_in_the_colcon_root_with_a_home_on_the_workspace(ws):
    workspace, _ = ws
    inside = workspace.ws_dir / "src"
    spec = shell_spec(workspace, "img", (1000, 1000), {}, False, "Dockerfile.ros", cwd=inside, user_name="ann")
    assert spec.workdir == "/workspace/src"
    env = dict(spec.env)
    assert env["HOME"] == "/workspace/build/espdock-home" and env["USER"] == env["LOGNAME"] == "ann"
    # Outside the colcon root: the colcon root, where `source install/setup.bash` works.
    assert shell_spec(workspace, "img", (1, 1), {}, False, cwd=workspace.root.parent).workdir == "/workspace"
    # In a package of a src/ that links elsewhere, as the shell reached it: there too, where the
    # resolved path (outside the workspace) opened the shell at the workspace's root.
    store = workspace.root.parent / "store"
    (store / "pkg").mkdir(parents=True)
    linked = workspace.ws_dir / "linked"
    linked.symlink_to(store)
    started = shell_spec(workspace, "img", (1, 1), {}, False, cwd=linked / "pkg")
    assert started.workdir == "/workspace/linked/pkg", started.workdir
    # In the workspace volume the home would not come back: /tmp, as before.
    in_volume = Mount("espdock-ws-x", "/workspace", volume=True)
    assert dict(shell_spec(workspace, "img", (1, 1), {}, False, "", in_volume).env)["HOME"] == "/tmp"


def test_a_compose_file_that_runs_another_workspace_s_runtime_image_is_found():
    import yaml

    from espdock.ros.compose import foreign_runtime_images, starter_compose

    def found(text: str, own: str) -> tuple[list[str], str | None]:
        return foreign_runtime_images(yaml.safe_load(text), own)

    original = starter_compose("robot", "espdock/robot:latest", {"talk": ["talker"]})
    # A copy or clone of the workspace under another name still runs the original's nodes.
    assert found(original, "espdock/robot-copy") == (["espdock/robot:latest"], "robot")
    assert found(original, "espdock/robot") == ([], None)
    # Whatever its project name (this repository's is espdock-demo, its image espdock/demo): a
    # copy keeps it, and replaces the original's containers. It went unsaid where they differed.
    other_project = original.replace("name: robot", "name: sim")
    assert found(other_project, "espdock/robot-copy") == (["espdock/robot:latest"], "sim")
    demo = (Path(__file__).parents[2] / "compose.yaml").read_text()
    assert found(demo, "espdock/demo52x") == (["espdock/demo:latest"], "espdock-demo")
    # Not a workspace's runtime image: keyed images, an interpolated one, anyone else's.
    for image in ("espdock/ros-jazzy-runtime:0123abcd", "espdock/${NAME}:latest", "microros/micro-ros-agent:jazzy"):
        assert found(f"services:\n  a:\n    image: {image}\n", "espdock/robot") == ([], None)


def test_a_foreign_image_in_a_compose_file_named_as_this_workspace_s_project_is_said_without_that_claim(tmp_path):
    """A service of espdock/other:latest in ws1's own file (`name: ws1`): the warning said ws1's
    project name was the other workspace's, whose containers would be replaced."""
    from espdock.ros.compose import check_compose_file, starter_compose

    (tmp_path / "compose.yaml").write_text(starter_compose("ws1", "espdock/other:latest", {"talk": ["talker"]}))
    said = "\n".join(check_compose_file(tmp_path, "espdock/ws1", [], {}))
    assert "runs espdock/other:latest, another workspace's runtime image" in said, said
    assert "name: ws1" not in said and "`up` replaces them" not in said, said
    # Another file chosen: not this one's to judge.
    assert check_compose_file(tmp_path, "espdock/ws1", [], {"COMPOSE_FILE": "other.yaml"}) == []
    # The other's project name in the file, but the project named elsewhere: nothing of it gets replaced.
    (tmp_path / "compose.yaml").write_text(starter_compose("other", "espdock/other:latest", {"talk": ["talker"]}))
    assert "`up` replaces them" in "\n".join(check_compose_file(tmp_path, "espdock/ws1", [], {}))
    for args, env in ((["-p", "mine"], {}), ([], {"COMPOSE_PROJECT_NAME": "mine"})):
        said = "\n".join(check_compose_file(tmp_path, "espdock/ws1", args, env))
        assert "runs espdock/other:latest" in said and "`up` replaces them" not in said, said


def test_a_build_in_a_worktree_of_the_committed_compose_file_says_what_plain_compose_runs(tmp_path):
    """`runtime_image = true` in a worktree made espdock/robot-feat:latest, and plain `docker compose
    up` there ran the original's image (the file's fallback name), replacing its containers."""
    robot = tmp_path / "robot"
    robot.mkdir()
    assert init_compose(Workspace(robot).with_layout(None, None), "espdock/robot", ()) == "wrote"
    assert plain_compose_note(robot, "espdock/robot", {}) is None
    feat = tmp_path / "robot-feat"
    feat.mkdir()
    (feat / "compose.yaml").write_text((robot / "compose.yaml").read_text())
    said = plain_compose_note(feat, "espdock/robot-feat", {})
    assert said is not None and "plain `docker compose` here runs espdock/robot:latest" in said, said
    assert "`echo ESPDOCK_NAME=robot-feat >> .env`" in said, said
    assert plain_compose_note(feat, "espdock/robot-feat", {"ESPDOCK_NAME": "robot-feat"}) is None
    (feat / ".env").write_text("ESPDOCK_NAME=robot-feat\n")
    assert plain_compose_note(feat, "espdock/robot-feat", {}) is None


def test_a_fast_dds_profiles_file_reaches_the_node_mounted_or_is_refused(ws, tmp_path, monkeypatch):
    """FASTRTPS_DEFAULT_PROFILES_FILE was passed on as the host's path, which the container
    lacks: Fast DDS warned (`XMLPARSER Error ... realpath failed`) and ran on its defaults."""
    from espdock.errors import ConfigError

    workspace, _ = ws
    profiles = tmp_path / "fastdds.xml"
    profiles.write_text("<profiles/>\n")
    monkeypatch.chdir(tmp_path)
    spec = node_spec(
        workspace, "img", "/n", (), (1, 1), {"FASTRTPS_DEFAULT_PROFILES_FILE": "fastdds.xml"}, "host", False
    )
    inside = "/opt/espdock/dds/FASTRTPS_DEFAULT_PROFILES_FILE.xml"
    assert dict(spec.env)["FASTRTPS_DEFAULT_PROFILES_FILE"] == inside
    assert [(m.source, m.target, m.read_only) for m in spec.mounts] == [(profiles, inside, True)]
    with pytest.raises(ConfigError) as caught:
        node_spec(workspace, "img", "/n", (), (1, 1), {"FASTDDS_DEFAULT_PROFILES_FILE": "nope.xml"}, "host", False)
    assert caught.value.message.startswith("FASTDDS_DEFAULT_PROFILES_FILE=nope.xml: no such file")
    # In the workspace volume (an engine elsewhere) there is nothing to mount it from: left out.
    in_volume = Mount("espdock-ws-x", "/workspace", volume=True)
    shell = shell_spec(
        workspace, "img", (1, 1), {"FASTRTPS_DEFAULT_PROFILES_FILE": "fastdds.xml"}, False, "", in_volume
    )
    assert "FASTRTPS_DEFAULT_PROFILES_FILE" not in dict(shell.env) and shell.mounts == (in_volume,)


def test_workspaces_named_with_no_ascii_letter_get_runtime_images_of_their_own(tmp_path):
    """Two workspaces called ロボット and _-.. both made espdock/workspace:latest, each build
    replacing the other's."""
    from espdock.config import Config
    from espdock.ros.plan import runtime_repository

    names = {runtime_repository(Config(), Workspace(tmp_path / name)) for name in ("ロボット", "_-..", "ロボ")}
    assert len(names) == 3 and all(n.startswith("espdock/workspace-") for n in names), names
    assert runtime_repository(Config(), Workspace(tmp_path / "My Robot")) == "espdock/my-robot"
    # Moved, or cloned elsewhere, as an ASCII-named one: the compose file init wrote named another.
    moved = runtime_repository(Config(), Workspace(tmp_path / "moved/ロボット"))
    assert moved == runtime_repository(Config(), Workspace(tmp_path / "ロボット")), moved


def test_a_workspace_directory_of_a_long_name_gives_an_image_name_docker_takes(tmp_path):
    """A directory name of 248 characters made espdock/<it>: `build` compiled everything, then
    failed on the engine's HTTP 400 (a repository's name over 255 characters); a name setting
    that long was taken, and failed the same way."""
    from espdock.config import Config, load_config
    from espdock.errors import ConfigError
    from espdock.ros.plan import runtime_repository

    names = {runtime_repository(Config(), Workspace(tmp_path / (stem * 250))) for stem in ("a", "b")}
    assert len(names) == 2 and all(len(name) <= 255 - len(":latest") for name in names), names
    assert all(name.startswith("espdock/" + "a" * 40) or name.startswith("espdock/" + "b" * 40) for name in names)
    assert runtime_repository(Config(), Workspace(tmp_path / ("r" * 100))) == "espdock/" + "r" * 100
    (tmp_path / "espdock.toml").write_text(f'[espdock]\nname = "{"n" * 248}"\n')
    with pytest.raises(ConfigError) as refused:
        load_config(tmp_path, {})
    assert "at most 247 characters" in refused.value.message + (refused.value.hint or "")


def test_a_workspace_directory_of_any_name_gives_an_image_name_docker_takes(tmp_path):
    """`robot_ (copy)` (a file manager's copy) made espdock/robot_-copy, and `projekt_übung`
    espdock/projekt_-bung: `espdock run` and `compose up` failed on "invalid reference format";
    the name setting took `robot_-x` and `robot..x` the same."""
    from espdock.config import Config, load_config
    from espdock.errors import ConfigError
    from espdock.ros.plan import runtime_repository

    component = re.compile(r"[a-z0-9]+(?:(?:[._]|__|-+)[a-z0-9]+)*")  # Docker's reference grammar
    for name, expected in (("robot_ (copy)", "robot-copy"), ("projekt_übung", "projekt-bung"), ("ws__2", "ws__2"),
                           ("a-._b", "a-b"), ("robot.v2", "robot.v2"), ("ros2_ws", "ros2_ws")):  # fmt: skip
        repository = runtime_repository(Config(), Workspace(tmp_path / name))
        assert repository == f"espdock/{expected}" and component.fullmatch(expected), (name, repository)
    for bad in ("robot_-x", "robot..x", "robot-"):
        (tmp_path / "espdock.toml").write_text(f'[espdock]\nname = "{bad}"\n')
        with pytest.raises(ConfigError):
            load_config(tmp_path, {})


def test_env_gives_the_node_a_variable_or_passes_one_and_refuses_the_images_own(ws):
    workspace, _ = ws
    assert variable("ROBOT_SITE=lab=2", {}) == ("ROBOT_SITE", "lab=2")
    assert variable("ROBOT_SITE", {"ROBOT_SITE": "here"}) == ("ROBOT_SITE", "here")
    assert variable("ROBOT_SITE", {}) is None  # as `docker run -e NAME` leaves out an unset one
    for bad in ("=x", "1A=x", "A B=x", "ROS_DISTRO=humble", "PATH=/x"):
        with pytest.raises(ConfigError, match="--env"):
            variable(bad, {})
    spec = node_spec(
        workspace, "img", "/n", (), (1, 1), {"ROS_DOMAIN_ID": "7"}, "host", False, variables=(("ROS_DOMAIN_ID", "9"),)
    )
    assert [value for name, value in spec.env if name == "ROS_DOMAIN_ID"] == ["9"]


def test_run_tells_what_it_runs_of_a_package_edited_since_its_build(tmp_path):
    """After `git checkout`, run ran the last build's install without a word; under a symlink
    install an ament_python package's edited modules are what runs, and a warning would be false."""
    from espdock.build.stamps import tree_state
    from espdock.ros.staleness import ROS_STAMP_FORMAT, edited_since_built
    from espdock.ros.trees import record_build_args

    workspace = Workspace(tmp_path, ("src",), ".")
    py = Package("talk", tmp_path / "src/talk", PackageKind.ROS, "ament_python", frozenset())
    cpp = Package("drive", tmp_path / "src/drive", PackageKind.ROS, "ament_cmake", frozenset())
    bringup = Package("bringup", tmp_path / "src/bringup", PackageKind.ROS, "ament_cmake", frozenset())
    for package in (py, cpp, bringup):
        package.path.mkdir(parents=True)
        (package.path / "node.py").write_text("print(1)\n")
    (py.path / "setup.py").write_text("setup()\n")
    (cpp.path / "CMakeLists.txt").write_text("project(drive)\nadd_executable(drive src/drive.cpp)\n")
    (bringup.path / "CMakeLists.txt").write_text("project(bringup)\ninstall(DIRECTORY config DESTINATION share)\n")
    stamps = StampFile(tmp_path / "build" / ROS_STAMPS, ROS_STAMP_FORMAT)
    built = (py, cpp, bringup)
    stamps.record({"talk": "s1", "drive": "s2", "bringup": "s3"}, {}, None, {p.name: tree_state(p.path) for p in built})
    assert edited_since_built(workspace, py) is None and edited_since_built(workspace, cpp) is None
    for package in built:
        (package.path / "node.py").write_text("print(2)\n")
    assert edited_since_built(workspace, py) == "what that build installed"
    (tmp_path / "build/espdock-ros").mkdir(parents=True)
    record_build_args(tmp_path / "build/espdock-ros", ("--symlink-install",))
    assert edited_since_built(workspace, py) is None, "the symlinked modules are the sources as they are"
    assert "compiled or generated" in (edited_since_built(workspace, cpp) or "")
    # A package that only installs its files (params, launch files): each is a link to its source.
    assert edited_since_built(workspace, bringup) is None
    (bringup.path / "new.yaml").write_text("{}\n")  # a new file gets its link from a build
    assert edited_since_built(workspace, bringup) is not None
    # One that generates a file from its sources (file(GENERATE)) installs the build's output.
    generated = Package("gen", tmp_path / "src/gen", PackageKind.ROS, "ament_cmake", frozenset())
    generated.path.mkdir(parents=True)
    (generated.path / "gen.yaml.in").write_text("gen: one\n")
    (generated.path / "CMakeLists.txt").write_text(
        "project(gen)\nfile(GENERATE OUTPUT ${CMAKE_CURRENT_BINARY_DIR}/gen.yaml INPUT gen.yaml.in)\n"
    )
    stamps.record({"gen": "s4"}, {}, None, {"gen": tree_state(generated.path)})
    (generated.path / "gen.yaml.in").write_text("gen: two\n")
    assert "compiled or generated" in (edited_since_built(workspace, generated) or "")
    (py.path / "setup.py").write_text("setup(name='talk')\n")
    assert edited_since_built(workspace, py) is not None, "an entry point changed is not linked"


def test_espdocks_workspace_option_and_the_env_files_compose_reads_are_found_among_composes_options(tmp_path):
    """`espdock compose -p NAME --workspace DIR ps`: click stopped at -p and left --workspace to
    Compose ("unknown flag"); an ESPDOCK_USER in the .env of `-f sub/alt.yaml`'s directory, or in
    COMPOSE_ENV_FILES, was overridden by espdock's."""
    from espdock.ros.compose import compose_env_files, own_workspace

    assert own_workspace(["-p", "x", "--workspace", "../ws", "ps"]) == (["-p", "x", "ps"], Path("../ws"))
    assert own_workspace(["--workspace=../ws", "up", "-w"]) == (["up", "-w"], Path("../ws"))
    assert own_workspace(["exec", "-w", "/params", "talker", "pwd"]) == (
        ["exec", "-w", "/params", "talker", "pwd"],
        None,
    )
    root = tmp_path
    assert compose_env_files(["up"], root, {}) == [root / ".env"]
    assert compose_env_files(["-f", "sub/alt.yaml", "up"], root, {}) == [root / "sub/.env"]
    assert compose_env_files(["--project-directory", "deploy", "up"], root, {}) == [root / "deploy/.env"]
    assert compose_env_files(["up"], root, {"COMPOSE_ENV_FILES": "a.env,b.env"}) == [root / "a.env", root / "b.env"]
    assert compose_env_files(["--env-file", "x.env", "-f", "sub/alt.yaml", "up"], root, {}) == [root / "x.env"]


def test_the_current_directory_as_the_shell_reached_it_keeps_its_links(tmp_path, monkeypatch):
    from espdock.workspace import current_dir

    (tmp_path / "real").mkdir()
    (tmp_path / "link").symlink_to(tmp_path / "real")
    monkeypatch.chdir(tmp_path / "link")
    monkeypatch.setenv("PWD", str(tmp_path / "link"))
    assert current_dir(logical=True) == tmp_path / "link"
    assert current_dir() == tmp_path / "real"
    monkeypatch.setenv("PWD", str(tmp_path))  # stale: another directory than the current one
    assert current_dir(logical=True) == tmp_path / "real"
