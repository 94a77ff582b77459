"""An engine reached as DOCKER_HOST=ssh://user@host, the way `docker` reaches it: the ssh command
logs in (with the user's ssh config, keys and known hosts) and runs `docker system dial-stdio`
there. Real OpenSSH on both ends (tests/sshd.py), in front of the shared engine. test_engines.py
reaches an engine that does not see the workspace this way too.
"""

from __future__ import annotations

import os
import subprocess
import sys
from collections.abc import Iterator

import pytest

from tests import sshd
from tests.conftest import REPO, espdock
from tests.integration.test_engines import edit_word, installed_word, once_workspace
from tests.sshd import SshEngine

pytestmark = [pytest.mark.engine]


@pytest.fixture(scope="module")
def ssh_engine(engine, tmp_path_factory) -> Iterator[SshEngine]:
    if sshd.missing():
        pytest.skip(sshd.missing())
    with sshd.serve(tmp_path_factory.mktemp("ssh")) as served:
        yield served


def test_an_ssh_engine_builds_rebuilds_an_edit_and_runs_the_node_as_docker_reaches_it(ssh_engine, engine, tmp_path):
    version = ["docker", "version", "--format", "{{.Server.Version}}"]
    seen = subprocess.run(version, env={**os.environ, **ssh_engine.env}, capture_output=True, text=True, check=False)
    assert seen.returncode == 0, f"the docker CLI cannot reach {ssh_engine.host} either: {seen.stderr}"
    root = once_workspace(tmp_path / "ws")
    config = root / "espdock.toml"  # the runtime image is made once, by `run`, not by each build
    config.write_text(config.read_text().replace("runtime_image = true", "runtime_image = false"))
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
from tests.sshd import started
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
