"""Serial ports and the esptool / monitor command lines for `espdock flash` and `espdock monitor`."""

from __future__ import annotations

import errno
import fcntl
import json
import os
import posixpath
import re
import shlex
import socket
import stat
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit

from espdock.config import CHIP_TARGETS
from espdock.errors import ConfigError, EspdockError, Interrupted, WorkspaceError
from espdock.firmware import transport
from espdock.firmware.install import flash_file_names
from espdock.firmware.plan import LONGCALLS_RISCV, IdfBuild
from espdock.firmware.provision import IMAGE_MOUNT
from espdock.firmware.steps import FirmwareSteps
from espdock.images.engine import Engine
from espdock.images.machine_lock import lock_holder, machine_lock
from espdock.images.port_urls import port_url_key
from espdock.images.specs import Mount, format_argv
from espdock.images.visibility import workspace_mount
from espdock.layout import FIRMWARE_DIR
from espdock.workspace import Workspace, component_targets

URL_SCHEMES = ("socket", "rfc2217")


# esptool's words (4 and 5) for an image whose minimum chip revision the board is below.
REVISION_REFUSED = "requires chip revision"
_FORCE = re.compile(r"\s*Use --force to flash anyway\.?", re.IGNORECASE)


class PortError(EspdockError):
    """The serial port is missing, busy or unreachable."""

    exit_code = 6


@dataclass(frozen=True)
class Port:
    """A serial port: a device node passed into the container, or a network URL (host network)."""

    spec: str
    device: str | None = None

    @property
    def is_url(self) -> bool:
        return self.device is None

    @property
    def devices(self) -> tuple[str, ...]:
        """The devices a container needs for this port: the port's own, or none for a URL."""
        return (self.device,) if self.device else ()

    @property
    def network(self) -> str | None:
        """The network a container needs for this port: the host's for a URL (it may be on loopback)."""
        return "host" if self.is_url else None


def parse_port(spec: str) -> Port:
    """A device path (/dev/ttyUSB0) or a socket:// / rfc2217:// URL with host and port."""
    if "://" in spec:
        parts = urlsplit(spec)
        try:
            number = parts.port
        except ValueError:  # out of 0..65535, or not a number
            number = None
        if parts.scheme not in URL_SCHEMES or not parts.hostname or not number:
            raise ConfigError(
                f"'{spec}' is not a port espdock can use",
                "Use a device such as /dev/ttyUSB0, socket://HOST:PORT or rfc2217://HOST:PORT.",
            )
        return Port(spec)
    if not spec.startswith("/"):
        raise ConfigError(f"'{spec}' is not a device path", "Give the full path, e.g. /dev/ttyUSB0.")
    return Port(spec, device=spec)


def idf_port(args: Sequence[str]) -> str | None:
    """The serial port in idf.py ARGS (`-p PORT`, `-pPORT`, `--port PORT`, `--port=PORT`), or None.
    idf.py takes it before or after its actions, as click parses them."""
    for index, arg in enumerate(args):
        if arg in ("-p", "--port"):
            return args[index + 1] if index + 1 < len(args) else None
        if arg.startswith("--port="):
            return arg.removeprefix("--port=")
        if arg.startswith("-p") and not arg.startswith("--") and len(arg) > 2:
            return arg[2:]
    return None


def port_of_env(args: Sequence[str], env: Mapping[str, str]) -> tuple[str, ...]:
    """ARGS with `-p $ESPPORT` first where they name no port but an action that uses one, as
    idf.py reads ESPPORT (the container has none of the host's environment)."""
    wanted = any(
        arg.endswith("flash") or arg.startswith("efuse") or arg in PORT_ACTIONS
        for arg in args
        if not arg.startswith("-")
    )
    if idf_port(args) is None and wanted and (port := env.get("ESPPORT")):
        return ("-p", port, *args)
    return tuple(args)


# idf.py's actions that talk to the board, other than the *flash and efuse-* ones (IDF v5.3's
# serial_ext.py and debug_ext.py: those with its PORT option, which reads ESPPORT).
PORT_ACTIONS = frozenset(
    {"monitor", "read-otadata", "read_otadata", "erase-otadata", "erase_otadata", "coredump-info", "coredump-debug"}
)


