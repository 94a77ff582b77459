"""What the engine's failures read like to users: espdock.images.engine turns the Docker SDK's
exceptions into EspdockErrors (exit code, message, hint) at its boundary.

An engine that is gone is the real SDK on a socket nothing listens on. An engine that refuses one
call is EngineDouble below, which raises the SDK's own exceptions, made as the SDK makes them from
an HTTP answer (a real engine refuses these calls only when its disk is full, a volume is in use,
a runtime is broken...).
"""

from __future__ import annotations

import contextlib
import json
import os
import socket
from pathlib import Path

import docker.errors
import pytest
import requests

from espdock.errors import ContainerError, EngineUnavailable, EspdockError, ImageBuildError, MountSourceMissing
from espdock.images.engine import Engine
from espdock.images.specs import RegistryAnswer, RegistryStatus, RunSpec

TCP = "tcp://engine.invalid:2375"
NAMED = f"the Docker engine at {TCP}"
RERUN = "then rerun: the next command removes what was left."
# An engine that went away, by where it was: another daemon's socket, or a TCP engine.
LOST_HINT = "Start the daemon of {} (rootless Docker: `systemctl --user start docker`), " + RERUN
TCP_LOST_HINT = f"Start the engine at {TCP}, " + RERUN
URL = "http+docker://localhost/v1.44/volumes/create"
SPEC = RunSpec("espdock/img:1", ("true",), "/")


def refusal(status: int, message: str) -> docker.errors.APIError:
    """The exception the SDK raises when the engine answers STATUS with MESSAGE."""
    response = requests.Response()
    response.status_code, response.url = status, URL
    response.reason = {404: "Not Found", 409: "Conflict"}.get(status, "Internal Server Error")
    response._content = json.dumps({"message": message}).encode()
    try:
        docker.errors.create_api_error_from_http_exception(requests.HTTPError(response=response))
    except docker.errors.APIError as exc:
        return exc
    raise AssertionError("the SDK made no exception")


class EngineDouble:
    """Stands in for the Docker SDK client of a Docker engine that answers /_ping, /info and every
    call but those named in FAILS (a dotted path, `()` after a call's result: "containers.prepare_model().start"),
    which raise their exception. CALLED records every call's path."""

    def __init__(self, fails: dict[str, Exception], path: str = "", called: list[str] | None = None) -> None:
        self._fails, self._path = fails, path
        self.called = [] if called is None else called

    def __getattr__(self, name: str) -> EngineDouble:
        return EngineDouble(self._fails, f"{self._path}.{name}".lstrip("."), self.called)

    def __call__(self, *args: object, **kwargs: object) -> object:
        self.called.append(self._path)
        if self._path in self._fails:
            raise self._fails[self._path]
        if self._path == "info":
            return {"Name": "host", "ID": "1"}
        if self._path == "api.get":  # /_ping, as Docker answers it
            return requests.Response()
        return EngineDouble(self._fails, f"{self._path}()", self.called)

    def __iter__(self):
        return iter(())

    def __getitem__(self, key: str) -> EngineDouble:
        return EngineDouble(self._fails, f"{self._path}[{key}]", self.called)


def refusing(fails: dict[str, Exception]) -> Engine:
    return Engine({"DOCKER_HOST": TCP}, client=EngineDouble(fails))


@pytest.fixture
def gone(tmp_path) -> tuple[Engine, str]:
    """The real SDK on a socket nothing listens on: every call's connection fails."""
    where = f"unix://{tmp_path / 'gone.sock'}"
    return Engine({"DOCKER_HOST": where}, client=docker.DockerClient(base_url=where, version="1.44")), where


@pytest.mark.parametrize(
    ("call", "doing"),
    [
        (lambda e: e.ensure_volume("v", {}), "making volume v"),
        (lambda e: e.remove_volume("v"), "removing volume v"),
        (lambda e: e.volumes({"a": "b"}), "listing volumes"),
        (lambda e: e.sweep({"a": "b"}), "listing containers"),
        (lambda e: e.remove_containers({"a": "b"}), "listing containers"),
        (lambda e: e.run(SPEC, print), "creating a container of espdock/img:1"),
        (lambda e: e.info(), "asking what it is"),
        (lambda e: e.images("espdock/img"), "listing images of espdock/img"),
        (lambda e: e.remove_tag("espdock/img:1"), "removing espdock/img:1"),
        (lambda e: e.tag("espdock/img:1", "espdock/img:2"), "tagging espdock/img:1 as espdock/img:2"),
        (lambda e: e.untag("espdock/img:1"), "removing the name espdock/img:1"),
        (lambda e: e.containers({"a": "b"}), "listing containers"),
        # Podman's `podman system service` ends after 5 s without a call: during a debootstrap.
        (lambda e: e.add_labels("espdock/img:1", {"a": "b"}), "adding labels to espdock/img:1"),
        (lambda e: e.import_rootfs(Path(__file__), "debian:x"), f"importing {__file__} as debian:x"),
    ],
    ids=[
        "ensure_volume",
        "remove_volume",
        "volumes",
        "sweep",
        "remove_containers",
        "run",
        "info",
        "images",
        "remove_tag",
        "tag",
        "untag",
        "containers",
        "add_labels",
        "import_rootfs",
    ],
)
def test_an_engine_that_is_gone_is_exit_3_naming_it_and_what_espdock_was_doing(gone, call, doing):
    engine, where = gone
    with pytest.raises(EngineUnavailable) as err:
        call(engine)
    assert (err.value.exit_code, err.value.message) == (3, f"the Docker engine at {where} went away while {doing}")
    assert err.value.hint == LOST_HINT.format(where.removeprefix("unix://"))


