"""Tools for testing and benchmarking the espdock demo from inside its ROS graph (not part of the demo)."""
