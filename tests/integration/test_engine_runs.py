"""Engine.run against the real engine, both ways espdock talks to it: plain HTTP on the local
socket, and the Docker SDK for any other DOCKER_HOST (here the same engine through a TCP
forwarder). What a step sees must not depend on which: its output line by line, its exit code,
files put in before it starts and fetched after it ends, a clear error for a missing image, and
no container left."""

from __future__ import annotations

import io
import json
import os
import shutil
import socket
import stat
import subprocess
import sys
import tarfile
import time
import uuid
from collections.abc import Callable, Iterator
from pathlib import Path

import certifi
import pytest

from espdock.errors import ConfigError, ContainerError, EngineUnavailable
from espdock.images import bootstrap
from espdock.images.addresses import DEFAULT_SOCKET
from espdock.images.engine import LABEL_OWNER, Engine
from espdock.images.keyed import DPKG_STATUS, installed_packages
from espdock.images.specs import Mount, RunSpec
from espdock.layout import MICRO_ROS_AGENT_IMAGE
from espdock.ros.compose import starter_compose
from espdock.scratch import owner_identity
from tests.conftest import REPO
from tests.integration.test_engines import TcpForwarder
from tests.integration.test_faults import PrivateEngine, drop_private_engine, private_home
from tests.tls import make_certificates

pytestmark = [pytest.mark.engine]

IMAGE = "debian:bookworm-slim"
KEYED = "io.espdock.key"  # the label every keyed image carries (what `espdock prune` and the size note list)


def local_socket() -> str:
    return (os.environ.get("DOCKER_HOST") or f"unix://{DEFAULT_SOCKET}").removeprefix("unix://")


@pytest.fixture(scope="module", params=["local socket", "tcp", "tls"])
def way(request, engine, tmp_path_factory) -> Iterator[Engine]:
    """The engine over its local socket (plain HTTP), or over TCP (the Docker SDK): plain, or TLS
    with a client certificate (DOCKER_TLS_VERIFY, DOCKER_CERT_PATH) where, as behind a proxy that
    re-signs HTTPS, REQUESTS_CA_BUNDLE names the system's CAs, which do not hold the engine's."""
    socket_path = local_socket()
    if request.param == "local socket":
        yield Engine.connect({**os.environ, "DOCKER_HOST": f"unix://{socket_path}"})
        return
    env = {**os.environ}
    tls = None
    if request.param == "tls":
        home = tmp_path_factory.mktemp("tls")
        tls = make_certificates(home)
        env.update(DOCKER_TLS_VERIFY="1", DOCKER_CERT_PATH=str(home / "client"))
    forwarder = TcpForwarder(Path(socket_path), tls)
    try:
        with pytest.MonkeyPatch.context() as patch:
            if tls is not None:
                patch.setenv("REQUESTS_CA_BUNDLE", certifi.where())
            yield Engine.connect({**env, "DOCKER_HOST": f"tcp://127.0.0.1:{forwarder.port}"})
    finally:
        forwarder.close()


def spec(argv: list[str], **fields) -> RunSpec:
    labels = (("io.espdock.test-run", uuid.uuid4().hex),)
    return RunSpec(image=IMAGE, argv=tuple(argv), workdir="/", labels=labels, **fields)


def test_output_comes_line_by_line_with_the_exit_code_and_no_container_stays(way):
    # Apart in time: the engine reads stdout and stderr from two pipes.
    run = spec(["sh", "-c", "echo one; sleep 0.1; echo two >&2; sleep 0.1; printf 'three\\r\\n'; exit 7"])
    lines: list[str] = []
    assert way.run(run, lines.append) == 7
    assert lines == ["one", "two", "three"]
    assert way.containers(dict(run.labels)) == []


def test_a_step_container_gets_the_proxies_of_the_cli_config_as_docker_run_gives_them(way, tmp_path):
    """Behind a proxy named in the CLI's config (`proxies`, as Docker documents), `docker run` and
    image builds had it and espdock's step containers did not: the IDF component manager's
    downloads, a vendor package's fetch at configure time went direct, where only the proxy leads."""
    config = tmp_path / "docker-config"
    config.mkdir()
    proxies = {
        "default": {"httpProxy": "http://alice:pw@proxy.example:3128", "noProxy": "localhost,.corp.example"},
        way.host: {"httpsProxy": "http://engine-own.example:3129"},  # this engine's own entry wins
    }
    (config / "config.json").write_text(json.dumps({"proxies": proxies}))
    engine = Engine.connect({**way._env, "DOCKER_CONFIG": str(config)})
    lines: list[str] = []
    run = spec(["sh", "-c", "env | grep -i _proxy= | sort"], env=(("no_proxy", "set.by.the.step"),))
    assert engine.run(run, lines.append) == 0
    assert lines == ["HTTPS_PROXY=http://engine-own.example:3129", "https_proxy=http://engine-own.example:3129",
                     "no_proxy=set.by.the.step"], lines  # fmt: skip
    del proxies[way.host]
    (config / "config.json").write_text(json.dumps({"proxies": proxies}))
    lines.clear()
    assert (
        Engine.connect({**way._env, "DOCKER_CONFIG": str(config)}).run(spec(["sh", "-c", "env | sort"]), lines.append)
        == 0
    )
    assert {"HTTP_PROXY=http://alice:pw@proxy.example:3128", "http_proxy=http://alice:pw@proxy.example:3128",
            "NO_PROXY=localhost,.corp.example", "no_proxy=localhost,.corp.example"} <= set(lines), lines  # fmt: skip


