"""A real OpenSSH server of a test's own, on a loopback port with its own host and client keys,
for engines reached as DOCKER_HOST=ssh://...: the client's settings come from an ssh config
file, handed to the real ssh by a wrapper first on PATH (where a user has ~/.ssh/config), which
also notes each ssh started."""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import time
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from tests.ports import free_port

SSHD = "/usr/sbin/sshd"


def missing() -> str | None:
    """Why no sshd can be served here; None when one can."""
    if not os.access(SSHD, os.X_OK) or shutil.which("ssh") is None:
        return "no OpenSSH server or client here (tests/install-system-deps.sh installs them)"
    return None


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


@contextmanager
def serve(home: Path, session: Mapping[str, str] | None = None) -> Iterator[SshEngine]:
    """An sshd whose logins as root run with SESSION's variables (DOCKER_HOST: which engine the
    remote `docker system dial-stdio` reaches), its files in HOME; the engine it is a way to."""
    for key in ("host_key", "client_key"):
        subprocess.run(["ssh-keygen", "-q", "-t", "ed25519", "-N", "", "-f", str(home / key)], check=True)
    (home / "authorized_keys").write_text((home / "client_key.pub").read_text())
    port = free_port()
    set_env = f"SetEnv {' '.join(f'{k}={v}' for k, v in session.items())}\n" if session else ""
    (home / "sshd_config").write_text(
        f"Port {port}\nListenAddress 127.0.0.1\nHostKey {home / 'host_key'}\n"
        f"AuthorizedKeysFile {home / 'authorized_keys'}\nPermitRootLogin prohibit-password\n"
        "PasswordAuthentication no\nKbdInteractiveAuthentication no\nUsePAM no\nStrictModes no\n"
        f"PidFile {home / 'sshd.pid'}\n{set_env}"
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
