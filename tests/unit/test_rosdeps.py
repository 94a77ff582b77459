"""package.xml dependencies: what the ROS image provides, rosdep's resolution (the real rosdep,
on the tests' database of real rules), rosdep.lock.json, and the check before colcon."""

import json
import shutil
from pathlib import Path

import pytest

from espdock import downloads
from espdock.config import Config
from espdock.errors import DependencyError, LockError
from espdock.ros import rosdeps
from espdock.ros.plan import ros_build_image, ros_image
from espdock.workspace import Package, PackageKind, Workspace, discover_packages, order_packages, read_build_inputs
from tests.conftest import REPO, espdock
from tests.rosdep_db import environment

PACKAGES = REPO / "tests" / "ros_packages"
NO_ENGINE = {"DOCKER_HOST": "unix:///nonexistent/docker.sock"}
WHEELS = rosdeps.RosImage("wheels", "jazzy", "debian:bookworm", frozenset({"rclpy", "std_msgs"}))


def package(name: str, depends: set[str], test_only: set[str] = frozenset()) -> Package:
    return Package(
        name, Path(f"/ws/src/{name}"), PackageKind.ROS, "ament_python", frozenset(depends | test_only),
        test_only_depends=frozenset(test_only),
    )  # fmt: skip


def make_workspace(root: Path, *names: str, toml: str = "") -> Path:
    (root / "src").mkdir(parents=True)
    for name in names:
        shutil.copytree(PACKAGES / name, root / "src" / name)
    (root / "espdock.toml").write_text(f"[espdock]\n{toml}")
    return root


def test_the_wheels_image_provides_the_ros_packages_its_locks_install():
    texts = [(REPO / "docker" / name).read_text() for name in ("ros-runtime.txt", "ros-build.txt")]
    provided = rosdeps.wheel_packages(texts, "jazzy")
    # ros-jazzy-rclpy and the unversioned ros-std-msgs wheels alike; no PyPI family has rclcpp.
    assert {"rclpy", "std_msgs", "sensor_msgs", "ament_cmake", "rosidl_default_generators"} <= provided
    assert not {"rclcpp", "launch", "sensor_msgs_py", "numpy"} & provided


def test_needed_keys_leave_out_workspace_packages_what_the_image_has_and_test_only_ones():
    packages = (
        package("msgs", {"rosidl_default_generators"}),
        package("node", {"msgs", "rclpy", "python3-numpy", "tinyxml2"}, test_only={"python3-pytest"}),
        package("quiet", {"rclpy"}),
    )
    image = rosdeps.RosImage("wheels", "jazzy", "debian:bookworm", frozenset({"rclpy", "rosidl_default_generators"}))
    assert rosdeps.needed_keys(packages, image) == {"node": ("python3-numpy", "tinyxml2")}


def test_a_lock_is_stale_when_a_key_the_image_or_its_locks_change():
    needed = {"node": ("tinyxml2",)}
    lock = {"format": rosdeps.FORMAT, "input": rosdeps.lock_input(needed, WHEELS)}
    assert rosdeps.stale_reason(lock, needed, WHEELS, "rosdep.lock.json") is None
    assert rosdeps.stale_reason(None, {}, WHEELS, "rosdep.lock.json") is None  # nothing needed: no lock needed
    assert rosdeps.stale_reason(None, needed, WHEELS, "rosdep.lock.json") == "rosdep.lock.json is missing"
    official = rosdeps.RosImage("official", "jazzy", "ubuntu:noble", frozenset())
    newer = rosdeps.RosImage("wheels", "jazzy", "debian:bookworm", WHEELS.provided, (("docker/ros-runtime.txt", "x"),))
    for changed_needed, image in (({"node": ("tinyxml2", "acpitool")}, WHEELS), (needed, official), (needed, newer)):
        assert "is stale" in rosdeps.stale_reason(lock, changed_needed, image, "rosdep.lock.json")
    # What changed, where the lock says what it answered for (a CI log then tells which package.xml).
    made = {**lock, "packages": needed, "ros_image": "wheels", "os": "debian:bookworm", "ros_distro": "jazzy"}
    said = rosdeps.stale_reason(made, {"node": ("acpitool",), "app": ("tinyxml2",)}, WHEELS, "rosdep.lock.json")
    assert said == (
        "rosdep.lock.json is stale: since it was made, app now depends on tinyxml2; node now depends on "
        "acpitool; node no longer depends on tinyxml2"
    )
    # A package left out (COLCON_IGNORE), removed or renamed is not one whose dependencies changed.
    said = rosdeps.stale_reason(made, {}, WHEELS, "rosdep.lock.json", present=["other"])
    assert said == "rosdep.lock.json is stale: since it was made, node is no package of the workspace now"
    assert "node no longer depends on tinyxml2" in rosdeps.stale_reason(made, {}, WHEELS, "x", present=["node"])
    said = rosdeps.stale_reason(made, needed, official, "rosdep.lock.json")
    assert said == (
        "rosdep.lock.json is stale: since it was made, ros_image is official, not wheels; "
        "os is ubuntu:noble, not debian:bookworm"
    )
    assert "its locks changed" in rosdeps.stale_reason(made, needed, newer, "rosdep.lock.json")


