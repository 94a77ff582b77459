"""demo_probe: observe and poke the running demo from inside the ROS graph (there is no `ros2` CLI here).

    demo_probe led                      the colour the LED strip shows now
    demo_probe follow --changes 3       scene changes and the LED colours that follow them, with latencies
                                        (--hops: and when the detector published the QR text of each)
    demo_probe frames --count 5         size and stamp of the next camera frames
    demo_probe stats --seconds 10       the nodes' /diagnostics counters over a window
    demo_probe set-config quality=70    call the camera's set_config directly (no validation here)
    demo_probe inject --image garbage --qr '#GGG' --text-size 1000000
                                        publish bad input straight onto the topics and report what happened

Each prints one JSON document on stdout (ROS logs go to stderr); the tests and
the benchmark run it in a container of the runtime image on the demo's network.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable

import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from rclpy.executors import SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile
from sensor_msgs.msg import CompressedImage
from std_msgs.msg import ColorRGBA, String

from espdock_demo.camera_config import DEFAULT_CONFIG
from espdock_demo.colors import Rgb
from espdock_demo.mjpeg import jpeg_size
from espdock_demo.names import (
    CAMERA_IMAGE_TOPIC,
    DIAGNOSTICS_TOPIC,
    IMAGE_FORMAT,
    LED_COLOR_TOPIC,
    QR_MESSAGE_TOPIC,
    SCENE_TOPIC,
)
from espdock_demo.ros_common import IMAGE_PUB_QOS, IMAGE_SUB_QOS, LATCHED_QOS, TEXT_QOS, run_ready
from espdock_demo_testing.report import follow_report

# The LED strip's latched colour, with room for every change that comes while `follow`
# sleeps between reads (Probe.poll_until); a late joiner still gets only the current one.
LED_READER_QOS = QoSProfile(
    history=LATCHED_QOS.history,
    depth=10,
    reliability=LATCHED_QOS.reliability,
    durability=LATCHED_QOS.durability,
)


def _until(done: Callable[[], bool], timeout: float, step: Callable[[], None]) -> bool:
    """Run STEP until DONE() or TIMEOUT seconds; whether DONE() came true."""
    deadline = time.monotonic() + timeout
    while not done():
        if time.monotonic() > deadline:
            return False
        step()
    return True


def _stamp_ns(stamp) -> int:
    return stamp.sec * 1_000_000_000 + stamp.nanosec


def _dds_times(info: dict) -> dict:
    """When the publisher wrote a message and when this probe's DDS reader got it (ns, wall clock),
    from the message info rclpy passes a two-argument callback."""
    return {"sent_ns": info["source_timestamp"], "dds_ns": info["received_timestamp"]}


class Probe(Node):
    """Records what it subscribes to, with receive times (ns, wall clock: containers share the host's).

    `recv_ns` is when the probe's callback ran; for the LED colour and the QR text also
    `dds_ns`, when its DDS reader received the message (before rclpy's executor woke up
    to run the callback), and `sent_ns`, when the publisher wrote it.
    """

    def __init__(self) -> None:
        super().__init__("demo_probe")
        # One executor for the probe's life: rclpy.spin_once(node) adds and removes the node
        # on every call, which costs every message a second pass through the wait set.
        self._spinner = SingleThreadedExecutor()
        self._spinner.add_node(self)
        self.leds: list[dict] = []
        self.scenes: list[dict] = []
        self.qr_texts: list[dict] = []
        self.frames: list[dict] = []
        self.diagnostics: dict[str, list[dict]] = {}

    def watch_led(self):
        def on_color(msg: ColorRGBA, info: dict) -> None:
            recv_ns = time.time_ns()
            self.leds.append({"hex": Rgb.from_floats(msg.r, msg.g, msg.b).hex, "recv_ns": recv_ns, **_dds_times(info)})

        return self.create_subscription(ColorRGBA, LED_COLOR_TOPIC, on_color, LED_READER_QOS)

    def watch_scene(self):
        def on_scene(msg: String) -> None:
            scene = json.loads(msg.data)
            scene["recv_ns"] = time.time_ns()
            self.scenes.append(scene)

        # Volatile: only changes from now on, not the scene shown before the probe came.
        return self.create_subscription(String, SCENE_TOPIC, on_scene, TEXT_QOS)

    def watch_qr(self) -> None:
        def on_qr(msg: String, info: dict) -> None:
            recv_ns = time.time_ns()
            text = {"text": msg.data[:80], "length": len(msg.data), "recv_ns": recv_ns}
            self.qr_texts.append({**text, **_dds_times(info)})

        self.create_subscription(String, QR_MESSAGE_TOPIC, on_qr, TEXT_QOS)

    def watch_frames(self) -> None:
        def on_frame(msg: CompressedImage) -> None:
            size = jpeg_size(bytes(msg.data))
            self.frames.append(
                {
                    "width": size[0] if size else None,
                    "height": size[1] if size else None,
                    "bytes": len(msg.data),
                    "stamp_ns": _stamp_ns(msg.header.stamp),
                    "recv_ns": time.time_ns(),
                    "format": msg.format,
                }
            )

        self.create_subscription(CompressedImage, CAMERA_IMAGE_TOPIC, on_frame, IMAGE_SUB_QOS)

    def watch_diagnostics(self) -> None:
        def on_diagnostics(msg: DiagnosticArray) -> None:
            for status in msg.status:
                values = {kv.key: kv.value for kv in status.values}
                values["stamp_ns"] = _stamp_ns(msg.header.stamp)
                self.diagnostics.setdefault(status.name.lstrip("/"), []).append(values)

        self.create_subscription(DiagnosticArray, DIAGNOSTICS_TOPIC, on_diagnostics, 50)

    def spin_until(self, done: Callable[[], bool], timeout: float) -> bool:
        """Spin until DONE() or TIMEOUT seconds; whether DONE() came true."""
        return _until(done, timeout, lambda: self._spinner.spin_once(timeout_sec=0.05))

    def poll_until(self, done: Callable[[], bool], timeout: float, period: float = 0.1) -> bool:
        """Like spin_until, but asleep between reads every PERIOD seconds: for timing the demo.

        A probe that wakes on each message runs its Python on the same CPUs at the same moment
        as the nodes it times (the scene change, the QR text, the colour all reach it while the
        detector and the LED strip work on them). Asleep, it leaves them the machine; its DDS
        reader thread still stamps each message as it arrives (`dds_ns`), which is what the
        latency is measured to.
        """

        def read() -> None:
            time.sleep(period)
            run_ready(self._spinner)

        return _until(done, timeout, read)

    def spin_for(self, seconds: float) -> None:
        self.spin_until(lambda: False, seconds)

    def wait_for_subscriber(self, topic: str, node_name: str, timeout: float) -> bool:
        """Wait until NODE_NAME subscribes to TOPIC (as the graph shows it), plus time for the match."""
        found = self.spin_until(
            lambda: any(i.node_name == node_name for i in self.get_subscriptions_info_by_topic(topic)), timeout
        )
        self.spin_for(0.5)
        return found

    def wait_for_publisher(self, topic: str, node_name: str, timeout: float) -> bool:
        found = self.spin_until(
            lambda: any(i.node_name == node_name for i in self.get_publishers_info_by_topic(topic)), timeout
        )
        self.spin_for(0.5)
        return found


# ---------------------------------------------------------------- commands


def cmd_led(probe: Probe, args: argparse.Namespace) -> dict:
    probe.watch_led()
    probe.spin_until(lambda: bool(probe.leds), args.timeout)
    return {"led": probe.leds[-1]["hex"] if probe.leds else None}


def cmd_follow(probe: Probe, args: argparse.Namespace) -> dict:
    led_sub = probe.watch_led()
    scene_sub = probe.watch_scene()
    if args.hops:
        probe.watch_qr()  # its sent_ns is when the detector published the text
    start = time.monotonic()
    # Count only scene changes after both subscriptions matched their publishers: an LED
    # change published before the match is never seen (only the latest is kept for late joiners).
    matched = probe.spin_until(
        lambda: led_sub.get_publisher_count() > 0 and scene_sub.get_publisher_count() > 0, args.timeout
    )
    since_ns = time.time_ns()
    checked = [0.0]

    def enough() -> bool:
        # The report pairs every scene with the LED changes: at most twice a second, so the
        # probe is idle, not computing, when the next colour arrives.
        if time.monotonic() - checked[0] < 0.5:
            return False
        checked[0] = time.monotonic()
        return len(follow_report(probe.scenes, probe.leds, since_ns)["changes"]) >= args.changes

    ok = matched and probe.poll_until(enough, args.timeout)
    probe.poll_until(lambda: False, 0.3)  # let the last LED change of the window arrive
    report = follow_report(probe.scenes, probe.leds, since_ns, probe.qr_texts if args.hops else None)
    report.update(
        ok=ok,
        seconds=round(time.monotonic() - start, 2),
        scenes=[{"text": s.get("text"), "stamp_ns": s["stamp_ns"]} for s in probe.scenes],
        leds=probe.leds,
    )
    return report


def cmd_frames(probe: Probe, args: argparse.Namespace) -> dict:
    probe.watch_frames()
    ok = probe.spin_until(lambda: len(probe.frames) >= args.count, args.timeout)
    return {"ok": ok, "frames": probe.frames}


def cmd_stats(probe: Probe, args: argparse.Namespace) -> dict:
    probe.watch_diagnostics()
    probe.spin_for(args.seconds)
    return {"diagnostics": probe.diagnostics}


def cmd_set_config(probe: Probe, args: argparse.Namespace) -> dict:
    """Call get_config, then set_config with the given fields changed; report both answers."""
    from custom_interface.msg import CameraConfig
    from custom_interface.srv import GetCameraConfig, SetCameraConfig

    from espdock_demo.names import CAMERA_GET_CONFIG_SERVICE, CAMERA_SET_CONFIG_SERVICE
    from espdock_demo.ros_common import config_to_dict

    def call(client, request):
        if not client.wait_for_service(timeout_sec=args.timeout):
            raise SystemExit(f"{client.srv_name} is not available")
        future = client.call_async(request)
        if not probe.spin_until(future.done, args.timeout):
            raise SystemExit(f"{client.srv_name} did not answer within {args.timeout:g} s")
        return future.result()

    before = config_to_dict(
        call(probe.create_client(GetCameraConfig, CAMERA_GET_CONFIG_SERVICE), GetCameraConfig.Request()).config
    )
    wanted = dict(before)
    for item in args.fields:
        name, _, value = item.partition("=")
        wanted[name] = int(value)
    answer = call(
        probe.create_client(SetCameraConfig, CAMERA_SET_CONFIG_SERVICE),
        SetCameraConfig.Request(config=CameraConfig(**wanted)),
    )
    return {"before": before, "status": bool(answer.status), "config": config_to_dict(answer.config)}


def _image_message(data: bytes) -> CompressedImage:
    msg = CompressedImage(format=IMAGE_FORMAT)
    msg.header.frame_id = "demo_probe"
    msg.data = data
    return msg


def cmd_inject(probe: Probe, args: argparse.Namespace) -> dict:
    """Publish each bad input in order; report the LED colour before/after and the nodes' counters."""
    from espdock_demo.scene import SceneRenderer

    probe.watch_led()
    probe.watch_qr()
    probe.watch_diagnostics()
    image_pub = probe.create_publisher(CompressedImage, CAMERA_IMAGE_TOPIC, IMAGE_PUB_QOS)
    text_pub = probe.create_publisher(String, QR_MESSAGE_TOPIC, TEXT_QOS)
    ready = {
        "qr_detector": probe.wait_for_subscriber(CAMERA_IMAGE_TOPIC, "qr_detector", args.timeout),
        "led_strip_sim": probe.wait_for_subscriber(QR_MESSAGE_TOPIC, "led_strip_sim", args.timeout),
    }
    probe.wait_for_publisher(QR_MESSAGE_TOPIC, "qr_detector", args.timeout)
    probe.spin_until(
        lambda: bool(probe.leds) and {"qr_detector", "led_strip_sim"} <= probe.diagnostics.keys(), args.timeout
    )
    before = {name: series[-1] for name, series in probe.diagnostics.items()}
    led_before = probe.leds[-1]["hex"] if probe.leds else None
    renderer = SceneRenderer()
    sent = []
    for kind, value in args.actions:
        if kind == "text":
            text_pub.publish(String(data=value))
            sent.append({"topic": QR_MESSAGE_TOPIC, "length": len(value), "text": value[:40]})
        else:
            if kind == "image":
                data = {
                    "garbage": b"\xff\xd8\xff\xe0 this is not a JPEG" * 50,
                    "empty": b"",
                    "truncated": renderer.frame("#123456", DEFAULT_CONFIG, 0)[:300],
                }[value]
            else:  # a QR code showing VALUE (qr: text; qr-bytes: hex of raw bytes)
                payload = bytes.fromhex(value) if kind == "qr-bytes" else value
                data = renderer.frame(payload, DEFAULT_CONFIG, 0)
            # Best effort to the detector: send each a few times so one arrives.
            for _ in range(args.repeat):
                image_pub.publish(_image_message(data))
                probe.spin_for(0.1)
            sent.append({"topic": CAMERA_IMAGE_TOPIC, "kind": kind, "value": value, "bytes": len(data)})
        probe.spin_for(args.gap)
    done_ns = time.time_ns()
    # Wait for counters stamped after the last input was handled.
    probe.spin_until(
        lambda: all(
            any(int(v["stamp_ns"]) > done_ns + 1_000_000_000 for v in probe.diagnostics.get(n, []))
            for n in ("qr_detector", "led_strip_sim")
        ),
        args.timeout,
    )
    after = {name: series[-1] for name, series in probe.diagnostics.items()}
    return {
        "ready": ready,
        "sent": sent,
        "led_before": led_before,
        "led_after": probe.leds[-1]["hex"] if probe.leds else None,
        "led_changes": probe.leds[1:],
        "qr_messages": probe.qr_texts,
        "diagnostics_before": before,
        "diagnostics_after": after,
    }


class _Append(argparse.Action):
    """Collects --image/--qr/--text... in command-line order as (kind, value)."""

    def __call__(self, parser, namespace, values, option_string=None):
        actions = list(getattr(namespace, "actions", None) or [])
        kind = option_string.lstrip("-")
        if kind == "text-size":
            kind, values = "text", "#" + "f" * (int(values) - 1)
        actions.append((kind, values))
        namespace.actions = actions


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="demo_probe", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("led", help="the LED strip's colour now")
    p.add_argument("--timeout", type=float, default=10.0)
    p = sub.add_parser("follow", help="scene changes and the LED changes that follow them")
    p.add_argument("--changes", type=int, default=3)
    p.add_argument("--timeout", type=float, default=60.0)
    p.add_argument("--hops", action="store_true", help="also time when the detector published each QR text")
    p = sub.add_parser("frames", help="size and stamp of the next camera frames")
    p.add_argument("--count", type=int, default=5)
    p.add_argument("--timeout", type=float, default=10.0)
    p = sub.add_parser("stats", help="the nodes' /diagnostics over a window")
    p.add_argument("--seconds", type=float, default=10.0)
    p = sub.add_parser("set-config", help="call the camera's set_config with FIELD=VALUE changes")
    p.add_argument("fields", nargs="+", metavar="FIELD=VALUE")
    p.add_argument("--timeout", type=float, default=10.0)
    p = sub.add_parser("inject", help="publish bad input onto the topics, in order")
    p.add_argument("--image", choices=("garbage", "empty", "truncated"), action=_Append, dest="actions")
    p.add_argument("--qr", metavar="TEXT", action=_Append, dest="actions", help="an image of a QR code of TEXT")
    p.add_argument("--qr-bytes", metavar="HEX", action=_Append, dest="actions", help="a QR code of raw bytes")
    p.add_argument("--text", metavar="TEXT", action=_Append, dest="actions", help="TEXT straight on /qr_message")
    p.add_argument(
        "--text-size",
        metavar="N",
        action=_Append,
        dest="actions",
        help="an N-character '#fff...' string on /qr_message",
    )
    p.add_argument("--repeat", type=int, default=3, help="times each image is sent (best effort)")
    p.add_argument("--gap", type=float, default=0.5, help="seconds between inputs")
    p.add_argument("--timeout", type=float, default=20.0)
    return parser


COMMANDS = {
    "led": cmd_led,
    "follow": cmd_follow,
    "frames": cmd_frames,
    "stats": cmd_stats,
    "set-config": cmd_set_config,
    "inject": cmd_inject,
}


def main(argv: list[str] | None = None) -> None:
    args = build_parser().parse_args(argv)
    if args.command == "inject" and not getattr(args, "actions", None):
        args.actions = []
    rclpy.init()
    try:
        probe = Probe()
        result = COMMANDS[args.command](probe, args)
        probe.destroy_node()
    finally:
        rclpy.try_shutdown()
    json.dump(result, sys.stdout)
    sys.stdout.write("\n")
    sys.stdout.flush()