@pytest.mark.parametrize(
    ("call", "doing"),
    [
        (lambda e: e.run(SPEC, print), "creating a container of espdock/img:1"),
        (lambda e: e.sweep({"a": "b"}), "listing containers"),
        (lambda e: e.remove_containers({"a": "b"}), "listing containers"),
        (lambda e: e.images("espdock/img"), "listing images of espdock/img"),
    ],
    ids=["run", "sweep", "remove_containers", "images"],
)
def test_a_gone_local_socket_is_exit_3_over_plain_http_too(tmp_path, call, doing):
    where = f"unix://{tmp_path / 'gone.sock'}"
    with pytest.raises(EngineUnavailable) as err:
        call(Engine({"DOCKER_HOST": where}))
    assert err.value.message == f"the Docker engine at {where} went away while {doing}"
    assert err.value.hint == LOST_HINT.format(where.removeprefix("unix://"))


def test_an_engine_nothing_answers_for_is_named_over_tcp_as_on_a_socket(tmp_path):
    from tests.ports import free_port

    for where in (f"tcp://127.0.0.1:{free_port()}", f"unix://{tmp_path / 'none.sock'}"):
        with pytest.raises(EngineUnavailable) as err:
            Engine.connect({"DOCKER_HOST": where}, timeout=5)
        assert err.value.message == f"no Docker engine answers at {where}: nothing is listening there"


def test_a_docker_host_naming_another_daemon_s_socket_or_a_file_is_exit_3_saying_what_is_there(tmp_path):
    """DOCKER_HOST at an ssh-agent's or sshd's socket, or at a file: exit 70 ("a bug in espdock")
    for the first, "permission denied ... join the docker group" (or, as root, "nothing is
    listening") for the second."""
    import socket
    import threading

    path = tmp_path / "sshd.sock"
    server = socket.socket(socket.AF_UNIX)
    server.bind(str(path))
    server.listen()

    def answer() -> None:
        with contextlib.suppress(OSError):
            while True:
                client, _ = server.accept()
                with client:
                    client.recv(4096)
                    client.sendall(b"SSH-2.0-OpenSSH_9.2\r\n")

    threading.Thread(target=answer, daemon=True).start()
    try:
        with pytest.raises(EngineUnavailable) as err:
            Engine.connect({"DOCKER_HOST": f"unix://{path}"}, timeout=5)
        said = err.value.message
        assert said.startswith(f"no Docker engine answers at unix://{path}: what answers there speaks no HTTP"), said
        assert "SSH-2.0-OpenSSH_9.2" in said
    finally:
        server.close()
    (tmp_path / "not-a-socket").write_text("")
    for target, kind in ((tmp_path / "not-a-socket", "a regular file"), (tmp_path, "a directory")):
        with pytest.raises(EngineUnavailable) as err:
            Engine.connect({"DOCKER_HOST": f"unix://{target}"}, timeout=5)
        assert err.value.message == f"no Docker engine answers at unix://{target}: {target} is {kind}, not a socket"
        assert "docker group" not in (err.value.hint or "") and "unix:///var/run/docker.sock" in err.value.hint


def test_a_tcp_engine_address_that_takes_the_connection_and_never_answers_is_said_within_the_timeout():
    """DOCKER_HOST at another service's port (a serial server's), which accepts and says nothing:
    espdock printed nothing for two minutes, the SDK's operation timeout, where a socket took 11 s."""
    import socket
    import time

    server = socket.create_server(("127.0.0.1", 0))
    port = server.getsockname()[1]
    try:
        started = time.monotonic()
        with pytest.raises(EngineUnavailable) as err:
            Engine.connect({"DOCKER_HOST": f"tcp://127.0.0.1:{port}"}, timeout=2)
        took = time.monotonic() - started
        said = err.value.message
        assert said.startswith(
            f"no Docker engine answers at tcp://127.0.0.1:{port}: it took the connection and gave no answer"
        ), said
        assert "Start the engine" not in (err.value.hint or "") and "Check DOCKER_HOST" in err.value.hint
        assert took < 30, f"said after {took:.0f} s"
    finally:
        server.close()


def test_keyed_images_unlisted_on_a_gone_local_socket_say_so_exit_1(tmp_path):
    # As over the SDK (labelled_images in the refusals below): the size note after a build
    # turns it into a warning, the build stands.
    with pytest.raises(EspdockError) as err:
        Engine({"DOCKER_HOST": f"unix://{tmp_path / 'gone.sock'}"}).labelled_images("io.espdock.key")
    assert (err.value.exit_code, err.value.message) == (
        1,
        "the engine failed to list its images: [Errno 2] No such file or directory",
    )