def test_a_lock_without_the_test_keys_names_them_and_whether_the_file_exists():
    """`CI=true espdock test` in a workspace with no lock said "rosdep.lock.json has no test
    dependencies recorded", of a file that did not exist, naming no key."""
    from espdock.ros import testdeps

    packages = (package("alpha", {"rclpy"}, test_only={"python3-pytest"}), package("quiet", {"rclpy"}))
    said = testdeps.stale_reason(None, packages, WHEELS, "rosdep.lock.json")
    assert said == "rosdep.lock.json is missing: alpha's tests need python3-pytest"
    no_part = testdeps.stale_reason({"format": rosdeps.FORMAT}, packages, WHEELS, "rosdep.lock.json")
    assert no_part == "rosdep.lock.json records no test dependencies: alpha's tests need python3-pytest"
    assert testdeps.stale_reason(None, packages[1:], WHEELS, "rosdep.lock.json") is None


def test_the_check_lists_each_package_with_its_missing_keys_and_the_ways_out():
    packages = (package("a", {"rclcpp"}), package("b", {"tinyxml2"}), package("c", {"rclcpp", "nope"}))
    needed = {"a": ("rclcpp",), "b": ("tinyxml2",), "c": ("nope", "rclcpp")}
    lock = {
        "keys": {
            "rclcpp": {"installer": None, "why": "PyPI has no ros-jazzy-rclcpp"},
            "tinyxml2": {"installer": "apt", "packages": ["libtinyxml2-dev"]},
            "nope": {"installer": None, "why": "no rosdep rule for this key"},
        }
    }
    with pytest.raises(DependencyError) as caught:
        rosdeps.check_dependencies(packages, needed, lock, WHEELS)
    lines = caught.value.message.splitlines()
    assert lines[1:] == [
        "  a (/ws/src/a): rclcpp: PyPI has no ros-jazzy-rclcpp",
        "  c (/ws/src/c): nope: no rosdep rule for this key; rclcpp: PyPI has no ros-jazzy-rclcpp",
    ]
    assert "debian:bookworm" in lines[0]
    for way in ("rosdep rule", 'ros_image = "official"', "COLCON_IGNORE", "another selection"):
        assert way in caught.value.hint
    rosdeps.check_dependencies(packages[1:2], needed, lock, WHEELS)  # b alone is fine
    # A key rosdep knows nowhere: the official image would not know it either.
    lock["keys"]["nope"]["why"] = rosdeps.UNKNOWN_KEY
    with pytest.raises(DependencyError) as caught:
        rosdeps.check_dependencies(packages[2:], {"c": ("nope",)}, lock, WHEELS)
    assert "official" not in caught.value.hint and "rosdep rule" in caught.value.hint


