"""`python -m espdock` and the `espdock` command. Ctrl-C is handled from the start: the CLI's
imports (Typer, rich) take a while, and a signal in that time would otherwise be lost or kill
espdock by SIGINT."""

import sys

from espdock import interrupts


def run() -> None:
    interrupts.install()
    try:
        from espdock.cli import main
    except KeyboardInterrupt:  # nothing started yet: nothing to clean up
        print("error: interrupted", file=sys.stderr)
        interrupts.finish(interrupts.EXIT_CODE)
    main()


if __name__ == "__main__":
    run()