def check_port_free(engine: Engine, port: Port) -> None:
    """Refuse PORT where another espdock container has its device (a monitor in another terminal,
    the agent of a board on serial): two containers opened it at once, each its own node of the
    device, and the flash or the monitor failed or read the other's bytes."""
    if users := engine.device_users(port.devices, port.spec if port.is_url else None):
        raise PortError(
            f"serial port {port.spec} is busy: the container {users[0]} has it",
            "Stop that (Ctrl-C in its terminal, or `docker stop " + users[0] + "`), then run again.",
        )


@contextmanager
def port_held(engine: Engine, port: Port) -> Iterator[None]:
    """Hold PORT for this command, among the espdock processes of this machine, and refuse it where
    another espdock container has its device (check_port_free). The container check alone let two
    flashes started together both pass, and a monitor start between one flash's containers (it
    runs three): on a board, the two esptools' frames interleave."""

    def busy(holder: str) -> None:
        raise _held_by_espdock(port, holder)

    with machine_lock(_port_lock_name(port), busy):
        check_port_free(engine, port)
        if port.device is not None and (holders := device_holders(port.device)):
            pid, name = holders[0]
            raise PortError(
                f"serial port {port.spec} is busy: {name} (pid {pid}) has it open",
                "Close that program (a terminal program such as screen or minicom, a monitor, an agent), "
                "then run again.",
            )
        yield


def _held_by_espdock(port: Port, holder: str) -> PortError:
    return PortError(
        f"serial port {port.spec} is busy: another espdock has it{holder}",
        "Wait for it to end (a flash), or stop it (a monitor or an agent: Ctrl-C in its terminal), then run again.",
    )


def device_holders(device: str) -> list[tuple[int, str]]:
    """(pid, name) of the processes but this one that have DEVICE open, of those this user may look
    into (/proc/PID/fd: their own, or all as root). A `screen` or a native agent on the port takes
    no lock: check_port's flock passed, and esptool read the other's bytes ("could not tell which
    chip"), or the two wrote at once."""
    try:
        wanted = os.stat(device).st_rdev
    except OSError:
        return []
    # This one and those that started it: a shell keeping the port open for it (`exec 3<>/dev/ttyUSB0`,
    # so that DTR stays as it is) hands espdock the port, and was refused as its holder.
    ours = _ancestors(os.getpid())
    found = []
    for entry in os.scandir("/proc"):
        if not entry.name.isdigit() or int(entry.name) in ours:
            continue
        try:
            with os.scandir(f"/proc/{entry.name}/fd") as fds:
                held = any(_is_device(fd.path, wanted) for fd in fds)
        except OSError:  # another user's, or gone
            continue
        if held:
            try:
                name = Path(f"/proc/{entry.name}/comm").read_text().strip()
            except OSError:
                name = "a process"
            found.append((int(entry.name), name))
    return found


def _ancestors(pid: int) -> set[int]:
    """PID and the processes it was started by, up to init (as far as /proc says)."""
    chain = set()
    while pid > 0 and pid not in chain:
        chain.add(pid)
        try:
            # The fields after the command's name, which may hold spaces and parentheses: state, ppid, ...
            pid = int(Path(f"/proc/{pid}/stat").read_text().rpartition(")")[2].split()[1])
        except (OSError, ValueError, IndexError):
            break
    return chain


def _is_device(path: str, rdev: int) -> bool:
    try:
        info = os.stat(path)
    except OSError:
        return False
    return stat.S_ISCHR(info.st_mode) and info.st_rdev == rdev


def _port_lock_name(port: Port) -> str:
    """One name for each device (its node, by whichever path: /dev/serial/by-id/... is a link) and
    each serial server."""
    if port.is_url:
        key = port_url_key(port.spec) or port.spec
    else:
        try:
            device = os.stat(port.spec).st_rdev
            key = f"dev-{os.major(device)}-{os.minor(device)}"
        except OSError:
            key = port.spec
    return "port-" + re.sub(r"[^A-Za-z0-9._-]", "_", key)


