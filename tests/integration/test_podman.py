"""Podman (Debian's 4.3), rootful, through its Docker API socket (`podman system service`).

Podman has no BuildKit endpoint, so espdock builds with the API's own builder (Buildah), passing
the CA bundle as a build secret; its compat import takes the tag only inside `repo`. The service
runs on a socket, storage root and run root of this module's own, with a containers.conf that
lowers the default rlimits (rootful Podman raises RLIMIT_NOFILE/NPROC by default, which machines
of this kind refuse). The workspace's ROS image is a small Dockerfile.ros over the shared engine's
ROS images (loaded with docker save | docker load): the wheels image would take minutes to build.
"""

from __future__ import annotations

import os
import shutil
import signal
import socket
import subprocess
import tarfile
import tempfile
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from espdock.errors import ContainerError
from espdock.images import engine as engine_module
from espdock.images.engine import Engine
from espdock.images.specs import RunSpec
from tests.conftest import (
    copy_images,
    espdock,
    images_key,
    kept_in_temp,
    owners,
    python_workspace,
    ros_build_tag,
    ros_runtime_tag,
    shared_ros_images,
)
from tests.integration.test_engines import TcpForwarder, edit_word, installed_word, once_workspace
from tests.integration.test_faults import copy_onto_tmpfs

pytestmark = [pytest.mark.engine, pytest.mark.slow]


def runtime_conf() -> str:
    """containers.conf's [engine] table for this host's cgroups. With hybrid cgroups (v1
    controllers, and a cgroup2 tree at /sys/fs/cgroup/unified holding one: hugetlb on some of
    these machines), Podman's default runtime crun refuses every container ("cgroups in hybrid
    mode not supported"); runc, which Debian's docker.io brings, runs them, as for Docker."""
    unified = Path("/sys/fs/cgroup/unified/cgroup.controllers")
    if unified.is_file() and unified.read_text().strip() and shutil.which("runc"):
        return '[engine]\nruntime = "runc"\n'
    return ""


ULIMITS = '[containers]\ndefault_ulimits = ["nofile=20000:20000", "nproc=32768:32768"]\n' + runtime_conf()


class PodmanService:
    def __init__(self, home: Path, runroot: Path, conf: str = ULIMITS) -> None:
        self.home = home
        self.runroot = runroot  # Podman refuses one longer than 50 characters
        self.tmpdir = runroot / "libpod"
        self.socket = home / "podman.sock"
        self.env = {**os.environ, "DOCKER_HOST": f"unix://{self.socket}"}
        (home / "containers.conf").write_text(conf)
        self.process: subprocess.Popen | None = None

    def start(self, root: Path) -> None:
        # Run root and libpod's tmp dir of this module's own: not the machine's /run/libpod.
        argv = ["podman", "--root", str(root / "storage"), "--runroot", str(self.runroot),
                "--tmpdir", str(self.tmpdir), "system", "service", "--time=0", f"unix://{self.socket}"]  # fmt: skip
        # Its process's temp dir too (Podman's default is /var/tmp): what it leaves there shows.
        self.process_tmp = self.home / "service-tmp"
        self.process_tmp.mkdir(exist_ok=True)
        env = {**os.environ, "CONTAINERS_CONF": str(self.home / "containers.conf"), "TMPDIR": str(self.process_tmp)}
        with open(self.home / "service.log", "ab") as log:
            self.process = subprocess.Popen(argv, env=env, stdout=log, stderr=subprocess.STDOUT,
                                            start_new_session=True)  # fmt: skip
        deadline = time.monotonic() + 60
        while self.docker("version", check=False).returncode != 0:
            if self.process.poll() is not None or time.monotonic() > deadline:
                pytest.skip(f"podman system service did not start here: {(self.home / 'service.log').read_text()}")
            time.sleep(0.3)

    def docker(self, *args: str, check: bool = True, **options) -> subprocess.CompletedProcess:
        return subprocess.run(["docker", *args], env=self.env, capture_output=True, text=True, check=check,
                              **options)  # fmt: skip

    def stop(self) -> None:
        if self.process is not None and self.process.poll() is None:
            os.killpg(self.process.pid, signal.SIGTERM)
            self.process.wait(timeout=30)


