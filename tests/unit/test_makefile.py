"""The Makefile's recipes where they meet the user's terminal, with a stand-in for espdock."""

from __future__ import annotations

import os
import pty
import sys
import time

from tests.conftest import REPO

# Plays espdock: `build` passes; `compose ... up` waits, and a Ctrl-C ends it after a clean-up
# second with espdock's 130 (its own exit, not death by the signal).
STAND_IN = """\
import os, signal, sys, time
def stop(signum, frame):
    time.sleep(1)
    print("stand-in: interrupted", flush=True)
    os._exit(130)
signal.signal(signal.SIGINT, stop)
if "up" in sys.argv:
    print("stand-in: up", flush=True)
    time.sleep(60)
"""


def test_ctrl_c_at_a_terminal_ends_make_demo_naming_make_demo_down(tmp_path):
    """Ctrl-C reaches make and the recipe's shell as well as espdock: a shell that died of it
    left the demo's containers without the line that says how to remove them."""
    espdock = tmp_path / "espdock"
    espdock.write_text(f"#!{sys.executable}\n{STAND_IN}")
    espdock.chmod(0o755)
    pid, terminal = pty.fork()
    if pid == 0:  # setup (venv, engine) taken as done: only the recipe runs
        os.execvp(
            "make", ["make", "-C", str(REPO), "--no-print-directory", "-o", "setup", "demo", f"ESPDOCK={espdock}"]
        )
    said = b""
    deadline = time.monotonic() + 30
    while b"stand-in: up" not in said and time.monotonic() < deadline:
        said += os.read(terminal, 4096)
    os.write(terminal, b"\x03")
    try:
        while chunk := os.read(terminal, 4096):
            said += chunk
    except OSError:  # the terminal closes with make
        pass
    os.waitpid(pid, 0)
    text = said.decode(errors="replace")
    assert "stand-in: interrupted" in text, text
    # After espdock's last words (make echoes the recipe, this line with it, before).
    after = text.split("stand-in: interrupted", 1)[1]
    assert "\nmake demo-down removes the demo's containers and network" in after, text
    assert "Interrupt" not in after, text


def test_make_setup_s_system_check_run_by_a_plain_user_finds_libzbar_where_it_is_installed():
    """ldconfig is in /sbin, on no plain user's PATH on Debian: `make setup` as a user in the
    docker group said "missing system packages: libzbar0" where it was installed."""
    import shutil
    import subprocess

    import pytest

    installed = subprocess.run(["/sbin/ldconfig", "-p"], capture_output=True, text=True, check=False).stdout
    if os.geteuid() != 0 or shutil.which("setpriv") is None or "libzbar.so.0" not in installed:
        pytest.skip("needs root (to run the check as another user) and libzbar0 installed")
    # The script on stdin: a clone in a private directory (mktemp -d) is not for that user to read.
    with (REPO / "tests/install-system-deps.sh").open() as script:
        checked = subprocess.run(
            ["setpriv", "--reuid=65534", "--regid=65534", "--clear-groups", "env", "PATH=/usr/bin:/bin", "bash", "-s"],
            stdin=script, capture_output=True, text=True, check=False, cwd="/",
        )  # fmt: skip
    assert checked.returncode == 0 and "libzbar0" not in checked.stderr, checked.stderr
