"""What `espdock micro-ros status` reports: each micro-ROS image, its inputs, and whether it exists."""

from __future__ import annotations

from collections.abc import Mapping
from datetime import UTC, datetime

from espdock.build.steps import ImageSpec
from espdock.errors import EspdockError, WorkspaceError
from espdock.firmware.pins import FOLLOW_HEAD, RESOLVED_FILE, Source, parse_resolved, parse_sources
from espdock.firmware.plan import derive_interface_packages, spec_target
from espdock.images.engine import Engine
from espdock.images.keyed import closest_image
from espdock.images.specs import RunSpec
from espdock.workspace import Package


def built_from(engine: Engine, image: str) -> dict[str, Source]:
    """The commits IMAGE's micro-ROS library was built from, by repository."""
    lines: list[str] = []
    code = engine.run(RunSpec(image=image, argv=("cat", RESOLVED_FILE), workdir="/"), lines.append)
    if code != 0:
        raise EspdockError(
            f"{image} has no record of its micro-ROS sources ({RESOLVED_FILE})",
            "Rebuild it with `espdock micro-ros rebuild`.",
        )
    return parse_resolved(lines)


def resolved_sources(engine: Engine, specs: Mapping[str, ImageSpec]) -> dict[str, Source]:
    """The commits the built micro-ROS images of SPECS were built from, by repository; images that
    disagree on one are an error (no single pin fits both)."""
    images = [spec.tag for spec in {s.key: s for s in specs.values()}.values() if engine.image(spec.tag)]
    if not images:
        raise WorkspaceError("no micro-ROS image of this workspace is built yet", "Run `espdock build` first.")
    resolved: dict[str, Source] = {}
    for image in images:
        for key, source in built_from(engine, image).items():
            if key in resolved and resolved[key].commit != source.commit:
                raise WorkspaceError(
                    f"the micro-ROS images disagree on {source.url}: {resolved[key].commit} and {source.commit}",
                    "Pin it by hand in docker/idf/micro_ros_sources.txt.",
                )
            resolved[key] = source
    return resolved


def micro_ros_report(
    engine: Engine, specs: Mapping[str, ImageSpec], packages: tuple[Package, ...], sources_text: str
) -> dict:
    """A JSON-ready account of the micro-ROS images (SPECS: firmware package -> its image's spec)
    and of the pinned sources (SOURCES_TEXT: docker/idf/micro_ros_sources.txt)."""
    by_name = {p.name: p for p in packages}
    grouped: dict[str, list[str]] = {}
    for firmware, spec in sorted(specs.items()):
        grouped.setdefault(spec.key, []).append(firmware)
    images = []
    for firmwares in grouped.values():
        spec = specs[firmwares[0]]
        interfaces = derive_interface_packages(packages, by_name[firmwares[0]])
        report = _image_report(engine, spec, firmwares, [p.name for p in interfaces])
        if report["present"]:
            report["built_from"] = {s.url: s.commit for s in built_from(engine, spec.tag).values()}
        images.append(report)
    sources = parse_sources(sources_text)
    return {
        "images": images,
        "firmware": {name: spec.tag for name, spec in sorted(specs.items())},
        "targets": {name: spec_target(spec) for name, spec in sorted(specs.items())},
        "sources": [{"url": s.url, "branch": s.branch, "commit": s.commit} for s in sources],
        "following_branch_head": [s.url for s in sources if s.commit == FOLLOW_HEAD],
    }


def _image_report(engine: Engine, spec: ImageSpec, firmware: list[str], interfaces: list[str]) -> dict:
    image = engine.image(spec.tag)
    report: dict = {
        "key": spec.key,
        "image": spec.tag,
        "target": spec_target(spec),
        "firmware_packages": firmware,
        "build_args": dict(spec.build_args),
        "interface_packages": interfaces,
        "inputs": dict(spec.inputs),
        "present": image is not None and image.labels.get("io.espdock.key") == spec.key,
    }
    if image is not None:
        report["size_bytes"] = image.size
        report["created"] = image.created.isoformat()
        report["age_seconds"] = int((datetime.now(UTC) - image.created).total_seconds())
        return report
    # No image for this key: say what changed since the closest image of this repository.
    closest = closest_image(engine.images(spec.repository), dict(spec.inputs))
    if closest is not None:
        image, changed = closest
        report["closest_image"] = image.tags[0] if image.tags else image.id
        report["changed_inputs"] = changed
    return report
