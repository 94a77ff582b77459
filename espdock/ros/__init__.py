"""The ROS 2 side: rosdep, colcon, the ROS and runtime images, `espdock run`/`shell`/`test`, the colcon extension."""
