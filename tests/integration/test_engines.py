"""Engines other than the local one: an engine reached over TCP that does not share the host's
files (what DOCKER_HOST=tcp://..., ssh://... and a docker:dind service are), and the same engine
where it sees the workspace at the same path (what GitLab's shared builds directory gives).

The engine is a private dockerd (tests/integration/test_faults.py's) in network and mount
namespaces of its own: a tmpfs over one directory hides the workspaces under it from the engine,
as another machine's disk would; workspaces elsewhere it sees at their own paths. espdock reaches
it only over TCP, through a forwarder to its socket.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import signal
import socket
import ssl
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from espdock.build.plan import EnsureImage
from espdock.cli.core import build_plan
from espdock.config import Config, load_config, resolve_ca_bundle
from espdock.layout import firmware_install_dir
from espdock.workspace import find_workspace
from tests import sshd
from tests.conftest import REPO, espdock, python_workspace
from tests.idf_contract_double.build import use_double
from tests.integration.test_faults import (  # noqa: F401 (seeded_data_root: a fixture)
    PrivateEngine,
    drop_private_engine,
    kept_data_root,
    private_home,
    seeded_data_root,
)

pytestmark = [pytest.mark.engine, pytest.mark.slow]


class TcpForwarder:
    """127.0.0.1:PORT, each connection passed byte for byte to a unix socket. With TLS (a server
    context), the connections are TLS as dockerd's with --tlsverify are: the server's certificate,
    and the client's checked against the context's CA."""

    def __init__(self, target: Path, tls: ssl.SSLContext | None = None) -> None:
        self._target = str(target)
        self._tls = tls
        self._server = socket.create_server(("127.0.0.1", 0))
        self.port = self._server.getsockname()[1]
        threading.Thread(target=self._accept, daemon=True).start()

    def _accept(self) -> None:
        while True:
            try:
                client, _ = self._server.accept()
            except OSError:
                return
            threading.Thread(target=self._connect, args=(client,), daemon=True).start()

    def _connect(self, client: socket.socket) -> None:
        upstream = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            if self._tls is not None:
                client = self._tls.wrap_socket(client, server_side=True)
            upstream.connect(self._target)
        except OSError:
            client.close()
            upstream.close()
            return
        pumps = [
            threading.Thread(target=self._pump, args=(source, sink), daemon=True)
            for source, sink in ((client, upstream), (upstream, client))
        ]
        for pump in pumps:
            pump.start()
        for pump in pumps:
            pump.join()
        # Closed here, once neither pump reads them: an SSL socket closed by one thread while the
        # other was in its read crashed the interpreter (a segfault, the worker lost).
        for end in (client, upstream):
            end.close()

    @staticmethod
    def _pump(source: socket.socket, sink: socket.socket) -> None:
        with contextlib.suppress(OSError):
            while data := source.recv(65536):
                sink.sendall(data)
        # TLS has no half close: the engine's end ends the client's connection whole. A shutdown of
        # the plain socket under it wakes the other pump's read, which then ends too.
        with contextlib.suppress(OSError):
            if isinstance(sink, ssl.SSLSocket):
                socket.socket.shutdown(sink, socket.SHUT_RDWR)
            else:
                sink.shutdown(socket.SHUT_WR)
        if not isinstance(source, ssl.SSLSocket):  # a failed send: the other way cannot go on either
            with contextlib.suppress(OSError):
                source.shutdown(socket.SHUT_RD)

    def close(self) -> None:
        self._server.close()


class RemoteEngine(PrivateEngine):
    """A private dockerd that does not see HIDDEN, reached over TCP. A tmpfs of its own mount
    namespace lies over HIDDEN, with an empty ws-root: there, the engine's machine has the same path
    holding another tree; at any other path under HIDDEN it has nothing."""

    def __init__(self, home: Path, hidden: Path) -> None:
        super().__init__(home)
        self.hidden = hidden
        self.forwarder: TcpForwarder | None = None

    def start(self) -> None:
        # dockerd's own containerd, in the same namespaces: runc resolves bind mounts there.
        self.launch(["unshare", "--net", "--mount", "--propagation", "private", "--",
                     "sh", "-c", 'mount -t tmpfs -o size=16m espdock-hidden "$0" && mkdir "$0/ws-root" && exec "$@"',
                     str(self.hidden),
                     *self.dockerd()])  # fmt: skip
        self.forwarder = TcpForwarder(self.socket)
        self.env = {**os.environ, "DOCKER_HOST": f"tcp://127.0.0.1:{self.forwarder.port}"}

    def stop(self) -> None:
        if self.forwarder is not None:
            self.forwarder.close()
        super().stop()

    def created(self, since: float, label: str) -> list[str]:
        """Containers created since SINCE (epoch seconds) that carry LABEL."""
        events = self.docker("events", "--since", f"{since:.3f}", "--until", f"{time.time():.3f}", "--filter",
                             "event=create", "--filter", f"label={label}", "--format", "{{.ID}}")  # fmt: skip
        return events.stdout.split()


@pytest.fixture(scope="module")
def hidden(tmp_path_factory) -> Path:
    """The directory the private engine does not see."""
    return tmp_path_factory.mktemp("hidden")


@pytest.fixture(scope="module")
def firmware_ws(engine, hidden) -> tuple[Path, dict[str, str], tuple[str, ...]]:
    """blink_fw in a workspace the private engine cannot see, built on the shared engine (it has a
    network; the private one has none); the settings that select the IDF contract double, which
    stands in for espressif/idf (not pullable here); the IDF and micro-ROS images it builds with."""
    root = hidden / "ws-firmware"
    shutil.copytree(REPO / "tests/firmware_packages/blink_fw", root / "src/blink_fw")
    (root / "espdock.toml").write_text("[espdock]\n")
    (root / "docker/idf").mkdir(parents=True)
    env = use_double(engine, resolve_ca_bundle(Config(), os.environ), lambda line: None, root)
    local = espdock("build", cwd=root, env=env)
    assert local.returncode == 0, local.stdout[-3000:] + local.stderr
    ws = find_workspace(root)
    config = load_config(ws.root, {**os.environ, **env})
    plan = build_plan(ws.with_layout(config.package_paths, config.colcon_root), config, [])
    images = (env["ESPDOCK_IDF_IMAGE"], *(step.spec.tag for step in plan.steps if isinstance(step, EnsureImage)))
    yield root, env, images
    engine.remove_containers({"io.espdock.workspace": str(root)})


@pytest.fixture(scope="module")
def engine_data_root(engine, seeded_data_root, firmware_ws) -> Path:  # noqa: F811
    """seeded_data_root with firmware_ws's IDF and micro-ROS images (a gigabyte: 25 s to load,
    where the copy onto the engine's tmpfs takes a second more)."""
    return kept_data_root(engine, "espdock-test-idf-engine", firmware_ws[2], base=seeded_data_root)


