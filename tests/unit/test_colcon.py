"""colcon's side of a build without colcon: options after `--`, settings files, the changed set,
colcon's event log and the failure hints made from it."""

from __future__ import annotations

import os
import re
import subprocess
import sys
import time
from dataclasses import replace
from pathlib import Path

import pytest
import yaml

from espdock.build.stamps import StampFile, package_stamps
from espdock.errors import ConfigError, WorkspaceError
from espdock.ros.colcon import (
    check_colcon_args,
    egg_info_order_define,
    meta_paths,
    not_naming,
    output_args,
    read_colcon_settings,
    user_defaults_file,
)
from espdock.ros.colcon_log import (
    ColconLog,
    PackageState,
    explain_failure,
    missing_dependencies,
    parse_events,
    usage_error,
)
from espdock.ros.plan import ColconBuild
from espdock.ros.trees import check_isolated_install, retire_container_caches, retire_other_underlay
from tests.conftest import copy_workspace, espdock

NO_ENGINE = {"DOCKER_HOST": "unix:///nonexistent/docker.sock"}
# The first of the CMake arguments of every build of a step at the default colcon root.
EGG_INFO_ORDER_DEFINE = egg_info_order_define(ColconBuild("i", ("a",)).workdir)


def test_a_selection_s_colcon_is_not_told_to_skip_the_packages_it_is_not_shown():
    """`espdock build a` where the options (or a defaults file's) skip b: colcon, shown only a,
    warned "ignoring unknown package 'b'". The option stays, emptied: it wins over a defaults
    file's. A typo, no package's name, stays for colcon to warn of; so do options that select."""
    given = ("--packages-skip", "b", "tpyo", "--packages-skip-regex", "b.*", "a.*", "--packages-ignore=b",
             "--packages-up-to", "b", "--cmake-args", "-Db")  # fmt: skip
    assert not_naming(given, outside=("b", "bb"), inside=("a",)) == (
        "--packages-skip", "tpyo", "--packages-skip-regex", "a.*", "--packages-ignore",
        "--packages-up-to", "b", "--cmake-args", "-Db",
    )  # fmt: skip
    assert ColconBuild("i", ("a",), sources=(("a", "src/a"),), colcon_args=given, outside=("b",)).argv().count("b") == 1


def test_build_options_pass_and_what_espdock_controls_is_refused():
    allowed = ("--cmake-args", "-DBUILD_TESTING=OFF", "--packages-skip", "x", "--continue-on-error")
    assert check_colcon_args(allowed) == allowed
    assert check_colcon_args(None) == ()
    for refused in ("--build-base", "--install-base=/x", "--merge-install", "--base-paths", "--packages-select",
                    "--packages-up-to", "--packages-above", "--event-handlers", "--install-b"):  # fmt: skip
        with pytest.raises(ConfigError) as err:
            check_colcon_args(("--symlink-install", refused, "a"))
        assert refused.split("=")[0] in err.value.message
    with pytest.raises(ConfigError, match=r"name them on its command line \(`espdock build PKG"):
        check_colcon_args(("--packages-select", "a"))


def test_an_empty_double_dash_is_an_error():
    with pytest.raises(ConfigError, match="nothing after `--`"):
        check_colcon_args(())


def test_scheduling_options_do_not_decide_the_output_but_build_options_do():
    args = ("--parallel-workers", "4", "--cmake-args", "-DX=1", "--continue-on-error", "--packages-skip", "a", "b")
    assert output_args(args) == ("--cmake-args", "-DX=1")
    assert output_args(("--parallel-w=2", "--symlink-install")) == ("--symlink-install",)


def test_metas_replaces_the_default_colcon_meta():
    assert meta_paths(()) == ("./colcon.meta",)
    assert meta_paths(("--metas", "a.meta", "dir", "--symlink-install")) == ("a.meta", "dir")
    assert meta_paths(("--metas=a.meta",)) == ("a.meta",)


def test_colcon_reads_the_users_defaults_where_colcon_looks():
    assert user_defaults_file({"COLCON_DEFAULTS_FILE": "/d.yaml", "HOME": "/h"}) == Path("/d.yaml")
    assert user_defaults_file({"COLCON_HOME": "/c", "HOME": "/h"}) == Path("/c/defaults.yaml")
    assert user_defaults_file({"HOME": "/h"}) == Path("/h/.colcon/defaults.yaml")


@pytest.mark.skipif(os.geteuid() != 0, reason="sudo's: espdock run as root")
def test_sudo_espdock_build_reads_the_caller_s_colcon_defaults_not_root_s():
    """`sudo espdock build` (sudo's HOME is root's): root's defaults, not the caller's, turned their
    --symlink-install off, everything was built again, and again by their own next build."""
    import pwd

    caller = pwd.getpwnam("nobody")
    root_home = pwd.getpwuid(0).pw_dir
    sudo = {"HOME": root_home, "SUDO_UID": str(caller.pw_uid), "SUDO_GID": str(caller.pw_gid)}
    assert user_defaults_file(sudo) == Path(caller.pw_dir) / ".colcon/defaults.yaml"
    # `sudo -E` keeps the caller's HOME; a COLCON_HOME given is taken as given.
    assert user_defaults_file({**sudo, "HOME": "/home/ann"}) == Path("/home/ann/.colcon/defaults.yaml")
    assert user_defaults_file({**sudo, "COLCON_HOME": "/c"}) == Path("/c/defaults.yaml")


def _workspace(tmp_path: Path) -> tuple[Path, dict[str, Path]]:
    dirs = {name: tmp_path / "src" / name for name in ("msgs", "app")}
    for directory in dirs.values():
        directory.mkdir(parents=True)
    return tmp_path, dirs


