"""`espdock run` with the real engine, the real runtime image and real DDS: a workspace of
Python nodes written for these tests (tests/ros_packages/beacon_nodes)."""

from __future__ import annotations

import contextlib
import json
import os
import random
import re
import select
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
import yaml

from espdock.config import Config, resolve_ca_bundle
from espdock.images.prune import read_records, state_dir
from tests.conftest import (
    REPO,
    Started,
    build_holding,
    copy_workspace,
    espdock,
    leftover_containers,
    python_workspace,
    reader_exits_at,
)
from tests.ros_official_double.build import build_double, settings
from tests.rosdep_db import environment

pytestmark = pytest.mark.engine


@pytest.fixture(scope="module")
def node_workspace(engine, tmp_path_factory) -> Path:
    root = python_workspace(tmp_path_factory.mktemp("run") / "nodes")
    built = espdock("build", "--only", "ros", cwd=root)
    assert built.returncode == 0, built.stdout + built.stderr
    return root


def dead_espdock_container(root: Path) -> str:
    """A running container of workspace ROOT whose espdock is gone (killed outright, or ended by a
    second Ctrl-C before its cleanup)."""
    from espdock.images.engine import LABEL_OWNER
    from espdock.scratch import owner_identity

    boot, running, _ = owner_identity().split(":")
    dead = f"{boot}:{running.rpartition('.')[0]}.4194304:0"  # this machine and namespace, no such pid
    return subprocess.run(
        ["docker", "run", "-d", "--label", f"io.espdock.workspace={root}", "--label", f"{LABEL_OWNER}={dead}",
         "debian:bookworm-slim", "sleep", "300"],
        capture_output=True, text=True, check=True,
    ).stdout.strip()  # fmt: skip


def test_a_refused_run_removes_what_a_build_ended_at_once_left(engine, tmp_path):
    """A second Ctrl-C ends a build at once, saying "the next espdock build or run here removes any
    container left behind"; a run refused at once (its package not built) left it there."""
    root = python_workspace(tmp_path / "ws-root")
    orphan = dead_espdock_container(root)
    try:
        refused = espdock("run", "beacon_nodes", "beacon", cwd=root)
        gone = subprocess.run(["docker", "container", "inspect", orphan], capture_output=True, check=False)
    finally:
        subprocess.run(["docker", "rm", "-f", orphan], capture_output=True, check=False)
    said = " ".join((refused.stdout + refused.stderr).split())
    assert refused.returncode == 2 and "not built yet" in said, said
    assert "removed 1 container(s) an espdock that ended before its cleanup" in said, said
    assert gone.returncode != 0, "the container left behind still runs"


def Node(root: Path, *args: str, domain: int) -> Started:
    """`espdock run ARGS` in the background in ROS domain DOMAIN."""
    return Started(root, "run", *args, env={"ROS_DOMAIN_ID": str(domain)})


def no_containers_left(engine, root: Path) -> list[str]:
    deadline = time.monotonic() + 10  # the engine's auto-remove finishes just after the CLI
    while (left := leftover_containers(engine, root)) and time.monotonic() < deadline:
        time.sleep(0.2)
    return left


def logs_show(argv: list[str], cwd: Path, text: str, timeout: float = 90) -> bool:
    """Whether ARGV (a `compose logs -f`) prints a line with TEXT within TIMEOUT: one follower
    that sees the line as it comes, not a `compose logs` started every second."""
    with subprocess.Popen(argv, cwd=cwd, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                          stderr=subprocess.STDOUT, text=True, start_new_session=True) as follower:  # fmt: skip
        # Its whole process group: espdock's Compose holds the pipe open as long as it lives.
        timer = threading.Timer(timeout, os.killpg, (follower.pid, signal.SIGKILL))
        timer.start()
        try:
            assert follower.stdout is not None
            return any(text in line for line in follower.stdout)
        finally:
            timer.cancel()
            with contextlib.suppress(ProcessLookupError):
                os.killpg(follower.pid, signal.SIGINT)  # Ctrl-C, as a user ends it
                try:
                    follower.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    os.killpg(follower.pid, signal.SIGKILL)


def test_run_prints_the_nodes_output_and_ctrl_c_ends_it_with_130_leaving_no_container(engine, node_workspace):
    node = Node(node_workspace, "beacon_nodes", "beacon", domain=random.randrange(100, 200))
    try:
        node.wait_for("beacon up")
        node.wait_for("sent: beacon 2")
        assert node.interrupt() == 130
    finally:
        node.stop()
    assert no_containers_left(engine, node_workspace) == []


def test_one_stop_ends_run_within_10_s_when_the_node_ignores_it(engine, node_workspace):
    """Without a terminal, a node that ignored SIGINT and SIGTERM kept running after one Ctrl-C,
    or a CI job's cancel, until two more came; docs/troubleshooting.md promises 10 s."""
    node = Node(node_workspace, "beacon_nodes", "beacon", "--ros-args", "-p", "ignore_stop:=true",
                domain=random.randrange(100, 200))  # fmt: skip
    try:
        node.wait_for("beacon up")
        code, took = node.interrupt_timed()
    finally:
        node.stop()
    assert code == 130 and took < 10, (code, took, node.output()[-2000:])
    assert no_containers_left(engine, node_workspace) == []


def test_a_closed_output_ends_run_as_a_shell_says_leaving_no_container(engine, node_workspace):
    """`espdock run ... 2>&1 | grep -m1 'sent:'`: the reader exits at its first match."""
    domain = {"ROS_DOMAIN_ID": str(random.randrange(100, 200))}
    run = ("run", "beacon_nodes", "beacon", "--ros-args", "-p", "period:=0.1")
    code, _ = reader_exits_at(node_workspace, "sent: beacon", *run, env=domain, stderr_too=True, timeout=30)
    assert code == 141  # 128 + SIGPIPE, which ended the node's output on its way out
    assert no_containers_left(engine, node_workspace) == []


def test_variables_reach_the_node_passed_through_and_given_with_env(engine, node_workspace):
    """RCUTILS_LOGGING_USE_STDOUT (rcutils' own, as the docs' "RCUTILS_* settings" promised) was
    dropped, and `espdock run` had no way to give the node any other variable. An RMW the image
    lacks (rmw_cyclonedds_cpp, from a ROS developer's ~/.bashrc) failed the node at its start:
    not passed, and said."""
    env = {"ROS_DOMAIN_ID": str(random.randrange(100, 200)), "RCUTILS_LOGGING_USE_STDOUT": "1",
           "RMW_IMPLEMENTATION": "rmw_cyclonedds_cpp"}  # fmt: skip
    given = ("-e", "RCUTILS_CONSOLE_OUTPUT_FORMAT=[from --env] {message}")
    run = ("run", *given, "beacon_nodes", "beacon", "--ros-args", "-p", "period:=0.1")
    # Its log lines on stdout alone (stderr kept apart), in the format --env gave.
    code, _ = reader_exits_at(node_workspace, "[from --env] sent: beacon", *run, env=env, timeout=30)
    assert code == 141
    assert no_containers_left(engine, node_workspace) == []
    # Given with --env (NAME: its value here), it is the user's choice: passed, and no word that it was not.
    chosen = ("run", "-e", "RMW_IMPLEMENTATION", "beacon_nodes", "beacon", "--ros-args", "-p", "period:=fast")
    given = espdock(*chosen, cwd=node_workspace, env=env)
    said = given.stdout + given.stderr
    assert "(from your environment) is not in" not in said and "'rmw_cyclonedds_cpp'" in said, said


def test_a_node_whose_espdock_was_killed_outright_is_removed_at_once_or_by_the_next_command(engine, node_workspace):
    """kill -9 of `espdock run` (a supervisor's escalation after its SIGTERM, a closed terminal's
    SIGKILL): the node went on running and talking on the ROS network, its docker CLI with it,
    until the next build; `espdock run` and `shell` never removed it."""
    domain = random.randrange(100, 200)
    node = Node(node_workspace, "beacon_nodes", "beacon", domain=domain)
    try:
        node.wait_for("sent: beacon 1")
        node.process.kill()
        node.process.wait(timeout=30)
    finally:
        node.stop()
    assert no_containers_left(engine, node_workspace) == [], "espdock's watcher removes it once espdock is gone"
    # Its watcher killed as well (a whole cgroup killed): the next command removes it.
    node = Node(node_workspace, "beacon_nodes", "beacon", domain=domain)
    try:
        node.wait_for("sent: beacon 1")
        watcher = subprocess.run(
            ["pgrep", "-f", f"espdock-reaper {node.process.pid} "], capture_output=True, text=True, check=False
        )
        assert watcher.stdout.split(), "no watcher of the running espdock"
        for pid in watcher.stdout.split():
            os.kill(int(pid), signal.SIGKILL)
        node.process.kill()
        node.process.wait(timeout=30)
    finally:
        node.stop()
    (left,) = leftover_containers(engine, node_workspace)
    again = Node(node_workspace, "beacon_nodes", "beacon", domain=domain)
    try:
        again.wait_for("sent: beacon 1")
        said = "\n".join(again.lines)
        assert "removed 1 container(s) an espdock that ended before its cleanup" in said and "Warning" not in said, said
        assert left not in leftover_containers(engine, node_workspace)
        assert again.interrupt() == 130
    finally:
        again.stop()
    assert no_containers_left(engine, node_workspace) == []