@pytest.fixture(scope="module")
def tcp_engine(engine_data_root, hidden) -> Iterator[RemoteEngine]:
    if shutil.which("dockerd") is None or shutil.which("unshare") is None:
        pytest.skip("no dockerd or unshare here")
    engine = RemoteEngine(private_home(), hidden)
    try:
        engine.seed(engine_data_root)
        engine.start()
        yield engine
    finally:
        drop_private_engine(engine)


ONCE = '''"""Prints its word once and exits."""


def main() -> None:
    print("word: one")
'''


def once_workspace(dest: Path) -> Path:
    """python_workspace with an executable `once` that prints a word and exits."""
    root = python_workspace(dest)
    package = root / "ws/src/beacon_nodes"
    (package / "beacon_nodes/once.py").write_text(ONCE)
    setup = package / "setup.py"
    entry = '"once = beacon_nodes.once:main",\n            "beacon = '
    setup.write_text(setup.read_text().replace('"beacon = ', entry))
    return root


def idle_package(directory: Path) -> None:
    """An ament_python package of nothing but its manifest and marker, with no dependency."""
    name = directory.name
    (directory / "resource").mkdir(parents=True)
    (directory / "resource" / name).touch()
    (directory / "package.xml").write_text(
        f'<?xml version="1.0"?>\n<package format="3">\n  <name>{name}</name>\n  <version>0.0.0</version>\n'
        f'  <description>Idle.</description>\n  <maintainer email="robot@example.com">Robot</maintainer>\n'
        f"  <license>Apache-2.0</license>\n  <export><build_type>ament_python</build_type></export>\n</package>\n"
    )
    (directory / "setup.py").write_text(
        f"from setuptools import setup\n\nsetup(name={name!r}, version='0.0.0', data_files=[\n"
        f"    ('share/ament_index/resource_index/packages', ['resource/{name}']),\n"
        f"    ('share/{name}', ['package.xml']),\n])\n"
    )