def test_an_image_lookup_on_a_gone_engine_is_exit_3_over_the_sdk_and_the_plain_socket(gone):
    """A build waiting on another's image lock looks the image up when the lock comes free: the
    engine killed meanwhile was exit 1, "[Errno 111] Connection refused", with no hint."""
    engine, where = gone
    for lookup in (engine, Engine({"DOCKER_HOST": where})):
        with pytest.raises(EngineUnavailable) as err:
            lookup.image("espdock/img:1")
        assert err.value.message == f"the Docker engine at {where} went away while looking up image espdock/img:1"


def fake_cli(tmp_path: Path, script: str) -> list[str]:
    """A docker CLI (and its compose plugin) that runs SCRIPT (sh) whatever it is asked."""
    cli = tmp_path / "docker"
    cli.write_text(f"#!/bin/sh\n{script}\n")
    cli.chmod(0o755)
    return [str(cli), "compose"]


def test_the_engine_going_away_under_buildkit_or_the_cli_s_run_is_exit_3(gone, tmp_path, monkeypatch):
    """dockerd killed during an image build: BuildKit's client says "rpc error: code = Unavailable
    desc = error reading from server: EOF", and it was exit 4, "Read the build output above"; under
    `espdock run` the CLI's 125 was exit 9, "could not start a container", of a node that had run."""
    from espdock.images.specs import ImageBuild

    engine, where = gone
    said = "ERROR: failed to receive status: rpc error: code = Unavailable desc = error reading from server: EOF"
    # It reads the build's compose file from stdin first, as Compose does.
    monkeypatch.setattr(engine, "compose_command", lambda: fake_cli(tmp_path, f"cat >/dev/null; echo '{said}'; exit 1"))
    build = ImageBuild(tmp_path, "Dockerfile", "build", "espdock/img:1", {}, {}, None, lambda line: None, False)
    with pytest.raises(EngineUnavailable) as err:
        engine._build_buildkit(build)
    assert err.value.message == f"the Docker engine at {where} went away while building espdock/img:1"
    monkeypatch.setattr(engine, "docker_command", lambda: fake_cli(tmp_path, "exit 125")[0])
    with pytest.raises(EngineUnavailable) as err:
        engine.run_foreground(SPEC)
    assert err.value.message == f"the Docker engine at {where} went away while running a container of espdock/img:1"


# apt's own words in a build container without a network (`docker run --network none
# debian:bookworm-slim sh -c 'apt-get update; apt-get install -y tini'`), then BuildKit's.
APT_OFFLINE = """#6 [image build 2/9] RUN apt-get update && apt-get install -y tini
#6 0.301 Err:1 http://deb.debian.org/debian bookworm InRelease
#6 0.301   Temporary failure resolving 'deb.debian.org'
#6 0.310 W: Failed to fetch http://deb.debian.org/debian/dists/bookworm/InRelease  Temporary failure resolving \
'deb.debian.org'
#6 0.310 W: Some index files failed to download. They have been ignored, or old ones used instead.
#6 0.320 Reading package lists...
#6 0.330 Building dependency tree...
#6 0.330 Reading state information...
#6 0.340 E: Unable to locate package tini
#6 ERROR: process "/bin/sh -c apt-get update && apt-get install -y tini" did not complete successfully: exit code: 100
------
 > [image build 2/9] RUN apt-get update && apt-get install -y tini:
0.320 Reading package lists...
0.330 Building dependency tree...
0.330 Reading state information...
0.340 E: Unable to locate package tini
------
Dockerfile.ros:12
--------------------
  11 |     # the apt step
  12 | >>> RUN apt-get update && apt-get install -y tini
--------------------
failed to solve: process "/bin/sh -c apt-get update && apt-get install -y tini" did not complete successfully: \
exit code: 100
"""


