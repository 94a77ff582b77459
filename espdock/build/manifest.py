"""What a build produced: a manifest of its inputs and of every installed file, and checks against it.

`espdock build` writes install/espdock-manifest.json in the colcon root after a successful
build: the image keys and tags, the chip target, the pinned micro-ROS inputs, and the sha256
of every file under install/. `espdock verify MANIFEST` compares an install tree with it.
"""

from __future__ import annotations

import json
import os
import stat
from collections.abc import Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path

from espdock import __version__, durable
from espdock.build.stamps import content_sha256
from espdock.build.steps import EnsureImage, ImageSpec, Plan
from espdock.errors import WorkspaceError, disk_full
from espdock.events import Outcome, StepFinished
from espdock.firmware.plan import IdfBuild
from espdock.images.containers import give_to
from espdock.layout import FIRMWARE_DIR, MANIFEST_NAME
from espdock.ros.plan import ColconBuild

FORMAT = 2
# The formats this espdock reads: 1 held no file modes.
READABLE = (1, 2)


def _installed(install: Path) -> Iterator[tuple[str, Path]]:
    """Every file and link under INSTALL (but the manifest), by relative path, in order."""
    for dirpath, dirnames, filenames in os.walk(install):
        dirnames.sort()
        for name in sorted(filenames + [d for d in dirnames if (Path(dirpath) / d).is_symlink()]):
            path = Path(dirpath) / name
            if (rel := path.relative_to(install).as_posix()) != MANIFEST_NAME:
                yield rel, path


def file_hashes(install: Path, modes: bool = True) -> dict[str, str]:
    """sha256 of every file under INSTALL (symlinks as 'symlink:' + target), by relative path; with
    MODES, an executable's (its owner's x bit) followed by EXECUTABLE: a script of `ros2 run` that
    lost it no longer starts, and matched all the same. Format 1 manifests hold no modes."""

    def entry(path: Path) -> str:
        if path.is_symlink():
            return "symlink:" + os.readlink(path)
        info = path.stat()
        digest = content_sha256(path, info).hex()
        return digest + EXECUTABLE if modes and info.st_mode & stat.S_IXUSR else digest

    return {rel: entry(path) for rel, path in _installed(install)}


# What marks an executable's hash in a manifest (format 2).
EXECUTABLE = " executable"


def _image(spec: ImageSpec) -> dict[str, object]:
    return {"tag": spec.tag, "key": spec.key, "build_args": dict(spec.build_args), "inputs": dict(spec.inputs)}


def build_manifest(plan: Plan, target: str, install: Path, previous: Mapping | None = None) -> dict[str, object]:
    """The manifest of PLAN's build: its images and inputs, and the install tree as it is now.
    PREVIOUS: the manifest of the builds before, whose firmware packages still installed (and the
    images they and, where PLAN built no ROS package, the ROS packages came from) PLAN did not
    build: a `--only ros` or one package's build dropped them, though their files stayed listed."""
    images = {s.spec.tag: _image(s.spec) for s in plan.steps if isinstance(s, EnsureImage)}
    # Each firmware package built, with the chip it was built for (the workspace's `target` is only the default).
    firmware = {s.package: {"target": s.target, "image": s.image} for s in plan.steps if isinstance(s, IdfBuild)}
    if previous is not None:
        before = previous.get("firmware") if isinstance(previous.get("firmware"), dict) else {}
        for name, entry in before.items():
            if name not in firmware and (install / name / "share" / name / FIRMWARE_DIR).is_dir():
                firmware[name] = entry
        used = {entry.get("image") for entry in firmware.values() if isinstance(entry, dict)}
        of_firmware = {entry.get("image") for entry in before.values() if isinstance(entry, dict)}
        ros_built = any(isinstance(s, ColconBuild) for s in plan.steps)
        old_images = previous.get("images") if isinstance(previous.get("images"), dict) else {}
        for tag, spec in old_images.items():
            if tag not in images and (tag in used or (not ros_built and tag not in of_firmware)):
                images[tag] = spec
    return {
        "format": FORMAT,
        "espdock": __version__,
        "target": target,
        "firmware": dict(sorted(firmware.items())),
        "images": dict(sorted(images.items())),
        "files": file_hashes(install),
    }


def _lists_other_files(manifest: Mapping, install: Path) -> bool:
    """Whether MANIFEST lists other files than INSTALL holds (paths only: hashing is what a no-change
    build saves): a package's prefix removed by hand (as a build's note on a renamed package says
    to), another job's install/ merged in, which no build rebuilds."""
    files = manifest.get("files")
    return not isinstance(files, dict) or set(files) != {rel for rel, _ in _installed(install)}


def _root_rewritten(manifest: Path, install: Path) -> bool:
    """Whether a file at INSTALL's root changed since MANIFEST was written: colcon's setup scripts,
    which no package's stamp covers, and which a native `colcon build` (espdock's colcon extension
    building a firmware package) rewrites after the espdock build that wrote the manifest."""
    written = manifest.stat().st_mtime_ns
    with os.scandir(install) as entries:
        return any(
            entry.name != MANIFEST_NAME
            and not entry.is_dir(follow_symlinks=False)
            and entry.stat(follow_symlinks=False).st_mtime_ns > written
            for entry in entries
        )


def _temporary(install: Path) -> Path:
    return install / f".{MANIFEST_NAME}.tmp"


