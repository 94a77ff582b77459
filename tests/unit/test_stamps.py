"""The install listing a build stamp records beside it: its format is on disk in every workspace."""

from __future__ import annotations

import hashlib
import os

from espdock.build.stamps import listing_digest


def test_an_install_listing_keeps_the_format_earlier_builds_recorded(tmp_path):
    # A changed order or field would make every workspace's recorded listing stale: each
    # package rebuilt once after an upgrade, for nothing.
    root = tmp_path / "install"
    (root / "pkg" / "share").mkdir(parents=True)
    (root / "pkg" / "share" / "package.xml").write_text("<package/>")
    (root / "pkg" / "lib.so").write_bytes(b"\0" * 10)
    (root / "setup.sh").write_text("# colcon's, ignored\n")
    (root / "pkg.txt").write_text("x")
    (root / "linked").symlink_to("pkg")
    (root / "dangling").symlink_to("nowhere")

    def line(rel: str, target: str = "") -> str:
        info = os.lstat(root / rel)
        return f"{rel}\0{info.st_size}\0{info.st_mtime_ns}\0{target}\n"

    # Each directory's files and links by name, then its directories, depth first; links not followed.
    lines = [line("dangling", "nowhere"), line("linked", "pkg"), line("pkg.txt"), line("pkg/lib.so")]
    lines.append(line("pkg/share/package.xml"))
    expected = hashlib.sha256("".join(lines).encode()).hexdigest()
    assert listing_digest(root, ignore={"setup.sh"}) == expected
    assert listing_digest(tmp_path / "missing") is None