def edit_word(root: Path, word: str) -> None:
    once = root / "ws/src/beacon_nodes/beacon_nodes/once.py"
    once.write_text(re.sub(r'print\("word: [^"]*"\)', f'print("word: {word}")', once.read_text()))


def installed_word(root: Path) -> str:
    found = list((root / "ws/install/beacon_nodes").rglob("once.py"))
    assert found, "once.py is not installed"
    return found[0].read_text()


def test_a_workspace_the_engine_cannot_see_is_exit_8_in_mount_mode_and_never_ships_the_old_install(tcp_engine, engine):
    root = once_workspace(tcp_engine.hidden / "ws-root")
    local = espdock("build", cwd=root)  # the shared engine sees it: an install of the old code
    assert local.returncode == 0, local.stdout + local.stderr
    edit_word(root, "two")

    remote = espdock("build", "--workspace-mode", "mount", cwd=root, env=tcp_engine.env)
    assert remote.returncode == 8, remote.stdout + remote.stderr
    assert f"Docker engine at {tcp_engine.env['DOCKER_HOST']} does not see the workspace {root}" in remote.stderr
    assert "CI_PROJECT_DIR" in remote.stderr
    assert "--workspace-mode volume" in remote.stderr
    assert "Traceback" not in remote.stderr
    assert "word: one" in installed_word(root)  # the old install is left, and nothing was made from it
    assert tcp_engine.containers(root) == []
    runtime = tcp_engine.docker("images", "-q", "--filter", "reference=espdock/ws-root").stdout.split()
    assert runtime == [], "a runtime image was made on the engine that never built the code"
    engine.remove_containers({"io.espdock.workspace": str(root)})


def test_the_docker_cli_s_current_context_is_the_engine_espdock_uses(tcp_engine, tmp_path):
    """Rootless Docker's setup tool, Docker Desktop and colima pick a context and leave DOCKER_HOST
    unset: `docker` and `docker compose` then talk to the context's engine, so espdock must too."""
    config = {"DOCKER_CONFIG": str(tmp_path / "docker"), "DOCKER_HOST": ""}
    host = tcp_engine.env["DOCKER_HOST"]
    for argv in (["create", "remote", "--docker", f"host={host}"], ["use", "remote"]):
        subprocess.run(["docker", "context", *argv], env={**os.environ, **config}, capture_output=True, check=True)
    root = once_workspace(tcp_engine.hidden / "ws-context")
    build = espdock("build", "--workspace-mode", "mount", cwd=root, env=config)
    assert build.returncode == 8, build.stdout + build.stderr
    assert f"Docker engine at {host} does not see the workspace {root}" in build.stderr
    assert not (root / "ws/install").exists(), "built on the default socket's engine, not the context's"


