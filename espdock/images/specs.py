"""What espdock asks of a container engine, as data, and how each request reads in the engine
API's and the docker CLI's terms: a container's run, an image build, a registry's answer, an
image listing. Nothing here talks to an engine (images/engine.py does), so each translation can be
read and tested on its own.
"""

from __future__ import annotations

import collections
import csv
import hashlib
import io
import json
import tarfile
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from datetime import UTC, datetime
from enum import StrEnum
from pathlib import Path
from typing import IO, Any

from espdock.images import addresses

LineSink = Callable[[str], None]


@dataclass(frozen=True)
class ImageInfo:
    id: str
    tags: tuple[str, ...]
    created: datetime
    size: int
    labels: Mapping[str, str] = field(default_factory=dict)
    # repository@sha256:... for each registry the image was pulled from (none when built here).
    digests: tuple[str, ...] = ()


@dataclass(frozen=True)
class Mount:
    # A host path, or with VOLUME the name of a volume on the engine.
    source: Path | str
    target: str
    read_only: bool = False
    volume: bool = False


@dataclass(frozen=True)
class RunSpec:
    """What a container needs to run one command."""

    image: str
    argv: tuple[str, ...]
    workdir: str
    user: str | None = None
    mounts: tuple[Mount, ...] = ()
    env: tuple[tuple[str, str], ...] = ()
    labels: tuple[tuple[str, str], ...] = ()
    # Device files: HOST, or HOST:CONTAINER (run_foreground only).
    devices: tuple[str, ...] = ()
    group_add: tuple[int, ...] = ()
    network: str | None = None
    tty: bool = False
    name: str | None = None
    # Tar streams put into the container before it starts (container directory, tar bytes): how
    # files reach an engine that does not see this machine's (espdock.volume).
    archives: tuple[tuple[str, bytes], ...] = ()


@dataclass(frozen=True)
class ImageBuild:
    """One image build as Engine.build_image was asked for it, for whichever builder runs it."""

    context: Path
    dockerfile: str
    target: str
    tag: str
    build_args: Mapping[str, str]
    labels: Mapping[str, str]
    ca_bundle: Path | None
    on_line: LineSink
    no_cache: bool


@dataclass(frozen=True)
class EngineInfo:
    """What kind of engine answers, as far as espdock's containers care."""

    # "docker" or "podman" (Podman's Docker API names its libpod version in /_ping's headers).
    kind: str
    # Containers run in a user namespace: uid 0 inside is the user who started the engine.
    rootless: bool
    # Stable for one engine and its data root: what a cached answer about the engine is keyed by.
    identity: str
    where: str
    # The engine maps its containers' users to subordinate ids (dockerd --userns-remap): a
    # container running as the user is another uid outside, refused the user's workspace.
    remapped: bool = False

    @property
    def name(self) -> str:
        """The engine as messages name it."""
        kind = "Podman" if self.kind == "podman" else "Docker"
        return f"{'rootless ' if self.rootless else ''}{kind} engine at {self.where}"


def describe(env: Mapping[str, str], info: Mapping[str, Any], libpod: Mapping[str, Any] | None = None) -> EngineInfo:
    """EngineInfo from a Docker engine's /info answer, or with LIBPOD, Podman's /libpod/info."""
    where = addresses.host_of(env)
    if libpod is None:
        options = [str(option).split(",")[0] for option in info.get("SecurityOptions") or ()]
        rootless, remapped = "name=rootless" in options, "name=userns" in options
        stable = [str(info.get(k, "")) for k in ("Name", "DockerRootDir", "ID")]
    else:
        host, store = libpod.get("host") or {}, libpod.get("store") or {}
        rootless = (host.get("security") or {}).get("rootless") is True
        # Podman has no lasting ID (its Docker API /info makes one up per call): its host name and
        # storage say which it is, which that /info gives as Name and DockerRootDir.
        stable = [str(host.get("hostname", "")), str(store.get("graphRoot", ""))]
        remapped = False
    identity = hashlib.sha256("\0".join([where, *stable]).encode()).hexdigest()[:16]
    kind = "docker" if libpod is None else "podman"
    return EngineInfo(kind, rootless=rootless, identity=identity, where=where, remapped=remapped)


