"""camera_sim's scene and qr_detector's decoding, together: what the camera shows, the detector reads."""

import io

import pytest

from demo_unit_support import require

require("PIL")
require("segno")
require("pyzbar.pyzbar")

from PIL import Image  # noqa: E402

from espdock_demo.camera_config import DEFAULT_CONFIG, FRAMESIZE_QVGA  # noqa: E402
from espdock_demo.mjpeg import jpeg_size  # noqa: E402
from espdock_demo.qr import ChangeFilter, FrameResult, Outcome, ZbarQrDecoder, decode_frame  # noqa: E402
from espdock_demo.scene import SceneRenderer, jpeg_quality, placeholder_jpeg, qr_image  # noqa: E402


@pytest.fixture
def renderer():
    return SceneRenderer()


def frame(renderer, payload="#ff0000", **config):
    return renderer.frame(payload, {**DEFAULT_CONFIG, **config}, 7)


def pixels(jpeg):
    return Image.open(io.BytesIO(jpeg)).convert("RGB")


@pytest.mark.parametrize("framesize", [1, 3, FRAMESIZE_QVGA, 10, 15])
def test_the_detector_reads_the_code_the_camera_shows_at_every_common_size(renderer, framesize):
    result = decode_frame(frame(renderer, "#00ff7f", framesize=framesize))
    assert result == FrameResult(Outcome.CODE, text="#00ff7f")


def grey(jpeg):
    return Image.open(io.BytesIO(jpeg)).convert("L")


def test_the_cameras_frames_are_read_by_the_coarse_scan_alone(renderer):
    decoder = ZbarQrDecoder()
    for text in ("#00ff7f", "#1af", "#123456"):
        assert decoder.scan(decoder.coarse, grey(frame(renderer, text))) == [("QRCODE", text.encode())]


def test_a_code_too_small_for_the_coarse_scan_is_read_by_the_full_one():
    decoder = ZbarQrDecoder()
    picture = Image.new("L", (320, 240), 128)
    picture.paste(qr_image("#00ff7f", scale=2).convert("L"), (40, 30))  # 2-pixel modules
    assert decoder.scan(decoder.coarse, picture) == []
    assert decoder(picture) == [("QRCODE", b"#00ff7f")]


def test_short_texts_are_full_qr_codes_not_micro_qr(renderer):
    # segno.make would pick a Micro QR code for "#1af", which zbar cannot read.
    assert decode_frame(frame(renderer, "#1af")).text == "#1af"


def test_framesize_sets_the_resolution(renderer):
    assert jpeg_size(frame(renderer, framesize=FRAMESIZE_QVGA)) == (320, 240)
    assert jpeg_size(frame(renderer, framesize=10)) == (640, 480)
    assert jpeg_size(frame(renderer, framesize=0)) == (96, 96)


def test_quality_changes_the_jpeg_size(renderer):
    best, worst = frame(renderer, quality=0), frame(renderer, quality=63)
    assert len(best) > 1.5 * len(worst)
    assert jpeg_quality(0) > jpeg_quality(10) > jpeg_quality(63)


def test_hmirror_and_vflip_flip_the_picture(renderer):
    plain = pixels(frame(renderer, "#ff0000"))
    mirrored = pixels(frame(renderer, "#ff0000", hmirror=1))
    flipped = pixels(frame(renderer, "#ff0000", vflip=1))
    # The picture's top-left module area moves to the top-right (mirror) or bottom-left (flip).
    width, _ = plain.size
    box = (width // 2 - 60, 20, width // 2 - 30, 50)
    mirror_box = (width - box[2], box[1], width - box[0], box[3])
    assert plain.crop(box).tobytes() != mirrored.crop(box).tobytes()
    assert _close(plain.crop(box), mirrored.crop(mirror_box).transpose(Image.FLIP_LEFT_RIGHT))
    assert _mean(plain.crop((0, 0, width, 20))) != pytest.approx(_mean(flipped.crop((0, 0, width, 20))), abs=10)


def test_brightness_and_colorbar_show(renderer):
    assert _mean(pixels(frame(renderer, brightness=2))) > _mean(pixels(frame(renderer))) + 20
    bars = pixels(frame(renderer, colorbar=1))
    width, height = bars.size
    assert bars.getpixel((width // 16, height // 2))[0] > 200  # white bar first
    assert max(bars.getpixel((width - width // 16, height // 2))) < 60  # black bar last
    assert decode_frame(frame(renderer, colorbar=1)).outcome is Outcome.NO_CODE


def test_a_blank_phase_has_no_code(renderer):
    assert decode_frame(frame(renderer, None)).outcome is Outcome.NO_CODE


def test_frames_move_even_when_the_scene_does_not(renderer):
    config = dict(DEFAULT_CONFIG)
    assert renderer.frame("#fff", config, 1) != renderer.frame("#fff", config, 2)


@pytest.mark.parametrize(
    ("data", "outcome"),
    [
        (b"", Outcome.EMPTY),
        (b"\xff\xd8\xff\xe0 not a jpeg" * 20, Outcome.CORRUPT),
        (b"hello", Outcome.CORRUPT),
    ],
)
def test_bad_frames_are_reported_not_raised(data, outcome):
    assert decode_frame(data).outcome is outcome


def test_a_truncated_jpeg_is_corrupt_or_codeless_never_an_exception(renderer):
    data = frame(renderer)
    for cut in (10, 100, 600, len(data) // 2):
        assert decode_frame(data[:cut]).outcome in (Outcome.CORRUPT, Outcome.NO_CODE)


def test_a_huge_declared_picture_is_refused_before_decoding():
    header = io.BytesIO()
    Image.new("L", (8, 8)).save(header, "JPEG")
    data = bytearray(header.getvalue())
    sof = data.index(b"\xff\xc0")
    data[sof + 5 : sof + 9] = (60000).to_bytes(2, "big") * 2
    assert decode_frame(bytes(data)).outcome is Outcome.CORRUPT


def test_a_code_that_is_not_utf8_is_reported():
    result = decode_frame(placeholder_jpeg(64, 64, "x"), decoder=lambda image: [("QRCODE", b"\xff\xfe\xfd")])
    assert result.outcome is Outcome.NOT_UTF8 and result.raw == b"\xff\xfe\xfd"


def test_the_filter_passes_only_changes_and_counts_everything():
    f = ChangeFilter()
    seen = [
        f.feed(r)
        for r in (
            FrameResult(Outcome.CODE, "#f00"),
            FrameResult(Outcome.CODE, "#f00"),
            FrameResult(Outcome.NO_CODE),
            FrameResult(Outcome.CODE, "#f00"),
            FrameResult(Outcome.CORRUPT),
            FrameResult(Outcome.CODE, "#0f0"),
        )
    ]
    assert seen == ["#f00", None, None, None, None, "#0f0"]
    assert f.counts == {"code": 4, "no_code": 1, "empty": 0, "corrupt": 1, "not_utf8": 0}


def _mean(image):
    data = image.convert("L").tobytes()
    return sum(data) / len(data)


def _close(a, b):
    return abs(_mean(a) - _mean(b)) < 8
