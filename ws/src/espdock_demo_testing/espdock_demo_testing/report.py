"""demo_probe's reports, without rclpy: pure functions of what the probe recorded."""

from __future__ import annotations

from espdock_demo.colors import parse_hex_color


def _ms(ns: int | None, since: int) -> float | None:
    return None if ns is None else (ns - since) / 1e6


def _arrived(message: dict) -> int:
    """When the observer's DDS reader got MESSAGE; its callback time where that is not known.
    (The probe reads its readers only now and then, so callback times say little.)"""
    return message.get("dds_ns", message["recv_ns"])


def follow_report(
    scenes: list[dict],
    leds: list[dict],
    since_ns: int = 0,
    qr_texts: list[dict] | None = None,
) -> dict:
    """Pair each scene change (stamped after SINCE_NS) that shows a new colour with the LED change that followed it.

    Each change's `latency_ms` runs from the camera's stamp to the LED colour reaching the
    observer's DDS reader (`dds_ns`; its callback time `recv_ns` where that is missing),
    and `led_sent_ms` to led_strip_sim publishing the colour (`sent_ns`). With QR_TEXTS (what
    the observer saw on /qr_message), `qr_sent_ms` is when qr_detector published that text:
    the frame's trip to the detector and its decoding. None where the observer did not see it.
    """
    changes, missed = [], []
    previous = None
    for i, scene in enumerate(scenes):
        if scene["stamp_ns"] < since_ns:
            continue
        text = scene.get("text")
        color = parse_hex_color(text) if isinstance(text, str) else None
        if color is None:
            continue
        if color.hex == previous:
            continue
        previous = color.hex
        stamp = scene["stamp_ns"]
        until = scenes[i + 1]["stamp_ns"] if i + 1 < len(scenes) else None
        led = next(
            (
                led
                for led in leds
                if led["hex"] == color.hex
                and _arrived(led) >= stamp
                and (until is None or _arrived(led) < until + 2_000_000_000)
            ),
            None,
        )
        if led is None:
            missed.append({"text": text, "stamp_ns": stamp})
            continue
        change = {
            "text": text,
            "hex": color.hex,
            "scene_stamp_ns": stamp,
            "led_arrived_ns": _arrived(led),
            "latency_ms": _ms(_arrived(led), stamp),
            "led_sent_ms": _ms(led.get("sent_ns"), stamp),
        }
        if qr_texts is not None:
            qr = next((q for q in qr_texts if q["text"] == text and stamp <= _arrived(q) <= _arrived(led)), None)
            change["qr_sent_ms"] = None if qr is None else _ms(qr.get("sent_ns"), stamp)
        changes.append(change)
    return {"changes": changes, "missed": missed}