class RegistryStatus(StrEnum):
    OK = "ok"
    MISSING = "missing"  # the registry answered: no such image
    DENIED = "denied"  # the registry refused the engine's credentials
    UNREACHABLE = "unreachable"  # nothing answered, or not as a registry


@dataclass(frozen=True)
class RegistryAnswer:
    status: RegistryStatus
    detail: str = ""


# What the engine says, by cause (distribution registry and Docker daemon wording).
_DENIED = ("no basic auth credentials", "unauthorized", "authentication required", "denied", "forbidden")

_MISSING = ("manifest unknown", "not found", "name unknown", "no such manifest")


def registry_answer(text: str) -> RegistryAnswer:
    lowered = text.lower()
    if any(word in lowered for word in _DENIED):
        return RegistryAnswer(RegistryStatus.DENIED, text)
    if any(word in lowered for word in _MISSING):
        return RegistryAnswer(RegistryStatus.MISSING, text)
    return RegistryAnswer(RegistryStatus.UNREACHABLE, text)


def registry_stream(events: Iterator[dict]) -> RegistryAnswer:
    """Pulls and pushes report most failures inside the progress stream, not as HTTP errors."""
    for event in events:
        error = event.get("error") or (event.get("errorDetail") or {}).get("message")
        if error:
            return registry_answer(str(error))
    return RegistryAnswer(RegistryStatus.OK)


def image_info(attrs: Mapping[str, Any]) -> ImageInfo:
    """ImageInfo from the engine's image inspect answer."""
    return ImageInfo(
        id=attrs["Id"],
        tags=tuple(tag for tag in attrs.get("RepoTags") or () if tag != "<none>:<none>"),
        created=datetime.fromisoformat(attrs["Created"][:19]).replace(tzinfo=UTC),
        size=int(attrs.get("Size", 0)),
        labels=dict((attrs.get("Config") or {}).get("Labels") or {}),
        digests=tuple(attrs.get("RepoDigests") or ()),
    )


def labelled(report: Sequence[Mapping[str, Any]], label: str) -> list[tuple[str, tuple[str, ...], int, int]]:
    """(id, tags, bytes no other image shares, size) of each image in the engine's REPORT carrying LABEL."""
    found = []
    for image in report:
        if label not in (image.get("Labels") or {}):
            continue
        size, common = int(image.get("Size", 0)), int(image.get("SharedSize", -1) or 0)
        tags = tuple(_short_name(t) for t in image.get("RepoTags") or () if t != "<none>:<none>")
        found.append((image["Id"], tags, size - max(common, 0), size))
    return found


def _short_name(tag: str) -> str:
    """TAG as espdock names it: Podman lists espdock/x:k as localhost/espdock/x:k, and a pulled
    image with its registry (docker.io/...), where Docker lists the name as it was given."""
    for prefix in ("localhost/", "docker.io/library/", "docker.io/"):
        if tag.startswith(prefix):
            return tag.removeprefix(prefix)
    return tag


def label_args(labels: Mapping[str, str]) -> list[str]:
    """LABELS as a Dockerfile's LABEL instruction takes them (KEY="VALUE")."""
    return [f"{key}={json.dumps(value)}" for key, value in labels.items()]


def label_selector(labels: Mapping[str, str]) -> list[str]:
    """LABELS as the engine's label filter takes them (KEY=VALUE, all of them must match)."""
    return [f"{key}={value}" for key, value in labels.items()]


# tini (the ROS images' init) forwards the signals it gets to its child's process group, not the child alone.
STOPPED_AS_AT_A_TERMINAL = {"TINI_KILL_PROCESS_GROUP": "1"}


