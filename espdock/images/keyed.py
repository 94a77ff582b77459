"""Keyed images: reused when the engine holds the key, else pulled from the cache registry,
else built (and pushed there with --push-cache); each one's Debian package set recorded."""

from __future__ import annotations

import hashlib
import json
import re
import shutil
from collections.abc import Iterator, Mapping
from contextlib import AbstractContextManager, contextmanager
from datetime import UTC, datetime
from pathlib import Path

from espdock import scratch
from espdock.build.steps import (
    LABEL_INPUTS,
    LABEL_KEY,
    LABEL_WORKSPACE,
    EnsureBaseImage,
    EnsureImage,
    ImageSpec,
    built_from,
    cache_ref,
)
from espdock.config import resolve_ca_bundle
from espdock.errors import EspdockError, RegistryError
from espdock.events import Outcome, StepNote, StepOutput
from espdock.images import bootstrap
from espdock.images.containers import Containers, first_line
from espdock.images.machine_lock import machine_lock
from espdock.images.specs import ImageInfo, RegistryAnswer, RegistryStatus
from espdock.workspace import Workspace

# dpkg's database: read from the image, not asked of a `dpkg-query` run in it (see installed_packages).
DPKG_STATUS = "/var/lib/dpkg/status"
# Whether a built image's package set is in its labels: "pending" from the build until then.
RECORDED_LABEL = f"{bootstrap.PACKAGES_LABEL}.recorded"
DPKG_LINE = re.compile(r"^[a-z0-9][a-z0-9+.-]*(:[a-z0-9]+)?=\S+$")

BUILDKIT_STEP = re.compile(r"^#\d+ \[.*\] (?P<what>.+)$")


def _denied(registry: str, what: str, answer: RegistryAnswer) -> RegistryError:
    host = registry.split("/", 1)[0]
    return RegistryError(
        f"the cache registry {registry} refused the engine's credentials to {what}: {first_line(answer.detail)}",
        f"Log the engine in: `docker login {host}` (espdock uses the engine's login; it reads no credentials).",
    )


def installed_packages(status: str) -> list[str]:
    """NAME=VERSION of every package dpkg's STATUS file holds, sorted, as `dpkg-query -W -f
    '${Package}=${Version}\\n'` lists them: each one not marked not-installed. Reading the file
    needs no container to start (and no entrypoint to run: the IDF image's sources export.sh)."""
    packages = []
    for stanza in status.split("\n\n"):
        fields = dict(line.split(":", 1) for line in stanza.splitlines() if line[:1] not in (" ", "\t") and ":" in line)
        if "Package" in fields and not fields.get("Status", "").rstrip().endswith(" not-installed"):
            entry = f"{fields['Package'].strip()}={fields.get('Version', '').strip()}"
            if DPKG_LINE.match(entry):
                packages.append(entry)
    return sorted(packages)


