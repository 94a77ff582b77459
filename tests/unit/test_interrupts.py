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


def start(
    grace: float = 8, hold: float = 0, cleanup: float = 0, ignore_sigint: bool = False, nohup: bool = False
) -> subprocess.Popen:
    def dispositions() -> None:
        # SIGINT ignored: what a shell without job control does to a command it starts in the
        # background. SIGHUP as a terminal's command has it, whatever the test run's own is (a
        # `nohup make test` ignores it, and espdock then leaves it ignored).
        if ignore_sigint:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
        signal.signal(signal.SIGHUP, signal.SIG_IGN if nohup else signal.SIG_DFL)

    return subprocess.Popen(
        [sys.executable, "-c", SCRIPT.format(grace=grace, hold=hold, cleanup=cleanup)],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=dispositions,  # noqa: PLW1509 (no threads in the test)
    )


def wait_for(process: subprocess.Popen, line: str) -> None:
    assert process.stdout is not None
    assert process.stdout.readline().strip() == line


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM, signal.SIGHUP])
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
    time.sleep(0.3)  # a hand's second Ctrl-C
    sent = time.monotonic()
    process.send_signal(signal.SIGINT)
    _, err = process.communicate(timeout=10)
    assert process.returncode == 130
    assert time.monotonic() - sent < 2
    assert "interrupted again" in err


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_one_signal_delivered_twice_at_once_is_one_interruption_that_cleans_up(signum):
    """Ctrl-C under `timeout --foreground` (the terminal's SIGINT and the one timeout relays), a
    process group's kill that a wrapper passes on: the second copy was "interrupted again",
    exiting at once with the build container still running and writing into the workspace."""
    process = start(cleanup=1)
    wait_for(process, "holding")
    wait_for(process, "ready")
    process.send_signal(signum)
    time.sleep(0.05)  # each copy handled (two at once could be one pending signal to Python)
    process.send_signal(signum)
    out, err = process.communicate(timeout=10)
    assert process.returncode == 130
    assert out.split() == ["cleaning", "up", "cleaned", "up"] and "again" not in err


def test_sigint_and_sigterm_together_are_one_interruption_that_cleans_up():
    """A wrapper relaying Ctrl-C as SIGINT and SIGTERM (or a CI runner's INT then TERM) 0.01 to
    0.1 s apart: the second was "interrupted again", exiting with the build container running."""
    process = start(cleanup=1)
    wait_for(process, "holding")
    wait_for(process, "ready")
    process.send_signal(signal.SIGINT)
    time.sleep(0.05)
    process.send_signal(signal.SIGTERM)
    out, err = process.communicate(timeout=10)
    assert process.returncode == 130
    assert out.split() == ["cleaning", "up", "cleaned", "up"] and "again" not in err


def test_a_signal_in_a_held_block_is_raised_when_the_block_ends():
    process = start(hold=1.5)
    wait_for(process, "holding")
    process.send_signal(signal.SIGINT)
    out, _ = process.communicate(timeout=10)
    assert process.returncode == 130
    # Raised after the block, so "ready" never printed: the interrupt was not lost.
    assert out.split() == ["cleaning", "up", "cleaned", "up"]


def run_main(app: str) -> subprocess.CompletedProcess:
    """espdock.cli.main in a process of its own (it ends the process), with APP as its Typer app."""
    script = f"import sys, time\nfrom espdock import cli, interrupts\n{app}\ncli.app = app\ncli.main()\n"
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=30, check=False)


def test_an_interrupt_outside_any_command_still_exits_130():
    # As if Ctrl-C came while Typer parsed, or after the command returned.
    result = run_main("def app(**options):\n    raise KeyboardInterrupt")
    assert result.returncode == 130
    assert "interrupted" in result.stderr


def test_an_interrupt_python_swallowed_still_exits_130():
    # Python only prints an exception raised in a weakref or GC callback: the command went on.
    result = run_main('def app(**options):\n    interrupts._state["first"] = time.monotonic()\n    sys.exit(0)')
    assert result.returncode == 130


def test_the_command_s_own_exit_code_is_kept():
    assert run_main("def app(**options):\n    sys.exit(5)").returncode == 5
    assert run_main("def app(**options):\n    sys.exit(0)").returncode == 0


def test_a_command_started_with_its_output_closed_keeps_its_exit_code():
    """`espdock build >&-`: the build succeeded, then ended with AttributeError and exit code 1."""
    script = "from espdock import interrupts\ninterrupts.finish(0)\n"
    closed = subprocess.run(["sh", "-c", 'exec "$0" -c "$1" >&- 2>&-', sys.executable, script], check=False)
    assert closed.returncode == 0


def test_a_hangup_is_left_to_nohup():
    """`nohup espdock build &`: the closed terminal's SIGHUP must not end it."""
    process = start(nohup=True)
    wait_for(process, "holding")
    wait_for(process, "ready")
    process.send_signal(signal.SIGHUP)
    time.sleep(0.5)
    assert process.poll() is None, "a hangup nohup asked to ignore ended the command"
    process.send_signal(signal.SIGTERM)
    out, _ = process.communicate(timeout=10)
    assert process.returncode == 130 and out.split() == ["cleaning", "up", "cleaned", "up"]
