"""What the machine does to a build: the engine going away, a full disk. Nothing may leave the
workspace or the engine in a state the next command cannot handle.

The shared engine is never stopped or filled: the engine tests start a private dockerd of
their own (own socket, data root, exec root, pid file, no iptables), on a copy of a data root
that holds the images they need (copied in once with `docker save`/`load`), and point espdock
at it with DOCKER_HOST.

That dockerd runs in a network namespace of its own (`unshare --net`): its bridge, veths
and sysctls are not the machine's. Not `--bridge=none` on the machine's network: Docker
20.10 then deletes the machine's docker0 (daemon_unix.go, removeDefaultBridgeInterface),
which is the shared engine's.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator, Sequence
from pathlib import Path

import pytest

from espdock.build.manifest import file_hashes
from tests.conftest import (
    copy_images,
    copy_workspace,
    espdock,
    images_key,
    kept_in_temp,
    python_workspace,
    ros_build_tag,
    shared_ros_images,
)

pytestmark = [pytest.mark.engine, pytest.mark.slow]


def mount_tmpfs(where: Path, size: str) -> None:
    where.mkdir(parents=True, exist_ok=True)
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(where)],
                             capture_output=True, text=True, check=False)  # fmt: skip
    if mounted.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here (needs root): {mounted.stderr.strip()}")


def copy_onto_tmpfs(source: Path, dest: Path) -> None:
    """SOURCE's contents at DEST, on a tmpfs unless a filesystem is mounted there already: a kept
    engine's or Podman's root is a gigabyte and some 40 000 files, which on the shared disk took
    10 to 25 s to copy and as long to remove again when other tests kept it busy; in memory both
    take a second or two (the removal is an umount)."""
    if not os.path.ismount(dest):
        mount_tmpfs(dest, "8g")  # an upper bound: a tmpfs takes only what is written to it
    subprocess.run(["cp", "-a", f"{source}/.", str(dest)], check=True)


@pytest.fixture
def small_disk(tmp_path: Path) -> Iterator[Path]:
    """A 300 MB filesystem of this test's own."""
    disk = tmp_path / "disk"
    mount_tmpfs(disk, "300m")
    yield disk
    subprocess.run(["umount", "--lazy", str(disk)], check=False)


def add_package(root: Path, name: str, cmake: str, depend: str | None = None) -> Path:
    """A plain CMake package NAME whose configure step runs CMAKE. (No `cmake` buildtool key: that
    is a rosdep key the image does not list, which would need a rosdep lock.)"""
    package = root / "ws/src" / name
    package.mkdir()
    depends = f"  <depend>{depend}</depend>\n" if depend else ""
    package.joinpath("package.xml").write_text(
        f'<?xml version="1.0"?>\n<package format="3">\n  <name>{name}</name>\n  <version>0.0.0</version>\n'
        f'  <description>{name}</description>\n  <maintainer email="dev@example.com">dev</maintainer>\n'
        f"  <license>Apache-2.0</license>\n{depends}"
        "  <export><build_type>cmake</build_type></export>\n</package>\n"
    )
    package.joinpath("CMakeLists.txt").write_text(
        f"cmake_minimum_required(VERSION 3.16)\nproject({name} NONE)\n{cmake}"
    )
    return package


# Writes into its build directory until the disk is full, failing as a compiler would.
FILL_DISK = """execute_process(COMMAND dd if=/dev/zero of=${CMAKE_BINARY_DIR}/fill bs=1M count=100000
                RESULT_VARIABLE written ERROR_QUIET)
if(written)
  message(FATAL_ERROR "could not write ${CMAKE_BINARY_DIR}/fill: ${written}")
endif()
"""


def unchanged(installed: dict[str, str], now: dict[str, str]) -> bool:
    """Whether every file of INSTALLED is there as it was (colcon may add a failed package's metadata)."""
    return {path: now.get(path) for path in installed} == installed