def test_an_engine_on_loopback_is_reached_past_the_shell_s_proxy(way, monkeypatch):
    """HTTP_PROXY in the shell (a company's) and an engine on tcp://127.0.0.1 (Docker Desktop's
    from WSL, a forwarded socket): espdock asked the proxy for the engine ("403 Forbidden", or two
    minutes of nothing), and said no engine answers where `docker` reached it; Go's rules, the
    CLI's, never proxy loopback."""
    with socket.socket() as closed:
        closed.bind(("127.0.0.1", 0))
        dead = f"http://127.0.0.1:{closed.getsockname()[1]}"  # nothing listens: a proxy that is down
    for name in ("HTTP_PROXY", "HTTPS_PROXY", "http_proxy", "https_proxy"):
        monkeypatch.setenv(name, dead)
    monkeypatch.setenv("NO_PROXY", "localhost")  # not the address: as requests matches it, no help
    lines: list[str] = []
    assert Engine.connect(way._env).run(spec(["echo", "reached"]), lines.append) == 0
    assert lines == ["reached"]


def test_files_go_in_before_the_start_and_come_out_after_the_end(way, tmp_path):
    archive = io.BytesIO()
    with tarfile.open(fileobj=archive, mode="w") as tar:
        data = b"from the host\n"
        member = tarfile.TarInfo("in.txt")
        member.size = len(data)
        tar.addfile(member, io.BytesIO(data))
    run = spec(
        ["sh", "-c", "mkdir /out && tr a-z A-Z < /tmp/in.txt > /out/up.txt"], archives=(("/tmp", archive.getvalue()),)
    )
    fetched, missing = tmp_path / "out.tar", tmp_path / "missing.tar"
    assert way.run(run, lambda line: None, fetch={"/out": fetched, "/nowhere": missing}) == 0
    with tarfile.open(fetched) as tar:
        assert tar.extractfile("out/up.txt").read() == b"FROM THE HOST\n"
    assert not missing.exists(), "a path the container lacks gives no file"
    assert way.containers(dict(run.labels)) == []


def test_a_foreground_run_goes_through_the_docker_cli_to_the_same_engine(way, capfd):
    """`espdock run`'s path: the docker CLI, given the engine's settings (TLS ones included)."""
    run = spec(["sh", "-c", "echo in the foreground; exit 3"])
    assert way.run_foreground(run) == (3, None)
    assert "in the foreground" in capfd.readouterr().out
    assert way.containers(dict(run.labels)) == []


def test_an_attached_run_s_container_goes_when_its_espdock_is_killed_outright(engine):
    """`espdock monitor` killed with kill -9: its container stayed, holding the serial port (a serial
    server's one connection), and every flash from elsewhere said nothing answered there."""
    label = ("io.espdock.test-run", uuid.uuid4().hex)
    selector = f"label={label[0]}={label[1]}"
    script = (
        "import os, sys; from espdock.images.engine import Engine; from espdock.images.specs import RunSpec; "
        "spec = RunSpec(image=sys.argv[1], argv=('sleep', '120'), workdir='/', labels=((sys.argv[2], sys.argv[3]),)); "
        "Engine.connect(os.environ).run_attached(spec)"
    )
    monitor = subprocess.Popen([sys.executable, "-c", script, IMAGE, *label], stdin=subprocess.PIPE, cwd=REPO)
    try:
        deadline = time.monotonic() + 60
        while not docker_ids("ps", "--filter", selector, "--filter", "status=running"):
            assert monitor.poll() is None and time.monotonic() < deadline, "the attached container never ran"
            time.sleep(0.2)
        monitor.kill()
        monitor.wait()
        deadline = time.monotonic() + 20
        while docker_ids("ps", "--all", "--filter", selector) and time.monotonic() < deadline:
            time.sleep(0.2)
        assert docker_ids("ps", "--all", "--filter", selector) == set(), "left running after its espdock was killed"
    finally:
        monitor.kill()
        subprocess.run(["docker", "rm", "--force", *docker_ids("ps", "--all", "--filter", selector)],
                       capture_output=True, check=False)  # fmt: skip


def without_docker_settings() -> dict[str, str]:
    """This process's environment without the shell's DOCKER_* settings (host, TLS, context, config),
    which a test then sets as the case it is about needs."""
    return {key: value for key, value in os.environ.items() if not key.startswith("DOCKER_")}


