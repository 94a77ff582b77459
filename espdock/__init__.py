"""espdock: build ESP-IDF firmware, micro-ROS and a ROS 2 workspace in containers."""

__version__ = "0.1.0"