def test_a_full_workspace_disk_is_named_and_the_install_survives(engine, small_disk):
    root = python_workspace(small_disk / "ws-root")
    for _ in range(2):  # twice: setuptools' egg-info lists more files on a rebuild than on a first build
        first = espdock("build", "--force", cwd=root)
        assert first.returncode == 0, first.stdout + first.stderr
    installed = file_hashes(root / "ws/install")

    hog = add_package(root, "disk_hog", FILL_DISK, depend="beacon_nodes")
    full = espdock("build", cwd=root)
    assert full.returncode == 7, full.stdout + full.stderr
    assert f"the disk holding {root / 'ws'}" in full.stderr
    assert f"mounted at {small_disk}" in full.stderr
    assert "is full" in full.stderr
    assert unchanged(installed, file_hashes(root / "ws/install"))

    shutil.rmtree(hog)
    shutil.rmtree(root / "ws/build/espdock-ros/disk_hog")  # the user frees the space
    again = espdock("build", cwd=root)
    assert again.returncode == 0, again.stdout + again.stderr
    assert unchanged(installed, file_hashes(root / "ws/install"))


class PrivateEngine:
    """A dockerd of this test's own: nothing it does touches the shared engine."""

    def __init__(self, home: Path) -> None:
        self.home = home
        self.socket = home / "docker.sock"
        self.env = {**os.environ, "DOCKER_HOST": f"unix://{self.socket}"}
        self.process: subprocess.Popen | None = None
        self.containerd: subprocess.Popen | None = None

    def start_containerd(self) -> None:
        """containerd as a service of its own, as Debian runs it: it outlives a killed dockerd."""
        (self.home / "containerd.toml").write_text(
            f'version = 2\nroot = "{self.home}/containerd/root"\nstate = "{self.home}/containerd/state"\n'
            f'disabled_plugins = ["io.containerd.grpc.v1.cri"]\n[grpc]\n  address = "{self.home}/containerd.sock"\n'
        )
        with open(self.home / "containerd.log", "ab") as log:
            argv = ["containerd", "--config", str(self.home / "containerd.toml")]
            self.containerd = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        deadline = time.monotonic() + 60
        while not (self.home / "containerd.sock").exists():
            if self.containerd.poll() is not None or time.monotonic() > deadline:
                pytest.skip(f"containerd did not start here: {(self.home / 'containerd.log').read_text()[-1500:]}")
            time.sleep(0.2)

    def start(self) -> None:
        if self.containerd is None:
            self.start_containerd()
        self.launch(["unshare", "--net", "--", *self.dockerd(), "--containerd", str(self.home / "containerd.sock")])

    def dockerd(self) -> list[str]:
        """dockerd with this engine's own socket, roots, config and cgroup: nothing of the machine's."""
        (self.home / "daemon.json").write_text("{}")  # not the machine's /etc/docker/daemon.json
        return ["dockerd", "--host", f"unix://{self.socket}",
                "--data-root", str(self.home / "data"), "--exec-root", str(self.home / "exec"),
                "--pidfile", str(self.home / "docker.pid"), "--config-file", str(self.home / "daemon.json"),
                "--iptables=false", "--ip-masq=false", "--ip-forward=false",
                "--cgroup-parent", f"/espdock-test-{self.home.name}"]  # fmt: skip

    def launch(self, argv: list[str]) -> None:
        """Start ARGV (a dockerd, maybe behind unshare) and wait until it answers; skip if it cannot."""
        with open(self.home / "dockerd.log", "ab") as log:
            self.process = subprocess.Popen(argv, stdout=log, stderr=subprocess.STDOUT, start_new_session=True)
        deadline = time.monotonic() + 60
        while self.docker("version", check=False).returncode != 0:
            if self.process.poll() is not None or time.monotonic() > deadline:
                pytest.skip(f"a private dockerd did not start here: {(self.home / 'dockerd.log').read_text()[-1500:]}")
            time.sleep(0.5)

    def kill(self) -> None:
        """What the engine going away looks like to its clients: SIGKILL, no shutdown."""
        assert self.process is not None
        self.process.send_signal(signal.SIGKILL)
        self.process.wait()

    def stop(self) -> None:
        for process in (self.process, self.containerd):
            if process is not None and process.poll() is None:
                process.terminate()
                try:
                    process.wait(timeout=30)
                except subprocess.TimeoutExpired:
                    process.kill()
                    process.wait()

    def docker(self, *args: str, check: bool = True, **options) -> subprocess.CompletedProcess:
        return subprocess.run(["docker", *args], env=self.env, capture_output=True, text=True, check=check,
                              **options)  # fmt: skip

    def load(self, *images: str) -> None:
        """IMAGES from the shared engine, copied in with docker save | docker load."""
        copy_images(images, self.env)

    def seed(self, data_root: Path) -> None:
        """Start from a copy of DATA_ROOT, a stopped engine's data root (before start()), on a tmpfs
        unless the test mounted a filesystem there itself."""
        copy_onto_tmpfs(data_root, self.home / "data")

    def containers(self, root: Path) -> list[str]:
        listed = self.docker("ps", "-aq", "--filter", f"label=io.espdock.workspace={root}")
        return listed.stdout.split()