def podman_storage(engine: Engine, images: tuple[str, ...]) -> Path:
    """A stopped Podman's storage root holding IMAGES (the shared engine's), for the module's
    Podman to start from a copy of.

    Loading them (`docker save | docker load`, about a gigabyte) took 40 s of the module's time at
    every run, a copy a few seconds; so it is made once for each set of image IDs and kept in the
    temp dir for the next run, as test_faults.py keeps its private engines' data root. libpod's own
    database is left out: it records the storage root's path, and the copy's differs."""

    def make(place: Path) -> None:
        runroot = Path(tempfile.mkdtemp(prefix="pm-", dir="/tmp"))
        loader = PodmanService(place, runroot)
        try:
            loader.start(place)
            copy_images(images, loader.env)
        finally:
            loader.stop()
            subprocess.run(["umount", "--lazy", str(place / "storage/overlay")], capture_output=True, check=False)
            shutil.rmtree(runroot, ignore_errors=True)
        shutil.rmtree(place / "storage/libpod")

    return kept_in_temp("espdock-test-podman", images_key(engine, images), make) / "storage"


@pytest.fixture(scope="module")
def podman(engine, tmp_path_factory) -> Iterator[PodmanService]:
    if shutil.which("podman") is None:
        pytest.skip("podman is not installed (tests/install-system-deps.sh installs it)")
    home = tmp_path_factory.mktemp("podman")
    kept = podman_storage(engine, shared_ros_images(engine, python_workspace(home / "seed")))
    runroot = Path(tempfile.mkdtemp(prefix="pm-", dir="/tmp"))
    service = PodmanService(home, runroot)
    try:
        copy_onto_tmpfs(kept, home / "storage")
        service.start(home)
        yield service
    finally:
        service.stop()
        reset = ["system", "reset", "--force"]
        subprocess.run(["podman", "--root", str(home / "storage"), "--runroot", str(runroot), "--tmpdir",
                        str(service.tmpdir), *reset], capture_output=True, check=False)  # fmt: skip
        # Podman's overlay driver mounts its layer directory on itself: gone with it, pytest can remove it.
        subprocess.run(["umount", "--lazy", str(home / "storage/overlay")], capture_output=True, check=False)
        subprocess.run(["umount", "--lazy", str(home / "storage")], capture_output=True, check=False)
        shutil.rmtree(runroot, ignore_errors=True)


def small_ros_image(root: Path, seed: Path) -> None:
    """Dockerfile.ros: the build and runtime stages over the shared engine's ROS images, the build
    stage proving that the CA bundle reached it as a secret."""
    (root / "Dockerfile.ros").write_text(
        f"ARG BASE_IMAGE={ros_build_tag(seed)}\nARG ROSDEP_OS=debian:bookworm\n"
        "FROM ${BASE_IMAGE} AS build\n"
        "RUN --mount=type=secret,id=ca_bundle grep -q espdock-test-ca /run/secrets/ca_bundle && touch /opt/ca-seen\n"
        f"FROM {ros_runtime_tag(seed)} AS runtime\n"
    )


def accepted_ca(place: Path) -> str:
    """A CA bundle small_ros_image's build stage accepts."""
    (place / "ca.pem").write_text("-----BEGIN CERTIFICATE-----\nespdock-test-ca\n-----END CERTIFICATE-----\n")
    return str(place / "ca.pem")


def images_built(podman: PodmanService, seed: Path, place: Path) -> None:
    """small_ros_image's images on PODMAN's storage, built there (by a workspace of their own in
    PLACE) unless an earlier test of the module left them: another Podman service on that storage
    may refuse the containers of their build."""
    root = once_workspace(place / "images")
    small_ros_image(root, seed)
    if podman.docker("image", "inspect", ros_build_tag(root), check=False).returncode != 0:
        built = espdock("build", cwd=root, env={**podman.env, "ESPDOCK_CA_BUNDLE": accepted_ca(place)})
        assert built.returncode == 0, built.stdout + built.stderr


