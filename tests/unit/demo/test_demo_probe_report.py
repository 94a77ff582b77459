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


def test_latency_runs_to_the_observers_reader_not_to_when_the_probe_read_it():
    leds = [{"hex": "#ff0000", "recv_ns": 90 * MS, "dds_ns": 6 * MS, "sent_ns": 5 * MS}]
    (change,) = follow_report([scene(0, "#ff0000")], leds)["changes"]
    assert (change["latency_ms"], change["led_sent_ms"]) == (6.0, 5.0)


def test_a_qr_text_read_after_its_led_change_but_received_before_it_is_a_hop_of_it():
    # The probe reads its readers every 0.1 s: in one read the colour's callback may run first.
    leds = [{"hex": "#ff0000", "recv_ns": 100 * MS, "dds_ns": 6 * MS, "sent_ns": 5 * MS}]
    qr_texts = [{"text": "#ff0000", "recv_ns": 101 * MS, "dds_ns": 4 * MS, "sent_ns": 3 * MS}]
    (change,) = follow_report([scene(0, "#ff0000")], leds, qr_texts=qr_texts)["changes"]
    assert change["qr_sent_ms"] == 3.0


def test_each_change_gets_when_the_detector_sent_its_text_and_none_where_the_observer_missed_it():
    scenes = [scene(0, "#ff0000"), scene(1000, "#00ff00")]
    leds = [
        {"hex": "#ff0000", "recv_ns": 7 * MS, "dds_ns": 6 * MS, "sent_ns": 5 * MS},
        {"hex": "#00ff00", "recv_ns": 1008 * MS, "dds_ns": 1007 * MS, "sent_ns": 1006 * MS},
    ]
    qr_texts = [{"text": "#ff0000", "recv_ns": 4 * MS, "sent_ns": 3 * MS}]  # the second text never came
    changes = follow_report(scenes, leds, qr_texts=qr_texts)["changes"]
    hops = [(c["qr_sent_ms"], c["led_sent_ms"], c["latency_ms"]) for c in changes]
    assert hops == [(3.0, 5.0, 6.0), (None, 6.0, 7.0)]


def test_a_qr_text_after_its_led_change_is_no_hop_of_it():
    changes = follow_report(
        [scene(0, "#ff0000")], [led(5, "#ff0000")], qr_texts=[{"text": "#ff0000", "recv_ns": 7 * MS, "sent_ns": 6 * MS}]
    )["changes"]
    assert changes[0]["qr_sent_ms"] is None
