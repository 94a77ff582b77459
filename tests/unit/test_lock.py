"""Dependency locks: staleness decided offline from a lock's header, `build --locked`, `espdock lock`."""

import json
import shutil
from pathlib import Path

import pytest

from espdock import defaults
from espdock.build import lock
from espdock.build.lock import LOCKS, check_locks, digest, stale_reason
from espdock.errors import LockError
from tests.conftest import REPO, copy_workspace, espdock
from tests.rosdep_db import environment

NO_ENGINE = {"DOCKER_HOST": "unix:///nonexistent/docker.sock"}
RUNTIME, BUILD, DEV = LOCKS


def state(root: Path, spec: lock.LockSpec) -> tuple[str | None, dict[str, str]]:
    lock_file = root / spec.lock
    digests = {rel: digest(rel, (root / rel).read_bytes()) for rel in spec.inputs}
    return (lock_file.read_text() if lock_file.is_file() else None), digests


def test_the_repository_locks_are_made_from_the_current_sources():
    # Fails when a source (docker/ros-*.in, pyproject.toml's dependencies) was edited without `espdock lock`.
    assert [spec for spec in LOCKS if lock.applies(spec, REPO)] == list(LOCKS)
    check_locks(REPO, LOCKS)


def test_every_locked_requirement_is_pinned_with_a_hash():
    for spec in LOCKS:
        entries = [line for line in (REPO / spec.lock).read_text().splitlines() if line[:1].isalnum()]
        assert entries, spec.lock
        for line in entries:
            assert "==" in line and line.endswith("\\"), f"{spec.lock}: {line}"


def test_the_build_lock_keeps_what_it_shares_with_the_runtime_lock_at_the_same_pin():
    def pins(rel: str) -> dict[str, str]:
        lines = (REPO / rel).read_text().splitlines()
        return dict(line.split(" ")[0].split("==") for line in lines if line[:1].isalnum())

    runtime, build = pins(RUNTIME.lock), pins(BUILD.lock)
    shared = runtime.keys() & build.keys()
    assert {"empy", "pyyaml", "setuptools"} <= shared
    assert {name: build[name] for name in shared} == {name: runtime[name] for name in shared}


def test_a_changed_source_makes_its_lock_stale_and_the_locks_made_against_it(tmp_path):
    root = copy_workspace(tmp_path / "w")
    assert stale_reason(RUNTIME, *state(root, RUNTIME)) is None
    assert stale_reason(BUILD, *state(root, BUILD)) is None
    source = root / RUNTIME.source
    source.write_text(source.read_text().replace("segno==1.6.6", "segno==1.6.5"))
    assert stale_reason(RUNTIME, *state(root, RUNTIME)) == (
        "docker/ros-runtime.txt is stale: docker/ros-runtime.in changed since it was locked"
    )
    assert stale_reason(BUILD, *state(root, BUILD)) is None
    runtime_lock = root / RUNTIME.lock
    runtime_lock.write_text(runtime_lock.read_text() + "\n")
    assert stale_reason(BUILD, *state(root, BUILD)) == (
        "docker/ros-build.txt is stale: docker/ros-runtime.txt changed since it was locked"
    )


def test_a_lock_compiled_for_another_python_is_stale(tmp_path):
    root = copy_workspace(tmp_path / "w")
    text, digests = state(root, RUNTIME)
    other = text.replace("--python-version 3.11", "--python-version 3.12")
    assert (
        stale_reason(RUNTIME, other, digests)
        == "docker/ros-runtime.txt is stale: it was compiled with other uv arguments"
    )


def test_a_hand_written_requirements_file_is_not_a_lock(tmp_path):
    root = copy_workspace(tmp_path / "w")
    (root / RUNTIME.lock).write_text("ros-jazzy-rclpy==7.1.6\n")
    assert stale_reason(RUNTIME, *state(root, RUNTIME)) == (
        "docker/ros-runtime.txt was not made by `espdock lock` (its header records no source)"
    )


def test_only_the_dependencies_of_pyproject_decide_the_dev_lock():
    pyproject = (REPO / "pyproject.toml").read_text()
    before = digest("pyproject.toml", pyproject.encode())
    retuned = pyproject.replace("line-length = 120", "line-length = 100")
    assert retuned != pyproject and digest("pyproject.toml", retuned.encode()) == before
    added = pyproject.replace('"pytest>=8",', '"pytest>=8",\n  "hypothesis>=6",')
    assert added != pyproject and digest("pyproject.toml", added.encode()) != before


def test_a_lock_missing_in_the_workspace_and_in_the_defaults_is_named(tmp_path, monkeypatch):
    root = copy_workspace(tmp_path / "w")
    (root / BUILD.lock).unlink()
    monkeypatch.setattr(defaults, "defaults_root", lambda: tmp_path / "no-defaults")
    with pytest.raises(LockError) as error:
        check_locks(root, LOCKS[:2])
    assert error.value.message == "docker/ros-build.txt is missing"
    assert error.value.exit_code == 2


