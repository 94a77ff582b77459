"""The espdock command line: parses, calls the library, maps known errors to exit codes.

Each command lives with its kind: workspace.py (build, lock, verify, new, init, setup, list),
testing.py (test), firmware.py (idf, micro-ros, flash, provision, monitor), nodes.py (compose,
run, shell), prune.py (prune, imported by workspace.py: a build records and prunes) and agent.py
(the micro-ROS agent). Importing them registers them on the app, in the order `espdock --help`
lists them."""

from __future__ import annotations

import sys
from typing import NoReturn

from espdock import interrupts
from espdock.cli.core import INTERRUPTED, app, command, fail
from espdock.errors import Interrupted

# isort: split
from espdock.cli import workspace  # noqa: F401

# isort: split
from espdock.cli import testing  # noqa: F401

# isort: split
from espdock.cli import firmware  # noqa: F401

# isort: split
from espdock.cli import nodes  # noqa: F401

# isort: split
from espdock.cli import agent  # noqa: F401

__all__ = ["app", "command", "main"]


def main() -> NoReturn:
    """Entry point: Ctrl-C and SIGTERM (CI timeouts, `docker stop`) end any command (espdock.interrupts)."""
    interrupts.install()
    try:
        try:
            app()
        except KeyboardInterrupt:  # in Typer's own code, before or after the command
            fail(INTERRUPTED)
        except SystemExit as exc:
            # A Ctrl-C that Python swallowed (raised in a callback whose exceptions it only prints)
            # still ends the command as interrupted.
            if interrupts.interrupted() and exc.code != Interrupted.exit_code:
                fail(INTERRUPTED)
            raise
        code = 0
    except KeyboardInterrupt:  # while the outcome was being reported: it stands, the exit code says why
        code = Interrupted.exit_code
    except SystemExit as exc:
        if exc.code is None or isinstance(exc.code, int):
            code = exc.code or 0
        else:
            print(exc.code, file=sys.stderr)
            code = 1
    interrupts.finish(code)
