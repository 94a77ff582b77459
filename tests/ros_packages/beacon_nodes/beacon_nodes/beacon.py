"""Publishes `<prefix> <n>` on /beacon every PERIOD seconds and logs each message; with
IGNORE_STOP it ignores SIGINT and SIGTERM, as a node busy in C code or written carelessly does."""

import signal

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from std_msgs.msg import String


class Beacon(Node):
    def __init__(self) -> None:
        super().__init__("beacon")
        self.declare_parameter("prefix", "beacon")
        self.declare_parameter("period", 0.2)
        if self.declare_parameter("ignore_stop", False).value:
            signal.signal(signal.SIGINT, signal.SIG_IGN)
            signal.signal(signal.SIGTERM, signal.SIG_IGN)
        self._publisher = self.create_publisher(String, "beacon", 10)
        self._count = 0
        self.create_timer(self.get_parameter("period").value, self._tick)
        self.get_logger().info("beacon up")

    def _tick(self) -> None:
        msg = String(data=f"{self.get_parameter('prefix').value} {self._count}")
        self._publisher.publish(msg)
        self.get_logger().info(f"sent: {msg.data}")
        self._count += 1


def main(args=None) -> None:
    rclpy.init(args=args)
    node = Beacon()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
