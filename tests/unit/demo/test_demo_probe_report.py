"""demo_probe's follow report: which scene changes the LED followed, how fast, and which it missed."""

from __future__ import annotations

from espdock_demo_testing.report import follow_report

MS = 1_000_000


def scene(t_ms: int, text: str) -> dict:
    return {"stamp_ns": t_ms * MS, "text": text}


def led(t_ms: int, hex_color: str) -> dict:
    return {"recv_ns": t_ms * MS, "hex": hex_color}


def test_each_new_colour_is_paired_with_the_led_change_after_it():
    scenes = [scene(0, "#ff0000"), scene(1000, "#00ff00"), scene(2000, "hello"), scene(3000, "#0f0")]
    leds = [led(50, "#ff0000"), led(1020, "#00ff00")]
    report = follow_report(scenes, leds)
    assert [(c["hex"], c["latency_ms"]) for c in report["changes"]] == [("#ff0000", 50.0), ("#00ff00", 20.0)]
    assert report["missed"] == []  # "hello" is no colour, #0f0 repeats the colour shown


def test_an_led_change_before_its_scene_or_far_after_the_next_does_not_count():
    scenes = [scene(1000, "#ff0000"), scene(2000, "#0000ff")]
    leds = [led(900, "#ff0000"), led(5000, "#0000ff")]
    report = follow_report(scenes, leds)
    assert [m["text"] for m in report["missed"]] == ["#ff0000"]
    assert [c["hex"] for c in report["changes"]] == ["#0000ff"]  # the last scene has no deadline


def test_scenes_before_since_are_left_out():
    report = follow_report([scene(0, "#ff0000"), scene(1000, "#00ff00")], [led(1010, "#00ff00")], since_ns=500 * MS)
    assert [c["hex"] for c in report["changes"]] == ["#00ff00"]


def test_each_change_gets_its_hops_and_none_where_the_observer_missed_a_message():
    scenes = [scene(0, "#ff0000"), scene(1000, "#00ff00")]
    leds = [led(5, "#ff0000"), led(1006, "#00ff00")]
    frames = {0: 1 * MS}  # the second change's frame never reached the observer (best effort)
    qr_texts = [{"text": "#ff0000", "recv_ns": 4 * MS}, {"text": "#00ff00", "recv_ns": 1004 * MS}]
    changes = follow_report(scenes, leds, frames=frames, qr_texts=qr_texts)["changes"]
    assert [(c["frame_ms"], c["qr_ms"], c["latency_ms"]) for c in changes] == [(1.0, 4.0, 5.0), (None, 4.0, 6.0)]


def test_a_qr_text_after_its_led_change_is_no_hop_of_it():
    changes = follow_report(
        [scene(0, "#ff0000")], [led(5, "#ff0000")], frames={}, qr_texts=[{"text": "#ff0000", "recv_ns": 7 * MS}]
    )["changes"]
    assert changes[0]["qr_ms"] is None