def test_a_key_the_lock_has_never_seen_names_the_stale_lock_not_rosdep():
    """A typo fixed in package.xml (python3-serail -> python3-serial), then `espdock run`: "not
    resolved", with ways out about rosdep rules and the official image, where `espdock lock` was it."""
    lock = {"keys": {"python3-serail": {"installer": None, "why": rosdeps.UNKNOWN_KEY}}}
    with pytest.raises(DependencyError) as caught:
        rosdeps.check_dependencies((package("a", {"python3-serial"}),), {"a": ("python3-serial",)}, lock, WHEELS)
    assert caught.value.message.splitlines() == [
        "rosdep.lock.json is older than the package.xml files:",
        "  a (/ws/src/a): python3-serial: not in the lock",
    ]
    assert "`espdock lock`" in caught.value.hint and "official" not in caught.value.hint
    # No lock at all (`espdock run` in a fresh clone) is said as such, not as one behind the manifests.
    with pytest.raises(DependencyError) as caught:
        rosdeps.check_dependencies((package("a", {"python3-serial"}),), {"a": ("python3-serial",)}, None, WHEELS)
    assert caught.value.message.splitlines()[0] == "rosdep.lock.json is missing:"


def test_python_keys_become_pip_in_the_wheels_venv_and_ros_keys_their_wheels():
    rules = {
        "python3-numpy": rosdeps.Rule("apt", ("python3-numpy",)),
        "python3-tabulate": rosdeps.Rule("apt", ("python3-tabulate",)),
        "rclcpp": rosdeps.Rule("apt", ("ros-jazzy-rclcpp",)),
        "tinyxml2": rosdeps.Rule("apt", ("libtinyxml2-dev",)),
        # rosdistro's python3-yaml: apt everywhere but osx, where pip installs pyyaml.
        "python3-yaml": rosdeps.Rule("apt", ("python3-yaml",), pip_elsewhere=("pyyaml",)),
    }
    pip_rules = {"python3-tabulate": rosdeps.Rule("pip", ("tabulate",))}
    mapped = rosdeps.for_image(rules, WHEELS, pip_rules)
    assert {k: (r.installer, r.packages) for k, r in mapped.items()} == {
        "python3-numpy": ("pip", ("numpy",)),
        "python3-tabulate": ("pip", ("tabulate",)),
        "rclcpp": ("pip", ("ros-jazzy-rclcpp",)),
        "tinyxml2": ("apt", ("libtinyxml2-dev",)),
        "python3-yaml": ("pip", ("pyyaml",)),
    }
    official = rosdeps.RosImage("official", "jazzy", "ubuntu:noble", frozenset())
    assert rosdeps.for_image(rules, official, pip_rules) == rules  # system Python sees apt's packages


def test_the_image_installs_only_debian_package_names_from_the_lock():
    files = rosdeps.image_files({"apt": ["libtinyxml2-dev"], "pip": ["tabulate==0.10.0 --hash=sha256:ab"]})
    assert files["apt.txt"].decode().splitlines()[1:] == ["libtinyxml2-dev"]
    assert files["pip.txt"].decode().splitlines()[1:] == ["tabulate==0.10.0 --hash=sha256:ab"]
    with pytest.raises(LockError, match="no Debian package names"):
        rosdeps.image_files({"apt": ["-o=APT::Get::AllowUnauthenticated=1"]})


def test_the_real_rosdep_resolves_the_rules_for_each_image_os(tmp_path, monkeypatch):
    env = environment(tmp_path)
    for name, value in env.items():
        monkeypatch.setenv(name, value)
    keys = [
        "tinyxml2",
        "python-tabulate-pip",
        "acpitool",
        "fswebcam",
        "rclcpp",
        "no_such_key",
        "espdock_test_satisfied",
    ]
    debian = rosdeps.rosdep_rules(keys, "debian:bookworm", "jazzy", env)
    ubuntu = rosdeps.rosdep_rules(keys, "ubuntu:noble", "jazzy", env)

    def answer(rule: rosdeps.Rule) -> tuple:
        return rule.installer, rule.packages

    assert answer(debian["tinyxml2"]) == answer(ubuntu["tinyxml2"]) == ("apt", ("libtinyxml2-dev",))
    assert answer(debian["python-tabulate-pip"]) == ("pip", ("tabulate",))
    # ROS packages come from the rosdistro distribution file, as ros-<distro>-<name>.
    assert answer(ubuntu["rclcpp"]) == ("apt", ("ros-jazzy-rclcpp",))
    # acpitool has a Debian rule only, fswebcam an Ubuntu one only.
    assert debian["acpitool"].installer == "apt" and ubuntu["acpitool"].installer is None
    assert "ubuntu:noble" in ubuntu["acpitool"].why
    assert ubuntu["fswebcam"].installer == "apt" and debian["fswebcam"].installer is None
    assert "unknown" in debian["no_such_key"].why
    # An empty list is rosdep's "nothing to install": satisfied, on the image as it is. It was refused
    # ("installs nothing") after the build's own hint had said to add a rule.
    assert answer(debian["espdock_test_satisfied"]) == ("apt", ())
    wheels = rosdeps.RosImage("wheels", "jazzy", "debian:bookworm", frozenset())
    assert answer(rosdeps.for_image(debian, wheels, {})["espdock_test_satisfied"]) == ("apt", ())
    assert rosdeps.database_age(env) is not None


