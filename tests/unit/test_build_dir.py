"""Reusing ws/build/<pkg>: what a new target, image or sdkconfig.defaults leaves of it."""

import os
from pathlib import Path

from espdock.firmware.steps import OLD_CHANGED, SDKCONFIG_MADE, SDKCONFIG_OLD, TARGET_MARKER, _defaults_digest
from espdock.firmware.steps import _prepare_build_dir as prepare


def _prepare_build_dir(build: Path, target: str, defaults: str, key: str, project: str = "firmware/app"):
    """The build dir BUILD of the project at PROJECT in workspace /w prepared for a build."""
    return prepare(build, target, defaults, key, Path("/w") / project, Path("/w"), (os.getuid(), os.getgid()))


def built(tmp_path: Path, target="esp32", defaults="d1", key="k1") -> Path:
    build = tmp_path / "build"
    (build / "esp-idf").mkdir(parents=True)
    (build / "CMakeCache.txt").write_text(
        "CMAKE_C_COMPILER:FILEPATH=/opt/old-image/xtensa-esp32-elf-gcc\n"
        "CMAKE_HOME_DIRECTORY:INTERNAL=/workspace/firmware/app\n"
    )
    (build / "sdkconfig").write_text('CONFIG_ESPDOCK_NODE_NAME="from menuconfig"\n')
    (build / TARGET_MARKER).write_text(f"{target}\n{defaults}\n{key}\n")
    return build


def test_same_inputs_keep_everything(tmp_path):
    build = built(tmp_path)
    assert _prepare_build_dir(build, "esp32", "d1", "k1") == (False, None)
    assert sorted(p.name for p in build.iterdir()) == [TARGET_MARKER, "CMakeCache.txt", "esp-idf", "sdkconfig"]


def test_a_new_image_key_resets_the_build_but_keeps_menuconfig_changes(tmp_path):
    build = built(tmp_path)
    assert _prepare_build_dir(build, "esp32", "d1", "k2") == (True, None)
    assert sorted(p.name for p in build.iterdir()) == [TARGET_MARKER, "sdkconfig"]
    assert "from menuconfig" in (build / "sdkconfig").read_text()


def test_a_new_image_key_with_new_defaults_sets_the_sdkconfig_aside_too(tmp_path):
    build = built(tmp_path)
    assert _prepare_build_dir(build, "esp32", "d2", "k2") == (True, "")
    assert sorted(p.name for p in build.iterdir()) == [OLD_CHANGED, TARGET_MARKER, SDKCONFIG_OLD]


def test_new_defaults_set_only_the_sdkconfig_aside_as_menuconfig_would(tmp_path):
    """New defaults make the sdkconfig afresh; the one before, menuconfig's changes in it, was
    deleted without a word."""
    build = built(tmp_path)
    assert _prepare_build_dir(build, "esp32", "d2", "k1") == (True, "")
    assert sorted(p.name for p in build.iterdir()) == [
        OLD_CHANGED, TARGET_MARKER, "CMakeCache.txt", "esp-idf", SDKCONFIG_OLD
    ]  # fmt: skip
    assert "from menuconfig" in (build / SDKCONFIG_OLD).read_text()


def test_a_new_target_empties_the_build_dir_and_sets_the_sdkconfig_aside_as_set_target_does(tmp_path):
    """A one-off build for another chip deleted the build dir, menuconfig's changes with it, unsaid."""
    build = built(tmp_path)
    assert _prepare_build_dir(build, "esp32s3", "d1", "k1") == (True, "esp32")
    assert sorted(p.name for p in build.iterdir()) == [OLD_CHANGED, TARGET_MARKER, SDKCONFIG_OLD]
    assert "from menuconfig" in (build / SDKCONFIG_OLD).read_text()