def test_the_same_engine_seeing_the_workspace_builds_rebuilds_an_edit_and_runs_it(tcp_engine, tmp_path):
    root = once_workspace(tmp_path / "ws-root")  # not under the hidden directory: the engine sees it
    first = espdock("build", cwd=root, env=tcp_engine.env)
    assert first.returncode == 0, first.stdout + first.stderr
    assert "1 package(s) built" in first.stdout, first.stdout

    edit_word(root, "three")
    since = time.time()
    again = espdock("build", cwd=root, env=tcp_engine.env)
    assert again.returncode == 0, again.stdout + again.stderr
    assert "word: three" in installed_word(root)
    # The engine was asked once whether it sees the workspace, not once per build.
    assert tcp_engine.created(since, "io.espdock.step=mount-check") == []
    assert tcp_engine.created(since, "io.espdock.step=colcon")

    run = espdock("run", "beacon_nodes", "once", cwd=root, env=tcp_engine.env)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "word: three" in run.stdout
    assert tcp_engine.containers(root) == []


def test_packages_linked_from_outside_build_as_colcon_finds_them_and_never_the_old_install(engine, tmp_path):
    """`ln -s ~/repos/driver src/`: colcon follows links, so espdock's containers get what they
    lead to. In the workspace volume they lead nowhere: a failure, and the old install stays."""
    root = once_workspace(tmp_path / "ws-root")
    first = espdock("build", cwd=root)
    assert first.returncode == 0, first.stdout + first.stderr
    outside = tmp_path / "repos"
    shutil.move(root / "ws/src", outside)
    (root / "ws/src").symlink_to(outside)  # absolute, as ln -s ~/repos makes it
    edit_word(root, "linked")
    linked = espdock("build", cwd=root)
    assert linked.returncode == 0, linked.stdout + linked.stderr
    assert "word: linked" in installed_word(root)

    (root / "ws/src").unlink()
    (root / "ws/src").symlink_to("../../repos")  # relative: from the container's mount, elsewhere
    edit_word(root, "relative")
    relative = espdock("build", cwd=root)
    assert relative.returncode == 0, relative.stdout + relative.stderr
    assert "word: relative" in installed_word(root)

    edit_word(root, "volume")
    try:
        result = espdock("build", "--workspace-mode", "volume", cwd=root)
        assert result.returncode == 5, result.stdout + result.stderr
        assert "colcon did not find 1 of the 1 package(s) it was to build: beacon_nodes (ws/src/beacon_nodes)" in (
            result.stderr
        )
        assert "✓ colcon build" not in result.stdout
        assert "word: relative" in installed_word(root)
    finally:
        assert espdock("prune", "--volume", cwd=root).returncode == 0
        engine.remove_containers({"io.espdock.workspace": str(root)})


def test_setup_prepares_the_base_image_of_a_workspace_made_by_init(engine, tmp_path):
    """A workspace of `espdock init` has no Dockerfile.ros: its builds use espdock's, and so does setup."""
    made = espdock("init", str(tmp_path / "robot"), cwd=tmp_path)
    assert made.returncode == 0, made.stdout + made.stderr
    ready = espdock("setup", cwd=tmp_path / "robot")
    assert ready.returncode == 0, ready.stdout + ready.stderr
    assert "base image debian:bookworm-slim: present" in ready.stdout


VOLUME_UID = 4246  # who owns the volume test's workspace: espdock, run as root, builds for them


def volumes_of(tcp_engine: RemoteEngine, root: Path) -> list[str]:
    listed = tcp_engine.docker("volume", "ls", "-q", "--filter", f"label=io.espdock.workspace={root}")
    return listed.stdout.split()


def strangers(colcon_root: Path) -> list[str]:
    """What of the colcon root's outputs on the host does not belong to the workspace's owner."""
    return [str(p) for space in ("build", "install", "log") for p in (colcon_root / space).rglob("*")
            if p.lstat().st_uid != VOLUME_UID or p.lstat().st_gid != VOLUME_UID]  # fmt: skip


