"""The camera UI's web server (seed 7.3), without rclpy: page, MJPEG stream, live state, settings.

Routes:
  GET  /             the page (assets/page.html): stream, QR text, LED swatch, nodes, settings form
  GET  /app.js, /style.css  its script and stylesheet (assets/)
  GET  /stream.mjpg  the camera as multipart/x-mixed-replace MJPEG (a "no camera" frame while none arrive)
  GET  /snapshot.jpg the newest frame
  GET  /events       server-sent events: one `state` event per change (and every second)
  GET  /api/state    the same state as JSON
  POST /config       apply settings (form-encoded): validated here, then sent to the camera
  GET  /healthz      200 while the node spins
Everything rendered is escaped; every form field is checked for type and range
before the camera sees it, and bad input gets 400 with a message saying why.
"""

from __future__ import annotations

import functools
import html
import json
import string
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from http import HTTPStatus
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from importlib import resources
from typing import Protocol
from urllib.parse import parse_qsl, urlsplit

from espdock_demo.camera_config import (
    DEFAULT_CONFIG,
    FRAME_SIZES,
    ConfigError,
    Setting,
    frame_size_name,
    parse_form,
)
from espdock_demo.colors import Rgb
from espdock_demo.mjpeg import CONTENT_TYPE as MJPEG_CONTENT_TYPE
from espdock_demo.mjpeg import FrameBroadcaster, jpeg_size, multipart_chunk

_MAX_FORM_BYTES = 16 * 1024
_MAX_QR_SHOWN = 200


class CameraUnavailable(Exception):
    """The camera did not answer a service call; HTTP_STATUS says how (503 no service, 504 timed out)."""

    def __init__(self, message: str, http_status: int) -> None:
        super().__init__(message)
        self.http_status = http_status


@dataclass(frozen=True)
class SetResult:
    """The camera's answer to set_config: whether it applied the request, and its config now."""

    accepted: bool
    config: dict[str, int]


class Backend(Protocol):
    """What the web server needs from the ROS side."""

    def set_config(self, config: Mapping[str, int], timeout: float) -> SetResult:
        """Ask the camera to apply CONFIG; its answer, or CameraUnavailable."""

    def healthy(self) -> bool:
        """True while the node's executor runs."""


class LiveState:
    """What the page shows live (QR text, LED colour, camera config); ROS callbacks update it."""

    def __init__(self) -> None:
        self._cond = threading.Condition()
        self._version = 0
        self._values: dict[str, object] = {"qr": None, "led": None, "config": None}

    def update(self, **values: object) -> None:
        """Set VALUES and wake every watcher (cheap: callers are ROS callbacks)."""
        with self._cond:
            self._values.update(values)
            self._version += 1
            self._cond.notify_all()

    def get(self, key: str) -> object:
        with self._cond:
            return self._values.get(key)

    def wait(self, version: int, timeout: float) -> tuple[int, dict[str, object]]:
        """The state once it is newer than VERSION, or after TIMEOUT seconds: (version, values)."""
        with self._cond:
            self._cond.wait_for(lambda: self._version != version, timeout)
            return self._version, dict(self._values)


@dataclass
class UiApp:
    """Everything a request handler needs."""

    settings: tuple[Setting, ...]
    frames: FrameBroadcaster
    state: LiveState
    backend: Backend
    service_timeout: float = 3.0
    offline_after: float = 2.0
    stopping: threading.Event = field(default_factory=threading.Event)
    _placeholder: bytes | None = None

    def placeholder(self) -> bytes:
        """The "no camera" frame (rendered once)."""
        if self._placeholder is None:
            from espdock_demo.scene import placeholder_jpeg

            self._placeholder = placeholder_jpeg(320, 240, "no camera")
        return self._placeholder

    def camera_online(self) -> bool:
        age = self.frames.age()
        return age is not None and age < self.offline_after