def test_a_fast_dds_profiles_file_named_on_the_host_reaches_the_node(engine, node_workspace, tmp_path):
    """The variable was passed on with the host's path: Fast DDS said `XMLPARSER Error ...
    realpath failed` and ran the node on its defaults."""
    profiles = tmp_path / "fastdds.xml"
    profiles.write_text(
        '<?xml version="1.0" encoding="UTF-8" ?>\n'
        '<profiles xmlns="http://www.eprosima.com/XMLSchemas/fastRTPS_Profiles">\n'
        '  <participant profile_name="espdock_test" is_default_profile="true">\n'
        "    <rtps><name>espdock_profiled</name></rtps>\n"
        "  </participant>\n"
        "</profiles>\n"
    )
    env = {"ROS_DOMAIN_ID": str(random.randrange(100, 200)), "FASTRTPS_DEFAULT_PROFILES_FILE": str(profiles)}
    node = Started(node_workspace, "run", "beacon_nodes", "beacon", env=env)
    try:
        node.wait_for("sent: beacon 1")
        assert node.interrupt() == 130
    finally:
        node.stop()
    assert not [line for line in node.lines if "XMLPARSER" in line], node.lines
    assert no_containers_left(engine, node_workspace) == []


def test_two_nodes_started_with_run_talk_over_a_topic(engine, node_workspace):
    domain = random.randrange(100, 200)
    listener = Node(node_workspace, "beacon_nodes", "beacon_log", domain=domain)
    talker = Node(
        node_workspace, "beacon_nodes", "beacon", "--ros-args", "-p", "prefix:=ping", "-p", "period:=0.1", domain=domain
    )
    try:
        listener.wait_for("heard: ping")
        assert talker.interrupt() == 130
        assert listener.interrupt() == 130
    finally:
        talker.stop()
        listener.stop()
    assert no_containers_left(engine, node_workspace) == []


def test_another_domain_hears_nothing(engine, node_workspace):
    """ROS_DOMAIN_ID reaches the node: a listener in another domain hears no beacon."""
    domain = random.randrange(100, 200)
    listener = Node(node_workspace, "beacon_nodes", "beacon_log", domain=domain + 1)
    talker = Node(node_workspace, "beacon_nodes", "beacon", "--ros-args", "-p", "period:=0.1", domain=domain)
    try:
        talker.wait_for("sent: beacon 20")
        assert not [line for line in listener.lines if "heard:" in line]
    finally:
        for node in (talker, listener):
            node.interrupt()
            node.stop()


def test_an_unknown_executable_is_exit_2_listing_what_there_is(node_workspace):
    result = espdock("run", "beacon_nodes", "beacon_lgo", cwd=node_workspace)
    assert result.returncode == 2
    assert "no executable 'beacon_lgo'" in result.stderr and "beacon, beacon_log" in result.stderr
    result = espdock("run", "beacon_node", "beacon", cwd=node_workspace)
    assert result.returncode == 2 and "beacon_nodes: beacon, beacon_log" in result.stderr


def test_run_during_a_build_runs_no_image_of_a_half_rebuilt_install(engine, node_workspace):
    """`espdock run` of a package the build was not rebuilding made the runtime image of the whole
    install/ while the build wrote into it, and moved `:latest` to it."""
    run = ("run", "beacon_nodes", "beacon", "--ros-args", "-p", "period:=fast")
    assert espdock(*run, cwd=node_workspace).returncode not in (0, 2)  # its image exists, for the install as it is
    with build_holding(node_workspace):
        # The image of the install as it is: the node runs (and fails on its parameter, as above).
        ran = espdock(*run, cwd=node_workspace)
        assert ran.returncode not in (0, 2), ran.stdout + ran.stderr
        # What the build writes beside beacon_nodes (colcon's top-level setup files, another
        # package's tree), which its image would hold.
        half = node_workspace / "ws/install/half_written.sh"
        half.write_text("# a file a build is writing\n")
        try:
            refused = espdock(*run, cwd=node_workspace)
        finally:
            half.unlink()
    assert refused.returncode == 2, refused.stdout + refused.stderr
    said = " ".join(refused.stderr.split())
    assert "install/ may be half rebuilt, and the runtime image would be made of it" in said, said


def test_run_during_a_build_rebuilding_the_package_afresh_says_a_build_runs(node_workspace):
    """A build that rebuilds a package afresh (a setup.py edit, --force) moves its install aside
    first: `espdock run` said "not built yet" and to build it, which the running build refused."""
    install = node_workspace / "ws/install/beacon_nodes"
    for moved in (install, install / "lib/beacon_nodes"):  # aside, and being filled in again
        aside = moved.with_name(moved.name + ".aside")
        with build_holding(node_workspace):
            moved.rename(aside)
            try:
                refused = espdock("run", "beacon_nodes", "beacon", cwd=node_workspace)
            finally:
                aside.rename(moved)
        said = " ".join(refused.stderr.split())
        assert refused.returncode == 2, refused.stdout + refused.stderr
        assert "an espdock build is running in" in said and "install/beacon_nodes may be half rebuilt" in said, said


def test_the_node_exit_code_passes_through(node_workspace):
    # A parameter of the wrong type makes rclpy raise at start-up: the node fails, so does run.
    result = espdock("run", "beacon_nodes", "beacon", "--ros-args", "-p", "period:=fast", cwd=node_workspace)
    assert result.returncode not in (0, 130), result.stdout + result.stderr


def test_a_source_put_back_with_its_older_time_is_what_gets_installed(node_workspace):
    """`git archive main | tar -x`, `cp -p` or a backup put a source back with its old time:
    setuptools copies only what is newer than its last copy, so the build said it built the
    package and the edited code stayed installed."""
    source = node_workspace / "ws/src/beacon_nodes/beacon_nodes/beacon.py"
    original, times = source.read_bytes(), source.stat()
    (installed,) = node_workspace.glob("ws/install/beacon_nodes/lib/python3*/site-packages/beacon_nodes/beacon.py")
    try:
        source.write_bytes(original + b"# edited\n")
        edited = espdock("build", "--only", "ros", cwd=node_workspace)
        assert edited.returncode == 0 and installed.read_bytes().endswith(b"# edited\n"), edited.stdout[-2000:]
    finally:
        source.write_bytes(original)
        os.utime(source, ns=(times.st_atime_ns, times.st_mtime_ns))
    restored = espdock("build", "--only", "ros", cwd=node_workspace)
    assert restored.returncode == 0 and "1 package(s) built" in restored.stdout, restored.stdout[-2000:]
    assert installed.read_bytes() == original


def test_a_module_removed_beside_an_edit_is_no_longer_installed(node_workspace):
    """`git checkout main` from a branch that added a module and edited another: the edit is newer
    than the last build, and the module the other branch added stayed installed, importable and
    in the runtime image."""
    package = node_workspace / "ws/src/beacon_nodes/beacon_nodes"
    source = package / "beacon.py"
    original = source.read_bytes()
    site = next(node_workspace.glob("ws/install/beacon_nodes/lib/python3*/site-packages/beacon_nodes"))
    (package / "extra.py").write_text("X = 1\n")
    try:
        added = espdock("build", "--only", "ros", cwd=node_workspace)
        assert added.returncode == 0 and (site / "extra.py").is_file(), added.stdout[-2000:]
    finally:
        (package / "extra.py").unlink()
        source.write_bytes(original + b"# the other branch\n")
    switched = espdock("build", "--only", "ros", cwd=node_workspace)
    assert switched.returncode == 0, switched.stdout[-2000:] + switched.stderr
    said = " ".join(switched.stdout.split())
    assert "installing afresh what lost source files since its last build: beacon_nodes (beacon_nodes/extra.py)" in said
    assert "building beacon_nodes afresh as well" in said
    assert not (site / "extra.py").exists() and (site / "beacon.py").read_bytes().endswith(b"# the other branch\n")
    source.write_bytes(original)
    assert espdock("build", "--only", "ros", cwd=node_workspace).returncode == 0