def test_an_sdkconfig_set_aside_with_no_menuconfig_change_leaves_the_one_with_changes(tmp_path):
    """menuconfig's change set aside as sdkconfig.old by new defaults, then the defaults back (a
    branch switched there and back): the sdkconfig the new defaults had made replaced it."""
    build = built(tmp_path)
    assert _prepare_build_dir(build, "esp32", "d2", "k1") == (True, "")
    made = 'CONFIG_ESPDOCK_NODE_NAME="from defaults d2"\n'
    for name in ("sdkconfig", SDKCONFIG_MADE):
        (build / name).write_text(made)
    (build / TARGET_MARKER).write_text("esp32\nd2\nk1\n")
    assert _prepare_build_dir(build, "esp32", "d1", "k1") == (True, "")
    assert "from menuconfig" in (build / SDKCONFIG_OLD).read_text() and not (build / "sdkconfig").exists()
    # One with no change replaces one with none: the last set aside, as IDF's set-target keeps it.
    (build / OLD_CHANGED).unlink()
    for name in ("sdkconfig", SDKCONFIG_MADE):
        (build / name).write_text(made)
    (build / TARGET_MARKER).write_text("esp32\nd2\nk1\n")
    assert _prepare_build_dir(build, "esp32", "d1", "k1") == (True, "")
    assert (build / SDKCONFIG_OLD).read_text() == made


def test_a_moved_project_empties_the_build_dir_but_keeps_menuconfig_changes(tmp_path):
    """`mv firmware/app firmware/board`: IDF refused the build dir ("configured for project
    .../app not .../board. Run 'idf.py fullclean'") and the hint said to fix the firmware."""
    build = built(tmp_path)
    assert _prepare_build_dir(build, "esp32", "d1", "k1", project="firmware/board") == (True, None)
    assert sorted(p.name for p in build.iterdir()) == [TARGET_MARKER, "sdkconfig"]
    assert "from menuconfig" in (build / "sdkconfig").read_text()


def test_only_the_defaults_files_a_build_for_the_chip_reads_decide_the_sdkconfig(tmp_path):
    """Another chip's sdkconfig.defaults.<chip>, or an editor's sdkconfig.defaults~, made the
    sdkconfig afresh, menuconfig's changes set aside."""
    (tmp_path / "sdkconfig.defaults").write_text("CONFIG_FREERTOS_HZ=1000\n")
    digest = _defaults_digest(tmp_path, "esp32")
    (tmp_path / "sdkconfig.defaults.esp32s3").write_text("CONFIG_SPIRAM=y\n")
    (tmp_path / "sdkconfig.defaults~").write_text("CONFIG_FREERTOS_HZ=100\n")
    assert _defaults_digest(tmp_path, "esp32") == digest
    assert _defaults_digest(tmp_path, "esp32s3") != digest
    (tmp_path / "sdkconfig.defaults.esp32").write_text("CONFIG_FREERTOS_HZ=500\n")
    assert _defaults_digest(tmp_path, "esp32") != digest


def test_a_defaults_file_the_cmakelists_names_decides_the_sdkconfig_too(tmp_path):
    """`set(SDKCONFIG_DEFAULTS "sdkconfig.defaults;sdkconfig.local")`: an edit of sdkconfig.local
    rebuilt the micro-ROS library with it, and the app's sdkconfig kept the old value, unsaid."""
    (tmp_path / "sdkconfig.defaults").write_text("CONFIG_FREERTOS_HZ=1000\n")
    (tmp_path / "sdkconfig.local").write_text("CONFIG_FREERTOS_HZ=250\n")
    digest = _defaults_digest(tmp_path, "esp32")
    (tmp_path / "CMakeLists.txt").write_text('set(SDKCONFIG_DEFAULTS "./sdkconfig.defaults;./sdkconfig.local")\n')
    listed = _defaults_digest(tmp_path, "esp32")
    assert listed != digest, "a file a build starts reading"
    (tmp_path / "sdkconfig.local").write_text("CONFIG_FREERTOS_HZ=300\n")
    assert _defaults_digest(tmp_path, "esp32") != listed
    # A project that names none, or only sdkconfig.defaults files, keeps its digest (no afresh
    # sdkconfig for it after an upgrade of espdock).
    (tmp_path / "CMakeLists.txt").write_text('set(SDKCONFIG_DEFAULTS "sdkconfig.defaults")\n')
    assert _defaults_digest(tmp_path, "esp32") == digest
    # CMake's other spelling of the list: an edit of sdkconfig.local went unseen.
    (tmp_path / "CMakeLists.txt").write_text('list(APPEND SDKCONFIG_DEFAULTS "sdkconfig.local")\n')
    appended = _defaults_digest(tmp_path, "esp32")
    (tmp_path / "sdkconfig.local").write_text("CONFIG_FREERTOS_HZ=125\n")
    assert _defaults_digest(tmp_path, "esp32") != appended
    # Set under a condition (a CI-only file), or after project(), which IDF ignores: whether the list
    # replaces sdkconfig.defaults is not known here, and an edit of sdkconfig.defaults went unseen.
    for cmake in (
        'if(DEFINED ENV{MY_CI})\n  set(SDKCONFIG_DEFAULTS "sdkconfig.local")\nendif()\nproject(board)\n',
        'project(board)\nlist(APPEND SDKCONFIG_DEFAULTS "sdkconfig.local")\n',
    ):
        (tmp_path / "CMakeLists.txt").write_text(cmake)
        before = _defaults_digest(tmp_path, "esp32")
        (tmp_path / "sdkconfig.defaults").write_text(f"CONFIG_FREERTOS_HZ={len(cmake)}\n")
        assert _defaults_digest(tmp_path, "esp32") != before, cmake
    (tmp_path / "CMakeLists.txt").write_text('list(APPEND SDKCONFIG_DEFAULTS "sdkconfig.local")\nproject(board)\n')
    # An sdkconfig.defaults the list leaves out is read by no build: its edit (save-defconfig's
    # menuconfig change) made the sdkconfig afresh, and lost that change.
    unread = _defaults_digest(tmp_path, "esp32")
    (tmp_path / "sdkconfig.defaults").write_text("CONFIG_FREERTOS_HZ=444\n")
    assert _defaults_digest(tmp_path, "esp32") == unread


