"""espdock new, flashing command lines, port checks and the atomic firmware install."""

import json
import os
import pty
import socket
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import pytest

from espdock.errors import BuildFailed, ConfigError, WorkspaceError
from espdock.firmware.flashing import (
    PortError,
    check_chip,
    check_port,
    esptool_major,
    flash_argv,
    idf_port,
    parse_port,
    port_held,
    port_of_env,
    verify_argv,
    write_region_argv,
)
from espdock.firmware.install import altered_since_installed, install_firmware
from espdock.firmware.scaffold import create_firmware_package, validate_package_name
from espdock.workspace import Package, PackageKind, Workspace, discover_packages
from tests.conftest import espdock
from tests.ports import free_port

FLASHER_ARGS = {
    "write_flash_args": ["--flash_mode", "dio", "--flash_size", "2MB", "--flash_freq", "40m"],
    "flash_files": {
        "0x10000": "cam.bin",
        "0x1000": "bootloader/bootloader.bin",
        "0x8000": "partition_table/partition-table.bin",
    },
    "extra_esptool_args": {"after": "hard_reset", "before": "default_reset", "stub": True, "chip": "esp32"},
}


@pytest.mark.parametrize("name", ["cam", "camera_node", "led2", "a1_b2"])
def test_valid_package_names(name):
    validate_package_name(name)


@pytest.mark.parametrize("name", ["Camera", "2cam", "cam-node", "cam__node", "cam_", "", "a", "cam node", "../x"])
def test_invalid_package_names_are_refused(name):
    with pytest.raises(ConfigError, match="not a valid ROS package name"):
        validate_package_name(name)


def test_new_creates_a_firmware_package_that_discovery_sees(tmp_path):
    ws = Workspace(tmp_path)
    (tmp_path / "espdock.toml").write_text("[espdock]\n")
    interface = Package("custom_interface", tmp_path / "ws/src/ci", PackageKind.ROS, "ament_cmake", frozenset(), True)
    path = create_firmware_package(ws, "blinky", ("custom_interface",), (interface,))
    assert (path / "main/main.c").is_file()
    assert "project(blinky)" in (path / "CMakeLists.txt").read_text()
    assert "$ENV{UROS_COMPONENT_DIR}" in (path / "CMakeLists.txt").read_text()
    json.loads((path / "app-colcon.meta").read_text())
    (package,) = discover_packages(ws)
    assert package.name == "blinky" and package.kind is PackageKind.FIRMWARE
    assert package.depends == {"std_msgs", "custom_interface"}
    assert package.build_type == "esp_idf"
    assert not [p for p in (ws.root / "firmware").iterdir() if p.name.startswith(".")], "no staging leftovers"
    # The shared component the app builds on comes along, once.
    assert (tmp_path / "firmware/components/espdock_uros/include/espdock_uros.h").is_file()
    assert path.stat().st_mode & 0o055 == 0o055, "readable by the build user, like any new directory"


def test_new_refuses_an_existing_directory_and_keeps_it(tmp_path):
    ws = Workspace(tmp_path)
    existing = (ws.root / "firmware") / "blinky"
    existing.mkdir(parents=True)
    (existing / "mine.c").write_text("keep me")
    with pytest.raises(WorkspaceError, match="already exists"):
        create_firmware_package(ws, "blinky", (), ())
    assert (existing / "mine.c").read_text() == "keep me"


def test_flash_argv_for_esptool4_and_5():
    port = parse_port("/dev/ttyUSB0")
    v4 = flash_argv(FLASHER_ARGS, port, 460800, 4)
    assert v4 == (
        "python", "-m", "esptool", "--chip", "esp32", "--port", "/dev/ttyUSB0", "--baud", "460800",
        "--before", "default_reset", "--after", "hard_reset", "write_flash",
        "--flash_mode", "dio", "--flash_size", "2MB", "--flash_freq", "40m",
        "0x1000", "bootloader/bootloader.bin", "0x8000", "partition_table/partition-table.bin", "0x10000", "cam.bin",
    )  # fmt: skip
    v5 = flash_argv(FLASHER_ARGS, port, 460800, 5)
    assert "write-flash" in v5 and "--flash-mode" in v5 and "default-reset" in v5
    assert not [a for a in v5 if a.startswith("--") and "_" in a]


