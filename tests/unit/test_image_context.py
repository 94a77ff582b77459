"""What espdock.images.keyed stages as an image's build context."""

from __future__ import annotations

import os

from espdock.build.steps import ImageSpec
from espdock.images.keyed import _context_dir
from espdock.workspace import Workspace


def test_an_image_s_staged_context_has_the_same_modes_under_any_umask(tmp_path):
    """Under umask 077 the staged files were 0600 and the directories 0700: an image only root
    could read (`sh: cannot open /opt/espdock/with-ca.sh`), with the key every umask shares."""
    spec = ImageSpec("espdock/x", "k", "Dockerfile", "build", (), context=(("a/b/with-ca.sh", b"echo\n"),))
    previous = os.umask(0o077)
    try:
        with _context_dir(Workspace(tmp_path), spec, {"c/d.txt": b"d"}) as staged:
            modes = {p.relative_to(staged).as_posix(): p.stat().st_mode & 0o777 for p in staged.rglob("*")}
    finally:
        os.umask(previous)
    assert modes == {"a": 0o755, "a/b": 0o755, "a/b/with-ca.sh": 0o644, "c": 0o755, "c/d.txt": 0o644}


def test_installed_files_copied_into_an_image_are_readable_by_its_user_under_any_umask(tmp_path):
    """umask 077: setuptools kept the sources' 0600 in install/, and the runtime image's node (not
    their owner there) failed on `Permission denied` reading its own package.xml and ament index."""
    from espdock.ros.runtime_tree import runtime_install_digest

    install = tmp_path / "install/talk"
    (install / "lib/talk").mkdir(parents=True)
    (install / "package.xml").write_text("<package/>\n")
    (install / "lib/talk/talker").write_text("#!/bin/sh\n")
    (install / "package.xml").chmod(0o644)
    (install / "lib/talk/talker").chmod(0o755)
    digest = runtime_install_digest(tmp_path / "install", ("talk",))
    (install / "package.xml").chmod(0o600)
    (install / "lib/talk/talker").chmod(0o700)
    assert runtime_install_digest(tmp_path / "install", ("talk",)) == digest, "the same image under any umask"
    spec = ImageSpec("espdock/w", "k", "Dockerfile", "runtime", (), context=(("Dockerfile", b"FROM x\n"),))
    files = {
        "install/talk/package.xml": install / "package.xml",
        "install/talk/lib/talk/talker": install / "lib/talk/talker",
    }
    with _context_dir(Workspace(tmp_path), spec, files) as staged:
        modes = {rel: (staged / rel).stat().st_mode & 0o777 for rel in files}
    assert modes == {"install/talk/package.xml": 0o644, "install/talk/lib/talk/talker": 0o755}


def test_a_context_a_killed_espdock_staged_is_removed_by_the_next_and_a_live_one_s_is_not(tmp_path, monkeypatch):
    """kill -9 during an image build left its staged context (Dockerfile and docker/) in /tmp for good."""
    import tempfile

    from espdock.scratch import owner_identity

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    left = tmp_path / "espdock-context-0000:1:1-abcd1234"  # another boot's process: gone
    live = tmp_path / f"espdock-context-{owner_identity()}-efgh5678"
    for path in (left, live):
        (path / "docker").mkdir(parents=True)
    spec = ImageSpec("espdock/x", "k", "Dockerfile", "build", (), context=(("Dockerfile", b"FROM x\n"),))
    with _context_dir(Workspace(tmp_path), spec, {}) as staged:
        assert staged.name.startswith(f"espdock-context-{owner_identity()}-")
    assert not left.exists() and live.is_dir()
