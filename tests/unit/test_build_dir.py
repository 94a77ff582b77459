"""Reusing ws/build/<pkg>: what a new target, image or sdkconfig.defaults leaves of it."""

from pathlib import Path

from espdock.firmware.steps import SDKCONFIG_OLD, TARGET_MARKER, _prepare_build_dir


def built(tmp_path: Path, target="esp32", defaults="d1", key="k1") -> Path:
    build = tmp_path / "build"
    (build / "esp-idf").mkdir(parents=True)
    (build / "CMakeCache.txt").write_text("CMAKE_C_COMPILER:FILEPATH=/opt/old-image/xtensa-esp32-elf-gcc\n")
    (build / "sdkconfig").write_text('CONFIG_ESPDOCK_NODE_NAME="from menuconfig"\n')
    (build / TARGET_MARKER).write_text(f"{target}\n{defaults}\n{key}\n")
    return build


def test_same_inputs_keep_everything(tmp_path):
    build = built(tmp_path)
    assert _prepare_build_dir(build, "esp32", "d1", "k1") == (False, False)
    assert sorted(p.name for p in build.iterdir()) == [TARGET_MARKER, "CMakeCache.txt", "esp-idf", "sdkconfig"]


def test_a_new_image_key_resets_the_build_but_keeps_menuconfig_changes(tmp_path):
    build = built(tmp_path)
    assert _prepare_build_dir(build, "esp32", "d1", "k2") == (True, False)
    assert sorted(p.name for p in build.iterdir()) == [TARGET_MARKER, "sdkconfig"]
    assert "from menuconfig" in (build / "sdkconfig").read_text()


def test_a_new_image_key_with_new_defaults_sets_the_sdkconfig_aside_too(tmp_path):
    build = built(tmp_path)
    assert _prepare_build_dir(build, "esp32", "d2", "k2") == (True, True)
    assert sorted(p.name for p in build.iterdir()) == [TARGET_MARKER, SDKCONFIG_OLD]


def test_new_defaults_set_only_the_sdkconfig_aside_as_menuconfig_would(tmp_path):
    """New defaults make the sdkconfig afresh; the one before, menuconfig's changes in it, was
    deleted without a word."""
    build = built(tmp_path)
    assert _prepare_build_dir(build, "esp32", "d2", "k1") == (True, True)
    assert sorted(p.name for p in build.iterdir()) == [TARGET_MARKER, "CMakeCache.txt", "esp-idf", SDKCONFIG_OLD]
    assert "from menuconfig" in (build / SDKCONFIG_OLD).read_text()


def test_a_new_target_removes_the_build_dir(tmp_path):
    build = built(tmp_path)
    _prepare_build_dir(build, "esp32s3", "d1", "k1")
    assert not build.exists()


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