def test_podman_builds_the_images_with_the_ca_as_a_secret_and_builds_edits_and_runs(podman, tmp_path):
    seed = python_workspace(tmp_path / "seed")
    root = once_workspace(tmp_path / "ws-root")
    small_ros_image(root, seed)
    env = {**podman.env, "ESPDOCK_CA_BUNDLE": accepted_ca(tmp_path)}

    first = espdock("build", cwd=root, env=env)
    assert first.returncode == 0, first.stdout + first.stderr
    build_image = ros_build_tag(root)
    listing = "test -f /opt/ca-seen && { ls -a / /opt; ls -a /run/secrets 2>/dev/null; true; }"
    seen = podman.docker("run", "--rm", "--entrypoint", "sh", build_image, "-c", listing, check=False)
    assert seen.returncode == 0, seen.stdout + seen.stderr
    assert ".espdock-secret" not in seen.stdout, "the CA bundle's file was left in the image"
    assert "ca_bundle" not in seen.stdout
    assert owners(root) == {os.getuid()}

    edit_word(root, "podman")
    again = espdock("build", cwd=root, env=env)
    assert again.returncode == 0, again.stdout + again.stderr
    assert "word: podman" in installed_word(root)
    run = espdock("run", "beacon_nodes", "once", cwd=root, env=env)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "word: podman" in run.stdout
    # A node that fails fails `espdock run`: the docker CLI's `run --rm` said 0 whatever the
    # container's code against Podman's compat API.
    failed = espdock("run", "beacon_nodes", "beacon", "--ros-args", "-p", "period:=fast", cwd=root, env=env)
    assert failed.returncode not in (0, 130), failed.stdout + failed.stderr
    assert podman.docker("ps", "-aq", check=False).stdout.strip() == "", "the container is removed all the same"
    # The runtime image of the build before the edit is no longer used: prune finds it. Podman's
    # disk-usage report has no labels and short tags, and its listing localhost/ names: it found none.
    pruned = espdock("prune", "--keep", "0", "--dry-run", cwd=root, env=env)
    assert pruned.returncode == 0, pruned.stdout + pruned.stderr
    assert "; no longer used by its inputs)" in pruned.stdout and "localhost/" not in pruned.stdout, pruned.stdout
    # Podman reports no layer its images share: each image's whole size was taken as freed.
    assert "how much they freed unknown (Podman does not say" in pruned.stdout and "at least" not in pruned.stdout


class SlowLink(TcpForwarder):
    """TcpForwarder passing what the client sends on PIECE bytes at a time, PAUSE seconds apart: a
    remote engine over a slow link, where a request's body reaches it in parts."""

    def __init__(self, target: Path, piece: int = 512, pause: float = 0.05) -> None:
        self._piece, self._pause = piece, pause
        super().__init__(target)

    def _pump(self, source: socket.socket, sink: socket.socket) -> None:
        if sink.family != socket.AF_UNIX:
            return TcpForwarder._pump(source, sink)
        try:
            while data := source.recv(self._piece):
                sink.sendall(data)
                time.sleep(self._pause)
            sink.shutdown(socket.SHUT_WR)
        except OSError:
            for end in (source, sink):
                end.close()


def test_a_build_over_a_slow_link_to_podman_gets_its_files_into_the_container(podman, tmp_path):
    """Every colcon build puts a file into its container (setuptools' settings) by an upload. Podman
    stops reading an upload at the archive's end blocks: over a slow link, the rest of the record
    padding Python's tarfile adds failed it with "passing bulk input to subprocess: write |1:
    broken pipe" (seen now and then on the local socket under load)."""
    root = once_workspace(tmp_path / "ws-root")
    seed = python_workspace(tmp_path / "seed")
    small_ros_image(root, seed)
    images_built(podman, seed, tmp_path)
    link = SlowLink(podman.socket)
    try:
        result = espdock("build", cwd=root, env={**podman.env, "DOCKER_HOST": f"tcp://127.0.0.1:{link.port}"})
    finally:
        link.close()
    assert result.returncode == 0, result.stdout + result.stderr
    assert "word: " in installed_word(root)


@pytest.mark.parametrize("reached", ["local socket", "tcp"])
def test_a_step_silent_for_longer_than_the_engine_timeout_runs_to_its_end_on_podman(
    podman, monkeypatch, tmp_path, reached
):
    """Podman 4.3 answers a followed log only with the container's first output: a colcon build that
    printed nothing for two minutes (a loaded machine's first configure) ended as "the Podman
    engine went away" (local socket) or "did not answer within 120 s" (tcp, through the SDK) while
    its container ran on. The two minutes made two seconds here, and the engine's timeout three:
    Podman takes 0.4 to 0.7 s to answer /version on an idle machine, and a timeout of one second
    failed the test on a loaded one before the step began."""
    monkeypatch.setattr(engine_module, "OPERATION_TIMEOUT", 2)
    image = ros_build_tag(python_workspace(tmp_path / "seed"))  # on the module's Podman storage
    lines: list[str] = []
    spec = RunSpec(image=image, argv=("sh", "-c", "sleep 7; echo done"), workdir="/")
    link = TcpForwarder(podman.socket) if reached == "tcp" else None
    env = {**podman.env, "DOCKER_HOST": f"tcp://127.0.0.1:{link.port}"} if link else podman.env
    try:
        assert Engine(env, timeout=3).run(spec, lines.append) == 0
    finally:
        if link:
            link.close()
    assert lines == ["done"]


