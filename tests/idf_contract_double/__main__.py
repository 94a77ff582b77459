"""Point a workspace at the IDF contract double, for trying espdock where Espressif's image is missing:

    eval "$(python -m tests.idf_contract_double use [WORKSPACE])"

builds the double (if needed), pins WORKSPACE's micro-ROS sources to the double's repositories
(WORKSPACE/docker/idf/micro_ros_sources.txt) and prints the ESPDOCK_* settings that select it,
as `export` lines. What the tests do through use_double(); see README.md here.
"""

from __future__ import annotations

import os
import shlex
import sys
from pathlib import Path

from espdock.config import Config, resolve_ca_bundle
from espdock.images.engine import Engine
from tests.conftest import REPO
from tests.idf_contract_double.build import use_double


def main(argv: list[str]) -> int:
    if not argv or argv[0] != "use" or len(argv) > 2:
        print(__doc__, file=sys.stderr)
        return 2
    root = Path(argv[1] if len(argv) == 2 else ".").resolve()
    if root == REPO or (root / "espdock/cli/__init__.py").is_file():
        # Its docker/idf/micro_ros_sources.txt is espdock's own, which ships in the wheel: pinned to
        # the double's repositories, it passed unsaid until test_pins failed on it.
        print(
            f"error: {root} is a checkout of espdock, whose micro-ROS sources espdock ships: point a workspace "
            "of your own at the double",
            file=sys.stderr,
        )
        return 2
    if not (root / "espdock.toml").is_file():
        # ws/ or tests/ of a checkout: pins no build reads, left in the checkout.
        print(f"error: {root} is no espdock workspace (no espdock.toml): give its root", file=sys.stderr)
        return 2
    (root / "docker/idf").mkdir(parents=True, exist_ok=True)
    engine = Engine.connect(os.environ)
    settings = use_double(engine, resolve_ca_bundle(Config(), os.environ), lambda line: None, root)
    for name, value in settings.items():
        print(f"export {name}={shlex.quote(value)}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
