"""Which demo nodes are alive: each publishes its diagnostics every second; silence means down or stuck."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable

# The nodes of the `sim` profile; with real boards only these two run in containers.
SIM_NODES = ("/camera_sim", "/led_strip_sim", "/qr_detector", "/camera_ui")
HARDWARE_NODES = ("/qr_detector", "/camera_ui")


class NodeHealth:
    """When each node last reported, and what that makes it: "ok", "stale", "not seen" or, not seen for
    `missing_after` seconds since the watch began, "missing" (a node that cannot start, as one given a
    setting it cannot parse, restarts in a loop without ever reporting)."""

    def __init__(
        self,
        expected: Iterable[str],
        stale_after: float = 3.0,
        clock: Callable[[], float] = time.monotonic,
        missing_after: float = 30.0,
    ) -> None:
        self.expected = tuple(expected)
        self.stale_after = stale_after
        self.missing_after = missing_after
        self.clock = clock
        self.started = clock()
        self.last: dict[str, float] = {}

    def seen(self, name: str) -> None:
        self.last[name] = self.clock()

    def report(self) -> dict[str, dict[str, object]]:
        """{node: {"state": "ok" | "stale" | "not seen" | "missing", "silent_s": seconds since its last report}}."""
        now = self.clock()
        out: dict[str, dict[str, object]] = {}
        for name in sorted({*self.expected, *self.last}):
            last = self.last.get(name)
            silent = now - (last if last is not None else self.started)
            if last is None:
                state = "missing" if silent > self.missing_after else "not seen"
            elif silent > self.stale_after:
                state = "stale"
            else:
                state = "ok"
            out[name] = {"state": state, "silent_s": round(silent, 1)}
        return out

    def changes(self, before: dict[str, dict[str, object]], after: dict[str, dict[str, object]]) -> list[str]:
        """Sentences for the nodes whose state changed from BEFORE to AFTER (both from report()). The demo's
        compose services are named as their nodes, so a missing node's sentence names its log."""
        lines = []
        for name, now in after.items():
            was = before.get(name, {}).get("state")
            if now["state"] == was:
                continue
            node = name.lstrip("/")
            if now["state"] == "stale":
                lines.append(f"{node} is down or stuck: no diagnostics for {now['silent_s']:.0f} s")
            elif now["state"] == "missing":
                lines.append(
                    f"{node} is down: not up {now['silent_s']:.0f} s after the demo started; "
                    f"`docker compose logs {node}` says why"
                )
            elif now["state"] == "ok" and was in ("stale", "not seen", "missing"):
                lines.append(f"{node} is {'back' if was == 'stale' else 'up'}")
        return lines
