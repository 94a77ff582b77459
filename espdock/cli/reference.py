"""espdock's command line as one click command, for the docs' command reference (docs/reference.md:
mkdocs-click reads `command`), so the reference is the CLI itself. Apart from espdock.cli, whose
start never needs it; every command is registered here."""

from __future__ import annotations

import typer.main

from espdock.cli import register

command = typer.main.get_command(register())