def test_volume_mode_builds_where_the_engine_cannot_see_rebuilds_edits_and_never_ships_the_old_install(
    tcp_engine, engine
):
    root = once_workspace(tcp_engine.hidden / "ws-volume")
    idle_package(root / "ws/src/idle_py")  # a package no edit touches
    subprocess.run(["chown", "-R", f"{VOLUME_UID}:{VOLUME_UID}", str(root)], check=True)
    local = espdock("build", cwd=root)  # the shared engine sees it: an install of the old code
    assert local.returncode == 0, local.stdout + local.stderr
    edit_word(root, "two")

    # auto: the engine does not see the workspace, so espdock keeps it in a volume there: a new
    # one, whose build builds every package
    remote = espdock("build", cwd=root, env=tcp_engine.env)
    assert remote.returncode == 0, remote.stdout + remote.stderr
    assert "2 package(s) built" in remote.stdout, remote.stdout
    assert "word: two" in installed_word(root)
    assert len(volumes_of(tcp_engine, root)) == 1
    run = espdock("run", "beacon_nodes", "once", cwd=root, env=tcp_engine.env)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "word: two" in run.stdout
    assert strangers(root / "ws") == []

    # A firmware package's install beside the ROS packages', as the host's install step makes it
    # after the copy back (the volume's colcon never builds it).
    flashable = root / "ws/install/board/share/board/firmware/flasher_args.json"
    flashable.parent.mkdir(parents=True)
    flashable.write_text("{}\n")
    subprocess.run(["chown", "-R", f"{VOLUME_UID}:{VOLUME_UID}", str(root / "ws/install/board")], check=True)

    # A one-line edit: only it goes to the engine, and the rebuild runs the new code.
    edit_word(root, "three")
    since = time.time()
    again = espdock("build", cwd=root, env=tcp_engine.env)
    assert again.returncode == 0, again.stdout + again.stderr
    assert ": 1 file(s) sent, 0 removed" in again.stdout, again.stdout
    # Only the edited package: the manifest and the firmware install the host adds after the copy
    # back made every build on the volume a whole one; and the copy back kept the firmware (it
    # swapped in the volume's install/, which has none: `espdock flash` found nothing to flash).
    assert "1 package(s) built, 1 up to date" in again.stdout, again.stdout
    assert flashable.read_text() == "{}\n"
    assert tcp_engine.created(since, "io.espdock.step=mount-check") == []
    run = espdock("run", "beacon_nodes", "once", cwd=root, env=tcp_engine.env)
    assert "word: three" in run.stdout, run.stdout + run.stderr

    # An edit that keeps the file's size and modification time (`cp -p`, `rsync -a`): it was
    # never sent, and the volume built the old file, "built".
    once = root / "ws/src/beacon_nodes/beacon_nodes/once.py"
    kept = once.stat()
    edit_word(root, "thr3e")
    os.utime(once, ns=(kept.st_atime_ns, kept.st_mtime_ns))
    same = espdock("build", cwd=root, env=tcp_engine.env)
    assert same.returncode == 0 and ": 1 file(s) sent, " in same.stdout, same.stdout + same.stderr
    assert "word: thr3e" in installed_word(root)
    # An edit in `espdock shell` stays on the volume; the next build that builds the package builds
    # the host's file, not the shell's (a no-op's "up to date" was kept while the two differed).
    shell = subprocess.run(
        [sys.executable, "-m", "espdock", "shell"],
        input=f"sed -i 's/word: thr3e/word: shell/' /workspace/{once.relative_to(root)}\n",
        cwd=root, env={**os.environ, **tcp_engine.env}, capture_output=True, text=True, timeout=600, check=False,
    )  # fmt: skip
    assert shell.returncode == 0, shell.stdout + shell.stderr
    (root / "ws/src/beacon_nodes/beacon_nodes/more.py").write_text("MORE = 1\n")  # a build of the package
    after = espdock("build", cwd=root, env=tcp_engine.env)
    assert after.returncode == 0, after.stdout + after.stderr
    assert "word: thr3e" in installed_word(root), "the shell's edit was built"
    # A file passed in would be the engine machine's (or none): exit 8 saying so, where it was the
    # engine's "bind source path does not exist" and a hint to fix what the engine says.
    passed = espdock("run", "-v", "espdock.toml:/params/p.toml:ro", "beacon_nodes", "once", cwd=root,
                     env=tcp_engine.env)  # fmt: skip
    assert passed.returncode == 8, passed.stdout + passed.stderr
    assert "the files and devices `espdock run` passes in (--volume" in passed.stderr

    # Nothing changed: decided on the host, no container on the engine.
    since = time.time()
    noop = espdock("build", "--only", "ros", cwd=root, env=tcp_engine.env)
    assert noop.returncode == 0, noop.stdout + noop.stderr
    assert "up to date" in noop.stdout
    assert tcp_engine.created(since, "io.espdock.workspace=" + str(root)) == []
    # The tests' results would stay in the volume: refused before any build there (it built first).
    tested = espdock("test", cwd=root, env=tcp_engine.env)
    assert tested.returncode == 8, tested.stdout[-2000:] + tested.stderr
    assert "the test results `espdock test` reads must be on this machine" in tested.stderr
    assert "flasher" not in tested.stderr and "colcon build" not in tested.stdout
    assert tcp_engine.created(since, "io.espdock.workspace=" + str(root)) == []
    # Refused before the rosdep lock too: with a key the wheels image lacks and rosdep's sources
    # out of reach, the run failed on `rosdep update` and never said it could not test here.
    manifest = root / "ws/src/beacon_nodes/package.xml"
    kept = manifest.read_text()
    manifest.write_text(
        kept.replace("<exec_depend>rclpy", "<exec_depend>python3-serial</exec_depend>\n  <exec_depend>rclpy")
    )
    offline = {"ROSDISTRO_INDEX_URL": "http://127.0.0.1:9/index.yaml", "XDG_CACHE_HOME": str(tcp_engine.hidden / "c")}
    try:
        unreachable = espdock("test", cwd=root, env={**tcp_engine.env, **offline})
    finally:
        manifest.write_text(kept)
    assert unreachable.returncode == 8, unreachable.stdout[-2000:] + unreachable.stderr
    assert "must be on this machine" in unreachable.stderr and "rosdep" not in unreachable.stderr

    # A deleted source is deleted on the volume too: its module leaves the install tree.
    extra = root / "ws/src/beacon_nodes/beacon_nodes/extra.py"
    extra.write_text("WORD = 'extra'\n")
    assert espdock("build", cwd=root, env=tcp_engine.env).returncode == 0
    assert list((root / "ws/install/beacon_nodes").rglob("extra.py"))
    extra.unlink()
    gone = espdock("build", cwd=root, env=tcp_engine.env)
    assert gone.returncode == 0, gone.stdout + gone.stderr
    # Built afresh (a file removed is no newer file: make would keep its object), so the
    # package's build dir and install prefix on the volume go with it.
    assert ": 0 file(s) sent, " in gone.stdout and "building afresh what changed with no newer file" in gone.stdout
    # Only that package: the install prefix emptied on purpose made the volume's install/ another
    # than the host's, and colcon built every package of the workspace.
    assert "1 package(s) built, 1 up to date" in gone.stdout, gone.stdout
    assert not list((root / "ws/install/beacon_nodes").rglob("extra.py"))
    (name,) = volumes_of(tcp_engine, root)
    listed = tcp_engine.docker("run", "--rm", "-v", f"{name}:/w", "debian:bookworm-slim", "ls", "-a",
                               "/w/ws/src/beacon_nodes/beacon_nodes")  # fmt: skip
    assert "once.py" in listed.stdout.split()
    assert "extra.py" not in listed.stdout.split()
    assert strangers(root / "ws") == []
    assert tcp_engine.containers(root) == []

    removed = espdock("prune", "--volume", cwd=root, env=tcp_engine.env)
    assert removed.returncode == 0, removed.stdout + removed.stderr
    assert volumes_of(tcp_engine, root) == []
    edit_word(root, "four")
    # A selection on a new volume: the volume's install/ holds it alone, and swapped in whole it
    # removed the host's other packages (idle_py here), unsaid.
    afresh = espdock("build", "beacon_nodes", cwd=root, env=tcp_engine.env)
    assert afresh.returncode == 0, afresh.stdout + afresh.stderr
    assert "(new)" in afresh.stdout
    assert "word: four" in installed_word(root)
    assert (root / "ws/install/idle_py").is_dir() and flashable.read_text() == "{}\n"
    assert espdock("prune", "--volume", cwd=root, env=tcp_engine.env).returncode == 0
    # The same with colcon's own selection: a package it leaves out as told is not built either.
    edit_word(root, "five")
    skipped = espdock("build", "--", "--packages-skip", "idle_py", cwd=root, env=tcp_engine.env)
    assert skipped.returncode == 0, skipped.stdout + skipped.stderr
    assert "word: five" in installed_word(root)
    assert (root / "ws/install/idle_py").is_dir(), "a package colcon skipped was removed from the host's install/"
    assert espdock("prune", "--volume", cwd=root, env=tcp_engine.env).returncode == 0
    engine.remove_containers({"io.espdock.workspace": str(root)})