def test_settings_decide_each_package_stamp(tmp_path):
    root, dirs = _workspace(tmp_path)
    env = {"HOME": str(tmp_path / "home")}

    def digests(args=None) -> dict[str, str]:
        return dict(read_colcon_settings(root, dirs, args, env).digests)

    base = digests()
    (root / "colcon.meta").write_text('{"names": {"app": {"cmake-args": ["-DX=1"]}}}')
    meta = digests()
    assert meta["msgs"] == base["msgs"] and meta["app"] != base["app"], "colcon.meta about app changes only app"
    (root / "colcon.meta").write_text('{"paths": {"src/msgs": {"cmake-args": ["-DX=1"]}}}')
    assert digests()["msgs"] != base["msgs"], "an entry by path counts too"
    (root / "colcon.meta").unlink()
    assert digests(("--parallel-workers", "2")) == base
    assert digests(("--cmake-args", "-DBUILD_TESTING=OFF"))["msgs"] != base["msgs"]
    joined = digests(("--cmake-args=-DFOO=1", "-DBAR=2", "--pytest-args=-k", "x"))
    assert joined == digests(("--cmake-args", "-DFOO=1", "-DBAR=2", "--pytest-args", "-k", "x")), (
        "either spelling of the same options builds the same"
    )
    assert joined != digests(("--cmake-args", "-DFOO=2", "-DBAR=2", "--pytest-args", "-k", "x"))
    (root / "colcon_defaults.yaml").write_text("build:\n  symlink-install: true\n")
    workspace_defaults = digests()
    assert workspace_defaults["msgs"] != base["msgs"]
    user = tmp_path / "home/.colcon/defaults.yaml"
    user.parent.mkdir(parents=True)
    user.write_text("build:\n  cmake-args: [-DA=1]\n")
    settings = read_colcon_settings(root, dirs, None, env)
    assert dict(settings.digests)["msgs"] != workspace_defaults["msgs"]
    assert settings.defaults_file == str(user)


def test_symlink_install_in_a_defaults_file_or_after_the_double_dash_is_one_setting(tmp_path):
    """`symlink-install: true` in ~/.colcon/defaults.yaml and `espdock build -- --symlink-install`
    build the same, but each switch between the two configured every CMake package afresh."""
    root, dirs = _workspace(tmp_path)
    env = {"HOME": str(tmp_path / "home")}

    def digests(args=None) -> dict[str, str]:
        return dict(read_colcon_settings(root, dirs, args, env).digests)

    given = digests(("--symlink-install",))
    user = tmp_path / "home/.colcon/defaults.yaml"
    user.parent.mkdir(parents=True)
    user.write_text("build:\n  symlink-install: true\n")
    assert digests() == given == digests(("--symlink-install",))
    user.write_text("build:\n  symlink-install: false\n")
    assert digests() != given and digests(("--symlink-install",)) == given, "the flag turns it on over the file"
    user.write_text("build:\n  symlink-install: true\n  cmake-args: [-DX=1]\n")
    assert digests() != given, "the file's other options still count"


def test_what_a_defaults_file_says_of_which_packages_build_and_when_decides_no_stamp(tmp_path):
    """A colcon_defaults.yaml of `packages-skip` alone rebuilt every package, and taking it out
    rebuilt them all again: the same option after `--` decides no stamp."""
    root, dirs = _workspace(tmp_path)
    env = {"HOME": str(tmp_path / "home")}
    defaults = root / "colcon_defaults.yaml"

    def digests(text: str | None) -> dict[str, str]:
        if text is None:
            defaults.unlink(missing_ok=True)
        else:
            defaults.write_text(text)
        return dict(read_colcon_settings(root, dirs, None, env).digests)

    assert digests("build:\n  packages-skip: [app]\n  parallel-workers: 1\n") == digests(None)
    options = digests("build:\n  cmake-args: [-DX=1]\n")
    assert options != digests(None)
    assert digests("build:\n  cmake-args: [-DX=1]\n  continue-on-error: true\n  packages-skip: [app]\n") == options
    assert digests("build:\n  cmake-args: [-DX=2]\n  packages-skip: [app]\n") != options
    # Another verb's options (`colcon test`'s), an anchor's holder, comments: no build's either.
    assert digests("base: &b {parallel-workers: 1}\nbuild: *b\ntest:\n  return-code-on-test-failure: true\n") == (
        digests(None)
    )
    assert digests("# ours\nbuild: {cmake-args: [-DX=1]}\ntest: {packages-skip: [app]}\n") == options


def test_malformed_or_conflicting_settings_files_are_named(tmp_path):
    root, dirs = _workspace(tmp_path)
    (root / "colcon.meta").write_text('{"names": {"app": ')
    with pytest.raises(WorkspaceError, match=r"colcon\.meta is not a valid colcon\.meta"):
        read_colcon_settings(root, dirs, None, {})
    (root / "colcon.meta").write_text('{"names": ["app"]}')
    with pytest.raises(WorkspaceError, match="'names' is not an object"):
        read_colcon_settings(root, dirs, None, {})
    (root / "colcon.meta").unlink()
    (dirs["app"] / "colcon.meta").write_text("not json")
    with pytest.raises(WorkspaceError, match=re.escape(str(dirs["app"] / "colcon.meta"))):
        read_colcon_settings(root, dirs, None, {})
    (dirs["app"] / "colcon.meta").unlink()
    (root / "colcon_defaults.yaml").write_text("build:\n  merge-install: true\n")
    with pytest.raises(ConfigError, match=r"colcon_defaults\.yaml sets merge-install"):
        read_colcon_settings(root, dirs, None, {})


def test_only_changed_packages_and_their_dependents_are_stale(tmp_path):
    depends = {"msgs": (), "app": ("msgs",), "tool": ()}
    sources = {"msgs": "m", "app": "a", "tool": "t"}
    stamps = package_stamps(sources, depends, "img")
    installed = dict.fromkeys(stamps, "listing")
    stamp_file = StampFile(tmp_path / "stamps.json")
    assert stamp_file.stale(stamps, installed) == ("msgs", "app", "tool")
    stamp_file.record(stamps, installed)
    assert stamp_file.stale(stamps, installed) == ()
    assert stamp_file.stale(package_stamps({**sources, "app": "a2"}, depends, "img"), installed) == ("app",)
    assert stamp_file.stale(package_stamps({**sources, "msgs": "m2"}, depends, "img"), installed) == ("msgs", "app")
    assert stamp_file.stale(package_stamps(sources, depends, "img", {"tool": "meta"}), installed) == ("tool",)
    assert stamp_file.stale(stamps, {**installed, "tool": None}) == ("tool",)
    stamp_file.forget(("msgs", "app"))
    assert stamp_file.stale(stamps, installed) == ("msgs", "app"), "a failed build's packages all build again"