def test_a_source_of_the_workspaces_own_without_its_lock_is_a_missing_lock_not_a_stale_default(tmp_path):
    """A ROS developer's first own docker/ros-build.in, no `espdock lock` yet: the workspace's
    docker/ros-build.txt was said to be stale (a file it does not have), espdock's default
    checked against the user's source."""
    root = tmp_path / "w"
    (root / "src").mkdir(parents=True)
    (root / "espdock.toml").write_text("[espdock]\n")
    shutil.copytree(REPO / "ws/src/custom_interface", root / "src/custom_interface")
    (root / "docker").mkdir()
    (root / BUILD.source).write_text("colcon-common-extensions\n")
    result = espdock("build", cwd=root, env={**NO_ENGINE, "CI": "true"})
    assert result.returncode == 2, result.stdout + result.stderr
    said = " ".join(result.stderr.split())
    assert (
        "docker/ros-build.txt is missing: the workspace has its own docker/ros-build.in, "
        "and espdock's default docker/ros-build.txt (compiled from espdock's) stands in"
    ) in said, said
    assert "stale" not in said and "ros-runtime" not in said, said


def test_build_in_ci_refuses_a_stale_lock_before_touching_the_engine(tmp_path):
    root = copy_workspace(tmp_path / "w")
    assert "warning" not in espdock("build", "--dry-run", cwd=root, env=NO_ENGINE).stderr
    source = root / RUNTIME.source
    source.write_text(source.read_text() + "requests==2.32.3\n")
    result = espdock("build", cwd=root, env={**NO_ENGINE, "CI": "true"})
    assert result.returncode == 2, result.stdout + result.stderr
    assert "docker/ros-runtime.txt is stale: docker/ros-runtime.in changed since it was locked" in result.stderr
    assert "run `espdock lock`" in result.stderr
    assert "Traceback" not in result.stderr
    # --no-locked, or outside CI, the build goes on (to the missing engine here), and says that the
    # image it makes lacks the change (a package added to the .in was missing without a word).
    warned = "warning: docker/ros-runtime.txt is stale: docker/ros-runtime.in changed since it was locked: "
    for args, ci in ((("--no-locked",), "true"), ((), "false"), (("--dry-run",), "false")):
        going_on = espdock("build", *args, cwd=root, env={**NO_ENGINE, "CI": ci})
        assert going_on.returncode == (0 if args == ("--dry-run",) else 3), going_on.stdout + going_on.stderr
        said = " ".join(going_on.stderr.split())
        assert warned + "the images are built from it as it is; run `espdock lock` to take the change in" in said
    assert espdock("build", "--locked", cwd=root, env={**NO_ENGINE, "CI": "false"}).returncode == 2


def test_build_checks_only_the_locks_of_the_images_it_uses(tmp_path):
    root = copy_workspace(tmp_path / "w")
    (root / RUNTIME.source).write_text("segno==1.6.5\n")
    assert espdock("build", "--locked", cwd=root, env=NO_ENGINE).returncode == 2
    previewed = espdock("build", "--locked", "--dry-run", cwd=root, env=NO_ENGINE)
    assert previewed.returncode == 2 and "docker/ros-runtime.txt is stale" in previewed.stderr, previewed.stdout
    # Only firmware (of which the workspace has none): no ROS image, so its locks do not matter:
    # nothing to build, and nothing refused.
    result = espdock("build", "--only", "firmware", "--locked", cwd=root, env=NO_ENGINE)
    assert result.returncode == 0, result.stdout + result.stderr
    assert "nothing to build: no firmware package in the workspace" in result.stdout
    # A ROS package named with --only firmware: nothing it names is built, which is no success
    # (it passed, "no firmware package in the workspace", and its report said succeeded).
    report = tmp_path / "report.json"
    named = espdock("build", "custom_interface", "--only", "firmware", "--report", str(report), cwd=root, env=NO_ENGINE)
    assert named.returncode == 2, named.stdout + named.stderr
    said = " ".join(named.stderr.split())
    assert "nothing to build: --only firmware builds no package of custom_interface (ROS)" in said, said
    assert json.loads(report.read_text())["outcome"] == "failed"
    # Beside a package of the kind: built, and the other named is said to be left out (it was not).
    shutil.copytree(REPO / "firmware/led_strip_node", root / "firmware/led_strip_node")
    mixed = espdock(
        "build", "custom_interface", "led_strip_node", "--only", "ros", "--dry-run", cwd=root, env=NO_ENGINE
    )
    said = " ".join(mixed.stdout.split())
    assert "note: not built, --only ros leaves them out: led_strip_node (firmware)" in said, said


