"""What the contract doubles share: an image tagged by a hash of the files it is built from."""

from __future__ import annotations

import hashlib
from collections.abc import Iterable
from pathlib import Path

from espdock.images.engine import Engine
from espdock.images.specs import LineSink


def inputs_hash(root: Path, names: Iterable[str]) -> str:
    """A hash of the files under ROOT named by NAMES (files or directories): path and content of each."""
    digest = hashlib.sha256()
    for name in names:
        top = root / name
        files = [top] if top.is_file() else sorted(p for p in top.rglob("*") if p.is_file())
        for path in files:
            if "__pycache__" in path.parts or path.suffix == ".pyc":
                continue
            digest.update(path.relative_to(root).as_posix().encode() + b"\0")
            digest.update(hashlib.sha256(path.read_bytes()).digest())
    return digest.hexdigest()[:16]


def ensure_double(
    engine: Engine,
    root: Path,
    names: Iterable[str],
    tag_prefix: str,
    label: str,
    ca_bundle: Path | None,
    on_line: LineSink,
) -> str:
    """Build ROOT's Dockerfile (stage `double`) as TAG_PREFIX-<inputs hash> unless an image built
    from the same files exists; return the tag. A changed double is another tag, so branches
    that change it share an engine without rebuilding one tag under each other's builds."""
    wanted = inputs_hash(root, names)
    tag = f"{tag_prefix}-{wanted}"
    existing = engine.image(tag)
    if existing is None or existing.labels.get(label) != wanted:
        engine.build_image(
            context=root,
            dockerfile="Dockerfile",
            target="double",
            tag=tag,
            build_args={},
            labels={label: wanted},
            ca_bundle=ca_bundle,
            on_line=on_line,
        )
    return tag