def test_colcon_gets_exactly_the_packages_to_rebuild_then_the_users_options():
    step = ColconBuild(image="i", packages=("msgs", "app", "tool"),
                       sources=(("msgs", "src/msgs"), ("app", "src/app"), ("tool", "src/tool")),
                       colcon_args=("--packages-skip", "tool"))  # fmt: skip
    argv = step.argv(("msgs", "app"))
    assert argv[argv.index("--packages-select") :] == (
        "--packages-select", "msgs", "app", "--packages-skip", "tool", "--cmake-args", EGG_INFO_ORDER_DEFINE,
    )  # fmt: skip
    assert "--packages-select" not in step.argv(("msgs", "app", "tool")), "all of them: no selection needed"
    assert argv[argv.index("--base-paths") + 1 : argv.index("--base-paths") + 4] == ("src/msgs", "src/app", "src/tool")


EVENTS = """\
[0.000010] (-) TimerEvent: {}
[0.000100] (-) JobUnselected: {'identifier': 'other'}
[0.000200] (msgs) JobQueued: {'identifier': 'msgs', 'dependencies': OrderedDict()}
[0.000200] (app) JobQueued: {'identifier': 'app', 'dependencies': OrderedDict([('msgs', '/w/install/msgs')])}
[0.000200] (slow) JobQueued: {'identifier': 'slow', 'dependencies': OrderedDict()}
[0.000200] (last) JobQueued: {'identifier': 'last', 'dependencies': OrderedDict()}
[0.000300] (msgs) JobStarted: {'identifier': 'msgs'}
[0.500000] (msgs) JobEnded: {'identifier': 'msgs', 'rc': 0}
[0.600000] (app) JobEnded: {'identifier': 'app', 'rc': 1}
[0.700000] (slow) JobEnded: {'identifier': 'slow', 'rc': 'SIGINT'}
[0.800000] (last) JobSkipped: {'identifier': 'last'}
"""


def test_the_event_log_tells_built_failed_aborted_and_not_processed_apart():
    assert parse_events(EVENTS.splitlines()) == {
        "msgs": PackageState.BUILT,
        "app": PackageState.FAILED,
        "slow": PackageState.ABORTED,
        "last": PackageState.NOT_PROCESSED,
    }


@pytest.mark.parametrize(
    "executor",
    [
        "colcon_parallel_executor.executor.parallel:run_until_complete",
        "colcon_core.executor.sequential:run_until_complete 'late'",
    ],
)
def test_a_package_an_interrupted_run_logged_as_ended_with_rc_0_is_built_only_if_it_finished(tmp_path, executor):
    """colcon logs "JobEnded rc 0" for a job a Ctrl-C cut short in its own Python code; every
    build task's last act is its runtime-dependencies file, which such a job never wrote."""
    log, install = tmp_path / "log", tmp_path / "install"
    for name in ("early", "late"):  # as a build before this run left them
        packages = install / name / "share/colcon-core/packages"
        packages.mkdir(parents=True)
        (packages / name).write_text("")
        os.utime(packages / name, (time.time() - 60, time.time() - 60))
    colcon = ColconLog(log, install)
    run = log / "build_2026-12-03_10-16-35"
    run.mkdir(parents=True)
    (log / "latest_build").symlink_to(run.name)
    (run / "events.log").write_text(
        "[0.000200] (early) JobQueued: {'identifier': 'early', 'dependencies': OrderedDict()}\n"
        "[0.000200] (late) JobQueued: {'identifier': 'late', 'dependencies': OrderedDict()}\n"
        "[0.600000] (early) JobEnded: {'identifier': 'early', 'rc': 0}\n"
        "[0.700000] (late) JobEnded: {'identifier': 'late', 'rc': 0}\n"
    )
    (install / "early/share/colcon-core/packages/early").write_text("")  # written by this run
    finished = "[0.255s] DEBUG:colcon.colcon_parallel_executor.executor.parallel:run_until_complete finished\n"
    (run / "logger_all.log").write_text(finished)
    assert colcon.states() == {"early": PackageState.BUILT, "late": PackageState.BUILT}
    assert colcon.unfinished == set()
    (run / "logger_all.log").write_text(f"[0.255s] DEBUG:colcon.{executor} was interrupted\n")
    assert colcon.states() == {"early": PackageState.BUILT, "late": PackageState.ABORTED}
    assert colcon.unfinished == {"late"}


def test_a_failure_of_the_package_itself_says_fix_it_and_what_was_kept():
    states = parse_events(EVENTS.splitlines())
    failure = explain_failure(1, states, {"app": (Path("/l/app.log"), "SyntaxError: invalid syntax")}, ())
    assert failure.message.splitlines()[0].startswith("colcon build failed (exit code 1) in app:")
    assert "1 built (msgs)" in failure.message and "1 aborted (slow)" in failure.message
    assert "app: its own build failed; log: /l/app.log" in failure.message
    assert failure.hint.startswith("Fix app")
    assert "--continue-on-error" in failure.hint
    # In a workspace of dozens, each state's packages past a few are counted, not named: it named
    # every one, in the summary's cell and the error line both.
    many = {**states, **{f"waiting_{i}": PackageState.NOT_PROCESSED for i in range(46)}}
    failure = explain_failure(1, many, {"app": (Path("/l/app.log"), "SyntaxError: invalid syntax")}, ())
    assert failure.message.splitlines()[0].endswith(
        ": 1 aborted (slow), 1 built (msgs), 1 failed (app), 47 not processed"
    )
    assert "The 1 package(s) that built are kept" in failure.hint


def test_a_build_dir_from_a_copying_build_under_symlink_install_is_named_not_the_package():
    """`-- --symlink-install` after a plain build: ament_cmake cannot put its link where the copy
    left a directory (colcon alone fails the same). The hint said to fix the package."""
    output = (  # the wheels image's colcon, custom_interface built plain, then with --symlink-install
        "failed to create symbolic link '/workspace/build/espdock-ros/robot_msgs/ament_cmake_python/"
        "robot_msgs/robot_msgs' because existing path cannot be removed: Is a directory\n"
    )
    failure = explain_failure(1, {"robot_msgs": PackageState.FAILED}, {"robot_msgs": (Path("/l/r.log"), output)}, ())
    assert "robot_msgs: its build dir is from a build without --symlink-install" in failure.message
    assert failure.hint.startswith("Remove build/espdock-ros/robot_msgs (only a cache") and "Fix" not in failure.hint