def test_save_defconfig_s_warning_reads_names_written_with_a_leading_dot_slash(tmp_path):
    """`./sdkconfig.defaults;./sdkconfig.defaults.local`: save-defconfig said no build reads
    sdkconfig.defaults, and not that the .local file overrides the change, which the next build lost."""
    from espdock.firmware.steps import chip_overrides
    from espdock.workspace import named_sdkconfig_defaults

    (tmp_path / "CMakeLists.txt").write_text(
        'set(SDKCONFIG_DEFAULTS "./sdkconfig.defaults;./sdkconfig.defaults.local")\n'
    )
    (tmp_path / "sdkconfig.defaults").write_text("CONFIG_SENSOR_PERIOD_MS=1200\n")
    (tmp_path / "sdkconfig.defaults.local").write_text("CONFIG_SENSOR_PERIOD_MS=5\n")
    order = named_sdkconfig_defaults(tmp_path / "CMakeLists.txt")
    assert order == ("sdkconfig.defaults", "sdkconfig.defaults.local")
    assert chip_overrides(tmp_path, "esp32", order) == [
        "CONFIG_SENSOR_PERIOD_MS=5 (sdkconfig.defaults.local) over 1200"
    ]


def test_options_a_chip_s_defaults_file_sets_over_sdkconfig_defaults_are_named(tmp_path):
    """menuconfig, then `save-defconfig`: a change to an option sdkconfig.defaults.<chip> also sets
    went into sdkconfig.defaults, and the next sdkconfig made afresh had the chip file's value."""
    from espdock.firmware.steps import chip_overrides

    (tmp_path / "sdkconfig.defaults").write_text(
        'CONFIG_IDF_TARGET="esp32"\nCONFIG_SENSOR_PERIOD_MS=1200\nCONFIG_ESPTOOLPY_FLASHSIZE_8MB=y\n'
    )
    (tmp_path / "sdkconfig.defaults.esp32").write_text(
        "CONFIG_SENSOR_PERIOD_MS=1000\nCONFIG_ESPTOOLPY_FLASHSIZE_8MB=y\n# CONFIG_SPIRAM is not set\n"
    )
    (tmp_path / "sdkconfig.defaults.esp32s3").write_text("CONFIG_SENSOR_PERIOD_MS=250\n")
    assert chip_overrides(tmp_path, "esp32") == ["CONFIG_SENSOR_PERIOD_MS=1000 (sdkconfig.defaults.esp32) over 1200"]
    assert chip_overrides(tmp_path, "esp32s3") == ["CONFIG_SENSOR_PERIOD_MS=250 (sdkconfig.defaults.esp32s3) over 1200"]
    assert chip_overrides(tmp_path, "esp32c3") == []
    # The files a CMakeLists' SDKCONFIG_DEFAULTS names after it win too; one that leaves it out
    # makes it a file no build reads.
    (tmp_path / "sdkconfig.defaults.local").write_text("CONFIG_SENSOR_PERIOD_MS=5\n")
    local = ("sdkconfig.defaults", "sdkconfig.defaults.local")
    assert chip_overrides(tmp_path, "esp32c3", local) == [
        "CONFIG_SENSOR_PERIOD_MS=5 (sdkconfig.defaults.local) over 1200"
    ]
    assert chip_overrides(tmp_path, "esp32c3", ("sdkconfig.defaults.local",)) is None


