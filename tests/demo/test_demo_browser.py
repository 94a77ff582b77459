"""The camera UI in headless Chromium: live frames, settings, the LED swatch."""

from __future__ import annotations

import time

import pytest

from cdp import Browser
from demo_support import FRAME_HASH, start_stack

pytestmark = [pytest.mark.engine, pytest.mark.slow]

SWATCH = "getComputedStyle(document.getElementById('swatch')).backgroundColor"


@pytest.fixture(scope="module")
def demo(request, demo_image):
    return start_stack(request, ESPDOCK_DEMO_PHASE_SECONDS="1.5")


@pytest.fixture(scope="module")
def browser(chromium):
    """One Chromium for the module (its start and stop are 2 s each time)."""
    with Browser(chromium) as browser:
        yield browser


@pytest.fixture
def page(demo, browser):
    """The UI freshly loaded: by way of a blank page, so no test sees another's document or edits."""
    browser.open("about:blank")
    browser.console.clear()
    browser.open(demo.url + "/")
    return browser


def distinct_frames(browser: Browser, seconds: float) -> int:
    """How many different pictures the stream showed in SECONDS."""
    seen = set()
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        seen.add(browser.evaluate(FRAME_HASH))
        time.sleep(0.05)
    seen.discard(None)
    return len(seen)


def hex_to_rgb(hex_color: str) -> str:
    r, g, b = (int(hex_color[i : i + 2], 16) for i in (1, 3, 5))
    return f"rgb({r}, {g}, {b})"


def test_the_page_shows_live_frames(page):
    page.wait_for("document.getElementById('stream').naturalWidth === 320")
    assert distinct_frames(page, 1.5) >= 10
    assert page.evaluate("document.getElementById('nocam').hidden") is True
    page.wait_for("document.getElementById('camera-info').textContent.startsWith('320x240 at')")


def test_the_picture_comes_back_after_the_ui_service_restarts(page, demo):
    """`espdock compose restart camera_ui`: the server's clean stop ended the stream as a finished
    picture, and the page went on showing that one frame (the settings and QR text still live)."""
    page.wait_for("document.getElementById('stream').naturalWidth === 320")
    assert distinct_frames(page, 1.0) >= 5
    demo.compose("restart", "-t", "5", "camera_ui")
    deadline = time.monotonic() + 60
    while distinct_frames(page, 1.0) < 5:
        assert time.monotonic() < deadline, "the stream did not come back after the restart"


def test_the_swatch_follows_the_led_colour(page):
    colours = []
    deadline = time.monotonic() + 15
    while len(colours) < 3 and time.monotonic() < deadline:
        hex_shown = page.evaluate("document.getElementById('led-hex').textContent")
        swatch = page.evaluate(SWATCH)
        if hex_shown.startswith("#") and swatch == hex_to_rgb(hex_shown) and hex_shown not in colours:
            colours.append(hex_shown)
        time.sleep(0.1)
    assert len(colours) >= 3, f"the swatch showed only {colours}"
    assert page.evaluate("document.getElementById('qr').textContent").startswith("#")


def test_a_setting_not_yet_applied_stays_as_the_user_set_it(page):
    """The page gets the camera's settings with every live update; that must not undo an edit."""
    page.wait_for("document.getElementById('config').textContent.includes('framesize')")
    page.click("input[type=checkbox][name=hmirror]")
    page.set_value("input[name=brightness]", "2")
    seen = {page.evaluate("document.getElementById('qr').textContent")}
    deadline = time.monotonic() + 15
    while len(seen) < 3 and time.monotonic() < deadline:  # two more QR codes: two more live updates
        seen.add(page.evaluate("document.getElementById('qr').textContent"))
        time.sleep(0.05)
    assert len(seen) >= 3, f"the page showed only {seen}"
    assert page.evaluate("document.querySelector('input[type=checkbox][name=hmirror]').checked") is True
    assert page.evaluate("document.querySelector('input[name=brightness]').value") == "2"
    assert '"hmirror": 0' in page.evaluate("document.getElementById('config').textContent"), "nothing was applied"


def test_changing_a_setting_in_the_page_changes_the_stream(page):
    page.wait_for("document.getElementById('stream').naturalWidth === 320")
    # Pick VGA from the frame size menu and turn on the mirror toggle, then press Apply.
    page.set_value("select[name=framesize]", "10")
    page.click("input[type=checkbox][name=hmirror]")
    assert page.evaluate("document.querySelector('input[type=checkbox][name=hmirror]').checked") is True
    page.click("#apply")
    message = page.wait_for(
        "(() => { const r = document.getElementById('result'); return r.className === 'ok' && r.textContent; })()",
        timeout=10,
    )
    assert "applied" in message and "framesize VGA" in message and "hmirror 1" in message
    page.wait_for("document.getElementById('stream').naturalWidth === 640", timeout=10)
    assert page.evaluate("document.getElementById('stream').naturalHeight") == 480
    assert distinct_frames(page, 1.0) >= 5
    assert '"framesize": 10' in page.evaluate("document.getElementById('config').textContent")

    # Back to QVGA without the mirror, so the other tests see the default.
    page.set_value("select[name=framesize]", "6")
    page.click("input[type=checkbox][name=hmirror]")
    page.click("#apply")
    page.wait_for("document.getElementById('stream').naturalWidth === 320", timeout=10)
    assert not any("exception" in line.lower() for line in page.console), page.console