def test_an_image_build_without_a_network_says_so_not_only_the_package_apt_could_not_find(tmp_path, monkeypatch):
    """An air-gapped lab: the error ended with apt's "Unable to locate package tini", and the hint
    was to read the build output; the cause ("Temporary failure resolving") had scrolled out of it."""
    from espdock.images.specs import ImageBuild

    engine = Engine({"DOCKER_HOST": "unix:///nonexistent.sock"}, client=object())
    monkeypatch.setattr(engine, "_answers", lambda: True)

    def hint_of(output: str) -> str:
        said = tmp_path / "said.txt"
        said.write_text(output)
        monkeypatch.setattr(
            engine, "compose_command", lambda: fake_cli(tmp_path, f"cat >/dev/null; cat {said}; exit 1")
        )
        build = ImageBuild(tmp_path, "Dockerfile", "build", "espdock/img:1", {}, {}, None, lambda line: None, False)
        with pytest.raises(ImageBuildError) as err:
            engine._build_buildkit(build)
        assert "Temporary failure resolving" not in err.value.message  # out of the tail it shows
        return err.value.hint

    hint = hint_of(APT_OFFLINE)
    assert hint.startswith("A step of the build could not reach the network (Temporary failure resolving "), hint
    assert "~/.docker/config.json" in hint
    # One dead source of several: apt fetched from the others, and failed for another reason.
    got = "#6 0.315 Get:2 http://deb.debian.org/debian bookworm/main amd64 Packages [8790 kB]\n"
    fetched = APT_OFFLINE.replace("#6 0.320 Reading package lists...", got + "#6 0.320 Reading package lists...")
    assert hint_of(fetched) == "Read the build output above; run with --verbose for all of it."
    # A step that found no network, then succeeded on a retry; the build failed at a later step.
    later = APT_OFFLINE.replace("#6 ERROR:", "#6 DONE 1.2s\n#7 [image build 3/9] RUN false\n#7 ERROR:", 1)
    assert hint_of(later) == "Read the build output above; run with --verbose for all of it."
    # pip's words come after a long repr of its connection: the hint quotes them.
    pip = (
        "#6 2.1 WARNING: Retrying (Retry(total=4, connect=None, read=None, redirect=None, status=None)) after "
        "connection broken by 'NewConnectionError('<pip._vendor.urllib3.connection.HTTPSConnection object at "
        "0x7f29c0d1e2d0>: Failed to establish a new connection: [Errno -2] Name or service not known')': /simple/x/\n"
    )
    assert "Failed to establish a new connection: [Errno -2]" in hint_of(
        APT_OFFLINE.replace("#6 0.301 Err:1", pip + "#6 0.301 Err:1")
    )


REFUSED = refusal(500, "no space left on device")
SAID = f'500 Server Error for {URL}: Internal Server Error ("no space left on device")'
HYBRID = "crun: cgroups in hybrid mode are not supported"
IN_USE = "remove v: volume is in use - [4f1c]"
# Docker's answer to a bind of a path its machine lacks (a remote engine; Binds made a directory).
NO_SOURCE = 'invalid mount config for type "bind": bind source path does not exist: /home/ann/.colcon/defaults.yaml'


@pytest.mark.parametrize(
    ("call", "fails", "kind", "message", "hint"),
    [
        (
            lambda e: e.ensure_volume("v", {}),
            {"volumes.get": refusal(404, "get v: no such volume"), "volumes.create": REFUSED},
            ContainerError,
            f"{NAMED} could not make volume v: no space left on device",
            None,
        ),
        (
            lambda e: e.remove_volume("v"),
            {"volumes.get().remove": refusal(409, IN_USE)},
            ContainerError,
            f"{NAMED} did not remove volume v: {IN_USE}",
            "Stop the espdock command or container using it (`docker ps -a --filter volume=NAME`), then again.",
        ),
        (
            lambda e: e.run(SPEC, print),
            {"api.create_container_from_config": REFUSED},
            ContainerError,
            f"{NAMED} could not create a container of espdock/img:1: no space left on device",
            None,
        ),
        (
            lambda e: e.run(SPEC, print),
            {"api.create_container_from_config": refusal(404, "No such image: espdock/img:1")},
            ContainerError,
            f'image espdock/img:1 is not there: 404 Client Error for {URL}: Not Found ("No such image: espdock/img:1")',
            "Run `espdock build` to build it.",
        ),
        (
            lambda e: e.run(SPEC, print),
            {"api.create_container_from_config": refusal(400, NO_SOURCE)},
            MountSourceMissing,
            f"{NAMED} has no /home/ann/.colcon/defaults.yaml for a container of espdock/img:1: it runs on another "
            "machine, which lacks that path",
            "Build on an engine that shares this machine's files at the same paths (a local engine: unset "
            'DOCKER_HOST), or let espdock keep the workspace in a volume on that engine (workspace_mode = "volume" '
            "in espdock.toml).",
        ),
        (
            lambda e: e.run(SPEC, print),
            {"containers.prepare_model().start": refusal(500, HYBRID)},
            ContainerError,
            f"{NAMED} could not run a container of espdock/img:1: {HYBRID}",
            'crun cannot run containers on this host\'s hybrid cgroups: set runtime = "runc" in the [engine] '
            "table of containers.conf (install runc if it is missing), restart the Podman service, then try again.",
        ),
        (
            lambda e: e.run(SPEC, print),
            {"containers.prepare_model().start": requests.exceptions.ConnectionError("Connection aborted.")},
            EngineUnavailable,
            f"{NAMED} went away while running a container of espdock/img:1",
            TCP_LOST_HINT,
        ),
        (
            lambda e: e.run(SPEC, print),
            {"containers.prepare_model().logs": requests.exceptions.ReadTimeout("Read timed out.")},
            EngineUnavailable,
            f"{NAMED} did not answer within 120 s while running a container of espdock/img:1",
            "Look at the engine (is it overloaded or hung?), then build again.",
        ),
        (
            lambda e: e.add_labels("espdock/img:1", {"a": "b"}),
            {"api.post": REFUSED},
            ImageBuildError,
            f"{NAMED} could not add labels to espdock/img:1: {SAID}",
            None,
        ),
        (
            lambda e: e.import_rootfs(Path("/t/rootfs.tar"), "espdock/img:1"),
            {"api.import_image_from_file": REFUSED},
            ImageBuildError,
            f"{NAMED} refused to import /t/rootfs.tar as espdock/img:1: {SAID}",
            None,
        ),
        (
            lambda e: e.tag("abc", "espdock/img:1"),
            {"api.tag": REFUSED},
            EspdockError,
            f"the engine could not tag abc as espdock/img:1: {SAID}",
            None,
        ),
        (
            lambda e: e.untag("espdock/img:1"),
            {"api.remove_image": REFUSED},
            EspdockError,
            f"the engine could not remove the name espdock/img:1: {SAID}",
            None,
        ),
        (
            lambda e: e.remove_tag("espdock/img:1"),
            {"api.remove_image": REFUSED},
            EspdockError,
            f"the engine could not remove espdock/img:1: {SAID}",
            None,
        ),
        (
            lambda e: e.image("espdock/img:1"),
            {"images.get": REFUSED},
            EspdockError,
            f"the engine failed to look up image espdock/img:1: {SAID}",
            None,
        ),
        (
            lambda e: e.images("espdock/img"),
            {"api.images": REFUSED},
            EspdockError,
            f"the engine failed to list images of espdock/img: {SAID}",
            None,
        ),
        (
            lambda e: e.containers({"a": "b"}),
            {"api.containers": REFUSED},
            EspdockError,
            f"the engine failed to list containers: {SAID}",
            None,
        ),
        (
            lambda e: e.sweep({"a": "b"}),
            {"api.containers": REFUSED},
            EspdockError,
            f"the engine failed to list containers: {SAID}",
            None,
        ),
        (
            lambda e: e.image_users(),
            {"api.containers": requests.exceptions.ConnectionError("Connection aborted.")},
            EspdockError,
            "the engine failed to list its containers: Connection aborted.",
            None,
        ),
        (
            lambda e: e.labelled_images("io.espdock"),
            {"api.images": REFUSED},
            EspdockError,
            f"the engine failed to list its images: {SAID}",
            None,
        ),
        (
            lambda e: e.trim_build_cache(1),
            {"api.prune_builds": REFUSED},
            EspdockError,
            f"the engine could not trim its build cache: {SAID}",
            None,
        ),
    ],
    ids=[
        "ensure_volume",
        "remove_volume-in-use",
        "run-create",
        "run-no-image",
        "run-no-bind-source",
        "run-start-runtime",
        "run-start-lost",
        "run-timeout",
        "add_labels",
        "import_rootfs",
        "tag",
        "untag",
        "remove_tag",
        "image",
        "images",
        "containers",
        "sweep",
        "image_users-unanswered",
        "labelled_images",
        "trim_build_cache",
    ],
)
def test_an_engine_that_refuses_a_call_is_an_error_with_its_explanation(call, fails, kind, message, hint):
    with pytest.raises(EspdockError) as err:
        call(refusing(fails))
    assert (type(err.value), err.value.message, err.value.hint) == (kind, message, hint)