def test_an_entry_point_taken_out_of_setup_py_is_no_longer_installed(node_workspace):
    """setuptools only adds to an install: the script stayed, `espdock run` listed it, and
    `espdock init --compose` wrote a service for it, which failed as it started."""
    setup = node_workspace / "ws/src/beacon_nodes/setup.py"
    original = setup.read_text()
    script = node_workspace / "ws/install/beacon_nodes/lib/beacon_nodes/beacon_log"
    assert script.is_file()
    setup.write_text(original.replace('"beacon_log = beacon_nodes.beacon_log:main",', ""))
    try:
        dropped = espdock("build", "--only", "ros", cwd=node_workspace)
        assert dropped.returncode == 0, dropped.stdout[-2000:] + dropped.stderr
        assert "building afresh what changed its setup.py or setup.cfg: beacon_nodes" in " ".join(
            dropped.stdout.split()
        )
        assert not script.exists()
        listed = espdock("run", "beacon_nodes", "beacon_log", cwd=node_workspace)
        assert listed.returncode == 2 and "no executable 'beacon_log'" in listed.stderr, listed.stderr
    finally:
        setup.write_text(original)
    restored = espdock("build", "--only", "ros", cwd=node_workspace)
    assert restored.returncode == 0 and script.is_file(), restored.stdout[-2000:] + restored.stderr


def test_a_package_built_afresh_whose_build_fails_or_is_interrupted_keeps_the_install_it_had(node_workspace):
    """A setup.py edit builds the package afresh: its old install went before colcon ran, so a
    typo in it, or Ctrl-C while it built, left no install at all, and `espdock run` said the
    package had no executable (or was not built), where a plain colcon keeps the old install."""
    setup = node_workspace / "ws/src/beacon_nodes/setup.py"
    original = setup.read_text()
    run = ("run", "beacon_nodes", "beacon", "--ros-args", "--params-file", "/nonexistent/params.yaml")

    def runs_the_old_install() -> None:
        ran = espdock(*run, cwd=node_workspace)
        said = " ".join((ran.stdout + ran.stderr).split())
        assert "beacon_nodes's sources changed since its last build: this runs what that build installed" in said
        assert ran.returncode != 2 and "executable" not in said and "not built" not in said, said[-2000:]

    try:
        setup.write_text(original.replace("zip_safe=True,", "zip_safe=True,,"))
        failed = espdock("build", "--only", "ros", cwd=node_workspace)
        assert failed.returncode == 5, failed.stdout[-2000:] + failed.stderr
        assert "building afresh what changed its setup.py or setup.cfg: beacon_nodes" in " ".join(failed.stdout.split())
        runs_the_old_install()
        # colcon runs setup.py to identify the package too: only its build (egg_info first) waits.
        setup.write_text('import sys, time\nif "egg_info" in sys.argv:\n    time.sleep(120)\n' + original)
        argv = [sys.executable, "-m", "espdock", "build", "--only", "ros"]
        with subprocess.Popen(argv, cwd=node_workspace, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) as b:
            try:
                for line in b.stdout:
                    if "Starting >>> beacon_nodes" in line:
                        time.sleep(1)  # into setup.py's wait
                        b.send_signal(signal.SIGINT)
                        break
                assert b.wait(timeout=60) == 130, b.stderr.read()
            finally:
                b.kill()
        runs_the_old_install()
    finally:
        setup.write_text(original)
    rebuilt = espdock("build", "--only", "ros", cwd=node_workspace)
    assert rebuilt.returncode == 0, rebuilt.stdout[-2000:] + rebuilt.stderr


def test_run_says_when_the_package_s_sources_changed_since_its_build(node_workspace):
    """After `git checkout other-branch`, `espdock run` ran the last build's install without a word."""
    source = node_workspace / "ws/src/beacon_nodes/beacon_nodes/beacon.py"
    original = source.read_bytes()
    # A params file rcl cannot open: the node ends at once.
    run = ("run", "beacon_nodes", "beacon", "--ros-args", "--params-file", "/nonexistent/params.yaml")
    try:
        source.write_bytes(original + b"# on another branch\n")
        edited = espdock(*run, cwd=node_workspace)
    finally:
        source.write_bytes(original)
    # On stderr: stdout is the node's (`espdock run pkg dump > data` took the warning into the data).
    said = " ".join(edited.stderr.split())
    assert "warning: beacon_nodes's sources changed since its last build: this runs what that build installed" in said
    assert "warning" not in edited.stdout, edited.stdout
    again = espdock(*run, cwd=node_workspace)
    assert "sources changed" not in again.stdout + again.stderr


def test_run_says_when_a_package_was_built_on_older_sources_of_one_it_depends_on(engine, tmp_path):
    """`espdock build msgs` after a .msg edit, then `espdock run` of a node of a package built on
    the old msgs: it aborted on rosidl's type hash assertion, and nothing had said the package was
    out of date (`--dry-run` knew: "would build" it)."""
    from tests.robot_packages import write_python_package

    root = python_workspace(tmp_path / "w")
    # Built on beacon_nodes (a `depend`, as `ros2 pkg create` writes it); the viewer only runs with it.
    write_python_package(root / "ws/src", "beacon_app", ("beacon_nodes",), tag="depend")
    write_python_package(root / "ws/src", "beacon_viewer", ("beacon_nodes",))
    built = espdock("build", "--only", "ros", cwd=root)
    assert built.returncode == 0, built.stdout[-2000:] + built.stderr
    run = ("run", "beacon_app", "beacon_app_node", "--ros-args", "--params-file", "/nonexistent/params.yaml")
    with open(root / "ws/src/beacon_nodes/beacon_nodes/beacon.py", "a") as source:
        source.write("# changed\n")
    lone = espdock("build", "beacon_nodes", cwd=root)
    assert lone.returncode == 0, lone.stdout[-2000:] + lone.stderr
    older = espdock(*run, cwd=root)
    said = " ".join((older.stdout + older.stderr).split())
    assert (
        "warning: beacon_app was built on other sources of the workspace packages it depends on (beacon_nodes "
        "among them):" in said
    ), said
    assert "`espdock build beacon_app` first" in said
    # A Python package's build reads nothing of what it only runs with (exec_depend): what it
    # installed is as current as the build of it would make it, and no build was skipped.
    viewer = espdock("run", "beacon_viewer", "beacon_viewer_node", *run[3:], cwd=root)
    assert "was built on other sources" not in viewer.stdout + viewer.stderr, viewer.stdout + viewer.stderr
    planned = espdock("build", "--dry-run", "--only", "ros", cwd=root, env={"COLUMNS": "400"}).stdout
    assert re.search(r"would build 1 of 3 package\(s\): beacon_app$", planned, flags=re.M), planned
    # But an edit of what it runs with, not built since, is what it would run the old install of.
    source = root / "ws/src/beacon_nodes/beacon_nodes/beacon.py"
    kept = source.read_text()
    source.write_text(kept + "# changed again\n")
    viewer = espdock("run", "beacon_viewer", "beacon_viewer_node", *run[3:], cwd=root)
    said = " ".join((viewer.stdout + viewer.stderr).split())
    assert (
        "warning: beacon_viewer was built on other sources of the workspace packages it depends on (beacon_nodes"
        in said
    )
    # That edit built, beacon_app left out as told: its install is whole, built on the old beacon_nodes.
    # run refused it: "the last espdock build of beacon_app did not finish ... may be half written".
    skipped = espdock("build", "--only", "ros", "--", "--packages-skip", "beacon_app", cwd=root)
    assert skipped.returncode == 0 and "not built (beacon_app)" in skipped.stdout, skipped.stdout[-2000:]
    left = espdock(*run, cwd=root)
    said = " ".join((left.stdout + left.stderr).split())
    assert "warning: beacon_app was built on other sources" in said and left.returncode != 2, said
    source.write_text(kept)
    again = espdock("build", "--only", "ros", cwd=root)
    assert again.returncode == 0, again.stdout[-2000:] + again.stderr
    current = espdock(*run, cwd=root)
    assert "was built on other sources" not in current.stdout + current.stderr
    # Built with options of its own: up to date by them, though a build without them would build again.
    optioned = espdock("build", "--only", "ros", "--", "--cmake-args", "-DESPDOCK_TEST=1", cwd=root)
    assert optioned.returncode == 0, optioned.stdout[-2000:] + optioned.stderr
    after = espdock(*run, cwd=root)
    assert "was built on other sources" not in after.stdout + after.stderr
    # And a selection with options of its own (which no whole build's record holds): beacon_app
    # was taken for out of date by the whole build's options, and said to be built on older sources.
    selected = espdock("build", "beacon_app", "--", "--cmake-args", "-DESPDOCK_TEST=2", cwd=root)
    assert selected.returncode == 0, selected.stdout[-2000:] + selected.stderr
    mine = espdock(*run, cwd=root)
    assert "was built on other sources" not in mine.stdout + mine.stderr, mine.stdout + mine.stderr
    # A build of beacon_nodes then interrupted (Ctrl-C, kill -9): the runtime image took its half
    # written install without a word. A build forgets a package's record before colcon builds it.
    from espdock.build.stamps import StampFile
    from espdock.ros.staleness import ROS_STAMPS

    StampFile(root / "ws/build" / ROS_STAMPS).forget(["beacon_nodes"])
    # And its colcon container, the espdock that started it killed outright, still writing install/.
    orphan = dead_espdock_container(root)
    try:
        cut = espdock(*run, cwd=root)
        gone = subprocess.run(["docker", "container", "inspect", orphan], capture_output=True, check=False)
    finally:
        subprocess.run(["docker", "rm", "-f", orphan], capture_output=True, check=False)
    said = " ".join((cut.stdout + cut.stderr).split())
    assert "warning: the last espdock build of beacon_nodes did not finish (it failed or was interrupted)" in said
    assert "removed 1 container(s) an espdock that ended before its cleanup (kill -9, " in said
    assert "left behind in this workspace" in said
    assert gone.returncode != 0, "the orphan still runs"
    assert no_containers_left(engine, root) == []