def test_official_flavour_builds_from_its_own_dockerfile_and_resolves_for_ubuntu(tmp_path):
    root = make_workspace(tmp_path / "w", "rosdeps_py_table")
    workspace = Workspace(root).with_layout(None, None)
    packages = order_packages(discover_packages(workspace))
    inputs = read_build_inputs(workspace, packages)
    name, text, image = ros_image(Config(ros_image="official"), inputs)
    assert (name, image.os, image.provided) == ("Dockerfile.ros-official", "ubuntu:noble", frozenset())
    assert "ARG BASE_IMAGE=ros:jazzy-ros-base" in text
    # The official image has every ROS package rosdep names; the wheels one only what its locks install.
    assert rosdeps.needed_keys(packages, image)["rosdeps_py_table"] == (
        "python-tabulate-pip", "python3-numpy", "python3-setuptools", "rclpy", "std_msgs",
    )  # fmt: skip
    _, _, wheels = ros_image(Config(), inputs)
    assert rosdeps.needed_keys(packages, wheels) == {
        "rosdeps_py_table": ("python-tabulate-pip", "python3-numpy", "python3-setuptools")
    }


def test_the_setting_is_checked_where_it_is_read(tmp_path):
    root = make_workspace(tmp_path / "w", toml='ros_image = "docker"\n')
    result = espdock("build", "--dry-run", cwd=root, env=NO_ENGINE)
    assert result.returncode == 2
    assert "ros_image" in result.stderr and "wheels, official" in result.stderr
    (root / "espdock.toml").write_text("[espdock]\n")
    result = espdock("build", "--dry-run", cwd=root, env={**NO_ENGINE, "ESPDOCK_ROS_IMAGE": "ros2"})
    assert result.returncode == 2 and "ESPDOCK_ROS_IMAGE" in result.stderr


def run_build(root: Path, tmp_path: Path, *args: str, **extra: str):
    return espdock("build", *args, cwd=root, env={**NO_ENGINE, **environment(tmp_path), **extra})


def test_an_rclcpp_package_on_the_wheels_image_is_refused_before_anything_builds(tmp_path):
    root = make_workspace(tmp_path / "w", "rosdeps_cpp_talker", "rosdeps_xml_count")
    result = run_build(root, tmp_path)
    # Refused before the engine is asked for (there is none at DOCKER_HOST): exit 2, not 3.
    assert result.returncode == 2, result.stderr
    lines = [line for line in result.stderr.splitlines() if line.startswith("  ")]
    assert lines == [f"  rosdeps_cpp_talker ({root}/src/rosdeps_cpp_talker): rclcpp: PyPI has no ros-jazzy-rclcpp"]
    assert 'ros_image = "official"' in result.stderr and "COLCON_IGNORE" in result.stderr
    assert not (root / "build").exists() and not (root / "install").exists()
    # Nor a lock: one written would say rclcpp is served by nothing, for a build that did not run.
    assert "rosdep.lock.json not written (it would leave rclcpp unresolved; `espdock lock` writes it so" in " ".join(
        result.stdout.split()
    ), result.stdout
    assert not (root / "rosdep.lock.json").exists()
    # Another selection, without the C++ node, passes the check (and then needs the engine); it
    # writes no lock either, which would name rclcpp as served by nothing.
    assert run_build(root, tmp_path, "rosdeps_xml_count").returncode == 3
    assert not (root / "rosdep.lock.json").exists()
    # `espdock lock` records the key nothing serves, and says so (it said nothing).
    locked = espdock("lock", cwd=root, env={**NO_ENGINE, **environment(tmp_path)})
    assert locked.returncode == 0, locked.stderr
    said = " ".join(locked.stderr.split())
    assert "warning: rclcpp: PyPI has no ros-jazzy-rclcpp; a build needing it is refused" in said, said
    lock = json.loads((root / "rosdep.lock.json").read_text())
    assert lock["keys"]["tinyxml2"] == {"installer": "apt", "packages": ["libtinyxml2-dev"]}
    assert run_build(root, tmp_path, "rosdeps_xml_count").returncode == 3  # the lock answers for it