def test_old_containers_that_cannot_be_listed_are_a_warning_not_a_failed_build():
    said = r"^could not list old espdock containers: the engine failed to list containers: 500"
    with pytest.warns(UserWarning, match=said):
        assert refusing({"api.containers": REFUSED}).remove_containers({"a": "b"}) == 0


def test_a_container_whose_run_fails_is_removed():
    client = EngineDouble({"containers.prepare_model().start": refusal(500, HYBRID)})
    with pytest.raises(ContainerError):
        Engine({"DOCKER_HOST": TCP}, client=client).run(SPEC, print)
    assert client.called[-1] == "containers.prepare_model().remove"


def test_the_build_cache_size_counts_what_docker_system_df_counts():
    """Entries BuildKit shares with images were counted again: prune said the cache took 10.25 GB
    (above its 10 GB bound, after trimming to it) where `docker system df` said 7.46 GB."""

    class Api:
        def df(self) -> dict:
            return {"BuildCache": [{"Size": 700, "Shared": False}, {"Size": 300, "Shared": True}, {"Size": 5}]}

    class Client:
        api = Api()

    assert Engine({"DOCKER_HOST": TCP}, client=Client()).build_cache_size() == 705


def test_what_is_gone_already_or_missing_is_an_answer_not_an_error():
    missing = refusal(404, "No such image: espdock/img:1")
    assert refusing({"volumes.get": refusal(404, "get v: no such volume")}).remove_volume("v") is None
    assert refusing({"api.remove_image": missing}).untag("espdock/img:1") is None
    assert refusing({"api.remove_image": missing}).remove_tag("espdock/img:1") is True
    assert refusing({"api.remove_image": refusal(409, "image is being used")}).remove_tag("espdock/img:1") is False
    assert refusing({"images.get": missing}).image("espdock/img:1") is None
    assert refusing({"volumes.get": refusal(404, "no such volume")}).ensure_volume("v", {}) is True
    assert refusing({"images.pull": REFUSED}).pull("espdock/img:1") is False
    assert refusing({"api.df": REFUSED}).layers_size() is None
    assert refusing({"api.df": REFUSED}).build_cache_size() is None
    denied = refusal(500, "unauthorized: authentication required")
    answer = refusing({"api.inspect_distribution": denied}).registry_has("espdock/img:1")
    assert answer == RegistryAnswer(RegistryStatus.DENIED, str(denied))