class KeyedImages:
    """Ensures the keyed images of one run's steps, on the engine of CONTAINERS."""

    def __init__(self, containers: Containers, push_cache: bool = False) -> None:
        """PUSH_CACHE: make sure config.cache_registry holds every keyed image this run ensures."""
        self.containers = containers
        self._push_cache = push_cache
        # The keyed images this run used (tag, repository), for espdock.images.prune's record.
        self.used: list[tuple[str, str]] = []
        # The images --push-cache could not push, with why: the build goes on, and fails at its end.
        self.unpushed: list[tuple[str, str]] = []
        # The keyed images of the plan being run: what decides whether a missing base is needed.
        self.planned: list[EnsureImage] = []
        # The cache registry's images this run pulled and rejected (another key label): --push-cache
        # replaces them, where "already in the cache registry" kept them for every later run to reject.
        self._rejected: set[str] = set()
        # Whether the cache registry did not answer a pull in this run: not asked again (a registry
        # that takes connections and never answers cost its timeout for every keyed image).
        self._silent = False

    def ensure_base(self, step: EnsureBaseImage) -> tuple[Outcome, str]:
        """Only an image build starts from the base: with it missing (no registry here, a cleaned-up
        tag), a build whose keyed images were all present went no further than pulling it."""
        engine = self.containers.engine
        if engine.image(step.image) is not None:
            return Outcome.CACHED, "present"
        if all(
            not s.force and is_current(s.spec, engine.image(s.spec.tag)) for s in built_from(self.planned, step.image)
        ):
            return Outcome.CACHED, "not here, and not needed: the images built from it are present"
        how = bootstrap.ensure_base_image(
            engine, step.image, self.containers.config, lambda text: self.containers.emit(StepNote(step.name, text))
        )
        return (Outcome.CACHED, "present") if how == "present" else (Outcome.BUILT, how)

    def ensure(
        self, workspace: Workspace, step: EnsureImage, extra_context: Mapping[str, Path | bytes] | None = None
    ) -> tuple[Outcome, str]:
        """EXTRA_CONTEXT: files copied into the build context (relative path -> source)."""
        spec = step.spec
        self.used.append((spec.tag, spec.repository))
        existing = self.containers.engine.image(spec.tag)
        if not step.force and self._hit(workspace, step, existing):
            return Outcome.CACHED, spec.tag
        # Two workspaces (CI jobs on one runner) that miss the same key at once: one builds, the
        # other waits and then finds it, instead of building it again and leaving one untagged.
        with self._building(step):
            if not step.force:
                existing = self.containers.engine.image(spec.tag)
                if self._hit(workspace, step, existing):
                    return Outcome.CACHED, spec.tag
            return self._make(workspace, step, existing, extra_context)

    def _hit(self, workspace: Workspace, step: EnsureImage, existing: ImageInfo | None) -> bool:
        """Whether EXISTING is STEP's image (its key); then say so, and publish it if asked."""
        spec = step.spec
        if not is_current(spec, existing):
            return False
        age = age_text((datetime.now(UTC) - existing.created).total_seconds())
        self.containers.emit(StepNote(step.name, f"{spec.tag}: cache hit (key {spec.key[:16]}, built {age} ago)"))
        if existing.labels.get(RECORDED_LABEL) == "pending":
            # Its build was interrupted between BuildKit's tagging and the labelling after it: the
            # image showed its base's package set, and every later build took it as it was.
            self.containers.emit(StepNote(step.name, "its build was interrupted before its packages were recorded"))
            self._record_packages(workspace, step)
        self._publish(step)
        return True

    def _building(self, step: EnsureImage) -> AbstractContextManager[None]:
        """The lock of STEP's tag on this engine, among the espdock processes of this machine."""
        name = hashlib.sha256(f"{self.containers.engine.info().identity}\0{step.spec.tag}".encode()).hexdigest()[:16]
        tag = step.spec.tag
        return machine_lock(
            f"image-{name}",
            lambda who: self.containers.emit(StepNote(step.name, f"{tag}: another espdock{who} is making it; waiting")),
        )

    def _make(
        self,
        workspace: Workspace,
        step: EnsureImage,
        existing: ImageInfo | None,
        extra_context: Mapping[str, Path | bytes] | None,
    ) -> tuple[Outcome, str]:
        """Pull STEP's image from the cache registry, else build it (EXISTING: what its tag names now)."""
        spec = step.spec
        if not step.force and self._pull_from_cache(step):
            return Outcome.PULLED, f"{spec.tag} from {self.containers.config.cache_registry}"
        why, since = ("rebuild requested", "") if step.force else ("cache miss", self._changed_since(spec))
        self.containers.emit(
            StepNote(step.name, f"{spec.tag}: {why} (key {spec.key[:16]}{since}), building stage {spec.target}")
        )
        bootstrap.ensure_compose(self.containers.env, lambda text: self.containers.emit(StepNote(step.name, text)))

        def on_line(line: str) -> None:
            match = BUILDKIT_STEP.match(line)
            shown = spec.host_paths(match.group("what") if match else line)
            self.containers.emit(StepOutput(step.name, shown, progress=True))

        with _context_dir(workspace, spec, extra_context or {}) as context, _host_paths_in(spec):
            self.containers.engine.build_image(
                context=context,
                dockerfile=spec.dockerfile,
                target=spec.target,
                tag=spec.tag,
                # Not part of the key: BuildKit (0.11 and newer) stamps the image with it instead of now.
                build_args=dict(spec.build_args) | dict(self.containers.source_date(workspace)),
                labels=spec.labels() | {RECORDED_LABEL: "pending"},
                ca_bundle=resolve_ca_bundle(self.containers.config, self.containers.env),
                on_line=on_line,
                no_cache=step.force,
            )
        self._record_packages(workspace, step)
        if existing is not None:
            self._drop_replaced(step, existing)
        self._publish(step)
        return Outcome.BUILT, spec.tag

    def _changed_since(self, spec: ImageSpec) -> str:
        """What changed since the closest image of SPEC's repository (an upgrade of espdock changes
        its own Dockerfiles and scripts: a bare "cache miss" left the user to wonder what they did)."""
        closest = closest_image(self.containers.engine.images(spec.repository), dict(spec.inputs))
        if closest is None or not closest[1]:
            return ""
        image, changed = closest
        shown = ", ".join(changed[:4]) + (f" and {len(changed) - 4} more" if len(changed) > 4 else "")
        return f"; since {image.tags[0] if image.tags else image.id[:19]}: {shown} changed"

    def _drop_replaced(self, step: EnsureImage, replaced: ImageInfo) -> None:
        """Remove REPLACED, the image STEP's tag named before this build, unless it still has a
        name, a container or a child image: untagged, nothing would ever reuse or prune it, and
        a micro-ROS image is half a gigabyte."""
        engine = self.containers.engine
        current, left = engine.image(step.spec.tag), engine.image(replaced.id)
        if current is None or left is None or current.id == left.id:
            return
        short = left.id.removeprefix("sha256:")[:12]
        # By id the engine removes an image with one name too: one named elsewhere stays.
        if not left.tags and engine.remove_tag(left.id):
            self.containers.emit(StepNote(step.name, f"removed the image it replaced ({short})"))
        else:
            self.containers.emit(StepNote(step.name, f"kept the image it replaced ({short}): something still uses it"))

    def _record_packages(self, workspace: Workspace, step: EnsureImage) -> None:
        """The image's Debian package set (what its apt installs gave today) as labels, as the base has."""
        labels = {LABEL_WORKSPACE: str(workspace.root), "io.espdock.step": "dpkg"}
        status = self.containers.engine.read_file(step.spec.tag, DPKG_STATUS, labels)
        if status is None:
            self.containers.engine.add_labels(step.spec.tag, {RECORDED_LABEL: "no dpkg"})
            self.containers.emit(StepNote(step.name, "warning: no dpkg in the image: its package set is not recorded"))
            return
        packages = installed_packages(status.decode("utf-8", "replace"))
        self.containers.engine.add_labels(step.spec.tag, bootstrap.package_labels(packages) | {RECORDED_LABEL: "yes"})
        self.containers.emit(StepNote(step.name, f"{len(packages)} Debian packages recorded in the image's labels"))

    def _pull_from_cache(self, step: EnsureImage) -> bool:
        """Take STEP's image from the cache registry, if it has one with the right key label."""
        registry = self.containers.config.cache_registry
        if not (registry and step.cached):
            return False
        spec = step.spec
        remote = cache_ref(registry, spec.tag)
        if self._silent:
            self.containers.emit(
                StepNote(step.name, f"cache registry {registry} did not answer earlier in this run; building locally")
            )
            return False
        answer = self.containers.engine.pull_cached(remote)
        if answer.status is RegistryStatus.DENIED:
            raise _denied(registry, "pull", answer)
        if answer.status is RegistryStatus.UNREACHABLE:
            self._silent = True
            why = first_line(answer.detail)
            self.containers.emit(
                StepNote(step.name, f"warning: cache registry {registry} did not answer ({why}); building locally")
            )
            return False
        if answer.status is RegistryStatus.MISSING:
            self.containers.emit(StepNote(step.name, f"{remote}: not in the cache registry"))
            return False
        pulled = self.containers.engine.image(remote)
        label = pulled.labels.get(LABEL_KEY) if pulled else None
        if label != spec.key:
            # Someone pushed another image under this key: building is safer than trusting it.
            self.containers.engine.untag(remote)
            found = (label or "missing")[:16]
            self._rejected.add(remote)
            replaced = "; --push-cache replaces it" if not self._push_cache else ", and --push-cache replaces it"
            self.containers.emit(
                StepNote(
                    step.name,
                    f"warning: rejected {remote}: its key label is {found}, expected {spec.key[:16]}; building it"
                    + replaced,
                )
            )
            return False
        self.containers.engine.tag(remote, spec.tag)
        self.containers.engine.untag(remote)
        self.containers.emit(
            StepNote(step.name, f"{spec.tag}: pulled from the cache registry {registry} (key {spec.key[:16]})")
        )
        return True

    def _publish(self, step: EnsureImage) -> None:
        """With --push-cache, push STEP's image unless the cache registry holds it already."""
        registry = self.containers.config.cache_registry
        if not (self._push_cache and registry and step.cached):
            return
        remote = cache_ref(registry, step.spec.tag)
        held = self.containers.engine.registry_has(remote)
        wrong = held.status is RegistryStatus.OK and remote in self._rejected  # another image: push over it
        if held.status is RegistryStatus.OK and not wrong:
            self.containers.emit(StepNote(step.name, f"{remote}: already in the cache registry"))
            return
        if held.status is RegistryStatus.DENIED:
            raise _denied(registry, "push", held)
        if held.status is RegistryStatus.MISSING or wrong:
            self.containers.engine.tag(step.spec.tag, remote)
            try:
                held = self.containers.engine.push_cached(remote)
            finally:
                self.containers.engine.untag(remote)
            if held.status is RegistryStatus.OK:
                self.containers.emit(
                    StepNote(step.name, f"pushed {remote}" + (", replacing the image it held" if wrong else ""))
                )
                return
            if held.status is RegistryStatus.DENIED:
                raise _denied(registry, "push", held)
        why = first_line(held.detail)
        self.unpushed.append((remote, why))
        self.containers.emit(StepNote(step.name, f"warning: could not push to the cache registry {registry} ({why})"))


