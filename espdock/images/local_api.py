"""The engine's API on its local socket over plain HTTP: the calls every command makes (the ping,
image lookups, and the containers of steps: create, files in and out, start, logs, wait,
remove) without the Docker SDK, which with requests and urllib3 was a third of `espdock test`'s
time around colcon. Failures come out as the SDK's exception types (imported then), so
engine.py's one set of handlers serves both ways.

http.client is imported on the first call, not with espdock: with the email parser it brings it
took about 13 ms of every start, and a command that never talks to the engine (`list`, `verify`, a
refusal of bad input, shell completion) need not pay it."""

from __future__ import annotations

import functools
import itertools
import json
import re
import socket
from collections.abc import Iterator, Mapping
from contextlib import AbstractContextManager, contextmanager
from typing import IO, TYPE_CHECKING, Any
from urllib.parse import quote

from espdock.images.sdk import docker, requests

if TYPE_CHECKING:
    import http.client


@functools.cache
def _unix_http() -> type[http.client.HTTPConnection]:
    import http.client

    class UnixHTTP(http.client.HTTPConnection):
        def __init__(self, path: str, timeout: float) -> None:
            super().__init__("localhost", timeout=timeout)
            self._path = path

        def connect(self) -> None:
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            sock.settimeout(self.timeout)
            sock.connect(self._path)
            self.sock = sock

    return UnixHTTP


class LocalContainer:
    """A container on the engine's local socket, driven over plain HTTP: what Engine.run needs of
    the Docker SDK's Container (files in and out, start, logs, wait, stop, remove) without
    importing the SDK and requests, a third of what `espdock test` spent around colcon. Failures
    come out as the SDK's exception types (imported then), so one set of handlers serves both."""

    def __init__(self, socket_path: str, timeout: float, container_id: str, tty: bool) -> None:
        self._socket = socket_path
        self._timeout = timeout
        self.id = container_id
        self.short_id = container_id[:12]
        self._tty = tty

    @classmethod
    def create(cls, socket_path: str, timeout: float, name: str | None, config: Mapping[str, Any]) -> LocalContainer:
        """A container of CONFIG (as specs.create_config makes it), named NAME unless None."""
        query = f"?name={quote(name, safe='')}" if name else ""
        answer = call(socket_path, timeout, "POST", f"/containers/create{query}", json.dumps(config).encode())
        return cls(socket_path, timeout, json.loads(answer)["Id"], bool(config["Tty"]))

    def _call(self, method: str, path: str, body: bytes | None = None, timeout: float = 0) -> bytes:
        return call(self._socket, self._timeout + timeout, method, f"/containers/{self.id}{path}", body)

    def _stream(
        self, method: str, path: str, answer_waits: bool = False
    ) -> AbstractContextManager[http.client.HTTPResponse]:
        return open_stream(self._socket, self._timeout, method, f"/containers/{self.id}{path}", answer_waits)

    def put_archive(self, path: str, data: bytes) -> bool:
        self._call("PUT", f"/archive?path={quote(path, safe='')}", data)
        return True

    def start(self) -> None:
        self._call("POST", "/start")

    def logs(self, stream: bool = True, follow: bool = True) -> Iterator[bytes]:
        """The output as it comes, stdout and stderr in order (demultiplexed unless on a TTY)."""
        # Podman 4.3 (Debian bookworm's) answers a followed log only with the container's first
        # output or its end: a colcon build silent for two minutes (a loaded machine's first
        # configure) ended as "the Podman engine went away" while it ran on.
        with self._stream("GET", "/logs?follow=1&stdout=1&stderr=1", answer_waits=True) as response:
            try:
                if self._tty:
                    while chunk := response.read1(65536):
                        yield chunk
                    return
                # Each frame: stream number, 3 bytes of padding, payload size (big-endian), payload.
                while len(header := response.read(8)) == 8:
                    yield response.read(int.from_bytes(header[4:], "big"))
            except (_http_error(), OSError):
                return  # the engine went away: the wait that follows says so

    def wait(self) -> dict:
        with self._stream("POST", "/wait") as response:
            try:
                return json.loads(response.read())
            except (_http_error(), OSError) as exc:
                raise requests.exceptions.ConnectionError(f"waiting for container {self.short_id}: {exc}") from exc

    def get_archive(self, path: str) -> tuple[Iterator[bytes], None]:
        def chunks() -> Iterator[bytes]:
            with self._stream("GET", f"/archive?path={quote(path, safe='')}") as response:
                while chunk := response.read1(65536):
                    yield chunk

        # The SDK raises NotFound for a path the container lacks when asked, not when read.
        chunk_iterator = chunks()
        first = next(chunk_iterator, b"")
        return itertools.chain((first,), chunk_iterator), None

    def stop(self, timeout: int) -> None:
        self._call("POST", f"/stop?t={timeout}", timeout=timeout)

    def remove(self, force: bool = False) -> None:
        self._call("DELETE", f"?force={int(force)}")


