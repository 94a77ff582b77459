"""Point espdock at the official-ROS-image contract double, where ros:jazzy-ros-base is missing:

    eval "$(python -m tests.ros_official_double use)"

builds the double (if needed) and prints the ESPDOCK_* settings that select it, as `export`
lines (ros_image = "official", base_image = the double's tag). See README.md here.
"""

from __future__ import annotations

import os
import shlex
import sys

from espdock.config import Config, resolve_ca_bundle
from espdock.images.engine import Engine
from tests.ros_official_double.build import build_double, settings


def main(argv: list[str]) -> int:
    if argv != ["use"]:
        print(__doc__, file=sys.stderr)
        return 2
    engine = Engine.connect(os.environ)
    tag = build_double(engine, resolve_ca_bundle(Config(), os.environ), lambda line: None)
    for name, value in settings(tag).items():
        print(f"export {name}={shlex.quote(value)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