def unpushed_error(unpushed: list[tuple[str, str]], registry: str, done: str) -> RegistryError:
    """The error of a run asked to --push-cache that could not push UNPUSHED (reference, why); DONE:
    what the run itself did."""
    return RegistryError(
        f"--push-cache: {len(unpushed)} image(s) not pushed to {registry}: "
        + "; ".join(f"{ref} ({why})" for ref, why in unpushed[:3]),
        f"{done}; run it again with --push-cache once the registry answers.",
    )


@contextmanager
def _host_paths_in(spec: ImageSpec) -> Iterator[None]:
    """A failed build's message names SPEC's sources by their host paths, as its output does."""
    try:
        yield
    except EspdockError as exc:
        exc.message = spec.host_paths(exc.message)
        exc.args = (exc.message,)
        raise


CONTEXT_PREFIX = "espdock-context-"


@contextmanager
def _context_dir(workspace: Workspace, spec: ImageSpec, files: Mapping[str, Path | bytes]) -> Iterator[Path]:
    """The build context: the workspace root, or a temporary directory staged from the spec
    and FILES (relative path -> a file copied there with its mode, symlinks staying links, or
    the content itself)."""
    if spec.context is None:
        yield workspace.root
        return
    # Named with this process's identity: the next run removes what a kill -9 left.
    with scratch.scratch_dir(CONTEXT_PREFIX) as tmp:
        for rel, data in spec.context:
            path = Path(tmp, rel)
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_bytes(data)
            path.chmod(0o644)
        for rel, source in files.items():
            path = Path(tmp, rel)
            path.parent.mkdir(parents=True, exist_ok=True)
            if isinstance(source, bytes):
                path.write_bytes(source)
                path.chmod(0o644)
            else:
                shutil.copy2(source, path, follow_symlinks=False)
                if not path.is_symlink():
                    path.chmod(image_mode(path.stat().st_mode))
        # The modes the image gets, whatever the umask (077 made files only root could read, in
        # an image whose key, of contents, every umask shares).
        for directory in (Path(tmp), *(p for p in Path(tmp).rglob("*") if p.is_dir() and not p.is_symlink())):
            directory.chmod(0o755)
        yield Path(tmp)