def _newer_than_stamps(manifest: Path, stamps: Iterable[Path]) -> bool:
    written = manifest.stat().st_mtime_ns
    return all(not stamp.is_file() or stamp.stat().st_mtime_ns <= written for stamp in stamps)


def write_manifest(manifest: Mapping[str, object], install: Path) -> Path:
    """Write MANIFEST to INSTALL/espdock-manifest.json in one rename, flushed (file and directory)."""
    install.mkdir(parents=True, exist_ok=True)
    path = install / MANIFEST_NAME
    tmp = _temporary(install)
    tmp.write_text(json.dumps(manifest, indent=1, sort_keys=True) + "\n")
    durable.replace(tmp, path)
    return path


def record_build(
    plan: Plan, target: str, install: Path, built: bool, stamps: Iterable[Path], owner: tuple[int, int] | None
) -> dict:
    """The manifest of PLAN's finished build, written to INSTALL unless nothing was BUILT and the one
    there, listing the files INSTALL holds, is newer than every stamp file in STAMPS (every install
    tree was checked against its stamp: re-hashing would be most of a no-change build's time; a stamp
    newer than the manifest is a build killed before its manifest was written). One that is no
    manifest is written anew: the build failed on it, every time. OWNER: who the written file
    belongs to (as root)."""
    existing = install / MANIFEST_NAME
    _temporary(install).unlink(missing_ok=True)  # left by an espdock killed while writing
    try:
        previous: dict | None = read_manifest(existing)
    except WorkspaceError:
        previous = None
    if previous is not None and previous["format"] == FORMAT and not built and _newer_than_stamps(existing, stamps):
        if not _lists_other_files(previous, install) and not _root_rewritten(existing, install):
            return previous
    manifest = build_manifest(plan, target, install, previous)
    try:
        written = write_manifest(manifest, install)
    except OSError as exc:
        full = disk_full(install)
        if full is not None:
            _temporary(install).unlink(missing_ok=True)
            raise full from exc
        raise
    if owner is not None:
        os.chown(written, *owner)
    return manifest


# A build's error when a signal (Ctrl-C, SIGTERM) stopped it.
INTERRUPTED = "interrupted"


def write_report(
    path: Path,
    finished: Iterable[StepFinished],
    manifest: dict | None,
    seconds: float,
    owner: tuple[int, int],
    error: str | None = None,
) -> None:
    """The --report JSON: every step's outcome, the build's, its duration, and the manifest (None on
    failure); ERROR: what stopped the build (INTERRUPTED: a signal, outcome "interrupted"). As root,
    a report it creates belongs to OWNER, as the build's files do."""
    steps = list(finished)
    failed = any(step.outcome is Outcome.FAILED for step in steps) or manifest is None or error is not None
    data: dict = {} if error is None else {"error": error}
    data |= {
        "outcome": "interrupted" if error == INTERRUPTED else "failed" if failed else "succeeded",
        "seconds": round(seconds, 3),
        "steps": [
            {"step": s.step, "outcome": s.outcome.value, "seconds": round(s.seconds, 3), "detail": s.detail}
            for s in steps
        ],
        "manifest": manifest,
    }
    created = not path.exists()
    path.write_text(json.dumps(data, indent=1, sort_keys=True) + "\n")
    if created:
        give_to(path, owner)


@dataclass(frozen=True)
class Difference:
    path: str
    what: str  # "missing", "extra", "changed" or "mode" (only whether it is executable changed)


def read_manifest(path: Path) -> dict:
    try:
        data = json.loads(path.read_text())
    except FileNotFoundError:
        raise WorkspaceError(f"{path} does not exist", f"A build writes it into install/ ({MANIFEST_NAME}).") from None
    except (OSError, ValueError) as exc:
        raise WorkspaceError(f"{path} is not an espdock manifest: {exc}", "Give the install tree's one.") from None
    if isinstance(data, dict) and isinstance(data.get("format"), int) and data["format"] > FORMAT:
        # A CI job's espdock, upgraded before this machine's: not "no manifest", which it is.
        raise WorkspaceError(
            f"{path} was made by a newer espdock (its format {data['format']}, this one's {FORMAT})",
            "Verify it with that espdock (or a newer one than this).",
        )
    if not isinstance(data, dict) or data.get("format") not in READABLE or not isinstance(data.get("files"), dict):
        raise WorkspaceError(f"{path} is not an espdock manifest (format {FORMAT})", "Give the install tree's one.")
    return data


def compare(expected: Mapping[str, str], actual: Mapping[str, str]) -> list[Difference]:
    """Every file that is missing, extra or changed in ACTUAL against EXPECTED (path -> hash)."""
    differences: Iterable[Difference] = (
        *(Difference(p, "missing") for p in expected if p not in actual),
        *(Difference(p, "extra") for p in actual if p not in expected),
        *(
            Difference(p, _changed(expected[p], actual[p]))
            for p in expected
            if p in actual and expected[p] != actual[p]
        ),
    )
    return sorted(differences, key=lambda d: (d.path, d.what))


def _changed(expected: str, actual: str) -> str:
    """How a file's two hashes differ: "mode" where the content is the same and only whether it is
    executable changed (a `chmod -x`, which `ros2 run` then fails on), else "changed"."""
    return "mode" if expected.removesuffix(EXECUTABLE) == actual.removesuffix(EXECUTABLE) else "changed"