def test_run_of_a_symlink_installed_node_edited_beside_its_dependency_s_build_says_it_was_built_on_older(
    engine, tmp_path
):
    """Under --symlink-install, the node's own module edited (which runs as it is) and the package it
    depends on rebuilt alone: `espdock run` said nothing, as for any package whose sources changed,
    and the node failed on what changed in the other (a .msg's new field)."""
    from tests.robot_packages import write_python_package

    root = python_workspace(tmp_path / "w")
    write_python_package(root / "ws/src", "beacon_app", ("beacon_nodes",), tag="depend")
    built = espdock("build", "--only", "ros", "--", "--symlink-install", cwd=root)
    assert built.returncode == 0, built.stdout[-2000:] + built.stderr
    with open(root / "ws/src/beacon_nodes/beacon_nodes/beacon.py", "a") as source:
        source.write("# changed\n")
    lone = espdock("build", "beacon_nodes", "--", "--symlink-install", cwd=root)
    assert lone.returncode == 0, lone.stdout[-2000:] + lone.stderr
    with open(root / "ws/src/beacon_app/beacon_app/beacon_app_node.py", "a") as source:
        source.write("# uses what changed\n")
    run = ("run", "beacon_app", "beacon_app_node", "--ros-args", "--params-file", "/nonexistent/params.yaml")
    older = espdock(*run, cwd=root)
    said = " ".join(older.stderr.split())
    assert "sources changed since its last build" not in said, said  # its module runs as it is
    assert "warning: beacon_app was built on other sources of the workspace packages it depends on" in said, said


def data_and_show(root: Path) -> Path:
    """beacon_data, a CMake package with nothing to compile, and beacon_show, a Python package
    built on it, beside beacon_nodes in the workspace at ROOT; beacon_data's CMakeLists.txt."""
    from tests.integration.test_faults import add_package
    from tests.robot_packages import write_python_package

    python_workspace(root)
    data = add_package(root, "beacon_data", "install(FILES package.xml DESTINATION share/${PROJECT_NAME})\n")
    write_python_package(root / "ws/src", "beacon_show", ("beacon_data",), tag="depend")
    return data / "CMakeLists.txt"


def test_run_takes_a_dependency_espdock_test_rebuilt_for_its_tests_as_the_one_it_was_built_on(engine, tmp_path):
    """`espdock test LIB` builds LIB again with its tests, an install a plain build of the same
    sources would make (every build after it is up to date): run of a package built on LIB warned
    that it was built on other sources of LIB, until a `--force` build."""
    root = tmp_path / "w"
    data = data_and_show(root)
    built = espdock("build", "--only", "ros", cwd=root)
    assert built.returncode == 0, built.stdout[-2000:] + built.stderr
    tested = espdock("test", "beacon_data", cwd=root)
    assert tested.returncode == 0 and "1 package(s) built" in tested.stdout, tested.stdout[-2000:] + tested.stderr
    ran = espdock("run", "beacon_show", "beacon_show_node", "--ros-args", "--params-file", "/nonexistent", cwd=root)
    said = " ".join((ran.stdout + ran.stderr).split())
    assert "Couldn't parse params file" in said and "was built on other sources" not in said, said[-2000:]
    again = espdock("build", "--only", "ros", cwd=root)
    assert again.returncode == 0 and "up to date" in again.stdout, again.stdout[-2000:]
    # The other way round: the tests' build of the package that runs, not of LIB. It recorded nothing of
    # what it was built on (LIB was no package of its step), so an edit of LIB not built since went unsaid.
    shown = espdock("test", "beacon_show", cwd=root)
    assert shown.returncode == 0 and "1 package(s) built" in shown.stdout, shown.stdout[-2000:] + shown.stderr
    data.write_text(data.read_text() + "# edited\n")
    ran = espdock("run", "beacon_show", "beacon_show_node", "--ros-args", "--params-file", "/nonexistent", cwd=root)
    said = " ".join((ran.stdout + ran.stderr).split())
    assert "warning: beacon_show was built on other sources of the workspace packages it depends on" in said, said


def test_what_a_failed_build_never_started_runs_and_what_failed_is_built_by_skip_build_finished(engine, tmp_path):
    """A dependency's build failed: run of a package colcon never started (its install untouched)
    refused it as "did not finish ... half written", its record forgotten. And the failed package,
    built afresh and put back, kept its old build dir's colcon_build.rc of 0: `-- --packages-skip-
    build-finished`, which espdock names for what did not finish, skipped it."""
    from tests.robot_packages import write_python_package

    root = python_workspace(tmp_path / "w")
    write_python_package(root / "ws/src", "beacon_app", ("beacon_nodes",), tag="depend")
    built = espdock("build", "--only", "ros", cwd=root)
    assert built.returncode == 0, built.stdout[-2000:] + built.stderr
    setup = root / "ws/src/beacon_nodes/setup.py"
    good = setup.read_text()
    setup.write_text(good.replace("zip_safe=True,", "zip_safe=True,,"))
    failed = espdock("build", "--only", "ros", cwd=root)
    assert failed.returncode == 5 and "beacon_nodes" in failed.stderr, failed.stdout[-2000:] + failed.stderr
    ran = espdock("run", "beacon_app", "beacon_app_node", "--ros-args", "--params-file", "/nonexistent", cwd=root)
    said = " ".join((ran.stdout + ran.stderr).split())
    assert "Couldn't parse params file" in said and "did not finish" not in said, said[-2000:]
    assert "warning: beacon_app was built on other sources of the workspace packages it depends on" in said
    setup.write_text(good + "# mended\n")
    again = espdock("build", "--only", "ros", "--", "--packages-skip-build-finished", cwd=root)
    assert again.returncode == 0, again.stdout[-2000:] + again.stderr
    # beacon_nodes is built; beacon_app, whose last build finished, colcon skips as told.
    assert "1 package(s) built, 0 up to date, 1 not built (beacon_app)" in again.stdout, again.stdout[-2000:]


