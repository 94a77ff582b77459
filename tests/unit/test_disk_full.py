"""A full disk is named: which path, which filesystem, how much is free."""

from __future__ import annotations

import os
import shutil

from espdock.errors import DiskFull, disk_full


def mount_point(path: str) -> str:
    while not os.path.ismount(path):
        path = os.path.dirname(path)
    return path


def test_a_disk_with_room_is_not_reported(tmp_path):
    assert disk_full(tmp_path, low=0) is None


def usage(total_mib: int, free_mib: int):
    return lambda path: shutil._ntuple_diskusage(total_mib << 20, (total_mib - free_mib) << 20, free_mib << 20)


def test_a_small_filesystem_with_most_of_it_free_is_not_full(tmp_path, monkeypatch):
    """A 21 MiB workspace filesystem with 16 MiB free was "full" at any failure: a .msg syntax
    error was exit 7, its package and rosidl's error never named."""
    monkeypatch.setattr(shutil, "disk_usage", usage(21, 16))
    assert disk_full(tmp_path) is None
    monkeypatch.setattr(shutil, "disk_usage", usage(21, 0))
    assert disk_full(tmp_path) is not None


def test_a_disk_known_full_is_named_whatever_it_has_free(tmp_path, monkeypatch):
    """ENOSPC on build/ of its own tmpfs was exit 70, "a bug in espdock", where the workspace's disk had room."""
    monkeypatch.setattr(shutil, "disk_usage", usage(100_000, 50_000))
    assert disk_full(tmp_path) is None
    assert "50000 MiB free" in disk_full(tmp_path, known=True).message


def test_a_full_disk_names_the_path_and_its_filesystem(tmp_path, monkeypatch):
    monkeypatch.setattr(shutil, "disk_usage", usage(100_000, 10))
    full = disk_full(tmp_path / "ws" / "not-made-yet")
    assert isinstance(full, DiskFull) and full.exit_code == 7
    assert f"the disk holding {tmp_path / 'ws' / 'not-made-yet'}" in full.message
    assert f"mounted at {mount_point(str(tmp_path))})" in full.message
    assert "MiB free of" in full.message


def test_a_full_filesystem_smaller_than_a_mebibyte_says_its_size_in_kibibytes(tmp_path, monkeypatch):
    """A 300 KiB filesystem, full, was "0 MiB free of 0 MiB"."""
    monkeypatch.setattr(shutil, "disk_usage", lambda path: shutil._ntuple_diskusage(300 << 10, 296 << 10, 4 << 10))
    assert disk_full(tmp_path, known=True).message.endswith(": 4 KiB free of 300 KiB")
