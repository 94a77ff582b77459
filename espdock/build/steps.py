"""A plan's vocabulary, pure and shared by both worlds: keyed image specs, the image steps, the plan."""

from __future__ import annotations

import hashlib
import json
import posixpath
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Protocol

from espdock.layout import (
    WORKSPACE_MOUNT,
)
from espdock.workspace import Workspace

LABEL_KEY = "io.espdock.key"


LABEL_INPUTS = "io.espdock.inputs"


LABEL_WORKSPACE = "io.espdock.workspace"


def cache_ref(registry: str, tag: str) -> str:
    """Where a keyed image TAG lives in the cache REGISTRY: the same name and key, under it."""
    return f"{registry.rstrip('/')}/{tag}"


def keyed_tag(repository: str, key: str) -> str:
    """The tag of REPOSITORY's image of KEY."""
    return f"{repository}:{key[:16]}"


@dataclass(frozen=True)
class ImageSpec:
    """An image espdock builds, tagged by a hash of everything that decides its content."""

    repository: str
    key: str
    dockerfile: str
    target: str
    build_args: tuple[tuple[str, str], ...]
    # The inputs that made the key, name -> sha256, shown by status commands.
    inputs: tuple[tuple[str, str], ...] = ()
    # The build context, by relative path; None: the workspace root (filtered by .dockerignore).
    context: tuple[tuple[str, bytes], ...] | None = None
    # Where the Dockerfile came from, and why (the workspace's own wins over espdock's default).
    origin: str = ""
    # Paths in the image build (a context directory's, as the Dockerfile copies it) and the host
    # paths the user knows them by: its errors name those.
    sources: tuple[tuple[str, str], ...] = ()

    def host_paths(self, text: str) -> str:
        """TEXT with the image build's paths of SOURCES as the host's."""
        for built, host in self.sources:
            text = text.replace(f"{built}/", f"{host}/")
        return text

    @property
    def tag(self) -> str:
        return keyed_tag(self.repository, self.key)

    def labels(self) -> dict[str, str]:
        return {LABEL_KEY: self.key, LABEL_INPUTS: json.dumps(dict(self.inputs), sort_keys=True)}


@dataclass(frozen=True)
class EnsureBaseImage:
    """Make the base image a Dockerfile starts FROM available locally."""

    image: str
    # Whether espdock builds it with debootstrap where it cannot be pulled (a Debian image the
    # wheels flavour starts from; never the official ROS image): a dry run said so of every one.
    debootstrap: bool = True

    @property
    def name(self) -> str:
        return f"base image {self.image}"


@dataclass(frozen=True)
class EnsureImage:
    """Build SPEC unless an image with its key already exists (or always, when FORCE)."""

    spec: ImageSpec
    force: bool = False
    # Whether a cache registry serves it: not a workspace's runtime image, one small layer over
    # the runtime base, which is served.
    cached: bool = True

    @property
    def name(self) -> str:
        return f"image {self.spec.repository}"


def built_from(steps: Iterable[object], base: str) -> list[EnsureImage]:
    """The keyed images of STEPS a Dockerfile builds FROM the base image BASE (its BASE_IMAGE)."""
    return [s for s in steps if isinstance(s, EnsureImage) and dict(s.spec.build_args).get("BASE_IMAGE") == base]


def container_path(rel: str) -> str:
    """Where REL (relative to the workspace root) is in a build container."""
    return posixpath.normpath(f"{WORKSPACE_MOUNT}/{rel}")


@dataclass(frozen=True)
class Plan:
    workspace: Workspace
    steps: tuple[PlanStep, ...] = field(default_factory=tuple)
    # The distinct micro-ROS images the firmware steps use.
    idf_images: tuple[ImageSpec, ...] = ()


def dockerfile_args(text: str) -> dict[str, str]:
    """The build args a Dockerfile declares with a default (ARG NAME=value)."""
    args = {}
    for match in re.finditer(r"^\s*ARG\s+([A-Za-z_][A-Za-z0-9_]*)=(\S+)\s*$", text, re.MULTILINE):
        args.setdefault(match.group(1), match.group(2).strip("\"'"))
    return args


def image_key(parts: Mapping[str, bytes]) -> tuple[str, tuple[tuple[str, str], ...]]:
    """A content key over named inputs: the same inputs give the same key, any change a new one."""
    inputs = tuple((name, hashlib.sha256(parts[name]).hexdigest()) for name in sorted(parts))
    digest = hashlib.sha256()
    for name, sha in inputs:
        digest.update(f"{name}\0{sha}\n".encode())
    return digest.hexdigest(), inputs


def image_origin(dockerfile: str, files: Mapping[str, bytes], own_files: frozenset[str]) -> str:
    """Which of an image's input files are the workspace's own, which espdock's defaults."""
    own = sorted(n for n in files if n in own_files)
    if dockerfile in own_files:
        head = f"{dockerfile}: the workspace's own (a workspace file wins over espdock's default)"
    else:
        head = f"{dockerfile}: espdock's default (the workspace has none of its own)"
    others = [n for n in own if n != dockerfile]
    return head + (f"; the workspace's own {', '.join(others)}" if others else "")


def keyed_image(
    repository: str,
    dockerfile: str,
    target: str,
    build_args: tuple[tuple[str, str], ...],
    files: Mapping[str, bytes],
    context: Mapping[str, bytes] | None = None,
    extra: Mapping[str, bytes] | None = None,
) -> ImageSpec:
    """An ImageSpec keyed by FILES, the build args and EXTRA (what else decides the image)."""
    parts = {**files, **{f"arg:{k}": v.encode() for k, v in build_args}, **(extra or {})}
    key, inputs = image_key(parts)
    return ImageSpec(
        repository=repository,
        key=key,
        dockerfile=dockerfile,
        target=target,
        build_args=build_args,
        inputs=inputs,
        context=None if context is None else tuple(sorted(context.items())),
    )


class PlanStep(Protocol):
    """What the runner is handed: any step of a world (ros.plan, firmware.plan) or of the core,
    which it dispatches on by type (build.plan.Step lists them)."""

    @property
    def name(self) -> str: ...
