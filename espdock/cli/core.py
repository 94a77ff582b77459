"""What every espdock command shares: the Typer app, loading the workspace and its plan, and turning
espdock's errors and Ctrl-C into a message and an exit code."""

from __future__ import annotations

import errno
import functools
import importlib.abc
import importlib.util
import os
import stat
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, NoReturn, ParamSpec, TextIO

import typer
import typer.core
from rich.console import Console
from rich.text import Text

from espdock import __version__
from espdock.build import prepare
from espdock.build.runner import Runner
from espdock.build.stamps import DIGESTS_FILE, keep_digests, save_digests
from espdock.build.steps import Plan
from espdock.cli.ui import STAMPED, QuietReporter, Reporter, stamped
from espdock.config import Config, invoking_user, load_config, misspelt_variables
from espdock.errors import ConfigError, DiskFull, EspdockBug, EspdockError, Interrupted, WorkspaceError
from espdock.firmware.plan import IdfBuild
from espdock.images import bootstrap
from espdock.images.engine import Engine
from espdock.images.prune import state_dir
from espdock.ros import colcon
from espdock.workspace import (
    Workspace,
    find_workspace,
)

app = typer.Typer(
    help="Build ESP-IDF firmware, micro-ROS and a ROS 2 workspace reproducibly, in containers.",
    no_args_is_help=True,
    add_completion=True,
    pretty_exceptions_enable=False,
)
# 128 + SIGPIPE: what a shell reports for a command a closed pipe ended.
OUTPUT_CLOSED = 141


def output_closed() -> NoReturn:
    """The reader of espdock's output went away (`espdock test | head`): end quietly, as SIGPIPE
    ends a command. The container the command ran is stopped and removed on the way out, as on
    Ctrl-C; stdout goes to /dev/null first, or the exit's flush would fail again."""
    console.quiet = True
    _discard(sys.stdout)
    raise SystemExit(OUTPUT_CLOSED)


def _discard(stream: TextIO) -> None:
    """What is still to be written to STREAM (stdout, stderr) goes to /dev/null: its reader went
    away or its disk is full, and the flush at exit would fail again."""
    os.dup2(os.open(os.devnull, os.O_WRONLY), stream.fileno())


def _stdout_closed() -> bool:
    """Whether stdout is a pipe nobody reads any more, rather than a pipe to a process espdock feeds."""
    import select

    try:
        poller = select.poll()
        poller.register(sys.stdout.fileno(), 0)
    except (OSError, ValueError):  # no file behind it (captured), or closed already
        return False
    return any(events & select.POLLERR for _, events in poller.poll(0))


console = Console(soft_wrap=True)
console.on_broken_pipe = output_closed  # rich's own exits 1, which `espdock verify` gives a changed file
err_console = Console(stderr=True, soft_wrap=True)


def _errors_unread() -> None:
    """The reader of espdock's errors went away (`espdock new X 2>&1 | head -1`): what is left of
    them goes nowhere, and the exit code stays the error's (rich's own would make it 1)."""
    err_console.quiet = True
    _discard(sys.stderr)


err_console.on_broken_pipe = _errors_unread


def _help_console(typer_console: Callable[[bool], Console]) -> Callable[[bool], Console]:
    """Typer's console for help and usage errors, whose reader going away ends espdock as it ends
    for espdock's own: rich's exits 1, and `espdock build --help | grep -q OPTION` failed under
    pipefail as the match came early (a CI step probing for an option)."""

    def made_for(stderr: bool = False) -> Console:
        made = typer_console(stderr)

        def closed() -> None:
            made.quiet = True
            (_errors_unread if stderr else output_closed)()

        made.on_broken_pipe = closed
        return made

    return made_for


class _PatchTyperHelp(importlib.abc.MetaPathFinder):
    """Gives typer.rich_utils espdock's help console when Typer first imports it, which it does
    only to draw help or a usage error: importing it (rich's Markdown and tracebacks) took a
    fifth of every espdock start's CPU. Typer has no hook for its console (0.x, pinned by the lock)."""

    def find_spec(self, name: str, path: object, target: object = None) -> importlib.machinery.ModuleSpec | None:
        if name != "typer.rich_utils":
            return None
        sys.meta_path.remove(self)
        spec = importlib.util.find_spec(name)
        if spec is not None and spec.loader is not None:
            spec.loader = _HelpConsoleLoader(spec.loader)
        return spec