def age_text(seconds: float) -> str:
    """SECONDS as a short age: 3 min, 2 h, 5 d."""
    for unit, size in (("d", 86400), ("h", 3600), ("min", 60)):
        if seconds >= size:
            return f"{seconds / size:.0f} {unit}"
    return f"{max(seconds, 0):.0f} s"


def is_current(spec: ImageSpec, existing: ImageInfo | None) -> bool:
    """Whether EXISTING (the engine's image of SPEC's tag, if any) is SPEC's image: its key."""
    return existing is not None and existing.labels.get(LABEL_KEY) == spec.key


def image_mode(st_mode: int) -> int:
    """The mode a file copied into an image gets: readable by all, executable by all where its
    owner may execute it. A umask of 077 left the install tree's files 0600 (setuptools keeps the
    sources' modes), which the runtime image's user, not their owner there, could not read."""
    return 0o755 if st_mode & 0o100 else 0o644


def closest_image(images: list[ImageInfo], current: dict[str, str]) -> tuple[ImageInfo, list[str]] | None:
    """The image whose inputs differ from CURRENT in the fewest names (newest on a tie)."""
    best = None
    for image in images:
        previous = json.loads(image.labels.get(LABEL_INPUTS, "{}"))
        changed = sorted(n for n in set(previous) | set(current) if previous.get(n) != current.get(n))
        rank = (len(changed), -image.created.timestamp())
        if best is None or rank < best[0]:
            best = (rank, image, changed)
    return None if best is None else (best[1], best[2])