def assert_the_cli_reaches(env: dict[str, str]) -> None:
    """The docker CLI, set up by ENV, reaches the engine: what espdock must then reach too."""
    asked = subprocess.run(["docker", "version", "--format", "{{.Server.Os}}"], env=env, capture_output=True,
                           text=True, check=False)  # fmt: skip
    assert asked.stdout.strip() == "linux", asked.stderr


SETUPS = ["DOCKER_TLS_VERIFY, the CA alone", "context with its CA only", "context skipping verification", "DOCKER_TLS"]


@pytest.mark.parametrize("setup", SETUPS)
def test_a_tls_engine_that_asks_no_client_certificate_is_reached_as_the_cli_reaches_it(engine, tmp_path, capfd, setup):
    """`dockerd --tls` without --tlsverify, or a TLS proxy before it, set up as `docker` takes it:
    DOCKER_CERT_PATH holding only the CA (the Docker SDK refused to go without a client
    certificate), a context holding a CA alone, a context skipping verification (no files at
    all), DOCKER_TLS=1 with the CLI's files in its config dir (espdock spoke plain HTTP to the
    last three)."""
    tls = make_certificates(tmp_path, client=False)
    forwarder = TcpForwarder(Path(local_socket()), tls)
    try:
        host = f"tcp://127.0.0.1:{forwarder.port}"
        env = {**without_docker_settings(), "DOCKER_CONFIG": str(tmp_path / "docker")}
        if setup.startswith("DOCKER_TLS_VERIFY"):
            env.update(DOCKER_HOST=host, DOCKER_TLS_VERIFY="1", DOCKER_CERT_PATH=str(tmp_path / "client"))
        elif setup == "DOCKER_TLS":
            # The CLI's files where it looks without DOCKER_CERT_PATH, its config dir: the CA alone.
            (tmp_path / "docker").mkdir()
            shutil.copy(tmp_path / "ca.pem", tmp_path / "docker")
            env.update(DOCKER_HOST=host, DOCKER_TLS="1")
        else:
            endpoint = f"host={host}," + (f"ca={tmp_path / 'ca.pem'}" if "CA" in setup else "skip-tls-verify=true")
            for args in (("create", "engine", "--docker", endpoint), ("use", "engine")):
                subprocess.run(["docker", "context", *args], env=env, capture_output=True, check=True)
        assert_the_cli_reaches(env)
        with pytest.MonkeyPatch.context() as patch:
            patch.setenv("REQUESTS_CA_BUNDLE", certifi.where())  # the engine's CA still decides, where one is named
            reached = Engine.connect(env)
            assert reached.image(IMAGE) is not None
            lines: list[str] = []
            assert reached.run(spec(["echo", "over tls"]), lines.append) == 0
            assert lines == ["over tls"]
            assert reached.run_foreground(spec(["echo", "through the cli"]))[0] == 0
            assert "through the cli" in capfd.readouterr().out
        # A command on that engine says what it did, and nothing of how it got there: where the
        # engine's certificate went unchecked, urllib3 printed a warning at each request.
        subprocess.run([sys.executable, "-m", "espdock", "init", str(tmp_path / "ws")], env=env, check=True,
                       capture_output=True)  # fmt: skip
        pruned = subprocess.run([sys.executable, "-m", "espdock", "prune", "--dry-run"], cwd=tmp_path / "ws",
                                env={**env, "REQUESTS_CA_BUNDLE": certifi.where()}, capture_output=True, text=True,
                                check=False)  # fmt: skip
        assert pruned.returncode == 0, pruned.stderr
        assert "would remove 0 images" in pruned.stdout
        assert pruned.stderr == ""
    finally:
        forwarder.close()


def test_a_context_with_a_client_certificate_and_no_ca_checks_the_engine_against_the_systems_cas(
    engine, tmp_path, capfd
):
    """`docker context create x --docker host=tcp://...,cert=...,key=...`: an engine whose CA the
    machine trusts (here SSL_CERT_FILE names it, which Go and OpenSSL read as the system's CAs).
    The CLI checks the engine against the system's CAs; espdock checked it against requests'
    bundle, and reached no engine."""
    tls = make_certificates(tmp_path)
    forwarder = TcpForwarder(Path(local_socket()), tls)
    try:
        env = {**without_docker_settings(), "DOCKER_CONFIG": str(tmp_path / "docker")}
        env["SSL_CERT_FILE"] = str(tmp_path / "ca.pem")
        client = tmp_path / "client"
        endpoint = f"host=tcp://127.0.0.1:{forwarder.port},cert={client / 'cert.pem'},key={client / 'key.pem'}"
        for args in (("create", "engine", "--docker", endpoint), ("use", "engine")):
            subprocess.run(["docker", "context", *args], env=env, capture_output=True, check=True)
        assert_the_cli_reaches(env)
        with pytest.MonkeyPatch.context() as patch:
            patch.setenv("REQUESTS_CA_BUNDLE", certifi.where())  # requests' own choice: not the engine's CA
            reached = Engine.connect(env)
            assert reached.image(IMAGE) is not None
            assert reached.run_foreground(spec(["echo", "through the cli"]))[0] == 0
            assert "through the cli" in capfd.readouterr().out
    finally:
        forwarder.close()