def check_port(port: Port, timeout: float = 3.0, urls: bool = True) -> None:
    """Fail with a clear message if PORT does not exist, is busy, or nothing listens at it (URLS:
    whether the caller could take the port as a socket:// URL instead, which the agent cannot)."""
    # Another espdock's port is said as such before any probe: a serial server takes one client at
    # a time (esp_rfc2217_server listens with a backlog of one), and each probe while another
    # espdock's client was connected queued a connection, until they timed out as "nothing answers".
    if (holder := lock_holder(_port_lock_name(port))) is not None:
        raise _held_by_espdock(port, holder)
    if port.is_url:
        parts = urlsplit(port.spec)
        try:
            with socket.create_connection((parts.hostname, parts.port), timeout=timeout):
                pass
        except OSError as exc:
            raise PortError(
                f"nothing answers at {port.spec}: {exc.strerror or exc}",
                "Start the serial server (esp_rfc2217_server, or the board's bridge) first.",
            ) from exc
        return
    path = Path(port.device)
    try:
        mode = path.stat().st_mode
    except FileNotFoundError:
        raise PortError(f"serial port {path} does not exist", "Is the board plugged in? See `ls /dev/tty*`.") from None
    if not stat.S_ISCHR(mode):
        raise PortError(f"{path} is not a serial device")
    try:
        fd = os.open(path, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK)
    except PermissionError:
        raise PortError(f"no permission to open {path}", "Add yourself to its group (usually dialout).") from None
    except OSError as exc:
        if exc.errno == errno.EBUSY:
            raise PortError(f"serial port {path} is busy", "Close the program using it (a monitor?).") from None
        raise PortError(f"cannot open {path}: {exc.strerror}") from exc
    try:
        if not os.isatty(fd):  # /dev/null, /dev/zero, ...: character devices, not serial ports
            raise PortError(f"{path} is not a serial port", "Serial ports are /dev/ttyUSB*, /dev/ttyACM*, ....")
        # pyserial (esptool, monitors) takes this lock on open: holding it means someone has the port.
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        raise PortError(f"serial port {path} is busy", "Close the program using it (a monitor?).") from None
    finally:
        os.close(fd)
    if os.major(path.stat().st_rdev) in _PTY_MAJORS:
        # The engine makes the node in the container's /dev/pts, its own devpts, where runc cannot
        # open it ("error creating device nodes: ... permission denied").
        said = f"{path} is a pseudo-terminal (an emulator's or socat's serial port), which no container can open"
        if not urls:
            raise PortError(
                said + ", and the micro-ROS agent reads serial devices only (not a socket:// URL)",
                f"Run a micro-ROS agent where the pseudo-terminal is (`micro_ros_agent serial --dev {path}`, "
                "outside a container), or give the board's firmware the Wi-Fi transport and run `espdock agent` "
                "without --port.",
            )
        raise PortError(
            said,
            "Serve it over the network and pass that: QEMU's `-serial tcp::5555,server,nowait` as "
            f"socket://localhost:5555, or `socat TCP-LISTEN:4000,reuseaddr FILE:{shlex.quote(str(path))},raw,echo=0` "
            "as socket://localhost:4000 (esp_rfc2217_server sets the DTR and RTS lines, which a pseudo-terminal "
            "does not have).",
        )


# Unix98 pseudo-terminal slaves (/dev/pts/N): the kernel's devices.txt.
_PTY_MAJORS = range(136, 144)


# An extra (offset, path in the container) to write beside, or instead of, the app's files.
Extra = tuple[int, str]


def flash_argv(
    flasher_args: dict, port: Port, baud: int | None, esptool_major: int, extra: Extra | None = None
) -> tuple[str, ...]:
    """`python -m esptool ... write_flash ...` for the artefacts flasher_args.json describes (and EXTRA)."""
    spell, head, files = _esptool_parts(flasher_args, port, baud, esptool_major, after=None, region=extra)
    options = [spell(a) if a.startswith("--") else a for a in flasher_args.get("write_flash_args", [])]
    return (*head, spell("write_flash"), *options, *files)


def verify_argv(flasher_args: dict, port: Port, esptool_major: int, extra: Extra | None = None) -> tuple[str, ...]:
    """`python -m esptool ... verify_flash ...` for the same artefacts, leaving the chip in its bootloader."""
    spell, head, files = _esptool_parts(flasher_args, port, None, esptool_major, after="no_reset", region=extra)
    return (*head, spell("verify_flash"), *files)


def write_region_argv(flasher_args: dict, port: Port, baud: int | None, esptool_major: int, region: Extra):
    """`python -m esptool ... write_flash OFFSET FILE`: REGION only, the app left as it is."""
    spell, head, _ = _esptool_parts(flasher_args, port, baud, esptool_major, after=None)
    return (*head, spell("write_flash"), hex(region[0]), region[1])


