"""espdock installed from a wheel, in workspaces that are not this repository: a new one
(`espdock init`, `espdock new`, `espdock build`) and an existing colcon workspace.

Real engine and ROS side; the firmware builds against the IDF contract double (see
tests/idf_contract_double), selected with the settings use_double returns.
"""

from __future__ import annotations

import grp
import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

from espdock.config import Config, resolve_ca_bundle
from espdock.layout import firmware_install_dir
from tests.conftest import REPO, as_user, espdock, message_package, owners, user_env
from tests.idf_contract_double.build import use_double

pytestmark = [pytest.mark.engine, pytest.mark.slow]

USER_UID = 4244  # a plain user in the docker group


@pytest.fixture(scope="module")
def run_as_user(shared_dir: Path, wheel_espdock: Path):
    docker_gid = grp.getgrnam("docker").gr_gid
    home = shared_dir / "home"
    env = user_env(home)
    subprocess.run(["chown", f"{USER_UID}:{USER_UID}", str(home)], check=True)

    def run(*args: str, cwd: Path, extra: dict[str, str] | None = None) -> subprocess.CompletedProcess:
        return espdock(*args, cwd=cwd, env={**env, **(extra or {})},
                       prefix=as_user(USER_UID, USER_UID, [docker_gid], wheel_espdock))  # fmt: skip

    return run


@pytest.fixture(scope="module")
def double_for(engine):
    def settings(root: Path) -> dict[str, str]:
        (root / "docker/idf").mkdir(parents=True, exist_ok=True)
        env = use_double(engine, resolve_ca_bundle(Config(), os.environ), lambda line: None, root)
        subprocess.run(["chown", "-R", f"{USER_UID}:{USER_UID}", str(root / "docker")], check=True)
        return env

    return settings


def test_the_wheel_carries_the_workspace_defaults(wheel_espdock: Path, shared_dir: Path):
    # cwd outside the checkout, whose espdock/ would otherwise be imported instead.
    listing = subprocess.run([str(wheel_espdock.with_name("python")), "-c",
                              "from espdock.defaults import defaults_root; print(defaults_root())"],
                             capture_output=True, text=True, check=True, cwd=shared_dir)  # fmt: skip
    root = Path(listing.stdout.strip())
    assert root.name == "workspace_defaults" and "site-packages" in str(root)
    for rel in ("Dockerfile.ros", "Dockerfile.idf", "docker/ros-build.txt", "docker/idf/micro_ros_sources.txt",
                "firmware/components/espdock_uros/espdock_uros.c"):  # fmt: skip
        assert (root / rel).read_bytes() == (REPO / rel).read_bytes(), rel


def test_a_new_workspace_from_init_to_installed_firmware(shared_dir, run_as_user, double_for, engine):
    # A colon and a comma: the engine's short mount syntax splits at both.
    parent = shared_dir / "robots:2026-11, old"
    parent.mkdir()
    subprocess.run(["chown", f"{USER_UID}:{USER_UID}", str(parent)], check=True)
    init = run_as_user("init", "myrobot", cwd=parent)
    assert init.returncode == 0, init.stdout + init.stderr
    root = parent / "myrobot"
    made = sorted(p.name for p in root.iterdir())
    assert made == [".gitattributes", ".gitignore", "compose.yaml", "espdock.toml", "src"]
    assert (root / ".gitignore").stat().st_uid == USER_UID
    message_package(root / "src/custom_interface")
    subprocess.run(["chown", "-R", f"{USER_UID}:{USER_UID}", str(root / "src")], check=True)
    new = run_as_user("new", "my_board", "--depends", "custom_interface", cwd=root)
    assert new.returncode == 0, new.stdout + new.stderr
    env = double_for(root)
    try:
        build = run_as_user("build", cwd=root, extra=env)
        assert build.returncode == 0, build.stdout[-4000:] + build.stderr
        assert "Dockerfile.ros: espdock's default" in run_as_user("build", "--dry-run", cwd=root, extra=env).stdout
        installed = root / firmware_install_dir("my_board")
        assert json.loads((installed / "flasher_args.json").read_text())["extra_esptool_args"]["chip"] == "esp32"
        assert (root / "install/custom_interface/share/custom_interface/msg/CameraConfig.msg").is_file()
        assert owners(root) == {USER_UID}
    finally:
        engine.remove_containers({"io.espdock.workspace": str(root)})


