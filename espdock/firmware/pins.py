"""docker/idf/micro_ros_sources.txt: the commit of every repository libmicroros.a is built from.

Parsing and pinning are pure text in, text out; the image build applies the pins
(docker/idf/pinned_git.py) and records what it checked out, which `espdock micro-ros pin`
writes back for "-" rows (write_pins, pin_idf_image: the only functions here that touch files).
"""

from __future__ import annotations

import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path

from espdock import durable
from espdock.defaults import locate
from espdock.errors import WorkspaceError
from espdock.images.containers import give_to, make_dirs_for
from espdock.layout import IDF_DOCKERFILE, SOURCES_FILE
from espdock.workspace import write_atomically

# Where Dockerfile.idf keeps the commits the image build checked out.
RESOLVED_FILE = "/opt/espdock/micro_ros_espidf_component/micro_ros_sources.resolved"
FOLLOW_HEAD = "-"
_ROW = re.compile(r"^(?P<url>\S+)\s+(?P<branch>\S+)\s+(?P<commit>[0-9a-f]{40}|-)\s*$")


@dataclass(frozen=True)
class Source:
    url: str
    branch: str
    commit: str  # 40 hex digits, or FOLLOW_HEAD

    @property
    def key(self) -> str:
        return self.url.rstrip("/").removesuffix(".git").lower()


def parse_sources(text: str, name: str = SOURCES_FILE) -> list[Source]:
    """The rows of a sources file; a malformed row is an error naming its line."""
    sources = []
    for number, line in enumerate(text.splitlines(), 1):
        row = line.split("#", 1)[0].strip()
        if not row:
            continue
        match = _ROW.match(row)
        if match is None:
            raise WorkspaceError(
                f"{name}:{number}: expected `URL BRANCH COMMIT` (a 40-hex commit or -), got {line.strip()!r}"
            )
        sources.append(Source(match["url"], match["branch"], match["commit"]))
    return sources


def parse_resolved(lines: Iterable[str]) -> dict[str, Source]:
    """What an image build checked out, by repository; other lines (a shell's banner) are skipped."""
    resolved = {}
    for line in lines:
        match = _ROW.match(line.strip())
        if match and match["commit"] != FOLLOW_HEAD:
            source = Source(match["url"], match["branch"], match["commit"])
            resolved[source.key] = source
    return resolved


def pin_heads(text: str, resolved: Mapping[str, Source]) -> tuple[str, list[Source]]:
    """TEXT with each "-" row that RESOLVED has a commit for pinned to it (comments and order
    kept), and the rows pinned."""
    out, pinned = [], []
    for line in text.splitlines(keepends=True):
        row = line.split("#", 1)[0].strip()
        match = _ROW.match(row) if row else None
        if match and match["commit"] == FOLLOW_HEAD:
            got = resolved.get(Source(match["url"], match["branch"], FOLLOW_HEAD).key)
            if got is not None and got.branch == match["branch"]:
                out.append(line.replace(row, f"{match['url']} {match['branch']} {got.commit}", 1))
                pinned.append(Source(match["url"], match["branch"], got.commit))
                continue
        out.append(line)
    return "".join(out), pinned


def pin_image_digest(dockerfile: str, arg: str, reference: str, digests: Iterable[str]) -> str | None:
    """DOCKERFILE with `ARG ARG=REFERENCE` pinned to REFERENCE@sha256:... from DIGESTS (an
    image's RepoDigests, `repository@sha256:...`); None when no digest is of that repository."""
    digest = _digest_of(reference, digests)
    if digest is None:
        return None
    line = re.compile(rf"^(\s*ARG\s+{re.escape(arg)}=){re.escape(reference)}[ \t]*$", re.MULTILINE)
    return line.sub(lambda m: f"{m.group(1)}{reference}@{digest}", dockerfile, count=1)


def _digest_of(reference: str, digests: Iterable[str]) -> str | None:
    repository = reference.rsplit(":", 1)[0] if ":" in reference.rsplit("/", 1)[-1] else reference
    return next((d.split("@", 1)[1] for d in digests if d.split("@", 1)[0] == repository), None)


def read_sources(root: Path) -> str:
    """The text of ROOT's sources file, or of espdock's default where the workspace has none, as
    the image builds read it; its absence is an error (it pins what micro-ROS is built from)."""
    path = locate(root, SOURCES_FILE)
    if path is None:
        raise WorkspaceError(f"{root / SOURCES_FILE} is missing", "It pins every repository micro-ROS is built from.")
    return path.read_text()


def write_pins(root: Path, resolved: Mapping[str, Source], owner: tuple[int, int]) -> list[Source]:
    """Pin ROOT's "-" rows to the commits in RESOLVED, in one rename; the rows pinned. A workspace
    on espdock's default gets its own file, the default pinned (as root, OWNER's)."""
    text, pinned = pin_heads(read_sources(root), resolved)
    if pinned:
        _write(root / SOURCES_FILE, text, owner)
    return pinned


def _write(path: Path, text: str, owner: tuple[int, int]) -> None:
    """PATH holds TEXT, in one rename: a file it replaces keeps its mode and owner, a new one
    (and the directories it needs) is OWNER's."""
    if path.exists():
        write_atomically(path, text)
        return
    make_dirs_for(path.parent, owner)
    durable.write_text(path, text)
    give_to(path, owner)


@dataclass(frozen=True)
class IdfPin:
    """What pin_idf_image did with the IDF image's reference."""

    reference: str
    digest: str | None  # None: the engine has no registry digest for it (built or loaded locally)
    written: bool  # False with a digest: the reference comes from espdock.toml, pinned there by hand


def pin_idf_image(
    root: Path, reference: str, digests: Iterable[str], from_config: bool, owner: tuple[int, int]
) -> IdfPin | None:
    """Pin ROOT's Dockerfile.idf `ARG IDF_IMAGE=REFERENCE` to the digest among DIGESTS (the pulled
    image's RepoDigests); None when REFERENCE is pinned already. FROM_CONFIG: espdock.toml's
    idf_image names it, so the Dockerfile is left alone. A workspace on espdock's default
    Dockerfile.idf gets its own, the default pinned (as root, OWNER's)."""
    if "@sha256:" in reference:
        return None
    digest = _digest_of(reference, digests)
    if digest is None:
        return IdfPin(reference, None, False)
    if from_config:
        return IdfPin(reference, digest, False)
    dockerfile = locate(root, IDF_DOCKERFILE)
    if dockerfile is None:
        raise WorkspaceError(f"{root / IDF_DOCKERFILE} is missing", "It builds the IDF and micro-ROS images.")
    text = dockerfile.read_text()
    _write(root / IDF_DOCKERFILE, pin_image_digest(text, "IDF_IMAGE", reference, digests) or text, owner)
    return IdfPin(reference, digest, True)
