"""Engine.run against the real engine, both ways espdock talks to it: plain HTTP on the local
socket, and the Docker SDK for any other DOCKER_HOST (here the same engine through a TCP
forwarder). What a step sees must not depend on which: its output line by line, its exit code,
files put in before it starts and fetched after it ends, a clear error for a missing image, and
no container left."""

from __future__ import annotations

import io
import os
import tarfile
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from espdock.errors import ContainerError
from espdock.images.engine import DEFAULT_SOCKET, Engine, RunSpec
from espdock.images.keyed import DPKG_STATUS, installed_packages
from tests.integration.test_engines import TcpForwarder

pytestmark = [pytest.mark.engine]

IMAGE = "debian:bookworm-slim"


@pytest.fixture(scope="module", params=["local socket", "tcp"])
def way(request, engine) -> Iterator[Engine]:
    """The engine over its local socket (plain HTTP) or over TCP (the Docker SDK)."""
    socket_path = (os.environ.get("DOCKER_HOST") or f"unix://{DEFAULT_SOCKET}").removeprefix("unix://")
    if request.param == "local socket":
        yield Engine.connect({**os.environ, "DOCKER_HOST": f"unix://{socket_path}"})
        return
    forwarder = TcpForwarder(Path(socket_path))
    try:
        yield Engine.connect({**os.environ, "DOCKER_HOST": f"tcp://127.0.0.1:{forwarder.port}"})
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