@contextmanager
def open_stream(
    socket_path: str, timeout: float, method: str, path: str, answer_waits: bool = False
) -> Iterator[http.client.HTTPResponse]:
    """METHOD PATH on the engine's local socket, for an answer that may take as long as the
    container runs: no timeout once the engine has answered, as the SDK has it for logs and wait,
    nor, ANSWER_WAITS, for the answer's start. Raises as call does."""
    with _streamed(socket_path, timeout, method, path, answer_waits=answer_waits) as response:
        if response.status >= 400:
            _raise_api_error(response.status, response.read(), path)
        yield response


@contextmanager
def post_stream(
    socket_path: str, timeout: float, path: str, body: bytes | IO[bytes], content_type: str
) -> Iterator[http.client.HTTPResponse]:
    """POST BODY to PATH on the engine's local socket, for an answer streamed as long as the work
    takes (an image build): whatever its status, which the caller reads (an error's body is its
    reason). A failed connection raises as call does."""
    with _streamed(socket_path, timeout, "POST", path, body, {"Content-Type": content_type}) as response:
        yield response


@contextmanager
def _streamed(
    socket_path: str,
    timeout: float,
    method: str,
    path: str,
    body: bytes | IO[bytes] | None = None,
    headers: Mapping[str, str] | None = None,
    answer_waits: bool = False,
) -> Iterator[http.client.HTTPResponse]:
    connection = _unix_http()(socket_path, timeout)
    try:
        try:
            # A file BODY goes in chunks (HTTP/1.1 chunked encoding), as the Docker CLI sends a context.
            connection.request(method, path, body=body, headers=dict(headers or {}))
            if answer_waits:
                connection.sock.settimeout(None)
            response = connection.getresponse()
        except (OSError, _http_error()) as exc:
            raise requests.exceptions.ConnectionError(f"{method} {path}: {exc}") from exc
        connection.sock.settimeout(None)
        yield response
    finally:
        connection.close()


def exchange(
    socket_path: str, timeout: float, method: str, path: str, body: bytes | None = None
) -> tuple[int, bytes, http.client.HTTPMessage]:
    """METHOD PATH on the engine's local socket: (HTTP status, the answer's body, its headers).
    Failures raise as the socket raises them; an answer that is no HTTP as a ConnectionError."""
    connection = _unix_http()(socket_path, timeout)
    headers = {"Content-Type": "application/x-tar" if method == "PUT" else "application/json"} if body else {}
    try:
        connection.request(method, path, body=body, headers=headers)
        response = connection.getresponse()
        return response.status, response.read(), response.headers
    except _http_error() as exc:
        # Another daemon's socket (an ssh-agent's, an sshd's): no engine, as a refused connection is
        # none. As http.client's own error it ended espdock as a bug of its own (exit 70).
        said = f"{type(exc).__name__}: {str(exc).strip()}"
        raise ConnectionError(f"what answers there speaks no HTTP ({said})") from exc
    finally:
        connection.close()


def _http_error() -> type[Exception]:
    import http.client

    return http.client.HTTPException


def call(socket_path: str, timeout: float, method: str, path: str, body: bytes | None = None) -> bytes:
    """METHOD PATH on the engine's local socket; the answer's body. A failed connection is
    requests' ConnectionError, a slow answer its ReadTimeout, an error status docker.errors'
    NotFound, ImageNotFound or APIError: as the SDK raises them."""
    try:
        status, answer, _ = exchange(socket_path, timeout, method, path, body)
    except TimeoutError as exc:
        raise requests.exceptions.ReadTimeout(f"{method} {path}: no answer within {timeout:g} s") from exc
    except OSError as exc:  # an answer that is no HTTP too (exchange)
        raise requests.exceptions.ConnectionError(f"{method} {path}: {exc}") from exc
    if status >= 400:
        _raise_api_error(status, answer, path)
    return answer


def _raise_api_error(status: int, body: bytes, path: str) -> None:
    try:
        explanation = str(json.loads(body).get("message", ""))
    except (ValueError, AttributeError):
        explanation = body.decode("utf-8", "replace").strip()
    message = f"{status} error from the engine for {path}"
    if status == 404:
        # Told apart as the SDK does (docker.errors.create_api_error_from_http_exception).
        missing = r"no such image|not found: does not exist or no pull access|repository does not exist"
        if path.startswith("/containers/create") and re.search(missing, explanation, re.IGNORECASE):
            raise docker.errors.ImageNotFound(message, explanation=explanation)
        raise docker.errors.NotFound(message, explanation=explanation)
    raise docker.errors.APIError(message, explanation=explanation)
