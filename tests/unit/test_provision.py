"""Provisioning: what is refused before a port is touched, the NVS image, the partition table."""

import hashlib
import io
import os
import stat
import struct
from pathlib import Path

import pytest

from espdock.errors import ConfigError, WorkspaceError
from espdock.firmware.provision import (
    IMAGE_NAME,
    NetSettings,
    check_settings,
    nvs_image,
    nvs_partition,
    optional_network_settings,
    parse_partition_table,
    read_password,
)
from tests.nvs_reader import read_nvs


def table(*rows: tuple[str, int, int, int, int]) -> bytes:
    """A partition-table.bin as ESP-IDF's gen_esp32part.py writes it (entries, MD5 row, erased rest)."""
    blob = b"".join(
        struct.pack("<2sBBII16sI", b"\xaa\x50", ptype, sub, offset, size, name.encode(), 0)
        for name, ptype, sub, offset, size in rows
    )
    blob += b"\xeb\xeb" + b"\xff" * 14 + hashlib.md5(blob).digest()
    return blob + b"\xff" * (0xC00 - len(blob))


# IDF's partitions_singleapp_large.csv
SINGLE_APP_LARGE = table(
    ("nvs", 1, 2, 0x9000, 0x6000), ("phy_init", 1, 1, 0xF000, 0x1000), ("factory", 0, 0, 0x10000, 0x177000)
)
NO_NVS = table(("phy_init", 1, 1, 0xF000, 0x1000), ("factory", 0, 0, 0x10000, 0x100000))  # fmt: skip


class Stdin(io.StringIO):
    def __init__(self, text: str = "", tty: bool = False) -> None:
        super().__init__(text)
        self._tty = tty

    def isatty(self) -> bool:
        return self._tty


def test_good_settings_pass():
    settings = check_settings("lab net", "correct horse", "10.0.0.2:8888", 7)
    assert settings == NetSettings("lab net", "correct horse", "10.0.0.2", 8888, 7)
    assert "correct horse" not in repr(settings)
    assert check_settings("x" * 32, "", "192.168.1.5:1", 232).password == ""  # open network


@pytest.mark.parametrize(
    ("ssid", "password", "agent", "domain", "message"),
    [
        ("", "", "10.0.0.2:8888", 0, "SSID is 0 bytes"),
        ("x" * 33, "", "10.0.0.2:8888", 0, "SSID is 33 bytes"),
        ("ü" * 17, "", "10.0.0.2:8888", 0, "SSID is 34 bytes"),
        ("lab\nnet", "", "10.0.0.2:8888", 0, "control characters"),
        ("lab", "1234567", "10.0.0.2:8888", 0, "password is 7 characters"),
        ("lab", "x" * 64, "10.0.0.2:8888", 0, "password is 64 characters"),
        ("lab", "pass\tword", "10.0.0.2:8888", 0, "printable ASCII"),
        ("lab", "", "agent.local:8888", 0, "not an IPv4 address"),
        ("lab", "", "::1:8888", 0, "not an IPv4 address"),
        ("lab", "", "10.0.0.2", 0, "is not HOST:PORT"),
        ("lab", "", "0.0.0.0:8888", 0, "not an address the board can send to"),
        ("lab", "", "10.0.0.2:0", 0, "port '0' is not 1..65535"),
        ("lab", "", "10.0.0.2:65536", 0, "port '65536' is not 1..65535"),
        ("lab", "", "10.0.0.2:http", 0, "port 'http' is not 1..65535"),
        ("lab", "", "10.0.0.2:²", 0, "port '²' is not 1..65535"),
        ("lab", "", "10.0.0.2:\u0668\u0668\u0668\u0668", 0, "is not 1..65535"),  # Arabic-Indic 8888
        ("lab", "", "10.0.0.2:+8888", 0, "is not 1..65535"),
        ("lab", "", "255.255.255.255:8888", 0, "not one host's address"),
        ("lab", "", "224.0.0.1:8888", 0, "not one host's address"),
        ("lab", "", "239.255.0.1:8888", 0, "not one host's address"),
        ("lab", "", "240.0.0.1:8888", 0, "not one host's address"),
        ("lab", "", "0.1.2.3:8888", 0, "not an address the board can send to"),
        ("lab", "", "127.0.0.1:8888", 0, "the board itself"),
        ("lab", "", "10.0.0.2:8888", 233, "domain id 233 is not 0..232"),
        ("lab", "", "10.0.0.2:8888", -1, "domain id -1 is not 0..232"),
    ],
)
def test_what_the_board_would_refuse_is_refused_here(ssid, password, agent, domain, message):
    with pytest.raises(ConfigError, match=message) as caught:
        check_settings(ssid, password, agent, domain)
    assert caught.value.exit_code == 2
    assert not password or password not in caught.value.message