def test_a_missing_dependency_is_not_the_packages_fault_and_nothing_kept_is_claimed():
    output = (
        'CMake Error at CMakeLists.txt:9 (find_package):\n  By not providing "Findrclcpp.cmake" in CMAKE_MODULE_PATH\n'
        '  Could not find a package configuration file provided by "rclcpp" with any\n'
    )
    assert missing_dependencies(output) == ("rclcpp",)
    states = {"cpp_node": PackageState.FAILED, "py_node": PackageState.NOT_PROCESSED}
    failure = explain_failure(1, states, {"cpp_node": (Path("/l/c.log"), output)}, ())
    assert "cpp_node: could not find rclcpp" in failure.message
    assert "Fix" not in failure.hint
    assert "cpp_node needs rclcpp, which the build image does not provide" in failure.hint
    assert "No package was built" in failure.hint and "kept" not in failure.hint
    kept_going = explain_failure(1, states, {"cpp_node": (Path("/l/c.log"), output)}, ("--continue-on-error",))
    assert "--continue-on-error` builds" not in kept_going.hint


def test_cli_refuses_an_empty_double_dash_and_refused_options_before_any_engine(tmp_path):
    root = copy_workspace(tmp_path / "w")
    empty = espdock("build", "--", cwd=root, env=NO_ENGINE)
    assert empty.returncode == 2, empty.stderr
    assert "nothing after `--`" in empty.stderr
    # A package named after `--`: colcon refused it as an --event-handlers value, in its container.
    word = espdock("build", "--", "custom_interface", cwd=root, env=NO_ENGINE)
    assert word.returncode == 2, word.stdout + word.stderr
    said = " ".join(word.stderr.split())
    assert "'custom_interface' after `--` is no colcon option" in said, said
    assert "Name packages before the `--` (`espdock build custom_interface`)" in said, said
    refused = espdock("build", "custom_interface", "--", "--install-base", "/tmp/x", cwd=root, env=NO_ENGINE)
    assert refused.returncode == 2 and "--install-base is not allowed" in refused.stderr
    (root / "ws/colcon.meta").write_text("{")
    malformed = espdock("build", cwd=root, env=NO_ENGINE)
    assert malformed.returncode == 2 and "colcon.meta is not a valid colcon.meta" in malformed.stderr
    assert not (root / "ws/build").exists()


def test_dry_run_shows_the_options_after_the_double_dash(tmp_path):
    root = copy_workspace(tmp_path / "w")
    result = espdock("build", "--dry-run", "--", "--cmake-args", "-DBUILD_TESTING=OFF", cwd=root, env=NO_ENGINE)
    assert result.returncode == 0, result.stderr
    order = egg_info_order_define("/workspace/ws")  # the repository's colcon root
    assert f"summary+ --cmake-args {order} -DBUILD_TESTING=OFF" in " ".join(result.stdout.split()), result.stdout


def test_colcon_meta_is_yaml_and_what_espdock_passes_itself_may_be_in_the_defaults(tmp_path):
    root, dirs = _workspace(tmp_path)
    base = dict(read_colcon_settings(root, dirs, None, {}).digests)
    # As colcon-metadata reads it: YAML, not only JSON.
    (root / "colcon.meta").write_text("names:\n  app:\n    cmake-args:\n      - -DX=1\n")
    meta = dict(read_colcon_settings(root, dirs, None, {}).digests)
    assert meta["msgs"] == base["msgs"] and meta["app"] != base["app"]
    # espdock gives --event-handlers and --base-paths on the command line, which beats a defaults file.
    user = tmp_path / "defaults.yaml"
    user.write_text("build:\n  event-handlers: [console_cohesion+]\n  base-paths: [elsewhere]\n")
    assert read_colcon_settings(root, dirs, None, {"COLCON_DEFAULTS_FILE": str(user)}).defaults_file == str(user)


def test_an_option_colcon_does_not_know_is_named_not_blamed_on_espdocks_own(tmp_path):
    # The real colcon, given espdock's command line and an option it does not know.
    (tmp_path / "src").mkdir()
    argv = ColconBuild("x", ("a",), (("a", "src"),), colcon_args=("--frobnicate",)).argv()
    colcon = Path(sys.executable).with_name("colcon")
    said = subprocess.run([str(colcon), *argv[1:]], cwd=tmp_path, capture_output=True, text=True, check=False)
    assert said.returncode != 0 and "--event-handlers: invalid choice" in said.stderr
    assert usage_error(said.stderr.splitlines(), ("--frobnicate",)) == (
        "colcon build does not accept --frobnicate (given after `--`)"
    )


def test_only_build_dirs_espdock_configured_in_its_container_are_retired(tmp_path):
    """espdock's CMake caches from before its own build base (configured at /workspace) go, so a
    native `colcon build` can configure build/PKG afresh; a native cache and the firmware's stay."""
    build = tmp_path / "build"
    mounted = "/workspace/ws/build"
    for name, where in (("old_msgs", mounted), ("native_msgs", str(build)), ("board", mounted)):
        (build / name).mkdir(parents=True)
        (build / name / "CMakeCache.txt").write_text(f"CMAKE_CACHEFILE_DIR:INTERNAL={where}/{name}\n")
    (build / "py_pkg").mkdir()
    assert retire_container_caches(build, ["old_msgs", "native_msgs", "py_pkg", "gone"], mounted) == ["old_msgs"]
    assert sorted(p.name for p in build.iterdir()) == ["board", "native_msgs", "py_pkg"]


def test_espdock_s_cmake_arguments_join_the_last_cmake_args_which_colcon_keeps():
    """`-- --cmake-args -DX=1 --cmake-args -DY=2`: colcon keeps the last one's values, and espdock's
    BUILD_TESTING and egg-info order, which joined the first, never reached CMake."""
    twice = ColconBuild("i", ("a",), tests_off=True, colcon_args=("--cmake-args", "-DX=1", "--cmake-args", "-DY=2"))
    assert twice.argv()[-6:] == (
        "--cmake-args", "-DX=1", "--cmake-args", EGG_INFO_ORDER_DEFINE, "-DBUILD_TESTING=OFF", "-DY=2",
    )  # fmt: skip


