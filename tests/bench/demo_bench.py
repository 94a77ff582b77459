"""Benchmark of the running demo (`make bench`): pipeline latency, decoding at 30 fps, MJPEG fan-out.

    .venv/bin/python tests/bench/demo_bench.py                 bring a demo up, measure, take it down
    .venv/bin/python tests/bench/demo_bench.py --project espdock-demo --port 8080
                                                               measure a demo that is already running

Measured with real ROS timestamps, all containers sharing the host's clock:
  latency   camera_sim stamps the first frame of each new QR colour (and announces
            it on /camera_sim/scene); the probe takes the time its DDS reader received
            the LED colour on /esp32/led_strip/color minus that stamp. The probe reads
            its readers only every 0.1 s: awake on each message, its Python ran beside
            the detector and the LED strip at the moments it times
  decoding  frames qr_detector decoded vs frames camera_sim published over a window,
            from their /diagnostics counters (published count interpolated at the
            detector's sample times); CPU per decoded frame from the detector
            process's CPU time
  MJPEG     frames per second each of 3 concurrent HTTP clients of /stream.mjpg receives
A benchmark, not a test: it prints the numbers against the targets and exits 0.
"""

from __future__ import annotations

import argparse
import http.client
import itertools
import json
import sys
import threading
import time
from pathlib import Path

# demo_stack by its own name, as the demo tests import it; it imports tests.ports from the checkout.
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "demo"))

from demo_stack import DemoStack, StackError, build_image, docker_problem

TARGETS = {"p50_ms": 5.0, "p95_ms": 8.0, "decoded_pct": 99.0, "client_fps": 25.0}


def percentile(values: list[float], q: float) -> float:
    """The Q-th percentile (0..100) by linear interpolation."""
    ordered = sorted(values)
    if not ordered:
        return float("nan")
    k = (len(ordered) - 1) * q / 100
    low, high = int(k), min(int(k) + 1, len(ordered) - 1)
    return ordered[low] + (ordered[high] - ordered[low]) * (k - low)


def hops_from(changes: list[dict]) -> dict[str, list[float]]:
    """Each change's latency cut into hops (ms), from the DDS source timestamps of the same
    change's QR text and LED colour (when qr_detector and led_strip_sim published them; every
    container reads the host's clock):
      camera -> detector's text out   the frame's trip, the detector's executor, decoding, publishing
      detector -> LED's colour out    the text's trip, led_strip_sim's executor and callback
      LED -> observer's reader        the colour's trip
    Changes whose QR text the observer missed are left out of the hops."""
    whole = [c for c in changes if c.get("qr_sent_ms") is not None and c.get("led_sent_ms") is not None]
    return {
        "camera -> detector's text out": [c["qr_sent_ms"] for c in whole],
        "detector -> LED's colour out": [c["led_sent_ms"] - c["qr_sent_ms"] for c in whole],
        "LED -> observer's reader": [c["latency_ms"] - c["led_sent_ms"] for c in whole],
    }


def measure_latency(stack: DemoStack, changes: int, timeout: float) -> dict:
    report = stack.probe("follow", "--changes", str(changes), "--timeout", str(timeout), "--hops", timeout=timeout + 30)
    latencies = [c["latency_ms"] for c in report["changes"]]
    return {
        "changes": len(latencies),
        "missed": len(report["missed"]),
        "p50_ms": percentile(latencies, 50),
        "p95_ms": percentile(latencies, 95),
        "max_ms": max(latencies, default=float("nan")),
        "seconds": report["seconds"],
        "hops": {
            name: (percentile(v, 50), percentile(v, 95), len(v)) for name, v in hops_from(report["changes"]).items()
        },
    }


def _series(diagnostics: dict, node: str, *keys: str) -> list[tuple[int, ...]]:
    return [(int(s["stamp_ns"]), *(float(s[k]) for k in keys)) for s in diagnostics.get(node, [])]


def _interpolate(series: list[tuple[int, float]], t: int) -> float:
    for (t0, v0), (t1, v1) in itertools.pairwise(series):
        if t0 <= t <= t1:
            return v0 + (v1 - v0) * (t - t0) / (t1 - t0)
    raise ValueError("time outside the series")


