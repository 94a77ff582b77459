"""`python -m espdock` and the `espdock` command. Ctrl-C is handled from the start: the CLI's
imports (Typer, rich) take a while, and a signal in that time would otherwise be lost or kill
espdock by SIGINT."""

import locale
import os
import sys

from espdock import interrupts


def utf8_mode() -> None:
    """Run again in Python's UTF-8 mode where the locale's encoding is another (en_US.ISO-8859-1,
    ja_JP.EUC-JP). File names are bytes; decoded by such a locale, a UTF-8 workspace path became
    another string, which the engine (given it as UTF-8) did not find, and file names hashed
    into the stamps differed by locale. Output keeps the locale's encoding."""
    if sys.flags.utf8_mode or sys.getfilesystemencoding().lower().replace("-", "") == "utf8" or not sys.executable:
        return
    env = dict(os.environ)
    env.setdefault("PYTHONIOENCODING", f"{locale.getpreferredencoding(False)}:replace")
    os.execve(sys.executable, [sys.executable, "-X", "utf8", *sys.orig_argv[1:]], env)


def run() -> None:
    utf8_mode()
    interrupts.install()
    try:
        from espdock.cli import main
    except KeyboardInterrupt:  # nothing started yet: nothing to clean up
        print("error: interrupted", file=sys.stderr)
        interrupts.finish(interrupts.EXIT_CODE)
    main()


if __name__ == "__main__":
    run()