@pytest.mark.parametrize("variable", ["DOCKER_TLS_VERIFY", "DOCKER_TLS"])
def test_tls_variables_naming_a_cert_path_without_a_ca_are_refused_as_the_cli_refuses_them(engine, tmp_path, variable):
    """DOCKER_CERT_PATH with the client's certificate and key and no ca.pem, the engine's CA one
    the machine trusts (SSL_CERT_FILE): the docker CLI and compose will not start, checking or
    not. espdock reached the engine (checked against the system's CAs, or unchecked) and built,
    and its own `run` and `compose` then failed."""
    tls = make_certificates(tmp_path)
    (tmp_path / "client/ca.pem").unlink()
    forwarder = TcpForwarder(Path(local_socket()), tls)
    try:
        env = without_docker_settings()
        env.update(DOCKER_HOST=f"tcp://127.0.0.1:{forwarder.port}", DOCKER_CERT_PATH=str(tmp_path / "client"))
        env.update({variable: "1", "SSL_CERT_FILE": str(tmp_path / "ca.pem")})
        asked = subprocess.run(["docker", "version"], env=env, capture_output=True, text=True, check=False)
        assert asked.returncode != 0 and "ca.pem: no such file" in asked.stderr, asked.stderr
        with pytest.raises(ConfigError) as raised:
            bootstrap.ensure_engine(env, lambda text: None)
    finally:
        forwarder.close()
    said = raised.value
    assert f"{variable} turns TLS on, and {tmp_path / 'client'} has no ca.pem" in said.message, said.message
    assert "as ca.pem" in said.hint and "docker context create" in said.hint


@pytest.mark.parametrize("wrong", ["the engine's CA", "the client's certificate"])
def test_a_tls_engine_that_cannot_be_checked_or_refuses_the_certificate_says_so_and_what_to_do(engine, tmp_path, wrong):
    """A running TLS engine and certificates of another CA: a wrong ca.pem (the engine's
    certificate fails the check), or a certificate the engine refuses. espdock said no engine
    answered, and to start the one DOCKER_HOST names."""
    for name in ("engine", "other"):
        (tmp_path / name).mkdir()
    tls = make_certificates(tmp_path / "engine")
    other = tmp_path / "other"
    make_certificates(other)
    given = tmp_path / "given"
    shutil.copytree(tmp_path / "engine/client", given)
    if wrong == "the engine's CA":
        shutil.copy(other / "ca.pem", given / "ca.pem")
    else:
        for name in ("cert.pem", "key.pem"):
            shutil.copy(other / "client" / name, given / name)
    forwarder = TcpForwarder(Path(local_socket()), tls)
    try:
        env = without_docker_settings()
        env.update(DOCKER_HOST=f"tcp://127.0.0.1:{forwarder.port}", DOCKER_TLS_VERIFY="1", DOCKER_CERT_PATH=str(given))
        with pytest.raises(EngineUnavailable) as raised:
            bootstrap.ensure_engine(env, lambda text: None)
    finally:
        forwarder.close()
    said = raised.value
    if wrong == "the engine's CA":
        assert "its TLS certificate is not signed by" in said.message and "[SSL: " in said.message, said.message
    else:  # OpenSSL's alert, or where it was lost as the engine closed (TLS 1.3), the end alone
        assert "espdock's TLS client certificate" in said.message, said.message
    assert "Start the engine" not in (said.hint or ""), said.hint
    assert "DOCKER_CERT_PATH" in said.hint and "`docker version` fails the same way" in said.hint


def test_a_cert_path_alone_turns_no_tls_on_as_for_the_cli(engine, tmp_path):
    """DOCKER_CERT_PATH without DOCKER_TLS_VERIFY or DOCKER_TLS (left over from an engine that
    had TLS) leaves the docker CLI and compose on plain HTTP. The Docker SDK alone takes it for
    TLS: espdock reached no plain engine then, or another engine than the CLI did."""
    make_certificates(tmp_path)
    forwarder = TcpForwarder(Path(local_socket()), None)
    try:
        env = without_docker_settings()
        env.update(DOCKER_HOST=f"tcp://127.0.0.1:{forwarder.port}", DOCKER_CERT_PATH=str(tmp_path / "client"))
        assert_the_cli_reaches(env)
        assert Engine.connect(env).image(IMAGE) is not None
    finally:
        forwarder.close()


