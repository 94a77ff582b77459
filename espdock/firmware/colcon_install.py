"""Installing a firmware package espdock built where colcon's options say (its colcon extension).

`python -m espdock.firmware.colcon_install --build-dir PKG_DIR PKG BUILD_DIR` before the build and
`python -m espdock.firmware.colcon_install PKG_DIR PKG PREFIX [--merged]` after it: run by the build
task of espdock.ros.colcon_extension with espdock's own Python, which is not colcon's where espdock
came from pipx. BUILD_DIR is colcon's build dir for PKG (BUILD_BASE/PKG): the IDF build happens
there, so `colcon clean` and `rm -rf BUILD_BASE` clean it. PREFIX is colcon's install prefix for
PKG (install/PKG, or the install base itself with --merge-install, where the ament index and
colcon's setup files then find it).
"""

from __future__ import annotations

import os
import shutil
import sys
from pathlib import Path

from espdock.config import load_config
from espdock.errors import EspdockError
from espdock.firmware.install import install_firmware
from espdock.firmware.steps import LIBRARY_BASELINE, OLD_CHANGED, SDKCONFIG_MADE, SDKCONFIG_OLD, TARGET_MARKER
from espdock.layout import FIRMWARE_DIR, INSTALL_LAYOUT_FILE, firmware_build_dir, install_prefix, merged_install
from espdock.workspace import Workspace, find_workspace, read_package, workspace_lock

# What a build dir keeps when it moves: the sdkconfig (menuconfig's changes) and what tells espdock
# what it was configured with. The rest is a cache, and CMake's records the path it was made at.
KEPT_ON_MOVE = ("sdkconfig", SDKCONFIG_OLD, OLD_CHANGED, SDKCONFIG_MADE, TARGET_MARKER, LIBRARY_BASELINE)


def _workspace(package_dir: Path) -> Workspace:
    ws = find_workspace(package_dir)
    config = load_config(ws.root, os.environ)
    return ws.with_layout(config.package_paths, config.colcon_root)


def place_build_dir(package_dir: Path, package: str, build_dir: Path) -> None:
    """Make colcon's BUILD_DIR for PACKAGE the real IDF build dir, and espdock's ws/build/PKG a
    link to it (relative inside the workspace, which build containers mount; absolute outside,
    where espdock mounts the target at that path), so espdock's commands find the one build dir
    and the one sdkconfig. A build dir elsewhere before hands over its sdkconfig."""
    ws = _workspace(package_dir)
    with workspace_lock(ws):
        own = firmware_build_dir(ws.ws_dir, package)
        before = own.resolve() if own.exists() else None
        if build_dir.is_symlink():  # ws/build/PKG itself, or the link an older espdock made to it
            build_dir.unlink()
        if before is not None and build_dir.exists() and before.samefile(build_dir):
            return
        if before is not None and build_dir.is_dir():
            shutil.rmtree(build_dir)  # a tree of another configuration: the one carried over wins
        build_dir.mkdir(parents=True, exist_ok=True)
        for name in KEPT_ON_MOVE if before is not None else ():
            if (before / name).is_file():
                shutil.copy2(before / name, build_dir / name)
        if own.absolute() == build_dir.absolute():
            return
        if own.is_symlink():
            own.unlink()  # the old target is another build base's: colcon's, left as it is
        elif own.exists():
            shutil.rmtree(own)
        own.parent.mkdir(parents=True, exist_ok=True)
        target = build_dir.resolve()
        if target.is_relative_to(ws.root.resolve()):
            own.symlink_to(os.path.relpath(target, own.parent.resolve()), target_is_directory=True)
        else:
            own.symlink_to(target, target_is_directory=True)


def install_where_colcon_says(package_dir: Path, package: str, prefix: Path, merged: bool) -> Path | None:
    """Install PACKAGE's firmware, built by espdock, under colcon's install PREFIX for it (the
    install base itself when MERGED); None when that is where espdock installed it already."""
    ws = _workspace(package_dir)
    own_build = firmware_build_dir(ws.ws_dir, package)
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
    try:
        if argv[:1] == ["--build-dir"]:
            package_dir, package, build_dir = argv[1:]
            place_build_dir(Path(package_dir), package, Path(build_dir))
            return 0
        merged = "--merged" in argv
        package_dir, package, prefix = [arg for arg in argv if arg != "--merged"]
        firmware = install_where_colcon_says(Path(package_dir), package, Path(prefix), merged)
    except EspdockError as exc:
        print(f"espdock: {exc.message}", file=sys.stderr)
        return exc.exit_code
    if firmware is not None:
        print(f"firmware installed in {firmware}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