def test_an_interface_package_built_before_its_egg_info_was_ordered_is_built_once_more():
    """An upgraded espdock said "up to date" of an install the race had spoiled (its egg-info without
    the generated modules), so two builds of one commit still installed different files."""
    step = ColconBuild("i", ("msgs", "cpp", "py"), python=("py",), interfaces=("msgs",))
    images = step.stamp_images()
    assert images["cpp"] == "i" and images["py"] == "i", "other packages keep their stamps"
    assert images["msgs"] != "i"


def test_the_shell_s_colcon_defaults_carry_the_egg_info_order_and_replace_an_older_espdock_s(tmp_path):
    """A build dir the shell's colcon configured itself lacked the include: its egg-info was the race's."""
    from espdock.ros.nodes import SHELL_COLCON_DEFAULTS, make_shell_home
    from espdock.workspace import Workspace

    (tmp_path / "espdock.toml").write_text('[espdock]\ncolcon_root = "ws"\n')
    home = tmp_path / "ws/build/espdock-home"
    home.mkdir(parents=True)
    (home / "colcon-defaults.yaml").write_text(SHELL_COLCON_DEFAULTS)  # an older espdock's, unedited
    make_shell_home(Workspace(tmp_path), (os.getuid(), os.getgid()))
    defaults = yaml.safe_load((home / "colcon-defaults.yaml").read_text())
    assert defaults["build"]["cmake-args"] == [egg_info_order_define("/workspace/ws")]
    # On the wheels image, as espdock's builds there: `ros2 pkg create`'s ament_cmake package asks for
    # ament_lint_auto under if(BUILD_TESTING), which the image lacks (the shell's colcon failed on it).
    make_shell_home(Workspace(tmp_path), (os.getuid(), os.getgid()), tests_off=True)
    defaults = yaml.safe_load((home / "colcon-defaults.yaml").read_text())
    assert defaults["build"]["cmake-args"] == [egg_info_order_define("/workspace/ws"), "-DBUILD_TESTING=OFF"]
    (home / "colcon-defaults.yaml").write_text("build: {build-base: build/espdock-ros, symlink-install: true}\n")
    make_shell_home(Workspace(tmp_path), (os.getuid(), os.getgid()))
    assert "symlink-install" in (home / "colcon-defaults.yaml").read_text(), "the user's edits stay"


def test_a_plain_build_on_the_wheels_image_configures_cmake_packages_without_tests():
    plain = ColconBuild(image="i", packages=("a",), sources=(("a", "src/a"),), tests_off=True)
    assert plain.argv()[-3:] == ("--cmake-args", EGG_INFO_ORDER_DEFINE, "-DBUILD_TESTING=OFF")
    own = ColconBuild(image="i", packages=("a",), tests_off=True, colcon_args=("--cmake-args", "-DX=1", "--foo"))
    # colcon keeps only the last --cmake-args: the value joins the user's own.
    assert own.argv()[-5:] == ("--cmake-args", EGG_INFO_ORDER_DEFINE, "-DBUILD_TESTING=OFF", "-DX=1", "--foo")
    # The `=` form is the same option (a second --cmake-args replaced it: FOO stayed as cached).
    equals = ColconBuild(image="i", packages=("a",), tests_off=True, colcon_args=("--cmake-args=-DFOO=3", "--foo"))
    assert equals.argv()[-5:] == ("--cmake-args", EGG_INFO_ORDER_DEFINE, "-DBUILD_TESTING=OFF", "-DFOO=3", "--foo")
    asked_equals = ColconBuild(
        image="i", packages=("a",), tests_off=True, colcon_args=("--cmake-args=-DBUILD_TESTING=ON",)
    )
    assert "-DBUILD_TESTING=OFF" not in asked_equals.argv() and not asked_equals.says_tests_off
    # The test build takes the last build's options as spelt (they decide the stamps): taken apart,
    # `espdock test` and `espdock build` rebuilt each other's packages each time.
    from espdock.ros.colcon import without_build_testing

    assert without_build_testing(("--cmake-args=-DFOO=7", "--foo")) == ("--cmake-args=-DFOO=7", "--foo")
    assert without_build_testing(("--cmake-args=-DBUILD_TESTING=ON", "--foo")) == ("--cmake-args", "--foo")
    asked = ColconBuild(image="i", packages=("a",), tests_off=True, colcon_args=("--cmake-args", "-DBUILD_TESTING=ON"))
    assert asked.argv().count("-DBUILD_TESTING=OFF") == 0 and not asked.says_tests_off
    official = ColconBuild(image="i", packages=("a",))
    # The official image builds as colcon does, the egg-info's order aside.
    assert official.argv()[-2:] == ("--cmake-args", EGG_INFO_ORDER_DEFINE) and "-DBUILD_TESTING" not in official.argv()
    testing = ColconBuild(image="i", packages=("a",), testing=True)
    # Said each time: CMake would keep the OFF an earlier build left in its cache.
    assert testing.argv()[-3:] == ("--cmake-args", EGG_INFO_ORDER_DEFINE, "-DBUILD_TESTING=ON")
    stamps = {step.stamp_images()["a"] for step in (plain, official, testing)}
    assert len(stamps) == 3, "a test build, a build without tests and colcon's default never pass for each other"
    assert official.stamp_images() == {"a": "i"}, "builds of before keep their stamps"


def test_a_test_only_dependency_colcon_missed_is_not_declare_it_in_package_xml():
    output = 'Could not find a package configuration file provided by "ament_lint_auto" with any\n'
    states = {"cpp_pkg": PackageState.FAILED}
    logs = {"cpp_pkg": (Path("/l/c.log"), output)}
    declared = {"cpp_pkg": (frozenset({"ament_cmake", "ament_lint_auto"}), frozenset({"ament_lint_auto"}))}
    failure = explain_failure(1, states, logs, (), declared)
    assert "declare it" not in failure.hint
    assert "only for its tests" in failure.hint and "-DBUILD_TESTING=OFF" in failure.hint
    build_dep = {"cpp_pkg": (frozenset({"ament_cmake", "ament_lint_auto"}), frozenset())}
    failure = explain_failure(1, states, logs, (), build_dep)
    assert "declare it" not in failure.hint and "package.xml declares ament_lint_auto" in failure.hint
    assert "declare it in cpp_pkg's package.xml" in explain_failure(1, states, logs, ()).hint


