"""A serial NMEA reader: GGA sentences from a GPS receiver become sensor_msgs/NavSatFix."""

import serial


def _degrees(value: str, hemisphere: str) -> float:
    """ddmm.mmmm (or dddmm.mmmm) and N/S/E/W as signed decimal degrees."""
    head, minutes = divmod(float(value), 100.0)
    degrees = head + minutes / 60.0
    return -degrees if hemisphere in ("S", "W") else degrees


def parse_gga(sentence: str) -> tuple[float, float, float] | None:
    """Latitude, longitude and altitude of a $..GGA sentence with a fix; None otherwise."""
    body, _, checksum = sentence.strip().lstrip("$").partition("*")
    if checksum:
        computed = 0
        for char in body:
            computed ^= ord(char)
        if f"{computed:02X}" != checksum.upper():
            return None
    fields = body.split(",")
    if not fields[0].endswith("GGA") or len(fields) < 10 or fields[6] in ("", "0"):
        return None
    return _degrees(fields[2], fields[3]), _degrees(fields[4], fields[5]), float(fields[9])


def read_fixes(port: serial.Serial, count: int) -> list[tuple[float, float, float]]:
    """The next COUNT fixes read from PORT."""
    fixes = []
    while len(fixes) < count:
        line = port.readline().decode("ascii", errors="replace")
        if not line:
            break
        fix = parse_gga(line)
        if fix is not None:
            fixes.append(fix)
    return fixes


def main() -> None:
    import rclpy
    from rclpy.node import Node
    from sensor_msgs.msg import NavSatFix

    rclpy.init()
    node = Node("serial_gps")
    port_name = node.declare_parameter("port", "/dev/ttyUSB0").value
    baud = node.declare_parameter("baud", 4800).value
    publisher = node.create_publisher(NavSatFix, "fix", 10)
    with serial.Serial(port_name, baud, timeout=2) as port:
        while rclpy.ok():
            for latitude, longitude, altitude in read_fixes(port, 1):
                message = NavSatFix()
                message.header.stamp = node.get_clock().now().to_msg()
                message.header.frame_id = "gps"
                message.latitude, message.longitude, message.altitude = latitude, longitude, altitude
                publisher.publish(message)
            rclpy.spin_once(node, timeout_sec=0)
    node.destroy_node()
    rclpy.shutdown()


if __name__ == "__main__":
    main()
