#!/bin/bash
# contract double of the official image's /ros_entrypoint.sh: the ROS environment of
# $ROS_DISTRO (its setup.bash, with no arguments passed on), then the command.
set -e
source "/opt/ros/$ROS_DISTRO/setup.bash" --
exec "$@"
