"""The camera UI's HTTP side, against a hand-written fake camera (the ROS edge), on a real socket."""

from __future__ import annotations

import http.client
import json
import threading
import time
import urllib.parse

import pytest

from demo_unit_support import require

require("PIL")
require("segno")

from espdock_demo.camera_config import DEFAULT_CONFIG  # noqa: E402
from espdock_demo.colors import Rgb  # noqa: E402
from espdock_demo.mjpeg import BOUNDARY, FrameBroadcaster  # noqa: E402
from espdock_demo.web import CameraUnavailable, LiveState, SetResult, UiApp, address_to_open, make_server  # noqa: E402


class FakeCamera:
    """Answers set_config like camera_sim (or not at all, or refusing), recording the requests."""

    def __init__(self) -> None:
        self.requests: list[dict] = []
        self.mode = "accept"
        self.alive = True

    def set_config(self, config, timeout):
        self.requests.append(dict(config))
        if self.mode == "timeout":
            raise CameraUnavailable(f"The camera did not answer within {timeout:g} s.", 504)
        if self.mode == "refuse":
            return SetResult(False, dict(DEFAULT_CONFIG))
        return SetResult(True, dict(config))

    def healthy(self):
        return self.alive


@pytest.fixture
def ui(settings):
    camera = FakeCamera()
    app = UiApp(settings, FrameBroadcaster(), LiveState(), camera, service_timeout=0.5, offline_after=0.5)
    server = make_server("127.0.0.1", 0, app)
    thread = threading.Thread(target=server.serve_forever, kwargs={"poll_interval": 0.1}, daemon=True)
    thread.start()
    yield app, camera, server.server_address[1]
    app.stopping.set()
    app.frames.close()
    server.shutdown()
    server.server_close()


def request(port, method, path, body=None, headers=None):
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
    conn.request(method, path, body=body, headers=headers or {})
    response = conn.getresponse()
    data = response.read()
    conn.close()
    return response.status, response.getheader("Content-Type"), data


def post_form(port, pairs, accept="application/json", **headers):
    body = urllib.parse.urlencode(pairs)
    return request(
        port,
        "POST",
        "/config",
        body,
        {"Content-Type": "application/x-www-form-urlencoded", "Accept": accept, **headers},
    )


def test_the_page_has_a_control_per_setting_with_its_range(ui, settings):
    app, _, port = ui
    app.state.update(config={**DEFAULT_CONFIG, "quality": 12})
    status, content_type, body = request(port, "GET", "/")
    page = body.decode()
    assert status == 200 and content_type.startswith("text/html")
    for setting in settings:
        assert f'data-setting="{setting.name}"' in page
    assert page.count("<option") == 16 + 7 + 5 + 7 + 9
    assert 'name="quality" data-setting="quality" min="0" max="63" step="1" value="12"' in page
    assert 'name="brightness" data-setting="brightness" min="-2" max="2"' in page
    assert '<input type="hidden" name="vflip" value="0"><input type="checkbox" name="vflip" value="1"' in page
    assert '<img id="stream" src="/stream.mjpg"' in page


def test_everything_shown_is_escaped(ui):
    app, _, port = ui
    app.state.update(qr='<script>alert("x")</script>', led=Rgb(1, 2, 3))
    page = request(port, "GET", "/")[2].decode()
    assert "<script>alert" not in page
    assert "&lt;script&gt;alert(&quot;x&quot;)&lt;/script&gt;" in page
    status, _, body = request(port, "GET", "/api/state")
    assert status == 200
    assert json.loads(body)["qr"]["text"] == '<script>alert("x")</script>'
    assert json.loads(body)["led"]["hex"] == "#010203"


def test_a_huge_qr_text_is_cut_for_display(ui):
    app, _, port = ui
    app.state.update(qr="#" + "f" * 999_999)
    state = json.loads(request(port, "GET", "/api/state")[2])
    assert len(state["qr"]["text"]) == 200 and state["qr"]["length"] == 1_000_000
    assert len(request(port, "GET", "/")[2]) < 50_000


def test_valid_settings_go_to_the_camera_and_its_answer_comes_back(ui):
    app, camera, port = ui
    app.state.update(config={**DEFAULT_CONFIG, "quality": 20})
    status, _, body = post_form(port, [("framesize", "10"), ("hmirror", "0"), ("hmirror", "1")])
    answer = json.loads(body)
    assert status == 200 and answer["ok"] is True
    assert camera.requests == [{**DEFAULT_CONFIG, "quality": 20, "framesize": 10, "hmirror": 1}]
    assert answer["config"]["framesize"] == 10 and "VGA" in answer["message"]
    assert app.state.get("config")["framesize"] == 10


@pytest.mark.parametrize(
    ("pairs", "message"),
    [
        ([("quality", "64")], "quality must be in 0..63, got 64"),
        ([("framesize", "x")], "framesize must be an integer, got 'x'"),
        ([("bogus", "1")], "unknown setting 'bogus'"),
    ],
)
def test_bad_settings_get_400_with_the_reason_and_never_reach_the_camera(ui, pairs, message):
    _, camera, port = ui
    status, _, body = post_form(port, pairs)
    assert status == 400 and message in json.loads(body)["message"]
    status, content_type, body = post_form(port, pairs, accept="text/html")
    assert status == 400 and content_type.startswith("text/html") and message.replace("'", "&#x27;") in body.decode()
    assert camera.requests == []


