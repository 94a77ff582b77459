"""Renders runner events on the terminal with rich: a live status per step, then a summary."""

from __future__ import annotations

import threading
import time
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, assert_never

from rich.console import Console
from rich.control import strip_control_codes
from rich.text import Text

from espdock.build.steps import EnsureBaseImage, EnsureImage, Plan
from espdock.events import Event, Outcome, StepFinished, StepNote, StepOutput, StepStarted
from espdock.firmware.pins import IdfPin, Source
from espdock.firmware.plan import IdfBuild, InstallFirmware
from espdock.layout import IDF_DOCKERFILE, SOURCES_FILE, firmware_install_dir
from espdock.ros.plan import ColconBuild, RuntimeImage
from espdock.workspace import Package, Workspace

if TYPE_CHECKING:
    from rich.status import Status
    from rich.table import Table


def _table(*columns: str, **options: object) -> Table:
    """A rich Table, imported when a summary is drawn: not at every start of a command that
    draws none (`espdock test`, `run`), whose time around the tool it runs counts."""
    from rich.table import Table

    return Table(*columns, **options)


MARKS = {
    Outcome.BUILT: ("✓", "green"),
    Outcome.CACHED: ("•", "cyan"),
    Outcome.PULLED: ("↓", "cyan"),
    Outcome.FAILED: ("✗", "red"),
}


# Set by a command asked for --timestamps: its notes and error lines (espdock.cli.core.say, fail),
# not only its steps' (Reporter), then start with the UTC time.
STAMPED = {"lines": False}


STAMP_EXAMPLE = "12:00:00 "


def stamped(text: Text) -> Text:
    """TEXT after the UTC time, as --timestamps starts every line."""
    return Text.assemble((time.strftime("%H:%M:%S ", time.gmtime()), "dim"), text)


class Reporter:
    """Turns events into terminal output; verbose shows image build logs too.

    Without a terminal (CI logs) there is no live status line: every line is printed,
    image build progress included, optionally after a UTC timestamp (TIMESTAMPS), and a step
    silent for SILENT seconds (a cache push, a long CMake configure) is said to be still running."""

    SILENT = 60.0
    _LOOK_EVERY = 5.0

    def __init__(self, console: Console, verbose: bool = False, timestamps: bool = False) -> None:
        self.console = console
        self.verbose = verbose or not console.is_terminal
        self.timestamps = timestamps
        self.finished: list[StepFinished] = []
        self._status: Status | None = None
        # The step running without a terminal, since when, and when anything was last printed:
        # what the watcher thread reads (under _lock, which every print takes).
        self._lock = threading.RLock()
        self._running: tuple[str, float] | None = None
        self._printed = time.monotonic()
        self._watcher: threading.Thread | None = None
        self._closed = threading.Event()

    def _print(self, text: Text, **options: object) -> None:
        with self._lock:
            self._printed = time.monotonic()
            self.console.print(stamped(text) if self.timestamps else text, **options)

    def _stamp(self) -> str:
        return time.strftime("%H:%M:%S ", time.gmtime()) if self.timestamps else ""

    def _watch(self) -> None:
        while not self._closed.wait(self._LOOK_EVERY):
            with self._lock:
                now = time.monotonic()
                if self._running is None or now - self._printed < self.SILENT:
                    continue
                step, started = self._running
                said = f"  {step}: still running, {now - started:.0f} s in, {now - self._printed:.0f} s without output"
                self._printed = now
                try:  # written as _line writes; a closed output is the command's to find, not this thread's
                    self.console.file.write(f"{self._stamp()}{said}\n")
                    self.console.file.flush()
                except (OSError, ValueError):
                    return

    def line(self, text: str | Text) -> None:
        """Print TEXT (a tool's output line as it is, or espdock's own), timestamped when asked."""
        with self._lock:
            self._printed = time.monotonic()
            self._line(text)

    def _line(self, text: str | Text) -> None:
        if isinstance(text, str) and self._status is None and not self.console.is_terminal:
            # A tool's output into a log or pipe, where rich has nothing to style: written as
            # rich would (control codes stripped, tabs expanded, no wrapping) at a twentieth of
            # its cost per line, which a test suite's thousands of lines add up to seconds of.
            try:
                line = strip_control_codes(text).expandtabs(self.console.tab_size)
                self.console.file.write(f"{self._stamp()}{line}\n")
                self.console.file.flush()
            except BrokenPipeError:  # as rich's own writes handle it
                self.console.on_broken_pipe()
            return
        self._print(Text(text) if isinstance(text, str) else text, soft_wrap=True)

    def __call__(self, event: Event) -> None:
        match event:
            case StepStarted():
                if self.console.is_terminal:
                    self._status = self.console.status(Text(event.step, style="bold"))
                    self._status.start()
                else:
                    with self._lock:
                        self._running = (event.step, time.monotonic())
                        self._print(Text(event.step, style="bold"))
                    if self._watcher is None:
                        self._watcher = threading.Thread(target=self._watch, name="espdock-silence", daemon=True)
                        self._watcher.start()
            case StepNote():
                self._print(Text(f"  {event.text}", style="dim"))
            case StepOutput(status=True):
                if self._status is not None:
                    self._status.update(Text.assemble((event.step, "bold"), "  ", (event.line[:100], "dim")))
            case StepOutput(progress=True) if not self.verbose:
                if self._status is not None:
                    self._status.update(Text.assemble((event.step, "bold"), "  ", (event.line[:100], "dim")))
            case StepOutput():
                self.line(event.line)
            case StepFinished():
                self._running = None
                if self._status is not None:
                    self._status.stop()
                    self._status = None
                mark, colour = MARKS[event.outcome]
                self._print(
                    Text.assemble(
                        (f"{mark} ", colour),
                        (event.step, "bold"),
                        f"  {event.outcome.value}",
                        (f"  {event.seconds:.1f} s", "dim"),
                        (f"  {event.detail}" if event.detail else "", "dim"),
                    )
                )
                self.finished.append(event)
            case _:
                assert_never(event)

    def close(self) -> None:
        self._closed.set()
        if self._status is not None:
            self._status.stop()
            self._status = None

    def summary(self) -> None:
        if not self.finished:
            return
        table = _table(title="espdock build", title_justify="left")
        table.add_column("step", overflow="fold")  # whole in an 80-column CI log, never cut short
        table.add_column("result")
        table.add_column("time", justify="right")
        table.add_column("detail", overflow="fold")
        for event in self.finished:
            _, colour = MARKS[event.outcome]
            table.add_row(event.step, Text(event.outcome.value, style=colour), f"{event.seconds:.1f} s", event.detail)
        # Into a CI log, at the table's own width: an image tag or a path folded at 80 columns is
        # found by no grep.
        console = wide(self.console)
        if not self.timestamps:
            console.print(table)
            return
        narrower = console.options.update(width=max(40, console.width - len(STAMP_EXAMPLE)))
        for line in console.render_lines(table, narrower, pad=False, new_lines=False):
            console.print(stamped(Text.assemble(*((seg.text, seg.style) for seg in line))), soft_wrap=True)


