import re

import pytest

from espdock_demo import camera_config
from espdock_demo.camera_config import (
    DEFAULT_CONFIG,
    FRAME_SIZES,
    ConfigError,
    Setting,
    frame_size,
    parse_form,
    settings_from_fields,
    validate,
)


def test_every_message_field_has_the_range_its_comment_states(msg_fields, msg_text):
    """RANGES and CameraConfig.msg's comments agree, field for field."""
    commented = {}
    for line in msg_text.splitlines():
        match = re.match(r"\s*\w+\s+(\w+)\s*#\s*(-?\d+)\.\.(-?\d+)", line)
        if match:
            commented[match.group(1)] = (int(match.group(2)), int(match.group(3)))
    assert commented == camera_config.RANGES
    assert list(msg_fields) == list(camera_config.RANGES)


def test_settings_follow_the_message_order_and_pick_their_controls(settings, msg_fields):
    assert [s.name for s in settings] == list(msg_fields)
    kinds = {s.name: s.kind for s in settings}
    assert kinds["framesize"] == kinds["special_effect"] == kinds["wb_mode"] == "menu"
    assert kinds["quality"] == kinds["brightness"] == kinds["aec_value"] == "slider"
    assert kinds["hmirror"] == kinds["vflip"] == kinds["colorbar"] == "toggle"
    framesize = next(s for s in settings if s.name == "framesize")
    assert framesize.choices[6] == "QVGA (320x240)" and framesize.choices[15] == "UXGA (1600x1200)"


def test_a_field_without_a_range_fails_at_start_up(msg_fields):
    with pytest.raises(ConfigError, match=r"without a range.*new_field"):
        settings_from_fields({**msg_fields, "new_field": "uint8"})


def test_a_range_outside_the_field_type_is_refused(msg_fields):
    with pytest.raises(ConfigError, match="does not fit"):
        settings_from_fields({**msg_fields, "brightness": "uint8"})


def test_frame_sizes_follow_esp32_camera():
    assert frame_size(6) == (320, 240)
    assert frame_size(10) == (640, 480)
    assert frame_size(15) == (1600, 1200)
    assert len(FRAME_SIZES) == camera_config.RANGES["framesize"][1] + 1


def test_the_default_config_is_valid(settings):
    assert validate(settings, DEFAULT_CONFIG) == []


def test_validation_names_every_bad_field(settings):
    errors = validate(settings, {**DEFAULT_CONFIG, "framesize": 16, "quality": 64, "brightness": -3})
    assert errors == [
        "framesize must be in 0..15, got 16",
        "quality must be in 0..63, got 64",
        "brightness must be in -2..2, got -3",
    ]
    assert validate(settings, {k: v for k, v in DEFAULT_CONFIG.items() if k != "vflip"}) == ["vflip is missing"]


def test_a_form_applies_its_fields_onto_the_current_config(settings):
    current = {**DEFAULT_CONFIG, "quality": 20}
    config = parse_form(
        settings, [("framesize", "10"), ("brightness", "-2"), ("hmirror", "0"), ("hmirror", "1")], current
    )
    assert config == {**current, "framesize": 10, "brightness": -2, "hmirror": 1}


def test_a_toggle_left_unchecked_sends_only_its_hidden_zero(settings):
    config = parse_form(settings, [("vflip", "0")], {**DEFAULT_CONFIG, "vflip": 1})
    assert config["vflip"] == 0


@pytest.mark.parametrize(
    ("pairs", "message"),
    [
        ([("quality", "64")], "quality must be in 0..63, got 64"),
        ([("framesize", "-1")], "framesize must be in 0..15, got -1"),
        ([("quality", "ten")], "quality must be an integer, got 'ten'"),
        ([("quality", "1.5")], "quality must be an integer"),
        ([("quality", "")], "quality must be an integer"),
        ([("quality", "9" * 400)], "quality must be an integer"),
        ([("gain", "1")], "unknown setting 'gain'"),
        ([("<script>", "1")], "unknown setting '<script>'"),
    ],
)
def test_bad_form_input_is_refused_with_a_reason(settings, pairs, message):
    with pytest.raises(ConfigError, match=re.escape(message)):
        parse_form(settings, pairs, DEFAULT_CONFIG)


def test_every_problem_of_a_form_is_reported_at_once(settings):
    with pytest.raises(ConfigError) as info:
        parse_form(settings, [("quality", "99"), ("vflip", "2"), ("x", "1")], DEFAULT_CONFIG)
    assert "quality" in str(info.value) and "vflip" in str(info.value) and "'x'" in str(info.value)


def test_setting_check_refuses_non_integers():
    setting = Setting("quality", "uint8", 0, 63)
    assert setting.check(True) is not None
    assert setting.check(1.0) is not None
    assert setting.check(63) is None
