"""The demo's end-to-end tests: real compose, real DDS, real browser.

Each test module brings its own stack up once (a `demo` fixture in the module)
and tears it down however the module ends. Without Docker (or Chromium, for
the browser tests) the tests skip with the reason, except when CI=true, where
that is a failure.
"""

from __future__ import annotations

import fcntl
import os
import shutil
import tempfile
from pathlib import Path

import pytest

# tests/demo and ws/src/espdock_demo (its pure helpers: jpeg_size, ...) are on pytest's
# pythonpath (pyproject.toml).
from demo_stack import build_image, docker_problem
from demo_support import need


@pytest.fixture(scope="session")
def demo_image() -> None:
    """The runtime image, built (or found up to date) once per session.

    One worker at a time: `espdock build` refuses to start while another holds the
    workspace, and the demo modules' workers start theirs at the same moment."""
    need(docker_problem())
    with open(Path(tempfile.gettempdir()) / "espdock-demo-image.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        build_image()


@pytest.fixture(scope="session")
def chromium() -> str:
    """Debian's Chromium (tests/install-system-deps.sh installs it); never a downloaded browser."""
    path = "/usr/bin/chromium"
    need(
        None
        if os.access(path, os.X_OK)
        else f"{path} is missing: apt-get install chromium (or run tests/install-system-deps.sh)"
    )
    try:
        import websocket  # noqa: F401
    except ImportError:
        need("websocket-client is missing: pip install -e '.[test]'")
    return shutil.which(path) or path