@pytest.mark.parametrize(
    ("key", "flavour", "os_name", "why"),
    [
        ("no_such_key", "wheels", "debian:bookworm", "no rosdep rule: the key is unknown to rosdep's database"),
        ("fswebcam", "wheels", "debian:bookworm", "no rosdep rule for debian:bookworm"),
        ("acpitool", "official", "ubuntu:noble", "no rosdep rule for ubuntu:noble"),
    ],
)
def test_a_key_with_no_rule_for_the_image_os_names_package_key_and_os(tmp_path, key, flavour, os_name, why):
    root = make_workspace(tmp_path / "w", "rosdeps_xml_count")
    manifest = root / "src/rosdeps_xml_count/package.xml"
    manifest.write_text(manifest.read_text().replace("<depend>tinyxml2</depend>", f"<depend>{key}</depend>"))
    result = run_build(root, tmp_path, ESPDOCK_ROS_IMAGE=flavour)
    assert result.returncode == 2, result.stderr
    assert f"rosdeps_xml_count ({manifest.parent}): {key}: {why}" in result.stderr
    assert os_name in result.stderr
    assert not (root / "build").exists()


def test_a_misspelt_dependency_is_named_with_the_key_or_workspace_package_it_is_most_like(tmp_path):
    """`<depend>std_msg</depend>` was "no rosdep rule: the key is unknown", its first way out a
    rosdep rule of one's own, where `espdock run` offers the executable meant; a workspace
    package's name misspelt, the same."""
    root = make_workspace(tmp_path / "w", "rosdeps_xml_count", "rosdeps_py_table")
    manifest = root / "src/rosdeps_xml_count/package.xml"
    manifest.write_text(
        manifest.read_text().replace(
            "<depend>tinyxml2</depend>",
            "<depend>tinyxml2</depend>\n  <depend>std_msg</depend>\n  <exec_depend>rosdeps_py_tabel</exec_depend>",
        )
    )
    unknown = "no rosdep rule: the key is unknown to rosdep's database"
    refused = run_build(root, tmp_path)
    said = " ".join(refused.stderr.split())
    assert refused.returncode == 2, said
    assert f"std_msg: {unknown} (did you mean std_msgs?)" in said, said
    assert f"rosdeps_py_tabel: {unknown} (did you mean rosdeps_py_table?)" in said, said
    assert "hint: Ways out: correct the name in the package.xml where it is misspelt; or add a rosdep rule" in said
    # A key rosdep knows nothing like is said as before.
    manifest.write_text(manifest.read_text().replace("std_msg<", "acme_lidar_sdk<"))
    locked = espdock("lock", cwd=root, env={**NO_ENGINE, **environment(tmp_path)})
    said = " ".join(locked.stderr.split())
    assert locked.returncode == 0, said
    assert f"warning: acme_lidar_sdk: {unknown}; a build needing it is refused" in said, said
    assert f"warning: rosdeps_py_tabel: {unknown} (did you mean rosdeps_py_table?); a build" in said, said