def test_init_writes_a_starter_compose_file_whose_services_start_and_talk(engine, node_workspace):
    written = espdock("init", cwd=node_workspace)
    assert written.returncode == 0 and "wrote compose.yaml" in written.stdout, written.stdout + written.stderr
    again = espdock("init", cwd=node_workspace)
    assert again.returncode == 0 and "wrote compose.yaml" not in again.stdout  # never overwritten
    project = f"espdock-test-run-{os.getpid()}-{random.randrange(16**6):06x}"
    env = {**os.environ, "ROS_DOMAIN_ID": str(random.randrange(100, 200))}

    def compose(*args: str) -> subprocess.CompletedProcess[str]:
        argv = ["docker", "compose", "-p", project, *args]
        return subprocess.run(
            argv, cwd=node_workspace, env=env, capture_output=True, text=True, timeout=300, check=False
        )

    config = compose("config", "--format", "json")
    assert config.returncode == 0, config.stderr
    assert {"beacon", "beacon_log"} <= set(json.loads(config.stdout)["services"])
    assert compose("--profile", "hardware", "config", "-q").returncode == 0
    try:
        up = compose("up", "-d", "beacon", "beacon_log")
        assert up.returncode == 0, up.stderr
        heard = logs_show(["docker", "compose", "-p", project, "logs", "-f", "--no-color", "beacon_log"],
                          node_workspace, "heard: beacon")  # fmt: skip
        assert heard, compose("logs", "--no-color").stdout[-3000:]
        # The nodes run as the image's user under plain Compose, as the user espdock builds for
        # under `espdock compose` (here root standing in for a sudo caller): they ran as ros
        # there too, and a node writing into a mounted directory of the user's was refused.
        ran = compose("run", "--rm", "--no-deps", "--entrypoint", "id", "beacon", "-u")
        assert ran.stdout.split() == ["10001"], ran.stdout + ran.stderr
        # Compose's own `-w` (run's and exec's --workdir) is Compose's: espdock took it for its
        # --workspace, and said "not inside an espdock workspace: no espdock.toml in /etc".
        mine = subprocess.run(
            [sys.executable, "-m", "espdock", "compose", "-p", project, "run", "--rm", "--no-deps",
             "-w", "/etc", "--entrypoint", "sh", "beacon", "-c", "id -u && pwd"],
            cwd=node_workspace, env={**env, "SUDO_UID": "1234", "SUDO_GID": "1234"},
            capture_output=True, text=True, timeout=300, check=False,
        )  # fmt: skip
        assert mine.stdout.split()[-2:] == ["1234", "/etc"], mine.stdout + mine.stderr
        # espdock's --workspace among Compose's global options, from elsewhere: click left it to Compose.
        elsewhere = espdock("compose", "-p", project, "--workspace", str(node_workspace), "ps", cwd=Path("/"))
        assert elsewhere.returncode == 0, elsewhere.stdout + elsewhere.stderr
        # The user's own ESPDOCK_USER in the project's .env, which plain Compose reads, is theirs.
        (node_workspace / ".env").write_text("# the stack's settings\nESPDOCK_USER=4321\n")
        try:
            theirs = subprocess.run(
                [sys.executable, "-m", "espdock", "compose", "-p", project, "run", "--rm", "--no-deps",
                 "--entrypoint", "id", "beacon", "-u"],
                cwd=node_workspace, env={**env, "SUDO_UID": "1234", "SUDO_GID": "1234"},
                capture_output=True, text=True, timeout=300, check=False,
            )  # fmt: skip
        finally:
            (node_workspace / ".env").unlink()
        assert theirs.stdout.split()[-1:] == ["4321"], theirs.stdout + theirs.stderr
        assert "install/ is not what the sources build now" not in mine.stdout + mine.stderr
        # A node edited since the build: `espdock run` warned of it, the services ran it unsaid.
        module = node_workspace / "ws/src/beacon_nodes/beacon_nodes/beacon.py"
        source = module.read_text()
        module.write_text(source + "# edited since the build\n")
        try:
            stale = espdock("compose", "-p", project, "run", "--rm", "--no-deps", "--entrypoint", "true", "beacon",
                            cwd=node_workspace)  # fmt: skip
        finally:
            module.write_text(source)
        said = " ".join((stale.stdout + stale.stderr).split())
        assert "install/ is not what the sources build now: `espdock build` would build beacon_nodes" in said, said
    finally:
        compose("--profile", "*", "down", "-v", "--remove-orphans", "-t", "3")


def test_ctrl_c_without_a_terminal_ends_compose_run_and_removes_its_container(engine, node_workspace):
    """`espdock compose run --rm SERVICE` interrupted by `kill -INT` (CI, a script): espdock said
    interrupted and exited, while Compose left the run's container up, as plain Compose does.
    Another `compose run` started meanwhile in the same directory (a colleague's plain one) is
    not its to remove: it was removed too, its output cut off with 137."""
    project = f"espdock-test-oneoff-{os.getpid()}-{random.randrange(16**6):06x}"
    file = node_workspace / f"{project}.yaml"
    file.write_text(
        "services:\n  beacon:\n    image: espdock/nodes:latest\n"
        "    command: [/opt/espdock/ws/install/beacon_nodes/lib/beacon_nodes/beacon]\n"
        f"    environment: {{ROS_DOMAIN_ID: '{random.randrange(100, 200)}', PYTHONUNBUFFERED: '1'}}\n"
    )
    oneoff = ["docker", "ps", "-aq", "--filter", f"label=com.docker.compose.project={project}"]
    try:
        run = Started(node_workspace, "compose", "-p", project, "-f", file.name, "run", "--rm", "beacon")
        run.wait_for("sent: beacon 1", timeout=300)
        other = subprocess.run(
            ["docker", "compose", "-p", project, "-f", file.name, "run", "-d", "--no-deps", "beacon"],
            cwd=node_workspace, capture_output=True, text=True, timeout=120, check=True,
        ).stdout.split()[-1]  # fmt: skip
        code, took = run.interrupt_timed()
        assert took < 15, took
        assert code == 130, run.output()
        assert "the container `compose run` started was stopped and removed" in run.output()
        left = subprocess.run(oneoff, capture_output=True, text=True, check=True).stdout.split()
        assert left == [other[:12]], "the run's container is still there, or the other run's is gone"
        # Without --rm Compose keeps a run's container (stopped, at a terminal): so does espdock.
        kept = Started(node_workspace, "compose", "-p", project, "-f", file.name, "run", "--name", f"{project}-kept",
                       "beacon")  # fmt: skip
        kept.wait_for("sent: beacon 1", timeout=300)
        assert kept.interrupt() == 130, kept.output()
        assert "the container `compose run` started was stopped (kept: run without --rm)" in kept.output()
        state = ["docker", "inspect", "-f", "{{.State.Status}}", f"{project}-kept"]
        assert subprocess.run(state, capture_output=True, text=True, check=False).stdout.strip() == "exited"
    finally:
        down = ["docker", "compose", "-p", project, "-f", file.name, "down", "--remove-orphans", "-t", "1"]
        subprocess.run(down, cwd=node_workspace, capture_output=True, check=False)
        file.unlink()


COMPOSE_PROJECT = """\
# A service that stops on SIGTERM and one that ignores it, which Compose kills at the end of its
# stop_grace_period (longer than espdock's Ctrl-C budget).
services:
  polite:
    image: {base}
    command: ["sh", "-c", "trap 'exit 0' TERM; echo polite up; while :; do sleep 0.1; done"]
  stubborn:
    image: {base}
    command: ["sh", "-c", "trap '' TERM; echo stubborn up; while :; do sleep 0.1; done"]
    stop_grace_period: 14s
"""


def base_image() -> str:
    from espdock.config import Config
    from espdock.ros.plan import base_image

    return base_image(Config(), (REPO / "Dockerfile.ros").read_text())


def test_ctrl_c_ends_compose_up_with_130_within_10_s_and_compose_stops_every_service(engine, tmp_path):
    """Without a terminal (CI, `kill -INT`) the signal reaches espdock alone: espdock passes it to
    Compose and waits for the services to stop, but not past its 10 s budget; Compose then goes
    on, and stops a service that ignores SIGTERM at the end of its grace period."""
    root = tmp_path / "compose-ws"
    root.mkdir()
    (root / "espdock.toml").write_text("")
    (root / "compose.yaml").write_text(COMPOSE_PROJECT.format(base=base_image()))
    project = f"espdock-ctrl-c-{os.getpid()}"

    def running() -> list[str]:
        return subprocess.run(
            ["docker", "ps", "--format", "{{.Label \"com.docker.compose.service\"}}",
             "--filter", f"label=com.docker.compose.project={project}"],
            capture_output=True, text=True, check=True,
        ).stdout.split()  # fmt: skip

    up = Started(root, "compose", "-p", project, "up")
    try:
        up.wait_for("polite up", timeout=120)
        up.wait_for("stubborn up", timeout=30)
        signalled = time.monotonic()
        code, took = up.interrupt_timed()
        assert code == 130, up.output()
        assert took < 10, f"espdock compose took {took:.1f} s to end after Ctrl-C"
        assert "Compose is still stopping the services" in up.output()
        # What is said is true: the containers are stopped, not removed, until `compose down`.
        assert "stopped and removed" not in up.output()
        assert "their containers remain" in up.output() and "espdock compose down" in up.output()
        # Said once, in one message: it was said still stopping, then "Compose stopped the services".
        assert "Compose stopped the services" not in up.output()
        assert running() == ["stubborn"], "the service that stops on SIGTERM was not stopped"
        while running() and time.monotonic() < signalled + 14 + 10:
            time.sleep(0.5)
        assert running() == [], "Compose left a service running after its stop_grace_period"
        remaining = subprocess.run(
            ["docker", "ps", "-a", "-q", "--filter", f"label=com.docker.compose.project={project}"],
            capture_output=True, text=True, check=True,
        ).stdout.split()  # fmt: skip
        assert len(remaining) == 2, "the message says the containers remain"
    finally:
        up.stop()
        subprocess.run(["docker", "compose", "-p", project, "down", "--timeout", "0"], cwd=root,
                       capture_output=True, check=False)  # fmt: skip