def test_the_password_is_asked_for_only_after_the_rest_checked_out():
    asked = []
    with pytest.raises(ConfigError, match="IPv4"):
        optional_network_settings("lab", None, "agent.local:8888", None, Stdin(tty=True), lambda: asked.append(1))
    assert asked == []


def test_flash_without_network_options_provisions_nothing_and_half_of_them_is_an_error():
    assert optional_network_settings(None, None, None, None, Stdin(), lambda: "") is None
    with pytest.raises(ConfigError, match="both --wifi-ssid and --agent"):
        optional_network_settings("lab", None, None, None, Stdin(), lambda: "")
    with pytest.raises(ConfigError, match="both --wifi-ssid and --agent"):
        optional_network_settings(None, None, None, 3, Stdin(), lambda: "")


def test_password_sources(tmp_path):
    secret = tmp_path / "pw"
    secret.write_text("hunter2hunter2\n")
    assert read_password(str(secret), Stdin(), lambda: "x") == "hunter2hunter2"
    secret.write_text("ends in spaces  \r\n")
    assert read_password(str(secret), Stdin(), lambda: "x") == "ends in spaces  "
    assert read_password("-", Stdin("from stdin\n"), lambda: "x") == "from stdin"
    assert read_password("/dev/null", Stdin(), lambda: "x") == ""
    assert read_password(None, Stdin(tty=True), lambda: "typed in") == "typed in"
    with pytest.raises(ConfigError, match="no terminal to ask on"):
        read_password(None, Stdin(), lambda: "x")
    with pytest.raises(ConfigError, match="cannot read the password file"):
        read_password(str(tmp_path / "missing"), Stdin(), lambda: "x")


def test_a_password_source_without_end_is_read_no_further_than_a_password(tmp_path):
    with pytest.raises(ConfigError, match="holds more than a Wi-Fi password") as caught:
        read_password("/dev/zero", Stdin(), lambda: "x")
    assert caught.value.exit_code == 2

    class Endless(Stdin):
        def read(self, size: int = -1) -> str:
            assert 0 < size < 100, "stdin read without a limit"
            return "p" * size

    with pytest.raises(ConfigError, match="stdin holds more than"):
        read_password("-", Endless(), lambda: "x")
    longest = tmp_path / "pw"
    longest.write_text("x" * 63 + "\r\n")
    assert read_password(str(longest), Stdin(), lambda: "x") == "x" * 63


def test_the_nvs_image_holds_the_settings_in_the_firmwares_namespace():
    settings = NetSettings('#lab, "net"', "p@ss,word #1", "10.0.0.2", 9999, 42)
    previous = os.umask(0o022)  # a usual umask: a file created without care would be 0644
    try:
        with nvs_image(settings, 0x6000) as image:
            data = image.read_bytes()
            assert len(data) == 0x6000
            # Nothing changes its mode after the generator wrote it: this is how it was created.
            assert stat.S_IMODE(image.stat().st_mode) == 0o600
            assert stat.S_IMODE(image.parent.stat().st_mode) == 0o700
            assert [p.name for p in image.parent.iterdir()] == [image.name], "the CSV is gone once the image exists"
    finally:
        os.umask(previous)
    assert read_nvs(data) == {
        "espdock": {
            "ssid": '#lab, "net"',
            "password": "p@ss,word #1",
            "agent_host": "10.0.0.2",
            "agent_port": 9999,
            "domain_id": 42,
        }
    }
    assert not image.parent.exists()


