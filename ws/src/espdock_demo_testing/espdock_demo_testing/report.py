"""demo_probe's reports, without rclpy: pure functions of what the probe recorded."""

from __future__ import annotations

from espdock_demo.colors import parse_hex_color


def follow_report(
    scenes: list[dict],
    leds: list[dict],
    since_ns: int = 0,
    frames: dict[int, int] | None = None,
    qr_texts: list[dict] | None = None,
) -> dict:
    """Pair each scene change (stamped after SINCE_NS) that shows a new colour with the LED change that followed it.

    With FRAMES (frame stamp -> when the observer got that frame) and QR_TEXTS (what it
    saw on /qr_message, with receive times), each change also gets its hops, in ms from
    the camera's stamp: `frame_ms` (the frame reaching a subscriber, as it reaches the
    detector) and `qr_ms` (the detector's text reaching a subscriber); None where the
    observer missed that message (the image topic is best effort).
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
        until = scenes[i + 1]["stamp_ns"] if i + 1 < len(scenes) else None
        led = next(
            (
                led
                for led in leds
                if led["hex"] == color.hex
                and led["recv_ns"] >= scene["stamp_ns"]
                and (until is None or led["recv_ns"] < until + 2_000_000_000)
            ),
            None,
        )
        if led is None:
            missed.append({"text": text, "stamp_ns": scene["stamp_ns"]})
            continue
        change = {
            "text": text,
            "hex": color.hex,
            "scene_stamp_ns": scene["stamp_ns"],
            "led_recv_ns": led["recv_ns"],
            "latency_ms": (led["recv_ns"] - scene["stamp_ns"]) / 1e6,
        }
        if frames is not None:
            frame_ns = frames.get(scene["stamp_ns"])
            change["frame_ms"] = None if frame_ns is None else (frame_ns - scene["stamp_ns"]) / 1e6
        if qr_texts is not None:
            qr = next(
                (q for q in qr_texts if q["text"] == text and scene["stamp_ns"] <= q["recv_ns"] <= led["recv_ns"]), None
            )
            change["qr_ms"] = None if qr is None else (qr["recv_ns"] - scene["stamp_ns"]) / 1e6
        changes.append(change)
    return {"changes": changes, "missed": missed}