def test_a_second_ctrl_c_in_compose_up_says_the_services_may_still_run(engine, tmp_path):
    """Ctrl-C twice, as Compose's own "press Ctrl+C again to force" invites: espdock said the next
    `espdock build` removes what was left; the services ran on, and a build touches none."""
    root = tmp_path / "compose-ws"
    root.mkdir()
    (root / "espdock.toml").write_text("")
    (root / "compose.yaml").write_text(COMPOSE_PROJECT.format(base=base_image()))
    project = f"espdock-twice-{os.getpid()}"
    # From elsewhere, the workspace named among Compose's options, as `espdock compose` allows.
    up = Started(tmp_path, "compose", "-p", project, "--workspace", str(root), "up")
    try:
        up.wait_for("polite up", timeout=120)
        up.wait_for("stubborn up", timeout=30)
        up.process.send_signal(signal.SIGINT)
        # espdock took the first and passed it on (two sent before its handler ran are one to it).
        up.wait_for("press Ctrl+C again", timeout=30)
        time.sleep(0.5)  # a hand's second Ctrl-C
        up.process.send_signal(signal.SIGINT)
        assert up.process.wait(timeout=30) == 130
        # Read as it comes: Compose, stopping its services, still holds the output espdock wrote
        # its last line into, so the reader goes on, and may not have it yet when espdock is gone.
        up.wait_for("interrupted again", timeout=30)
        said = up.output()
        assert "services Compose started may still be running" in said, said
        # As `up` was given, and run where it was: `down` without the workspace found none.
        assert f"`espdock compose --workspace {root} -p {project} down` stops and removes them" in said, said
        assert "espdock build" not in said, said
    finally:
        up.stop()
        subprocess.run(["docker", "compose", "-p", project, "down", "--timeout", "0"], cwd=root,
                       capture_output=True, check=False)  # fmt: skip


def test_ctrl_c_at_a_terminal_ends_compose_up_with_130_and_says_what_remains(engine, tmp_path):
    """At a real terminal Compose's navigation menu took the key itself: it stopped the services,
    and espdock said nothing and exited 0."""
    import pty

    root = tmp_path / "compose-ws"
    root.mkdir()
    (root / "espdock.toml").write_text("")
    (root / "compose.yaml").write_text(COMPOSE_PROJECT.format(base=base_image()).replace("14s", "1s"))
    project = f"espdock-tty-{os.getpid()}"
    env = {k: v for k, v in os.environ.items() if k != "COMPOSE_MENU"}
    pid, terminal = pty.fork()
    if pid == 0:
        os.chdir(root)
        os.execve(sys.executable, [sys.executable, "-m", "espdock", "compose", "-p", project, "up"], env)
    said = b""
    try:
        deadline = time.monotonic() + 120
        while b"stubborn up" not in said or b"polite up" not in said:
            assert time.monotonic() < deadline, said.decode(errors="replace")
            if select.select([terminal], [], [], 0.5)[0]:
                said += os.read(terminal, 4096)
        time.sleep(1)  # the menu, where Compose shows one, is up by now
        os.write(terminal, b"\x03")
        with contextlib.suppress(OSError):  # the terminal closes with espdock
            while chunk := os.read(terminal, 4096):
                said += chunk
        _, status = os.waitpid(pid, 0)
    finally:
        subprocess.run(["docker", "compose", "-p", project, "down", "--timeout", "0"], cwd=root,
                       capture_output=True, check=False)  # fmt: skip
    text = said.decode(errors="replace")
    assert os.waitstatus_to_exitcode(status) == 130, text
    assert "the containers it had made remain" in text and "espdock compose down" in text, text


def test_compose_in_a_copy_of_a_workspace_warns_that_its_file_runs_the_original_s_nodes(engine, tmp_path):
    """A workspace copied, cloned into another directory or checked out as a git worktree keeps
    the original's compose file: `espdock compose up` built this one's runtime image, then ran
    the original's, in the original's project, replacing its containers, without a word."""
    from espdock.ros.compose import starter_compose

    # The original's name no engine holds an image of: with a real workspace's (a user's
    # espdock/robot:latest), `compose create` made a container in that workspace's project.
    original = f"original{os.getpid()}"
    root = tmp_path / "robot-copy"
    root.mkdir()
    (root / "espdock.toml").write_text("[espdock]\n")
    generated = starter_compose(original, f"espdock/{original}:latest", {"talk": ["talker"]})
    # As espdock wrote it, the command that wrote it is the fix; edited since, the lines to change.
    for text, fix in (
        (generated, "`espdock build`, then `espdock init --compose`, writes it afresh for this workspace"),
        # The file is committed: the original's name as what ESPDOCK_NAME falls back to serves both.
        (
            generated + "# the team's\n",
            f"set image: espdock/${{ESPDOCK_NAME:-{original}}}:latest and name: ${{ESPDOCK_NAME:-{original}}} in "
            "compose.yaml (`espdock compose` sets ESPDOCK_NAME to each workspace's name)",
        ),
    ):
        (root / "compose.yaml").write_text(text)
        try:
            created = espdock("compose", "create", "--pull", "never", "talker", cwd=root)
        finally:  # the project's network, which Compose makes before it finds no image
            subprocess.run(["docker", "compose", "down"], cwd=root, capture_output=True, check=False)
        said = " ".join((created.stdout + created.stderr).split())
        assert f"compose.yaml runs espdock/{original}:latest, another workspace's runtime image" in said, said
        assert fix in said, said
    assert leftover_containers(engine, root) == []


def test_the_compose_file_init_writes_names_each_clone_s_own_project_and_image(engine, tmp_path):
    """A git worktree or clone of another name kept the committed file's `name: robot` and
    `image: espdock/robot:latest`: `espdock compose up` ran the original's nodes in the original's
    project, and `espdock compose down` there removed the original's running services."""
    original = copy_workspace(tmp_path / f"original{os.getpid()}", packages=(), test_packages=("beacon_nodes",))
    lib = original / "ws/install/beacon_nodes/lib/beacon_nodes"
    lib.mkdir(parents=True)
    (lib / "beacon").write_text("#!/bin/sh\n")
    (lib / "beacon").chmod(0o755)
    assert espdock("init", "--compose", cwd=original).returncode == 0
    clone = tmp_path / "robot-clone"
    clone.mkdir()
    shutil.copy2(original / "compose.yaml", clone / "compose.yaml")
    (clone / "espdock.toml").write_text("[espdock]\n")
    # As Compose reads it, under `espdock compose` and under plain `docker compose`.
    read = espdock("compose", "config", "--format", "json", cwd=clone)
    assert read.returncode == 0, read.stdout + read.stderr
    config = json.loads(read.stdout)
    assert (config["name"], config["services"]["beacon"]["image"]) == ("robot-clone", "espdock/robot-clone:latest")
    env = {k: v for k, v in os.environ.items() if k != "ESPDOCK_NAME"}
    plain = subprocess.run(["docker", "compose", "config", "--format", "json"], cwd=original, env=env,
                           capture_output=True, text=True, check=True)  # fmt: skip
    config = json.loads(plain.stdout)
    assert (config["name"], config["services"]["beacon"]["image"]) == (original.name, f"espdock/{original.name}:latest")