def test_a_podman_engine_that_went_away_says_its_container_may_still_run_and_how_to_start_it(gone):
    """Podman's containers outlive its API service: a build's kept writing install/ after espdock said
    exit 3, and the hint named the Docker service."""
    engine, where = gone
    engine._podman = True  # what /_ping said before the service went away
    with pytest.raises(EngineUnavailable) as err:
        engine.containers({"a": "b"})
    assert err.value.message.startswith(f"the Podman engine at {where} went away while listing containers")
    assert "may still be running" in err.value.message
    assert "podman.socket" in err.value.hint and "stops and removes" in err.value.hint
    assert "docker" not in err.value.hint


def test_a_missing_default_socket_s_hint_names_the_user_s_own_running_engine(tmp_path):
    """No system engine, the user's rootless Docker or Podman running: the hint said only to start
    Docker with sudo."""
    import socket

    from espdock.images.addresses import DEFAULT_SOCKET

    (tmp_path / "podman").mkdir()
    own = socket.socket(socket.AF_UNIX)
    own.bind(str(tmp_path / "podman/podman.sock"))
    try:
        hint = Engine({"DOCKER_HOST": f"unix://{DEFAULT_SOCKET}", "XDG_RUNTIME_DIR": str(tmp_path)}).start_hint()
    finally:
        own.close()
    assert f"or use your own engine: DOCKER_HOST=unix://{tmp_path}/podman/podman.sock" in hint, hint


def test_the_default_socket_s_engine_is_started_as_docker_is():
    from espdock.images.addresses import DEFAULT_SOCKET

    lost = Engine({"DOCKER_HOST": f"unix://{DEFAULT_SOCKET}"})._lost("listing containers")
    assert lost.hint == "Start Docker (`sudo systemctl start docker`), " + RERUN


def test_an_address_no_engine_has_is_bad_input_and_a_name_that_does_not_resolve_is_said_so():
    """DOCKER_HOST=bogus://x was exit 3 with the SDK's words and "start the engine"; a host name
    that does not resolve showed urllib3's text."""
    from espdock.errors import ConfigError

    with pytest.raises(ConfigError) as err:
        Engine.connect({"DOCKER_HOST": "bogus://x"}, timeout=5)
    assert err.value.exit_code == 2 and "bogus:// is no engine address the docker CLI knows" in err.value.message
    with pytest.raises(EngineUnavailable) as err:
        Engine.connect({"DOCKER_HOST": "tcp://no-such-host.invalid:2375"}, timeout=5)
    said = "no Docker engine answers at tcp://no-such-host.invalid:2375: its host name does not resolve"
    assert err.value.message == said


def test_docker_host_is_read_as_the_docker_cli_reads_it(tmp_path):
    """`unix://` was "[Errno 22] Invalid argument" and `tcp://HOST` "port is required", each said
    as an engine to start, where the docker CLI, which espdock runs on the same value, takes the
    default socket and port 2375; a bare socket path was told to start an engine there."""
    from espdock.errors import ConfigError
    from espdock.images.addresses import DEFAULT_SOCKET

    for given, read in (
        ("unix://", f"unix://{DEFAULT_SOCKET}"),
        ("tcp://127.0.0.1", "tcp://127.0.0.1:2375"),
        ("tcp://build-host:", "tcp://build-host:2375"),
        ("tcp://[::1]", "tcp://[::1]:2375"),
        ("127.0.0.1:2376", "tcp://127.0.0.1:2376"),
        ("tcp://build-host:2376", "tcp://build-host:2376"),
        (" unix:///run/user/1000/docker.sock", "unix:///run/user/1000/docker.sock"),
    ):
        assert Engine({"DOCKER_HOST": given}).host == read, given
    for path in ("docker.sock", "run/user/1000/docker.sock"):  # the CLI's tcp://docker.sock:2375, tcp://run
        with pytest.raises(ConfigError, match="a socket's path needs its scheme"):
            Engine({"DOCKER_HOST": path})
    assert Engine({"DOCKER_HOST": "localhost:5555/path"}).host == "tcp://localhost:5555/path"
    # A relative socket path (a slash left out) was told to start "the daemon of var/run/docker.sock",
    # and one without a scheme given unix:// before the same relative path as the fix.
    with socket.socket(socket.AF_UNIX) as listening:
        listening.bind(str(tmp_path / "engine.sock"))
        slash_left_out = str(tmp_path / "engine.sock").removeprefix("/")
        for given, fix in (
            (f"unix://{slash_left_out}", f"unix:///{slash_left_out}"),
            ("unix://./docker.sock", f"unix://{Path.cwd() / 'docker.sock'}"),
        ):
            with pytest.raises(ConfigError, match="a socket's path must be whole") as err:
                Engine({"DOCKER_HOST": given})
            assert err.value.hint == f"Set DOCKER_HOST={fix}", given
        with pytest.raises(ConfigError) as err:
            Engine({"DOCKER_HOST": slash_left_out})
        assert err.value.hint.startswith(f"Set DOCKER_HOST=unix:///{slash_left_out} "), err.value.hint
    # One slash after unix: (read as a relative path), and a trailing one (said as an engine to start).
    for given, fix in (
        ("unix:/var/run/docker.sock", "unix:///var/run/docker.sock"),
        ("unix:var/run/docker.sock", "unix:///var/run/docker.sock"),
        ("unix:///var/run/docker.sock/", "unix:///var/run/docker.sock"),
    ):
        with pytest.raises(ConfigError) as err:
            Engine({"DOCKER_HOST": given})
        assert err.value.hint == f"Set DOCKER_HOST={fix}", given
    # Not a client's address (SDK: "fd protocol is not implemented"), and an ssh:// of no host
    # ("Check that `ssh None` logs in"): refused as what they are.
    for given, said in (("fd://", "a daemon's own listening socket"), ("ssh://", "names no host")):
        with pytest.raises(ConfigError, match=said):
            Engine({"DOCKER_HOST": given})
    with pytest.raises(ConfigError) as err:
        Engine.connect({"DOCKER_HOST": "/var/run/docker.sock"}, timeout=5)
    assert err.value.exit_code == 2
    assert err.value.message == "DOCKER_HOST /var/run/docker.sock: a socket's path needs its scheme, " \
        "unix:///var/run/docker.sock"  # fmt: skip