def test_volume_mode_builds_firmware_in_the_idf_image_and_installs_it_for_the_user(tcp_engine, firmware_ws):
    """The private engine holds the images the shared engine built from the IDF contract double
    (firmware_ws), and builds the firmware on the volume. Reached through its unix socket, as a
    dind sidecar's mounted socket is: espdock then talks plain HTTP to it (files in and out of the
    container included), where over TCP it uses the Docker SDK."""
    root, env, _ = firmware_ws
    subprocess.run(["chown", "-R", f"{VOLUME_UID}:{VOLUME_UID}", str(root)], check=True)
    main = root / "src/blink_fw/main/main.c"
    main.write_text(main.read_text() + "/* built on the volume */\n")

    since = time.time()
    remote = espdock("build", cwd=root, env={**env, "DOCKER_HOST": f"unix://{tcp_engine.socket}"})
    assert remote.returncode == 0, remote.stdout[-3000:] + remote.stderr
    assert tcp_engine.created(since, "io.espdock.step=idf-blink_fw")
    assert len(volumes_of(tcp_engine, root)) == 1
    firmware = root / firmware_install_dir("blink_fw")
    assert (firmware / "flasher_args.json").is_file()
    assert strangers(root) == []
    assert tcp_engine.containers(root) == []
    assert espdock("prune", "--volume", cwd=root, env=tcp_engine.env).returncode == 0