def test_an_existing_colcon_workspace_with_firmware_deep_in_src(shared_dir, run_as_user, double_for, engine):
    root = shared_dir / "ros2_ws"
    (root / "src").mkdir(parents=True)
    message_package(root / "src/interfaces/my_msgs", "my_msgs")
    py = root / "src/my_py"
    (py / "resource").mkdir(parents=True)
    (py / "my_py").mkdir()
    (py / "my_py/__init__.py").write_text("")
    (py / "resource/my_py").write_text("")
    (py / "setup.py").write_text(
        "from setuptools import setup\nsetup(name='my_py', version='0.1.0', packages=['my_py'], data_files=["
        "('share/ament_index/resource_index/packages', ['resource/my_py']), ('share/my_py', ['package.xml'])])\n"
    )
    (py / "package.xml").write_text(
        (REPO / "ws/src/espdock_demo_testing/package.xml").read_text().replace("espdock_demo_testing", "my_py")
        .replace("<exec_depend>espdock_demo</exec_depend>", "").replace("custom_interface", "my_msgs")
    )  # fmt: skip
    subprocess.run(["chown", "-R", f"{USER_UID}:{USER_UID}", str(root)], check=True)
    init = run_as_user("init", cwd=root)
    assert init.returncode == 0, init.stdout + init.stderr
    assert "found 2 ROS package(s): my_msgs, my_py" in init.stdout
    new = run_as_user("new", "my_cam", "--depends", "my_msgs", cwd=root)
    assert new.returncode == 0, new.stdout + new.stderr
    # Two folders deep, with its shared component beside it.
    (root / "src/boards/esp").mkdir(parents=True)
    for name in ("my_cam", "components"):
        (root / "src" / name).rename(root / "src/boards/esp" / name)
    subprocess.run(["chown", "-R", f"{USER_UID}:{USER_UID}", str(root / "src/boards")], check=True)
    env = double_for(root)
    try:
        listing = run_as_user("list", cwd=root / "src")
        assert "my_cam" in listing.stdout and "esp_idf" in listing.stdout
        build = run_as_user("build", "my_cam", cwd=root, extra=env)
        assert build.returncode == 0, build.stdout[-4000:] + build.stderr
        # Only what my_cam needs: my_msgs, not my_py; colcon's outputs in the workspace root.
        assert (root / "install/my_msgs").is_dir() and not (root / "install/my_py").exists()
        assert (root / firmware_install_dir("my_cam") / "flasher_args.json").is_file()
        assert (root / "build/my_cam").is_dir() and (root / "log").is_dir()
        assert owners(root) == {USER_UID}
    finally:
        engine.remove_containers({"io.espdock.workspace": str(root)})


def test_a_uid_with_no_passwd_entry_and_no_home_is_told_to_set_home(shared_dir, wheel_espdock):
    """`env -i` as a uid /etc/passwd lacks (a CI runner's or OpenShift's random uid): exit 70,
    "a bug in espdock" (RuntimeError: Could not determine home directory.) at nearly every command."""
    uid = 123457
    root = shared_dir / "random-uid"
    (root / "src").mkdir(parents=True)
    shutil.copytree(REPO / "tests/ros_packages/beacon_nodes", root / "src/beacon_nodes")
    (root / "espdock.toml").write_text("[espdock]\n")
    subprocess.run(["chown", "-R", f"{uid}:{uid}", str(root)], check=True)
    *setpriv, command = as_user(uid, uid, [], wheel_espdock)
    listed = espdock("list", cwd=root, prefix=(*setpriv, "env", "-u", "HOME", command))
    assert listed.returncode == 2, listed.stdout + listed.stderr
    assert f"HOME is not set and uid {uid} has no entry in /etc/passwd" in listed.stderr
    assert "Set HOME to a directory of yours" in listed.stderr
    listed = espdock("list", cwd=root, env={"HOME": str(root / "home")}, prefix=(*setpriv, command))
    assert listed.returncode == 0 and "beacon_nodes" in listed.stdout, listed.stderr


