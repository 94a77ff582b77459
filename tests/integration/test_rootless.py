"""Rootless engines run by a test user: Docker (Debian's dockerd-rootless.sh under rootlesskit)
and Podman (`podman system service` as the user). What espdock's build containers write into the
user's workspace belongs to the user.

Inside a rootless engine uid 0 is the user who started it; any other uid is one of the user's
subordinate ids, which the user cannot delete. /dev/net/tun is 0600 on machines of this kind and
rootless networking (slirp4netns) opens it as the user: the engine runs in a mount namespace of
its own where a tun device node the user may open lies over /dev/net/tun (the host's stays as
it is). The images come from the shared engine (docker save | docker load), once per data root.
"""

from __future__ import annotations

import contextlib
import os
import pwd
import shutil
import signal
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.conftest import as_user, copy_images, espdock, owners, python_workspace, shared_ros_images
from tests.integration.test_engines import edit_word, once_workspace
from tests.integration.test_podman import runtime_conf

pytestmark = [pytest.mark.engine, pytest.mark.slow]

TEST_USER = "espdock-rootless"
ROOTLESS_SCRIPT = Path("/usr/share/docker.io/contrib/dockerd-rootless.sh")
STORAGE_CONF = '[storage]\ndriver = "overlay"\n'


def ensure_test_user() -> pwd.struct_passwd:
    """TEST_USER with a home and subordinate ids (useradd gives them on Debian), made if missing."""
    if os.geteuid() != 0:
        pytest.skip("making a test user and starting its rootless engine needs root")
    try:
        return pwd.getpwnam(TEST_USER)
    except KeyError:
        subprocess.run(["useradd", "--create-home", "--shell", "/bin/sh", TEST_USER], check=True)
    user = pwd.getpwnam(TEST_USER)
    for table, option in (("/etc/subuid", "--add-subuids"), ("/etc/subgid", "--add-subgids")):
        if f"{TEST_USER}:" not in Path(table).read_text():
            subprocess.run(["usermod", option, "300000-365535", TEST_USER], check=True)
    return user


class RootlessDocker:
    """The test user's rootless dockerd; DOCKER_HOST for it in self.env."""

    socket_name = "docker.sock"

    def __init__(self, user: pwd.struct_passwd) -> None:
        self.user = user
        self.runtime = Path(f"/run/user/{user.pw_uid}")
        self.socket = self.runtime / self.socket_name
        self.home = Path(user.pw_dir)
        self.env = {"HOME": str(self.home), "PATH": os.environ["PATH"], "DOCKER_HOST": f"unix://{self.socket}"}
        self.process: subprocess.Popen | None = None

    def command(self) -> list[str]:
        missing = [tool for tool in ("rootlesskit", "newuidmap", "slirp4netns") if shutil.which(tool) is None]
        if missing or not ROOTLESS_SCRIPT.is_file():
            pytest.skip(f"rootless Docker is not installed here ({', '.join(missing) or ROOTLESS_SCRIPT}): "
                        "tests/install-system-deps.sh installs it")  # fmt: skip
        return [str(ROOTLESS_SCRIPT), "--iptables=false"]

    def start(self) -> None:
        command = self.command()
        self.runtime.mkdir(parents=True, exist_ok=True)
        os.chown(self.runtime, self.user.pw_uid, self.user.pw_gid)
        self.runtime.chmod(0o700)
        tun = self.home / ".espdock-test-tun"
        if not tun.exists():
            os.mknod(tun, 0o600 | 0o020000, os.makedev(10, 200))  # a character device, as /dev/net/tun
        os.chown(tun, self.user.pw_uid, self.user.pw_gid)
        uid = str(self.user.pw_uid)
        argv = ["unshare", "--mount", "--propagation", "private", "--",
                "sh", "-c", 'mount --bind "$0" /dev/net/tun && exec "$@"', str(tun),
                "setpriv", f"--reuid={uid}", f"--regid={self.user.pw_gid}", "--init-groups",
                "env", "-i", f"HOME={self.home}", f"USER={TEST_USER}", f"XDG_RUNTIME_DIR={self.runtime}",
                "PATH=/usr/bin:/bin:/usr/sbin:/sbin", *command]  # fmt: skip
        log = self.home / f".espdock-test-{self.socket_name}.log"
        with open(log, "ab") as out:
            # From the user's home: the checkout may sit in a 0700 directory (a CI clone made with
            # mktemp -d), where rootless Podman's re-exec as the user cannot chdir.
            self.process = subprocess.Popen(
                argv, cwd=self.home, stdout=out, stderr=subprocess.STDOUT, start_new_session=True
            )
        deadline = time.monotonic() + 90
        while self.docker("version", check=False).returncode != 0:
            if self.process.poll() is not None or time.monotonic() > deadline:
                self.stop()
                pytest.skip(f"the rootless engine did not start here: {log.read_text()[-1500:]}")
            time.sleep(0.5)

    def docker(self, *args: str, check: bool = True, **options) -> subprocess.CompletedProcess:
        return subprocess.run(["docker", *args], env={**os.environ, **self.env}, capture_output=True, text=True,
                              check=check, **options)  # fmt: skip

    def load(self, *images: str) -> None:
        """IMAGES from the shared engine, unless this engine has them with the same ID."""
        wanted = []
        for image in images:
            here = self.docker("image", "inspect", "-f", "{{.Id}}", image, check=False).stdout.strip()
            there = subprocess.run(["docker", "image", "inspect", "-f", "{{.Id}}", image], capture_output=True,
                                   text=True, check=True).stdout.strip()  # fmt: skip
            if here != there:
                wanted.append(image)
        if not wanted:
            return
        copy_images(wanted, {**os.environ, **self.env})

    def stop(self) -> None:
        if self.process is not None and self.process.poll() is None:
            os.killpg(self.process.pid, signal.SIGTERM)
            try:
                self.process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                os.killpg(self.process.pid, signal.SIGKILL)
                self.process.wait()


