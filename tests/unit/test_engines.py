"""Engines other than a local rootful Docker, as the runner sees them (FakeEngine): one that does
not see the workspace, a rootless one, and what /info says about an engine."""

from __future__ import annotations

import hashlib
import http.server
import io
import json
import os
import socketserver
import subprocess
import sys
import tarfile
import tempfile
import threading
import time
from pathlib import Path
from typing import ClassVar

import pytest

from espdock.build.runner import Runner
from espdock.build.steps import Plan
from espdock.config import Config
from espdock.errors import BuildFailed, EngineUnavailable, WorkspaceError, WorkspaceNotVisible
from espdock.images import bootstrap, volume
from espdock.images.addresses import DEFAULT_HOST
from espdock.images.engine import LIBPOD_INFO, Engine
from espdock.images.specs import EngineInfo, describe
from espdock.images.visibility import linked_mounts
from espdock.ros.colcon_log import unselected
from espdock.ros.plan import ColconBuild
from espdock.workspace import Workspace
from tests.conftest import REPO
from tests.fake_engine import FakeEngine
from tests.unit.test_runner import COLCON, colcon_installs


@pytest.fixture
def ws(tmp_path, monkeypatch) -> Workspace:
    monkeypatch.setattr(bootstrap, "ensure_compose", lambda env, notify: None)
    for name in ("msgs", "app"):
        (tmp_path / "ws/src" / name).mkdir(parents=True)
        (tmp_path / "ws/src" / name / "package.xml").write_text(f"<package><name>{name}</name></package>\n")
    return Workspace(tmp_path)


def runner(engine: FakeEngine, config: Config | None = None) -> Runner:
    owner = (os.getuid(), os.getgid())
    return Runner(engine, config or Config(), {}, lambda event: None, owner)  # type: ignore[arg-type]


def test_an_engine_that_does_not_see_the_workspace_stops_a_mount_mode_build_before_colcon(ws):
    engine = FakeEngine(run_script=colcon_installs(ws), sees_host=False)
    with pytest.raises(WorkspaceNotVisible) as err:
        runner(engine, Config(workspace_mode="mount")).run(Plan(ws, (COLCON,)))
    assert err.value.exit_code == 8
    assert f"the Docker engine at fake://engine does not see the workspace {ws.root}" in err.value.message
    assert "CI_PROJECT_DIR" in (err.value.hint or "")
    assert engine.runs == []  # colcon never ran
    assert not list(ws.root.glob(".espdock-probe-*"))  # the nonce file is gone


def test_the_engine_is_asked_once_per_workspace_path_not_per_build(ws):
    engine = FakeEngine(run_script=colcon_installs(ws))
    runner(engine).run(Plan(ws, (COLCON,)))
    (ws.ws_dir / "src/app/new.txt").write_text("an edit")
    runner(engine).run(Plan(ws, (COLCON,)))
    assert len(engine.runs) == 2
    assert engine.mount_checks == 1


def test_a_rootless_engine_runs_build_containers_as_its_root_which_is_the_user(ws):
    engine = FakeEngine(run_script=colcon_installs(ws), rootless=True)
    runner(engine).run(Plan(ws, (COLCON,)))
    assert [spec.user for spec in engine.runs] == ["0:0"]
    local = FakeEngine(run_script=colcon_installs(ws))
    runner(local).run(Plan(ws, (ColconBuild(**{**COLCON.__dict__, "force": True}),)))
    assert [spec.user for spec in local.runs] == [f"{os.getuid()}:{os.getgid()}"]


def test_a_package_colcon_did_not_find_fails_and_one_left_out_as_told_does_not(ws):
    engine = FakeEngine(run_script=lambda spec, on_line: lost_app(ws, spec, on_line))
    with pytest.raises(BuildFailed) as err:
        runner(engine).run(Plan(ws, (COLCON,)))
    assert err.value.exit_code == 5
    assert "colcon did not find 1 of the 2 package(s) it was to build: app (ws/src/app)" in err.value.message
    assert unselected(["[0.1] (-) JobUnselected: {'identifier': 'app'}", "[0.2] (msgs) JobQueued: {}"]) == {"app"}


def lost_app(ws: Workspace, spec, on_line) -> int:
    """colcon that found only msgs (app's directory is not there in its container)."""
    log = ws.ws_dir / "log/build_0"
    log.mkdir(parents=True)
    (ws.ws_dir / "install/msgs").mkdir(parents=True)
    (log / "events.log").write_text(
        "[0.1] (msgs) JobQueued: {'identifier': 'msgs'}\n[0.8] (msgs) JobEnded: {'identifier': 'msgs', 'rc': 0}\n"
    )
    (ws.ws_dir / "log/latest_build").symlink_to("build_0")
    return 0


def test_a_permission_error_on_a_workspace_path_names_it_and_its_owner(ws, monkeypatch):
    engine = FakeEngine(run_script=colcon_installs(ws))

    def denied(*args, **kwargs):
        raise PermissionError(13, "Permission denied", str(ws.ws_dir / "build"))

    monkeypatch.setattr("espdock.ros.staleness.package_stamps", denied)
    with pytest.raises(WorkspaceError) as err:
        runner(engine).run(Plan(ws, (COLCON,)))
    assert err.value.exit_code == 2
    assert f"permission denied on {ws.ws_dir / 'build'} (owner uid {os.getuid()}" in err.value.message


