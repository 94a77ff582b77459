"""An engine reached as DOCKER_HOST=ssh://user@host, the way `docker` reaches it: the ssh command
logs in (with the user's ssh config, keys and known hosts) and runs `docker system dial-stdio`
there. Real OpenSSH on both ends: an sshd of the test's own on a loopback port, with its own host
and client keys, in front of the shared engine; the client's settings come from an ssh config
file, handed to the real ssh by a wrapper first on PATH (where a user has ~/.ssh/config), which
also notes each ssh started.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from tests.conftest import REPO, espdock
from tests.integration.test_engines import edit_word, installed_word, once_workspace
from tests.ports import free_port

pytestmark = [pytest.mark.engine]

SSHD = "/usr/sbin/sshd"


@dataclass(frozen=True)
class SshEngine:
    host: str  # DOCKER_HOST
    env: dict[str, str]  # DOCKER_HOST, and PATH with the ssh that reads the test's config
    logins: Path  # a line per ssh started: its pid

    def pids(self) -> list[int]:
        return started(self.logins)


def started(logins: Path) -> list[int]:
    """The pids of the ssh processes the wrapper noted in LOGINS."""
    return [int(line) for line in logins.read_text().split()] if logins.exists() else []


@pytest.fixture(scope="module")
def ssh_engine(engine, tmp_path_factory) -> Iterator[SshEngine]:
    if not os.access(SSHD, os.X_OK) or shutil.which("ssh") is None:
        pytest.skip("no OpenSSH server or client here (tests/install-system-deps.sh installs them)")
    home = tmp_path_factory.mktemp("ssh")
    for key in ("host_key", "client_key"):
        subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(home / key)], check=True)
    (home / "authorized_keys").write_text((home / "client_key.pub").read_text())
    port = free_port()
    (home / "sshd_config").write_text(
        f"Port {port}\nListenAddress 127.0.0.1\nHostKey {home / 'host_key'}\n"
        f"AuthorizedKeysFile {home / 'authorized_keys'}\nPermitRootLogin prohibit-password\n"
        "PasswordAuthentication no\nKbdInteractiveAuthentication no\nUsePAM no\nStrictModes no\n"
        f"PidFile {home / 'sshd.pid'}\n"
    )
    (home / "known_hosts").write_text(f"[127.0.0.1]:{port} {(home / 'host_key.pub').read_text()}")
    (home / "ssh_config").write_text(
        f"Host *\n  IdentityFile {home / 'client_key'}\n  IdentitiesOnly yes\n"
        f"  UserKnownHostsFile {home / 'known_hosts'}\n  StrictHostKeyChecking yes\n  BatchMode yes\n"
    )
    wrapper = home / "bin/ssh"
    wrapper.parent.mkdir()
    logins = home / "logins"
    wrapper.write_text(f'#!/bin/sh\necho $$ >> {logins}\nexec {shutil.which("ssh")} -F {home / "ssh_config"} "$@"\n')
    wrapper.chmod(0o755)
    Path("/run/sshd").mkdir(exist_ok=True)  # sshd's privilege separation dir
    daemon = subprocess.Popen([SSHD, "-D", "-e", "-f", str(home / "sshd_config")],
                              stdout=subprocess.DEVNULL, stderr=(home / "sshd.log").open("wb"))  # fmt: skip
    try:
        deadline = time.monotonic() + 20
        while True:
            assert daemon.poll() is None, (home / "sshd.log").read_text()
            try:
                socket.create_connection(("127.0.0.1", port), timeout=1).close()
                break
            except OSError:
                assert time.monotonic() < deadline, "sshd never listened"
                time.sleep(0.05)
        host = f"ssh://root@127.0.0.1:{port}"
        yield SshEngine(host, {"DOCKER_HOST": host, "PATH": f"{wrapper.parent}:{os.environ['PATH']}"}, logins)
    finally:
        daemon.terminate()
        daemon.wait(timeout=10)


def test_an_ssh_engine_builds_rebuilds_an_edit_and_runs_the_node_as_docker_reaches_it(ssh_engine, engine, tmp_path):
    version = ["docker", "version", "--format", "{{.Server.Version}}"]
    seen = subprocess.run(version, env={**os.environ, **ssh_engine.env}, capture_output=True, text=True, check=False)
    assert seen.returncode == 0, f"the docker CLI cannot reach {ssh_engine.host} either: {seen.stderr}"
    root = once_workspace(tmp_path / "ws")
    try:
        first = espdock("build", cwd=root, env=ssh_engine.env)
        assert first.returncode == 0, first.stdout + first.stderr
        assert "1 package(s) built" in first.stdout, first.stdout
        edit_word(root, "ssh")
        again = espdock("build", cwd=root, env=ssh_engine.env)
        assert again.returncode == 0, again.stdout + again.stderr
        assert "word: ssh" in installed_word(root)
        run = espdock("run", "beacon_nodes", "once", cwd=root, env=ssh_engine.env)
        assert run.returncode == 0, run.stdout + run.stderr
        assert "word: ssh" in run.stdout
        assert engine.containers({"io.espdock.workspace": str(root)}) == []
        # One login per command, as docker's own (0.35 s each here; a passphrase or a key touch
        # elsewhere): the SDK alone logged in for each request, 9 times for this build.
        before = len(ssh_engine.pids())
        quiet = espdock("build", cwd=root, env=ssh_engine.env)
        assert quiet.returncode == 0, quiet.stdout + quiet.stderr
        assert "up to date (1 package(s))" in quiet.stdout, quiet.stdout
        assert len(ssh_engine.pids()) - before == 1
    finally:
        engine.remove_containers({"io.espdock.workspace": str(root)})


# Two calls of one Engine, the ssh processes it logged in with killed between them (a dropped
# network, an sshd restarted): the second call logs in again instead of failing.
LOST = """
import os, signal, sys, time
from espdock.images.engine import Engine
from pathlib import Path
from tests.integration.test_ssh_engine import started
logins = Path(os.environ["SSH_LOGINS"])
engine = Engine.connect(os.environ)
assert engine.image("debian:bookworm-slim") is not None
pids = started(logins)
for pid in pids:
    os.kill(pid, signal.SIGKILL)
while any(os.path.exists(f"/proc/{pid}") and open(f"/proc/{pid}/stat").read().split()[2] != "Z" for pid in pids):
    time.sleep(0.05)
print(len(pids), engine.image("debian:bookworm-slim") is not None, len(started(logins)))
"""


def test_a_lost_ssh_connection_is_made_anew_at_the_next_call(ssh_engine, engine):
    env = {**os.environ, **ssh_engine.env, "SSH_LOGINS": str(ssh_engine.logins)}
    ssh_engine.logins.unlink(missing_ok=True)
    lost = subprocess.run([sys.executable, "-c", LOST], env=env, cwd=REPO, capture_output=True, text=True, check=False)
    assert lost.returncode == 0, lost.stderr
    assert lost.stdout.split() == ["1", "True", "2"]