def test_an_ssh_engine_that_cannot_see_the_workspace_builds_it_in_the_volume(tcp_engine, tmp_path_factory):
    """DOCKER_HOST=ssh://build-box, the usual way to a remote engine: the workspace goes to the
    volume and the build comes back through the ssh connection espdock keeps for the command."""
    if sshd.missing():
        pytest.skip(sshd.missing())
    root = once_workspace(tcp_engine.hidden / "ws-ssh")
    config = root / "espdock.toml"  # no runtime image: its build goes through compose, not espdock's connection
    config.write_text(config.read_text().replace("runtime_image = true", "runtime_image = false"))
    subprocess.run(["chown", "-R", f"{VOLUME_UID}:{VOLUME_UID}", str(root)], check=True)
    with sshd.serve(tmp_path_factory.mktemp("ssh"), {"DOCKER_HOST": f"unix://{tcp_engine.socket}"}) as ssh:
        first = espdock("build", cwd=root, env=ssh.env)
        assert first.returncode == 0, first.stdout + first.stderr
        assert "(new)" in first.stdout and "1 package(s) built" in first.stdout, first.stdout
        assert len(volumes_of(tcp_engine, root)) == 1
        edit_word(root, "over ssh")
        again = espdock("build", cwd=root, env=ssh.env)
        assert again.returncode == 0, again.stdout + again.stderr
        assert ": 1 file(s) sent, 0 removed" in again.stdout, again.stdout
        assert "word: over ssh" in installed_word(root)
        assert strangers(root / "ws") == []
        assert tcp_engine.containers(root) == []
        assert espdock("prune", "--volume", cwd=root, env=ssh.env).returncode == 0
        assert volumes_of(tcp_engine, root) == []


