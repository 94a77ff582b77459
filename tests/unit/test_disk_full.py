"""A full disk is named: which path, which filesystem, how much is free."""

from __future__ import annotations

import os

from espdock.errors import DiskFull, disk_full


def mount_point(path: str) -> str:
    while not os.path.ismount(path):
        path = os.path.dirname(path)
    return path


def test_a_disk_with_room_is_not_reported(tmp_path):
    assert disk_full(tmp_path, low=0) is None


def test_a_full_disk_names_the_path_and_its_filesystem(tmp_path):
    full = disk_full(tmp_path / "ws" / "not-made-yet", low=1 << 62)
    assert isinstance(full, DiskFull) and full.exit_code == 7
    assert f"the disk holding {tmp_path / 'ws' / 'not-made-yet'}" in full.message
    assert f"mounted at {mount_point(str(tmp_path))})" in full.message
    assert "MiB free of" in full.message
