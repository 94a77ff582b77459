import pytest

from espdock_demo.colors import OFF, Rgb, parse_hex_color, shorten


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("#ff0000", Rgb(255, 0, 0)),
        ("#00FF7f", Rgb(0, 255, 127)),
        ("#1af", Rgb(0x11, 0xAA, 0xFF)),
        ("#000", OFF),
        ("#FFF", Rgb(255, 255, 255)),
    ],
)
def test_hex_codes_give_their_colour(text, expected):
    assert parse_hex_color(text) == expected


@pytest.mark.parametrize(
    "text",
    [
        "#GGG",
        "#12345",
        "hello",
        "",
        "#",
        "#1234",
        "#1234567",
        "ff0000",
        " #fff",
        "#fff ",
        "#fff\n",
        "#ff00gg",
        "#\u0661\u0662\u0663",  # Arabic-Indic digits are digits, not hex digits
        "#" + "f" * 999_999,
    ],
)
def test_anything_else_is_not_a_colour(text):
    assert parse_hex_color(text) is None


def test_rgb_converts_to_and_from_colorrgba_floats():
    color = Rgb(0x11, 0xAA, 0xFF)
    assert color.hex == "#11aaff"
    assert Rgb.from_floats(*color.as_floats()) == color
    assert Rgb.from_floats(1.5, -0.2, 0.5) == Rgb(255, 0, 128)


def test_long_text_is_shortened_for_logs():
    assert shorten("#fff") == "'#fff'"
    line = shorten("x" * 1_000_000)
    assert len(line) < 100 and "1000000 characters" in line