def private_home() -> Path:
    return Path(tempfile.mkdtemp(prefix="ed-", dir="/tmp"))  # short: socket paths have a length limit


def drop_private_engine(engine: PrivateEngine) -> None:
    engine.stop()
    # What is still mounted under its home (a seeded data root's tmpfs; the network namespace of a
    # container on the host's network, which dockerd leaves bound in exec/netns): rmtree stops there.
    for point in mounts_under(engine.home):
        subprocess.run(["umount", "--lazy", point], capture_output=True, check=False)
    shutil.rmtree(engine.home, ignore_errors=True)
    drop_cgroups(f"espdock-test-{engine.home.name}")


def mounts_under(home: Path) -> list[str]:
    """The mount points under HOME, the deepest first."""
    with open("/proc/self/mounts") as table:
        # Spaces and the like come octal-escaped in the table (\040).
        points = [line.split()[1].encode().decode("unicode_escape") for line in table]
    return sorted((p for p in points if Path(p).is_relative_to(home)), key=len, reverse=True)


def drop_cgroups(name: str) -> None:
    """The cgroup parent NAME the private dockerd made in each hierarchy: the kernel keeps empty
    cgroups until someone removes them, so every run would leave its own behind."""
    top = Path("/sys/fs/cgroup")
    for parent in (top / name, *top.glob(f"*/{name}")):
        for directory, _, _ in sorted(os.walk(parent), reverse=True):  # children before their parent
            with contextlib.suppress(OSError):
                os.rmdir(directory)


@pytest.fixture
def private_engine() -> Iterator[PrivateEngine]:
    if shutil.which("dockerd") is None or shutil.which("unshare") is None:
        pytest.skip("no dockerd or unshare here")
    engine = PrivateEngine(private_home())
    try:
        yield engine
    finally:
        drop_private_engine(engine)


@pytest.fixture(scope="module")
def seeded_data_root(engine, tmp_path_factory) -> Path:
    """A stopped private engine's data root holding Debian's base image and the workspace's ROS
    build and runtime images, for the private engines to start from a copy of (about 17 s and 20 s
    of CPU to load, a copy 2 s)."""
    root = copy_workspace(tmp_path_factory.mktemp("seed") / "ws-root")
    return kept_data_root(engine, "espdock-test-engine", shared_ros_images(engine, root, "debian:bookworm-slim"))


def kept_data_root(engine, name: str, images: Sequence[str], base: Path | None = None) -> Path:
    """A stopped private engine's data root holding IMAGES of the shared engine, over a copy of BASE
    (another such root) when given. Made once for each set of image IDs (and BASE) and kept in the
    temp dir as NAME-<key> for the next run, which removes an older one."""

    def make(place: Path) -> None:
        loader = PrivateEngine(private_home())
        try:
            if base is not None:
                loader.seed(base)
            loader.start()
            loader.load(*images)
            loader.stop()
            if base is None:
                (loader.home / "data").rename(place / "data")
            else:  # the seed's tmpfs: copied out before drop_private_engine unmounts it
                subprocess.run(["cp", "-a", str(loader.home / "data"), str(place / "data")], check=True)
        finally:
            drop_private_engine(loader)

    return kept_in_temp(name, images_key(engine, images, extra="" if base is None else str(base)), make) / "data"