def test_what_info_says_about_the_engine():
    env = {"DOCKER_HOST": "unix:///run/podman/podman.sock"}
    libpod = {"host": {"hostname": "vm", "security": {"rootless": False}}, "store": {"graphRoot": "/var/lib/c"}}
    podman = describe(env, {}, libpod)
    assert (podman.kind, podman.rootless) == ("podman", False)
    assert podman.name == "Podman engine at unix:///run/podman/podman.sock"
    user_podman = describe(env, {}, {**libpod, "host": {"hostname": "vm", "security": {"rootless": True}}})
    assert (user_podman.kind, user_podman.rootless) == ("podman", True)
    # Podman's identity is its host name and storage, which its Docker API /info gives as Name and
    # DockerRootDir (beside an ID it makes up per call): records made before it asked /libpod/info hold.
    assert podman.identity == compat_identity("unix:///run/podman/podman.sock", "vm", "/var/lib/c")
    assert describe(env, {}, {**libpod, "store": {"graphRoot": "/home/u/c"}}).identity != podman.identity
    rootless = describe({}, {"ID": "x", "SecurityOptions": ["name=seccomp,profile=default", "name=rootless"]})
    assert (rootless.kind, rootless.rootless) == ("docker", True)
    assert rootless.name == "rootless Docker engine at unix:///var/run/docker.sock"
    assert describe({}, {"ID": "y", "SecurityOptions": ["name=seccomp"]}).identity != rootless.identity


class PodmanApiDouble(http.server.BaseHTTPRequestHandler):
    """Stands in for Podman 4.3's API service (`podman system service`) where what is tested is
    which requests espdock makes, which the real service does not show (test_podman runs espdock
    against the real one). It answers /_ping with the headers Podman 4.3.1 sends, and /version,
    /info and /libpod/info with what it says of itself there (abridged); anything else is a 500.
    Its class attribute ASKED records each path."""

    asked: ClassVar[list[str]] = []
    protocol_version = "HTTP/1.1"

    def do_GET(self) -> None:
        type(self).asked.append(self.path)
        route = unversioned(self.path)
        headers = {"Api-Version": "1.41", "Libpod-Api-Version": "4.3.1", "Server": "Libpod/4.3.1 (linux)"}
        if route == "/_ping":
            self.answer(200, b"OK", headers)
        elif route == "/version":
            version = {"Components": [{"Name": "Podman Engine", "Version": "4.3.1"}], "ApiVersion": "1.41",
                       "MinAPIVersion": "1.24", "Version": "4.3.1"}  # fmt: skip
            self.answer(200, json.dumps(version).encode(), headers)
        elif route == "/info":
            info = {"ID": str(time.time()), "Name": "vm", "DockerRootDir": "/c", "SecurityOptions": ["name=seccomp"]}
            self.answer(200, json.dumps(info).encode(), headers)
        elif route == LIBPOD_INFO:
            info = {"host": {"hostname": "vm", "security": {"rootless": True}}, "store": {"graphRoot": "/c"}}
            self.answer(200, json.dumps(info).encode(), headers)
        else:
            self.answer(500, b'{"message": "not asked of a Podman by espdock"}', headers)

    def answer(self, status: int, body: bytes, headers: dict[str, str]) -> None:
        self.send_response(status)
        for name, value in headers.items():
            self.send_header(name, value)
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, format: str, *args: object) -> None:
        pass


def unversioned(path: str) -> str:
    """PATH without its query and the Docker API version the SDK puts in front."""
    return path.split("?")[0].removeprefix("/v1.41")


def compat_identity(where: str, name: str, root: str) -> str:
    """The identity espdock gave a Podman from its Docker API /info's Name and DockerRootDir."""
    return hashlib.sha256("\0".join((where, name, root)).encode()).hexdigest()[:16]


class UnixHTTPServer(socketserver.ThreadingMixIn, socketserver.UnixStreamServer):
    daemon_threads = True

    def get_request(self):
        request, _ = super().get_request()
        return request, ("local", 0)  # http.server wants a host and port


@pytest.mark.parametrize("where", ["socket", "tcp"])
def test_podman_is_told_by_its_ping_and_asked_only_its_own_info(tmp_path, where):
    """Podman's Docker API /info and /version each took it 0.4 to 0.7 s here (it asks dpkg the
    versions of its packages): on the local socket espdock asks neither; the SDK, over TCP,
    asks /version once to pick its API version."""
    PodmanApiDouble.asked = []
    if where == "socket":
        server = UnixHTTPServer(str(tmp_path / "podman.sock"), PodmanApiDouble)
        env = {"DOCKER_HOST": f"unix://{tmp_path / 'podman.sock'}"}
    else:
        server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), PodmanApiDouble)
        env = {"DOCKER_HOST": f"tcp://127.0.0.1:{server.server_address[1]}"}
    threading.Thread(target=server.serve_forever, daemon=True).start()
    try:
        info = Engine.connect(env, timeout=10).info()
    finally:
        server.shutdown()
        server.server_close()
    assert (info.kind, info.rootless) == ("podman", True)
    # As when espdock read the Name and DockerRootDir of Podman's Docker API /info.
    assert info.identity == compat_identity(env["DOCKER_HOST"], "vm", "/c")
    assert info.name == f"rootless Podman engine at {env['DOCKER_HOST']}"
    asked = [unversioned(path) for path in PodmanApiDouble.asked]
    assert "/info" not in asked and asked[-1] == LIBPOD_INFO, asked
    if where == "socket":
        assert asked == ["/_ping", LIBPOD_INFO]