def test_build_dirs_of_another_ros_image_go_and_the_new_kind_is_recorded(tmp_path):
    """The first base, or one from before the marker, is taken as the image's; another kind of
    image removes every package's build dir (colcon's own files stay), and says so even with none
    here (the workspace volume holds them then)."""
    me = (os.getuid(), os.getgid())
    base = tmp_path / "build/espdock-ros"
    assert retire_other_underlay(base, "espdock/ros-jazzy-build", me) is None
    (base / "driver/CMakeFiles").mkdir(parents=True)
    (base / "COLCON_IGNORE").write_text("")
    assert retire_other_underlay(base, "espdock/ros-jazzy-build", me) is None
    assert (base / "driver").is_dir()
    assert retire_other_underlay(base, "espdock/ros-jazzy-official-build", me) == ["driver"]
    assert sorted(p.name for p in base.iterdir()) == [".espdock-underlay", "COLCON_IGNORE"]
    assert retire_other_underlay(base, "espdock/ros-jazzy-build", me) == []


def test_an_install_a_native_merge_install_made_is_refused_before_colcon(tmp_path):
    """colcon itself stopped before any package, advising --merge-install, which espdock refuses
    after `--`; the hint said to check the options given after `--` (there were none)."""
    install = tmp_path / "install"
    check_isolated_install(install)  # none yet
    install.mkdir()
    (install / ".colcon_install_layout").write_text("isolated\n")
    check_isolated_install(install)
    (install / ".colcon_install_layout").write_text("merged\n")
    with pytest.raises(WorkspaceError) as raised:
        check_isolated_install(install)
    assert raised.value.exit_code == 2 and "--merge-install" in raised.value.message
    assert "Remove install/" in raised.value.hint and "--install-base" in raised.value.hint


def test_the_defaults_files_cmake_args_join_the_build_testing_espdock_gives(tmp_path):
    """A `--cmake-args` on colcon's command line replaces the defaults file's: espdock's own
    -DBUILD_TESTING dropped the user's cmake-args unsaid."""
    root, dirs = _workspace(tmp_path)
    user = tmp_path / "defaults.yaml"
    user.write_text("build:\n  cmake-args: [-DCMAKE_EXPORT_COMPILE_COMMANDS=ON, -DBUILD_TESTING=OFF]\n")
    settings = read_colcon_settings(root, dirs, None, {"COLCON_DEFAULTS_FILE": str(user)})
    assert settings.cmake_args == ("-DCMAKE_EXPORT_COMPILE_COMMANDS=ON", "-DBUILD_TESTING=OFF")
    build = ColconBuild("x", ("a",), (("a", "src"),), defaults_cmake_args=("-DCMAKE_EXPORT_COMPILE_COMMANDS=ON",))
    plain = replace(build, tests_off=True)
    assert plain.options == (
        "--cmake-args", EGG_INFO_ORDER_DEFINE, "-DCMAKE_EXPORT_COMPILE_COMMANDS=ON", "-DBUILD_TESTING=OFF",
    )  # fmt: skip
    # A test build configures the tests whatever the defaults say; a defaults file setting them
    # itself is left to say so for a plain build.
    testing = replace(build, testing=True, defaults_cmake_args=settings.cmake_args)
    assert testing.options == (
        "--cmake-args", EGG_INFO_ORDER_DEFINE, "-DCMAKE_EXPORT_COMPILE_COMMANDS=ON", "-DBUILD_TESTING=ON",
    )  # fmt: skip
    # The defaults file's own cmake-args, given on the command line beside the egg-info's order (a
    # `--cmake-args` there replaces the file's).
    assert replace(plain, defaults_cmake_args=settings.cmake_args).options == (
        "--cmake-args", EGG_INFO_ORDER_DEFINE, *settings.cmake_args,
    )  # fmt: skip
    assert not replace(plain, defaults_cmake_args=settings.cmake_args).says_tests_off


def test_the_defaults_files_symlink_install_is_read_the_workspace_s_over_the_user_s(tmp_path):
    root, dirs = _workspace(tmp_path)
    user = tmp_path / "defaults.yaml"
    user.write_text("build:\n  symlink-install: true\n")
    env = {"COLCON_DEFAULTS_FILE": str(user)}
    assert read_colcon_settings(root, dirs, None, env).symlink_install
    (root / "colcon_defaults.yaml").write_text("build: {symlink-install: false}\n")
    assert not read_colcon_settings(root, dirs, None, env).symlink_install


def test_a_find_module_s_could_not_find_is_a_missing_dependency():
    """find_package_handle_standard_args's "Could NOT find" (a Find module: OpenSSL, Boost) was
    the package's own fault: "Fix cam_node"."""
    output = (
        "CMake Error at /usr/share/cmake-3.28/Modules/FindPackageHandleStandardArgs.cmake:230 (message):\n"
        "  Could NOT find OpenSSL, try to set the path to OpenSSL root folder in the\n"
        "  system variable OPENSSL_ROOT_DIR (missing: OPENSSL_CRYPTO_LIBRARY\n"
        "Call Stack (most recent call first):\n"
        "  CMakeLists.txt:12 (find_package)\n"
    )
    assert missing_dependencies(output) == ("OpenSSL",)
    failure = explain_failure(1, {"cam_node": PackageState.FAILED}, {"cam_node": (Path("/l/c.log"), output)}, ())
    assert "cam_node: could not find OpenSSL" in failure.message and "Fix" not in failure.hint


def test_a_file_of_the_user_s_in_a_directory_of_another_s_is_the_directory_denied(tmp_path):
    """`chown 0:0` of a package's installed module directory: setuptools' "could not delete
    '.../envdump.py': Permission denied" named a file of the user's, so the build blamed the
    package ("Fix py_talker") where the directory was root's."""
    from espdock.ros.steps import denied_path

    module = tmp_path / "install/py_talker/lib/python3.11/site-packages/py_talker"
    module.mkdir(parents=True)
    (module / "envdump.py").write_text("")
    for path in (tmp_path / "install", *module.relative_to(tmp_path).parents, module, module / "envdump.py"):
        os.chown(tmp_path / path, 1000, 1000)
    os.chown(module, 0, 0)
    inside = "/workspace/install/py_talker/lib/python3.11/site-packages/py_talker/envdump.py"
    said = f"error: could not delete '{inside}': Permission denied"
    assert denied_path([said], tmp_path, 1000) == module
    os.chown(module, 1000, 1000)  # the user's own, all of it: not a matter of owners
    assert denied_path([said], tmp_path, 1000) is None