class _HelpConsoleLoader(importlib.abc.Loader):
    """typer.rich_utils' own loader, then the patch. A loader of its own: a zip's importer is one
    object for every module in it, which patching its exec_module would have patched for all."""

    def __init__(self, loader: importlib.abc.Loader) -> None:
        self.loader = loader

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> object:
        return self.loader.create_module(spec)

    def exec_module(self, module: object) -> None:
        self.loader.exec_module(module)
        module._get_rich_console = _help_console(module._get_rich_console)


if (_loaded := sys.modules.get("typer.rich_utils")) is not None:  # imported before espdock (tests)
    _loaded._get_rich_console = _help_console(_loaded._get_rich_console)
else:
    sys.meta_path.insert(0, _PatchTyperHelp())
_state = {"debug": False}
P = ParamSpec("P")

WorkspaceOption = Annotated[
    Path | None, typer.Option("--workspace", "-w", help="Workspace root (default: search upward from here).")
]


INTERRUPTED = Interrupted("interrupted; any container or image build this run had started was stopped and removed")


def command(function: Callable[P, None]) -> Callable[P, None]:
    """Make FUNCTION a command whose espdock errors and Ctrl-C end in a message and an exit code.

    Handled here, inside the command, because Typer would turn Ctrl-C into a bare exit code.
    """

    @functools.wraps(function)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> None:
        try:
            try:
                function(*args, **kwargs)
            finally:
                save_digests()  # what the command read, for the next one; also after a failed build
        except EspdockError as exc:
            fail(exc)
        except KeyboardInterrupt:
            fail(INTERRUPTED)
        except (typer.Exit, typer.Abort, SystemExit):
            raise
        except BrokenPipeError as exc:  # from a plain print (`micro-ros status --json | head`)
            if not _stdout_closed():
                fail(_bug_report(exc))
            output_closed()
        except Exception as exc:  # anything else is espdock's own bug: say so, keep the traceback
            fail(output_failed(exc) or not_writable(exc) or _bug_report(exc))

    return wrapper


def not_writable(exc: BaseException) -> EspdockError | None:
    """EXC as a file espdock must write (its records, install/) on a read-only mount or not this
    user's, or None where it is something else: a bug report named the user's mount."""
    if not isinstance(exc, OSError) or exc.errno not in (errno.EROFS, errno.EACCES, errno.EPERM) or not exc.filename:
        return None
    return WorkspaceError(
        f"espdock cannot use {exc.filename}: {exc.strerror}",
        "The workspace (or the directory named) must be this user's to read and write: a build writes its records "
        "and install/ there. Remount it read-write or fix its owner or mode, then run again.",
    )


def output_failed(exc: BaseException) -> EspdockError | None:
    """EXC as espdock's output finding no room where stdout goes (`espdock build > build.log` on a
    full disk), or None where it is something else."""
    if not isinstance(exc, OSError) or exc.errno != errno.ENOSPC or exc.filename is not None or not _stdout_full():
        return None
    where = _stdout_name()
    _discard(sys.stdout)
    return DiskFull(
        f"espdock could not write its output to {where}: {exc.strerror}",
        "Free space there, or send the output elsewhere, and run the command again.",
    )


def _stdout_full() -> bool:
    """Whether stdout goes to a filesystem with no room left, or a device that takes nothing (/dev/full)."""
    try:
        fd = sys.stdout.fileno()
        if stat.S_ISCHR(os.fstat(fd).st_mode):
            try:
                os.write(fd, b"")  # a terminal takes an empty write; /dev/full refuses any
            except OSError:
                return True
            return False
        free = os.fstatvfs(fd)
    except (OSError, ValueError):
        return False
    return free.f_bavail * free.f_frsize < 1 << 20


def _stdout_name() -> str:
    try:
        return os.readlink(f"/proc/self/fd/{sys.stdout.fileno()}")
    except (OSError, ValueError):
        return "stdout"


def _bug_report(exc: Exception) -> EspdockBug:
    """EXC as a short message, with its traceback written to a log file for the bug report."""
    import tempfile
    import traceback

    text = "".join(traceback.format_exception(exc))
    # Whatever bytes the command line held (not UTF-8: lone surrogates) go into the report as escapes.
    with tempfile.NamedTemporaryFile(
        "w", prefix="espdock-bug-", suffix=".log", delete=False, encoding="utf-8", errors="backslashreplace"
    ) as log:
        log.write(f"espdock {__version__}, {' '.join(sys.argv)}\n{text}")
    return EspdockBug(
        f"espdock failed unexpectedly ({type(exc).__name__}: {exc}); this is a bug in espdock",
        f"Please report it with the traceback in {log.name}.",
    )


def _version(value: bool) -> None:
    if value:
        console.print(f"espdock {__version__}")
        raise typer.Exit()


