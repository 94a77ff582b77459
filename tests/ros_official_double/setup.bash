# contract double of /opt/ros/jazzy/setup.bash: the same environment as setup.sh, from bash.
AMENT_SHELL=bash
. /opt/ros/jazzy/setup.sh
