"""Subscribes to /count ("count: N") and logs the mean and spread of the last values as a table."""

from __future__ import annotations

import numpy
from tabulate import tabulate


def summary(values: list[float]) -> str:
    """A table of how many VALUES there are, their mean and their standard deviation."""
    data = numpy.array(values, dtype=float)
    return tabulate([[len(data), data.mean(), data.std()]], headers=["n", "mean", "std"], floatfmt=".2f")


def main() -> None:
    import rclpy
    from std_msgs.msg import String

    rclpy.init()
    node = rclpy.create_node("table")
    values: list[float] = []

    def on_count(message: String) -> None:
        values.append(float(message.data.rsplit(" ", 1)[-1]))
        del values[:-20]
        node.get_logger().info("\n" + summary(values))

    node.create_subscription(String, "count", on_count, 10)
    try:
        rclpy.spin(node)
    except KeyboardInterrupt:
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    print(summary([1.0, 2.0, 3.0]))