def test_malformed_requests_are_refused(ui):
    _, camera, port = ui
    assert request(port, "POST", "/config", "{}", {"Content-Type": "application/json"})[0] == 415
    too_big = "quality=1&" * 3000
    assert request(port, "POST", "/config", too_big, {"Content-Type": "application/x-www-form-urlencoded"})[0] == 413
    assert (
        request(
            port,
            "POST",
            "/config",
            b"quality=\xff",
            {"Content-Type": "application/x-www-form-urlencoded", "Accept": "application/json"},
        )[0]
        == 400
    )
    assert post_form(port, [("quality", "1")], Origin="http://evil.example")[0] == 403
    assert request(port, "POST", "/elsewhere", "a=1")[0] == 404
    assert camera.requests == []


def test_a_camera_that_does_not_answer_gives_504_with_a_message(ui):
    _, camera, port = ui
    camera.mode = "timeout"
    status, _, body = post_form(port, [("quality", "5")])
    assert status == 504 and "did not answer" in json.loads(body)["message"]


def test_a_camera_that_refuses_keeps_its_config(ui):
    _, camera, port = ui
    camera.mode = "refuse"
    status, _, body = post_form(port, [("quality", "5")])
    answer = json.loads(body)
    assert status == 422 and answer["ok"] is False and answer["config"] == DEFAULT_CONFIG


def read_parts(port, count, timeout=5.0):
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=timeout)
    conn.request("GET", "/stream.mjpg")
    response = conn.getresponse()
    assert response.getheader("Content-Type") == f"multipart/x-mixed-replace; boundary={BOUNDARY}"
    parts = []
    while len(parts) < count:
        line = response.fp.readline()
        if line.startswith(b"Content-Length:"):
            length = int(line.split(b":")[1])
            response.fp.readline()
            parts.append(response.fp.read(length))
    conn.close()
    return parts


def test_the_stream_sends_the_frames_as_they_come(ui):
    app, _, port = ui
    stop = threading.Event()

    def camera():
        i = 0
        while not stop.is_set():
            app.frames.publish(b"\xff\xd8frame%d" % i)
            i += 1
            time.sleep(0.02)

    threading.Thread(target=camera, daemon=True).start()
    try:
        parts = read_parts(port, 5)
    finally:
        stop.set()
    numbers = [int(p[len(b"\xff\xd8frame") :]) for p in parts]
    assert numbers == sorted(numbers) and len(set(numbers)) == 5


def test_without_frames_the_stream_shows_no_camera_and_the_state_says_so(ui):
    import io

    from PIL import Image

    app, _, port = ui
    (part,) = read_parts(port, 1)
    assert Image.open(io.BytesIO(part)).size == (320, 240)
    assert json.loads(request(port, "GET", "/api/state")[2])["camera"]["online"] is False
    assert request(port, "GET", "/snapshot.jpg")[0] == 503
    app.frames.publish(b"\xff\xd8live")
    assert json.loads(request(port, "GET", "/api/state")[2])["camera"]["online"] is True
    assert request(port, "GET", "/snapshot.jpg")[2] == b"\xff\xd8live"


def test_events_push_each_change(ui):
    app, _, port = ui
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=5)
    conn.request("GET", "/events")
    response = conn.getresponse()
    assert response.getheader("Content-Type") == "text/event-stream"

    def next_state():
        while True:
            line = response.fp.readline()
            if line.startswith(b"data: "):
                return json.loads(line[6:])

    assert next_state()["led"] is None
    app.state.update(led=Rgb(0x11, 0xAA, 0xFF))
    deadline = time.monotonic() + 3
    while time.monotonic() < deadline:
        state = next_state()
        if state["led"]:
            break
    conn.close()
    assert state["led"]["hex"] == "#11aaff"


def test_health_follows_the_executor(ui):
    _, camera, port = ui
    assert request(port, "GET", "/healthz")[0] == 200
    camera.alive = False
    assert request(port, "GET", "/healthz")[0] == 503
    assert request(port, "GET", "/nothing")[0] == 404


@pytest.mark.parametrize(
    ("published", "opened"),
    [
        ("http://127.0.0.1:8080", "http://127.0.0.1:8080"),
        ("http://192.168.1.20:9000", "http://192.168.1.20:9000"),
        ("http://0.0.0.0:8080", "http://127.0.0.1:8080 (or this machine's address"),
        ("http://[::]:8081", "http://[::1]:8081 (or this machine's address"),
    ],
)
def test_the_console_names_an_address_a_browser_opens(published, opened):
    """ESPDOCK_DEMO_BIND=0.0.0.0 made the console say `open http://0.0.0.0:8080`: no address to open."""
    assert address_to_open(published).startswith(opened)