@app.callback()
def _main(
    debug: Annotated[bool, typer.Option("--debug", help="Show tracebacks for errors.")] = False,
    version: Annotated[
        bool, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")
    ] = False,
) -> None:
    _state["debug"] = debug


# Where notify's notes go: stdout, but for `espdock run` and `shell`, whose stdout is the node's
# own (`espdock run pkg dump > data` took espdock's warnings into the data).
NOTES = {"stderr": False}


def notify(text: str) -> None:
    say(Text(visible(text), style="dim"), err=NOTES["stderr"])


def say(line: Text, err: bool = False) -> None:
    """Print LINE (on stderr: ERR), after the UTC time where the command was asked for --timestamps."""
    (err_console if err else console).print(stamped(line) if STAMPED["lines"] else line)


def visible(text: str) -> str:
    """TEXT with each carriage return that ends no line shown as `\\r`: Rich drops it, and a value
    read from a file with Windows line endings (a script's `crlf_py\\r`) was said as the same
    name it was told to be wrong beside."""
    return text.replace("\r\n", "\n").replace("\r", "\\r")


def load(workspace: Path | None, **overrides: object) -> tuple[Workspace, Config]:
    if workspace is not None and not workspace.is_dir():
        # A workspace looked for above a path that is not there was found where the user was.
        raise ConfigError(f"--workspace {workspace}: no such directory", "Give the workspace's root directory.")
    ws = find_workspace(workspace)
    config = load_config(ws.root, os.environ, overrides)
    for warning in misspelt_variables(os.environ):  # on stderr: `$(espdock list -n)` read them as packages
        say(Text(visible(warning), style="yellow"), err=True)
    state_dir(os.environ)  # checked before any work: a build records its images into it as it ends
    ws = ws.with_layout(config.package_paths, config.colcon_root)
    keep_digests(ws.ws_dir / "build" / DIGESTS_FILE)
    return ws, config


def build_plan(ws: Workspace, config: Config, names: list[str], *args, **options) -> Plan:
    """prepare.build_plan, saying what happened to the rosdep lock on stderr."""
    return prepare.build_plan(ws, config, names, *args, env=os.environ, notify=notify, **options)


class PassThrough(typer.core.TyperCommand):
    """A command whose arguments after the first `--` are not its own: they go as they are to
    the tool it runs (ctx.meta[PASSED], absent when there is no `--`)."""

    def parse_args(self, ctx: typer.Context, args: list[str]) -> list[str]:
        if "--" in args:
            ctx.meta[PASSED] = tuple(args[args.index("--") + 1 :])
            args = args[: args.index("--")]
        try:
            return super().parse_args(ctx, args)
        except typer.TyperException as exc:
            # `espdock build --symlink-install`: click's "No such option" (its NoSuchOption, which
            # Typer carries) alone does not say where it goes.
            option = getattr(exc, "option_name", None)
            if isinstance(option, str) and (said := colcon.misplaced_option(option, self.name or "")):
                exc.message, exc.possibilities = said, None
            raise


PASSED = "espdock.passed_args"


def firmware_plan(
    ws: Workspace, config: Config, name: str, target: str | None = None, installed: bool = False
) -> tuple[Plan, IdfBuild]:
    return prepare.firmware_plan(ws, config, name, os.environ, notify, target, installed)


def runner_for(
    ws: Workspace, config: Config, reporter: Reporter | QuietReporter, engine: Engine | None = None
) -> Runner:
    """A runner on ENGINE, where the caller has connected to it already (over SSH, a connection
    costs a login), else on the engine the environment names."""
    engine = engine or bootstrap.ensure_engine(os.environ, notify)
    return Runner(engine, config, os.environ, reporter, invoking_user(os.environ, ws.root))


def ensure_images(ws: Workspace, config: Config, plan: Plan, engine: Engine | None = None) -> Runner:
    """A runner that has made sure PLAN's images exist (saying so only when it builds one)."""
    reporter = QuietReporter(Reporter(err_console))
    runner = runner_for(ws, config, reporter, engine)
    try:
        runner.run(plan, lock=False)
    finally:
        reporter.close()
    return runner


def fail(exc: EspdockError) -> NoReturn:
    if _state["debug"]:
        import traceback

        traceback.print_exception(exc)
    lines = [Text.assemble(("error: ", "bold red"), visible(exc.message))]
    if exc.hint:
        lines.append(Text.assemble(("hint: ", "yellow"), visible(exc.hint)))
    for line in lines:
        say(line, err=True)
    sys.exit(exc.exit_code)