class RootlessPodman(RootlessDocker):
    """The test user's `podman system service` (rootless: its storage in the user's home)."""

    socket_name = "podman.sock"

    def command(self) -> list[str]:
        if shutil.which("podman") is None or shutil.which("newuidmap") is None:
            pytest.skip("podman or newuidmap is not installed here: tests/install-system-deps.sh installs them")
        # Podman 4.3 may settle on vfs for a rootless store, which copies the whole image for each
        # container (a minute each for the ROS image here); the kernel's own overlay works rootless.
        engine_conf = self.home / ".config/containers/containers.conf"
        engine_conf.parent.mkdir(parents=True, exist_ok=True)
        engine_conf.write_text(runtime_conf())
        for path in (engine_conf.parent.parent, engine_conf.parent, engine_conf):
            os.chown(path, self.user.pw_uid, self.user.pw_gid)
        conf = self.home / ".config/containers/storage.conf"
        if not conf.is_file() or conf.read_text() != STORAGE_CONF:
            conf.parent.mkdir(parents=True, exist_ok=True)
            conf.write_text(STORAGE_CONF)
            for path in (conf.parent.parent, conf.parent, conf):
                os.chown(path, self.user.pw_uid, self.user.pw_gid)
            # A store made with another driver is not readable by this one.
            subprocess.run(["setpriv", f"--reuid={self.user.pw_uid}", f"--regid={self.user.pw_gid}", "--init-groups",
                            "env", "-i", f"HOME={self.home}", f"XDG_RUNTIME_DIR={self.runtime}",
                            "PATH=/usr/bin:/bin:/usr/sbin:/sbin", "podman", "system", "reset", "--force"],
                           cwd=self.home, capture_output=True, check=False)  # fmt: skip
        return ["podman", "system", "service", "--time=0", f"unix://{self.socket}"]

    def stop(self) -> None:
        super().stop()
        # Rootless Podman's pause process, which holds the user's namespace, leaves the service's
        # session (setsid): it outlived every run.
        pause = self.runtime / "libpod/tmp/pause.pid"
        with contextlib.suppress(OSError, ValueError):
            os.kill(int(pause.read_text().strip()), signal.SIGKILL)
            pause.unlink()


@pytest.fixture(scope="module", params=[RootlessDocker, RootlessPodman], ids=["docker", "podman"])
def rootless_engine(request, engine, tmp_path_factory) -> Iterator[RootlessDocker]:
    user = ensure_test_user()
    daemon = request.param(user)
    daemon.start()
    try:
        # The images a copied workspace builds with, made by the shared engine (it has a network).
        root = python_workspace(tmp_path_factory.mktemp("seed") / "ws-root")
        daemon.load(*shared_ros_images(engine, root, "debian:bookworm-slim"))
        yield daemon
    finally:
        daemon.stop()
    # Nothing of the engine outlives the tests (Podman's pause process did).
    deadline = time.monotonic() + 10
    while (left := processes_of(user.pw_uid)) and time.monotonic() < deadline:
        time.sleep(0.2)
    assert not left, f"the rootless engine left processes of {TEST_USER}: {left}"


def processes_of(uid: int) -> list[str]:
    """The command lines of UID's processes."""
    found = []
    for pid in (p for p in os.listdir("/proc") if p.isdigit()):
        with contextlib.suppress(OSError):
            if os.stat(f"/proc/{pid}").st_uid == uid:
                found.append(Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode().strip())
    return found


def test_a_rootless_engine_builds_runs_and_everything_written_is_the_users(rootless_engine, wheel_espdock):
    user = rootless_engine.user
    parent = Path(user.pw_dir) / "espdock-test-ws"
    shutil.rmtree(parent, ignore_errors=True)
    root = once_workspace(parent / "ws-root")
    subprocess.run(["chown", "-R", f"{user.pw_uid}:{user.pw_gid}", str(parent)], check=True)
    prefix = as_user(user.pw_uid, user.pw_gid, [], wheel_espdock)

    first = espdock("build", cwd=root, env=rootless_engine.env, prefix=prefix)
    assert first.returncode == 0, first.stdout + first.stderr
    edit_word(root, "rootless")
    again = espdock("build", cwd=root, env=rootless_engine.env, prefix=prefix)
    assert again.returncode == 0, again.stdout + again.stderr
    assert owners(root) == {user.pw_uid}, "a file in the workspace belongs to another uid"

    run = espdock("run", "beacon_nodes", "once", cwd=root, env=rootless_engine.env, prefix=prefix)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "word: rootless" in run.stdout

    # A compose service as the starter compose file makes them (user: ${ESPDOCK_USER}) writing
    # into a mounted directory: it ran as the user's uid, a subordinate one in the engine, and was
    # refused (or, the directory opened to it, wrote files the user could not remove).
    (root / "out").mkdir()
    (root / "compose.yaml").write_text(
        "services:\n  writer:\n    image: espdock/ws-root:latest\n    user: ${ESPDOCK_USER}\n"
        "    network_mode: none\n    volumes: [./out:/out]\n    entrypoint: [sh, -c, 'touch /out/written']\n"
    )
    subprocess.run(["chown", "-R", f"{user.pw_uid}:{user.pw_gid}", str(root)], check=True)
    composed = espdock("compose", "run", "--rm", "writer", cwd=root, env=rootless_engine.env, prefix=prefix)
    assert composed.returncode == 0, composed.stdout + composed.stderr
    assert (root / "out/written").stat().st_uid == user.pw_uid
    shutil.rmtree(parent)  # root may; the user could too, every file being theirs