def test_lock_where_rosdeps_cache_cannot_be_written_names_the_cache_not_the_network(tmp_path):
    """A read-only HOME (XDG_CACHE_HOME unset): `espdock lock` said "`rosdep update` failed:
    [Errno 30] Read-only file system" with the hint to reach rosdep's sources on GitHub. Here the
    cache's parent is a file, which even root cannot write under."""
    root = make_workspace(tmp_path / "w", "rosdeps_xml_count")
    blocked = tmp_path / "home-cache"
    blocked.write_text("")
    locked = espdock("lock", cwd=root, env={**NO_ENGINE, **environment(tmp_path), "XDG_CACHE_HOME": str(blocked)})
    said = " ".join(locked.stderr.split())
    assert locked.returncode == 2, said
    assert f"espdock cannot keep rosdep's database in {blocked}/" in said, said
    assert f"Make {blocked}/espdock" in said and "set XDG_CACHE_HOME to a directory you can write" in said, said
    assert "GitHub" not in said and "Traceback" not in said, said
    assert not (root / "rosdep.lock.json").exists()
    # A build that needs the lock made refuses with the same words, and then `espdock lock`.
    built = run_build(root, tmp_path, XDG_CACHE_HOME=str(blocked))
    said = " ".join(built.stderr.split())
    assert built.returncode == 2, said
    assert f"espdock cannot keep rosdep's database in {blocked}/" in said, said
    assert "set XDG_CACHE_HOME to a directory you can write. Then run `espdock lock`" in said, said
    assert "Reach rosdep's sources" not in said, said


def test_locked_refuses_a_missing_or_stale_lock_and_lock_refreshes_it(tmp_path):
    root = make_workspace(tmp_path / "w", "rosdeps_xml_count")
    result = run_build(root, tmp_path, "--locked")
    assert result.returncode == 2 and "rosdep.lock.json is missing" in result.stderr
    assert not (root / "rosdep.lock.json").exists()
    made = espdock("lock", cwd=root, env={**NO_ENGINE, **environment(tmp_path)})
    assert made.returncode == 0, made.stderr
    assert "rosdep.lock.json: created (rosdep database in" in made.stdout and "ago)" in made.stdout
    # Said first: uv against an index that does not answer is minutes of silence.
    assert made.stdout.index(
        "rosdep.lock.json: resolving the workspace's dependencies (rosdep; uv"
    ) < made.stdout.index("rosdep.lock.json: created")
    assert run_build(root, tmp_path, "--locked").returncode == 3  # current: on to the engine
    manifest = root / "src/rosdeps_xml_count/package.xml"
    manifest.write_text(manifest.read_text().replace("<depend>tinyxml2</depend>", "<depend>acpitool</depend>"))
    result = run_build(root, tmp_path, "--locked")
    assert result.returncode == 2 and "rosdep.lock.json is stale" in result.stderr, result.stderr
    assert "acpitool" not in (root / "rosdep.lock.json").read_text()
    again = espdock("lock", cwd=root, env={**NO_ENGINE, **environment(tmp_path)})
    assert "rosdep.lock.json: updated" in again.stdout
    assert json.loads((root / "rosdep.lock.json").read_text())["apt"] == ["acpitool"]
    # A teammate's copy of the same rules elsewhere (file:// sources under their home): the same
    # resolution keeps the committed file as it is (it churned, and leaked their paths into git).
    theirs = tmp_path / "teammate"
    shutil.copytree(
        REPO / "tests/rosdep_db", theirs / "rosdep_db", ignore=shutil.ignore_patterns("*.py", "__pycache__")
    )
    (theirs / "sources").mkdir()
    (theirs / "sources/50-team.list").write_text(
        "".join(f"yaml {(theirs / 'rosdep_db' / name).as_uri()}\n" for name in ("base.yaml", "python.yaml"))
    )
    elsewhere = {
        "ROSDEP_SOURCE_PATH": str(theirs / "sources"),
        "ROSDISTRO_INDEX_URL": (theirs / "rosdep_db/rosdistro/index-v4.yaml").as_uri(),
        "XDG_CACHE_HOME": str(theirs / "cache"),
        "CI": "",
    }
    committed = (root / "rosdep.lock.json").read_text()
    relocked = espdock("lock", cwd=root, env={**NO_ENGINE, **elsewhere})
    assert relocked.returncode == 0 and "rosdep.lock.json: unchanged" in relocked.stdout, relocked.stdout
    assert (root / "rosdep.lock.json").read_text() == committed


