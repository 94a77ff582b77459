"""NodeHealth: which demo nodes report, which went silent, what to say when that changes."""

from __future__ import annotations

from espdock_demo.health import NodeHealth


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


def test_nodes_are_not_seen_then_ok_then_stale_then_back():
    clock = Clock()
    health = NodeHealth(["/qr_detector", "/camera_sim"], stale_after=3.0, clock=clock)
    start = health.report()
    assert start["/qr_detector"]["state"] == "not seen"
    health.seen("/qr_detector")
    clock.now += 1
    up = health.report()
    assert up["/qr_detector"] == {"state": "ok", "silent_s": 1.0}
    assert health.changes(start, up) == ["qr_detector is up"]
    clock.now += 4.5
    stale = health.report()
    assert stale["/qr_detector"] == {"state": "stale", "silent_s": 5.5}
    assert health.changes(up, stale) == ["qr_detector is down or stuck: no diagnostics for 6 s"]
    health.seen("/qr_detector")
    back = health.report()
    assert health.changes(stale, back) == ["qr_detector is back"]
    assert health.changes(back, health.report()) == []


def test_an_unexpected_node_that_reports_is_listed_too():
    health = NodeHealth([], clock=Clock())
    health.seen("/probe")
    assert health.report() == {"/probe": {"state": "ok", "silent_s": 0.0}}


def test_a_node_never_seen_for_half_a_minute_is_said_to_be_down_with_where_its_log_is():
    """A node that cannot start (a bad ESPDOCK_DEMO_COLORS) restarts in a loop and never reports: the
    console said nothing of it, and the UI "not seen yet" for as long as the demo ran."""
    clock = Clock()
    health = NodeHealth(["/camera_sim", "/qr_detector"], clock=clock)
    health.seen("/qr_detector")
    clock.now += 29
    health.seen("/qr_detector")
    before = health.report()
    assert before["/camera_sim"]["state"] == "not seen"
    clock.now += 2
    after = health.report()
    assert after["/camera_sim"] == {"state": "missing", "silent_s": 31.0}
    assert health.changes(before, after) == [
        "camera_sim is down: not up 31 s after the demo started; `docker compose logs camera_sim` says why"
    ]
    health.seen("/camera_sim")
    assert health.changes(after, health.report()) == ["camera_sim is up"]
