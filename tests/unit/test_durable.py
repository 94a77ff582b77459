"""What a power cut could lose: the firmware swapped into the install tree, the manifest and the
build stamps are flushed to disk (file, then the directory that names it) before espdock goes on."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from espdock.build.manifest import write_manifest
from espdock.build.stamps import StampFile
from espdock.firmware.install import install_firmware
from tests.unit.test_firmware_tools import write_build


@pytest.fixture
def synced(monkeypatch) -> list[str]:
    """The paths os.fsync was called on, in order (the real fsync still runs)."""
    paths: list[str] = []
    real = os.fsync

    def fsync(fd: int) -> None:
        paths.append(os.readlink(f"/proc/self/fd/{fd}"))
        real(fd)

    monkeypatch.setattr(os, "fsync", fsync)
    return paths


def test_the_firmware_swapped_into_the_install_tree_is_flushed(tmp_path, synced):
    build, install = tmp_path / "build/cam", tmp_path / "install"
    (tmp_path / "package.xml").write_text("<package/>")
    write_build(build, b"\xe9app")
    firmware = install_firmware("cam", tmp_path / "package.xml", build, install, (), owner=None)
    share = str(install / "cam/share/cam")
    files = {Path(p).name for p in synced if Path(p).parent.name.startswith(".firmware-staging-")}
    assert {"cam.bin", "cam.elf", "flasher_args.json"} <= files
    assert "partition-table.bin" in {Path(p).name for p in synced}
    # The name swap is flushed after the files it names.
    assert synced[-1] == share and synced.index(share) > max(i for i, p in enumerate(synced) if p.endswith("cam.bin"))
    assert (firmware / "cam.bin").read_bytes() == b"\xe9app"


def test_the_manifest_is_flushed_file_and_directory(tmp_path, synced):
    path = write_manifest({"format": 1, "files": {}}, tmp_path / "install")
    assert synced == [str(tmp_path / "install/.espdock-manifest.json.tmp"), str(tmp_path / "install")]
    assert path.read_text().startswith("{")


def test_the_stamps_are_flushed_file_and_directory(tmp_path, synced):
    stamps = StampFile(tmp_path / "build/.espdock-stamps.json")
    stamps.record({"a": "1"}, {"a": "x"})
    stamps.forget(["a"])
    stamps.restore({"a": {"stamp": "1", "installed": "x"}})
    tmp, directory = str(tmp_path / f"build/..espdock-stamps.json.{os.getpid()}.tmp"), str(tmp_path / "build")
    assert synced == [tmp, directory] * 3


def test_two_processes_writing_one_file_at_once_each_write_it_whole(tmp_path):
    """Two `espdock run`s recording their images at once: both wrote and renamed one temporary,
    and the second's rename failed ("could not record the images this command used")."""
    import subprocess
    import sys

    target = tmp_path / "record.json"
    script = (
        "import sys; from pathlib import Path; from espdock.durable import write_text\n"
        "for i in range(300): write_text(Path(sys.argv[1]), sys.argv[2] * 1000)"
    )
    writers = [subprocess.Popen([sys.executable, "-c", script, str(target), c], stderr=subprocess.PIPE) for c in "ab"]
    errors = [w.communicate()[1].decode() for w in writers]
    assert [w.returncode for w in writers] == [0, 0], errors
    assert target.read_text() in ("a" * 1000, "b" * 1000)
    assert [p.name for p in tmp_path.iterdir()] == ["record.json"]
