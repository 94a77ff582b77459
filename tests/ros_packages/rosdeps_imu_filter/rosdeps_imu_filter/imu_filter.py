"""Orientation from an IMU's raw readings: sensor_msgs/Imu in on imu/data_raw, out on imu/data."""

import numpy as np
from ahrs.filters import Madgwick


class OrientationFilter:
    """Madgwick's filter over successive readings, starting level."""

    def __init__(self, period: float) -> None:
        self._filter = Madgwick(Dt=period)
        self.quaternion = np.array([1.0, 0.0, 0.0, 0.0])  # w, x, y, z

    def update(self, gyro: tuple[float, float, float], accel: tuple[float, float, float]) -> np.ndarray:
        self.quaternion = self._filter.updateIMU(self.quaternion, gyr=np.array(gyro), acc=np.array(accel))
        return self.quaternion


def main() -> None:
    import rclpy
    from rclpy.node import Node
    from sensor_msgs.msg import Imu

    rclpy.init()
    node = Node("imu_filter")
    fusion = OrientationFilter(node.declare_parameter("period", 0.01).value)
    publisher = node.create_publisher(Imu, "imu/data", 10)

    def on_raw(raw: Imu) -> None:
        w, x, y, z = fusion.update(
            (raw.angular_velocity.x, raw.angular_velocity.y, raw.angular_velocity.z),
            (raw.linear_acceleration.x, raw.linear_acceleration.y, raw.linear_acceleration.z),
        )
        raw.orientation.w, raw.orientation.x, raw.orientation.y, raw.orientation.z = w, x, y, z
        publisher.publish(raw)

    node.create_subscription(Imu, "imu/data_raw", on_raw, 10)
    try:
        rclpy.spin(node)
    finally:
        node.destroy_node()
        rclpy.shutdown()


if __name__ == "__main__":
    main()
