"""Faults: a crashed node comes back by itself; a camera that goes away shows as such and comes back."""

from __future__ import annotations

import http.client
import time

import pytest

from cdp import Browser
from demo_stack import StackError
from demo_support import FRAME_HASH, start_stack
from espdock_demo.mjpeg import jpeg_size

pytestmark = [pytest.mark.engine, pytest.mark.slow]


@pytest.fixture(scope="module")
def demo(request, demo_image):
    return start_stack(request, ESPDOCK_DEMO_PHASE_SECONDS="1.5")


def breaks(*services: str):
    """The services a test breaks on purpose: the only ones Docker may restart meanwhile."""

    def mark(test):
        test.breaks = services
        return test

    return mark


@pytest.fixture(autouse=True)
def only_the_broken_service_restarts(request, demo):
    """A fault in one node must not take down another (the monitor once crashed on every
    node that went down, and Docker's restart hid it)."""
    before = demo.restart_counts()
    yield
    after = demo.restart_counts()
    allowed = getattr(request.function, "breaks", ())
    restarted = {name: after[name] - before.get(name, 0) for name in after if after[name] > before.get(name, 0)}
    assert set(restarted) <= set(allowed), f"restarted besides {allowed or 'nothing'}: {restarted}"


@breaks("qr_detector")
def test_a_crashed_qr_detector_comes_back_and_the_led_follows_again(demo):
    assert demo.probe("follow", "--changes", "1", "--timeout", "20")["ok"]
    restarts = demo.restart_count("qr_detector")
    demo.crash("qr_detector")
    demo.wait_until(lambda: demo.restart_count("qr_detector") > restarts, 30, "qr_detector restarted")
    report = demo.probe("follow", "--changes", "3", "--timeout", "30")
    assert report["ok"] and len({c["hex"] for c in report["changes"]}) >= 3, report
    # Docker's first healthcheck of the new container comes an interval after its start: by now, mostly.
    demo.wait_until(lambda: demo.health("qr_detector") == "healthy", 60, "qr_detector healthy again")


def node_pid(demo, service: str, program: str) -> int:
    """The host PID of SERVICE's node process (not its demo_watchdog parent, whose argv names it too)."""
    import subprocess

    top = subprocess.run(["docker", "top", demo.container(service), "-eo", "pid,args"],
                         capture_output=True, text=True, check=True).stdout.splitlines()[1:]  # fmt: skip
    pids = [int(line.split()[0]) for line in top if program in line and "demo_watchdog" not in line]
    assert len(pids) == 1, top
    return pids[0]


@breaks("qr_detector")
def test_a_stuck_qr_detector_is_restarted_and_the_ui_says_so_meanwhile(demo):
    """SIGSTOP freezes the node (every thread of it): healthcheck-unhealthy alone would never recover."""
    import os
    import signal

    assert demo.probe("follow", "--changes", "1", "--timeout", "20")["ok"]
    restarts = demo.restart_count("qr_detector")
    stopped_at = time.monotonic()
    os.kill(node_pid(demo, "qr_detector", "qr_detector"), signal.SIGSTOP)
    demo.wait_until(lambda: demo.state()["nodes"].get("/qr_detector", {}).get("state") == "stale", 15,
                    "the UI reporting qr_detector as down or stuck")  # fmt: skip
    reported = time.monotonic() - stopped_at
    demo.wait_until(lambda: demo.restart_count("qr_detector") > restarts, 30, "qr_detector restarted")
    report = demo.probe("follow", "--changes", "2", "--timeout", "60")
    recovered = time.monotonic() - stopped_at
    assert report["ok"] and len({c["hex"] for c in report["changes"]}) >= 2, report
    assert demo.state()["nodes"]["/qr_detector"]["state"] == "ok"
    print(
        f"stuck qr_detector: reported stale after {reported:.1f} s, LED following new colours again "
        f"{recovered:.1f} s after the SIGSTOP (bound: 15 s to report, 30 s to restart, 60 s to follow)"
    )