def test_the_lock_decides_the_image_key_and_the_flavour_its_dockerfile_and_name(tmp_path):
    root = make_workspace(tmp_path / "w", "rosdeps_xml_count")
    workspace = Workspace(root).with_layout(None, None)
    inputs = read_build_inputs(workspace, order_packages(discover_packages(workspace)))
    lock = {"apt": ["libtinyxml2-dev"], "pip": []}
    wheels = ros_build_image(Config(), inputs.ros_dockerfile, inputs.ros_files, rosdep_lock=lock)
    assert wheels.repository == "espdock/ros-jazzy-build"
    context = dict(wheels.context)
    assert context["docker/rosdep/apt.txt"].decode().splitlines()[1:] == ["libtinyxml2-dev"]
    assert "docker/rosdep-install.sh" in context
    other = ros_build_image(
        Config(), inputs.ros_dockerfile, inputs.ros_files, rosdep_lock={**lock, "apt": ["acpitool"]}
    )
    assert other.key != wheels.key
    # No lock: the repository's empty lists, so a workspace without keys keeps one image.
    assert (
        ros_build_image(Config(), inputs.ros_dockerfile, inputs.ros_files).key
        == ros_build_image(Config(), inputs.ros_dockerfile, inputs.ros_files, rosdep_lock={}).key
    )
    official = ros_build_image(
        Config(ros_image="official", base_image="ros:jazzy-ros-base@sha256:" + "0" * 64),
        inputs.ros_official_dockerfile,
        {k: v for k, v in inputs.ros_files.items() if "rosdep" in k},
        rosdep_lock=lock,
        dockerfile="Dockerfile.ros-official",
    )
    assert official.repository == "espdock/ros-jazzy-official-build"
    assert official.dockerfile == "Dockerfile.ros-official" and official.target == "build"
    assert dict(official.build_args)["BASE_IMAGE"].startswith("ros:jazzy-ros-base@sha256:")
    assert sorted(dict(official.context)) == [
        "Dockerfile.ros-official", "docker/rosdep-install.sh", "docker/rosdep/apt.txt", "docker/rosdep/pip.txt",
    ]  # fmt: skip


def test_uv_gets_the_extra_ca_bundle_beside_the_system_s_which_it_reads_from_no_pip_conf(tmp_path, monkeypatch):
    """Behind a TLS-intercepting proxy with pip.conf's `cert` (or ESPDOCK_CA_BUNDLE), `espdock lock`
    failed: "invalid peer certificate: UnknownIssuer", and uv's own hint named a flag espdock passes."""
    extra = tmp_path / "proxy-ca.pem"
    extra.write_text("-----BEGIN CERTIFICATE-----\nproxy\n-----END CERTIFICATE-----\n")
    monkeypatch.delenv("SSL_CERT_FILE", raising=False)
    assert "SSL_CERT_FILE" not in downloads.uv_env(tmp_path)
    bundle = Path(downloads.uv_env(tmp_path, extra)["SSL_CERT_FILE"]).read_text()
    assert bundle.endswith(extra.read_text()) and bundle.count("BEGIN CERTIFICATE") > 1, "the system's CAs too"
    # An SSL_CERT_FILE of the user's (a CI image's, naming the system's bundle): the extra CA joins it.
    own = tmp_path / "own.pem"
    own.write_text("-----BEGIN CERTIFICATE-----\nown\n-----END CERTIFICATE-----\n")
    monkeypatch.setenv("SSL_CERT_FILE", str(own))
    joined = Path(downloads.uv_env(tmp_path, extra)["SSL_CERT_FILE"]).read_text()
    assert joined == own.read_text() + "\n" + extra.read_text()
    assert downloads.uv_env(tmp_path)["SSL_CERT_FILE"] == str(own)


def test_the_keys_a_lock_records_that_nothing_installs_are_listed_with_why():
    """`espdock lock` recorded `launch_ros: installer null` without a word; the user learnt it at build time."""
    lock = {
        "keys": {
            "launch_ros": {"installer": None, "why": "PyPI has no ros-jazzy-launch-ros"},
            "tinyxml2": {"installer": "apt", "packages": ["libtinyxml2-dev"]},
        },
        "test": {"keys": {"ament_lint_auto": {"installer": None, "why": "PyPI has no ros-jazzy-ament-lint-auto"}}},
    }
    assert rosdeps.unserved(lock) == [
        ("launch_ros", "PyPI has no ros-jazzy-launch-ros"),
        ("ament_lint_auto", "PyPI has no ros-jazzy-ament-lint-auto"),
    ]
    assert rosdeps.unserved(None) == []