def test_a_label_build_the_engine_fails_says_the_engine_s_words(monkeypatch):
    """The labels' build is posted as is (no registry logins): the engine's error in its stream."""

    class Answer:
        status_code = 200

        def iter_lines(self):
            return iter([b'{"stream": "Step 2/2 : LABEL a=b"}', b'{"error": "step 2 failed"}'])

    class Api:
        base_url, api_version = "http://engine", "1.44"

        def post(self, *args: object, **kwargs: object) -> Answer:
            return Answer()

    class Client:
        api = Api()

    engine = Engine({"DOCKER_HOST": TCP}, client=Client())
    monkeypatch.setattr(engine, "info", refusing({}).info)
    with pytest.raises(ImageBuildError) as err:
        engine.add_labels("espdock/img:1", {"a": "b"})
    assert err.value.message == f"{NAMED} could not add labels to espdock/img:1: step 2 failed"


def test_espdock_s_own_builds_and_runs_take_none_of_the_users_docker_cli_habits(tmp_path, monkeypatch):
    """DOCKER_DEFAULT_PLATFORM=linux/arm64 (an Apple silicon habit) in the shell: `espdock run` and
    `shell` found no image ("Unable to find image ... locally"); DOCKER_BUILDKIT=0 failed every
    image build (no secrets, no cache mounts); DOCKER_CONTENT_TRUST=1 had each run ask a notary."""
    from espdock.images.specs import ImageBuild

    habits = {"DOCKER_DEFAULT_PLATFORM": "linux/arm64", "DOCKER_BUILDKIT": "0", "DOCKER_CONTENT_TRUST": "1"}
    engine = Engine({"DOCKER_HOST": TCP, "PATH": os.environ["PATH"], **habits}, client=object())
    seen = tmp_path / "env.txt"
    monkeypatch.setattr(engine, "compose_command", lambda: fake_cli(tmp_path, f"cat >/dev/null; env > {seen}"))
    build = ImageBuild(tmp_path, "Dockerfile", "build", "espdock/img:1", {}, {}, None, lambda line: None, False)
    engine._build_buildkit(build)
    given = dict(line.split("=", 1) for line in seen.read_text().splitlines() if "=" in line)
    assert given["DOCKER_HOST"] == TCP and not habits.keys() & given.keys(), given
    # Podman's `docker` (podman-docker) reads CONTAINER_HOST: run and shell went to another engine.
    assert given["CONTAINER_HOST"] == TCP


def test_an_interrupted_podman_build_says_podman_goes_on_and_a_refused_one_its_answer(tmp_path, monkeypatch):
    """Podman 4.3's build API does not stop a build its client left: after Ctrl-C, espdock said
    every build it had started "was stopped and removed" while the step ran on (a `sleep 100`
    for its 100 s). A refused build's answer was read after its stream: RuntimeError, exit 70."""
    from espdock.errors import Interrupted
    from espdock.images.specs import ImageBuild

    class Answer:
        closed = False

        def __init__(self, status: int, lines: list[bytes], text: str = "") -> None:
            self.status_code, self._lines, self.text = status, lines, text

        def iter_lines(self):
            yield from self._lines
            raise KeyboardInterrupt

        def close(self) -> None:
            self.closed = True

    answers: list[Answer] = []

    class Api:
        base_url, api_version = "http://engine", "1.41"

        def post(self, *args: object, **kwargs: object) -> Answer:
            return answers.pop(0)

    class Client:
        api = Api()

    engine = Engine({"DOCKER_HOST": TCP}, client=Client())
    monkeypatch.setattr(engine, "info", refusing({}).info)
    (tmp_path / "Dockerfile").write_text("FROM debian:bookworm-slim\nRUN sleep 100\n")
    build = ImageBuild(tmp_path, "Dockerfile", "build", "espdock/img:1", {}, {}, None, lambda line: None, False)
    running = Answer(200, [b'{"stream": "STEP 2/2: RUN sleep 100"}'])
    answers.append(running)
    with pytest.raises(Interrupted) as err:
        engine._build_classic(build)
    assert "Podman goes on with the image build's current step" in err.value.message and running.closed
    answers.append(Answer(400, [], '{"message": "no such stage build"}'))
    with pytest.raises(ImageBuildError, match=r"HTTP 400: .*no such stage build"):
        engine._build_classic(build)


