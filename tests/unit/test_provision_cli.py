"""`espdock provision` and `flash` against hostile command lines, in a workspace with installed
firmware (a flasher_args.json and partition table as IDF writes them): every refusal comes
before the port and the engine are touched, with exit 2 and no traceback."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from tests.unit.test_provision import SINGLE_APP_LARGE

REPO = Path(__file__).resolve().parents[2]
AGENT = ("--agent", "10.0.0.2:8888")
NOWHERE = "socket://127.0.0.1:1"  # never reached: every case fails before the port


@pytest.fixture(scope="module")
def installed(tmp_path_factory) -> Path:
    root = tmp_path_factory.mktemp("ws")
    for name in ("Dockerfile.idf", "Dockerfile.ros", "docker"):
        copy = shutil.copytree if (REPO / name).is_dir() else shutil.copy2
        copy(REPO / name, root / name)
    shutil.copytree(REPO / "firmware", root / "firmware")
    (root / "espdock.toml").write_text('[espdock]\npackage_paths = ["firmware"]\ncolcon_root = "ws"\n')
    firmware = root / "ws/install/camera_node/share/camera_node/firmware"
    (firmware / "partition_table").mkdir(parents=True)
    (firmware / "partition_table/partition-table.bin").write_bytes(SINGLE_APP_LARGE)
    args = {"partition-table": {"offset": "0x8000", "file": "partition_table/partition-table.bin"}}
    (firmware / "flasher_args.json").write_text(json.dumps({**args, "extra_esptool_args": {"chip": "esp32"}}))
    return root


def run(root: Path, *args: bytes | str, stdin_closed: bool = False) -> subprocess.CompletedProcess[bytes]:
    argv = [sys.executable, "-m", "espdock", *args]
    return subprocess.run(
        argv,
        cwd=root,
        stdin=subprocess.DEVNULL,
        capture_output=True,
        timeout=60,
        check=False,
        # `<&-`: the child starts with file descriptor 0 closed, so Python's sys.stdin is None.
        preexec_fn=(lambda: __import__("os").close(0)) if stdin_closed else None,
    )


@pytest.mark.parametrize("command", ["provision", "flash"])
def test_an_ssid_whose_bytes_are_not_utf8_is_refused(installed, command, tmp_path, monkeypatch):
    monkeypatch.setenv("TMPDIR", str(tmp_path))  # where a bug report would go
    result = run(installed, command, "camera_node", "-p", NOWHERE, "--wifi-ssid", b"caf\xe9", *AGENT,
                 "--wifi-password-file", "/dev/null")  # fmt: skip
    assert result.returncode == 2, result.stderr
    assert b"the Wi-Fi SSID is not UTF-8 text (caf\\xe9)" in result.stderr
    assert b"Traceback" not in result.stderr and not list(tmp_path.glob("espdock-bug-*"))


@pytest.mark.parametrize("command", ["provision", "flash"])
@pytest.mark.parametrize("password", [("--wifi-password-file", "-"), ()], ids=["dash", "prompt"])
def test_a_closed_stdin_is_bad_input_not_a_bug(installed, command, password):
    result = run(installed, command, "camera_node", "-p", NOWHERE, "--wifi-ssid", "lab", *AGENT, *password,
                 stdin_closed=True)  # fmt: skip
    assert result.returncode == 2, result.stderr
    expected = b"reads stdin, which is closed" if password else b"no terminal to ask on"
    assert expected in result.stderr and b"Traceback" not in result.stderr


@pytest.mark.parametrize(
    ("command", "domain"),
    [("flash", "\u0664\u0662")]
    + [("provision", d) for d in ("\u0664\u0662", "\uff14\uff12", "4_2", " 42 ", "+42", "042x", "233", "-1", "")],
)
def test_the_domain_id_is_ascii_digits_only(installed, command, domain):
    result = run(installed, command, "camera_node", "-p", NOWHERE, "--wifi-ssid", "lab", *AGENT,
                 "--wifi-password-file", "/dev/null", "--domain-id", domain)  # fmt: skip
    assert result.returncode == 2, result.stderr
    assert b"ROS domain id" in result.stderr and b"is not 0..232" in result.stderr


@pytest.mark.parametrize("command", ["provision", "flash"])
def test_an_ssid_with_c1_control_characters_is_refused(installed, command):
    result = run(installed, command, "camera_node", "-p", NOWHERE, "--wifi-ssid", "lab\u009bnet", *AGENT,
                 "--wifi-password-file", "/dev/null")  # fmt: skip
    assert result.returncode == 2 and b"the Wi-Fi SSID contains control characters" in result.stderr, result.stderr


def test_a_bug_report_keeps_a_command_line_that_is_not_utf8(tmp_path, monkeypatch):
    from espdock.cli import core

    monkeypatch.setattr(sys, "argv", ["espdock", "provision", "--wifi-ssid", "caf\udce9"])
    monkeypatch.setattr("tempfile.tempdir", str(tmp_path))
    try:
        raise ValueError("caf\udce9")
    except ValueError as exc:
        bug = core._bug_report(exc)
    (log,) = tmp_path.glob("espdock-bug-*.log")
    assert log.name in bug.hint
    text = log.read_text()
    assert "--wifi-ssid caf\\udce9" in text and "ValueError" in text and "Traceback" in text


@pytest.mark.parametrize("command", ["provision", "flash"])
def test_firmware_built_without_the_settings_component_is_not_provisioned(installed, command):
    description = installed / "ws/install/camera_node/share/camera_node/firmware/project_description.json"
    argv = (command, "camera_node", "-p", NOWHERE, "--wifi-ssid", "lab", *AGENT, "--wifi-password-file", "/dev/null")
    try:
        description.write_text(json.dumps({"build_components": ["blinklib", "main", "nvs_flash"]}))
        refused = run(installed, *argv)
        description.write_text(json.dumps({"build_components": ["espdock_uros", "main", "nvs_flash"]}))
        reading = run(installed, *argv)
    finally:
        description.unlink()
    assert refused.returncode == 2, refused.stderr
    assert b"camera_node does not read the settings provisioning writes" in refused.stderr
    assert b"erase its NVS partition" in refused.stderr and b"Nothing was written" in refused.stderr
    # Firmware on the component goes on to the port (here one that answers nothing).
    assert b"does not read the settings" not in reading.stderr and b"127.0.0.1:1" in reading.stderr, reading.stderr


@pytest.mark.parametrize("command", ["provision", "flash"])
def test_an_agent_on_the_engine_s_bridge_is_warned_of(installed, command):
    """`hostname -I` lists docker0's address among the machine's: given as the agent's, the board's
    Wi-Fi traffic went nowhere, and nothing said so."""
    import socket

    from espdock.firmware.provision import container_bridge

    shown = subprocess.run(["ip", "-4", "-o", "addr"], capture_output=True, text=True, check=False).stdout
    addresses = {f[1]: f[3].split("/")[0] for f in (line.split() for line in shown.splitlines()) if len(f) > 3}
    if "docker0" not in addresses:
        pytest.skip("no docker0 on this machine (make test starts the engine first)")
    bridge = addresses["docker0"]
    assert container_bridge(bridge) == "docker0"
    lans = [
        a for name, a in addresses.items() if name != "lo" and not name.startswith(("docker", "br-", "podman", "cni-"))
    ]
    assert all(container_bridge(lan) is None for lan in lans)
    # A container's address on it (`docker inspect`'s), as the agent's in a container.
    container = ".".join([*bridge.split(".")[:3], "77"])
    assert container_bridge(container) == "docker0"
    assert container_bridge(socket.gethostbyname("localhost")) is None
    result = run(installed, command, "camera_node", "-p", "/dev/nonexistent-port", "--wifi-ssid", "lab",
                 "--agent", f"{bridge}:8888", "--wifi-password-file", "/dev/null")  # fmt: skip
    said = b" ".join(result.stdout.split() + result.stderr.split()).decode()
    assert f"warning: agent host {bridge} is on this machine's container bridge (docker0)" in said, said
    assert result.returncode == 6 and "does not exist" in said  # it goes on: a routed lab may reach it


def test_a_lan_bridge_is_not_taken_for_a_container_bridge(tmp_path):
    """OpenStack's br-ex and a router's br-lan are the LAN's bridges: an agent on another machine of
    that LAN was warned of as on a container bridge. A Compose network's br-<12 hex digits> is one."""
    import sys

    script = (
        "ip link add br-ex type bridge && ip addr add 192.168.1.10/24 dev br-ex && ip link set br-ex up && "
        "ip link add br-0123456789ab type bridge && ip addr add 172.30.0.1/16 dev br-0123456789ab && "
        f"ip link set br-0123456789ab up && {sys.executable} -c '"
        "from espdock.firmware.provision import container_bridge as c; "
        'print(c("192.168.1.20"), c("172.30.0.7"))\''
    )
    ran = subprocess.run(["unshare", "-rn", "sh", "-c", script], cwd=REPO, capture_output=True, text=True, check=False)
    if ran.returncode != 0 and "Operation not permitted" in ran.stderr:
        pytest.skip("no network namespace of its own here")
    assert ran.returncode == 0, ran.stderr
    assert ran.stdout.split() == ["None", "br-0123456789ab"]