def live_view(app: UiApp, values: Mapping[str, object] | None = None) -> dict[str, object]:
    """The page's live state as JSON-ready data."""
    if values is None:
        values = app.state.wait(-1, 0)[1]
    latest = app.frames.latest()
    size = jpeg_size(latest.data) if latest else None
    qr = values.get("qr")
    led = values.get("led")
    return {
        "camera": {
            "online": app.camera_online(),
            "fps": round(app.frames.rate(), 1),
            "width": size[0] if size else None,
            "height": size[1] if size else None,
            "frames": latest.seq if latest else 0,
        },
        "qr": None if qr is None else {"text": str(qr)[:_MAX_QR_SHOWN], "length": len(str(qr))},
        "led": None if not isinstance(led, Rgb) else {"hex": led.hex, "r": led.r, "g": led.g, "b": led.b},
        "config": values.get("config"),
        # {node: {"state": "ok" | "stale" | "not seen" | "missing", "silent_s": ...}} from the nodes' diagnostics.
        "nodes": values.get("nodes") or {},
    }


def address_to_open(url: str) -> str:
    """URL as a browser can open it: a UI published on every address (ESPDOCK_DEMO_BIND=0.0.0.0
    or ::) is reached at none of them by that name, so name this machine's own and say the rest."""
    parts = urlsplit(url)
    if parts.hostname not in ("0.0.0.0", "::"):
        return url
    local = "127.0.0.1" if parts.hostname == "0.0.0.0" else "[::1]"
    port = f":{parts.port}" if parts.port else ""
    return f"{parts.scheme}://{local}{port}{parts.path} (or this machine's address: the UI is published on every one)"


def make_server(host: str, port: int, app: UiApp) -> ThreadingHTTPServer:
    """A threading HTTP server for APP on HOST:PORT (not yet serving)."""
    server = ThreadingHTTPServer((host, port), _Handler)
    server.daemon_threads = True
    server.app = app  # type: ignore[attr-defined]
    return server


# ---------------------------------------------------------------- rendering


def _e(value: object) -> str:
    return html.escape(str(value), quote=True)


def render_control(setting: Setting, value: int) -> str:
    """The form control for SETTING showing VALUE: a menu, a toggle or a slider with its range."""
    name = _e(setting.name)
    label = _e(setting.label)
    disabled = " disabled" if setting.read_only else ""
    note = " <small>(the camera node always publishes JPEG)</small>" if setting.read_only else ""
    if setting.kind == "menu":
        options = "".join(
            f'<option value="{i}"{" selected" if i == value else ""}>{_e(choice)}</option>'
            for i, choice in enumerate(setting.choices)
            if setting.low <= i <= setting.high
        )
        return (
            f'<label class="menu">{label}{note}<select name="{name}" data-setting="{name}"{disabled}>'
            f"{options}</select></label>"
        )
    if setting.kind == "toggle":
        checked = " checked" if value else ""
        return (
            f'<label class="toggle"><input type="hidden" name="{name}" value="0">'
            f'<input type="checkbox" name="{name}" value="1" data-setting="{name}"{checked}{disabled}> '
            f"{label}</label>"
        )
    return (
        f'<label class="slider">{label} <output id="out-{name}">{_e(value)}</output>'
        f'<input type="range" name="{name}" data-setting="{name}" min="{setting.low}" max="{setting.high}" '
        f'step="1" value="{_e(value)}"{disabled}>'
        f'<span class="range">{setting.low} .. {setting.high}</span></label>'
    )


def render_page(app: UiApp, message: str = "", ok: bool = True) -> str:
    """The whole page, with MESSAGE (the result of a form post) shown when given."""
    view = live_view(app)
    config = view["config"] if isinstance(view["config"], dict) else None
    values = config or DEFAULT_CONFIG
    groups: dict[str, list[str]] = {"menu": [], "slider": [], "toggle": []}
    for setting in app.settings:
        groups[setting.kind].append(render_control(setting, int(values.get(setting.name, setting.low))))
    qr = view["qr"]
    led = view["led"]
    camera = view["camera"]
    camera_info = _e(f"{camera['width']}x{camera['height']}") if camera["width"] else "no frames yet"
    swatch = _e(led["hex"]) if led else "#000000"
    known = "" if config else '<p class="warn" id="config-unknown">The camera has not reported its settings yet.</p>'
    banner = (
        f'<div id="result" role="status" class="{"ok" if ok else "error"}">{_e(message)}</div>'
        if message
        else '<div id="result" role="status"></div>'
    )
    return _page().substitute(
        nocam_hidden="" if not camera["online"] else " hidden",
        offline_after=f"{app.offline_after:g}",
        camera_info=camera_info,
        qr_text=_e(qr["text"]) if qr else "(none yet)",
        swatch=swatch,
        led_hex=_e(led["hex"]) if led else "(unknown)",
        known=known,
        menus="".join(groups["menu"]),
        sliders="".join(groups["slider"]),
        toggles="".join(groups["toggle"]),
        banner=banner,
        config_json=_e(json.dumps(config, indent=1)) if config else "(unknown)",
        # JSON inside <script type="application/json">: "</" must not end the element.
        size_names=json.dumps([name for name, _, _ in FRAME_SIZES]).replace("</", "<\\/"),
    )


