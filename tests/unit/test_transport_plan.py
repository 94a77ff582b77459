"""The transport a firmware package selects and the micro-ROS library it gets, without an engine."""

import json
from dataclasses import replace

import pytest

from espdock.errors import WorkspaceError
from espdock.firmware.plan import micro_ros_image
from espdock.firmware.transport import firmware_transport, library_colcon_meta
from tests.unit.test_micro_ros_plan import CAM, DEFAULT, INPUTS, META, PACKAGES

UART = b"CONFIG_ESPDOCK_TRANSPORT_UART=y\nCONFIG_ESPDOCK_UART_BAUD=115200\n"
USB = b"CONFIG_ESPDOCK_TRANSPORT_USB_SERIAL_JTAG=y\n"


def with_defaults(text: bytes, meta: str = META):
    return replace(INPUTS, sdkconfig_defaults={"cam": {"sdkconfig.defaults": text}}, app_metas={"cam": meta})


def image(inputs, target="esp32s3"):
    return micro_ros_image(DEFAULT, inputs, PACKAGES, CAM, target)


def library_meta(spec) -> dict:
    return json.loads(dict(spec.context)["micro-ros/app-colcon.meta"])


def rmw_args(spec) -> list[str]:
    return library_meta(spec)["names"]["rmw_microxrcedds"]["cmake-args"]


def test_no_choice_is_udp_and_the_target_file_wins():
    assert firmware_transport({}, "esp32") == "udp"
    assert firmware_transport({"sdkconfig.defaults": UART}, "esp32") == "uart"
    both = {"sdkconfig.defaults": UART, "sdkconfig.defaults.esp32s3": USB}
    assert firmware_transport(both, "esp32s3") == "usb-serial-jtag"
    assert firmware_transport(both, "esp32") == "uart"


def test_a_udp_package_keeps_its_meta_and_its_library_key():
    """Adding the transport changed nothing for existing UDP packages: no library rebuild."""
    plain = image(with_defaults(b"CONFIG_SPIRAM=y\n"))
    explicit = image(with_defaults(b"CONFIG_SPIRAM=y\nCONFIG_ESPDOCK_TRANSPORT_UDP=y\n"))
    assert plain.key == explicit.key
    assert dict(plain.context)["micro-ros/app-colcon.meta"] == META.encode()


def test_a_serial_package_gets_a_custom_transport_library_in_its_own_image():
    udp = image(with_defaults(b""))
    uart = image(with_defaults(UART))
    usb = image(with_defaults(USB))
    assert "-DRMW_UXRCE_TRANSPORT=custom" in rmw_args(uart)
    assert "-DRMW_UXRCE_MAX_PUBLISHERS=1" in rmw_args(uart)  # the package's own limits stay
    assert not any(a.startswith("-DRMW_UXRCE_TRANSPORT") for a in rmw_args(udp))
    assert udp.key != uart.key
    # The same library serves a UART and a USB board: only the firmware's callbacks differ.
    assert uart.key == usb.key


def test_a_serial_package_without_a_meta_gets_one():
    spec = image(with_defaults(UART, meta=""))
    assert rmw_args(spec) == ["-DRMW_UXRCE_TRANSPORT=custom"]


def test_usb_serial_jtag_on_a_chip_without_one_is_refused_before_any_build():
    for chip in ("esp32", "esp32s2"):
        with pytest.raises(
            WorkspaceError, match=rf"{chip} has no USB-Serial-JTAG port, but its sdkconfig\.defaults selects"
        ):
            image(with_defaults(USB), target=chip)
    for chip in ("esp32c3", "esp32s3"):
        image(with_defaults(USB), target=chip)
    # The file that chose it is the one named: the target's own, where that one chose.
    chip_file = replace(INPUTS, sdkconfig_defaults={"cam": {"sdkconfig.defaults.esp32": USB}}, app_metas={"cam": META})
    with pytest.raises(WorkspaceError, match=r"but its sdkconfig\.defaults\.esp32 selects"):
        image(chip_file, target="esp32")


def test_a_meta_contradicting_the_kconfig_choice_is_refused():
    custom = json.dumps({"names": {"rmw_microxrcedds": {"cmake-args": ["-DRMW_UXRCE_TRANSPORT=custom"]}}})
    with pytest.raises(WorkspaceError, match="but it uses the udp transport, which needs -DRMW_UXRCE_TRANSPORT=udp"):
        image(with_defaults(b"", meta=custom))
    # Chosen in a file: that file is named, the target's own where that one chose.
    udp = b"CONFIG_ESPDOCK_TRANSPORT_UDP=y\n"
    files = {"sdkconfig.defaults": UART, "sdkconfig.defaults.esp32s3": udp}
    chosen = replace(INPUTS, sdkconfig_defaults={"cam": files}, app_metas={"cam": custom})
    with pytest.raises(WorkspaceError, match=r"but its sdkconfig\.defaults\.esp32s3 selects the udp transport"):
        image(chosen)
    # Saying what espdock would add is fine, and changes nothing.
    assert library_colcon_meta("cam", custom, "uart") == custom