def test_a_host_dir_is_mounted_whatever_its_path_holds(way, tmp_path):
    """A workspace's path is the user's: a colon (a dir named for a time, ws:old), a comma or a
    space in it must neither break the mount nor move it. Read-only stays read-only."""
    parent = tmp_path / "ws:old, 10:30 copy"
    (parent / "ws").mkdir(parents=True)
    (parent / "defaults.yaml").write_text("build: {}\n")
    mounts = (Mount(parent / "ws", "/workspace"), Mount(parent / "defaults.yaml", "/defaults.yaml", read_only=True))
    script = "cat /defaults.yaml > /workspace/seen && ! touch /defaults.yaml 2>/dev/null"
    run = spec(["sh", "-c", script], mounts=mounts, user=f"{os.getuid()}:{os.getgid()}")
    lines: list[str] = []
    assert way.run(run, lines.append) == 0, lines
    assert (parent / "ws" / "seen").read_text() == "build: {}\n"
    assert way.containers(dict(run.labels)) == []


def test_a_missing_image_is_a_clear_error_and_leaves_nothing(way):
    run = RunSpec(image=f"espdock/not-built-{uuid.uuid4().hex[:8]}:1", argv=("true",), workdir="/",
                  labels=(("io.espdock.test-run", uuid.uuid4().hex),))  # fmt: skip
    with pytest.raises(ContainerError) as raised:
        way.run(run, lambda line: None)
    assert f"image {run.image} is not there" in raised.value.message
    assert "espdock build" in (raised.value.hint or "")
    assert way.containers(dict(run.labels)) == []


def test_a_file_is_read_from_an_image_without_starting_it_and_a_missing_one_is_none(way, engine):
    """What a keyed image's package labels come from: dpkg's status file, read without running the
    image, gives the set `dpkg-query -W` prints when it runs in it."""
    labels = {"io.espdock.test-run": uuid.uuid4().hex}
    status = way.read_file(IMAGE, DPKG_STATUS, labels)
    assert status is not None
    queried: list[str] = []
    assert engine.run(spec(["dpkg-query", "-W", "-f", "${Package}=${Version}\n"]), queried.append) == 0
    assert installed_packages(status.decode()) == sorted(queried)
    assert len(queried) > 50
    assert way.read_file(IMAGE, "/no/such/file", labels) is None
    assert way.containers(labels) == []


def docker_ids(*args: str) -> set[str]:
    listed = subprocess.run(["docker", *args, "--quiet", "--no-trunc"], capture_output=True, text=True, check=True)
    return set(listed.stdout.split())


def test_the_listings_are_the_engine_s_own_and_removing_labelled_containers_removes_exactly_them(way):
    label = ("io.espdock.test-run", uuid.uuid4().hex)
    selector = f"label={label[0]}={label[1]}"
    for start in ("create", "run", "run"):  # one never started, two running (stopped by the removal)
        detached = ["--detach"] if start == "run" else []
        # --init: sleep as PID 1 would ignore the stop's SIGTERM and hold each removal 3 s.
        made = ["docker", start, *detached, "--init", "--label", "=".join(label), IMAGE, "sleep", "60"]
        subprocess.run(made, capture_output=True, check=True)
    other = spec(["true"])  # a container carrying other labels stays
    subprocess.run(
        ["docker", "create", "--label", "=".join(other.labels[0]), IMAGE, "true"], capture_output=True, check=True
    )
    # So does a live espdock's of another PID namespace of this machine (a CI job beside this one
    # at the same workspace path): its build container was removed under it (exit 137).
    boot = owner_identity().partition(":")[0]
    elsewhere = f"{boot}:1.{os.getpid()}:1"
    made = ["docker", "create", "--label", "=".join(label), "--label", f"{LABEL_OWNER}={elsewhere}", IMAGE, "true"]
    spared = subprocess.run(made, capture_output=True, text=True, check=True).stdout.strip()
    try:
        assert way.remove_containers(dict([label])) == 3
        assert docker_ids("ps", "--all", "--filter", selector) == {spared}
        subprocess.run(["docker", "rm", "--force", spared], capture_output=True, check=True)
        assert docker_ids("ps", "--all", "--filter", selector) == set()
        assert way.containers(dict(other.labels)) != []
    finally:
        way.remove_containers(dict(other.labels))
    assert_listed(lambda: {image_id for image_id, *_ in way.labelled_images(KEYED)}, "--filter", f"label={KEYED}")
    assert_listed(lambda: {image.id for image in way.images("debian")}, "debian")


