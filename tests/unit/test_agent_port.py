"""The agent-port check against the micro-ROS library's own header (espdock.firmware.agent_port)."""

import pytest

from espdock.errors import ConfigError
from espdock.firmware.agent_port import check_agent_port, port_digits_kept

# rmw_microxrcedds_c/include/rmw_microros/rmw_microros.h as upstream writes it: before #315 (rolling and
# humble at 6833232 / 3144202, the last trees readable here) and with #315's MAX_PORT_LEN.
BEFORE_315 = """#ifdef RMW_UXRCE_TRANSPORT_IPV4
  #define MAX_IP_LEN         16
#elif defined(RMW_UXRCE_TRANSPORT_IPV6)
  #define MAX_IP_LEN         39
#endif  // ifdef RMW_UXRCE_TRANSPORT_IPV4
#define MAX_PORT_LEN         5
#define MAX_SERIAL_DEVICE    50
"""
AFTER_315 = BEFORE_315.replace("MAX_PORT_LEN         5", "MAX_PORT_LEN         6")


def test_the_digits_kept_are_max_port_len_minus_the_terminator():
    assert port_digits_kept(BEFORE_315) == 4
    assert port_digits_kept(AFTER_315) == 5
    assert port_digits_kept("#define MAX_IP_LEN 16\n") is None
    assert port_digits_kept("// #define MAX_PORT_LEN 5 was the old value\n") is None


@pytest.mark.parametrize("port", [10000, 16510, 65535])
def test_a_five_digit_port_is_refused_for_a_library_before_315_saying_what_the_board_would_use(port):
    with pytest.raises(ConfigError) as err:
        check_agent_port(port, BEFORE_315, "camera_node")
    message = err.value.message
    assert f"agent port {port} does not fit camera_node's micro-ROS library" in message
    assert f"would talk to port {str(port)[:4]}" in message and "#315" in message
    assert "below 10000" in err.value.hint


@pytest.mark.parametrize(("port", "header"), [(8888, BEFORE_315), (9999, BEFORE_315), (65535, AFTER_315)])
def test_ports_the_library_keeps_pass(port, header):
    check_agent_port(port, header, "camera_node")


def test_a_header_that_states_no_length_leaves_the_check_to_the_board():
    check_agent_port(65535, "", "camera_node")
