"""The espdock command line: parses, calls the library, maps known errors to exit codes."""

from __future__ import annotations

import functools
import json
import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, NoReturn, ParamSpec

import typer
import typer.core
from rich.console import Console
from rich.text import Text

from espdock import __version__, bootstrap, interrupts, nodes
from espdock.colcon import read_colcon_settings
from espdock.config import Config, check_target, invoking_user, load_config, resolve_ca_bundle
from espdock.engine import format_argv
from espdock.errors import ConfigError, EspdockBug, EspdockError, Interrupted, WorkspaceError
from espdock.events import Outcome
from espdock.flashing import check_port, flash_package, parse_port, read_flasher_args
from espdock.layout import ROS_DOCKERFILE, ROSDEP_LOCK, firmware_install_dir
from espdock.lock import check_locks, current_rosdep_inputs, lock_rosdeps, lock_workspace, plan_locks, uv_binary
from espdock.manifest import compare, file_hashes, read_manifest, record_build, write_report
from espdock.pins import pin_idf_image, read_sources, write_pins
from espdock.plan import (
    EnsureImage,
    IdfBuild,
    ImageSpec,
    Plan,
    base_image,
    firmware_step,
    plan_workspace,
    runtime_repository,
    workspace_micro_ros_images,
)
from espdock.provision import network_settings, nvs_image, nvs_partition, optional_network_settings
from espdock.runner import Runner, reset_build_dir, stamp_files
from espdock.scaffold import check_new_package, create_firmware_package, init_compose, init_workspace
from espdock.status import micro_ros_report, resolved_sources
from espdock.ui import QuietReporter, Reporter, render_micro_ros_status, render_packages, render_pins, render_plan
from espdock.workspace import (
    Package,
    PackageKind,
    Workspace,
    discover_packages,
    find_workspace,
    order_packages,
    read_build_inputs,
)