def test_a_serial_device_another_espdock_container_has_is_named_as_busy(way):
    """A monitor (or the agent) in another terminal holds the board's port in its container, which
    opens its own node of the device: the host's lock check saw nothing, and flash opened it beside."""
    from espdock.firmware.flashing import PortError, check_port_free, parse_port

    boot, running, _ = owner_identity().split(":")
    dead = f"{boot}:{running.rpartition('.')[0]}.4194304:0"  # a killed espdock's: this machine, no such pid
    made = []
    try:
        for owner in (owner_identity(), dead):
            made.append(
                subprocess.run(
                    ["docker", "run", "--detach", "--init", "--device", "/dev/full", "--label",
                     f"{LABEL_OWNER}={owner}", IMAGE, "sleep", "60"],
                    capture_output=True, text=True, check=True,
                ).stdout.strip()
            )  # fmt: skip
        (name,) = way.device_users(["/dev/full"])
        assert docker_ids("ps", "--filter", f"name=^{name}$") == {made[0]}
        assert docker_ids("ps", "--all", "--filter", f"id={made[1]}") == set(), "the killed espdock's goes"
        assert way.device_users(["/dev/zero"]) == []
        # Not espdock's: the micro-ROS agent of the compose file `init` writes (its serial profile).
        made.append(
            subprocess.run(
                ["docker", "run", "--detach", "--init", "--device", "/dev/zero", IMAGE, "sleep", "60"],
                capture_output=True, text=True, check=True,
            ).stdout.strip()
        )  # fmt: skip
        (agent,) = way.device_users(["/dev/zero"])
        assert docker_ids("ps", "--filter", f"name=^{agent}$") == {made[-1]}
        with pytest.raises(PortError, match=f"serial port /dev/full is busy: the container {name} has it"):
            check_port_free(way, parse_port("/dev/full"))
        # A serial server (esp_rfc2217_server, a board's bridge) serves one client: a flash beside a
        # monitor on it saw a silent board ("could not tell which chip"), and named no container.
        url = "socket://127.0.0.1:4567"
        made.append(
            subprocess.run(
                ["docker", "run", "--detach", "--init", "--label", f"{LABEL_OWNER}={owner_identity()}", IMAGE,
                 "sh", "-c", f"sleep 60 # idf.py -p {url} monitor"],
                capture_output=True, text=True, check=True,
            ).stdout.strip()
        )  # fmt: skip
        (holder,) = way.device_users([], url)
        with pytest.raises(PortError, match=f"serial port {url} is busy: the container {holder} has it"):
            check_port_free(way, parse_port(url))
        assert way.device_users([], "socket://127.0.0.1:456") == []  # another port, a prefix of its
        # The same server written otherwise: as text, another one.
        assert way.device_users([], "socket://localhost:4567/") == [holder]
        # This machine by its other names: IPv4-mapped, "any address", IPv6 loopback (a dual-stack
        # server's): each went on to esptool's "could not tell which chip".
        for same in ("socket://[::ffff:127.0.0.1]:4567", "socket://0:4567", "socket://[::1]:4567"):
            assert way.device_users([], same) == [holder], same
    finally:
        subprocess.run(["docker", "rm", "--force", *made], capture_output=True, check=False)


def assert_listed(listing: Callable[[], set[str]], *selection: str) -> None:
    """LISTING gives what `docker images SELECTION` lists. The other test workers build and remove
    images meanwhile, and an image can come and go within one listing, so the check waits for a
    listing the CLI's answers on both sides of agree with; then the two must be the same set."""
    for _ in range(60):
        before = docker_ids("images", *selection)
        listed = listing()
        after = docker_ids("images", *selection)
        if before == after:
            assert listed == before, (before - listed, listed - before)
            return
        time.sleep(0.5)
    pytest.fail(f"`docker images {' '.join(selection)}` changed during each of 60 listings")


def test_a_builds_listings_on_the_local_socket_load_neither_the_sdk_nor_requests(engine):
    """A no-change build lists containers (the sweeps around its steps) and keyed images (its
    closing size note); `micro-ros status` lists images. Over the local socket none of that may
    load the Docker SDK and requests: a fifth of a second of CPU at every espdock start."""
    script = (
        "import json, os, sys\n"
        "from espdock.images.engine import Engine\n"
        "engine = Engine.connect(dict(os.environ))\n"
        "labels = {'io.espdock.test-run': 'nothing-carries-this'}\n"
        "answers = [engine.remove_containers(labels), engine.sweep(labels),\n"
        "           sorted(i for i, *_ in engine.labelled_images(sys.argv[1])), len(engine.images('debian'))]\n"
        "print(json.dumps([answers, [name for name in ('docker', 'requests') if name in sys.modules]]))\n"
    )
    env = {**os.environ, "DOCKER_HOST": f"unix://{local_socket()}"}
    loaded: list[str] = []

    def keyed_images() -> set[str]:
        argv = [sys.executable, "-c", script, KEYED]
        ran = subprocess.run(argv, env=env, capture_output=True, text=True, check=False)
        assert ran.returncode == 0, ran.stderr
        (removed, swept, keyed, debian), imported = json.loads(ran.stdout)
        assert (removed, swept) == (0, 0) and debian >= 1
        loaded.extend(imported)
        return set(keyed)

    assert_listed(keyed_images, "--filter", f"label={KEYED}")
    assert loaded == [], f"listing over the local socket imported {loaded}"