def test_a_file_cmake_may_not_chmod_is_another_s_file_not_the_package_s_fault(tmp_path):
    """A `sudo chown -R root:` of part of a package's install: CMake's install of an unchanged
    file says the path, then "Operation not permitted." on the next line, and the build blamed
    the package ("its own build failed ... Fix probea_interfaces")."""
    from espdock.ros.steps import denied_path

    json_file = tmp_path / "install/robot_msgs/share/robot_msgs/msg/Status.json"
    json_file.parent.mkdir(parents=True)
    json_file.write_text("{}")
    for path in (*json_file.relative_to(tmp_path).parents, json_file.relative_to(tmp_path)):
        os.chown(tmp_path / path, 1000, 1000)
    os.chown(json_file, 0, 0)
    said = (
        "CMake Error at cmake_install.cmake:50 (file):\n  file INSTALL cannot set permissions on\n"
        '  "/workspace/install/robot_msgs/share/robot_msgs/msg/Status.json":\n  Operation not permitted.\n'
    )
    assert denied_path([said], tmp_path, 1000) == json_file
    os.chown(json_file, 1000, 1000)
    assert denied_path([said], tmp_path, 1000) is None


def test_symlink_install_abbreviated_as_colcon_takes_it_is_a_switch_of_the_install_kind(tmp_path):
    """`-- --symlink` (colcon takes unique prefixes) after a copying build: espdock saw no switch,
    and colcon failed in the build dirs the copying build had left."""
    from espdock.ros.trees import install_kind_switched, record_build_args

    record_build_args(tmp_path, ())
    for spelt in ("--symlink", "--sym", "--s"):
        args = check_colcon_args((spelt, "--packages-skip", "x"))
        assert args == ("--symlink-install", "--packages-skip", "x")
        assert install_kind_switched(tmp_path, ["x"], args) == ["x"]
    assert check_colcon_args(("--cmake-args", "-DSYM=1")) == ("--cmake-args", "-DSYM=1")


def test_what_a_defaults_file_skips_is_left_out_of_the_checks_as_colcon_leaves_it_out(tmp_path):
    """packages-skip in colcon_defaults.yaml: colcon skipped the package, and espdock refused the
    build for the package's dependencies no image has."""
    from espdock.ros.colcon import left_out

    root = tmp_path / "ws"
    dirs = {name: root / "src" / name for name in ("app", "driver")}
    for path in dirs.values():
        path.mkdir(parents=True)
    (root / "colcon_defaults.yaml").write_text(
        "build:\n  packages-skip: [driver]\n  packages-skip-build-finished: true\n"
    )
    settings = read_colcon_settings(root, dirs, None, {})
    assert left_out(settings.args, {"app": (), "driver": ()}) == {"driver"}
    # Given on the command line, the option wins over the file's, as in colcon.
    given = read_colcon_settings(root, dirs, ("--packages-skip", "app"), {})
    assert left_out(given.args, {"app": (), "driver": ()}) == {"app"}
    assert output_args(settings.args) == ()


def test_the_install_kind_is_kept_per_package_so_a_selection_s_switch_is_not_taken_for_the_workspace_s(tmp_path):
    """`espdock build leaf -- --symlink-install`, then `espdock build -- --symlink-install`: kept for
    the workspace, the switch seemed done, and msgs (still copies) was built in place and failed;
    the other way round, a copying build left msgs' install links."""
    from espdock.ros.trees import install_kind_switched, record_build_args, record_install_kinds

    record_build_args(tmp_path, ())
    record_install_kinds(tmp_path, ["msgs", "leaf"], ())
    record_build_args(tmp_path, ("--symlink-install",))
    record_install_kinds(tmp_path, ["leaf"], ("--symlink-install",))
    assert install_kind_switched(tmp_path, ["msgs", "leaf"], ("--symlink-install",)) == ["msgs"]
    assert install_kind_switched(tmp_path, ["msgs", "leaf"], ()) == ["leaf"]
    # A package an older espdock built (no record of its own): the last build's options say.
    assert install_kind_switched(tmp_path, ["old"], ()) == ["old"]


def test_a_cmake_package_s_install_kind_is_what_its_cmake_cache_says_whoever_built_it(tmp_path):
    """A `colcon build --symlink-install` in `espdock shell` builds in espdock's build base and
    keeps no record: the cache's AMENT_CMAKE_SYMLINK_INSTALL stays on (colcon only sets it), so the
    next plain build made links again, or failed on what the copying build had left."""
    from espdock.ros.trees import install_kind_switched, record_install_kinds

    record_install_kinds(tmp_path, ["msgs", "tools", "nodes"], ())  # espdock's own build: copies
    (tmp_path / "msgs").mkdir()
    (tmp_path / "msgs/CMakeCache.txt").write_text("CMAKE_BUILD_TYPE:STRING=\nAMENT_CMAKE_SYMLINK_INSTALL:BOOL=1\n")
    (tmp_path / "tools").mkdir()
    (tmp_path / "tools/CMakeCache.txt").write_text("AMENT_CMAKE_SYMLINK_INSTALL:BOOL=OFF\n")
    (tmp_path / "nodes").mkdir()  # ament_python: no cache, its record says
    assert install_kind_switched(tmp_path, ["msgs", "tools", "nodes"], ()) == ["msgs"]
    assert install_kind_switched(tmp_path, ["msgs", "tools", "nodes"], ("--symlink-install",)) == ["tools", "nodes"]


