"""Helpers for the demo's unit tests (a uniquely named module: test dirs here have no __init__.py)."""

from __future__ import annotations

import importlib
import os

import pytest


def require(module: str) -> None:
    """Import MODULE or skip the test, except in CI, where a missing test dependency is a failure."""
    try:
        importlib.import_module(module)
    except ImportError as exc:
        message = f"{module} is needed (pip install -e '.[test]'; pyzbar also needs Debian's libzbar0): {exc}"
        if os.environ.get("CI", "").lower() == "true":
            pytest.fail(message, pytrace=False)
        pytest.skip(message, allow_module_level=True)
