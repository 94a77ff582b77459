"""Ctrl-C, SIGTERM and SIGHUP: the first ends any command within GRACE seconds, cleaning up; a second at once.

espdock installs its own handler because Python turns SIGINT into KeyboardInterrupt only
when SIGINT was at its default at start-up: a process started in the background by a shell
without job control (`make test &` in a script, many CI runners) inherits SIGINT ignored,
and such an espdock then never answered Ctrl-C or `kill -INT` at all.

The first signal raises KeyboardInterrupt in the main thread, so `finally` blocks stop and
remove containers; a watchdog ends the process if that cleanup is not done within GRACE
seconds (an engine that does not answer a stop), and a second signal ends it at once.
Whatever is left then carries this process's identity in a label, which the next command
sees is dead (engine.Engine.sweep).
"""

from __future__ import annotations

import os
import signal
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import NoReturn

GRACE = 8.0  # seconds between the first signal and the exit, however cleanup goes
EXIT_CODE = 130  # 128 + SIGINT, as shells report it

# A signal of the other kind this soon after the first is the same interruption passed on twice
# (a wrapper that relays Ctrl-C as SIGINT and SIGTERM, a CI runner's INT then TERM), not a second.
RELAYED = 1.0
# The same signal this soon after the first is the same interruption too: a terminal's Ctrl-C
# reaches espdock and the wrapper that relays it (`timeout --foreground`), a kill of a process
# group whose wrapper passes it on, microseconds apart. A hand pressing Ctrl-C again is slower.
ECHOED = 0.2

# Only the main thread reads and writes this (Python runs signal handlers there).
_state: dict[str, float | int | bool | str | None] = {
    "first": None, "signal": None, "held": 0, "pending": False, "left": None,
}  # fmt: skip
# What may be left behind when a second signal, or the watchdog, ends a command at once.
LEFT_BEHIND = "the next espdock build or run here removes any container left behind"
# Who left the containers the next command removes, as that command says it.
ENDED_UNCLEAN = "an espdock that ended before its cleanup (kill -9, a second Ctrl-C, a closed terminal)"


def swept(count: int, of: str = "", where: str = "") -> str:
    """What the next command says of the COUNT containers an espdock that ended uncleanly left
    (OF: whose they were; WHERE: after "left behind"), in one wording wherever it sweeps."""
    return f"removed {count} container(s) {of}{' ' if of else ''}{ENDED_UNCLEAN} left behind{where}"


def leaving(text: str) -> None:
    """Say TEXT, instead of LEFT_BEHIND, of what is left when the command ends at once: what a
    command leaves that no later espdock removes (`compose up`'s services, which `espdock build`
    was said to remove and did not touch)."""
    _state["left"] = text


def install() -> None:
    """Handle SIGINT and SIGTERM as described above, whatever their disposition was at start-up;
    and SIGHUP (the terminal closed, an ssh session dropped), unless it was ignored at start-up
    (`nohup espdock build`): by default it ended espdock with no cleanup at all, leaving a
    `monitor` or `menuconfig` container running, holding the serial port."""
    for signum in _handled():
        signal.signal(signum, _on_signal)


def _handled() -> tuple[signal.Signals, ...]:
    hangup = () if signal.getsignal(signal.SIGHUP) == signal.SIG_IGN else (signal.SIGHUP,)
    return (signal.SIGINT, signal.SIGTERM, *hangup)


def finish(code: int) -> NoReturn:
    """End the process with CODE once the command is over: flush what it printed, and leave
    without Python's shutdown, which resets signal handlers to the default: a Ctrl-C then would
    kill the process by SIGINT instead of ending it with EXIT_CODE."""
    for signum in _handled():  # first: the flush below can wait on a full pipe
        signal.signal(signum, _exit_now)
    for stream in (sys.stdout, sys.stderr):
        if stream is None:  # started with it closed (`espdock build >&-`): nothing to flush
            continue
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


def _exit_now(signum: int, frame: object) -> None:
    os._exit(EXIT_CODE)


def interrupted() -> bool:
    """Whether a first signal arrived."""
    return _state["first"] is not None


def remaining() -> float:
    """Seconds left before the watchdog ends the process (GRACE when no signal came yet)."""
    first = _state["first"]
    return GRACE if first is None else max(0.0, GRACE - (time.monotonic() - float(first)))


def _say(text: str) -> None:
    # os.write: the main thread may be inside a buffered write to stderr at this moment.
    try:
        os.write(2, f"\nerror: {text}\n".encode())
    except OSError:
        pass


def _left() -> str:
    return str(_state["left"] or LEFT_BEHIND)


def _give_up() -> None:
    _say(f"interrupted; cleaning up took longer than {GRACE:.0f} s, so espdock stopped waiting ({_left()})")
    os._exit(EXIT_CODE)


def _on_signal(signum: int, frame: object) -> None:
    first = _state["first"]
    if first is not None:
        since = time.monotonic() - float(first)
        if since < ECHOED or (signum != _state["signal"] and since < RELAYED):
            return  # the cleanup the first one started goes on
        _say(f"interrupted again: exiting now ({_left()})")
        os._exit(EXIT_CODE)
    _state["first"], _state["signal"] = time.monotonic(), signum
    watchdog = threading.Timer(GRACE, _give_up)
    watchdog.daemon = True
    watchdog.start()
    if _state["held"]:
        _state["pending"] = True
        return
    raise KeyboardInterrupt


@contextmanager
def held() -> Iterator[None]:
    """Hold a first signal until the block ends, then raise it: for an engine call whose answer
    cleanup needs (the id of a container being created). A second signal still exits at once."""
    _state["held"] = int(_state["held"] or 0) + 1
    try:
        yield
    finally:
        _state["held"] = int(_state["held"] or 0) - 1
        if _state["pending"] and not _state["held"]:
            _state["pending"] = False
            raise KeyboardInterrupt


def reset() -> None:
    """Forget a first signal (tests run several commands in one process)."""
    _state.update(first=None, signal=None, held=0, pending=False)