def wide(console: Console) -> Console:
    """CONSOLE at a terminal; into a pipe or a file, one as wide as what it prints."""
    if console.is_terminal:
        return console
    unbounded = Console(file=console.file, width=10_000, no_color=console.no_color, soft_wrap=True)
    unbounded.on_broken_pipe = console.on_broken_pipe
    return unbounded


class QuietReporter:
    """For commands that ensure images before they run something (`run`, `shell`): silent while
    every step is a cache hit; a step that builds is shown as Reporter shows it."""

    def __init__(self, reporter: Reporter) -> None:
        self._reporter = reporter
        self._held: list[Event] = []
        self._live = False

    def __call__(self, event: Event) -> None:
        if self._live:
            self._reporter(event)
            return
        self._held.append(event)
        if isinstance(event, StepOutput) or (isinstance(event, StepFinished) and event.outcome is not Outcome.CACHED):
            self._live = True
            for held in self._held:
                self._reporter(held)
            self._held.clear()
        elif isinstance(event, StepFinished):
            self._held.clear()

    def close(self) -> None:
        self._reporter.close()


def nothing_to_build(workspace: Workspace) -> str:
    """What a build of a workspace without packages says: where it looked (package_paths), and
    which of those places do not exist (a typo in espdock.toml)."""
    missing = [rel for rel in workspace.package_paths if not (workspace.root / rel).is_dir()]
    said = f"nothing to build: no packages in {', '.join(workspace.package_paths)} (package_paths)"
    if missing:
        said += f"; {', '.join(missing)} does not exist in {workspace.root}"
    return said