def test_a_runtime_image_s_labels_and_tag_on_the_local_socket_load_neither_the_sdk_nor_requests(engine):
    """Every build that makes a runtime image adds its package labels (a build of its own) and
    tags it espdock/<name>:latest. Over the local socket neither may load the Docker SDK and
    requests (a third of a second of CPU, where the whole step takes 2 s); a tag the engine
    refuses is still said as one."""
    ref = f"espdock-test/labels:{uuid.uuid4().hex[:12]}"
    latest = ref.rsplit(":", 1)[0] + ":latest"
    script = (
        "import json, os, sys\n"
        "from espdock.errors import EspdockError\n"
        "from espdock.images.engine import Engine\n"
        "engine = Engine.connect(dict(os.environ))\n"
        "engine.add_labels(sys.argv[1], {'io.espdock.test-label': 'plain'})\n"
        "engine.tag(sys.argv[1], sys.argv[2])\n"
        "loaded = [name for name in ('docker', 'requests') if name in sys.modules]\n"
        "try:\n"
        "    engine.tag(sys.argv[1] + '-none', sys.argv[2])\n"
        "    refused = None\n"
        "except EspdockError as exc:\n"
        "    refused = exc.message\n"
        "print(json.dumps([engine.image(sys.argv[2]).labels.get('io.espdock.test-label'), refused, loaded]))\n"
    )
    subprocess.run(["docker", "tag", IMAGE, ref], check=True)
    try:
        env = {**os.environ, "DOCKER_HOST": f"unix://{local_socket()}"}
        ran = subprocess.run(
            [sys.executable, "-c", script, ref, latest], env=env, capture_output=True, text=True, check=False
        )
        assert ran.returncode == 0, ran.stderr
        label, refused, loaded = json.loads(ran.stdout)
        assert label == "plain"
        assert refused is not None and f"could not tag {ref}-none as {latest}" in refused, refused
        assert "no such image" in refused.lower(), refused
        assert loaded == [], f"labelling and tagging over the local socket imported {loaded}"
    finally:
        subprocess.run(["docker", "rmi", ref, latest], capture_output=True, check=False)


class RemappedEngine(PrivateEngine):
    """A dockerd of the test's own that maps its containers' users to subordinate ids, as a
    hardened host's is set up (--userns-remap=default; dockerd adds the system user dockremap
    and its id ranges where they are missing)."""

    def dockerd(self) -> list[str]:
        return [*super().dockerd(), "--userns-remap=default"]


@pytest.fixture(scope="module")
def remapped_engine() -> Iterator[RemappedEngine]:
    """One remapping engine for the module's tests, holding IMAGE; gone with its files after them."""
    if shutil.which("dockerd") is None or shutil.which("unshare") is None:
        pytest.skip("no dockerd or unshare here")
    # dockerd adds the user whose id ranges it maps to: the test removes it again if it was not there.
    adds_user = subprocess.run(["getent", "passwd", "dockremap"], capture_output=True, check=False).returncode != 0
    home = private_home()
    home.chmod(0o711)  # the remapped root of the engine's own storage passes through
    private = RemappedEngine(home)
    try:
        private.start()
        private.load(IMAGE)
        yield private
    finally:
        drop_private_engine(private)
        if adds_user:  # with its group and its lines in /etc/subuid and /etc/subgid
            subprocess.run(["userdel", "dockremap"], capture_output=True, check=False)


def serial_port(engine: PrivateEngine) -> Path:
    """A board's serial port as the host has it: a character device of root and the dialout
    group, mode 0660 (here the null device's numbers), where anyone may reach it, as in /dev (in
    the engine's home: the test's own temp dir lets no other uid through)."""
    port = engine.home / f"ttyUSB-{uuid.uuid4().hex[:8]}"
    os.mknod(port, 0o660 | stat.S_IFCHR, os.makedev(1, 3))
    os.chown(port, 0, 20)
    return port


def test_on_an_engine_that_remaps_users_a_step_writes_the_workspace_as_the_user(remapped_engine, tmp_path, capfd):
    """A step runs as the invoking user, whose workspace it writes: remapped, that user is another
    uid outside, which the workspace refused ("Permission denied"), both ways a step is run. The
    agent's container, on the host's network with a serial port, was refused by dockerd."""
    workspace = tmp_path / "ws"
    workspace.mkdir(mode=0o755)
    reached = Engine.connect(remapped_engine.env)
    user = f"{os.getuid()}:{os.getgid()}"
    mounts = (Mount(workspace, "/workspace"),)
    step = spec(["sh", "-c", "echo built > /workspace/out"], mounts=mounts, user=user)
    lines: list[str] = []
    assert reached.run(step, lines.append) == 0, lines
    foreground = spec(["sh", "-c", "echo ran > /workspace/node.log"], mounts=mounts, user=user)
    assert reached.run_foreground(foreground)[0] == 0, capfd.readouterr().err
    for name, text in (("out", "built\n"), ("node.log", "ran\n")):
        written = workspace / name
        assert written.read_text() == text
        assert (written.stat().st_uid, written.stat().st_gid) == (os.getuid(), os.getgid())
    assert reached.containers(dict(step.labels)) == [] == reached.containers(dict(foreground.labels))

    # The micro-ROS agent's container: root, the host's network and a board's serial port.
    port = serial_port(remapped_engine)
    agent = spec(["sh", "-c", f"echo frame > {port} && echo sent"], devices=(str(port),), network="host")
    lines = []
    assert reached.run(agent, lines.append) == 0, lines
    assert lines == ["sent"]