def test_a_registry_is_asked_without_a_login_where_the_credential_helper_is_missing():
    """`"credsStore": "desktop"` in a config copied from Docker Desktop, no such helper here: the
    Docker CLI goes on without a login, and a registry that needs none answers. espdock said the
    base image "is not here and cannot be pulled" and the cache registry "did not answer"."""
    asked: list[dict] = []

    def registry_call(*args: object, **kwargs: object) -> object:
        asked.append(kwargs)
        if "auth_config" not in kwargs:  # as the SDK's auth lookup fails before any request
            raise docker.errors.DockerException("Credentials store error: StoreError('docker-credential-desktop')")
        return iter([{"status": "Digest: sha256:0"}])

    class Client:
        class images:
            pull = staticmethod(registry_call)

        class api:
            pull = push = inspect_distribution = staticmethod(registry_call)

    engine = Engine({"DOCKER_HOST": TCP}, client=Client())
    assert engine.pull("127.0.0.1:5000/debian:base") is True
    assert engine.pull_cached("127.0.0.1:5000/espdock/x:1").status is RegistryStatus.OK
    assert engine.registry_has("127.0.0.1:5000/espdock/x:1").status is RegistryStatus.OK
    assert [call.get("auth_config") for call in asked] == [None, {}, None, {}, None, {}]


def test_an_ssh_engine_that_does_not_answer_is_told_to_check_the_login_first():
    """ssh refused (a key not loaded, a host key not yet known): the hint said to start the engine,
    under ssh's own words that the login had failed."""
    hint = Engine({"DOCKER_HOST": "ssh://me@build:2222"}).start_hint()
    assert hint.startswith("Check that `ssh -p 2222 me@build` logs in without a question"), hint
    assert Engine({"DOCKER_HOST": "ssh://build"}).start_hint().startswith("Check that `ssh build` logs in")
    # An address the SDK's ssh transport misreads, or no port: bad input, said as such (the first
    # was "too many values to unpack", the second "a bug in espdock", exit 70).
    from espdock.errors import ConfigError

    for host, said in (("ssh://me@[::1]:22", "cannot reach an ssh engine at an IPv6 address"),
                       ("ssh://me@build:abc", "its port is not a number")):  # fmt: skip
        with pytest.raises(ConfigError, match=said):
            Engine.connect({"DOCKER_HOST": host}, timeout=5)


def test_a_foreground_run_ends_on_ctrl_c_when_the_engine_hangs(tmp_path):
    """An engine stopped (kill -STOP of Podman's service, a wedged dockerd): `docker kill` and the
    CLI hung with it, and `espdock run` never ended on Ctrl-C, however many."""
    import signal
    import subprocess
    import sys
    import time

    from espdock import interrupts

    stop_wait = 5.0  # engine.STOP_WAIT
    fake = tmp_path / "bin/docker"  # every docker command hangs, as against a stopped engine
    fake.parent.mkdir()
    # Its own duration, to find its leftovers by: another run's cleanup (`make test` beside a unit run)
    # killed this one's, and the run it stood for ended as if the container had.
    hang = f"sleep 299.{os.getpid()}"
    fake.write_text(f"#!/bin/sh\ntrap '' INT TERM\nexec {hang}\n")
    fake.chmod(0o755)
    script = (
        "import os, sys\n"
        "from espdock.errors import Interrupted\n"
        "from espdock.images.engine import Engine\n"
        "from espdock.images.specs import RunSpec\n"
        "spec = RunSpec(image='debian:bookworm-slim', argv=('sleep', '300'), workdir='/')\n"
        "print('running', flush=True)\n"
        "try:\n"
        "    Engine(dict(os.environ)).run_foreground(spec)\n"
        "except Interrupted as exc:\n"
        "    print(exc.message, flush=True)\n"
        "    sys.exit(130)\n"
    )
    env = {**os.environ, "PATH": f"{fake.parent}:{os.environ['PATH']}", "DOCKER_HOST": "unix:///nonexistent.sock"}
    run = subprocess.Popen([sys.executable, "-c", script], env=env, stdout=subprocess.PIPE, text=True)
    try:
        assert run.stdout.readline().strip() == "running"
        time.sleep(1)
        run.send_signal(signal.SIGINT)
        started = time.monotonic()
        said, _ = run.communicate(timeout=interrupts.GRACE + 4 * stop_wait + 10)
        took = time.monotonic() - started
    finally:
        run.kill()
        subprocess.run(["pkill", "-KILL", "-xf", hang], check=False)  # the fake's, if any is left
    assert run.returncode == 130, said
    assert "the engine did not stop the container within 13 s, so espdock stopped waiting" in said, said
    assert took < interrupts.GRACE + 4 * stop_wait, f"{took:.0f} s"