def test_raw_socket_ports_get_no_baud_and_no_reset():
    argv = flash_argv(FLASHER_ARGS, parse_port("socket://127.0.0.1:9876"), 460800, 5)
    assert "--baud" not in argv
    assert argv[argv.index("--before") + 1] == "no-reset"


def test_verify_reads_back_the_same_files_without_flash_options():
    argv = verify_argv(FLASHER_ARGS, parse_port("rfc2217://host:4000"), 4)
    assert argv[argv.index("verify_flash") + 1:] == (
        "0x1000", "bootloader/bootloader.bin", "0x8000", "partition_table/partition-table.bin", "0x10000", "cam.bin",
    )  # fmt: skip
    assert argv[argv.index("--after") + 1] == "no_reset"


def test_esptool_version_parsing():
    assert esptool_major(["esptool.py v4.8.1", "4.8.1"]) == 4
    assert esptool_major(["esptool v5.1.0"]) == 5


@pytest.mark.parametrize("spec", ["ttyUSB0", "tcp://x:1", "socket://nohost", "rfc2217://:4000"])
def test_bad_port_specs_are_refused(spec):
    with pytest.raises(ConfigError):
        parse_port(spec)


@pytest.mark.parametrize(
    ("args", "port"),
    [
        (["-p", "/dev/ttyUSB0", "flash"], "/dev/ttyUSB0"),
        (["flash", "monitor", "--port", "socket://h:1"], "socket://h:1"),
        (["--port=/dev/ttyACM1", "flash"], "/dev/ttyACM1"),
        (["-p/dev/ttyUSB1", "monitor"], "/dev/ttyUSB1"),
        (["build", "--preview"], None),
        (["flash"], None),
    ],
)
def test_the_idf_passthrough_finds_the_port_idf_py_is_given(args, port):
    assert idf_port(args) == port


def test_espport_is_the_port_of_actions_that_use_one_and_only_where_none_is_given():
    env = {"ESPPORT": "/dev/ttyUSB3"}
    assert port_of_env(["flash", "monitor"], env) == ("-p", "/dev/ttyUSB3", "flash", "monitor")
    assert port_of_env(["erase-flash"], env)[:2] == ("-p", "/dev/ttyUSB3")
    assert port_of_env(["efuse-summary"], env)[:2] == ("-p", "/dev/ttyUSB3")
    # IDF's debug_ext.py gives the core dump actions its PORT option, which reads ESPPORT.
    assert port_of_env(["coredump-info"], env)[:2] == ("-p", "/dev/ttyUSB3")
    assert port_of_env(["coredump-debug"], env)[:2] == ("-p", "/dev/ttyUSB3")
    assert port_of_env(["-p", "/dev/ttyACM0", "flash"], env) == ("-p", "/dev/ttyACM0", "flash")
    assert port_of_env(["menuconfig"], env) == ("menuconfig",), "no board: an unplugged one must not stop it"
    assert port_of_env(["flash"], {}) == ("flash",)


def test_missing_device_is_a_clear_error(tmp_path):
    with pytest.raises(PortError, match="does not exist"):
        check_port(parse_port(str(tmp_path / "ttyUSB9")))


def test_a_regular_file_is_not_a_serial_port(tmp_path):
    (tmp_path / "ttyFAKE").write_text("")
    with pytest.raises(PortError, match="not a serial device"):
        check_port(parse_port(str(tmp_path / "ttyFAKE")))


def test_busy_serial_port_is_reported():
    import fcntl

    controller, device = pty.openpty()
    path = os.ttyname(device)
    holder = os.open(path, os.O_RDWR | os.O_NOCTTY)
    fcntl.flock(holder, fcntl.LOCK_EX | fcntl.LOCK_NB)  # as pyserial does for an open port
    try:
        with pytest.raises(PortError, match="busy"):
            check_port(parse_port(path))
    finally:
        for fd in (holder, device, controller):
            os.close(fd)


class _NoContainers:
    """An engine where no container has any device."""

    def device_users(self, devices, url=None):
        return []


def _another_espdock_holding(*ports: str) -> subprocess.Popen:
    """A process that holds PORTS as an espdock flashing them does, until its stdin is closed."""
    holds = ", ".join(f"port_held(_NoContainers(), parse_port({port!r}))" for port in ports)
    holder = subprocess.Popen(
        [sys.executable, "-c",
         "import sys; from tests.unit.test_firmware_tools import _NoContainers; "
         "from espdock.firmware.flashing import parse_port, port_held\n"
         f"with {holds}:\n    print('held', flush=True); sys.stdin.read()"],
        cwd=Path(__file__).parents[2], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
    )  # fmt: skip
    assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
    return holder