@pytest.mark.parametrize("compose_file", ["demo", "starter"])
def test_on_an_engine_that_remaps_users_the_compose_serial_agent_opens_the_board_s_port(
    remapped_engine, tmp_path, compose_file
):
    """The serial agent of the demo's compose file and of the one `espdock init --compose` writes,
    as compose runs it. Remapped, runc cannot make its /dev/microros (in a user namespace it
    bind-mounts the host's node at the container's path, which the host lacks: "error creating
    device nodes"), and where the paths match, the port (root and dialout, 0660) refuses the
    remapped root; `espdock agent` opened it."""
    if compose_file == "demo":
        path = REPO / "compose.yaml"
    else:
        path = tmp_path / "compose.yaml"
        path.write_text(starter_compose("starter", "espdock/starter:latest", {}))
    remapped_engine.docker("tag", IMAGE, MICRO_ROS_AGENT_IMAGE)  # what the agent runs on: a shell
    env = {**remapped_engine.env, "MICROROS_SERIAL_DEVICE": str(serial_port(remapped_engine))}
    project = ["-p", f"espdock-test-{uuid.uuid4().hex[:8]}", "-f", str(path), "--project-directory", str(path.parent)]
    argv = ["docker", "compose", *project, "--profile", "serial", "run", "--rm", "--no-deps", "--entrypoint", "sh",
            "micro_ros_agent_serial", "-c", "echo frame > /dev/microros && echo sent"]  # fmt: skip
    try:
        ran = subprocess.run(argv, env=env, capture_output=True, text=True, timeout=120, check=False)
    finally:
        subprocess.run(["docker", "compose", *project, "down"], env=env, capture_output=True, check=False)
    assert ran.returncode == 0, ran.stdout + ran.stderr
    assert ran.stdout.splitlines()[-1] == "sent", ran.stdout + ran.stderr


def test_labels_are_added_and_registries_asked_whatever_credential_helper_the_cli_config_names(
    engine, tmp_path, monkeypatch
):
    """A Docker CLI config naming a credential helper this machine lacks (`"credsStore": "desktop"`,
    as Docker Desktop leaves it in a config copied over): adding a keyed image's package labels,
    the step after its build, ended espdock as a bug of its own (exit 70), the SDK asking the
    helper for every registry login for a build FROM a local image; a registry call the same."""
    (tmp_path / "config.json").write_text('{"credsStore": "desktop"}\n')
    monkeypatch.setenv("DOCKER_CONFIG", str(tmp_path))
    ref = f"espdock-test/labels:{uuid.uuid4().hex[:12]}"
    subprocess.run(["docker", "tag", IMAGE, ref], check=True)
    try:
        for host in (f"unix://{local_socket()}", None):  # the plain-HTTP client and the SDK's
            fresh = Engine.connect({**os.environ, **({"DOCKER_HOST": host} if host else {})})
            fresh.add_labels(ref, {"io.espdock.test-label": host or "sdk"})
            assert fresh.image(ref).labels["io.espdock.test-label"] == (host or "sdk")
            assert fresh.pull("127.0.0.1:9/espdock-test/none:1") is False
            # Asked without a login, as the CLI goes on: the registry's own answer (nothing listens there).
            answer = fresh.pull_cached("127.0.0.1:9/espdock-test/none:1")
            assert answer.status.value == "unreachable" and "127.0.0.1:9" in answer.detail, answer
            assert "credential" not in answer.detail.lower(), answer
    finally:
        subprocess.run(["docker", "rmi", ref], capture_output=True, check=False)


def test_an_image_build_s_output_is_the_build_s_not_compose_s_builder_note(engine, tmp_path):
    """Every build's log (and every CI log) began with Compose's "configured to build using Bake,
    but buildx isn't installed": of the machine's docker set-up, not of the image being built."""
    (tmp_path / "Dockerfile").write_text(f"FROM {IMAGE} AS build\nRUN echo built-here\n")
    tag = f"espdock-test-note:{os.getpid()}"
    said: list[str] = []
    try:
        engine.build_image(tmp_path, "Dockerfile", "build", tag, {}, {}, None, said.append, no_cache=True)
    finally:
        subprocess.run(["docker", "rmi", tag], capture_output=True, check=False)
    assert any("built-here" in line for line in said), said
    assert not any("Bake" in line for line in said), said