def test_run_passes_a_params_file_with_volume_and_a_device_and_refuses_missing_ones(engine, node_workspace, tmp_path):
    params = tmp_path / "beacon.yaml"
    params.write_text("beacon:\n  ros__parameters:\n    prefix: fromfile\n    period: 0.1\n")
    node = Started(
        tmp_path, "run", "--workspace", str(node_workspace), "--volume", "beacon.yaml:/params/beacon.yaml:ro",
        "--device", "/dev/null:/dev/ttyUSB0", "beacon_nodes", "beacon", "--ros-args", "--params-file",
        "/params/beacon.yaml", env={"ROS_DOMAIN_ID": str(random.randrange(100, 200))},
    )  # fmt: skip
    try:
        node.wait_for("sent: fromfile 1")
        (container,) = engine.containers({"io.espdock.workspace": str(node_workspace), "io.espdock.step": "run"})
        inside = subprocess.run(["docker", "exec", container, "sh", "-c", "test -c /dev/ttyUSB0 && ls /params"],
                                capture_output=True, text=True, check=False)  # fmt: skip
        assert inside.returncode == 0 and inside.stdout.split() == ["beacon.yaml"], inside.stdout + inside.stderr
        assert node.interrupt() == 130
    finally:
        node.stop()
    for option, said in (("--volume", "does not exist"), ("--device", "does not exist")):
        missing = espdock("run", option, "/nope/ttyUSB9:/dev/ttyUSB0", "beacon_nodes", "beacon", cwd=node_workspace)
        assert missing.returncode == 2 and f"{option} /nope/ttyUSB9:/dev/ttyUSB0" in missing.stderr, missing.stderr
        assert said in missing.stderr and "Traceback" not in missing.stderr


def test_build_makes_no_runtime_image_run_and_compose_make_it_from_the_last_build(engine, tmp_path):
    """The runtime image is made when a command needs it, of what install/ holds then."""
    root = python_workspace(tmp_path / "ondemand")
    name = f"ondemand-{os.getpid()}-{random.randrange(16**6):06x}"
    config = root / "espdock.toml"
    lines = [line for line in config.read_text().splitlines(True) if not line.startswith("runtime_image")]
    config.write_text("".join(lines).replace("[espdock]\n", f'[espdock]\nname = "{name}"\n', 1))
    domain = str(random.randrange(100, 200))
    project = f"espdock-test-ondemand-{os.getpid()}"
    try:
        built = espdock("build", cwd=root)
        assert built.returncode == 0, built.stdout[-3000:] + built.stderr
        assert "runtime image" not in built.stdout and engine.image(f"espdock/{name}:latest") is None
        refreshed = espdock("init", "--compose", cwd=root)
        assert refreshed.returncode == 0, refreshed.stderr
        assert refreshed.stdout.splitlines()[-2:] == [
            "next:",
            "  espdock compose up        # the nodes compose.yaml names, each a service",
        ], refreshed.stdout
        services = yaml.safe_load((root / "compose.yaml").read_text())["services"]
        assert services["beacon"]["restart"] == "no"  # merged from the node template in Compose
        env = {"ROS_DOMAIN_ID": domain}
        up = espdock("compose", "-p", project, "up", "-d", "beacon", "beacon_log", cwd=root, env=env)
        assert up.returncode == 0, up.stdout + up.stderr
        first = engine.image(f"espdock/{name}:latest")
        assert first is not None
        # Recorded as a build's images are: `espdock prune` knows it, and the test run removes it.
        (record,) = [r for r in read_records(state_dir(os.environ)) if r.root == str(root)]
        assert any(tag.startswith(f"espdock/{name}:") for tag in record.current), record
        follow = [sys.executable, "-m", "espdock", "compose", "-p", project, "logs", "-f", "--no-color", "beacon_log"]
        assert logs_show(follow, root, "heard: beacon"), "the compose services did not talk"
        # An edit and a build: the next run notices install/ changed and makes the image again.
        node = root / "ws/src/beacon_nodes/beacon_nodes/beacon.py"
        node.write_text(node.read_text().replace('info("beacon up")', 'info("beacon up, edited")'))
        rebuilt = espdock("build", cwd=root)
        assert rebuilt.returncode == 0 and engine.image(f"espdock/{name}:latest").id == first.id
        # Plain `docker compose up` would run the old image, silently: the build says so.
        stale = f"note: espdock/{name}:latest is older than install/ now"
        assert stale in rebuilt.stdout.replace("\n", " "), rebuilt.stdout[-2000:]
        assert "older than install/" not in built.stdout
        started = Node(root, "beacon_nodes", "beacon", domain=int(domain))
        try:
            started.wait_for("beacon up, edited", timeout=180)
            assert started.interrupt() == 130
        finally:
            started.stop()
        assert engine.image(f"espdock/{name}:latest").id != first.id
        # A build that installs the same files leaves it the image of install/: nothing to say.
        again = espdock("build", "--force", cwd=root)
        assert again.returncode == 0 and "older than install/" not in again.stdout, again.stdout[-2000:]
    finally:
        espdock("compose", "-p", project, "down", "-t", "1", cwd=root)
        # By tag: the image is bit-identical to any other runtime image of the same install tree
        # (another test's, a developer's own), and removing it by ID would take their tags too.
        listed = ["docker", "images", "--format", "{{.Repository}}:{{.Tag}}", f"espdock/{name}"]
        tags = subprocess.run(listed, capture_output=True, text=True, check=False).stdout.split()
        if tags:
            subprocess.run(["docker", "rmi", *tags], capture_output=True, check=False)