def test_podman_imports_a_root_filesystem_under_its_own_tag(podman, tmp_path):
    rootfs = tmp_path / "rootfs"
    (rootfs / "etc").mkdir(parents=True)
    (rootfs / "etc/os-release").write_text("ID=espdock-test\n")
    tarball = tmp_path / "rootfs.tar"
    with tarfile.open(tarball, "w") as archive:
        archive.add(rootfs, arcname=".")
    engine = Engine.connect(podman.env)
    assert engine.info().kind == "podman"
    engine.import_rootfs(tarball, "espdock-test/imported:v1", {"io.espdock.test": "yes"})
    imported = engine.image("espdock-test/imported:v1")
    assert imported is not None and imported.labels["io.espdock.test"] == "yes"
    assert engine.image("espdock-test/imported:latest") is None
    # Podman's Docker API kept each uploaded tarball, a whole base image, in /var/tmp.
    assert list(podman.process_tmp.iterdir()) == []


def test_a_container_podman_refuses_to_start_is_exit_9_naming_podman(podman, tmp_path):
    """Without the containers.conf override, rootful Podman asks for rlimits this machine refuses."""
    strict = PodmanService(tmp_path, podman.runroot, conf="[containers]\n" + runtime_conf())
    root = once_workspace(tmp_path / "ws-root")
    seed = python_workspace(tmp_path / "seed")
    small_ros_image(root, seed)
    images_built(podman, seed, tmp_path)
    strict.start(podman.home)  # the same storage: the images are there
    try:
        started = subprocess.run(["docker", "run", "--rm", ros_build_tag(root), "true"], env=strict.env,
                                 capture_output=True, text=True, check=False)  # fmt: skip
        if started.returncode == 0:
            pytest.skip("this machine lets rootful Podman raise its rlimits: no container is refused")
        result = espdock("build", cwd=root, env=strict.env)
        assert result.returncode == ContainerError.exit_code, result.stdout + result.stderr
        assert f"the Podman engine at unix://{strict.socket}" in result.stderr
        assert "Traceback" not in result.stderr and "bug in espdock" not in result.stderr
    finally:
        strict.stop()


def test_crun_refusing_hybrid_cgroups_is_a_clear_error_that_names_runc(podman, tmp_path):
    """On a host whose cgroups crun refuses, a build on Podman's default runtime tells the user what
    to set instead of a bare OCI error."""
    if not runtime_conf():
        pytest.skip("this host's cgroups are not hybrid: crun runs Podman's containers here")
    crun = PodmanService(tmp_path, podman.runroot, conf=ULIMITS.replace(runtime_conf(), ""))
    root = once_workspace(tmp_path / "ws-root")
    seed = python_workspace(tmp_path / "seed")
    small_ros_image(root, seed)
    images_built(podman, seed, tmp_path)
    crun.start(podman.home)  # the same storage: the images are there
    try:
        result = espdock("build", cwd=root, env=crun.env)
        assert result.returncode != 0, result.stdout + result.stderr
        assert "cgroups in hybrid mode" in result.stderr, result.stderr
        assert 'set runtime = "runc"' in " ".join(result.stderr.split()), result.stderr
        assert "Traceback" not in result.stderr and "bug in espdock" not in result.stderr
    finally:
        crun.stop()


def test_where_docker_is_podman_s_run_and_compose_reach_the_engine_the_build_used(podman, tmp_path):
    """podman-docker (Fedora's and RHEL's `docker`: a script that runs podman): `docker compose`
    is no command of Podman 4.3's, and espdock copied Compose's 76 MB plugin into
    ~/.docker/cli-plugins at every command, then failed (exit 125); and podman reads
    CONTAINER_HOST, not DOCKER_HOST, so `espdock run` went to another engine than the build."""
    seed = python_workspace(tmp_path / "seed")
    images_built(podman, seed, tmp_path)
    root = tmp_path / "images"  # built there, unless an earlier test of the module made the images
    built = espdock("build", cwd=root, env={**podman.env, "ESPDOCK_CA_BUNDLE": accepted_ca(tmp_path)})
    assert built.returncode == 0, built.stdout[-3000:] + built.stderr
    shim = tmp_path / "bin/docker"
    shim.parent.mkdir()
    shim.write_text('#!/bin/sh\nexec podman "$@"\n')
    shim.chmod(0o755)
    config = tmp_path / "docker-config"
    config.mkdir()
    (config / "config.json").write_text("{}\n")  # podman reads it, as the docker CLI does
    env = {**podman.env, "PATH": f"{shim.parent}:{os.environ['PATH']}", "DOCKER_CONFIG": str(config)}
    env.pop("CONTAINER_HOST", None)
    run = espdock("run", "beacon_nodes", "once", cwd=root, env=env)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "word:" in run.stdout
    composed = espdock("compose", "version", cwd=root, env=env)
    assert composed.returncode == 0 and "Docker Compose version" in composed.stdout, composed.stdout + composed.stderr
    assert not (config / "cli-plugins").exists()