def render_plan(console: Console, plan: Plan, states: Sequence[str] = ()) -> None:
    """Print the steps a plan would run, without running them (--dry-run), each with its STATE."""
    from espdock.images.specs import format_argv

    console.print(Text(f"workspace {plan.workspace.root}", style="bold"))
    if not plan.steps:
        console.print(nothing_to_build(plan.workspace))
    for number, step in enumerate(plan.steps, 1):
        console.print(Text(f"{number}. {step.name}", style="bold"))
        match step:
            case EnsureBaseImage():
                made_so = "build it with debootstrap" if step.debootstrap else "stop: `docker load` it"
                console.print(f"   use {step.image} if present, else pull it, else {made_so}")
            case EnsureImage():
                spec = step.spec
                console.print(f"   {spec.tag} from {spec.dockerfile} stage {spec.target} (key {spec.key})")
                if spec.origin:
                    console.print(Text(f"     {spec.origin}", style="dim"))
                for name, sha in spec.inputs:
                    console.print(Text(f"     {name}  {sha[:12]}", style="dim"))
            case ColconBuild():
                console.print(f"   in {step.image}, {step.workdir}: {format_argv(step.argv())}")
                console.print(Text(f"     packages: {', '.join(step.building)}", style="dim"))
                console.print(
                    Text("     colcon gets only the changed ones and their dependents (--packages-select)", style="dim")
                )
            case IdfBuild():
                console.print(f"   in {step.image} (target {step.target}): {format_argv(step.argv())}")
            case InstallFirmware():
                console.print(f"   artefacts to {firmware_install_dir(step.package)}, package.xml, ament index")
            case RuntimeImage():
                console.print(f"   {step.repository}:<key> and {step.stable_tag}: {step.base.tag} plus install/")
                console.print(Text(f"     packages: {', '.join(step.packages)}", style="dim"))
            case _:
                assert_never(step)
        if len(states) >= number:
            state = states[number - 1]
            console.print(
                Text.assemble("   now: ", (state, "green" if state.startswith(("up to date", "present")) else "yellow"))
            )


def render_micro_ros_status(console: Console, report: dict) -> None:
    """Print `espdock micro-ros status` for people: one block per micro-ROS image."""
    for image in report["images"]:
        state = "present" if image["present"] else "not built"
        console.print(Text.assemble(("micro-ROS image ", "bold"), image["image"], f"  ({state})"))
        console.print(f"for     {', '.join(image['firmware_packages'])} (chip {image['target']})")
        console.print(f"key     {image['key']}")
        for name, value in image["build_args"].items():
            console.print(f"{name:<18}{value}")
        console.print(f"interface packages {', '.join(image['interface_packages']) or '(none)'}")
        if image["present"]:
            console.print(f"size    {image['size_bytes'] / 1e6:.0f} MB, built {image['created']}")
            console.print(f"built from {len(image['built_from'])} pinned source repositories")
            console.print(Text("the workspace matches this image", style="green"))
        else:
            console.print(Text("no image has this key: `espdock build` will build it", style="yellow"))
            if "closest_image" in image:
                changed = ", ".join(image["changed_inputs"])
                console.print(f"closest image {image['closest_image']} differs in: {changed}")
        table = _table("input", "sha256", title="inputs", title_justify="left")
        for name, sha in sorted(image["inputs"].items()):
            table.add_row(name, sha[:16])
        console.print(table)
    if report["following_branch_head"]:
        console.print(
            Text(
                f"{len(report['following_branch_head'])} micro-ROS sources follow a branch head, not a commit: "
                "run `espdock micro-ros pin` after a build to pin them",
                style="yellow",
            )
        )


def render_pins(console: Console, pinned: list[Source], idf: IdfPin | None) -> None:
    """`espdock micro-ros pin`: the sources it pinned, and what became of the IDF image's reference."""
    for source in pinned:
        console.print(f"pinned {source.url} ({source.branch}) at {source.commit}")
    if pinned:
        console.print(f"wrote {SOURCES_FILE}; the next build makes images under new keys")
    else:
        console.print("every micro-ROS source the images were built from is pinned already")
    if idf is None:
        return
    if idf.digest is None:
        console.print(f"{idf.reference} is pinned by tag only: this engine did not pull it from a registry")
    elif not idf.written:
        console.print(f"{idf.reference} comes from idf_image; pin it there: {idf.reference}@{idf.digest}")
    else:
        console.print(f"pinned IDF_IMAGE in {IDF_DOCKERFILE} to its digest")


def render_packages(
    console: Console, workspace: Workspace, packages: tuple[Package, ...], chips: Mapping[str, str]
) -> None:
    """`espdock list`: PACKAGES (in build order) with kind, build type (a firmware's with its chip,
    CHIPS) and workspace dependencies."""
    table = _table(title=str(workspace.root), title_justify="left")
    for column in ("package", "kind", "build type", "depends on (in workspace)"):
        # Folded at a narrow terminal: cut with an ellipsis, `camera…` named no package.
        table.add_column(column, overflow="fold")
    names = {p.name for p in packages}
    for p in packages:
        build_type = f"{p.build_type} ({chips[p.name]})" if p.name in chips else p.build_type
        table.add_row(p.name, p.kind.value, build_type, ", ".join(sorted(p.depends & names)))
    # Into a pipe or a file, at the table's own width: a name cut at 80 columns is another name.
    wide(console).print(table)