def _esptool_parts(
    flasher_args: dict, port: Port, baud: int | None, esptool_major: int, after: str | None, region: Extra | None = None
):
    # esptool 5 renamed commands and options to hyphens and deprecates the old names;
    # the IDF 5.x images ship esptool 4.x, which only knows the underscores.
    def spell(word: str) -> str:
        dashes = "--" if word.startswith("--") else ""
        body = word[len(dashes) :]
        return dashes + (body.replace("_", "-") if esptool_major >= 5 else body.replace("-", "_"))

    extra = flasher_args.get("extra_esptool_args", {})
    chip = extra.get("chip")
    if not chip:
        raise ConfigError("flasher_args.json names no chip (extra_esptool_args.chip)")
    files = flasher_args.get("flash_files", {})
    if not files:
        raise ConfigError("flasher_args.json lists no flash_files")
    raw_socket = port.spec.startswith("socket://")
    head = ["python", "-m", "esptool", "--chip", chip, "--port", port.spec]
    # A raw socket can neither change the baud rate nor reset the chip (esptool's remote serial docs).
    if baud and not raw_socket:
        head += ["--baud", str(baud)]
    head += ["--before", spell("no_reset" if raw_socket else extra.get("before", "default_reset"))]
    head += ["--after", spell(after or extra.get("after", "hard_reset"))]
    if extra.get("stub") is False:
        head.append(spell("--no_stub"))
    regions = {int(offset, 16): path for offset, path in files.items()}
    if region is not None:
        regions[region[0]] = region[1]
    ordered = [item for offset in sorted(regions) for item in (hex(offset), regions[offset])]
    return spell, head, ordered


def chip_id_argv(port: Port, esptool_major: int) -> tuple[str, ...]:
    """`python -m esptool ... chip_id` with no --chip: esptool detects the connected chip and
    leaves it in its bootloader for the write that follows."""
    raw_socket = port.spec.startswith("socket://")
    reset = "no-reset" if raw_socket else "default-reset"
    words = ("--before", reset, "--after", "no-reset", "chip-id")
    if esptool_major < 5:
        words = tuple(w if w.startswith("--") else w.replace("-", "_") for w in words)
    return ("python", "-m", "esptool", "--port", port.spec, *words)


# Run by the IDF image's Python with the probe's words spelled for esptool 5, then for esptool 4
# (their count first): the esptool it imports picks its own spelling, so the container that probes
# the chip is the only one needed before writing, not a second one asking `esptool version` first.
_SPELLED_FOR_ITS_ESPTOOL = (
    "import runpy, sys, esptool\n"
    "count = int(sys.argv[1])\n"
    "new = int(esptool.__version__.split('.')[0]) >= 5\n"
    "sys.argv = ['esptool', *(sys.argv[2 : 2 + count] if new else sys.argv[2 + count :])]\n"
    "runpy.run_module('esptool', run_name='__main__', alter_sys=True)\n"
)


def chip_probe_argv(port: Port) -> tuple[str, ...]:
    """chip_id_argv for whichever esptool the image holds; esptool's banner in its output
    ('esptool.py v4.12.0', 'esptool v5.6.0') tells esptool_major for the commands that follow."""
    new, old = (chip_id_argv(port, major)[len(("python", "-m", "esptool")) :] for major in (5, 4))
    return ("python", "-c", _SPELLED_FOR_ITS_ESPTOOL, str(len(new)), *new, *old)


def detected_chip(output: list[str]) -> str | None:
    """The chip esptool detected ('Detecting chip type... ESP32-C3', esptool 4 and 5), as an IDF
    target name (esp32c3), if it said."""
    for line in output:
        match = re.search(r"Detecting chip type\.*\s*(ESP[0-9A-Z-]+)", line)
        if match:
            return match.group(1).lower().replace("-", "")
    return None


def buildable_chip(chip: str, supported: Sequence[str], link: str = transport.UDP) -> bool:
    """Whether `espdock build --target CHIP` would build a package that lists SUPPORTED chips
    (none: any) in its idf_component.yml and talks over LINK on CHIP: the checks of
    plan.package_target and transport.check_transport."""
    if transport.lacks_port(link, chip):
        return False
    return chip in CHIP_TARGETS and chip not in LONGCALLS_RISCV and (not supported or chip in supported)