def test_espdock_run_in_a_directory_the_user_may_not_look_into_says_so(shared_dir, wheel_espdock):
    """`cd /root && runuser -u builder -- espdock list` (cron, `sudo -u`): exit 70, "a bug in
    espdock" (PermissionError: '/root/espdock.toml')."""
    barred = shared_dir / "root-only"
    barred.mkdir(mode=0o700)
    listed = espdock(
        "list", cwd=barred, env=user_env(shared_dir / "home"), prefix=as_user(USER_UID, USER_UID, [], wheel_espdock)
    )
    assert listed.returncode == 2, listed.stdout + listed.stderr
    said = " ".join(listed.stderr.split())
    assert f"not inside an espdock workspace: no espdock.toml in {barred} or any parent" in said, said
    assert f"you may not look into {barred}" in said, said


def test_a_user_who_may_not_use_the_engine_s_socket_is_told_to_join_its_group(shared_dir, wheel_espdock):
    """Not in the docker group, with the engine running: the hint began "Start Docker (`sudo
    systemctl start docker`)"."""
    home = shared_dir / "outsider"
    home.mkdir()
    subprocess.run(["chown", f"{USER_UID + 1}:{USER_UID + 1}", str(home)], check=True)
    refused = espdock(
        "setup", cwd=home, env=user_env(home), prefix=as_user(USER_UID + 1, USER_UID + 1, [], wheel_espdock)
    )
    assert refused.returncode == 3, refused.stdout + refused.stderr
    said = " ".join(refused.stderr.split())
    assert "permission denied on the engine's socket" in said and "Start Docker" not in said, said
    assert "join the group that owns it (the docker group, for Docker's: `sudo usermod -aG docker $USER`" in said


def test_a_workspace_a_team_shares_through_its_group_rebuilds_for_each_member(shared_dir, wheel_espdock):
    """A setgid directory of a team's group, umask 002, the group each member's supplementary one:
    the containers ran with the primary group alone (and wrote 0755), so the second member's build
    was refused on log/ ("give it back: sudo chown"), which the first member owns."""
    docker_gid, team = grp.getgrnam("docker").gr_gid, 4300
    root = shared_dir / "team"
    (root / "src").mkdir(parents=True)
    shutil.copytree(REPO / "tests/ros_packages/beacon_nodes", root / "src/beacon_nodes")
    (root / "espdock.toml").write_text("[espdock]\n")
    for directory, dirnames, filenames in os.walk(root):
        for name in (".", *dirnames, *filenames):
            os.chown(os.path.join(directory, name), USER_UID, team)
        os.chmod(directory, 0o2775)
    subprocess.run(["chmod", "-R", "g+w", str(root)], check=True)
    homes = {}
    for uid in (USER_UID, USER_UID + 2):
        homes[uid] = shared_dir / f"home-{uid}"
        homes[uid].mkdir()
        os.chown(homes[uid], uid, uid)

    def build_as(uid: int) -> subprocess.CompletedProcess:
        *setpriv, command = as_user(uid, uid, [docker_gid, team], wheel_espdock)
        return espdock("build", cwd=root, env=user_env(homes[uid]),
                       prefix=(*setpriv, "sh", "-c", 'umask 002 && exec "$@"', "sh", command))  # fmt: skip

    first = build_as(USER_UID)
    assert first.returncode == 0, first.stdout[-3000:] + first.stderr
    node = root / "src/beacon_nodes/beacon_nodes/beacon.py"
    node.write_text(node.read_text() + "# a teammate's edit\n")
    second = build_as(USER_UID + 2)
    assert second.returncode == 0, second.stdout[-3000:] + second.stderr
    assert "1 package(s) built" in second.stdout