def slow_package(root: Path) -> Path:
    return add_package(root, "slow_pkg", "execute_process(COMMAND sleep 300)\n")


def test_the_engine_going_away_mid_build_is_exit_3_and_the_next_build_just_works(
    private_engine, seeded_data_root, tmp_path
):
    root = python_workspace(tmp_path / "ws-root")
    private_engine.seed(seeded_data_root)
    private_engine.start()
    slow = slow_package(root)
    build = subprocess.Popen([sys.executable, "-m", "espdock", "build"], cwd=root, env=private_engine.env,
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)  # fmt: skip
    try:
        deadline = time.monotonic() + 300
        while not private_engine.containers(root):
            assert build.poll() is None, build.communicate()
            assert time.monotonic() < deadline, "the build container never started"
            time.sleep(0.2)
        time.sleep(3)
        private_engine.kill()
        out, err = build.communicate(timeout=60)
    finally:
        if build.poll() is None:
            build.kill()
    assert build.returncode == 3, out + err
    assert "went away" in err and str(private_engine.socket) in err
    assert "Traceback" not in err

    private_engine.start()
    shutil.rmtree(slow)
    again = espdock("build", cwd=root, env=private_engine.env)
    assert again.returncode == 0, again.stdout + again.stderr
    assert private_engine.containers(root) == []
    assert (root / "ws/install/beacon_nodes/share/beacon_nodes/package.xml").is_file()


def test_an_image_build_on_a_full_engine_disk_says_so(private_engine, seeded_data_root, tmp_path):
    data = private_engine.home / "data"
    mount_tmpfs(data, "2g")
    private_engine.seed(seeded_data_root)
    # Room for the first build (it takes under 1 MB) and not much more: the payload that fills it is
    # written below, as random bytes (CPU, and the engine's to copy: 15 s of it with 512 MB of room).
    used = shutil.disk_usage(data).used
    assert subprocess.run(["mount", "-o", f"remount,size={used + (64 << 20)}", str(data)], check=False).returncode == 0
    root = python_workspace(tmp_path / "ws-root")
    base = ros_build_tag(root)
    private_engine.start()
    # The workspace's ROS image: the usual one plus a file of its own (COPY: there is no network).
    big = root / "docker/payload.bin"
    big.parent.mkdir(exist_ok=True)
    big.write_bytes(b"small")
    (root / "Dockerfile.ros").write_text(
        f"ARG BASE_IMAGE={base}\nARG ROSDEP_OS=debian:bookworm\n"
        "FROM ${BASE_IMAGE} AS build\nCOPY docker/ /opt/payload/\n"
    )
    first = espdock("build", cwd=root, env=private_engine.env)
    assert first.returncode == 0, first.stdout + first.stderr
    installed = file_hashes(root / "ws/install")

    # A payload bigger than what is left of the engine's disk.
    free = shutil.disk_usage(data).free
    with open(big, "wb") as out:
        for _ in range(free // (1 << 20) + 64):
            out.write(os.urandom(1 << 20))
    full = espdock("build", cwd=root, env=private_engine.env)
    assert full.returncode == 4, full.stdout + full.stderr
    assert "the engine's disk is full" in full.stderr
    assert str(data) in full.stderr
    assert unchanged(installed, file_hashes(root / "ws/install"))

    # Space is freed (even `docker builder prune` needs some: it writes BuildKit's database).
    big.write_bytes(b"small again")
    grown = subprocess.run(["mount", "-o", "remount,size=3g", str(data)], check=False)
    assert grown.returncode == 0
    again = espdock("build", cwd=root, env=private_engine.env)
    assert again.returncode == 0, again.stdout + again.stderr
    assert private_engine.containers(root) == []