@functools.cache
def _asset(name: str) -> bytes:
    """A file of the page (assets/: page.html, style.css, app.js), read once."""
    return (resources.files("espdock_demo") / "assets" / name).read_bytes()


def _page() -> string.Template:
    return string.Template(_asset("page.html").decode())


# ---------------------------------------------------------------- HTTP

_SECURITY_HEADERS = (
    (
        "Content-Security-Policy",
        "default-src 'none'; img-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; "
        "connect-src 'self'; form-action 'self'; base-uri 'none'; frame-ancestors 'none'",
    ),
    ("X-Content-Type-Options", "nosniff"),
    ("Referrer-Policy", "no-referrer"),
)


class _Handler(BaseHTTPRequestHandler):
    server_version = "espdock-camera-ui"
    # A client that stops reading gets dropped after this many seconds, freeing its thread.
    timeout = 15

    @property
    def app(self) -> UiApp:
        return self.server.app  # type: ignore[attr-defined]

    def log_message(self, format: str, *args: object) -> None:
        pass  # the node logs what matters; per-request lines would drown it

    # -- responses

    def _send(self, status: int, body: bytes, content_type: str, extra: tuple[tuple[str, str], ...] = ()) -> None:
        self.send_response(status)
        self.send_header("Content-Type", content_type)
        self.send_header("Content-Length", str(len(body)))
        self.send_header("Cache-Control", "no-store")
        for name, value in (*_SECURITY_HEADERS, *extra):
            self.send_header(name, value)
        self.end_headers()
        if self.command != "HEAD":
            self.wfile.write(body)

    def _json(self, status: int, data: object) -> None:
        self._send(status, json.dumps(data).encode(), "application/json")

    def _text(self, status: int, text: str) -> None:
        self._send(status, text.encode(), "text/plain; charset=utf-8")

    def _html(self, status: int, text: str) -> None:
        self._send(status, text.encode(), "text/html; charset=utf-8")

    def _start_stream(self, content_type: str) -> None:
        self.send_response(HTTPStatus.OK)
        self.send_header("Content-Type", content_type)
        self.send_header("Cache-Control", "no-store")
        self.send_header("Connection", "close")
        for name, value in _SECURITY_HEADERS:
            self.send_header(name, value)
        self.end_headers()

    # -- routes

    def do_GET(self) -> None:
        path = urlsplit(self.path).path
        routes: dict[str, Callable[[], None]] = {
            "/": lambda: self._html(HTTPStatus.OK, render_page(self.app)),
            "/app.js": lambda: self._send(HTTPStatus.OK, _asset("app.js"), "text/javascript; charset=utf-8"),
            "/style.css": lambda: self._send(HTTPStatus.OK, _asset("style.css"), "text/css; charset=utf-8"),
            "/stream.mjpg": self._stream,
            "/snapshot.jpg": self._snapshot,
            "/events": self._events,
            "/api/state": lambda: self._json(HTTPStatus.OK, live_view(self.app)),
            "/healthz": self._health,
        }
        route = routes.get(path)
        if route is None:
            self._text(HTTPStatus.NOT_FOUND, f"no page at {path[:100]}\n")
            return
        try:
            route()
        except (BrokenPipeError, ConnectionResetError, ConnectionAbortedError, TimeoutError):
            pass  # the client went away

    def do_HEAD(self) -> None:
        self.do_GET()

    def do_POST(self) -> None:
        if urlsplit(self.path).path != "/config":
            self._text(HTTPStatus.NOT_FOUND, "POST only to /config\n")
            return
        try:
            self._post_config()
        except (BrokenPipeError, ConnectionResetError, ConnectionAbortedError, TimeoutError):
            pass

    def _health(self) -> None:
        if self.app.backend.healthy():
            self._text(HTTPStatus.OK, "ok\n")
        else:
            self._text(HTTPStatus.SERVICE_UNAVAILABLE, "the ROS executor is not spinning\n")

    def _snapshot(self) -> None:
        latest = self.app.frames.latest()
        if latest is None or not self.app.camera_online():
            self._text(HTTPStatus.SERVICE_UNAVAILABLE, "no camera frames\n")
            return
        self._send(HTTPStatus.OK, latest.data, "image/jpeg")

    def _stream(self) -> None:
        app = self.app
        self._start_stream(MJPEG_CONTENT_TYPE)
        if self.command == "HEAD":
            return
        seq = 0
        last_placeholder = 0.0
        while not app.stopping.is_set():
            frame = app.frames.wait_newer(seq, timeout=0.5)
            if frame is not None:
                seq = frame.seq
                if app.camera_online():
                    self.wfile.write(multipart_chunk(frame.data))
                    continue
            now = time.monotonic()
            if not app.camera_online() and now - last_placeholder >= 1.0:
                self.wfile.write(multipart_chunk(app.placeholder()))
                last_placeholder = now

    def _events(self) -> None:
        app = self.app
        self._start_stream("text/event-stream")
        if self.command == "HEAD":
            return
        self.wfile.write(b"retry: 2000\n\n")
        version = -1
        last_key = None
        last_sent = 0.0
        while not app.stopping.is_set():
            version, values = app.state.wait(version, timeout=0.5)
            view = live_view(app, values)
            key = json.dumps(
                [
                    view["qr"],
                    view["led"],
                    view["config"],
                    view["camera"]["online"],
                    view["camera"]["width"],
                    view["camera"]["height"],
                ]
            )
            now = time.monotonic()
            if key != last_key or now - last_sent >= 1.0:
                self.wfile.write(f"event: state\ndata: {json.dumps(view)}\n\n".encode())
                last_key, last_sent = key, now

    def _post_config(self) -> None:
        wants_json = "application/json" in self.headers.get("Accept", "")

        def answer(status: int, message: str, config: dict[str, int] | None = None, ok: bool = False) -> None:
            if wants_json:
                self._json(status, {"ok": ok, "message": message, "config": config})
            else:
                self._html(status, render_page(self.app, message, ok))

        origin = self.headers.get("Origin")
        host = self.headers.get("Host", "")
        if origin and origin != "null" and urlsplit(origin).netloc != host:
            answer(HTTPStatus.FORBIDDEN, f"Refused: a form from {origin[:80]} may not change this camera.")
            return
        content_type = self.headers.get("Content-Type", "").split(";")[0].strip().lower()
        if content_type != "application/x-www-form-urlencoded":
            answer(HTTPStatus.UNSUPPORTED_MEDIA_TYPE, "Send the settings as application/x-www-form-urlencoded.")
            return
        try:
            length = int(self.headers.get("Content-Length", ""))
        except ValueError:
            answer(HTTPStatus.LENGTH_REQUIRED, "Content-Length is required.")
            return
        if not 0 <= length <= _MAX_FORM_BYTES:
            answer(HTTPStatus.REQUEST_ENTITY_TOO_LARGE, f"The form is larger than {_MAX_FORM_BYTES} bytes.")
            return
        body = self.rfile.read(length)
        try:
            pairs = parse_qsl(body.decode("ascii"), keep_blank_values=True, max_num_fields=200)
        except (UnicodeDecodeError, ValueError) as exc:
            answer(HTTPStatus.BAD_REQUEST, f"Invalid settings: the form is not readable ({exc}).")
            return
        current = self.app.state.get("config")
        try:
            config = parse_form(self.app.settings, pairs, current if isinstance(current, dict) else DEFAULT_CONFIG)
        except ConfigError as exc:
            answer(HTTPStatus.BAD_REQUEST, f"Invalid settings: {exc}.")
            return
        try:
            result = self.app.backend.set_config(config, self.app.service_timeout)
        except CameraUnavailable as exc:
            answer(exc.http_status, str(exc))
            return
        self.app.state.update(config=result.config)
        if result.accepted:
            size = frame_size_name(result.config.get("framesize", 0))
            answer(HTTPStatus.OK, f"The camera applied the settings ({size}).", result.config, ok=True)
        else:
            answer(
                HTTPStatus.UNPROCESSABLE_ENTITY,
                "The camera refused the settings and kept its configuration.",
                result.config,
            )
