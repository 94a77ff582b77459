"""`python -m espdock` and the `espdock` command. Ctrl-C is handled from the start: the CLI's
imports (Typer, rich) take a while, and a signal in that time would otherwise be lost or kill
espdock by SIGINT."""

from espdock import interrupts


def run() -> None:
    interrupts.install()
    from espdock.cli import main

    main()


if __name__ == "__main__":
    run()