def test_a_menuconfig_change_of_a_library_option_is_reported_and_others_are_not(tmp_path):
    from espdock.firmware.steps import LIBRARY_BASELINE, _library_settings_changed

    build = tmp_path / "build"
    build.mkdir()
    sdkconfig = build / "sdkconfig"
    sdkconfig.write_text('CONFIG_FREERTOS_HZ=1000\nCONFIG_SPIRAM=y\nCONFIG_ESPDOCK_NODE_NAME="a"\n')
    assert _library_settings_changed(build, fresh=True) == []  # configured from sdkconfig.defaults
    sdkconfig.write_text('CONFIG_FREERTOS_HZ=1000\nCONFIG_SPIRAM=y\nCONFIG_ESPDOCK_NODE_NAME="b"\n')
    assert _library_settings_changed(build, fresh=False) == []  # an app option: the library has none
    sdkconfig.write_text("CONFIG_FREERTOS_HZ=100\n# CONFIG_SPIRAM is not set\nCONFIG_LWIP_IPV6=y\n")
    assert _library_settings_changed(build, fresh=False) == [
        "CONFIG_FREERTOS_HZ=100 (was 1000)",
        "CONFIG_LWIP_IPV6=y (was n)",
        "CONFIG_SPIRAM=n (was y)",
    ]
    # The baseline survives an image change with the sdkconfig (the library is still without them).
    (build / TARGET_MARKER).write_text("esp32\nd1\nk1\n")
    _prepare_build_dir(build, "esp32", "d1", "k2")
    assert sorted(p.name for p in build.iterdir()) == [LIBRARY_BASELINE, TARGET_MARKER, "sdkconfig"]
    assert _library_settings_changed(build, fresh=False)


def test_the_defaults_list_is_read_from_cmakelists_written_the_ways_idf_projects_write_them(tmp_path):
    """What IDF's project() reads of SDKCONFIG_DEFAULTS, as espdock reads it (the chip it guesses,
    the micro-ROS library's settings and what makes the sdkconfig afresh all follow it)."""
    from espdock.workspace import sdkconfig_defaults_list

    cases = {
        # A base file and a developer's own if present: one condition lost the whole list, and the
        # package was built for the workspace's chip, not the base file's.
        'set(SDKCONFIG_DEFAULTS "sdkconfig.base")\nif(EXISTS "${CMAKE_CURRENT_LIST_DIR}/sdkconfig.local")\n'
        '  list(APPEND SDKCONFIG_DEFAULTS "sdkconfig.local")\nendif()\nproject(app)\n': (
            ("sdkconfig.base", "sdkconfig.local"),
            True,
        ),
        # A `#` in a quoted argument is no comment: it hid the line after it.
        'set(PROJECT_VER "1.0#beta")\nset(SDKCONFIG_DEFAULTS sdkconfig.base)\nproject(app)\n': (
            ("sdkconfig.base",),
            False,
        ),
        'set(SDKCONFIG_DEFAULTS "sdkconfig.base" CACHE STRING "defaults (see doc)")\nproject(app)\n': (
            ("sdkconfig.base",),
            False,
        ),
        "set(SDKCONFIG_DEFAULTS a)\nlist(PREPEND SDKCONFIG_DEFAULTS base)\nproject(app)\n": (("base", "a"), False),
        "set(SDKCONFIG_DEFAULTS a)\nunset(SDKCONFIG_DEFAULTS)\nproject(app)\n": ((), False),
        'set(SDKCONFIG_DEFAULTS "$ENV{BOARD_DIR}/sdkconfig.board")\nproject(app)\n': ((), False),
        'if(A) message("x") endif()\nset(SDKCONFIG_DEFAULTS z)\nproject(app)\n': (("z",), False),
        "project(app)\nset(SDKCONFIG_DEFAULTS late)\n": ((), False),
        # A bracket comment, over lines: it was read as code.
        "#[[ the old way:\nset(SDKCONFIG_DEFAULTS sdkconfig.old)\n]]\nproject(app)\n": ((), False),
    }
    cmake = tmp_path / "CMakeLists.txt"
    for text, expected in cases.items():
        cmake.write_text(text)
        assert tuple(sdkconfig_defaults_list(cmake)) == expected, text