def create_config(
    spec: RunSpec, labels: Mapping[str, str], host_users: bool = False, proxies: Mapping[str, str] | None = None
) -> dict[str, Any]:
    """The engine API's configuration of a container for SPEC with LABELS (POST /containers/create),
    detached: nothing attaches at creation, Engine.run_attached's `docker start --attach` later.
    PROXIES: the proxy variables `docker run` would add where SPEC sets none of that name."""
    host: dict[str, Any] = {
        # Mounts, not Binds: a Binds entry is split at its colons, so a workspace under
        # /home/me/ws:old could not be mounted ("invalid volume specification").
        "Mounts": [
            {
                "Type": "volume" if m.volume else "bind",
                "Source": str(m.source),
                "Target": m.target,
                "ReadOnly": m.read_only,
            }
            for m in spec.mounts
        ],
        "Devices": [{"PathOnHost": d, "PathInContainer": d, "CgroupPermissions": "rwm"} for d in spec.devices],
        "NetworkMode": spec.network or "default",
    }
    if spec.group_add:
        host["GroupAdd"] = [str(g) for g in spec.group_add]
    if host_users:
        host["UsernsMode"] = "host"
    config: dict[str, Any] = {
        "Image": spec.image,
        "Cmd": list(spec.argv),
        "WorkingDir": spec.workdir,
        "Env": [
            f"{key}={value}" for key, value in {**STOPPED_AS_AT_A_TERMINAL, **(proxies or {}), **dict(spec.env)}.items()
        ],
        "Labels": dict(labels),
        "Tty": spec.tty,
        "OpenStdin": spec.tty,
        "HostConfig": host,
        # A container espdock stops (Ctrl-C, SIGTERM, a failure elsewhere) is stopped as a
        # terminal's Ctrl-C stops a command: SIGINT to its whole process group (the images' tini
        # forwards it so, with STOPPED_AS_AT_A_TERMINAL). Docker's SIGTERM reached colcon alone,
        # whose death took make down mid-write before make could delete the file it was writing:
        # the next build found that file newer than its inputs and installed it half written.
        "StopSignal": "SIGINT",
    }
    if spec.user:
        config["User"] = spec.user
    return config


def run_argv(docker_cli: str, name: str, spec: RunSpec, host_users: bool = False, stdin: bool = True) -> list[str]:
    """`docker run` of SPEC as container NAME, signals left to espdock to pass on; STDIN: forward it.
    Without --rm, which made the docker CLI exit 0 whatever the container's code against Podman's
    compat API (4.3): run_foreground removes the container when it ends, and the sweep one a killed
    espdock left."""
    argv = [docker_cli, "run", "--name", name, "--sig-proxy=false", *(["--interactive"] if stdin else [])]
    argv += ["--tty"] if spec.tty else []
    argv += ["--workdir", spec.workdir] + (["--user", spec.user] if spec.user else [])
    argv += [arg for key, value in spec.env for arg in ("--env", f"{key}={value}")]
    argv += [arg for key, value in spec.labels for arg in ("--label", f"{key}={value}")]
    for mount in spec.mounts:
        kind = "volume" if mount.volume else "bind"
        fields = [f"type={kind}", f"source={mount.source}", f"target={mount.target}"]
        argv += ["--mount", _csv_line([*fields, "readonly"] if mount.read_only else fields)]
    argv += [arg for device in spec.devices for arg in ("--device", device)]
    argv += [arg for group in spec.group_add for arg in ("--group-add", str(group))]
    argv += ["--network", spec.network] if spec.network else []
    argv += ["--userns", "host"] if host_users else []
    return [*argv, spec.image, *spec.argv]


def _csv_line(fields: list[str]) -> str:
    """FIELDS as one CSV line, as `docker run --mount` parses it (a path with a comma is quoted)."""
    out = io.StringIO()
    csv.writer(out, lineterminator="").writerow(fields)
    return out.getvalue()


def format_argv(argv: Sequence[str]) -> str:
    """ARGV as one shell-quoted line, for display only."""
    import shlex

    return shlex.join(argv)