def test_the_shell_opens_where_you_are_keeps_its_home_and_sources_install_as_ros_does(engine, node_workspace):
    """`source install/setup.bash`, a ROS developer's reflex, said `not found:
    "/opt/espdock/venv/local_setup.bash"`; the shell opened in the colcon root wherever it was
    started, its home (/tmp) went with each container, and $USER was empty."""

    def shell(cwd: Path, commands: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([sys.executable, "-m", "espdock", "shell"], cwd=cwd, input=commands,
                              capture_output=True, text=True, timeout=600, check=False)  # fmt: skip

    first = shell(node_workspace, 'source install/setup.bash\necho "user=$USER"\necho kept > ~/mark\n')
    assert first.returncode == 0, first.stdout + first.stderr
    assert first.stderr == "", first.stderr
    assert "user=root" in first.stdout, first.stdout  # the workspace's owner (a root-made test workspace)
    package = node_workspace / "ws/src/beacon_nodes"
    # And with what espdock's build containers get for reproducible output: a colcon build here wrote
    # time-based .pyc files, which `espdock verify` then called changed.
    second = shell(package, "pwd\ncat ~/mark\necho ${SOURCE_DATE_EPOCH:-unset} ${CMAKE_INSTALL_ALWAYS:-unset}\n")
    assert second.returncode == 0, second.stdout + second.stderr
    said = second.stdout.split()
    assert said[:2] == ["/workspace/ws/src/beacon_nodes", "kept"], second.stdout
    assert said[2].isdigit() and said[3] == "1", second.stdout
    assert (node_workspace / "ws/build/espdock-home/mark").is_file()
    # colcon in the shell builds where espdock does: a later `espdock build` took its CMake caches
    # (colcon's default build/) for espdock's own old ones and removed them.
    third = shell(node_workspace, "colcon build --event-handlers console_direct- >/dev/null && ls build\n")
    assert third.returncode == 0, third.stdout + third.stderr
    assert sorted(third.stdout.split()) == ["espdock-home", "espdock-ros"], third.stdout
    assert no_containers_left(engine, node_workspace) == []


def test_ctrl_c_stops_a_script_piped_into_the_shell(engine, node_workspace):
    """`... | espdock shell`, then Ctrl-C: the command running went on to its end and the rest of
    the script ran after it (Ctrl-C reached bash alone, which waited for its command), exit 130."""
    after = node_workspace / "ws/build/after-ctrl-c"
    script = f"echo started\nsleep 60\necho ran > /workspace/ws/build/{after.name}\n"
    process = subprocess.Popen([sys.executable, "-m", "espdock", "shell"], cwd=node_workspace, stdin=subprocess.PIPE,
                               stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)  # fmt: skip
    try:
        process.stdin.write(script)
        process.stdin.close()
        assert any("started" in line for line in process.stdout), "the shell never ran the script"
        started = time.monotonic()
        process.send_signal(signal.SIGINT)
        assert process.wait(timeout=90) == 130
        assert time.monotonic() - started < 30, "the script's sleep ran to its end"
    finally:
        if process.poll() is None:
            process.kill()
    time.sleep(1)
    assert not after.exists(), "the script went on after Ctrl-C"
    assert no_containers_left(engine, node_workspace) == []


def test_the_shell_at_a_terminal_keeps_the_callers_term(engine, node_workspace):
    """Emacs' `M-x shell` (TERM=dumb) got the engine's TERM=xterm: bash's bracketed-paste escapes
    and colour prompt in a buffer that cannot show them. A terminal the image has no terminfo
    for (kitty's) gets xterm's, which it speaks: `clear` said "unknown terminal type"."""
    import pty

    def shell(term: str, command: bytes) -> tuple[int, str]:
        env = {**os.environ, "TERM": term}
        pid, terminal = pty.fork()
        if pid == 0:
            os.chdir(node_workspace)
            os.execve(sys.executable, [sys.executable, "-m", "espdock", "shell"], env)
        said = b""
        try:
            os.write(terminal, command)
            deadline = time.monotonic() + 120
            with contextlib.suppress(OSError):  # the terminal closes with espdock
                while time.monotonic() < deadline:
                    if select.select([terminal], [], [], 1)[0]:
                        if not (chunk := os.read(terminal, 4096)):
                            break
                        said += chunk
            _, status = os.waitpid(pid, 0)
        finally:
            with contextlib.suppress(ChildProcessError, ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
                os.waitpid(pid, 0)
        return os.waitstatus_to_exitcode(status), said.decode(errors="replace")

    code, text = shell("dumb", b'echo "term:$TERM:"; exit 3\n')
    assert code == 3, text
    assert "term:dumb:" in text, text
    assert "\x1b[?2004h" not in text, text
    code, text = shell("xterm-kitty", b'clear >/dev/null && echo "cleared:$TERM:"; exit 3\n')
    assert code == 3 and "cleared:xterm-256color:" in text, text
    assert no_containers_left(engine, node_workspace) == []


@pytest.mark.slow
def test_shell_on_the_official_image_has_the_workspace_sourced(engine, tmp_path):
    """The official image's build stage keeps its own entrypoint, which sources ROS only."""
    tag = build_double(engine, resolve_ca_bundle(Config(), os.environ), lambda line: None)
    root = python_workspace(tmp_path / "official")
    env = {**os.environ, **environment(tmp_path), **settings(tag)}
    built = espdock("build", cwd=root, env=env)
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr
    commands = 'python3 -c "import beacon_nodes; print(beacon_nodes.__file__)"\necho "ament: $AMENT_PREFIX_PATH"\n'
    shell = subprocess.run([sys.executable, "-m", "espdock", "shell"], cwd=root, env=env, input=commands,
                           capture_output=True, text=True, timeout=600, check=False)  # fmt: skip
    assert shell.returncode == 0, shell.stdout + shell.stderr
    assert "/workspace/ws/install/beacon_nodes/" in shell.stdout
    assert "ament: /workspace/ws/install/beacon_nodes" in shell.stdout and "/opt/ros/jazzy" in shell.stdout


def test_compose_up_that_fails_on_a_taken_port_names_the_services_it_left_running(engine, tmp_path):
    """`make demo` with the UI's port taken: Compose failed on that service and left the others
    running (restart: unless-stopped), and nothing said so."""
    import socket

    root = python_workspace(tmp_path / "taken")
    project = f"espdock-test-taken-{os.getpid()}"
    with socket.socket() as holder:
        holder.bind(("127.0.0.1", 0))
        holder.listen()
        port = holder.getsockname()[1]
        (root / "compose.yaml").write_text(
            "services:\n"
            "  first:\n    image: debian:bookworm-slim\n    command: [sleep, '60']\n    init: true\n"
            f"  second:\n    image: debian:bookworm-slim\n    command: [sleep, '60']\n    init: true\n"
            f"    depends_on: [first]\n    ports: ['127.0.0.1:{port}:80']\n"
        )
        try:
            up = espdock("compose", "-p", project, "up", cwd=root, timeout=120)
            assert up.returncode != 0, up.stdout + up.stderr
            said = " ".join((up.stdout + up.stderr).split())
            assert "these services are still running: first; `espdock compose down` stops them" in said, said
            # The service `up --attach` follows ends (`make demo`'s console, restarted from another
            # terminal): up returns, and the rest run on where Ctrl-C no longer reaches them.
            (root / "compose.yaml").write_text(
                "services:\n"
                "  first:\n    image: debian:bookworm-slim\n    command: [sleep, '60']\n    init: true\n"
                "  console:\n    image: debian:bookworm-slim\n    command: [sleep, '1']\n    depends_on: [first]\n"
            )
            # Another project's services from the same directory (`-p robot2`, a second copy of
            # the stack) are not this one's to stop: they were named, and `down` left them.
            (root / "other.yaml").write_text(
                "services:\n  stranger:\n    image: debian:bookworm-slim\n    command: [sleep, '60']\n    init: true\n"
            )
            other = subprocess.run(["docker", "compose", "-p", f"{project}-other", "-f", "other.yaml", "up", "-d"],
                                   cwd=root, capture_output=True, text=True, timeout=120, check=False)  # fmt: skip
            assert other.returncode == 0, other.stderr
            # A colleague's `compose run` of the project is no service `up` left running.
            oneoff = ["docker", "compose", "-p", project, "run", "-d", "--no-deps", "console", "sleep", "60"]
            colleague = subprocess.run(oneoff, cwd=root, capture_output=True, text=True, check=False)
            assert colleague.returncode == 0, colleague.stderr
            attached = espdock("compose", "-p", project, "up", "--attach", "console", cwd=root, timeout=120)
            said = " ".join((attached.stdout + attached.stderr).split())
            assert attached.returncode == 0, said
            assert "compose up returned, and these services are still running: first;" in said, said
        finally:
            # --remove-orphans: the colleague's one-off too.
            subprocess.run(["docker", "compose", "-p", project, "down", "-t", "0", "--remove-orphans"], cwd=root,
                           capture_output=True, check=False)  # fmt: skip
            subprocess.run(["docker", "compose", "-p", f"{project}-other", "-f", "other.yaml", "down", "-t", "0"],
                           cwd=root, capture_output=True, check=False)  # fmt: skip


def test_a_loaded_runtime_image_runs_without_the_images_it_was_made_from(engine, tmp_path):
    """An air-gapped lab that `docker load`ed a workspace's runtime image (or cleaned up its
    base): `espdock run` made the runtime image's base first, from a base image the engine no
    longer had, and failed ("not here and cannot be pulled"), where the image to run was there."""
    from tests.integration.test_engines import once_workspace

    unique = f"{os.getpid()}-{random.randrange(16**6):06x}"
    base = f"espdock-test/base-{unique}:bookworm-slim"  # images built from it have keys of their own
    subprocess.run(["docker", "tag", "debian:bookworm-slim", base], check=True)
    root = once_workspace(tmp_path / "loaded")
    config = root / "espdock.toml"
    named = f'[espdock]\nname = "loaded-{unique}"\nbase_image = "{base}"\n'
    config.write_text(config.read_text().replace("[espdock]\n", named, 1))
    made: list[str] = []
    try:
        built = espdock("build", "--runtime-image", cwd=root)
        assert built.returncode == 0, built.stdout[-3000:] + built.stderr
        made = json.loads((root / "ws/install/espdock-manifest.json").read_text())["images"]
        runtime_base = next(tag for tag in made if tag.startswith("espdock/ros-jazzy-runtime:"))
        for gone in (base, runtime_base):
            subprocess.run(["docker", "rmi", gone], capture_output=True, check=True)
        # From a directory removed under the shell, with --workspace, as other commands run: a crash
        # ("a bug in espdock"), or the image build's docker CLI failing on its getwd.
        gone = root.parent / "gone"
        gone.mkdir()
        ran = subprocess.run(
            ["sh", "-c", f'cd "{gone}" && rmdir "{gone}" && exec "$0" -m espdock run -w "$1" beacon_nodes once',
             sys.executable, str(root)],
            capture_output=True, text=True, check=False, stdin=subprocess.DEVNULL, timeout=600,
        )  # fmt: skip
        assert ran.returncode == 0 and "word:" in ran.stdout, ran.stdout + ran.stderr
    finally:
        listed = subprocess.run(["docker", "images", "--format", "{{.Repository}}:{{.Tag}}"], capture_output=True,
                                text=True, check=False).stdout.split()  # fmt: skip
        subprocess.run(["docker", "rmi", *[t for t in listed if unique in t or t in made]], capture_output=True,
                       check=False)  # fmt: skip
