"""Installing a firmware package espdock built where colcon's options say (its colcon extension).

`python -m espdock.firmware.colcon_install PKG_DIR PKG PREFIX BUILD_DIR [--merged]`: run by the build task
of espdock.ros.colcon_extension with espdock's own Python, which is not colcon's where espdock came
from pipx. PREFIX is colcon's install prefix for PKG (install/PKG, or the install base itself
with --merge-install, where the ament index and colcon's setup files then find it); BUILD_DIR
colcon's build dir for it, which becomes a link to the IDF build dir when it is elsewhere (the IDF
container sees only the workspace, so the build itself stays in espdock's build/PKG).
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

from espdock.config import load_config
from espdock.errors import EspdockError
from espdock.firmware.install import install_firmware
from espdock.layout import FIRMWARE_DIR, INSTALL_LAYOUT_FILE, install_prefix, merged_install
from espdock.workspace import find_workspace, read_package


def install_where_colcon_says(
    package_dir: Path, package: str, prefix: Path, merged: bool, build_dir: Path | None = None
) -> Path | None:
    """Install PACKAGE's firmware, built by espdock, under colcon's install PREFIX for it (the
    install base itself when MERGED); None when that is where espdock installed it already.
    BUILD_DIR: colcon's build dir for PACKAGE, linked to espdock's when it is elsewhere."""
    ws = find_workspace(package_dir)
    config = load_config(ws.root, os.environ)
    ws = ws.with_layout(config.package_paths, config.colcon_root)
    own_build = ws.ws_dir / "build" / package
    if build_dir is not None and os.path.realpath(build_dir) != os.path.realpath(own_build):
        if build_dir.is_symlink() or not build_dir.exists():
            build_dir.parent.mkdir(parents=True, exist_ok=True)
            build_dir.unlink(missing_ok=True)
            build_dir.symlink_to(own_build, target_is_directory=True)
    own_base = ws.ws_dir / "install"
    own_isolated = own_base / package
    own_prefix = install_prefix(own_base, package)  # where espdock build just installed it
    if merged and os.path.realpath(prefix) == os.path.realpath(own_base) and not merged_install(own_base):
        # An older colcon (Debian's 0.12) does not record the layout: recorded here, espdock's
        # own installs (espdock build and flash) use it from now on.
        (own_base / INSTALL_LAYOUT_FILE).write_text("merged\n")
    if os.path.realpath(prefix) == os.path.realpath(own_prefix):
        installed = None
    else:
        manifest = package_dir / "package.xml"
        installed = install_firmware(
            package=package,
            manifest=manifest,
            build_dir=own_build,
            install_base=prefix if merged else prefix.parent,
            run_depends=tuple(sorted(read_package(manifest).depends)),
            owner=None,
            prefix=prefix,
            workspace_root=ws.root,
        )
    if merged_install(own_base) and (own_isolated / "share" / package / FIRMWARE_DIR).is_symlink():
        # espdock build's isolated copy, made before the layout was recorded: in a merged install
        # base nothing sources it, and a second copy is not what colcon was asked for.
        shutil.rmtree(own_isolated)
    return installed


def main(argv: list[str]) -> int:
    merged = "--merged" in argv
    package_dir, package, prefix, build_dir = [arg for arg in argv if arg != "--merged"]
    try:
        firmware = install_where_colcon_says(Path(package_dir), package, Path(prefix), merged, Path(build_dir))
    except EspdockError as exc:
        print(f"espdock: {exc.message}", file=sys.stderr)
        return exc.exit_code
    if firmware is not None:
        print(f"firmware installed in {firmware}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