def decoding_from(diagnostics: dict) -> dict:
    """Decoded vs published frames and CPU per decoded frame, from a window of /diagnostics samples."""
    published = [(t, v) for t, v in _series(diagnostics, "camera_sim", "frames_published")]
    decoded = _series(diagnostics, "qr_detector", "frames_decoded", "cpu_seconds", "decode_seconds")
    # Detector samples inside the camera's series, so the published count can be interpolated there.
    inside = [d for d in decoded if published and published[0][0] <= d[0] <= published[-1][0]]
    if len(inside) < 2:
        raise StackError(f"too few /diagnostics samples to compare: {len(published)} camera, {len(decoded)} detector")
    (t0, d0, c0, s0), (t1, d1, c1, s1) = inside[0], inside[-1]
    frames_published = _interpolate(published, t1) - _interpolate(published, t0)
    frames_decoded = d1 - d0
    seconds = (t1 - t0) / 1e9
    return {
        "seconds": seconds,
        "published": frames_published,
        "decoded": frames_decoded,
        "published_fps": frames_published / seconds,
        "decoded_pct": 100.0 * frames_decoded / frames_published if frames_published else float("nan"),
        "cpu_ms_per_frame": 1000.0 * (c1 - c0) / frames_decoded if frames_decoded else float("nan"),
        "decode_ms_per_frame": 1000.0 * (s1 - s0) / frames_decoded if frames_decoded else float("nan"),
    }


def measure_decoding(stack: DemoStack, seconds: float) -> dict:
    return decoding_from(stack.probe("stats", "--seconds", str(seconds), timeout=seconds + 30)["diagnostics"])


def mjpeg_client(port: int, seconds: float, result: dict) -> None:
    """Read /stream.mjpg for SECONDS, counting parts (after the first, which may be an old frame)."""
    conn = http.client.HTTPConnection("127.0.0.1", port, timeout=10)
    conn.request("GET", "/stream.mjpg")
    response = conn.getresponse()
    parts, first_at, sizes = 0, None, 0
    deadline = None
    while True:
        line = response.fp.readline()
        if not line:
            break
        if line.startswith(b"Content-Length:"):
            length = int(line.split(b":")[1])
            response.fp.readline()
            sizes += len(response.fp.read(length))
            now = time.monotonic()
            if first_at is None:
                first_at, deadline = now, now + seconds
                continue
            parts += 1
            if now >= deadline:
                break
    conn.close()
    elapsed = (time.monotonic() - first_at) if first_at else float("nan")
    result.update(frames=parts, seconds=elapsed, fps=parts / elapsed if first_at else 0.0, bytes=sizes)


def measure_mjpeg(stack: DemoStack, clients: int, seconds: float) -> dict:
    """CLIENTS concurrent MJPEG readers; meanwhile the decoding counters under that load."""
    results = [{} for _ in range(clients)]
    threads = [threading.Thread(target=mjpeg_client, args=(stack.port, seconds, r)) for r in results]
    stats: dict = {}

    def probe_stats() -> None:
        try:
            stats.update(measure_decoding(stack, seconds))
        except StackError as exc:
            stats["error"] = str(exc)

    watcher = threading.Thread(target=probe_stats)
    watcher.start()
    time.sleep(2.0)  # the probe container starts and discovers the graph first
    for t in threads:
        t.start()
    for t in threads:
        t.join(seconds + 30)
    watcher.join(seconds + 60)
    return {"clients": results, "decoding_under_load": stats}