def test_a_port_another_espdock_holds_is_busy_by_whichever_name(tmp_path):
    """One device by its /dev/serial/by-id-style link and by its node; one server by two URLs."""
    controller, device = pty.openpty()
    node = os.ttyname(device)
    os.close(device)  # open in no process: one that holds it makes the port busy
    link = tmp_path / "usb-Espressif_board-if00"
    link.symlink_to(node)
    url = f"socket://127.0.0.1:{free_port()}"
    holder = _another_espdock_holding(node, url)
    try:
        for other in (str(link), url.replace("127.0.0.1", "localhost") + "/"):
            with pytest.raises(PortError, match=f"busy: another espdock has it \\(pid {holder.pid}: "):
                with port_held(_NoContainers(), parse_port(other)):
                    pass
    finally:
        holder.communicate(timeout=30)
    with port_held(_NoContainers(), parse_port(str(link))):  # let go: free again
        pass
    os.close(controller)


def test_a_serial_server_another_espdock_holds_is_busy_every_time_not_silent():
    """A serial server takes one client at a time (esp_rfc2217_server listens with a backlog of
    one). While a monitor of another espdock had it, each flash's probe of the server queued a
    connection: the first two flashes were told the port was busy, every later one that "nothing
    answers" and to start the server, which ran."""
    server = socket.socket()
    server.bind(("127.0.0.1", 0))
    server.listen(1)  # and never accepts, as a server whose one client is connected
    url = f"socket://127.0.0.1:{server.getsockname()[1]}"
    holder = _another_espdock_holding(url)
    try:
        for _ in range(4):
            with pytest.raises(PortError, match=f"busy: another espdock has it \\(pid {holder.pid}: "):
                check_port(parse_port(url), timeout=1)
    finally:
        holder.communicate(timeout=30)
        server.close()


