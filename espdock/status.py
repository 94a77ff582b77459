"""What `espdock micro-ros status` reports: the key, its inputs, and the image that has it (if any)."""

from __future__ import annotations

import json
from datetime import UTC, datetime

from espdock.engine import Engine
from espdock.plan import LABEL_INPUTS, ImageSpec
from espdock.workspace import Package


def micro_ros_report(engine: Engine, spec: ImageSpec, interfaces: tuple[Package, ...]) -> dict:
    """A JSON-ready account of the micro-ROS image for SPEC, compared with what the engine holds."""
    image = engine.image(spec.tag)
    report: dict = {
        "key": spec.key,
        "image": spec.tag,
        "build_args": dict(spec.build_args),
        "interface_packages": [p.name for p in interfaces],
        "inputs": dict(spec.inputs),
        "present": image is not None,
        "matches_workspace": image is not None,
    }
    if image is not None:
        report["size_bytes"] = image.size
        report["created"] = image.created.isoformat()
        report["age_seconds"] = int((datetime.now(UTC) - image.created).total_seconds())
        return report
    # No image for this key: say what changed since the newest image of this repository.
    newest = engine.newest_image(spec.repository)
    if newest is not None:
        previous = json.loads(newest.labels.get(LABEL_INPUTS, "{}"))
        current = dict(spec.inputs)
        report["newest_image"] = newest.tags[0] if newest.tags else newest.id
        report["changed_inputs"] = sorted(
            name for name in set(previous) | set(current) if previous.get(name) != current.get(name)
        )
    return report
