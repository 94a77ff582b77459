"""Where a firmware package's IDF build dir is when colcon's --build-base says (the colcon
extension's espdock.firmware.colcon_install), and what espdock's ws/build/PKG then is."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

from espdock.firmware.colcon_install import place_build_dir
from espdock.layout import firmware_build_dir


def workspace(tmp_path: Path) -> tuple[Path, Path]:
    root = tmp_path / "root"
    (root / "ws" / "src").mkdir(parents=True)
    (root / "espdock.toml").write_text("")
    package = root / "firmware" / "cam"
    package.mkdir(parents=True)
    own = root / "ws" / "build" / "cam"
    (own / "esp-idf").mkdir(parents=True)
    (own / "CMakeCache.txt").write_text("CMAKE_HOME_DIRECTORY:INTERNAL=/workspace/ws/build/cam\n")
    (own / "sdkconfig").write_text('CONFIG_ESPDOCK_NODE_NAME="from menuconfig"\n')
    return package, own


def test_a_base_in_the_workspace_gets_the_tree_with_its_sdkconfig_and_a_relative_link(tmp_path):
    package, own = workspace(tmp_path)
    other = own.parent.parent / "build-other" / "cam"
    place_build_dir(package, "cam", other)
    assert other.is_dir() and not other.is_symlink()
    assert "from menuconfig" in (other / "sdkconfig").read_text()
    assert not (other / "CMakeCache.txt").exists()  # CMake's records the old path: built afresh
    assert os.readlink(own) == "../build-other/cam" and own.resolve() == other.resolve()
    # Back to the default base: the real tree is ws/build/cam again, the sdkconfig with it.
    place_build_dir(package, "cam", own)
    assert own.is_dir() and not own.is_symlink()
    assert "from menuconfig" in (own / "sdkconfig").read_text()


def test_a_link_whose_base_was_removed_gives_a_fresh_build_dir(tmp_path):
    package, own = workspace(tmp_path)
    elsewhere = tmp_path / "elsewhere" / "cam"
    place_build_dir(package, "cam", elsewhere)
    assert os.readlink(own) == str(elsewhere.resolve())
    shutil.rmtree(elsewhere.parent)  # colcon clean, or rm -rf of the build base
    assert firmware_build_dir(own.parent.parent, "cam") == own and not own.is_symlink() and not own.exists()