app = typer.Typer(
    help="Build ESP-IDF firmware, micro-ROS and a ROS 2 workspace reproducibly, in containers.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
console = Console(soft_wrap=True)
err_console = Console(stderr=True, soft_wrap=True)
_state = {"debug": False}
P = ParamSpec("P")

WorkspaceOption = Annotated[
    Path | None, typer.Option("--workspace", "-w", help="Workspace root (default: search upward from here).")
]


INTERRUPTED = Interrupted("interrupted; containers started by this run were stopped and removed")


def _command(function: Callable[P, None]) -> Callable[P, None]:
    """Make FUNCTION a command whose espdock errors and Ctrl-C end in a message and an exit code.

    Handled here, inside the command, because Typer would turn Ctrl-C into a bare exit code.
    """

    @functools.wraps(function)
    def wrapper(*args: P.args, **kwargs: P.kwargs) -> None:
        try:
            function(*args, **kwargs)
        except EspdockError as exc:
            _fail(exc)
        except KeyboardInterrupt:
            _fail(INTERRUPTED)
        except (typer.Exit, typer.Abort, SystemExit):
            raise
        except Exception as exc:  # anything else is espdock's own bug: say so, keep the traceback
            _fail(_bug_report(exc))

    return wrapper


def _bug_report(exc: Exception) -> EspdockBug:
    """EXC as a short message, with its traceback written to a log file for the bug report."""
    import tempfile
    import traceback

    text = "".join(traceback.format_exception(exc))
    with tempfile.NamedTemporaryFile("w", prefix="espdock-bug-", suffix=".log", delete=False) as log:
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


def _notify(text: str) -> None:
    console.print(Text(text, style="dim"))


def _load(workspace: Path | None, **overrides: object) -> tuple[Workspace, Config]:
    ws = find_workspace(workspace or Path.cwd())
    config = load_config(ws.root, os.environ, overrides)
    return ws.with_layout(config.package_paths, config.colcon_root), config


def _packages(ws: Workspace) -> tuple[Package, ...]:
    return order_packages(discover_packages(ws))


def _build_plan(
    ws: Workspace,
    config: Config,
    names: list[str],
    only: PackageKind | None = None,
    force: bool = False,
    colcon_args: tuple[str, ...] | None = None,
    locked: bool | None = None,
    target: str | None = None,
) -> Plan:
    """The build's plan; LOCKED not None: first a rosdep lock that answers for the packages
    (refusing a stale one when LOCKED)."""
    packages = _packages(ws)
    inputs = read_build_inputs(ws, packages)
    if locked is not None:
        owner = invoking_user(os.environ, ws.root) if os.geteuid() == 0 else None
        inputs, note = current_rosdep_inputs(ws.root, config, packages, inputs, locked, os.environ, owner)
        if note:
            _notify(note)
    ros = {p.name: p.path for p in packages if p.kind is PackageKind.ROS}
    colcon = read_colcon_settings(ws.ws_dir, ros, colcon_args, os.environ)
    return plan_workspace(ws, config, packages, inputs, tuple(names), only, force, target, colcon)


class _PassThrough(typer.core.TyperCommand):
    """A command whose arguments after the first `--` are not its own: they go as they are to
    the tool it runs (ctx.meta[PASSED], absent when there is no `--`)."""

    def parse_args(self, ctx: typer.Context, args: list[str]) -> list[str]:
        if "--" in args:
            ctx.meta[PASSED] = tuple(args[args.index("--") + 1 :])
            args = args[: args.index("--")]
        return super().parse_args(ctx, args)


PASSED = "espdock.passed_args"


def _firmware_step(ws: Workspace, config: Config, name: str) -> tuple[Plan, IdfBuild]:
    return firmware_step(_build_plan(ws, config, [name]), name)


@app.command(cls=_PassThrough)
@_command
def build(
    ctx: typer.Context,
    packages: Annotated[
        list[str] | None, typer.Argument(help="Build only these packages and what they depend on.")
    ] = None,
    dry_run: Annotated[bool, typer.Option("--dry-run", help="Print the plan without running it.")] = False,
    verbose: Annotated[bool, typer.Option("--verbose", "-v", help="Show image build logs in full.")] = False,
    timestamps: Annotated[
        bool, typer.Option("--timestamps", help="Start every output line with the UTC time (for CI logs).")
    ] = False,
    target: Annotated[
        str | None, typer.Option(help="Chip for the firmware packages built (overrides each one's own).")
    ] = None,
    only: Annotated[PackageKind | None, typer.Option(help="Build only the ROS packages or only the firmware.")] = None,
    force: Annotated[bool, typer.Option("--force", help="Build the packages even when nothing changed.")] = False,
    report: Annotated[
        Path | None, typer.Option("--report", help="Write a JSON summary (steps, outcome, keys, artefacts) here.")
    ] = None,
    locked: Annotated[
        bool | None,
        typer.Option(
            "--locked/--no-locked",
            help="Refuse to build when a lock the images use is missing or stale (default: on when CI=true).",
            show_default=False,
        ),
    ] = None,
    push_cache: Annotated[
        bool,
        typer.Option(
            "--push-cache", help="Push keyed images the cache registry lacks (cache_registry; CI on the main branch)."
        ),
    ] = False,
    workspace: WorkspaceOption = None,
) -> None:
    """Build the images when their inputs changed, then every package whose sources changed and what
    depends on it; record what the build produced in install/espdock-manifest.json.

    Options after `--` go to `colcon build` (e.g. `espdock build -- --cmake-args -DBUILD_TESTING=OFF`)."""
    ws, config = _load(workspace)
    locked = locked if locked is not None else os.environ.get("CI", "").lower() == "true"
    plan = _build_plan(
        ws,
        config,
        packages or [],
        only,
        force,
        ctx.meta.get(PASSED),
        locked,
        target and check_target(target, "--target"),
    )
    if dry_run:
        render_plan(console, plan)
        return
    if locked:
        check_locks(ws.root, plan_locks(plan))
    if push_cache and not config.cache_registry:
        raise ConfigError("--push-cache needs a cache registry", "Set cache_registry or ESPDOCK_CACHE_REGISTRY.")
    reporter = Reporter(console, verbose=verbose, timestamps=timestamps)
    engine = bootstrap.ensure_engine(os.environ, _notify)
    manifest: dict | None = None
    started = time.monotonic()
    try:
        owner = invoking_user(os.environ, ws.root)
        results = Runner(engine, config, os.environ, reporter, owner, push_cache=push_cache).run(plan)
        built = any(r.outcome is not Outcome.CACHED for r in results)
        chown = owner if os.geteuid() == 0 else None
        manifest = record_build(plan, config.target, ws.ws_dir / "install", built, stamp_files(ws), chown)
    finally:
        reporter.close()
        reporter.summary()
        if report is not None:
            write_report(report, reporter.finished, manifest, time.monotonic() - started)


@app.command()
@_command
def lock(
    upgrade: Annotated[
        bool, typer.Option("--upgrade", help="Move every pin to the newest version its source allows.")
    ] = False,
    workspace: WorkspaceOption = None,
) -> None:
    """Compile every dependency lock of the workspace from its source with uv (pinned, with hashes),
    keeping the current pins the sources allow; say which locks changed."""
    ws, config = _load(workspace)
    owner = invoking_user(os.environ, ws.root) if os.geteuid() == 0 else None
    packages = _packages(ws)
    status, database = lock_rosdeps(ws.root, config, packages, read_build_inputs(ws, packages), os.environ, owner)
    if database:  # else: none needed, none there
        console.print(f"{ROSDEP_LOCK}: {status} ({database})")
    for result in lock_workspace(ws.root, uv_binary(), upgrade, owner):
        spec = result.spec
        if result.status == "default":
            console.print(f"{spec.lock}: espdock's default (the workspace has no {spec.source} of its own)")
        else:
            console.print(f"{spec.lock}: {result.status} (from {', '.join(spec.inputs)})")


@app.command()
@_command
def verify(
    manifest: Annotated[Path, typer.Argument(help="An espdock-manifest.json (install/ of the build it describes).")],
    install: Annotated[
        Path | None, typer.Option("--install", help="The install tree to check (default: the manifest's directory).")
    ] = None,
) -> None:
    """Compare an install tree with a build manifest: every missing, extra or changed file; exit 1 on any."""
    data = read_manifest(manifest)
    tree = install or manifest.parent
    differences = compare(data["files"], file_hashes(tree))
    for difference in differences:
        console.print(f"{difference.what:<8} {difference.path}")
    if differences:
        err_console.print(f"{tree} differs from {manifest} in {len(differences)} file(s)")
        raise typer.Exit(1)
    console.print(f"{tree} matches {manifest}: {len(data['files'])} file(s)")


@app.command()
@_command
def new(
    name: Annotated[str, typer.Argument(help="Package name (lower case, digits, underscores).")],
    target: Annotated[
        str | None,
        typer.Option(help="The package's chip: written to its sdkconfig.defaults (CONFIG_IDF_TARGET)."),
    ] = None,
    depends: Annotated[
        list[str] | None, typer.Option("--depends", "-d", help="Interface package the firmware uses (repeatable).")
    ] = None,
    workspace: WorkspaceOption = None,
) -> None:
    """Create NAME beside the workspace's firmware: an ESP-IDF project that is also a ROS 2 package,
    with a micro-ROS app on the shared espdock_uros component (added beside it if missing)."""
    ws, config = _load(workspace)
    packages = _packages(ws)
    check_new_package(name, tuple(depends or ()), packages)
    chip = target and check_target(target, "--target")
    owner = invoking_user(os.environ, ws.root) if os.geteuid() == 0 else None
    path = create_firmware_package(ws, name, tuple(depends or ()), packages, owner, chip)
    console.print(f"created {path.relative_to(ws.root)}; build it with `espdock build {name}`")
    where = f"CONFIG_IDF_TARGET in {name}/sdkconfig.defaults" if chip else "the workspace's `target`"
    console.print(f"chip target {chip or config.target} ({where})")


@app.command()
@_command
def init(
    directory: Annotated[
        Path, typer.Argument(help="The workspace: empty, new, or an existing colcon workspace.")
    ] = Path("."),
) -> None:
    """Make DIRECTORY an espdock workspace: writes a commented espdock.toml with the layout it finds
    (and src/ if there is none) and a starter compose.yaml of its nodes. Only adds files."""
    # As root for someone else: the new files belong to who owns the nearest existing directory.
    existing = next(d for d in (directory.resolve(), *directory.resolve().parents) if d.exists())
    owner = invoking_user(os.environ, existing) if os.geteuid() == 0 else None
    ws, created = init_workspace(directory, owner)
    if "espdock.toml" not in created:
        console.print(f"{ws.root} is an espdock workspace already (espdock.toml exists); nothing changed")
    else:
        console.print(f"made {ws.root} an espdock workspace: created {', '.join(created)}")
    ws, config = _load(ws.root)
    packages = _packages(ws)
    if init_compose(ws, runtime_repository(config, ws), packages, owner):
        console.print("wrote compose.yaml: the workspace's nodes as services (`espdock compose up`)")
    firmware = [p.name for p in packages if p.kind is PackageKind.FIRMWARE]
    ros = [p.name for p in packages if p.kind is PackageKind.ROS]
    console.print(f"layout: packages in {', '.join(ws.package_paths)}; colcon's build/install/log in {ws.colcon_root}")
    console.print(f"found {len(ros)} ROS package(s){': ' + ', '.join(ros) if ros else ''}")
    console.print(f"found {len(firmware)} firmware package(s){': ' + ', '.join(firmware) if firmware else ''}")
    here = "" if directory.resolve() == Path.cwd() else f"cd {directory} && "
    console.print("next:")
    if not firmware:
        console.print(f"  {here}espdock new my_board      # a firmware package (ESP-IDF project + ROS 2 package)")
    console.print(f"  {here}espdock build             # images, then every package, each in its container")


@app.command(context_settings={"allow_extra_args": True, "ignore_unknown_options": True})
@_command
def idf(
    package: Annotated[str, typer.Argument(help="Firmware package.")],
    args: Annotated[list[str] | None, typer.Argument(help="Arguments for idf.py (after --).")] = None,
    workspace: WorkspaceOption = None,
) -> None:
    """Run idf.py ARGS for a firmware package in the IDF image (e.g. `espdock idf cam -- menuconfig`)."""
    ws, config = _load(workspace)
    if not args:
        raise ConfigError(
            "no idf.py arguments given", f"Put them after --, e.g. `espdock idf {package} -- menuconfig`."
        )
    plan, step = _firmware_step(ws, config, package)
    if "fullclean" in args:
        cleaned = reset_build_dir(ws, step)
        console.print(f"fullclean: emptied {cleaned.relative_to(ws.root)} but its sdkconfig (espdock's reset)")
        args = [a for a in args if a != "fullclean"]
        if not args:
            return
    argv = step.argv(tuple(args))
    console.print(Text(f"in {step.image}: {format_argv(argv)}", style="dim"))
    runner = _runner(ws, config, Reporter(console))
    runner.run(plan)
    raise typer.Exit(runner.run_idf(ws, step, argv))


def _micro_ros_specs(
    workspace: Path | None, target: str | None
) -> tuple[Workspace, Config, tuple[Package, ...], dict[str, ImageSpec]]:
    ws, config = _load(workspace)
    packages = _packages(ws)
    return (
        ws,
        config,
        packages,
        workspace_micro_ros_images(config, read_build_inputs(ws, packages), packages, target and check_target(target)),
    )


micro_ros = typer.Typer(help="The prebuilt micro-ROS library of this workspace.", no_args_is_help=True)
app.add_typer(micro_ros, name="micro-ros")


@micro_ros.command("status")
@_command
def micro_ros_status(
    as_json: Annotated[bool, typer.Option("--json", help="Print machine-readable JSON.")] = False,
    target: Annotated[
        str | None, typer.Option(help="Chip for every firmware package (overrides each one's own).")
    ] = None,
    workspace: WorkspaceOption = None,
) -> None:
    """Each micro-ROS image: its key, the inputs it is made of, its firmware, whether it exists."""
    ws, _, packages, specs = _micro_ros_specs(workspace, target)
    engine = bootstrap.ensure_engine(os.environ, _notify)
    report = micro_ros_report(engine, specs, packages, read_sources(ws.root))
    if as_json:
        print(json.dumps(report, indent=2, sort_keys=True))
        return
    render_micro_ros_status(console, report)


@micro_ros.command("rebuild")
@_command
def micro_ros_rebuild(
    target: Annotated[
        str | None, typer.Option(help="Chip for every firmware package (overrides each one's own).")
    ] = None,
    workspace: WorkspaceOption = None,
) -> None:
    """Rebuild the micro-ROS images for the current inputs from scratch (no build cache)."""
    ws, config, _, specs = _micro_ros_specs(workspace, target)
    unique = tuple({spec.key: spec for spec in specs.values()}.values())
    reporter = Reporter(console)
    try:
        _runner(ws, config, reporter).run(Plan(ws, tuple(EnsureImage(s, force=True) for s in unique), unique))
    finally:
        reporter.close()


@micro_ros.command("pin")
@_command
def micro_ros_pin(
    target: Annotated[
        str | None, typer.Option(help="Chip for every firmware package (overrides each one's own).")
    ] = None,
    workspace: WorkspaceOption = None,
) -> None:
    """Pin the sources that follow a branch head ("-" in docker/idf/micro_ros_sources.txt) to the
    commits the current micro-ROS images were built from, and IDF_IMAGE to its digest."""
    ws, config, _, specs = _micro_ros_specs(workspace, target)
    engine = bootstrap.ensure_engine(os.environ, _notify)
    pinned = write_pins(ws.root, resolved_sources(engine, specs))
    reference = dict(next(iter(specs.values())).build_args)["IDF_IMAGE"]
    image = engine.image(reference)
    idf = pin_idf_image(ws.root, reference, image.digests if image else (), bool(config.idf_image))
    render_pins(console, pinned, idf)


PortOption = Annotated[
    str, typer.Option("--port", "-p", help="/dev/ttyUSB0, socket://HOST:PORT or rfc2217://HOST:PORT.")
]
BaudOption = Annotated[int | None, typer.Option("--baud", "-b", help="Baud rate (serial devices only).")]
SsidOption = Annotated[str | None, typer.Option("--wifi-ssid", help="Wi-Fi network the board joins (1..32 bytes).")]
PasswordFileOption = Annotated[
    str | None,
    typer.Option(
        "--wifi-password-file",
        help="File holding the Wi-Fi password (- reads stdin; empty for an open network). Asked for when omitted.",
    ),
]
AgentOption = Annotated[
    str | None, typer.Option("--agent", help="micro-ROS agent as IPV4:PORT (the board resolves no host names).")
]
DomainOption = Annotated[int | None, typer.Option("--domain-id", help="ROS_DOMAIN_ID of the board (0..232).")]


def _ask_password() -> str:
    return typer.prompt(
        "Wi-Fi password (empty for an open network)",
        default="",
        show_default=False,
        hide_input=True,
        confirmation_prompt=True,
    )


@app.command()
@_command
def flash(
    package: Annotated[str, typer.Argument(help="Firmware package (built and installed).")],
    port: PortOption,
    baud: BaudOption = 460800,
    verify: Annotated[bool, typer.Option("--verify", help="Read the flash back and compare afterwards.")] = False,
    wifi_ssid: SsidOption = None,
    wifi_password_file: PasswordFileOption = None,
    agent: AgentOption = None,
    domain_id: DomainOption = None,
    workspace: WorkspaceOption = None,
) -> None:
    """Flash a firmware package's installed artefacts with esptool, passing only that port into the container;
    with --wifi-ssid and --agent, provision its network settings in the same run (see `provision`)."""
    ws, config = _load(workspace)
    serial = parse_port(port)
    plan, step = _firmware_step(ws, config, package)
    firmware_dir = ws.ws_dir / firmware_install_dir(package)
    flasher_args = read_flasher_args(firmware_dir, package)
    settings = optional_network_settings(wifi_ssid, wifi_password_file, agent, domain_id, sys.stdin, _ask_password)
    nvs = nvs_partition(firmware_dir, flasher_args, package) if settings else None
    check_port(serial)
    runner = _runner(ws, config, Reporter(console))
    runner.run(plan)
    say = lambda line: console.print(Text(line))  # noqa: E731
    if settings is None or nvs is None:
        flash_package(runner, ws, step, flasher_args, serial, baud, verify, say)
    else:
        with nvs_image(settings, nvs.size, runner.owner) as image:
            flash_package(runner, ws, step, flasher_args, serial, baud, verify, say, nvs_image=(nvs.offset, image))
    what = " with its network settings" if settings else ""
    console.print(f"flashed {package}{what} through {port}" + (" and verified it" if verify else ""))


@app.command()
@_command
def provision(
    package: Annotated[str, typer.Argument(help="Firmware package (built and installed).")],
    port: PortOption,
    wifi_ssid: Annotated[str, typer.Option("--wifi-ssid", help="Wi-Fi network the board joins (1..32 bytes).")],
    agent: Annotated[str, typer.Option("--agent", help="micro-ROS agent as IPV4:PORT (no host names).")],
    wifi_password_file: PasswordFileOption = None,
    domain_id: Annotated[int, typer.Option("--domain-id", help="ROS_DOMAIN_ID of the board (0..232).")] = 0,
    baud: BaudOption = 460800,
    workspace: WorkspaceOption = None,
) -> None:
    """Write the board's Wi-Fi and agent settings into its NVS partition, leaving the app as it is.

    The whole NVS partition is replaced: every other namespace on the board is erased.

    The password never appears on a command line (espdock's or esptool's), in the workspace or in an image."""
    ws, config = _load(workspace)
    serial = parse_port(port)
    plan, step = _firmware_step(ws, config, package)
    firmware_dir = ws.ws_dir / firmware_install_dir(package)
    flasher_args = read_flasher_args(firmware_dir, package)
    nvs = nvs_partition(firmware_dir, flasher_args, package)
    settings = network_settings(wifi_ssid, wifi_password_file, agent, domain_id, sys.stdin, _ask_password)
    check_port(serial)
    runner = _runner(ws, config, Reporter(console))
    runner.run(plan)
    with nvs_image(settings, nvs.size, runner.owner) as image:
        flash_package(
            runner, ws, step, flasher_args, serial, baud, False, lambda line: console.print(Text(line)),
            nvs_image=(nvs.offset, image), app=False,
        )  # fmt: skip
    console.print(
        f"provisioned {package} through {port}: Wi-Fi {settings.ssid!r}, agent {settings.agent_host}:"
        f"{settings.agent_port}, ROS domain {settings.domain_id} (NVS partition '{nvs.label}' at {nvs.offset:#x})"
    )


@app.command()
@_command
def monitor(
    package: Annotated[str, typer.Argument(help="Firmware package.")],
    port: Annotated[str, typer.Option("--port", "-p", help="/dev/ttyUSB0, socket://HOST:PORT or rfc2217://HOST:PORT.")],
    workspace: WorkspaceOption = None,
) -> None:
    """Open idf.py monitor on PORT for a firmware package (needs a terminal)."""
    ws, config = _load(workspace)
    serial = parse_port(port)
    if not sys.stdin.isatty():
        raise ConfigError("the monitor needs a terminal (stdin is not a TTY)", "Run it from an interactive shell.")
    check_port(serial)
    plan, step = _firmware_step(ws, config, package)
    runner = _runner(ws, config, Reporter(console))
    runner.run(plan)
    devices = (serial.device,) if serial.device else ()
    raise typer.Exit(
        runner.run_idf(
            ws, step, step.argv(("-p", port, "monitor")), devices=devices, network="host" if serial.is_url else None
        )
    )


def _runner(ws: Workspace, config: Config, reporter: Reporter | QuietReporter) -> Runner:
    engine = bootstrap.ensure_engine(os.environ, _notify)
    return Runner(engine, config, os.environ, reporter, invoking_user(os.environ, ws.root))


@app.command()
@_command
def setup() -> None:
    """Make this machine ready: a Docker engine (started or installed), Compose v2, the base image."""
    notify = _notify
    engine = bootstrap.ensure_engine(os.environ, notify)
    bootstrap.ensure_compose(os.environ, notify)
    try:
        ws, config = _load(None)
    except WorkspaceError:
        console.print("engine and compose ready (not in a workspace: no base image to prepare)")
        return
    dockerfile = ws.root / ROS_DOCKERFILE
    base = base_image(config, dockerfile.read_text() if dockerfile.is_file() else "")
    if base:
        how = bootstrap.ensure_base_image(engine, base, config, notify)
        console.print(f"base image {base}: {how}")
    console.print("ready")


@app.command(context_settings={"allow_extra_args": True, "ignore_unknown_options": True, "help_option_names": []})
@_command
def compose(ctx: typer.Context, workspace: WorkspaceOption = None) -> None:
    """Run `docker compose ARGS...` in the workspace with espdock's settings (CA bundle) in its environment."""
    ws, config = _load(workspace)
    notify = _notify
    engine = bootstrap.ensure_engine(os.environ, notify)
    bootstrap.ensure_compose(os.environ, notify)
    env = dict(os.environ)
    ca_bundle = resolve_ca_bundle(config, os.environ)
    if ca_bundle is not None:
        env["ESPDOCK_CA_BUNDLE"] = str(ca_bundle)
    raise typer.Exit(engine.run_compose(ctx.args, ws.root, env))


@app.command(context_settings={"allow_interspersed_args": False, "ignore_unknown_options": True})
@_command
def run(
    package: Annotated[str, typer.Argument(help="A ROS package of the workspace (built).")],
    executable: Annotated[str, typer.Argument(help="One of its executables (install/PKG/lib/PKG/).")],
    args: Annotated[list[str] | None, typer.Argument(help="Arguments for the node (--ros-args ...).")] = None,
    network: Annotated[
        str, typer.Option(help="Docker network: host (the host's DDS traffic), or a compose project's network.")
    ] = nodes.DEFAULT_NETWORK,
    workspace: WorkspaceOption = None,
) -> None:
    """Run EXECUTABLE of a built PACKAGE in the workspace's runtime image, like `ros2 run`
    (espdock's options go before PACKAGE; everything after EXECUTABLE goes to the node)."""
    ws, config = _load(workspace)
    packages = _packages(ws)
    path = nodes.find_executable(ws, packages, package, executable)
    plan, step = nodes.runtime_plan(_build_plan(ws, config, [], PackageKind.ROS))
    runner = _ensure(ws, config, plan)
    image = runner.runtime_spec(ws, step).tag
    tty = sys.stdin.isatty() and sys.stdout.isatty()
    spec = nodes.node_spec(ws, image, path, tuple(args or ()), runner.owner, os.environ, network, tty)
    code, stopped_by = runner.engine.run_foreground(spec)
    raise typer.Exit(128 + stopped_by if stopped_by else code)


@app.command()
@_command
def shell(workspace: WorkspaceOption = None) -> None:
    """Open a shell in the ROS build image with the workspace mounted and its install tree sourced."""
    ws, config = _load(workspace)
    plan, image = nodes.build_image_plan(_build_plan(ws, config, [], PackageKind.ROS))
    runner = _ensure(ws, config, plan)
    spec = nodes.shell_spec(ws, image, runner.owner, os.environ, sys.stdin.isatty() and sys.stdout.isatty())
    code, stopped_by = runner.engine.run_foreground(spec)
    raise typer.Exit(128 + stopped_by if stopped_by else code)


def _ensure(ws: Workspace, config: Config, plan: Plan) -> Runner:
    """A runner that has made sure PLAN's images exist (saying so only when it builds one)."""
    reporter = QuietReporter(Reporter(err_console))
    runner = _runner(ws, config, reporter)
    try:
        runner.run(plan, lock=False)
    finally:
        reporter.close()
    return runner


@app.command("list")
@_command
def list_packages(workspace: WorkspaceOption = None) -> None:
    """List the workspace's packages in build order."""
    ws, _ = _load(workspace)
    render_packages(console, ws, _packages(ws))


def main() -> NoReturn:
    """Entry point: Ctrl-C and SIGTERM (CI timeouts, `docker stop`) end any command (espdock.interrupts)."""
    interrupts.install()
    try:
        try:
            app()
        except KeyboardInterrupt:  # in Typer's own code, before or after the command
            _fail(INTERRUPTED)
        except SystemExit as exc:
            # A Ctrl-C that Python swallowed (raised in a callback whose exceptions it only prints)
            # still ends the command as interrupted.
            if interrupts.interrupted() and exc.code != Interrupted.exit_code:
                _fail(INTERRUPTED)
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


def _fail(exc: EspdockError) -> NoReturn:
    if _state["debug"]:
        import traceback

        traceback.print_exception(exc)
    err_console.print(Text.assemble(("error: ", "bold red"), exc.message))
    if exc.hint:
        err_console.print(Text.assemble(("hint: ", "yellow"), exc.hint))
    sys.exit(exc.exit_code)
