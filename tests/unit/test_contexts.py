"""The engine espdock picks is the one the Docker CLI would: DOCKER_HOST, else its context.

The contexts are made by the real `docker context create` and `docker context use` in a private
DOCKER_CONFIG, so espdock reads the CLI's own store as that version writes it; `docker context
inspect` says what the CLI makes of each, and espdock must agree. No engine is needed.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest

from espdock.errors import ConfigError, EngineUnavailable
from espdock.images import bootstrap, contexts
from espdock.images.engine import Engine

pytestmark = pytest.mark.skipif(shutil.which("docker") is None, reason="no docker CLI (make setup installs it)")

ROOTLESS = "unix:///run/user/1000/docker.sock"


def cli(config: Path, *args: str, env: dict[str, str] | None = None) -> str:
    ran = subprocess.run(["docker", *args], env={"PATH": "/usr/bin:/bin", "DOCKER_CONFIG": str(config), **(env or {})},
                         capture_output=True, text=True, check=True)  # fmt: skip
    return ran.stdout


def cli_host(config: Path, env: dict[str, str]) -> str:
    """The host the CLI talks to in ENV, as `docker context inspect` of its current context says."""
    name = env.get("DOCKER_CONTEXT") or json.loads((config / "config.json").read_text()).get("currentContext")
    return json.loads(cli(config, "context", "inspect", name))[0]["Endpoints"]["docker"]["Host"]


def self_signed(cert: Path, key: Path) -> None:
    """A self-signed certificate and its key, by openssl (the CLI checks a context's files)."""
    argv = ["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", str(key), "-out", str(cert)]
    subprocess.run([*argv, "-days", "1", "-subj", "/CN=engine"], capture_output=True, check=True)


@pytest.fixture
def config(tmp_path) -> Path:
    """A Docker CLI configuration as rootless Docker's setup tool leaves it: a "rootless" context, in use."""
    config = tmp_path / "docker"
    cli(config, "context", "create", "rootless", "--description", "Rootless mode", "--docker", f"host={ROOTLESS}")
    cli(config, "context", "use", "rootless")
    return config


def test_the_cli_s_current_context_is_the_engine_and_docker_host_or_docker_context_win(config):
    env = {"DOCKER_CONFIG": str(config)}
    assert contexts.engine_env(env)["DOCKER_HOST"] == ROOTLESS == cli_host(config, env)
    assert Engine(env)._socket == ROOTLESS.removeprefix("unix://")  # talked to over its own socket

    cli(config, "context", "create", "ci", "--docker", "host=tcp://10.0.0.5:2375")
    assert contexts.engine_env({**env, "DOCKER_CONTEXT": "ci"})["DOCKER_HOST"] == "tcp://10.0.0.5:2375"
    local = {**env, "DOCKER_CONTEXT": "default"}
    assert contexts.engine_env(local) == local
    assert contexts.engine_env({**env, "DOCKER_HOST": "tcp://elsewhere:2375"})["DOCKER_HOST"] == "tcp://elsewhere:2375"

    cli(config, "context", "use", "default")
    assert contexts.engine_env(env) == env  # the default socket, as before any context


def test_no_configuration_or_a_broken_one_is_the_default_engine_as_the_cli_has_it(tmp_path):
    assert contexts.engine_env({"DOCKER_CONFIG": str(tmp_path / "none")}) == {"DOCKER_CONFIG": str(tmp_path / "none")}
    (tmp_path / "config.json").write_text("{not json")
    env = {"DOCKER_CONFIG": str(tmp_path)}
    assert contexts.engine_env(env) == env
    assert contexts.config_dir({"HOME": "/home/ann"}) == Path("/home/ann/.docker")


def test_a_tls_context_gives_its_certificates_and_skipping_verification_stays_skipped(config, tmp_path):
    self_signed(tmp_path / "cert.pem", tmp_path / "key.pem")
    pems = f"ca={tmp_path / 'cert.pem'},cert={tmp_path / 'cert.pem'},key={tmp_path / 'key.pem'}"
    cli(config, "context", "create", "secure", "--docker", f"host=tcp://10.0.0.5:2376,{pems}")
    cli(config, "context", "create", "lax", "--docker", f"host=tcp://10.0.0.6:2376,{pems},skip-tls-verify=true")
    env = {"DOCKER_CONFIG": str(config), "DOCKER_TLS_VERIFY": "1"}

    secure = contexts.engine_env({**env, "DOCKER_CONTEXT": "secure"})
    certs = Path(secure["DOCKER_CERT_PATH"])
    assert (certs / "key.pem").read_bytes() == (tmp_path / "key.pem").read_bytes()
    assert (secure["DOCKER_HOST"], secure["DOCKER_TLS_VERIFY"]) == ("tcp://10.0.0.5:2376", "1")
    lax = contexts.engine_env({**env, "DOCKER_CONTEXT": "lax"})
    assert Path(lax["DOCKER_CERT_PATH"], "cert.pem").is_file() and "DOCKER_TLS_VERIFY" not in lax


def test_a_context_decides_tls_alone_and_the_cli_espdock_runs_is_pinned_to_it(config, tmp_path):
    """The CLI reads no TLS variable for a context of its own: a plain one stays plain whatever
    the shell's DOCKER_TLS_VERIFY says, and a CA alone means TLS. The docker CLI and compose
    espdock runs get the context's name, so they go where espdock goes even when the current
    context changes meanwhile."""
    shell = {"DOCKER_CONFIG": str(config), "DOCKER_TLS_VERIFY": "1", "DOCKER_CERT_PATH": str(tmp_path)}
    plain = contexts.engine_env(shell)
    assert plain["DOCKER_HOST"] == ROOTLESS and not set(plain) & {"DOCKER_TLS_VERIFY", "DOCKER_CERT_PATH"}

    self_signed(tmp_path / "ca.pem", tmp_path / "key.pem")
    cli(config, "context", "create", "tls-ca", "--docker", f"host=tcp://10.0.0.7:2376,ca={tmp_path / 'ca.pem'}")
    cli(config, "context", "use", "tls-ca")
    with_ca = contexts.engine_env({"DOCKER_CONFIG": str(config)})
    assert with_ca["DOCKER_TLS_VERIFY"] == "1"
    assert Path(with_ca["DOCKER_CERT_PATH"], "ca.pem").read_bytes() == (tmp_path / "ca.pem").read_bytes()
    assert not Path(with_ca["DOCKER_CERT_PATH"], "cert.pem").exists()

    assert contexts.cli_env({"DOCKER_CONFIG": str(config)})["DOCKER_CONTEXT"] == "tls-ca"
    assert "DOCKER_CONTEXT" not in contexts.cli_env({"DOCKER_CONFIG": str(config), "DOCKER_HOST": ROOTLESS})


def test_a_context_the_cli_does_not_have_is_bad_input_naming_it_and_what_chose_it(config):
    env = {"DOCKER_CONFIG": str(config), "DOCKER_CONTEXT": "desktop-linux"}
    with pytest.raises(ConfigError) as raised:
        Engine.connect(env)
    assert raised.value.message.startswith('the Docker context "desktop-linux" (DOCKER_CONTEXT) does not exist')
    assert "docker context ls" in raised.value.hint
    failed = subprocess.run(["docker", "version"], env={"PATH": "/usr/bin:/bin", **env}, capture_output=True,
                            text=True, check=False)  # fmt: skip
    assert failed.returncode != 0 and '"desktop-linux"' in failed.stderr  # the CLI refuses it too


def test_a_context_s_engine_that_is_down_is_never_replaced_by_a_local_one(config):
    """espdock setup starts (or installs) a local engine when the default socket has none: never
    when the CLI's context names another engine, which the user has to start."""
    with pytest.raises(EngineUnavailable) as raised:
        bootstrap.ensure_engine({"DOCKER_CONFIG": str(config)}, print)
    assert f"no Docker engine answers at {ROOTLESS}" in raised.value.message
    assert raised.value.hint == (
        f'Start the engine of the Docker context "rootless" (currentContext in {config / "config.json"}, '
        f"at {ROOTLESS}), "
        "or `docker context use default` for the local one."
    )


def test_a_context_s_engine_that_went_away_is_named_by_its_context_as_when_it_never_answered(config):
    """An engine lost mid-build was named by its address alone, with other words for how to start
    it than an engine that never answered got."""
    lost = Engine({"DOCKER_CONFIG": str(config)})._lost("listing containers")
    assert lost.hint == (
        f'Start the engine of the Docker context "rootless" (currentContext in {config / "config.json"}, '
        f"at {ROOTLESS}), "
        "then rerun: the next command removes what was left."
    )


@pytest.mark.parametrize(
    ("socket", "start"),
    [
        ("run/user/1000/docker.sock", "(rootless Docker: `systemctl --user start docker`), or unset DOCKER_HOST."),
        ("run/user/1000/podman/podman.sock", "`systemctl --user start podman.socket`"),
    ],
)
def test_a_user_socket_that_never_answered_is_started_as_what_it_is(tmp_path, socket, start):
    """DOCKER_HOST naming rootless Docker's or Podman's socket, neither running: the hint said only
    "start the engine DOCKER_HOST names", where an engine that went away got the command."""
    # Not under tmp_path: with a long TMPDIR the path was over AF_UNIX's 107 characters.
    host = f"unix:///nonexistent-{os.getpid()}/{socket}"
    with pytest.raises(EngineUnavailable) as raised:
        bootstrap.ensure_engine({"DOCKER_HOST": host, "DOCKER_CONFIG": str(tmp_path)}, print)
    assert raised.value.message == f"no Docker engine answers at {host}: nothing is listening there"
    assert start in raised.value.hint, raised.value.hint
    assert ("docker" in raised.value.hint) == ("podman" not in socket), raised.value.hint
