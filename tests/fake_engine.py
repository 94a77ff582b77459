"""FakeEngine: stands in for espdock.images.engine.Engine (the Docker engine) in unit tests of the runner.

It records what it was asked to do and plays back scripted container runs, so the runner's
cache decisions, failure parsing and reporting can be tested in milliseconds. Its cache
registry is a dict (or one forced answer). The real engine and a real registry are
exercised by tests/integration and tests/demo.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path

from espdock.images.specs import EngineInfo, ImageInfo, LineSink, RegistryAnswer, RegistryStatus, RunSpec


@dataclass
class FakeEngine:
    """Images by tag; RUN_SCRIPT(spec, on_line) -> exit code plays a container."""

    images_by_tag: dict[str, ImageInfo] = field(default_factory=dict)
    run_script: Callable[[RunSpec, LineSink], int] = lambda spec, on_line: 0
    builds: list[dict] = field(default_factory=list)
    runs: list[RunSpec] = field(default_factory=list)
    removed: list[Mapping[str, str]] = field(default_factory=list)
    swept: list[Mapping[str, str]] = field(default_factory=list)
    registry: dict[str, ImageInfo] = field(default_factory=dict)
    registry_answer: RegistryStatus | None = None  # every registry call answers this, when set
    pushed: list[str] = field(default_factory=list)
    # Whether its containers see the host's files (a local engine) or not (one on another machine).
    sees_host: bool = True
    rootless: bool = False
    kind: str = "docker"
    mount_checks: int = 0
    # Files read_file finds, by path in any image (an empty dpkg database unless set); what it read.
    files: dict[str, bytes | None] = field(default_factory=dict)
    reads: list[tuple[str, str]] = field(default_factory=list)
    host: str = "unix:///var/run/docker.sock"
    # Where it keeps images and containers (DockerRootDir), for disk-full messages.
    root: str = "unknown"

    def data_root(self) -> str:
        return self.root

    def info(self) -> EngineInfo:
        return EngineInfo(kind=self.kind, rootless=self.rootless, identity="fake", where="fake://engine")

    def _forced(self) -> RegistryAnswer | None:
        return RegistryAnswer(self.registry_answer, "forced") if self.registry_answer else None

    def pull(self, ref: str) -> bool:
        if ref in self.registry:
            self.images_by_tag[ref] = self.registry[ref]
        return ref in self.registry

    def pull_cached(self, ref: str) -> RegistryAnswer:
        if forced := self._forced():
            return forced
        if ref not in self.registry:
            return RegistryAnswer(RegistryStatus.MISSING, "manifest unknown")
        self.images_by_tag[ref] = self.registry[ref]
        return RegistryAnswer(RegistryStatus.OK)

    def push_cached(self, ref: str) -> RegistryAnswer:
        if forced := self._forced():
            return forced
        self.registry[ref] = self.images_by_tag[ref]
        self.pushed.append(ref)
        return RegistryAnswer(RegistryStatus.OK)

    def registry_has(self, ref: str) -> RegistryAnswer:
        if forced := self._forced():
            return forced
        return RegistryAnswer(RegistryStatus.OK if ref in self.registry else RegistryStatus.MISSING)

    def add_labels(self, ref: str, labels: Mapping[str, str]) -> None:
        image = self.images_by_tag[ref]
        self.images_by_tag[ref] = ImageInfo(image.id, image.tags, image.created, image.size, {**image.labels, **labels})

    def tag(self, source: str, ref: str) -> None:
        self.images_by_tag[ref] = self.images_by_tag[source]

    def untag(self, ref: str) -> None:
        self.images_by_tag.pop(ref, None)

    def image(self, ref: str) -> ImageInfo | None:
        return self.images_by_tag.get(ref)

    def images(self, repository: str) -> list[ImageInfo]:
        return [i for tag, i in self.images_by_tag.items() if tag.split(":")[0] == repository]

    def build_image(self, *, context: Path, dockerfile: str, target: str, tag: str, build_args: Mapping[str, str],
                    labels: Mapping[str, str], ca_bundle: Path | None, on_line: LineSink,
                    no_cache: bool = False) -> None:  # fmt: skip
        self.builds.append({"tag": tag, "target": target, "build_args": dict(build_args), "labels": dict(labels),
                            "no_cache": no_cache})  # fmt: skip
        on_line("#5 [build 2/3] RUN colcon build")
        self.images_by_tag[tag] = ImageInfo(tag, (tag,), datetime.now(UTC), 1, dict(labels))

    def run(self, spec: RunSpec, on_line: LineSink, keep: bool = False) -> int:
        if ("io.espdock.step", "mount-check") in spec.labels:
            # The probe's `test "$(cat FILE)" = NONCE`, against the host's files when it sees them.
            self.mount_checks += 1
            mount = spec.mounts[0]
            path = mount.source / spec.argv[3].removeprefix(mount.target + "/")
            return 0 if self.sees_host and path.is_file() and path.read_text() == spec.argv[4] else 1
        self.runs.append(spec)
        return self.run_script(spec, on_line)

    def read_file(self, image: str, path: str, labels: Mapping[str, str]) -> bytes | None:
        dict(labels.items())  # as the engine's, which labels the container it reads from
        self.reads.append((image, path))
        return self.files.get(path, b"")

    def remove_containers(self, labels: Mapping[str, str]) -> int:
        self.removed.append(dict(labels))
        return 0

    def sweep(self, labels: Mapping[str, str]) -> int:
        self.swept.append(dict(labels))
        return 0
