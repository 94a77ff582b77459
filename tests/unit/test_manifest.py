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
    # A newer espdock's (a CI job's, upgraded first): "not an espdock manifest" and "give the
    # install tree's one", of the very file given, told its user nothing.
    newer = json.loads(json.dumps({"format": 99, "files": {}}))
    bad.write_text(json.dumps(newer))
    with pytest.raises(WorkspaceError, match="made by a newer espdock \\(its format 99"):
        read_manifest(bad)


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


def test_a_no_change_build_after_a_native_colcon_build_records_the_setup_scripts_it_rewrote(tmp_path):
    """A plain `colcon build` of a firmware package (espdock's colcon extension) rewrites the install
    root's setup scripts after the espdock build in it wrote the manifest; the next `espdock build`
    had nothing to build and kept that manifest, and `espdock verify` failed on every script until
    a --force build."""
    install = tree(tmp_path)
    (install / "setup.sh").write_text("_colcon_prefix_chain_sh_source_script /ws/install\n")
    stamp = tmp_path / "build/.espdock-colcon-stamps.json"
    stamp.parent.mkdir()
    stamp.write_text("{}")
    plan = Plan(Workspace(tmp_path))
    first = record_build(plan, "esp32", install, True, [stamp], None)
    (install / "setup.sh").write_text(f"_colcon_prefix_chain_sh_source_script {install}\n")
    os.utime(install / "setup.sh", ns=((install / MANIFEST_NAME).stat().st_mtime_ns + 1,) * 2)
    again = record_build(plan, "esp32", install, False, [stamp], None)
    assert again["files"] == file_hashes(install) != first["files"]
    assert compare(read_manifest(install / MANIFEST_NAME)["files"], file_hashes(install)) == []


def test_a_no_change_build_after_a_package_s_prefix_was_removed_lists_it_no_more(tmp_path):
    """A build's note on a renamed package says `rm -r install/OLD build/espdock-ros/OLD`; done, the
    next builds (nothing to build) kept the manifest listing OLD's files, and `espdock verify` of
    every later install failed until some package was rebuilt."""
    install = tree(tmp_path)
    (install / "old_pkg/share/old_pkg").mkdir(parents=True)
    (install / "old_pkg/share/old_pkg/package.xml").write_text("<package/>")
    stamp = tmp_path / "build/.espdock-colcon-stamps.json"
    stamp.parent.mkdir()
    stamp.write_text("{}")
    plan = Plan(Workspace(tmp_path))
    record_build(plan, "esp32", install, True, [stamp], None)
    (install / "old_pkg/share/old_pkg/package.xml").unlink()
    for directory in ("old_pkg/share/old_pkg", "old_pkg/share", "old_pkg"):
        (install / directory).rmdir()
    again = record_build(plan, "esp32", install, False, [stamp], None)
    assert again["files"] == file_hashes(install)
    assert compare(read_manifest(install / MANIFEST_NAME)["files"], file_hashes(install)) == []


def test_a_no_change_build_writes_anew_a_manifest_that_is_none_or_lists_other_files(tmp_path):
    """A manifest cut short made every later build exit 2 ("is not an espdock manifest") until it was
    removed by hand; another CI job's install/ merged in kept the job's manifest, which `espdock
    verify` then failed against."""
    install = tree(tmp_path)
    stamp = tmp_path / "build/.espdock-colcon-stamps.json"
    stamp.parent.mkdir()
    stamp.write_text("{}")
    plan = Plan(Workspace(tmp_path))
    record_build(plan, "esp32", install, True, [stamp], None)
    (install / MANIFEST_NAME).write_text('{"format": 1, "files":')
    assert record_build(plan, "esp32", install, False, [stamp], None)["files"] == file_hashes(install)
    (install / "fw_pkg/share/fw_pkg").mkdir(parents=True)
    (install / "fw_pkg/share/fw_pkg/app.bin").write_bytes(b"\xe9")  # the firmware job's
    kept = record_build(plan, "esp32", install, False, [stamp], None)
    assert "fw_pkg/share/fw_pkg/app.bin" in kept["files"]
    assert compare(read_manifest(install / MANIFEST_NAME)["files"], file_hashes(install)) == []