def row(name: str, value: str, target: str = "", ok: bool | None = None) -> str:
    verdict = "" if ok is None else ("ok" if ok else "MISSED")
    return f"{name:<52} {value:>16}  {target:<10} {verdict}"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--project", help="measure this running compose project instead of starting one")
    parser.add_argument("--port", type=int, default=8080, help="UI port of the running project (with --project)")
    parser.add_argument("--changes", type=int, default=120, help="LED changes to time (at least 100)")
    parser.add_argument("--phase", type=float, default=0.4, help="seconds per QR colour (a started demo only)")
    parser.add_argument("--window", type=float, default=30.0, help="seconds of the decoding window")
    parser.add_argument("--clients", type=int, default=3)
    parser.add_argument("--mjpeg-seconds", type=float, default=15.0)
    parser.add_argument("--no-build", action="store_true", help="use the runtime image as it is")
    parser.add_argument("--json", type=Path, help="also write the results here")
    args = parser.parse_args()

    problem = docker_problem()
    if problem:
        print(f"demo_bench: {problem}", file=sys.stderr)
        return 1
    started = args.project is None
    if started:
        stack = DemoStack(name=f"espdock-bench-{int(time.time())}", ESPDOCK_DEMO_PHASE_SECONDS=str(args.phase))
    else:
        stack = DemoStack(name=args.project)
        stack.port = args.port
        stack.env.pop("ROS_DOMAIN_ID")  # the probe joins the running project's domain
        stack.env["ESPDOCK_DEMO_PORT"] = str(args.port)
    try:
        if started:
            if not args.no_build:
                print("building the runtime image (cached when nothing changed)...", flush=True)
                build_image()
            print(f"starting the demo as compose project {stack.project} (QR phase {args.phase:g} s)...", flush=True)
            stack.up()
            time.sleep(3)  # past start-up: every node's first frames, discovery settled
        print(f"timing {args.changes} LED changes...", flush=True)
        latency = measure_latency(stack, args.changes, timeout=max(120.0, args.changes * args.phase * 3))
        print(f"decoding over {args.window:g} s...", flush=True)
        decoding = measure_decoding(stack, args.window)
        print(f"{args.clients} MJPEG clients for {args.mjpeg_seconds:g} s...", flush=True)
        mjpeg = measure_mjpeg(stack, args.clients, args.mjpeg_seconds)
        state = stack.state()
    except StackError as exc:
        print(f"demo_bench: {exc}", file=sys.stderr)
        if started:
            print(stack.logs(), file=sys.stderr)
        return 1
    finally:
        if started:
            stack.down()

    fps = [c.get("fps", 0.0) for c in mjpeg["clients"]]
    under = mjpeg["decoding_under_load"]
    camera = state["camera"]
    lines = [
        "",
        f"espdock demo benchmark: camera_sim at {camera['width']}x{camera['height']}, "
        f"{decoding['published_fps']:.1f} fps published",
        row("metric", "value", "target"),
        row(
            f"QR -> LED latency p50 ({latency['changes']} changes)",
            f"{latency['p50_ms']:.2f} ms",
            f"<= {TARGETS['p50_ms']:g} ms",
            latency["p50_ms"] <= TARGETS["p50_ms"],
        ),
        row(
            "QR -> LED latency p95",
            f"{latency['p95_ms']:.2f} ms",
            f"<= {TARGETS['p95_ms']:g} ms",
            latency["p95_ms"] <= TARGETS["p95_ms"],
        ),
        row("  floor: qr_detector's decode per frame", f"{decoding['decode_ms_per_frame']:.2f} ms"),
        row("QR -> LED latency max", f"{latency['max_ms']:.1f} ms"),
        *(
            row(f"  hop {name} p50 / p95 ({n})", f"{p50:.2f} / {p95:.2f} ms")
            for name, (p50, p95, n) in latency["hops"].items()
        ),
        row("colour changes the LED missed", f"{latency['missed']}", "0", latency["missed"] == 0),
        row(
            f"frames decoded / published ({decoding['seconds']:.0f} s)",
            f"{decoding['decoded']:.0f} / {decoding['published']:.0f}",
        ),
        row(
            "frames decoded",
            f"{decoding['decoded_pct']:.2f} %",
            ">= 99 %",
            decoding["decoded_pct"] >= TARGETS["decoded_pct"],
        ),
        row("qr_detector CPU per decoded frame", f"{decoding['cpu_ms_per_frame']:.2f} ms"),
        row("  of which JPEG decode + pyzbar", f"{decoding['decode_ms_per_frame']:.2f} ms"),
    ]
    for i, f in enumerate(fps, 1):
        lines.append(row(f"MJPEG client {i} of {len(fps)}", f"{f:.1f} fps", ">= 25 fps", f >= TARGETS["client_fps"]))
    if "decoded_pct" in under:
        lines.append(
            row(
                f"frames decoded while {len(fps)} clients stream",
                f"{under['decoded_pct']:.2f} %",
                ">= 99 %",
                under["decoded_pct"] >= TARGETS["decoded_pct"],
            )
        )
    print("\n".join(lines))
    if args.json:
        args.json.write_text(
            json.dumps({"latency": latency, "decoding": decoding, "mjpeg": mjpeg, "camera": camera}, indent=1)
        )
    return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:  # the stack is down by then (main's finally): no traceback to read
        print("demo_bench: interrupted", file=sys.stderr)
        sys.exit(130)
