"""Ctrl-C and SIGTERM end espdock: the first within its grace, a second at once, whatever the
signal disposition espdock was started with (espdock.interrupts), in real processes."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest

# A command that blocks, then cleans up for CLEANUP seconds when interrupted.
SCRIPT = """
import sys, time
from espdock import interrupts
interrupts.GRACE = {grace}
interrupts.install()
try:
    with interrupts.held():
        print("holding", flush=True)
        time.sleep({hold})
    print("ready", flush=True)
    time.sleep(60)
except KeyboardInterrupt:
    print("cleaning up", flush=True)
    time.sleep({cleanup})
    print("cleaned up", flush=True)
    sys.exit(130)
"""


def start(grace: float = 8, hold: float = 0, cleanup: float = 0, ignore_sigint: bool = False) -> subprocess.Popen:
    def ignore() -> None:
        # What a shell without job control does to a command it starts in the background.
        signal.signal(signal.SIGINT, signal.SIG_IGN)

    return subprocess.Popen(
        [sys.executable, "-c", SCRIPT.format(grace=grace, hold=hold, cleanup=cleanup)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=ignore if ignore_sigint else None,  # noqa: PLW1509 (no threads in the test)
    )


def wait_for(process: subprocess.Popen, line: str) -> None:
    assert process.stdout is not None
    assert process.stdout.readline().strip() == line


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_ends_a_command_started_with_sigint_ignored(signum):
    process = start(ignore_sigint=True)
    wait_for(process, "holding")
    wait_for(process, "ready")
    process.send_signal(signum)
    out, _ = process.communicate(timeout=10)
    assert process.returncode == 130
    assert out.split() == ["cleaning", "up", "cleaned", "up"]


def test_cleanup_that_hangs_is_abandoned_after_the_grace():
    process = start(grace=1, cleanup=60)
    wait_for(process, "holding")
    wait_for(process, "ready")
    sent = time.monotonic()
    process.send_signal(signal.SIGINT)
    out, err = process.communicate(timeout=10)
    assert process.returncode == 130
    assert time.monotonic() - sent < 5
    assert "cleaned up" not in out
    assert "longer than 1 s" in err


def test_a_second_signal_ends_it_at_once():
    process = start(cleanup=60)
    wait_for(process, "holding")
    wait_for(process, "ready")
    process.send_signal(signal.SIGINT)
    wait_for(process, "cleaning up")
    sent = time.monotonic()
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=10)
    assert process.returncode == 130
    assert time.monotonic() - sent < 2
    assert "interrupted again" in err


def test_a_signal_in_a_held_block_is_raised_when_the_block_ends():
    process = start(hold=1.5)
    wait_for(process, "holding")
    process.send_signal(signal.SIGINT)
    out, _ = process.communicate(timeout=10)
    assert process.returncode == 130
    # Raised after the block, so "ready" never printed: the interrupt was not lost.
    assert out.split() == ["cleaning", "up", "cleaned", "up"]


@pytest.fixture
def entry_point(monkeypatch):
    """espdock.cli.main with its handlers put back afterwards (they are process-wide)."""
    from espdock import cli, interrupts

    handlers = {signum: signal.getsignal(signum) for signum in (signal.SIGINT, signal.SIGTERM)}
    yield cli, interrupts
    for signum, handler in handlers.items():
        signal.signal(signum, handler)
    interrupts.reset()


def test_an_interrupt_outside_any_command_still_exits_130(entry_point, monkeypatch, capsys):
    cli, _ = entry_point

    def app() -> None:
        raise KeyboardInterrupt  # as if Ctrl-C came while Typer parsed, or after the command returned

    monkeypatch.setattr(cli, "app", app)
    with pytest.raises(SystemExit) as exited:
        cli.main()
    assert exited.value.code == 130
    assert "interrupted" in capsys.readouterr().err


def test_an_interrupt_python_swallowed_still_exits_130(entry_point, monkeypatch, capsys):
    cli, interrupts = entry_point

    def app() -> None:
        # Python only prints an exception raised in a weakref or GC callback: the command went on.
        interrupts._state["first"] = time.monotonic()
        raise SystemExit(0)

    monkeypatch.setattr(cli, "app", app)
    with pytest.raises(SystemExit) as exited:
        cli.main()
    assert exited.value.code == 130


def test_a_signal_after_the_command_finished_exits_130_not_by_the_signal():
    script = (
        "import time\nfrom espdock import interrupts\ninterrupts.install()\nprint('done', flush=True)\n"
        "interrupts.finish()\ntime.sleep(60)\n"
    )
    process = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, text=True)
    wait_for(process, "done")
    process.send_signal(signal.SIGINT)
    process.communicate(timeout=10)
    assert process.returncode == 130