def test_a_build_of_part_of_the_workspace_keeps_what_the_manifest_said_of_the_rest(tmp_path):
    """`espdock build --only ros` (or of one package) wrote a manifest without the firmware packages
    still installed, their chips and images, though it listed their files."""
    from espdock.ros.plan import ColconBuild

    install = tmp_path / "install"
    for name in ("cam_fw", "led_fw"):
        (install / name / "share" / name / "firmware").mkdir(parents=True)
    stamp = tmp_path / "build/.espdock-colcon-stamps.json"
    uros, ros, gone = "espdock/idf-micro-ros-jazzy-esp32s3:a1", "espdock/ros-jazzy-build:b2", "espdock/idf-x:c3"
    previous = {
        "format": 1,
        "files": {},
        "firmware": {
            "cam_fw": {"target": "esp32s3", "image": uros},
            "led_fw": {"target": "esp32s3", "image": uros},
            "old_fw": {"target": "esp32", "image": gone},  # uninstalled since
        },
        "images": {tag: {"tag": tag} for tag in (uros, ros, gone)},
    }
    write_manifest(previous, install)
    ros_only = Plan(Workspace(tmp_path), (ColconBuild(image=ros, packages=("app",)),))
    manifest = record_build(ros_only, "esp32", install, True, [stamp], None)
    assert manifest["firmware"] == {name: previous["firmware"][name] for name in ("cam_fw", "led_fw")}
    assert sorted(manifest["images"]) == [uros]  # the ROS image is the plan's: it has no EnsureImage here
    firmware_only = Plan(Workspace(tmp_path))
    write_manifest(previous, install)
    manifest = record_build(firmware_only, "esp32", install, True, [stamp], None)
    assert sorted(manifest["images"]) == [uros, ros], "what built the ROS packages stays"


def test_an_executable_that_lost_its_x_bit_is_a_mode_change_and_older_manifests_still_read(tmp_path):
    """`chmod -x` of an installed node script (`ros2 run` then fails, "Permission denied"):
    `espdock verify` said the install matched, then "changed", as for an edit of its content."""
    install = tree(tmp_path)
    script = install / "pkg/lib/pkg/node"
    script.parent.mkdir(parents=True)
    script.write_text("#!/usr/bin/python3\n")
    script.chmod(0o755)
    before = file_hashes(install)
    script.chmod(0o644)
    assert compare(before, file_hashes(install)) == [Difference("pkg/lib/pkg/node", "mode")]
    script.write_text("#!/usr/bin/python3\nprint()\n")
    assert compare(before, file_hashes(install)) == [Difference("pkg/lib/pkg/node", "changed")]
    # A manifest an earlier espdock wrote (format 1, no modes) reads, and is compared without them.
    old = {"format": 1, "files": file_hashes(install, modes=False)}
    write_manifest(old, install)
    script.chmod(0o755)
    assert compare(read_manifest(install / MANIFEST_NAME)["files"], file_hashes(install, modes=False)) == []


def test_verify_of_an_install_path_that_is_no_directory_is_refused(tmp_path):
    """`espdock verify M --install /typo`: exit 1 with every file "missing", as for a wiped install."""
    from tests.conftest import espdock

    install = tree(tmp_path)
    write_manifest({"format": 2, "files": file_hashes(install)}, install)
    typo = espdock("verify", str(install / MANIFEST_NAME), "--install", str(tmp_path / "instal"), cwd=tmp_path)
    assert typo.returncode == 2, typo.stdout + typo.stderr
    assert f"{tmp_path / 'instal'} is no directory" in typo.stderr and "missing" not in typo.stdout
    ok = espdock("verify", str(install / MANIFEST_NAME), cwd=tmp_path)
    assert ok.returncode == 0, ok.stdout + ok.stderr


def test_verify_of_a_manifest_kept_outside_its_install_tree_asks_for_the_tree(tmp_path):
    """A CI job's manifest, downloaded into a directory of other files: verify took that directory for
    the install tree and listed each of its files as extra and each of the manifest's as missing."""
    import shutil

    from tests.conftest import espdock

    install = tree(tmp_path / "job")
    write_manifest({"format": 2, "files": file_hashes(install)}, install)
    downloads = tmp_path / "downloads"
    (downloads / "other").mkdir(parents=True)
    (downloads / "other/notes.txt").write_text("not an install tree\n")
    kept = shutil.copy(install / MANIFEST_NAME, downloads / "m2.json")
    lost = espdock("verify", str(kept), cwd=tmp_path)
    assert lost.returncode == 2, lost.stdout + lost.stderr
    assert "is no install tree of it" in lost.stderr and "--install" in lost.stderr and lost.stdout == ""
    found = espdock("verify", str(kept), "--install", str(install), cwd=tmp_path)
    assert found.returncode == 0, found.stdout + found.stderr
    # --install given the colcon root, not its install/: every file of build/ and log/ was listed.
    above = espdock("verify", str(kept), "--install", str(tmp_path / "job"), cwd=tmp_path)
    assert above.returncode == 2 and above.stdout == "", above.stdout[-2000:] + above.stderr
    assert f"Did you mean --install {install}?" in " ".join(above.stderr.split()), above.stderr