def test_a_workspace_on_espdocks_defaults_builds_locked_and_has_nothing_to_lock(tmp_path):
    root = tmp_path / "w"
    (root / "src").mkdir(parents=True)
    (root / "espdock.toml").write_text("[espdock]\n")
    shutil.copytree(REPO / "ws/src/custom_interface", root / "src/custom_interface")
    assert espdock("build", "--locked", cwd=root, env=NO_ENGINE).returncode == 3  # past the check, at the engine
    result = espdock("lock", cwd=root, env=NO_ENGINE)
    assert result.returncode == 0, result.stderr
    assert "docker/ros-runtime.txt: espdock's default" in result.stdout
    assert "docker/ros-build.txt: espdock's default" in result.stdout
    assert "requirements/dev.txt" not in result.stdout
    assert sorted(p.name for p in root.iterdir()) == ["espdock.toml", "src"]


def test_lock_follows_a_changed_pin_leaves_the_other_lock_alone_and_every_lock_current(tmp_path):
    """Runs uv against the package index. The rosdep lock answers for the wheel locks' pins (they
    constrain its pip part): `espdock lock` made it before it compiled them, and after a changed
    pin the next `build --locked` (CI's) refused it as stale until a second `espdock lock`."""
    root = copy_workspace(tmp_path / "w", test_packages=("rosdeps_xml_count",))
    temp = tmp_path / "tmp"  # the user's temp dir: uv's setuptools builds left a file each in it
    temp.mkdir()
    env = {**environment(tmp_path), "TMPDIR": str(temp)}
    first = espdock("lock", cwd=root, env=env, timeout=300)  # today's index may hold newer files
    assert first.returncode == 0, first.stdout + first.stderr
    runtime = (root / RUNTIME.lock).read_text()
    source = root / BUILD.source
    source.write_text(source.read_text().replace("cmake==3.31.6", "cmake==3.31.4"))
    result = espdock("lock", cwd=root, env=env, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    assert list(temp.iterdir()) == []
    lines = result.stdout.splitlines()
    assert lines[:2] == [
        "docker/ros-runtime.txt: unchanged (from docker/ros-runtime.in)",
        "docker/ros-build.txt: updated (from docker/ros-build.in, docker/ros-runtime.txt)",
    ], result.stdout
    assert any(line.startswith("rosdep.lock.json: updated") for line in lines), result.stdout
    assert (root / RUNTIME.lock).read_text() == runtime
    build = (root / BUILD.lock).read_text()
    assert "\ncmake==3.31.4 \\\n    --hash=sha256:" in build and "cmake==3.31.6" not in build
    check_locks(root, LOCKS[:2])
    built = espdock("build", "--locked", cwd=root, env={**env, **NO_ENGINE, "CI": "true"})
    assert built.returncode == 3, built.stdout + built.stderr  # past every lock, at the engine


def test_lock_names_the_source_uv_cannot_resolve(tmp_path):
    """Runs uv against the package index."""
    root = copy_workspace(tmp_path / "w")
    before = (root / RUNTIME.lock).read_text()
    (root / RUNTIME.source).write_text("segno==0.0.0.404\n")
    result = espdock("lock", cwd=root, timeout=300)
    assert result.returncode == 2
    assert "uv could not lock docker/ros-runtime.txt from docker/ros-runtime.in" in result.stderr
    assert "segno" in result.stderr and "Traceback" not in result.stderr
    assert (root / RUNTIME.lock).read_text() == before


def test_lock_through_a_proxy_that_is_down_names_the_proxy(tmp_path):
    """HTTPS_PROXY set, its proxy not running: uv's "Connection refused" was hinted "Fix
    docker/ros-runtime.in (or the network)", naming neither the proxy nor that it was one."""
    import socket

    root = copy_workspace(tmp_path / "w")
    (root / RUNTIME.source).write_text((root / RUNTIME.source).read_text() + "segno\n")  # something to resolve
    with socket.socket() as closed:
        closed.bind(("127.0.0.1", 0))
        port = closed.getsockname()[1]
    proxy = f"http://alice:S3cret@127.0.0.1:{port}"
    env = {name: proxy for name in ("HTTPS_PROXY", "https_proxy", "HTTP_PROXY", "http_proxy")}
    result = espdock("lock", cwd=root, env={**env, "UV_NO_CACHE": "1"}, timeout=300)
    said = " ".join(result.stderr.split())
    assert result.returncode == 2, said
    assert f"went through the proxy at 127.0.0.1:{port}: check that it is up" in said, said
    assert "S3cret" not in said.partition("hint:")[2], "no credentials in espdock's own words"


def test_a_lock_compiled_from_espdocks_default_source_does_not_name_where_espdock_is_installed(tmp_path):
    """Runs uv against the package index. A workspace with its own runtime lock gets its own build
    lock, from espdock's default docker/ros-build.in: its "# via -r" named that file's absolute
    path, so the same `espdock lock` from another install (a colleague's, an upgrade) rewrote the
    committed lock and the build image's key changed with it."""
    root = copy_workspace(tmp_path / "w")
    (root / BUILD.source).unlink()
    (root / BUILD.lock).unlink()
    result = espdock("lock", cwd=root, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    text = (root / BUILD.lock).read_text()
    assert "# via -r docker/ros-build.in" in text
    assert str(defaults.defaults_root()) not in text and str(REPO) not in text