def check_chip(
    package: str,
    expected: str,
    output: list[str],
    port: Port,
    supported: Sequence[str] = (),
    project: Path | None = None,
) -> None:
    """Refuse (before anything is written) a board whose chip is not the one PACKAGE was built for;
    suggest building for the board's chip only where espdock can (SUPPORTED: the package's chips;
    PROJECT: its directory, whose sdkconfig.defaults choose the transport on that chip)."""
    found = detected_chip(output)
    if found is None:
        tail = " | ".join(line.strip() for line in output[-3:] if line.strip())
        raise PortError(f"esptool could not tell which chip is at {port.spec}", tail or "Is a board connected?")
    if found != expected:
        link = transport.project_transport(project, found) if project is not None else transport.UDP
        if buildable_chip(found, supported, link):
            hint = (
                f"Connect an {expected} board, or build {package} for it: `espdock build {package} --target {found}`."
            )
        else:
            hint = f"Connect an {expected} board: espdock cannot build {package} for an {found}"
            if supported and found not in supported:
                hint += f" (it supports {', '.join(supported)})."
            elif transport.lacks_port(link, found):
                hint += f" (its transport is USB-Serial-JTAG, a port an {found} has not)."
            else:
                hint += "."
        raise ConfigError(
            f"the board at {port.spec} is an {found}, but {package} is built for {expected}; nothing was written", hint
        )


def esptool_major(version_output: list[str]) -> int:
    """esptool's major version from the banner it prints as it starts (e.g. 'esptool.py v4.8.1', 'esptool v5.1.0')."""
    for line in version_output:
        match = re.search(r"esptool(?:\.py)? v(\d+)\.", line)
        if match:
            return int(match.group(1))
    raise EspdockError("could not tell esptool's version from: " + " | ".join(version_output[-3:]))


