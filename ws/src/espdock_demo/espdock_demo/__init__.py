"""The QR-driven LED demo of the seed's chapter 7: nodes, simulators and their pure logic.

Modules without `rclpy` imports (names, colors, camera_config, scene, qr, mjpeg,
web) hold the logic and are unit-tested on the host; the node modules wire them
to ROS.
"""
