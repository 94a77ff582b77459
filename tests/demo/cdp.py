"""A small headless-Chromium driver over the DevTools protocol (websocket-client), for the browser tests.

Debian's /usr/bin/chromium, never a downloaded browser. Just what the tests
need: open a page, evaluate JavaScript (awaiting promises), click at a point,
take a screenshot.
"""

from __future__ import annotations

import base64
import itertools
import json
import os
import shutil
import subprocess
import tempfile
import time
import urllib.request
from pathlib import Path

import websocket

CHROMIUM = "/usr/bin/chromium"
FLAGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update",
    "--disable-sync",
    "--disable-quic",
    "--disable-dev-shm-usage",
    "--window-size=1280,1400",
)


class BrowserError(RuntimeError):
    """Chromium failed, or a page's JavaScript threw."""


class Browser:
    """One headless Chromium with one page; use as a context manager."""

    def __init__(self, executable: str = CHROMIUM, timeout: float = 30.0) -> None:
        self.executable = executable
        self.timeout = timeout
        self._ids = itertools.count(1)
        self.console: list[str] = []

    def __enter__(self) -> Browser:
        self._profile = tempfile.mkdtemp(prefix="espdock-chromium-")
        self._process = subprocess.Popen(
            [self.executable, *FLAGS, f"--user-data-dir={self._profile}", "--remote-debugging-port=0", "about:blank"],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            # Its singleton socket's dir goes into TMPDIR, and a terminated Chromium leaves it
            # there: inside the profile, it goes with the profile.
            env={**os.environ, "TMPDIR": self._profile},
        )
        try:
            port = self._wait_for_port()
            targets = json.load(urllib.request.urlopen(f"http://127.0.0.1:{port}/json/list", timeout=5))
            page = next(t for t in targets if t.get("type") == "page")
            self._ws = websocket.create_connection(
                page["webSocketDebuggerUrl"], timeout=self.timeout, suppress_origin=True
            )
            self.call("Page.enable")
            self.call("Runtime.enable")
        except BaseException:
            self.__exit__(None, None, None)
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        ws = getattr(self, "_ws", None)
        if ws is not None:
            ws.close()
        self._process.terminate()
        try:
            self._process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            self._process.kill()
            self._process.wait()
        # Chromium's helper processes may still write a file or two after the browser exits.
        for _ in range(10):
            shutil.rmtree(self._profile, ignore_errors=True)
            time.sleep(0.2)
            if not Path(self._profile).exists():
                break

    def _wait_for_port(self) -> int:
        marker = Path(self._profile) / "DevToolsActivePort"
        deadline = time.monotonic() + self.timeout
        while time.monotonic() < deadline:
            if self._process.poll() is not None:
                raise BrowserError(f"{self.executable} exited with {self._process.returncode} at start")
            if marker.is_file():
                first = marker.read_text().splitlines()[:1]
                if first and first[0].isdigit():
                    return int(first[0])
            time.sleep(0.1)
        raise BrowserError(f"{self.executable} did not open its DevTools port within {self.timeout:g} s")

    def call(self, method: str, **params: object) -> dict:
        """Send one DevTools command and return its result (events in between are kept as console lines)."""
        call_id = next(self._ids)
        self._ws.send(json.dumps({"id": call_id, "method": method, "params": params}))
        while True:
            message = json.loads(self._ws.recv())
            if message.get("id") == call_id:
                if "error" in message:
                    raise BrowserError(f"{method}: {message['error']}")
                return message.get("result", {})
            if message.get("method") == "Runtime.consoleAPICalled":
                args = message["params"].get("args", [])
                self.console.append(" ".join(str(a.get("value", a.get("description", ""))) for a in args))
            elif message.get("method") == "Runtime.exceptionThrown":
                details = message["params"]["exceptionDetails"]
                self.console.append("exception: " + details.get("exception", {}).get("description", details["text"]))

    def open(self, url: str) -> None:
        """Navigate to URL and wait for its DOM (the page's streams never "finish" loading)."""
        self.call("Page.navigate", url=url)
        self.wait_for("document.readyState !== 'loading' && location.href.startsWith(" + json.dumps(url) + ")")

    def evaluate(self, expression: str) -> object:
        """The value of the JavaScript EXPRESSION (a promise is awaited)."""
        result = self.call("Runtime.evaluate", expression=expression, awaitPromise=True, returnByValue=True)
        if "exceptionDetails" in result:
            details = result["exceptionDetails"]
            raise BrowserError(details.get("exception", {}).get("description", details.get("text")))
        return result["result"].get("value")

    def wait_for(self, expression: str, timeout: float = 15.0, interval: float = 0.1) -> object:
        """Poll EXPRESSION until it is truthy; its value. Raises TimeoutError saying which condition failed."""
        deadline = time.monotonic() + timeout
        while True:
            value = self.evaluate(expression)
            if value:
                return value
            if time.monotonic() > deadline:
                raise TimeoutError(f"not true after {timeout:g} s: {expression}")
            time.sleep(interval)

    def click(self, selector: str) -> None:
        """A real mouse click in the middle of the element SELECTOR matches."""
        box = self.evaluate(
            f"(() => {{ const el = document.querySelector({json.dumps(selector)}); if (!el) return null;"
            " el.scrollIntoView({block: 'center'}); const r = el.getBoundingClientRect();"
            " return {x: r.x + r.width / 2, y: r.y + r.height / 2}; })()"
        )
        if not box:
            raise BrowserError(f"nothing on the page matches {selector}")
        for kind in ("mousePressed", "mouseReleased"):
            self.call("Input.dispatchMouseEvent", type=kind, x=box["x"], y=box["y"], button="left", clickCount=1)

    def set_value(self, selector: str, value: str) -> None:
        """Set the form field SELECTOR matches to VALUE and fire the input and change events a
        user's edit fires (assigning .value alone fires none, so the page would not know)."""
        done = self.evaluate(
            f"(() => {{ const el = document.querySelector({json.dumps(selector)}); if (!el) return false;"
            f" el.value = {json.dumps(value)};"
            " for (const kind of ['input', 'change']) el.dispatchEvent(new Event(kind, {bubbles: true}));"
            " return true; })()"
        )
        if not done:
            raise BrowserError(f"nothing on the page matches {selector}")

    def screenshot(self, path: Path) -> None:
        path.write_bytes(base64.b64decode(self.call("Page.captureScreenshot", format="png")["data"]))