def read_flasher_args(firmware_dir: Path, package: str) -> dict:
    """The installed flasher_args.json of PACKAGE (in FIRMWARE_DIR), checked to be one."""
    args_file = firmware_dir / "flasher_args.json"
    if not args_file.is_file():
        raise WorkspaceError(f"{package} has no installed firmware ({args_file})", f"Run `espdock build {package}`.")
    try:
        flasher_args = json.loads(args_file.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise WorkspaceError(
            f"{args_file} is not valid JSON ({exc}); the installed firmware is damaged",
            f"Run `espdock build {package}` again.",
        ) from None
    if not isinstance(flasher_args, dict):
        raise WorkspaceError(f"{args_file} is not a flasher_args.json object", f"Run `espdock build {package}` again.")
    return flasher_args


def check_flash_files(firmware_dir: Path, flasher_args: dict, package: str) -> None:
    """Refuse to flash PACKAGE's firmware at FIRMWARE_DIR where a file FLASHER_ARGS names is gone:
    said here, not by esptool inside the container, whose "No such file" came back as exit 6, a
    problem with the serial port. (A monitor or a provision writes none of them.)"""
    missing = [name for name in flash_file_names(flasher_args) if not (firmware_dir / name).is_file()]
    if missing:
        # Named by the link the user knows (share/PKG/firmware), not its hidden version directory.
        shown = (
            firmware_dir.parent / FIRMWARE_DIR if firmware_dir.name.startswith(f".{FIRMWARE_DIR}-") else firmware_dir
        )
        raise WorkspaceError(
            f"the installed firmware of {package} lacks {', '.join(missing)} ({shown})",
            f"Run `espdock build {package}`: it installs the build's files again.",
        )


def flash_package(
    steps: FirmwareSteps,
    workspace: Workspace,
    step: IdfBuild,
    firmware_dir: Path,
    flasher_args: dict,
    port: Port,
    baud: int | None,
    verify: bool,
    say: Callable[[str], None],
    nvs_image: tuple[int, Path] | None = None,
    app: bool = True,
) -> None:
    """esptool write_flash (then verify_flash, with VERIFY) of STEP's installed artefacts in
    FIRMWARE_DIR (install.installed_version's, which FLASHER_ARGS were read from) through PORT, in
    STEP's IDF image, with only that port passed in (or the host network for a URL).

    NVS_IMAGE (offset, host file) is written in the same run; without APP, only it is."""
    # The firmware is installed on this machine, not on a workspace volume.
    steps.containers.needs_this_machine(workspace, step.image, "the installed firmware `espdock flash` writes")
    workdir = posixpath.join(workspace_mount(workspace).target, firmware_dir.relative_to(workspace.root).as_posix())
    mounts: tuple[Mount, ...] = ()
    extra: Extra | None = None
    if nvs_image is not None:
        offset, image = nvs_image
        mounts = (Mount(image.parent, IMAGE_MOUNT, read_only=True),)
        extra = (offset, f"{IMAGE_MOUNT}/{image.name}")
    chip = flasher_args.get("extra_esptool_args", {}).get("chip")
    if not chip:
        raise ConfigError("flasher_args.json names no chip (extra_esptool_args.chip)")
    probe: list[str] = []
    steps.run_idf(
        workspace,
        step,
        chip_probe_argv(port),
        on_line=probe.append,
        devices=port.devices,
        network=port.network,
        workdir=workdir,
    )
    try:
        supported = component_targets(workspace.root / step.project / "main" / "idf_component.yml")
    except WorkspaceError:  # mid-edit: the installed firmware's chip is what the board is checked against
        supported = ()
    check_chip(step.package, chip, probe, port, supported, workspace.root / step.project)
    major = esptool_major(probe)
    if app:
        commands = [flash_argv(flasher_args, port, baud, major, extra)]
        if verify:
            commands.append(verify_argv(flasher_args, port, major, extra))
    elif extra is not None:
        commands = [write_region_argv(flasher_args, port, baud, major, extra)]
    else:
        commands = []
    said: list[str] = []

    def line(text: str) -> None:
        said.append(text)
        say(text)

    # What a write cut short leaves, and what writes it whole: provisioning writes the NVS
    # partition alone, which `flash` without the settings never writes again.
    if app:
        half = "its flash is half written, and it may not boot"
        again = f"`espdock flash {step.package} --port {port.spec}`" + (
            " with the same --wifi-ssid/--agent options" if extra is not None else ""
        )
    else:
        half = "its NVS partition (the network settings) is half written; the app is untouched"
        again = f"`espdock provision {step.package} --port {port.spec}` with the same options"
    for at, argv in enumerate(commands):
        say(format_argv(argv))
        said.clear()
        try:
            code = steps.run_idf(
                workspace,
                step,
                argv,
                on_line=line,
                devices=port.devices,
                network=port.network,
                workdir=workdir,
                extra_mounts=mounts,
            )
        except KeyboardInterrupt:
            if _writing(said):
                raise Interrupted(
                    f"interrupted while esptool was writing the board at {port.spec}: {half}",
                    f"Write it again: {again}.",
                ) from None
            raise
        if code != 0 and (revision := next((t for t in said if REVISION_REFUSED in t), None)):
            # esptool checks every image against the chip before it writes: a board matter, not the port's.
            raise ConfigError(
                f"the board at {port.spec} is older than {step.package} is built for: "
                # Without esptool's "Use --force to flash anyway.": flash has no --force.
                f"{_FORCE.sub('', revision.strip().removeprefix('A fatal error occurred: ')).strip()}",
                "Nothing was written. Build it for that revision (the minimum chip revision in its sdkconfig.defaults, "
                f"e.g. CONFIG_{chip.upper()}_REV_MIN_0=y for an early {chip}), or flash a newer board.",
            )
        if code != 0 and at > 0:
            # The read-back after a write that finished: what the board holds is not known to be it.
            raise PortError(
                f"esptool failed (exit code {code}) on {port.spec} reading the flash back: the write before it had "
                "finished, and the board is not verified to hold it",
                "See its output above (a board unplugged, or a flash that differs from the firmware); flash it again "
                "with --verify to write it and check it.",
            )
        if code != 0:
            # Unplugged or reset mid-write: the bootloader and partition table new, the app in part.
            written = f" It had begun writing: {half}; {again} writes it whole." if _writing(said) else ""
            raise PortError(f"esptool failed (exit code {code}) on {port.spec}", f"See its output above.{written}")


def _writing(said: list[str]) -> bool:
    """Whether esptool's output SAID shows it had begun writing the flash ("Writing at 0x...")."""
    return any("Writing at 0x" in text for text in said)