def test_colcon_denied_its_log_dir_names_the_dir_and_its_owner(ws):
    """What a rootless engine's subordinate uid left behind: colcon may not write ws/log."""
    if os.geteuid() != 0:
        pytest.skip("giving a directory to another uid needs root")
    (ws.ws_dir / "log").mkdir()
    os.chown(ws.ws_dir / "log", 100999, 100999)

    def denied(spec, on_line):
        on_line("PermissionError: [Errno 13] Permission denied: 'log'")
        return 1

    with pytest.raises(WorkspaceError) as err:
        runner(FakeEngine(run_script=denied)).run(Plan(ws, (COLCON,)))
    assert f"permission denied on {ws.ws_dir / 'log'} (owner uid 100999" in err.value.message


class VolumeEngine:
    """The part of an engine espdock.volume's sync asks: whether the volume is new, and who the engine is."""

    def __init__(self) -> None:
        self.made: list[str] = []

    def ensure_volume(self, name: str, labels: dict[str, str]) -> bool:
        if name in self.made:
            return False
        self.made.append(name)
        return True

    def info(self) -> EngineInfo:
        return EngineInfo(kind="docker", rootless=False, identity="remote-1", where="tcp://remote:2375")


def sent_names(sync: volume.Sync) -> list[str]:
    with tarfile.open(fileobj=io.BytesIO(sync.archive)) as tar:
        return [m.name for m in tar.getmembers() if m.isfile()]


def test_a_sync_sends_what_changed_since_the_last_one_and_removes_what_was_deleted(ws):
    engine = VolumeEngine()
    (ws.ws_dir / "src/app/keep.py").write_text("x = 1\n")
    (ws.ws_dir / "src/app/gone.py").write_text("y = 2\n")
    (ws.ws_dir / "build/app").mkdir(parents=True)
    (ws.ws_dir / "build/app/out.o").write_text("object")  # colcon's output: never sent
    first = volume.prepare(engine, ws, (1000, 1000))  # type: ignore[arg-type]
    assert first.fresh
    assert sorted(sent_names(first)) == [
        "ws/src/app/gone.py", "ws/src/app/keep.py", "ws/src/app/package.xml", "ws/src/msgs/package.xml"
    ]  # fmt: skip
    with tarfile.open(fileobj=io.BytesIO(first.archive)) as tar:
        assert {(m.uid, m.gid) for m in tar.getmembers()} == {(1000, 1000)}
    volume.record(ws, engine, first, None)  # type: ignore[arg-type]

    (ws.ws_dir / "src/app/keep.py").write_text("x = 10\n")
    (ws.ws_dir / "src/app/gone.py").unlink()
    second = volume.prepare(engine, ws, (1000, 1000))  # type: ignore[arg-type]
    assert not second.fresh
    assert sent_names(second) == ["ws/src/app/keep.py"]
    assert second.deleted == ("/workspace/ws/src/app/gone.py",)
    volume.record(ws, engine, second, None)  # type: ignore[arg-type]
    assert sent_names(volume.prepare(engine, ws, (1000, 1000))) == []  # type: ignore[arg-type]


def test_a_copy_back_swaps_the_whole_tree_in_and_a_missing_one_leaves_the_old(ws, tmp_path):
    install = ws.ws_dir / "install"
    (install / "app").mkdir(parents=True)
    (install / "app/old.txt").write_text("old")
    assert not volume.replace_tree(tmp_path / "absent.tar", install, (os.getuid(), os.getgid()))
    assert (install / "app/old.txt").read_text() == "old"
    made = tmp_path / "made/install/app"
    made.mkdir(parents=True)
    (made / "new.txt").write_text("new")
    with tarfile.open(tmp_path / "install.tar", "w") as tar:
        tar.add(tmp_path / "made/install", arcname="install")
    assert volume.replace_tree(tmp_path / "install.tar", install, (os.getuid(), os.getgid()))
    assert sorted(p.name for p in (install / "app").iterdir()) == ["new.txt"]
    assert [p.name for p in ws.ws_dir.iterdir() if p.name.startswith(".")] == []  # no staging left


def test_what_a_copy_back_killed_outright_left_is_removed_by_the_next_and_a_live_one_s_is_not(
    ws, tmp_path, monkeypatch
):
    """kill -9 during a copy back from the volume left its tar streams in the temp dir and the
    unpacked or swapped-out install tree hidden in the colcon root, for good."""
    from espdock.scratch import owner_identity

    temp = tmp_path / "temp"
    temp.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temp))
    gone, live = "0000:1:1", owner_identity()  # another boot's process, and this one
    left = [temp / f"espdock-volume-{gone}-ab12", ws.ws_dir / f".espdock-fetched-{gone}-cd34"]
    left.append(ws.ws_dir / f".espdock-old-{gone}-ef56")
    kept = [temp / f"espdock-volume-{live}-ab12", ws.ws_dir / f".espdock-fetched-{live}-cd34"]
    kept.append(temp / "espdock-volume-bench-gh78")  # not one of espdock's: tests/bench/volume_mode.py's
    for path in (*left, *kept):
        (path / "install/app").mkdir(parents=True)
    made = tmp_path / "made/install/app"
    made.mkdir(parents=True)
    (made / "new.txt").write_text("new")
    with volume.fetched("install") as archives:
        with tarfile.open(archives["install"], "w") as tar:
            tar.add(tmp_path / "made/install", arcname="install")
        assert volume.replace_tree(archives["install"], ws.ws_dir / "install", (os.getuid(), os.getgid()))
    assert [path for path in left if path.exists()] == []
    assert all(path.is_dir() for path in kept)