def test_the_temporary_files_go_also_when_the_write_fails():
    with pytest.raises(KeyboardInterrupt), nvs_image(NetSettings("lab", "", "10.0.0.2", 1), 0x3000) as image:
        directory = image.parent
        raise KeyboardInterrupt
    assert not directory.exists()


def test_the_credentials_a_provisioning_killed_outright_left_are_removed_by_the_next(tmp_path, monkeypatch):
    """kill -9 while the generator ran left the WiFi password in the temp dir, for good."""
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    left = tmp_path / "espdock-provision-0000:1:1-ab12cd34"  # another boot's process: gone
    left.mkdir()
    (left / "nvs.csv").write_text("espdock,namespace,,\npassword,data,string,secret\n")
    with nvs_image(NetSettings("lab", "", "10.0.0.2", 1), 0x3000) as image:
        assert image.parent.parent == tmp_path
    assert list(tmp_path.iterdir()) == []


def test_the_credentials_root_s_provisioning_handed_to_the_user_and_left_are_removed_by_root_s_next(
    tmp_path, monkeypatch
):
    """Run as root, provisioning hands its directory to the container's user; killed outright, it
    left the password there, and root's next provisioning removed only root's own leftovers."""
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    left = tmp_path / "espdock-provision-0000:1:1-ab12cd34"  # another boot's process: gone
    left.mkdir()
    (left / IMAGE_NAME).write_bytes(b"secret")
    for path in (left, left / IMAGE_NAME):
        os.chown(path, 4243, 4243)
    with nvs_image(NetSettings("lab", "", "10.0.0.2", 1), 0x3000, owner=(4243, 4243)) as image:
        assert image.parent.parent == tmp_path
    assert list(tmp_path.iterdir()) == []


def test_the_nvs_partition_comes_from_the_installed_table(tmp_path):
    (tmp_path / "partition_table").mkdir()
    (tmp_path / "partition_table/partition-table.bin").write_bytes(SINGLE_APP_LARGE)
    nvs = nvs_partition(tmp_path, {}, "cam")
    assert (nvs.label, nvs.offset, nvs.size) == ("nvs", 0x9000, 0x6000)
    assert [p.label for p in parse_partition_table(SINGLE_APP_LARGE)] == ["nvs", "phy_init", "factory"]


def test_a_table_without_nvs_or_no_table_is_refused(tmp_path):
    (tmp_path / "partition_table").mkdir()
    path = tmp_path / "partition_table/partition-table.bin"
    path.write_bytes(NO_NVS)
    with pytest.raises(ConfigError, match="no NVS partition labelled 'nvs' to provision") as caught:
        nvs_partition(tmp_path, {}, "cam")
    assert caught.value.exit_code == 2
    # An NVS partition of another name: nvs_flash_init() never opens it, and it would be erased.
    path.write_bytes(table(("myconf", 1, 2, 0xA000, 0x6000), ("factory", 0, 0, 0x10000, 0x100000)))
    with pytest.raises(ConfigError, match="'myconf'; the firmware reads none of them") as caught:
        nvs_partition(tmp_path, {}, "cam")
    assert caught.value.exit_code == 2
    # Too small for a read-write NVS: the generator warned and made a read-only image, which the
    # firmware's nvs_flash_init() refused (and erased), and provisioning said it had provisioned.
    path.write_bytes(table(("nvs", 1, 2, 0x9000, 0x2000), ("factory", 0, 0, 0x10000, 0x100000)))
    with pytest.raises(
        ConfigError, match="'nvs' partition is 0x2000 bytes; a read-write NVS partition needs"
    ) as caught:
        nvs_partition(tmp_path, {}, "cam")
    assert caught.value.exit_code == 2
    path.write_bytes(os.urandom(64))
    with pytest.raises(WorkspaceError, match="not an ESP-IDF partition table"):
        nvs_partition(tmp_path, {}, "cam")
    with pytest.raises(WorkspaceError, match="no installed partition table"):
        nvs_partition(Path(tmp_path / "elsewhere"), {}, "cam")