def classic_params(build: ImageBuild, secret: str) -> dict[str, Any]:
    """The engine API's /build parameters for BUILD, its CA bundle in the context file SECRET."""
    return {
        "t": build.tag,
        "dockerfile": build.dockerfile,
        "target": build.target,
        "buildargs": json.dumps(dict(build.build_args)),
        "labels": json.dumps(dict(build.labels)),
        "secrets": json.dumps([f"id=ca_bundle,src={secret}"]),
        "nocache": build.no_cache,
        "rm": True,
        "forcerm": True,
    }


def classic_events(chunks: Iterator[bytes], tail: collections.deque[str], on_line: LineSink) -> str | None:
    """The /build answer's JSON lines: each output line to ON_LINE and TAIL; the first error, if any."""
    error = None
    for chunk in chunks:
        try:
            event = json.loads(chunk) if chunk else {}
        except ValueError:
            continue
        for line in str(event.get("stream", "")).splitlines():
            tail.append(line)
            on_line(line)
        error = error or event.get("error") or (event.get("errorDetail") or {}).get("message")
    return error


def compose_build(build: ImageBuild) -> dict[str, Any]:
    """A Compose file (as JSON, on stdin) whose one service builds BUILD."""
    return {
        "name": "espdock-build",
        "services": {
            "image": {
                "image": build.tag,
                "build": {
                    "context": str(build.context),
                    "dockerfile": build.dockerfile,
                    "target": build.target,
                    "args": dict(build.build_args),
                    "labels": dict(build.labels),
                    "secrets": ["ca_bundle"],
                },
            }
        },
        # An empty secret means "no extra CA"; the Dockerfile checks for that.
        "secrets": {"ca_bundle": {"file": str(build.ca_bundle or "/dev/null")}},
    }


def split_ref(ref: str) -> tuple[str, str]:
    """REPOSITORY, TAG of REF (a registry's host:port is not a tag)."""
    name = ref.rsplit("/", 1)[-1]
    if ":" in name:
        repository, _, tag = ref.rpartition(":")
        return repository, tag
    return ref, "latest"


def runtime_hint(error: str) -> str | None:
    """What to do when the engine's OCI runtime, not the build or the command, refused the container."""
    if "cgroups in hybrid mode" in error:
        # crun (Podman's default) refuses hosts that mount cgroup v1 controllers beside a cgroup2
        # tree holding one; runc runs there, as it does under Docker.
        return (
            'crun cannot run containers on this host\'s hybrid cgroups: set runtime = "runc" in the [engine] '
            "table of containers.conf (install runc if it is missing), restart the Podman service, then try again."
        )
    return None


def unpadded(archive: bytes) -> bytes:
    """ARCHIVE up to its two end blocks, without the zeros Python's tarfile pads it with to a 10 KiB
    record. Podman's upload (buildah's copier, before buildah#6678) stops reading at the end blocks,
    and the padding the engine is still passing on then fails the upload with "passing bulk input
    to subprocess: write |1: broken pipe": now and then, and more often the slower the link."""
    with tarfile.open(fileobj=io.BytesIO(archive), mode="r:") as tar:
        tar.getmembers()
        end = tar.offset + 2 * tarfile.BLOCKSIZE
    return archive[:end]


def context_tar(context: Path, dockerfile: str, out: IO[bytes], extra: Mapping[str, bytes]) -> None:
    """CONTEXT as the builder gets it (its .dockerignore applied, as the Docker CLI does), and the
    EXTRA files (name -> bytes) at its top, into OUT."""
    from docker.utils.build import exclude_paths

    ignore = context / ".dockerignore"
    patterns = [
        line.strip()
        for line in (ignore.read_text().splitlines() if ignore.is_file() else ())
        if line.strip() and not line.startswith("#")
    ]
    with tarfile.open(fileobj=out, mode="w") as archive:
        for rel in sorted(exclude_paths(str(context), patterns, dockerfile=dockerfile)):
            archive.add(context / rel, arcname=rel, recursive=False)
        for name, data in extra.items():
            member = tarfile.TarInfo(name)
            member.size = len(data)
            member.mode = 0o600
            archive.addfile(member, io.BytesIO(data))
