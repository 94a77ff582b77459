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
