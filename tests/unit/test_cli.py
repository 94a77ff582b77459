"""The CLI's answers to bad input; none of these may need (or touch) a container engine."""

from pathlib import Path

from tests.conftest import copy_workspace, espdock

# Any engine use would fail loudly against this address.
NO_ENGINE = {"DOCKER_HOST": "unix:///nonexistent/docker.sock"}


def test_outside_a_workspace_says_where_it_looked(tmp_path):
    result = espdock("build", cwd=tmp_path, env=NO_ENGINE)
    assert result.returncode == 2
    assert f"no espdock.toml in {tmp_path}" in result.stderr
    assert "Traceback" not in result.stderr


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


def test_no_engine_at_docker_host_is_a_clear_error(tmp_path):
    root = copy_workspace(tmp_path / "w")
    result = espdock("build", cwd=root, env=NO_ENGINE)
    assert result.returncode == 3
    assert "no Docker engine answers at unix:///nonexistent/docker.sock" in result.stderr
    assert not (root / "ws/build").exists()


def test_list_shows_packages_in_build_order(tmp_path):
    root = copy_workspace(tmp_path / "w")
    result = espdock("list", cwd=Path(root, "ws/src"), env=NO_ENGINE)
    assert result.returncode == 0
    assert "custom_interface" in result.stdout


def test_monitor_needs_a_terminal_and_says_so(tmp_path):
    root = copy_workspace(tmp_path / "w")
    result = espdock("monitor", "anything", "--port", "socket://127.0.0.1:1", cwd=root, env=NO_ENGINE)
    assert result.returncode == 2
    assert "needs a terminal" in result.stderr


def test_flash_refuses_a_port_that_is_not_one(tmp_path):
    root = copy_workspace(tmp_path / "w")
    result = espdock("flash", "anything", "--port", "ttyUSB0", cwd=root, env=NO_ENGINE)
    assert result.returncode == 2
    assert "not a device path" in result.stderr
