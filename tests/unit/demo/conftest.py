"""Unit tests of espdock_demo's pure modules: run on the host, no rclpy, no engine."""

from __future__ import annotations

from pathlib import Path

import pytest

# ws/src/espdock_demo is on pytest's pythonpath (pyproject.toml).
ROOT = Path(__file__).resolve().parents[3]
MSG_FILE = ROOT / "ws" / "src" / "custom_interface" / "msg" / "CameraConfig.msg"


@pytest.fixture(scope="session")
def msg_text() -> str:
    """custom_interface's CameraConfig.msg."""
    return MSG_FILE.read_text()


@pytest.fixture(scope="session")
def msg_fields(msg_text) -> dict[str, str]:
    """CameraConfig's fields and types, read from the .msg file as rosidl would."""
    from espdock_demo.camera_config import parse_msg_fields

    return parse_msg_fields(msg_text)


@pytest.fixture(scope="session")
def settings(msg_fields):
    from espdock_demo.camera_config import settings_from_fields

    return settings_from_fields(msg_fields)