def test_a_port_a_program_holds_open_without_a_lock_is_busy_naming_it():
    """`screen /dev/ttyUSB0`, or a native agent, takes no lock: the flash went on, and esptool read
    the other's bytes ("could not tell which chip") or the two wrote at once."""
    controller, device = pty.openpty()
    node = os.ttyname(device)
    os.close(device)  # only the other program has it
    holder = subprocess.Popen(
        ["sh", "-c", f"exec 3<>{node}; echo held; exec sleep 60"], stdout=subprocess.PIPE, text=True
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        with pytest.raises(PortError, match=rf"busy: (sh|sleep) \(pid {holder.pid}\) has it open"):
            with port_held(_NoContainers(), parse_port(node)):
                pass
    finally:
        holder.kill()
        holder.wait()
    with port_held(_NoContainers(), parse_port(node)):  # closed: free again
        pass
    # A shell that keeps the port open for the espdock it starts (`exec 3<>PORT`): handed, not held.
    handed = subprocess.run(
        ["sh", "-c", f'exec 3<>{node}; "$0" -c "$1"', sys.executable,
         "from tests.unit.test_firmware_tools import _NoContainers\n"
         "from espdock.firmware.flashing import parse_port, port_held\n"
         f"with port_held(_NoContainers(), parse_port({node!r})):\n    print('held')"],
        cwd=Path(__file__).parents[2], capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert handed.returncode == 0 and handed.stdout.strip() == "held", handed.stderr
    os.close(controller)


def test_a_serial_server_s_name_and_its_address_are_one_port_to_hold(monkeypatch):
    """A bridge's name with an A and an AAAA record, and its IPv4 address: the busy check took them
    for one server, and each command took a lock of its own."""
    import socket

    from espdock.images.port_urls import port_url_key, same_port_url

    real = socket.getaddrinfo

    def resolve(host, *args, **kwargs):
        if host == "esp-bridge.lan":
            return [
                (socket.AF_INET6, 1, 6, "", ("fd00::50", 4000, 0, 0)),
                (socket.AF_INET, 1, 6, "", ("192.168.1.50", 4000)),
            ]
        return real(host, *args, **kwargs)

    monkeypatch.setattr(socket, "getaddrinfo", resolve)
    name, literal = "socket://esp-bridge.lan:4000", "socket://192.168.1.50:4000"
    assert same_port_url(name, literal) and port_url_key(name) == port_url_key(literal)
    assert port_url_key("socket://192.168.1.51:4000") != port_url_key(literal)


def test_a_port_s_lock_is_one_other_users_can_open_whatever_the_umask(tmp_path, monkeypatch):
    """Under umask 077 the lock file was made 0400: another user's espdock could not open it, went on
    unlocked, and flashed the board the first one was flashing."""
    from espdock.images import machine_lock

    monkeypatch.setattr(machine_lock, "LOCK_DIR", tmp_path)
    before = os.umask(0o077)
    try:
        with port_held(_NoContainers(), parse_port("socket://127.0.0.1:4999")):
            (lock,) = tmp_path.glob("espdock-port-*.lock")
            assert lock.stat().st_mode & 0o777 == 0o444
    finally:
        os.umask(before)


def test_a_pseudo_terminal_is_refused_with_the_network_way_to_serve_it(tmp_path):
    """The engine cannot make a /dev/pts node in a container: runc failed with "error creating
    device nodes: ... permission denied". socat's and emulators' ports are such nodes, often
    under a name of their own."""
    controller, device = pty.openpty()
    (tmp_path / "ttyV0").symlink_to(os.ttyname(device))
    try:
        for path in (os.ttyname(device), str(tmp_path / "ttyV0")):
            with pytest.raises(PortError, match="is a pseudo-terminal") as err:
                check_port(parse_port(path))
            assert "socket://localhost:5555" in (err.value.hint or "")
            assert f"socat TCP-LISTEN:4000,reuseaddr FILE:{path},raw,echo=0" in (err.value.hint or "")
        # What the hint once named, esp_rfc2217_server, sets the port's DTR and RTS lines (as
        # pyserial does here), which a pseudo-terminal refuses: it failed every connection.
        import serial

        with serial.Serial(os.ttyname(device)) as opened, pytest.raises(OSError, match="Inappropriate ioctl"):
            opened.dtr = False
        # The agent reads serial devices only: the hint's socket:// URL, given to it, was refused in turn.
        agent = espdock("agent", "--port", os.ttyname(device), cwd=tmp_path, env={"NO_COLOR": "1"})
        said = " ".join(agent.stderr.split())
        assert agent.returncode == PortError.exit_code and "socket://localhost" not in said, said
        assert "the micro-ROS agent reads serial devices only" in said, said
        assert f"`micro_ros_agent serial --dev {os.ttyname(device)}`" in said, said
    finally:
        os.close(device)
        os.close(controller)


def test_network_port_with_nothing_listening():
    with pytest.raises(PortError, match="nothing answers"):
        check_port(parse_port(f"socket://127.0.0.1:{free_port()}"), timeout=1)


def write_build(build: Path, app: bytes) -> None:
    (build / "bootloader").mkdir(parents=True, exist_ok=True)
    (build / "partition_table").mkdir(exist_ok=True)
    (build / "bootloader/bootloader.bin").write_bytes(b"\xe9boot")
    (build / "partition_table/partition-table.bin").write_bytes(b"pt")
    (build / "cam.bin").write_bytes(app)
    (build / "cam.elf").write_bytes(b"elf")
    (build / "flasher_args.json").write_text(
        json.dumps({**FLASHER_ARGS, "app": {"offset": "0x10000", "file": "cam.bin"}})
    )


def test_install_is_colcon_shaped_and_swaps_firmware_atomically(tmp_path):
    build, install = tmp_path / "build/cam", tmp_path / "install"
    manifest = tmp_path / "package.xml"
    manifest.write_text("<package/>")
    write_build(build, b"\xe9app-v1")
    firmware = install_firmware("cam", manifest, build, install, ("custom_interface",), owner=None)
    assert (firmware / "cam.bin").read_bytes() == b"\xe9app-v1"
    assert (firmware / "cam.elf").is_file()
    assert (install / "cam/share/ament_index/resource_index/packages/cam").is_file()
    assert (install / "cam/share/colcon-core/packages/cam").read_text() == "custom_interface"
    assert (install / "cam/share/cam/package.xml").read_text() == "<package/>"
    first_target = os.readlink(firmware)

    write_build(build, b"\xe9app-v2")
    install_firmware("cam", manifest, build, install, (), owner=None)
    assert firmware.is_symlink() and os.readlink(firmware) != first_target
    assert (firmware / "cam.bin").read_bytes() == b"\xe9app-v2"
    share = install / "cam/share/cam"
    assert sorted(p.name for p in share.iterdir() if p.name.startswith(".firmware")) == [os.readlink(firmware)]


def test_install_gives_each_package_idf_flash_and_monitor_for_ros2_run_alike_in_every_clone(tmp_path):
    installed = {}
    for clone in ("one", "elsewhere/two"):
        build, install = tmp_path / clone / "ws/build/cam", tmp_path / clone / "ws/install"
        manifest = tmp_path / clone / "package.xml"
        manifest.parent.mkdir(parents=True, exist_ok=True)
        manifest.write_text("<package/>")
        write_build(build, b"\xe9app")
        install_firmware("cam", manifest, build, install, (), owner=None)
        lib = install / "cam/lib/cam"
        assert sorted(p.name for p in lib.iterdir()) == ["flash", "idf", "monitor"]
        assert all(os.access(p, os.X_OK) for p in lib.iterdir())
        installed[clone] = {p.name: p.read_bytes() for p in lib.iterdir()}
        assert str(tmp_path).encode() not in b"".join(installed[clone].values())
    # The reproducibility check compares install trees of clones at different paths byte for byte.
    assert installed["one"] == installed["elsewhere/two"]
    scripts = installed["one"]
    assert b'exec espdock flash cam --workspace "$here/../../../.." "$@"' in scripts["flash"]
    assert b'exec espdock idf cam --workspace "$here/../../../.." -- "$@"' in scripts["idf"]
    assert b'exec espdock monitor cam --workspace "$here/../../../.." "$@"' in scripts["monitor"]


@pytest.mark.parametrize("merged", [False, True])
def test_the_installed_commands_name_the_workspace_in_colcon_s_merged_layout_too(tmp_path, merged):
    """Run as `ros2 run` runs them, with a stand-in `espdock` on PATH that prints what it is given."""
    root = tmp_path / "ws-root"
    build, install = root / "build/cam", root / "install"
    manifest = root / "package.xml"
    manifest.parent.mkdir(parents=True)
    manifest.write_text("<package/>")
    write_build(build, b"\xe9app")
    prefix = install if merged else install / "cam"
    install_firmware("cam", manifest, build, install, (), owner=None, prefix=prefix, workspace_root=root)
    fake = tmp_path / "bin" / "espdock"
    fake.parent.mkdir()
    fake.write_text('#!/bin/sh\nprintf "%s\\n" "$@"\n')
    fake.chmod(0o755)
    env = {**os.environ, "PATH": f"{fake.parent}{os.pathsep}{os.environ['PATH']}"}
    ran = subprocess.run(
        [str(prefix / "lib/cam/idf"), "menuconfig"], cwd="/", env=env, capture_output=True, text=True, check=True
    )
    command, package, option, workspace, separator, argument = ran.stdout.splitlines()
    assert (command, package, option, separator, argument) == ("idf", "cam", "--workspace", "--", "menuconfig")
    assert Path(workspace).resolve() == root.resolve()


def test_a_build_missing_artefacts_installs_nothing_and_keeps_the_old_firmware(tmp_path):
    build, install = tmp_path / "build/cam", tmp_path / "install"
    manifest = tmp_path / "package.xml"
    manifest.write_text("<package/>")
    write_build(build, b"\xe9good")
    firmware = install_firmware("cam", manifest, build, install, (), owner=None)
    (build / "partition_table/partition-table.bin").unlink()
    with pytest.raises(BuildFailed, match=r"partition-table\.bin"):
        install_firmware("cam", manifest, build, install, (), owner=None)
    assert (firmware / "cam.bin").read_bytes() == b"\xe9good"


def test_provisioning_writes_only_the_nvs_region_or_adds_it_in_flash_order():
    port = parse_port("socket://127.0.0.1:9876")
    nvs = (0x9000, "/run/espdock-provision/nvs.bin")
    alone = write_region_argv(FLASHER_ARGS, port, 460800, 5, nvs)
    assert alone[-3:] == ("write-flash", "0x9000", "/run/espdock-provision/nvs.bin")
    assert "cam.bin" not in alone and "--flash-mode" not in alone
    both = flash_argv(FLASHER_ARGS, port, 460800, 5, nvs)
    start = both.index("write-flash") + 7  # after the flash options
    assert both[start::2] == ("0x1000", "0x8000", "0x9000", "0x10000")
    assert verify_argv(FLASHER_ARGS, port, 5, nvs)[-4:-2] == ("0x9000", "/run/espdock-provision/nvs.bin")


@pytest.mark.parametrize(
    ("found", "supported", "hint"),
    [
        ("esp32s3", ("esp32", "esp32s3"), "`espdock build camera_node --target esp32s3`"),
        (
            "esp32c3",
            ("esp32", "esp32s3"),
            "espdock cannot build camera_node for an esp32c3 (it supports esp32, esp32s3)",
        ),
        ("esp32c6", (), "espdock cannot build camera_node for an esp32c6."),  # micro-ROS: -mlongcalls
        ("esp32c3", (), "`espdock build camera_node --target esp32c3`"),
    ],
)
def test_the_chip_mismatch_hint_suggests_only_a_chip_espdock_builds_the_package_for(found, supported, hint):
    probe = ["esptool v5.1.0", f"Detecting chip type... {found.upper().replace('ESP32', 'ESP32-')}"]
    with pytest.raises(ConfigError) as error:
        check_chip("camera_node", "esp32", probe, parse_port("socket://127.0.0.1:1"), supported)
    assert f"is an {found}, but camera_node is built for esp32" in error.value.message
    assert hint in error.value.hint


def test_the_chip_mismatch_hint_suggests_no_chip_the_package_s_transport_has_no_port_on(tmp_path):
    """A USB-Serial-JTAG package built for an esp32c3, at an esp32: the hint said to build it with
    --target esp32, which espdock refuses (an esp32 has no USB-Serial-JTAG port)."""
    (tmp_path / "sdkconfig.defaults").write_text("CONFIG_ESPDOCK_TRANSPORT_USB_SERIAL_JTAG=y\n")
    probe = ["esptool v5.1.0", "Detecting chip type... ESP32"]
    with pytest.raises(ConfigError) as error:
        check_chip("u2", "esp32c3", probe, parse_port("socket://127.0.0.1:1"), (), tmp_path)
    assert "--target" not in error.value.hint
    assert "espdock cannot build u2 for an esp32 (its transport is USB-Serial-JTAG" in error.value.hint
    at_s3 = ["esptool v5.1.0", "Detecting chip type... ESP32-S3"]
    with pytest.raises(ConfigError) as error:
        check_chip("u2", "esp32c3", at_s3, parse_port("socket://127.0.0.1:1"), (), tmp_path)
    assert "`espdock build u2 --target esp32s3`" in error.value.hint


def _flash_against(tmp_path: Path, esptool: Callable[[tuple[str, ...], Callable[[str], None]], int], **options):
    """flash_package of a board package at a fake board: the IdfSteps it runs esptool through answer
    the chip probe as an ESP32 and every other esptool command with ESPTOOL(argv, on_line)."""
    from espdock.firmware.flashing import flash_package
    from espdock.firmware.plan import IdfBuild

    class Esptool:
        class containers:  # the engine sees this machine
            @staticmethod
            def needs_this_machine(*args: object) -> None:
                pass

        def run_idf(self, workspace, step, argv, on_line=None, **kwargs):
            if argv[:2] == ("python", "-c"):  # the probe, spelled for either esptool
                for text in ("esptool.py v4.8.1", "Detecting chip type... ESP32"):
                    on_line(text)
                return 0
            return esptool(argv, on_line)

    (tmp_path / "fw/board/main").mkdir(parents=True)
    args = {"extra_esptool_args": {"chip": "esp32"}, "flash_files": {"0x10000": "board.bin"}}
    step = IdfBuild("board", "fw/board", "img", "esp32", "k")
    flash_package(
        Esptool(), Workspace(tmp_path), step, tmp_path / "ws/install/board/share/board/firmware", args,
        parse_port("socket://127.0.0.1:9"), None, options.pop("verify", False), lambda text: None, **options,
    )  # type: ignore[arg-type]  # fmt: skip


def test_a_read_back_that_fails_after_the_write_finished_says_the_write_finished(tmp_path):
    """A board unplugged during `flash --verify`'s read-back: espdock said only "esptool failed ...
    See its output above", where the write before it had finished."""
    from espdock.firmware.flashing import PortError

    def esptool(argv: tuple[str, ...], on_line: Callable[[str], None]) -> int:
        """A whole write, then a read-back cut short."""
        if any("verify" in arg for arg in argv):
            on_line("Verifying 0x2ca00 (182784) bytes @ 0x00010000 in flash against board.bin...")
            return 2
        on_line("Writing at 0x00010000... (100 %)")
        return 0

    with pytest.raises(PortError) as failed:
        _flash_against(tmp_path, esptool, verify=True)
    said = " ".join(f"{failed.value} {failed.value.hint}".split())
    assert "reading the flash back: the write before it had finished" in said, said
    assert "half written" not in said and "--verify" in said, said


def test_a_serial_server_s_url_is_the_same_port_however_it_is_written():
    """A monitor on socket://127.0.0.1:45451 in one terminal: `flash -p socket://localhost:45451`
    (or SOCKET://, a trailing /, rfc2217's ?ign_set_control, 0.0.0.0) was not called busy, and
    esptool said it could not tell the chip."""
    from espdock.images.port_urls import same_port_url

    held = "socket://127.0.0.1:45451"
    for same in (
        "socket://localhost:45451",
        "SOCKET://127.0.0.1:45451",
        "socket://127.0.0.1:45451/",
        "socket://0.0.0.0:45451",
    ):
        assert same_port_url(same, held), same
    assert same_port_url("rfc2217://localhost:4000?ign_set_control", "rfc2217://127.0.0.1:4000")
    for other in ("socket://127.0.0.1:45452", "socket://192.0.2.7:45451", "socket://127.0.0.1", "/dev/ttyUSB0"):
        assert not same_port_url(other, held), other


@pytest.mark.parametrize(
    ("writes", "half", "again"),
    [
        ("app", "the board's flash is half written", "espdock flash board --port socket://127.0.0.1:9"),
        (
            "app and settings",
            "the board's flash is half written",
            "espdock flash board --port socket://127.0.0.1:9` with the same --wifi-ssid/--agent options",
        ),
        # provision writes the NVS partition alone: `flash` without the settings never rewrote it,
        # and the app, untouched, still boots.
        (
            "settings",
            "its NVS partition (the network settings) is half written; the app is untouched",
            "espdock provision board --port socket://127.0.0.1:9` with the same options",
        ),
    ],
)
@pytest.mark.parametrize("cut", ["unplugged", "interrupted"])
def test_esptool_stopping_mid_write_says_what_is_half_written(tmp_path, writes, half, again, cut):
    """A board unplugged (or reset) at "Writing at 0x00010000... (11 %)": espdock said only "See its
    output above", where the bootloader was new and the app in part, and the board would not boot.
    Ctrl-C there says the same; an interrupted `provision` said to flash the app again."""
    from espdock.errors import Interrupted
    from espdock.firmware.flashing import PortError

    def esptool(argv: tuple[str, ...], on_line: Callable[[str], None]) -> int:
        """A write the board leaves at 11 %."""
        for text in ("Compressed 182784 bytes to 95391...", "Writing at 0x00010000... (11 %)"):
            on_line(text)
        if cut == "interrupted":
            raise KeyboardInterrupt
        return 1

    settings = {"nvs_image": (0x9000, tmp_path / "nvs.bin")} if "settings" in writes else {}
    with pytest.raises(PortError if cut == "unplugged" else Interrupted) as failed:
        _flash_against(tmp_path, esptool, app="app" in writes, **settings)
    said = " ".join(f"{failed.value} {failed.value.hint}".split())
    assert half.removeprefix("the board's ") in said and again in said, said
    assert ("may not boot" in said) == ("app" in writes), said


def test_firmware_edited_in_the_install_tree_is_put_back_by_the_next_install_and_flash_says_so(tmp_path):
    """The install tree's firmware edited by hand (a .bin patched, replaced): `espdock build` said it
    installed the build's firmware and left the edited one (same build, same version directory),
    and flash wrote it without a word."""
    from tests.conftest import copy_workspace, espdock

    root = copy_workspace(tmp_path / "w", packages=())
    assert espdock("new", "cam", cwd=root, env={"DOCKER_HOST": "unix:///nonexistent/docker.sock"}).returncode == 0
    build, install = tmp_path / "build/cam", root / "ws/install"
    write_build(build, b"\xe9app")
    firmware = install_firmware("cam", root / "firmware/cam/package.xml", build, install, (), owner=None)
    version = firmware.parent / os.readlink(firmware)
    assert not altered_since_installed(version)
    (firmware / "cam.bin").write_bytes(b"\xe9app, patched")
    assert altered_since_installed(version)

    flashed = espdock("flash", "cam", "--port", str(tmp_path / "ttyUSB9"), cwd=root, env={"DOCKER_HOST": "unix:///x"})
    said = " ".join(flashed.stdout.split())
    assert "note: the installed firmware of cam was changed after espdock installed it" in said, flashed.stdout
    assert flashed.returncode == 6, flashed.stderr  # then the missing port, as before

    install_firmware("cam", root / "firmware/cam/package.xml", build, install, (), owner=None)
    assert (firmware / "cam.bin").read_bytes() == b"\xe9app"
    assert not altered_since_installed(firmware.parent / os.readlink(firmware))
    # A file removed: said before esptool (whose "No such file" was exit 6, a serial port problem).
    (firmware / "bootloader/bootloader.bin").unlink()
    flashed = espdock("flash", "cam", "--port", str(tmp_path / "ttyUSB9"), cwd=root, env={"DOCKER_HOST": "unix:///x"})
    assert flashed.returncode == 2, flashed.stdout + flashed.stderr
    said = " ".join(flashed.stderr.split())
    assert f"the installed firmware of cam lacks bootloader/bootloader.bin ({firmware})" in said, said
    # Not for what writes none of them: a monitor, a provision (the NVS partition alone).
    for command in (("monitor", "cam"), ("provision", "cam", "--wifi-ssid", "lab", "--agent", "10.0.0.1:8888")):
        other = espdock(*command, "--port", str(tmp_path / "ttyUSB9"), cwd=root, env={"DOCKER_HOST": "unix:///x"})
        assert "lacks" not in other.stdout + other.stderr, other.stdout + other.stderr
    install_firmware("cam", root / "firmware/cam/package.xml", build, install, (), owner=None)
    assert (firmware / "bootloader/bootloader.bin").read_bytes() == b"\xe9boot"
    assert [p.name for p in firmware.parent.iterdir() if p.name.startswith(".firmware-")] == [os.readlink(firmware)]


def test_the_same_firmware_installed_again_gets_this_build_s_record_of_its_domain(tmp_path):
    """Firmware installed by an espdock before the domain was recorded: the same build's files name
    the same version directory, whose old record stayed ("ROS domain as built", with no number)
    through every later build, --force too, until the firmware's bytes changed."""
    from espdock.firmware.transport import TRANSPORT_RECORD, installed_domain_id

    build, install = tmp_path / "build/cam", tmp_path / "install"
    manifest = tmp_path / "package.xml"
    manifest.write_text("<package/>")
    write_build(build, b"\xe9app")
    (build / "config").mkdir()
    (build / "config/sdkconfig.json").write_text(
        json.dumps({"ESPDOCK_TRANSPORT_UDP": True, "ESPDOCK_ROS_DOMAIN_ID": 3})
    )
    firmware = install_firmware("cam", manifest, build, install, (), owner=None)
    assert installed_domain_id(firmware) == 3
    (firmware / TRANSPORT_RECORD).write_text('{"transport": "udp"}\n')  # as the espdock before wrote it
    assert installed_domain_id(firmware) is None

    install_firmware("cam", manifest, build, install, (), owner=None)
    assert installed_domain_id(firmware) == 3
    assert (firmware / "cam.bin").read_bytes() == b"\xe9app"


def test_an_install_an_older_espdock_recorded_is_redone_where_its_record_is_not_this_one_s(tmp_path, monkeypatch):
    """Upgraded from an espdock that recorded no domain: the install step was up to date by its
    stamp and never ran, so the record stayed without it through every build (0c16868 fixed the
    install itself, which then never ran)."""
    from espdock.firmware import steps
    from espdock.firmware.plan import InstallFirmware
    from espdock.workspace import Workspace

    root = tmp_path / "w"
    (root / "fw").mkdir(parents=True)
    (root / "fw/package.xml").write_text("<package/>")
    write_build(root / "build/cam", b"\xe9app")
    ws, step = Workspace(root, ("fw",), "."), InstallFirmware("cam", "fw", ())
    monkeypatch.setattr(steps, "firmware_build_dir", lambda ws_dir, package: root / "build/cam")
    monkeypatch.setattr(steps, "built_transport_record", lambda build_dir: b'{"transport": "udp"}\n', raising=False)
    older = steps._install_stamps(ws, step)[1]
    monkeypatch.setattr(
        steps, "built_transport_record", lambda build_dir: b'{"ros_domain_id": 0, "transport": "udp"}\n', raising=False
    )
    assert steps._install_stamps(ws, step)[1] != older
