"""Build manifests: hashing an install tree, and telling what differs from it."""

from __future__ import annotations

import json
import os

import pytest

from espdock.build.manifest import (
    MANIFEST_NAME,
    Difference,
    compare,
    file_hashes,
    read_manifest,
    record_build,
    write_manifest,
)
from espdock.build.steps import Plan
from espdock.errors import WorkspaceError
from espdock.workspace import Workspace


def tree(tmp_path):
    install = tmp_path / "install"
    (install / "pkg/share/pkg").mkdir(parents=True)
    (install / "pkg/share/pkg/package.xml").write_text("<package/>")
    (install / "pkg/share/pkg/.firmware-abc").mkdir()
    (install / "pkg/share/pkg/.firmware-abc/app.bin").write_bytes(b"\xe9app")
    (install / "pkg/share/pkg/firmware").symlink_to(".firmware-abc")
    return install


def test_every_file_and_link_is_hashed_and_the_manifest_itself_is_not(tmp_path):
    install = tree(tmp_path)
    write_manifest({"format": 1, "files": {}}, install)
    hashes = file_hashes(install)
    assert sorted(hashes) == [
        "pkg/share/pkg/.firmware-abc/app.bin",
        "pkg/share/pkg/firmware",
        "pkg/share/pkg/package.xml",
    ]
    assert hashes["pkg/share/pkg/firmware"] == "symlink:.firmware-abc"
    assert MANIFEST_NAME not in hashes


def test_missing_extra_and_changed_files_are_each_named(tmp_path):
    install = tree(tmp_path)
    before = file_hashes(install)
    (install / "pkg/share/pkg/package.xml").write_text("<package>changed</package>")
    (install / "pkg/share/pkg/.firmware-abc/app.bin").unlink()
    (install / "pkg/share/pkg/new.txt").write_text("new")
    assert compare(before, file_hashes(install)) == [
        Difference("pkg/share/pkg/.firmware-abc/app.bin", "missing"),
        Difference("pkg/share/pkg/new.txt", "extra"),
        Difference("pkg/share/pkg/package.xml", "changed"),
    ]
    assert compare(before, before) == []


def test_something_that_is_no_manifest_is_refused(tmp_path):
    bad = tmp_path / "m.json"
    bad.write_text(json.dumps({"files": []}))
    with pytest.raises(WorkspaceError, match="not an espdock manifest"):
        read_manifest(bad)
    bad.write_text("{")
    with pytest.raises(WorkspaceError, match="not an espdock manifest"):
        read_manifest(bad)
    with pytest.raises(WorkspaceError, match=f"{tmp_path / 'gone.json'} does not exist$"):
        read_manifest(tmp_path / "gone.json")  # a typo: not a file that is no manifest


def test_a_build_killed_before_its_manifest_was_written_gets_a_new_one(tmp_path):
    install = tree(tmp_path)
    stamp = tmp_path / "build/.espdock-colcon-stamps.json"
    stamp.parent.mkdir()
    plan = Plan(Workspace(tmp_path))
    first = record_build(plan, "esp32", install, True, [stamp], None)
    # Nothing built, nothing newer than the manifest: the manifest stands as it is.
    (install / "pkg/share/pkg/package.xml").write_text("<package>changed by hand</package>")
    assert record_build(plan, "esp32", install, False, [stamp], None) == first
    # A step that finished (its stamp written) after the manifest: a build killed before its manifest.
    (install / f".{MANIFEST_NAME}.tmp").write_text("{half")
    stamp.write_text("{}")
    os.utime(stamp, ns=((install / MANIFEST_NAME).stat().st_mtime_ns + 1,) * 2)
    again = record_build(plan, "esp32", install, False, [stamp], None)
    assert again["files"] == file_hashes(install) != first["files"]
    assert read_manifest(install / MANIFEST_NAME) == again
    assert not (install / f".{MANIFEST_NAME}.tmp").exists()