def first_stream_part(demo) -> bytes:
    conn = http.client.HTTPConnection("127.0.0.1", demo.port, timeout=10)
    conn.request("GET", "/stream.mjpg")
    response = conn.getresponse()
    while True:
        line = response.fp.readline()
        if line.startswith(b"Content-Length:"):
            length = int(line.split(b":")[1])
            response.fp.readline()
            part = response.fp.read(length)
            conn.close()
            return part


@breaks("camera_sim")
def test_the_ui_shows_no_camera_while_it_is_gone_and_recovers_by_itself(demo, chromium):
    with Browser(chromium) as page:
        page.open(demo.url + "/")
        page.wait_for("document.getElementById('stream').naturalWidth === 320")
        demo.compose("stop", "camera_sim")
        try:
            page.wait_for("!document.getElementById('nocam').hidden", timeout=10)
            assert page.evaluate("document.getElementById('camera-info').textContent") == "no camera"
            assert demo.state()["camera"]["online"] is False
            assert demo.http("/snapshot.jpg")[0] == 503
            # The stream itself says so too, for clients without the page's script.
            assert jpeg_size(first_stream_part(demo)) == (320, 240)
            # The UI node itself is fine.
            assert demo.checked_health("camera_ui") == "healthy"
        finally:
            demo.compose("start", "camera_sim")
        page.wait_for("document.getElementById('nocam').hidden", timeout=30)
        first = page.wait_for(FRAME_HASH, timeout=10)
        page.wait_for(f"(() => {{ const h = {FRAME_HASH}; return h !== null && h !== {first}; }})()", timeout=10)
    try:
        demo.wait_until(lambda: demo.state()["camera"]["online"], 10, "camera online in /api/state")
    except StackError:
        pytest.fail(f"the UI did not see the camera come back: {demo.state()}")


@breaks("camera_sim")
def test_settings_for_a_camera_that_does_not_answer_end_in_a_clear_error(demo):
    demo.freeze("camera_sim")  # there, but stopped: the service call times out
    try:
        started = time.monotonic()
        status, answer = demo.post_settings(quality=20)
        waited = time.monotonic() - started
    finally:
        demo.thaw("camera_sim")
    assert status == 504 and "did not answer within 3 s" in answer["message"]
    assert 2.5 < waited < 6
    demo.compose("stop", "camera_sim")  # gone: no service at all
    try:
        demo.wait_until(lambda: demo.post_settings(quality=20)[0] == 503, 15, "set_config seen as unavailable")
        assert "not available" in demo.post_settings(quality=20)[1]["message"]
    finally:
        demo.compose("start", "camera_sim")
    demo.wait_until(lambda: demo.post_settings(quality=10)[0] == 200, 30, "the camera answering again")


@breaks("led_strip_sim", "camera_ui", "camera_sim")  # camera_sim: its watchdog, thawed, finds it stale
def test_nodes_restarted_while_one_code_stays_in_view_show_it(demo):
    """qr_detector publishes a text when it changes: an LED strip restarted while one code stayed
    in view stayed dark, next to the code in the UI, and a restarted UI said "(none yet)"."""
    assert demo.probe("follow", "--changes", "1", "--timeout", "20")["ok"]
    demo.freeze("camera_sim")  # the scene stands still: no new text
    try:
        time.sleep(1)  # what the last frames said has been said
        shown = demo.wait_until(lambda: (demo.state()["qr"] or {}).get("text"), 10, "a code in the UI")
        led = demo.state()["led"]["hex"]
        for service in ("led_strip_sim", "camera_ui"):
            restarts = demo.restart_count(service)
            demo.crash(service)
            demo.wait_until(lambda s=service, r=restarts: demo.restart_count(s) > r, 30, f"{service} restarted")

        def ui_text() -> str | None:
            try:
                return (demo.state()["qr"] or {}).get("text")
            except (StackError, OSError):  # the UI still starting
                return None

        demo.wait_until(lambda: ui_text() == shown, 60, f"the UI showing {shown} again")
        demo.wait_until(lambda: demo.probe("led")["led"] == led, 20, f"the LED strip showing {led} again")
    finally:
        demo.thaw("camera_sim")
