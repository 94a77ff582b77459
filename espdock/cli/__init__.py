"""The espdock command line: parses, calls the library, maps known errors to exit codes.

Each command lives with its kind: workspace.py (build, lock, verify, new, init, setup, list,
colcon-extension), testing.py (test), firmware.py (idf, micro-ros, flash, provision, monitor),
nodes.py (compose, run, shell), prune.py (prune, imported by workspace.py: a build records and
prunes) and agent.py (the micro-ROS agent). Importing one registers its commands on the app.

`espdock CMD` imports only CMD's module: Typer makes a click command of every registered
command at each start, and the modules import the firmware, lock and image code the others
need; together a fifth of a second before anything runs, which a command as quick as a
re-run of `espdock test` feels. Anything else (`--help`, a name espdock does not know, the
docs' reference) registers them all, in the order `espdock --help` lists them."""

from __future__ import annotations

import contextlib
import importlib
import inspect
import os
import sys
from collections.abc import Sequence
from typing import NoReturn

import typer

from espdock import interrupts
from espdock.cli import core, home
from espdock.cli.core import INTERRUPTED, app, command, fail, output_failed
from espdock.errors import Interrupted

MODULES = ("workspace", "testing", "firmware", "nodes", "agent")
# Which module registers each top-level command (tests/unit/test_cli.py checks it against them).
COMMANDS = {
    **dict.fromkeys(("build", "lock", "verify", "new", "init", "setup", "list", "colcon-extension"), "workspace"),
    "prune": "prune",
    "test": "testing",
    **dict.fromkeys(("idf", "micro-ros", "flash", "provision", "monitor"), "firmware"),
    **dict.fromkeys(("compose", "run", "shell"), "nodes"),
    "agent": "agent",
}

__all__ = ["app", "command", "main", "register"]


def register(argv: Sequence[str] | None = None) -> typer.Typer:
    """The app with the command ARGV names registered, or, ARGV None or naming none espdock
    knows, every command."""
    # The first word that is not an option is the command: the app's own options are all flags.
    name = next((arg for arg in argv or () if not arg.startswith("-")), None)
    for module in (COMMANDS[name],) if name in COMMANDS and "--help" not in argv[: argv.index(name)] else MODULES:
        importlib.import_module(f"espdock.cli.{module}")
    _one_line_summaries(core.app)
    return app


def _one_line_summaries(group: typer.Typer) -> None:
    """Each command's summary in a list of commands (`espdock --help`) as one paragraph: Typer's
    rich help keeps a docstring's line breaks there, and every summary broke off mid-sentence
    ("keeping the last few of" / "each kind; ...") where its source line ended."""
    for info in group.registered_commands:
        if info.short_help is None:
            text = info.help or inspect.getdoc(info.callback) or ""
            info.short_help = " ".join(text.split("\n\n")[0].split())
    for sub in group.registered_groups:
        if sub.typer_instance is not None:
            _one_line_summaries(sub.typer_instance)


UTF8 = ("utf-8", "utf8")


def main() -> NoReturn:
    """Entry point: Ctrl-C, SIGTERM (CI timeouts, `docker stop`) and SIGHUP end any command (espdock.interrupts)."""
    interrupts.install()
    hand_back = home.kept(os.environ)
    for stream in (sys.stdout, sys.stderr):
        # A Latin-1 or ASCII locale (or PYTHONIOENCODING) cannot write a bullet or a workspace's
        # non-ASCII path: a `?` for each such character, not a crash.
        if stream is not None and hasattr(stream, "reconfigure") and (stream.encoding or "").lower() not in UTF8:
            stream.reconfigure(errors="replace")
    try:
        try:
            register(sys.argv[1:])
            app(prog_name="espdock")  # `python -m espdock` too: its help and completion are the command's
        except KeyboardInterrupt:  # in Typer's own code, before or after the command
            fail(INTERRUPTED)
        except OSError as exc:  # in Typer's: its help, `--version`
            if failed := output_failed(exc):
                fail(failed)
            raise
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
    with contextlib.suppress(OSError):
        hand_back()
    interrupts.finish(code)