def test_a_process_of_another_pid_namespace_of_this_machine_is_never_taken_for_a_gone_one():
    """Two CI jobs in containers of their own, on one engine, at the same checkout path: each
    espdock looked the other's pid up in its own /proc, took the live build for one killed
    outright, and removed its colcon container (exit 137, "colcon stopped before building")."""
    from espdock.scratch import owner_alive, owner_identity

    job = subprocess.run(
        [
            "unshare",
            "-rpf",
            "--mount-proc",
            sys.executable,
            "-c",
            "from espdock.scratch import owner_identity as o; print(o())",
        ],
        cwd=REPO,
        capture_output=True,
        text=True,
        check=False,
    )
    if job.returncode != 0:
        pytest.skip(f"unshare cannot make a PID namespace here: {job.stderr.strip()}")
    other = job.stdout.strip()
    assert other != owner_identity() and owner_alive(other), other
    boot, _, rest = owner_identity().partition(":")
    mine = rest.partition(":")[0]
    assert not owner_alive(f"{boot}:{mine.rpartition('.')[0]}.999999999:1"), "one of this namespace that is gone"
    assert owner_alive(owner_identity())


@pytest.mark.parametrize("cut", ["empty", "truncated"])
def test_a_copy_back_the_engine_cut_short_is_the_engine_s_failure_and_leaves_the_old_tree(ws, tmp_path, cut):
    install = ws.ws_dir / "install"
    (install / "app").mkdir(parents=True)
    (install / "app/old.txt").write_text("old")
    made = tmp_path / "made/install/app"
    made.mkdir(parents=True)
    (made / "new.bin").write_bytes(os.urandom(64 * 1024))
    archive = tmp_path / "install.tar"
    with tarfile.open(archive, "w") as tar:
        tar.add(tmp_path / "made/install", arcname="install")
    data = archive.read_bytes()
    archive.write_bytes(b"" if cut == "empty" else data[: len(data) // 2])
    with pytest.raises(EngineUnavailable, match=r"copy of the container's install/ came back broken"):
        volume.replace_tree(archive, install, (os.getuid(), os.getgid()))
    assert [p.name for p in (install / "app").iterdir()] == ["old.txt"]
    assert [p.name for p in ws.ws_dir.iterdir() if p.name.startswith(".")] == []  # no staging left


def test_a_link_out_of_the_workspace_within_a_package_is_mounted_for_colcon(ws, tmp_path):
    """A package's `config -> /abs/common_cfg`: the container found nothing there, the build
    passed without a word, and the config was never installed."""
    from espdock.images.visibility import directory_links
    from espdock.ros.steps import _linked

    common = tmp_path.parent / f"{tmp_path.name}-common_cfg"
    common.mkdir()
    package = ws.ws_dir / "src/bringup"
    (package / "bringup").mkdir(parents=True)
    (package / "bringup/config").symlink_to(common)
    (package / "bringup/launch").symlink_to("../launch_files")  # within the package: its mount has it
    (package / "launch_files").mkdir()
    assert directory_links(package) == [package / "bringup/config", package / "bringup/launch"]
    assert {m.target: m.source for m in _linked(ws, [("bringup", "src/bringup")])} == {str(common): common}


def test_links_out_of_the_workspace_are_mounted_where_a_container_follows_them(ws, tmp_path):
    repos = tmp_path.parent / f"{tmp_path.name}-repos"  # beside the workspace (tmp_path)
    for name in ("driver", "relative", "deep/inner"):
        (repos / name).mkdir(parents=True)
    src = ws.ws_dir / "src"
    (src / "driver").symlink_to(repos / "driver")  # ln -s ~/repos/driver src/
    (src / "relative").symlink_to(f"../../../{repos.name}/relative")
    (src / "stack").symlink_to(repos / "deep")  # a link above the package
    (src / "inside").symlink_to("app")  # within the workspace: its mount has it
    (src / "loop").symlink_to("loop")
    paths = [src / p for p in ("driver", "relative", "stack/inner", "inside", "loop", "msgs")]
    mounts = {m.target: m.source for m in linked_mounts(ws, paths)}
    assert mounts == {
        str(repos / "driver"): repos / "driver",
        f"/{repos.name}/relative": repos / "relative",  # as the container resolves it from /workspace/ws/src
        str(repos / "deep/inner"): repos / "deep/inner",
    }


def test_a_whole_volume_build_that_failed_brings_back_what_it_built_and_keeps_the_rest(ws, tmp_path):
    """A new volume builds every package; when that fails part way, the volume's install/ lacks
    what it did not reach, which the host's install/ still has from earlier builds."""
    install = ws.ws_dir / "install"
    for name, word in (("built", "old"), ("reached_not", "old"), ("setup.sh", None)):
        if word is None:
            (install / name).write_text("host's\n")
        else:
            (install / name).mkdir(parents=True, exist_ok=True)
            (install / name / "word").write_text(word)
    (install / "built/link").symlink_to("word")
    made = tmp_path / "made/install"
    (made / "built").mkdir(parents=True)
    (made / "built/word").write_text("new")
    (made / "setup.sh").write_text("volume's\n")
    (made / "only_there").mkdir()
    archive = tmp_path / "install.tar"
    with tarfile.open(archive, "w") as tar:
        tar.add(made, arcname="install")
    assert volume.replace_tree(archive, install, (os.getuid(), os.getgid()), only=["built"])
    assert (install / "built/word").read_text() == "new" and not (install / "built/link").exists()
    assert (install / "reached_not/word").read_text() == "old"
    assert (install / "setup.sh").read_text() == "host's\n"
    assert (install / "only_there").is_dir()
    assert [p.name for p in ws.ws_dir.iterdir() if p.name.startswith(".")] == []  # no staging left
    # As root (`sudo espdock build` in a user's workspace): what stays is still the user's, its
    # directories too, which were root's and kept the user from removing the old tree after.
    os.chown(install / "reached_not", 4242, 4242)
    (install / "reached_not/firmware").symlink_to(".firmware-0123")  # as a firmware install links it
    os.chown(install / "reached_not/firmware", 4242, 4242, follow_symlinks=False)
    assert volume.replace_tree(archive, install, (4242, 4242), only=["built"])
    assert (install / "reached_not").stat().st_uid == 4242
    assert (install / "reached_not/firmware").lstat().st_uid == 4242


@pytest.mark.parametrize("host", [{}, {"DOCKER_HOST": ""}], ids=["unset", "empty"])
def test_the_dockerd_espdock_starts_keeps_nothing_of_the_commands_temp_dirs(tmp_path, monkeypatch, host):
    """dockerd outlives the command that started it (a CI job, a session): it gets a service's
    environment, the proxies and PATH, not the job's TMPDIR (runc's exec files) or its directory.
    An empty DOCKER_HOST (a CI file's way to unset it) is the local engine, as for `docker`."""
    seen = tmp_path / "seen"
    fake = tmp_path / "bin/dockerd"  # stands in for dockerd: says what it was given, then fails to start
    fake.parent.mkdir()
    fake.write_text(f"#!/bin/sh\n{{ pwd; env; }} > {seen}\nexit 3\n")
    fake.chmod(0o755)
    monkeypatch.setattr(bootstrap, "DOCKERD_LOG", tmp_path / "dockerd.log")
    monkeypatch.setattr(bootstrap, "_can_manage_engine", lambda: True)
    monkeypatch.setattr(Engine, "connect", classmethod(lambda cls, env, timeout: (_ for _ in ()).throw(
        bootstrap.EngineUnavailable("no engine"))))  # fmt: skip
    path = f"{fake.parent}:{os.environ['PATH']}"
    monkeypatch.setenv("PATH", path)
    monkeypatch.chdir(tmp_path)
    job = {"PATH": path, "TMPDIR": str(tmp_path / "job-tmp"), "XDG_CACHE_HOME": str(tmp_path / "cache"),
           "HTTPS_PROXY": "http://proxy.example:3128", **host}  # fmt: skip
    with pytest.raises(bootstrap.EngineUnavailable, match="dockerd exited with code 3"):
        bootstrap.ensure_engine(job, lambda text: None)
    cwd, *lines = seen.read_text().splitlines()
    given = dict(line.split("=", 1) for line in lines if "=" in line)
    assert cwd == "/"
    assert given["HTTPS_PROXY"] == "http://proxy.example:3128" and given["PATH"] == path
    assert "TMPDIR" not in given and "XDG_CACHE_HOME" not in given


@pytest.mark.parametrize(
    ("host", "ssh"), [("tcp://127.0.0.1:9", False), ("unix:///nowhere.sock", False), ("ssh://ci@buildbox", True)]
)
def test_the_sdk_brings_paramiko_only_for_an_ssh_engine(host, ssh):
    """paramiko is a tenth of a second at each start of espdock on a TCP engine (a third of a
    no-change build there), and only ssh:// needs it: the SDK's ssh adapter is there then."""
    script = (
        "import sys\n"
        "from espdock.images import engine\n"
        f"made = engine.Engine({{'DOCKER_HOST': {host!r}, 'PATH': '/usr/bin:/bin'}})\n"
        "try:\n"
        "    made._client\n"  # the SDK, as espdock's first use of it imports it (no engine answers)
        "except engine.EngineUnavailable:\n"
        "    pass\n"
        "assert engine.docker.errors.APIError\n"
        "import docker.transport\n"
        "print('paramiko' in sys.modules, hasattr(docker.transport, 'SSHHTTPAdapter'))\n"
    )
    ran = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=False)
    assert ran.returncode == 0, ran.stderr
    assert ran.stdout.split()[:2] == [str(ssh), str(ssh)]


def test_a_tool_s_paths_in_the_workspace_mount_are_shown_as_the_user_s():
    from espdock.images.visibility import host_paths

    ws = Workspace(Path("/home/ann/robot"))
    assert host_paths("/workspace/ws/src/d/a.c:3:1: error: x", ws) == "/home/ann/robot/ws/src/d/a.c:3:1: error: x"
    assert host_paths("CMake Error at /workspace/firmware/b/CMakeLists.txt:3", ws).endswith(
        " /home/ann/robot/firmware/b/CMakeLists.txt:3"
    )
    assert host_paths("cwd '/workspace'", ws) == "cwd '/home/ann/robot'"
    # Only the mount point itself: other paths that contain its name stay as they are.
    for line in ("/workspaces/x", "src/workspace/x", "~/workspace/x", "/workspace_2/x", "no path here"):
        assert host_paths(line, ws) == line


def _archive(path: Path, members: dict[str, tuple[bytes, int]]) -> Path:
    with tarfile.open(path, "w") as tar:
        for name, (data, mode) in members.items():
            info = tarfile.TarInfo(name)
            info.size, info.mode = len(data), mode
            tar.addfile(info, io.BytesIO(data))
    return path


def test_a_copy_back_from_the_volume_unpacks_on_a_python_without_tar_filters(tmp_path, monkeypatch):
    """Python before 3.11.4 (Debian bookworm's 3.11.2) has no extraction filters: every volume-mode
    build crashed on `filter=` (exit 70, after colcon had built), and no install/ came back."""
    original = tarfile.TarFile.extractall

    def old_extractall(self, path=".", members=None, *, numeric_owner=False, **filters):
        if filters:
            raise TypeError("TarFile.extractall() got an unexpected keyword argument 'filter'")
        return original(self, path, members, numeric_owner=numeric_owner)

    monkeypatch.setattr(tarfile.TarFile, "extractall", old_extractall)
    monkeypatch.delattr(tarfile, "tar_filter")
    archive = _archive(tmp_path / "ok.tar", {"install/p/lib/p/node": (b"#!/bin/sh\n", 0o4777)})
    staging = volume._unpacked(archive, tmp_path, (os.getuid(), os.getgid()))
    node = staging / "install/p/lib/p/node"
    assert node.read_bytes() == b"#!/bin/sh\n" and node.stat().st_mode & 0o7777 == 0o755, "as the tar filter has it"
    bad = _archive(tmp_path / "bad.tar", {"install/../../escaped": (b"x", 0o644)})
    with pytest.raises(ValueError, match="out of the directory"):
        volume._unpacked(bad, tmp_path, (os.getuid(), os.getgid()))
    assert not (tmp_path.parent / "escaped").exists()
    assert list(tmp_path.glob(".espdock-fetched-*")) == [staging], "the refused one's staging dir went"


def test_what_needs_this_machine_is_refused_before_any_image_where_the_volume_is_known(ws):
    """`espdock test` on an engine that does not see the workspace built its test image (minutes,
    left on that engine), then refused with exit 8: the engine's answer was known from the build."""
    engine = FakeEngine(run_script=colcon_installs(ws), sees_host=False)
    auto = runner(engine).containers
    auto.known_to_need_this_machine(ws, "the results")  # never asked: no container to find out here
    assert engine.runs == []
    with pytest.raises(WorkspaceNotVisible):
        auto.needs_this_machine(ws, "img", "the results")  # asks the engine, and keeps its answer
    asked = len(engine.runs)
    with pytest.raises(WorkspaceNotVisible, match="the results must be on this machine"):
        runner(engine).containers.known_to_need_this_machine(ws, "the results")
    assert len(engine.runs) == asked, "decided from the kept answer"
    with pytest.raises(WorkspaceNotVisible):
        runner(FakeEngine(), Config(workspace_mode="volume")).containers.known_to_need_this_machine(ws, "x")


def test_a_workspace_espdock_may_not_write_is_said_before_anything_runs(ws, monkeypatch):
    """A read-only checkout (`chmod -R a-w`, or root's clone built by a user): `espdock shell`
    failed as "a bug in espdock" (PermissionError) writing the file it asks the engine to find."""
    from pathlib import Path

    write_text = Path.write_text

    def read_only(path, *args, **kwargs):
        if path.parent == ws.root:
            raise PermissionError(13, "Permission denied", str(path))
        return write_text(path, *args, **kwargs)

    monkeypatch.setattr(Path, "write_text", read_only)
    engine = FakeEngine(run_script=colcon_installs(ws))
    with pytest.raises(WorkspaceError) as err:
        runner(engine).run(Plan(ws, (COLCON,)))
    assert err.value.exit_code == 2
    assert err.value.message == f"espdock cannot write in the workspace {ws.root}: Permission denied"
    assert engine.runs == []


def test_permission_hints_quote_their_path_and_name_the_fix_that_applies(tmp_path):
    """`chmod -R a-w src` of the user's own tree got "sudo chown -R" to the user it already was;
    a workspace called `my ws` got a chown hint that, pasted, changed two other paths."""
    import shlex

    from espdock.images.containers import permission_error

    root = tmp_path / "my ws"
    (root / "install/talker").mkdir(parents=True)
    os.chown(root / "install", 4242, 4242)
    os.chown(root / "install/talker", 4242, 4242)
    other = permission_error(PermissionError(13, "denied", str(root / "install/talker/x")), (1000, 1000), root)
    assert f"`sudo chown -R 1000:1000 {shlex.quote(str(root / 'install'))}`" in other.hint
    own = permission_error(PermissionError(13, "denied", str(root / "install/talker/x")), (4242, 4242), root)
    assert "its owner, but its mode does not let it write" in own.message and "chown" not in own.hint
    assert f"`chmod u+w {shlex.quote(str(root / 'install/talker'))}`" in own.hint
    # A checkout another user owns down to its root (`git clone` as root, built by a user): the
    # hint named a literal PATH, and blamed the engine for files no container wrote.
    checkout = tmp_path / "checkout"
    checkout.mkdir()
    os.chown(checkout, 0, 0)
    theirs = permission_error(PermissionError(13, "denied", str(checkout / "build")), (1000, 1000), checkout)
    assert f"(owner uid 0, mode {checkout.stat().st_mode & 0o7777:04o}, its directory)" in theirs.message
    # A read-only build dir: named, not the temporary file espdock was about to write in it.
    stamps = checkout / "build/..espdock-colcon-stamps.json.3112.tmp"
    stamps.parent.mkdir()
    read_only = permission_error(PermissionError(13, "denied", str(stamps)), (1000, 1000), checkout)
    assert f"permission denied on {stamps.parent} (owner uid 0" in read_only.message, read_only.message
    assert f"`sudo chown -R 1000:1000 {checkout}`), or work in a copy of your own" in theirs.hint, theirs.hint


def test_no_space_left_where_the_workspace_disk_has_room_is_a_full_disk_not_a_bug(ws, monkeypatch):
    """build/ on a filesystem of its own, full: colcon's ENOSPC in espdock's own write was exit 70."""
    import errno

    from espdock.errors import DiskFull

    engine = FakeEngine(run_script=colcon_installs(ws))

    def no_space(base, args):
        raise OSError(errno.ENOSPC, "No space left on device", str(base / ".espdock-colcon-args"))

    monkeypatch.setattr("espdock.ros.steps.record_build_args", no_space)
    with pytest.raises(DiskFull) as err:
        runner(engine).run(Plan(ws, (COLCON,)))
    assert err.value.exit_code == 7 and f"the disk holding {ws.ws_dir / 'build'}" in err.value.message


def test_an_image_build_that_cannot_make_the_docker_cli_config_dir_names_docker_config():
    """HOME read-only: every image build failed with `mkdir ~/.docker: permission denied` and the
    hint to read the build output, which had nothing more."""
    from espdock.images.build_failures import buildkit_hint

    for why in ("permission denied", "read-only file system"):
        hint = buildkit_hint([f"mkdir /home/ci/.docker: {why}"])
        assert "config dir /home/ci/.docker" in hint and "DOCKER_CONFIG" in hint, why


def test_a_build_tree_linked_out_of_the_workspace_is_refused_naming_it(ws, tmp_path_factory):
    """`ln -s ../scratch/build build`: colcon failed on "FileNotFoundError: /workspace/build/espdock-ros",
    with the hint to check the options after `--` that the user never gave."""
    from espdock.errors import WorkspaceError

    elsewhere = tmp_path_factory.mktemp("scratch-build")
    (ws.ws_dir / "build").symlink_to(elsewhere)
    engine = FakeEngine(run_script=colcon_installs(ws))
    with pytest.raises(WorkspaceError, match=r"build links to .*scratch-build0, outside the workspace") as err:
        runner(engine).run(Plan(ws, (COLCON,)))
    assert err.value.exit_code == 2 and engine.runs == []


def test_the_not_pulled_hint_is_for_a_base_image_that_failed_to_load_not_any_failed_step():
    """A RUN that failed after the base image's metadata loaded was hinted "debian:... is not here
    and could not be pulled", of an image the engine had."""
    from espdock.images.build_failures import buildkit_hint

    loaded = "#2 [internal] load metadata for docker.io/library/debian:bookworm-slim"
    ran = [
        loaded,
        "#2 DONE 0.0s",
        '#7 ERROR: process "/bin/sh -c ./setup.sh" did not complete successfully: exit code: 1',
    ]
    assert "could not be pulled" not in buildkit_hint(ran)
    # Compose's build (the service `image`, as espdock names it) with no registry reachable, as here.
    missing = [
        "#3 [image internal] load metadata for docker.io/library/debian:nope",
        '#3 ERROR: failed to do request: Head "https://registry-1.docker.io/v2/library/debian/manifests/nope": '
        "dial tcp: lookup registry-1.docker.io: no such host",
    ]
    assert buildkit_hint(missing).startswith("docker.io/library/debian:nope is not here and could not be pulled")
    solver = "ERROR: failed to solve: debian:nope: failed to resolve source metadata for docker.io/library/debian:nope"
    assert buildkit_hint([missing[0], solver]).startswith("docker.io/library/debian:nope is not here")


def test_a_node_run_as_a_background_job_of_the_terminal_forwards_neither_it_nor_its_keys(tmp_path):
    """`espdock run PKG EXE &` at a terminal: the docker CLI set the terminal raw and read it, and
    the shell's job control stopped it ("Stopped (tty output)") before the node started, until `fg`.
    In the foreground, the terminal is forwarded as before."""
    import pty

    script = (
        "import os, sys, fcntl, termios\n"
        "from espdock.images.engine import in_background\n"
        "from espdock.images.specs import run_argv, RunSpec\n"
        "fcntl.ioctl(0, termios.TIOCSCTTY, 0)\n"  # the pty is this session's terminal, this its foreground
        "spec = RunSpec(image='img', argv=('node',), workdir='/')\n"
        "def say(out):\n"
        "    print(in_background(), '--interactive' in run_argv('docker', 'n', spec, stdin=not in_background()),\n"
        "          file=open(out, 'w'))\n"
        "say(sys.argv[1])\n"
        "if os.fork() == 0:\n"
        "    os.setpgid(0, 0)\n"  # a job the shell put in the background: a group that is not the terminal's
        "    say(sys.argv[2])\n"
        "    os._exit(0)\n"
        "os.wait()\n"
    )
    primary, secondary = pty.openpty()
    try:
        subprocess.run([sys.executable, "-c", script, str(tmp_path / "fg"), str(tmp_path / "bg")], stdin=secondary,
                       start_new_session=True, check=True, timeout=30)  # fmt: skip
    finally:
        os.close(primary)
        os.close(secondary)
    assert (tmp_path / "fg").read_text().split() == ["False", "True"]
    assert (tmp_path / "bg").read_text().split() == ["True", "False"]


def test_a_script_with_windows_line_endings_is_named_as_such():
    """A Windows checkout's docker/apt-install.sh: the image build failed on dash's "set: Illegal
    option -" and the hint said to read the output."""
    from espdock.images.build_failures import buildkit_hint

    dash = ["#9 0.213 /usr/local/bin/apt-install: 6: set: Illegal option -", "#9 ERROR: process did not complete"]
    assert "Windows line endings (CRLF)" in buildkit_hint(dash)
    env = ["#9 0.2 /usr/bin/env: \u2018python3\r\u2019: No such file or directory", "#9 ERROR: exit code: 127"]
    assert "Windows line endings (CRLF)" in buildkit_hint(env)
    bash = ["#9 0.2 /tmp/setup.sh: line 2: $'\\r': command not found"]
    assert "Windows line endings (CRLF)" in buildkit_hint(bash)
    assert "Windows line endings" not in buildkit_hint(["#9 0.2 set: -o: invalid option", "#9 ERROR"])


def test_a_copy_back_onto_an_install_tree_mounted_on_its_own_is_refused_leaving_it(ws, tmp_path):
    """install/ a bind mount of its own (another disk for the build outputs): the copy back's
    rename failed with EXDEV/EBUSY, and espdock said "a bug in espdock" (exit 70)."""
    import subprocess
    import sys

    if subprocess.run(["unshare", "-m", "true"], capture_output=True, check=False).returncode != 0:
        pytest.skip("no mount namespace here (unshare -m needs CAP_SYS_ADMIN)")
    install = ws.ws_dir / "install"
    (install / "app").mkdir(parents=True)
    (install / "app/old.txt").write_text("old")
    made = tmp_path / "made/install/app"
    made.mkdir(parents=True)
    (made / "new.txt").write_text("new")
    with tarfile.open(tmp_path / "install.tar", "w") as tar:
        tar.add(tmp_path / "made/install", arcname="install")
    program = (
        "import os, sys; from pathlib import Path; from espdock.images import volume; from espdock.errors import "
        "WorkspaceError\ntry:\n"
        "    volume.replace_tree(Path(sys.argv[1]), Path(sys.argv[2]), (os.getuid(), os.getgid()))\n"
        "except WorkspaceError as exc:\n    print(exc.message); print(exc.hint)"
    )
    script = f'mount --bind "{install}" "{install}" && exec "$0" -c "$1" "$2" "$3"'
    said = subprocess.run(
        ["unshare", "-m", "sh", "-c", script, sys.executable, program, str(tmp_path / "install.tar"), str(install)],
        capture_output=True, text=True, check=False,
    )  # fmt: skip
    assert said.returncode == 0, said.stderr
    assert f"{install} is a mount point of its own" in said.stdout and "left as it was" in said.stdout, said.stdout
    assert (install / "app/old.txt").read_text() == "old"


def test_a_build_the_cli_config_s_proxy_did_not_let_through_names_that_proxy():
    """apt behind the proxy `proxies` names, the proxy down: the hint said to name a proxy in
    the Docker CLI's config, where the user had named this one."""
    from espdock.images.build_failures import buildkit_hint

    line = "8.140   Could not connect to 172.17.0.1:3199 (172.17.0.1). - connect (111: Connection refused)"
    tail = [line, "8.228 E: Unable to locate package acpitool"]
    proxies = {"HTTP_PROXY": "http://alice:S3cret@172.17.0.1:3199", "http_proxy": "http://alice:S3cret@172.17.0.1:3199"}
    hint = buildkit_hint(tail, line, proxies)
    assert hint.startswith("The proxy the Docker CLI's config names (HTTP_PROXY 172.17.0.1:3199"), hint
    assert "S3cret" not in hint and "alice" not in hint
    # A proxy whose name does not resolve: apt names it alone, quoted.
    unresolved = "0.915 Could not resolve 'proxy.invalid'"
    named = {"HTTPS_PROXY": "http://user:secret@proxy.invalid:3128"}
    hint = buildkit_hint([unresolved], unresolved, named)
    assert hint.startswith("The proxy the Docker CLI's config names (HTTPS_PROXY proxy.invalid:3128"), hint
    # Another proxy named there, or none: the failure is the network's.
    for other in ({"HTTP_PROXY": "http://10.0.0.9:3128"}, {}):
        assert buildkit_hint(tail, line, other).startswith("A step of the build could not reach the network")


@pytest.mark.parametrize(
    ("host", "kind", "rootless", "load"),
    [
        (
            "unix:///run/user/1000/docker.sock",
            "docker",
            True,
            "DOCKER_HOST=unix:///run/user/1000/docker.sock docker load",
        ),
        ("unix:///run/user/1000/podman/podman.sock", "podman", True, "podman load"),
    ],
)
def test_a_user_s_rootless_engine_without_the_base_image_is_told_to_load_it_there_not_to_sudo(
    monkeypatch, host, kind, rootless, load
):
    """`sudo espdock setup`, the hint for a rootless Docker or Podman user, ran espdock as root,
    whose environment has no DOCKER_HOST: it provisioned root's engine (starting one), not the user's."""
    monkeypatch.setattr(bootstrap, "_can_manage_engine", lambda: False)
    ref = "debian:bookworm-slim"
    with pytest.raises(bootstrap.ImageBuildError) as err:
        bootstrap._make_base_image(
            FakeEngine(host=host, kind=kind, rootless=rootless), ref, Config(), lambda text: None
        )
    assert "sudo espdock setup`" not in err.value.hint.split("(")[0], err.value.hint
    assert f"`sudo docker save {ref} | {load}`" in err.value.hint, err.value.hint
    with pytest.raises(bootstrap.ImageBuildError) as rootful:
        bootstrap._make_base_image(FakeEngine(host=DEFAULT_HOST), ref, Config(), lambda text: None)
    assert rootful.value.hint.startswith("Run `sudo espdock setup` once"), "the machine's own engine: root's is it"
