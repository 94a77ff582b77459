"""espdock's command line as one click command, for the docs' command reference (docs/reference.md:
mkdocs-click reads `command`), so the reference is the CLI itself. Apart from espdock.cli, whose
start never needs it."""

from __future__ import annotations

import typer.main

from espdock.cli import app

command = typer.main.get_command(app)
