"""Logs every message heard on /beacon."""

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from std_msgs.msg import String


class BeaconLog(Node):
    def __init__(self) -> None:
        super().__init__("beacon_log")
        self.create_subscription(String, "beacon", self._heard, 10)

    def _heard(self, msg: String) -> None:
        self.get_logger().info(f"heard: {msg.data}")


def main(args=None) -> None:
    rclpy.init(args=args)
    node = BeaconLog()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