def word_now(root: Path) -> str:
    """installed_word, or "" while install/ is being swapped."""
    with contextlib.suppress(OSError, AssertionError):
        return installed_word(root)
    return ""


def test_ctrl_c_as_install_comes_back_from_the_volume_does_not_make_the_next_build_a_whole_one(tcp_engine):
    """Ctrl-C the moment the build's install/ came back from the workspace volume: the record of the
    copy was not yet written, so the next build took install/ for one changed by hand and built
    every package again, without a word of why."""
    root = once_workspace(tcp_engine.hidden / "ws-copied-back")
    idle_package(root / "ws/src/idle_py")
    first = espdock("build", "--only", "ros", cwd=root, env=tcp_engine.env)
    assert first.returncode == 0, first.stdout + first.stderr
    edit_word(root, "six")
    argv = [sys.executable, "-m", "espdock", "build", "--only", "ros"]
    with subprocess.Popen(argv, cwd=root, env={**os.environ, **tcp_engine.env}, stdin=subprocess.DEVNULL,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) as build:  # fmt: skip
        deadline = time.monotonic() + 120
        while "word: six" not in word_now(root):
            assert build.poll() is None and time.monotonic() < deadline, "install/ never came back"
            time.sleep(0.002)
        build.send_signal(signal.SIGINT)
        output, _ = build.communicate(timeout=60)
    assert build.returncode in (0, 130), output
    again = espdock("build", "--only", "ros", cwd=root, env=tcp_engine.env)
    said = " ".join(again.stdout.split())
    assert again.returncode == 0, said + again.stderr
    assert "2 package(s) built" not in said and "every package is built there again" not in said, said
    assert "word: six" in installed_word(root)
    assert espdock("prune", "--volume", cwd=root, env=tcp_engine.env).returncode == 0


def test_an_interrupted_volume_build_leaves_the_old_install_whole_and_no_container(tcp_engine):
    root = once_workspace(tcp_engine.hidden / "ws-interrupt")
    first = espdock("build", cwd=root, env=tcp_engine.env)
    assert first.returncode == 0, first.stdout + first.stderr
    edit_word(root, "five")
    argv = [sys.executable, "-m", "espdock", "build"]
    with subprocess.Popen(argv, cwd=root, env={**os.environ, **tcp_engine.env}, stdin=subprocess.DEVNULL,
                          stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True) as build:  # fmt: skip
        deadline = time.monotonic() + 120
        while not tcp_engine.docker("ps", "-q", "--filter", f"label=io.espdock.workspace={root}", "--filter",
                                    "label=io.espdock.step=colcon").stdout.split():  # fmt: skip
            assert build.poll() is None and time.monotonic() < deadline, "colcon never started"
            time.sleep(0.1)
        build.send_signal(signal.SIGINT)
        output, _ = build.communicate(timeout=60)
    assert build.returncode == 130, output
    assert tcp_engine.containers(root) == []
    assert "word: one" in installed_word(root)  # the old tree, whole: nothing of the new one came back
    assert [p.name for p in (root / "ws").iterdir() if p.name.startswith(".")] == []
    again = espdock("build", cwd=root, env=tcp_engine.env)
    assert again.returncode == 0, again.stdout + again.stderr
    assert "word: five" in installed_word(root)
    assert espdock("prune", "--volume", cwd=root, env=tcp_engine.env).returncode == 0
