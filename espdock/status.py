"""What `espdock micro-ros status` reports: each micro-ROS image, its inputs, and whether it exists."""

from __future__ import annotations

import json
from collections.abc import Mapping
from datetime import UTC, datetime

from espdock.engine import Engine, ImageInfo
from espdock.plan import LABEL_INPUTS, ImageSpec, derive_interface_packages
from espdock.workspace import Package


def micro_ros_report(engine: Engine, specs: Mapping[str, ImageSpec], packages: tuple[Package, ...]) -> dict:
    """A JSON-ready account of the micro-ROS images (SPECS: firmware package -> its image's spec)."""
    by_name = {p.name: p for p in packages}
    grouped: dict[str, list[str]] = {}
    for firmware, spec in sorted(specs.items()):
        grouped.setdefault(spec.key, []).append(firmware)
    images = []
    for firmwares in grouped.values():
        spec = specs[firmwares[0]]
        interfaces = derive_interface_packages(packages, by_name[firmwares[0]])
        images.append(_image_report(engine, spec, firmwares, [p.name for p in interfaces]))
    return {"images": images, "firmware": {name: spec.tag for name, spec in sorted(specs.items())}}


def _image_report(engine: Engine, spec: ImageSpec, firmware: list[str], interfaces: list[str]) -> dict:
    image = engine.image(spec.tag)
    report: dict = {
        "key": spec.key,
        "image": spec.tag,
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
    closest = _closest(engine.images(spec.repository), dict(spec.inputs))
    if closest is not None:
        image, changed = closest
        report["closest_image"] = image.tags[0] if image.tags else image.id
        report["changed_inputs"] = changed
    return report


def _closest(images: list[ImageInfo], current: dict[str, str]) -> tuple[ImageInfo, list[str]] | None:
    """The image whose inputs differ from CURRENT in the fewest names (newest on a tie)."""
    best = None
    for image in images:
        previous = json.loads(image.labels.get(LABEL_INPUTS, "{}"))
        changed = sorted(n for n in set(previous) | set(current) if previous.get(n) != current.get(n))
        rank = (len(changed), -image.created.timestamp())
        if best is None or rank < best[0]:
            best = (rank, image, changed)
    return None if best is None else (best[1], best[2])