def test_mixins_named_in_the_user_s_defaults_file_are_warned_of_naming_it(tmp_path):
    """`mixin: [release]` in ~/.colcon/defaults.yaml (the ROS tutorials' habit): the build image has no
    colcon-mixin, and the only sign was a colcon warning among its output naming the container's path."""
    root = copy_workspace(tmp_path / "w")
    defaults = tmp_path / "home/.colcon/defaults.yaml"
    defaults.parent.mkdir(parents=True)
    defaults.write_text("build:\n  symlink-install: true\n  mixin:\n    - release\n")
    planned = espdock("build", "--dry-run", cwd=root, env={**NO_ENGINE, "HOME": str(tmp_path / "home")})
    said = " ".join((planned.stdout + planned.stderr).split())
    assert planned.returncode == 0, said
    assert f"warning: {defaults} names colcon mixins, which the build image's colcon does not have" in said
    defaults.write_text("build:\n  symlink-install: true\n")
    quiet = espdock("build", "--dry-run", cwd=root, env={**NO_ENGINE, "HOME": str(tmp_path / "home")})
    assert "names colcon mixins" not in quiet.stdout + quiet.stderr


def test_a_tool_s_option_given_without_the_colcon_option_that_passes_it_on_is_refused_naming_it():
    """`espdock build -- -DBUILD_TESTING=OFF`: colcon's argparse took it for a value of espdock's own
    --event-handlers, and said "argument --event-handlers: invalid choice", an option never given."""
    with pytest.raises(ConfigError, match="'-DBUILD_TESTING=OFF' after `--` is no colcon option") as err:
        check_colcon_args(("--packages-skip", "a", "-DBUILD_TESTING=OFF"))
    assert "`espdock build -- --cmake-args -DBUILD_TESTING=OFF`" in err.value.hint
    assert check_colcon_args(("--cmake-args", "-DX=1", "-DY=2", "--ctest-args", "-E", "lint")) == (
        "--cmake-args", "-DX=1", "-DY=2", "--ctest-args", "-E", "lint",
    )  # fmt: skip


def test_what_espdock_controls_is_refused_in_a_defaults_file_in_any_yaml_style_and_abbreviated(tmp_path):
    """`test: {test-result-base: x}` (flow style) or JSON got past the check, which read each line's
    first key, and a failing test passed; `-- --t=DIR` is colcon's --test-result-base as well."""
    from espdock.ros.colcon import check_defaults

    for text in (
        "test: {test-result-base: x}\n",
        '{"build": {"merge-install": true}}\n',
        "build:\n  {a: 1, log-base: y}\n",
    ):
        with pytest.raises(ConfigError, match=r"defaults\.yaml sets (test-result-base|merge-install|log-base)"):
            check_defaults("defaults.yaml", text)
    check_defaults("defaults.yaml", "build: {symlink-install: true, cmake-args: [-DX=1]}\n")
    with pytest.raises(ConfigError, match=r"--t \(--test-result-base\) is not allowed"):
        check_colcon_args(("--t=/tmp/x",))


def test_an_older_espdock_s_packages_keep_the_install_kind_its_options_said_once_a_build_records_kinds(tmp_path):
    """A workspace an older espdock built with --symlink-install (its options its only record): the
    first build of one package recorded that one's kind and the options anew, and the next build
    took the others for copies, built them in place, and failed on an interface package."""
    from espdock.ros.trees import install_kind_switched, record_build_args, record_install_kinds

    for name in ("msgs", "app"):
        (tmp_path / name).mkdir()
    record_build_args(tmp_path, ("--symlink-install",))  # as the older espdock left it
    record_install_kinds(tmp_path, ["app"], ())  # `espdock build app`, copies
    record_build_args(tmp_path, ())
    assert install_kind_switched(tmp_path, ["msgs", "app"], ()) == ["msgs"]


def test_a_second_double_dash_or_a_passing_option_abbreviated_as_colcon_takes_it():
    """`-- --cmake-args -DX=1 -- --symlink-install`: espdock removed the switched install prefixes,
    then colcon refused the second `--`; `--cmake-arg -DX=1` is colcon's --cmake-args."""
    with pytest.raises(ConfigError, match="a second `--`"):
        check_colcon_args(("--cmake-args", "-DX=1", "--", "--symlink-install"))
    assert check_colcon_args(("--cmake-arg", "-DX=1")) == ("--cmake-arg", "-DX=1")


def test_colcon_s_rerun_of_what_failed_is_refused_naming_the_way_that_works():
    """`-- --packages-select-test-failures`, a CI habit, was refused as any selection: the way
    that does work, `--packages-skip-test-passed`, went unsaid."""
    with pytest.raises(ConfigError) as refused:
        check_colcon_args(["--packages-select-test-failures"], "test")
    assert "`espdock test -- --packages-skip-test-passed`" in str(refused.value)
    with pytest.raises(ConfigError) as refused:
        check_colcon_args(["--packages-select-build-failed"])
    assert "--packages-skip-build-finished" in str(refused.value)
    assert check_colcon_args(["--packages-skip-test-passed"], "test") == ("--packages-skip-test-passed",)


def test_a_killed_build_or_compiler_is_named_with_how_to_build_with_less_memory():
    """The OOM killer (or `docker kill`) ending the colcon container was "colcon build failed
    (exit code 137) in no package", with `--continue-on-error` for a hint; a compiler it killed
    was "its own build failed: fix it". A machine of little memory had no way to compile less
    at once: MAKEFLAGS stayed on the host."""
    states = {"msgs": PackageState.BUILT, "app": PackageState.NOT_PROCESSED}
    killed = explain_failure(137, states, {}, ())
    assert killed.message.startswith("colcon build was killed (exit code 137, SIGKILL) before any package failed")
    assert "OOM killer" in killed.hint and "MAKEFLAGS=-j2 espdock build" in killed.hint
    assert "--continue-on-error" not in killed.hint
    output = "c++: fatal error: Killed signal terminated program cc1plus\ncompilation terminated.\n"
    compiler = explain_failure(2, {"app": PackageState.FAILED}, {"app": (Path("/l/a.log"), output)}, ())
    assert "app: its compiler was killed (out of memory?)" in compiler.message
    assert "Fix app" not in compiler.hint and "--parallel-workers 1" in compiler.hint
    from espdock.ros.colcon import make_jobs

    assert make_jobs({"MAKEFLAGS": "-j2 -l3 --jobs=4 -k CXXFLAGS=-O0 --load-average=2.5"}) == (
        "-j2 -l3 --jobs=4 --load-average=2.5"
    )
    assert make_jobs({"MAKEFLAGS": "-k"}) is None and make_jobs({}) is None
