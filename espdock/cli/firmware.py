"""The firmware commands: idf, micro-ros, flash, provision, monitor."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path
from typing import Annotated

import typer
from rich.text import Text

from espdock.build import prepare
from espdock.build.prepare import workspace_packages
from espdock.build.runner import Runner
from espdock.build.steps import EnsureImage, ImageSpec, Plan
from espdock.cli import complete
from espdock.cli.core import (
    WorkspaceOption,
    app,
    command,
    console,
    firmware_plan,
    load,
    notify,
    runner_for,
)
from espdock.cli.ui import Reporter, render_micro_ros_status, render_pins
from espdock.config import Config, check_target, invoking_user
from espdock.errors import ConfigError, WorkspaceError
from espdock.firmware import transport
from espdock.firmware.flashing import (
    Port,
    check_flash_files,
    check_port,
    flash_package,
    idf_port,
    parse_port,
    port_held,
    port_of_env,
    read_flasher_args,
)
from espdock.firmware.install import altered_since_installed, installed_version
from espdock.firmware.pins import pin_idf_image, read_sources, write_pins
from espdock.firmware.plan import IdfBuild, images_to_rebuild, workspace_micro_ros_images
from espdock.firmware.provision import (
    NetSettings,
    check_reads_settings,
    check_settings,
    container_bridge,
    network_settings,
    nvs_image,
    nvs_partition,
    optional_network_settings,
    parse_domain_id,
)
from espdock.firmware.status import micro_ros_report, resolved_sources
from espdock.firmware.steps import built_chip, chip_overrides, reset_build_dir
from espdock.images import bootstrap
from espdock.images.specs import format_argv
from espdock.layout import firmware_build_dir, installed_firmware_dir
from espdock.workspace import Package, Workspace, named_sdkconfig_defaults, read_build_inputs

# idf.py's options that say where the project and its build dir are.
IDF_PLACES = frozenset({"-C", "--project-dir", "-B", "--build-dir"})


@app.command(context_settings={"allow_extra_args": True, "ignore_unknown_options": True})
@command
def idf(
    package: Annotated[str, typer.Argument(help="Firmware package.", autocompletion=complete.firmware_packages)],
    args: Annotated[list[str] | None, typer.Argument(help="Arguments for idf.py (after --).")] = None,
    workspace: WorkspaceOption = None,
) -> None:
    """Run idf.py ARGS for a firmware package in the IDF image (e.g. `espdock idf cam -- menuconfig`)."""
    ws, config = load(workspace)
    if not args:
        raise ConfigError(
            "no idf.py arguments given", f"Put them after --, e.g. `espdock idf {package} -- menuconfig`."
        )
    if screen := next((a for a in ("menuconfig", "monitor") if a in args), None):
        _need_terminal(f"idf.py {screen}")
    if "set-target" in args:
        # IDF's set-target empties the build dir (its fullclean, sdkconfig and espdock's records
        # with it) and then refuses the target, which espdock's build passes as IDF_TARGET.
        raise ConfigError(
            "idf.py set-target is not how espdock changes a package's chip: it would empty "
            f"build/{package} (its sdkconfig too) and then fail on the chip espdock builds it for",
            f'Set CONFIG_IDF_TARGET="CHIP" in {package}\'s sdkconfig.defaults, or build with `espdock build '
            f"{package} --target CHIP`: espdock starts a build dir afresh for a new chip; nothing was changed.",
        )
    if placed := next((a for a in args if a.split("=", 1)[0] in IDF_PLACES), None):
        # espdock passes -C and -B itself: another build dir is one in the container, gone with it.
        raise ConfigError(
            f"idf.py {placed}: espdock decides where {package} is built (-C its project, -B "
            f"build/{package} in the colcon root) and passes them itself",
            "Leave it out; the build dir is where `espdock build`, flash and monitor find it. Nothing ran.",
        )
    plan, step = firmware_plan(ws, config, package)
    if (chip := built_chip(ws, package)) and chip != step.target:
        if "save-defconfig" in args:
            # IDF writes the chip's whole configuration, CONFIG_IDF_TARGET among it, into the file
            # every build of the package reads: the package then built for that chip for good.
            # The files its builds read (IDF's __target_guess takes the chip from the first that names one).
            read = named_sdkconfig_defaults(ws.root / step.project / "CMakeLists.txt") or ("sdkconfig.defaults",)
            raise ConfigError(
                f"build/{package} is a one-off {chip} build (`espdock build --target {chip}`): save-defconfig would "
                f'write its settings, CONFIG_IDF_TARGET="{chip}" among them, into {step.project}/sdkconfig.defaults, '
                f"and every build of {package} would be for {chip} from then on",
                f"Put the {chip} changes in {step.project}/{read[-1]}.{chip} by hand; or `espdock build "
                f'{package}` first, to save {step.target}\'s; or set CONFIG_IDF_TARGET="{chip}" in its '
                f"{read[0]} to make it the package's chip. Nothing was written.",
            )
        # Its build dir holds that chip's sdkconfig, which IDF refuses for another chip's IDF_TARGET
        # (and set-target would empty it): idf.py runs for that chip, as `flash` does.
        notify(
            f"note: build/{package} was last built for {chip} (`espdock build --target {chip}`): idf.py runs for "
            f"{chip}; `espdock build {package}` builds it for {step.target} again"
        )
        plan, step = firmware_plan(ws, config, package, chip)
    if "fullclean" in args:
        cleaned = reset_build_dir(ws, step)
        console.print(
            f"fullclean: emptied {cleaned.relative_to(ws.root)} but its sdkconfig and sdkconfig.old (espdock's reset)"
        )
        args = [a for a in args if a != "fullclean"]
        if not args:
            return
    # `flash` and `monitor` through idf.py: only the port they name goes into the container.
    args = list(port_of_env(args, os.environ))
    port = idf_port(args)
    serial = parse_port(port) if port is not None else None
    if serial is not None:
        check_port(serial)
    console.print(Text(f"in {step.image}: {format_argv(step.argv(tuple(args)))}", style="dim"))
    runner = runner_for(ws, config, Reporter(console))
    if serial is None:
        runner.run(plan)
        code = runner.firmware.run_passthrough(ws, step, tuple(args))
    else:
        with port_held(runner.engine, serial):
            runner.run(plan)
            code = runner.firmware.run_passthrough(
                ws, step, tuple(args), devices=serial.devices, network=serial.network
            )
    if code == 0 and "save-defconfig" in args:
        project = ws.root / step.project
        overrides = chip_overrides(project, step.target, named_sdkconfig_defaults(project / "CMakeLists.txt"))
        if overrides is None:
            notify(
                f"warning: save-defconfig wrote {step.project}/sdkconfig.defaults, which its CMakeLists.txt's "
                "SDKCONFIG_DEFAULTS leaves out: no build reads it; put the lines in a file it names"
            )
        elif overrides:
            notify(
                f"warning: {step.project}: a defaults file IDF reads after sdkconfig.defaults, where save-defconfig "
                f"writes, sets {', '.join(overrides)}: the next sdkconfig made from the defaults has that value; put "
                "the line in that file to keep a menuconfig change"
            )
    raise typer.Exit(code)


def _need_terminal(what: str) -> None:
    """Refuse WHAT (a screen of its own: menuconfig, the monitor) without a terminal to draw it on."""
    if not (sys.stdin and sys.stdin.isatty()):
        raise ConfigError(f"{what} needs a terminal (stdin is not a TTY)", "Run it from an interactive shell.")


def _installed(ws: Workspace, config: Config, plan: Plan, step: IdfBuild) -> tuple[Runner, IdfBuild]:
    """A runner, and STEP as the installed firmware was built (firmware.steps.installed_from):
    its image, made by PLAN only where that is the current one. Says when the firmware is not
    what its sources build now."""
    runner = runner_for(ws, config, Reporter(console))
    built, current = runner.firmware.installed_from(ws, step)
    if current and built.target != step.target:
        # A one-off chip's: current while its sources build the same library for that chip.
        _, for_chip = prepare.firmware_plan(
            ws, config, step.package, os.environ, lambda text: None, built.target, installed=True
        )
        current = for_chip.image_key == built.image_key
    if not current:
        # For the chip it was built for: a plain build would replace a `--target` one's firmware
        # (its build dir's chip, where that chip's image is gone and flash runs in another).
        chip = built.target if built.target != step.target else built_chip(ws, step.package)
        again = f" --target {chip}" if chip and chip != step.target else ""
        console.print(
            Text(
                f"note: the installed firmware of {step.package} is not what its sources build now; this is the one "
                f"built last (`espdock build {step.package}{again}` builds them)",
                style="yellow",
            )
        )
    if not plan.steps and runner.engine.image(built.image) is None:
        # Its sources did not plan (firmware_plan's note): no image of them to make instead.
        raise WorkspaceError(
            f"the micro-ROS image the installed firmware of {step.package} was built in, {built.image}, is gone "
            "from the engine, and its sources do not plan now (the note above)",
            f"Mend them and run `espdock build {step.package}`.",
        )
    if built is step:
        # Only the image: what they write is the installed firmware, which a build swaps in whole,
        # so another board's build in the workspace does not stop them.
        runner.run(plan, lock=False)
    return runner, built


def _micro_ros_specs(
    workspace: Path | None, target: str | None
) -> tuple[Workspace, Config, tuple[Package, ...], dict[str, ImageSpec]]:
    ws, config = load(workspace)
    packages = workspace_packages(ws, config.ros_distro)
    return (
        ws,
        config,
        packages,
        workspace_micro_ros_images(config, read_build_inputs(ws, packages), packages, target and check_target(target)),
    )


micro_ros = typer.Typer(help="The prebuilt micro-ROS library of this workspace.", no_args_is_help=True)
app.add_typer(micro_ros, name="micro-ros")


@micro_ros.command("status")
@command
def micro_ros_status(
    as_json: Annotated[bool, typer.Option("--json", help="Print machine-readable JSON.")] = False,
    target: Annotated[
        str | None, typer.Option(help="Chip for every firmware package (overrides each one's own).")
    ] = None,
    workspace: WorkspaceOption = None,
) -> None:
    """Each micro-ROS image: its key, the inputs it is made of, its firmware, whether it exists."""
    ws, _, packages, specs = _micro_ros_specs(workspace, target)
    engine = bootstrap.ensure_engine(os.environ, notify)
    report = micro_ros_report(engine, specs, packages, read_sources(ws.root))
    if as_json:
        print(json.dumps(report, indent=2, sort_keys=True))
        return
    render_micro_ros_status(console, report)


@micro_ros.command("rebuild")
@command
def micro_ros_rebuild(
    packages: Annotated[
        list[str] | None,
        typer.Argument(
            help="Firmware packages whose images to rebuild (default: all).",
            autocompletion=complete.firmware_packages,
        ),
    ] = None,
    target: Annotated[
        str | None, typer.Option(help="Chip for every firmware package (overrides each one's own).")
    ] = None,
    workspace: WorkspaceOption = None,
) -> None:
    """Rebuild the micro-ROS images for the current inputs from scratch (no build cache)."""
    ws, config, found, specs = _micro_ros_specs(workspace, target)
    chosen = images_to_rebuild(specs, packages or (), [p.name for p in found], ws)
    reporter = Reporter(console)
    try:
        runner_for(ws, config, reporter).run(Plan(ws, tuple(EnsureImage(s, force=True) for s in chosen), chosen))
    finally:
        reporter.close()


@micro_ros.command("pin")
@command
def micro_ros_pin(
    target: Annotated[
        str | None, typer.Option(help="Chip for every firmware package (overrides each one's own).")
    ] = None,
    workspace: WorkspaceOption = None,
) -> None:
    """Pin the sources that follow a branch head ("-" in docker/idf/micro_ros_sources.txt) to the
    commits the current micro-ROS images were built from, and IDF_IMAGE to its digest."""
    ws, config, _, specs = _micro_ros_specs(workspace, target)
    engine = bootstrap.ensure_engine(os.environ, notify)
    owner = invoking_user(os.environ, ws.root)
    pinned = write_pins(ws.root, resolved_sources(engine, specs), owner)
    reference = dict(next(iter(specs.values())).build_args)["IDF_IMAGE"]
    image = engine.image(reference)
    idf = pin_idf_image(ws.root, reference, image.digests if image else (), bool(config.idf_image), owner)
    render_pins(console, pinned, idf)


# ESPPORT and ESPBAUD: idf.py's own variables, which an IDF developer's shell has set.
PortOption = Annotated[
    str,
    typer.Option("--port", "-p", envvar="ESPPORT", help="/dev/ttyUSB0, socket://HOST:PORT or rfc2217://HOST:PORT."),
]
BaudOption = Annotated[
    int | None, typer.Option("--baud", "-b", envvar="ESPBAUD", help="Baud rate (serial devices only).")
]
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
# Text, parsed by espdock: Click's int takes other scripts' digits, '4_2', ' 42 ' and '+42' as 42.
DomainOption = Annotated[
    str | None,
    typer.Option(
        "--domain-id",
        help="ROS_DOMAIN_ID of the board (0..232; default: the one it was built with).",
        show_default=False,
    ),
]


DEFAULT_BAUD = 460800


def _warn_unreachable(settings: NetSettings) -> None:
    """Warn of an agent address only containers reach (`hostname -I` lists docker0's first)."""
    if (bridge := container_bridge(settings.agent_host)) is not None:
        notify(
            f"warning: agent host {settings.agent_host} is on this machine's container bridge ({bridge}), which "
            "containers reach and a board on Wi-Fi does not (the agent listens on the host's network): give the "
            "machine's address on the board's network (`ip -4 addr`)"
        )


def _baud_unused(serial: Port, baud: int | None, ctx: typer.Context) -> None:
    """Refuse a baud rate that is none (esptool took 0 and failed on the port); say so where one
    asked for (--baud, ESPBAUD) goes unused: a raw socket has none. CTX: the command's, which knows
    where the rate came from."""
    if baud is not None and baud <= 0:
        # Typer read it from ESPBAUD where the command line has none: name where it came from.
        # By name: the enum is of whichever click Typer runs on.
        from_env = getattr(ctx.get_parameter_source("baud"), "name", None) == "ENVIRONMENT"
        given = f"ESPBAUD={baud}" if from_env else f"--baud {baud}"
        raise ConfigError(f"{given} is not a baud rate", f"Leave it out for {DEFAULT_BAUD}.")
    if serial.spec.lower().startswith("socket://") and (baud != DEFAULT_BAUD or "ESPBAUD" in os.environ):
        notify(
            f"note: --baud {baud} is not used on {serial.spec}: a raw socket has no baud rate (the serial server's "
            "own is the line's; rfc2217:// lets esptool set it)"
        )


def domain_said(settings: NetSettings, firmware_dir: Path) -> str:
    """The board's ROS domain as provisioned: the one given, else the one its firmware (installed
    at FIRMWARE_DIR) was built with, by its number where the install recorded it."""
    if settings.domain_id is not None:
        return f"ROS domain {settings.domain_id}"
    built = transport.installed_domain_id(firmware_dir)
    number = "" if built is None else f" {built}"
    return f"ROS domain{number} as built (CONFIG_ESPDOCK_ROS_DOMAIN_ID; --domain-id sets another)"


def _say_if_altered(firmware_dir: Path, package: str) -> None:
    """A note where the installed firmware at FIRMWARE_DIR was edited by hand since its install:
    flash and provision write it as it is."""
    if altered_since_installed(firmware_dir):
        console.print(
            Text(
                f"note: the installed firmware of {package} was changed after espdock installed it; this writes it "
                f"as it is (`espdock build {package}` installs the build's again)",
                style="yellow",
            )
        )


def _ask_password() -> str:
    return typer.prompt(
        "Wi-Fi password (empty for an open network)",
        default="",
        show_default=False,
        hide_input=True,
        confirmation_prompt=True,
    )


@app.command()
@command
def flash(
    ctx: typer.Context,
    package: Annotated[
        str, typer.Argument(help="Firmware package (built and installed).", autocompletion=complete.firmware_packages)
    ],
    port: PortOption,
    baud: BaudOption = DEFAULT_BAUD,
    verify: Annotated[bool, typer.Option("--verify", help="Read the flash back and compare afterwards.")] = False,
    wifi_ssid: SsidOption = None,
    wifi_password_file: PasswordFileOption = None,
    agent: AgentOption = None,
    domain_id: DomainOption = None,
    workspace: WorkspaceOption = None,
) -> None:
    """Flash a firmware package's installed artefacts with esptool, passing only that port into the container;
    with --wifi-ssid and --agent, provision its network settings in the same run (see `provision`)."""
    domain = None if domain_id is None else parse_domain_id(domain_id)
    if wifi_ssid is not None and agent is not None:
        _warn_unreachable(check_settings(wifi_ssid, "", agent, domain))  # before anything else: no typo costs a wait
    ws, config = load(workspace)
    serial = parse_port(port)
    _baud_unused(serial, baud, ctx)
    plan, step = firmware_plan(ws, config, package, installed=True)
    provisioning = any(option is not None for option in (wifi_ssid, agent, wifi_password_file, domain_id))
    installed = installed_firmware_dir(ws.ws_dir, package)
    if provisioning:
        transport.check_provisionable(package, ws.root / step.project, step.target, installed)
    # One version of the installed firmware throughout, whatever a build swaps in meanwhile.
    with installed_version(installed) as firmware_dir:
        flasher_args = read_flasher_args(firmware_dir, package)
        check_flash_files(firmware_dir, flasher_args, package)
        _say_if_altered(firmware_dir, package)
        if provisioning:
            check_reads_settings(firmware_dir, package)
        settings = optional_network_settings(wifi_ssid, wifi_password_file, agent, domain, sys.stdin, _ask_password)
        nvs = nvs_partition(firmware_dir, flasher_args, package) if settings else None
        domain_is = domain_said(settings, firmware_dir) if settings else None
        check_port(serial)
        runner, step = _installed(ws, config, plan, step)
        with port_held(runner.engine, serial):
            if settings is not None:
                runner.firmware.check_library_port(ws, step, settings.agent_port)
            say = lambda line: console.print(Text(line))  # noqa: E731
            if settings is None or nvs is None:
                flash_package(runner.firmware, ws, step, firmware_dir, flasher_args, serial, baud, verify, say)
            else:
                with nvs_image(settings, nvs.size, runner.owner) as image:
                    flash_package(
                        runner.firmware, ws, step, firmware_dir, flasher_args, serial, baud, verify, say,
                        nvs_image=(nvs.offset, image),
                    )  # fmt: skip
    what = f" with its network settings ({domain_is})" if settings else ""
    console.print(f"flashed {package}{what} through {port}" + (" and verified it" if verify else ""))


@app.command()
@command
def provision(
    ctx: typer.Context,
    package: Annotated[
        str, typer.Argument(help="Firmware package (built and installed).", autocompletion=complete.firmware_packages)
    ],
    port: PortOption,
    wifi_ssid: Annotated[
        str | None, typer.Option("--wifi-ssid", help="Wi-Fi network the board joins (1..32 bytes); required.")
    ] = None,
    agent: Annotated[
        str | None, typer.Option("--agent", help="micro-ROS agent as IPV4:PORT (no host names); required.")
    ] = None,
    wifi_password_file: PasswordFileOption = None,
    domain_id: DomainOption = None,
    baud: BaudOption = DEFAULT_BAUD,
    workspace: WorkspaceOption = None,
) -> None:
    """Write the board's Wi-Fi and agent settings into its NVS partition, leaving the app as it is.

    The whole NVS partition is replaced: every other namespace on the board is erased.

    The password never appears on a command line (espdock's or esptool's), in the workspace or in an image."""
    domain = None if domain_id is None else parse_domain_id(domain_id)
    if wifi_ssid is not None and agent is not None:
        _warn_unreachable(check_settings(wifi_ssid, "", agent, domain))  # before anything else: no typo costs a wait
    ws, config = load(workspace)
    serial = parse_port(port)
    _baud_unused(serial, baud, ctx)
    plan, step = firmware_plan(ws, config, package, installed=True)
    installed = installed_firmware_dir(ws.ws_dir, package)
    transport.check_provisionable(package, ws.root / step.project, step.target, installed)
    if wifi_ssid is None or agent is None:
        raise ConfigError(f"provisioning {package} needs --wifi-ssid and --agent", "See `espdock provision --help`.")
    with installed_version(installed) as firmware_dir:
        flasher_args = read_flasher_args(firmware_dir, package)
        _say_if_altered(firmware_dir, package)
        check_reads_settings(firmware_dir, package)
        nvs = nvs_partition(firmware_dir, flasher_args, package)
        settings = network_settings(wifi_ssid, wifi_password_file, agent, domain, sys.stdin, _ask_password)
        domain_is = domain_said(settings, firmware_dir)
        check_port(serial)
        runner, step = _installed(ws, config, plan, step)
        with port_held(runner.engine, serial):
            runner.firmware.check_library_port(ws, step, settings.agent_port)
            say = lambda line: console.print(Text(line))  # noqa: E731
            with nvs_image(settings, nvs.size, runner.owner) as image:
                flash_package(
                    runner.firmware, ws, step, firmware_dir, flasher_args, serial, baud, False, say,
                    nvs_image=(nvs.offset, image), app=False,
                )  # fmt: skip
    open_network = "" if settings.password else " (an open network: no password)"
    console.print(
        f"provisioned {package} through {port}: Wi-Fi {settings.ssid!r}{open_network}, agent {settings.agent_host}:"
        f"{settings.agent_port}, {domain_is} (NVS partition '{nvs.label}' at {nvs.offset:#x})"
    )


@app.command()
@command
def monitor(
    package: Annotated[str, typer.Argument(help="Firmware package.", autocompletion=complete.firmware_packages)],
    port: PortOption,
    workspace: WorkspaceOption = None,
) -> None:
    """Open idf.py monitor on PORT for a firmware package (needs a terminal)."""
    ws, config = load(workspace)
    serial = parse_port(port)
    _need_terminal("the monitor")
    check_port(serial)
    plan, step = firmware_plan(ws, config, package, installed=True)
    # As flash: a package never built said its installed firmware was "not what its sources build
    # now", then failed in idf.py.
    read_flasher_args(installed_firmware_dir(ws.ws_dir, package), package)
    build_dir = firmware_build_dir(ws.ws_dir, package)
    if not (build_dir / "project_description.json").is_file():
        # idf.py monitor decodes addresses with the ELF its build dir's description names: after
        # `espdock idf PKG -- fullclean` it said "Cannot load ... Run 'idf.py build' first".
        raise WorkspaceError(
            f"the monitor reads {package}'s build dir, {build_dir}, which holds no build (a fullclean?)",
            f"Run `espdock build {package}` first (flash works from the installed firmware without it).",
        )
    runner, step = _installed(ws, config, plan, step)
    argv = step.argv(("-p", port, "monitor"))
    with port_held(runner.engine, serial):
        code = runner.firmware.run_idf(ws, step, argv, devices=serial.devices, network=serial.network)
    raise typer.Exit(code)
