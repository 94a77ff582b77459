# contract double of /opt/ros/jazzy/setup.sh (POSIX sh): puts this prefix on the paths the
# real one extends (ament, CMake, executables, libraries, Python) and sets the ROS_* variables
# its ros_environment hook sets. Sourcing it twice adds nothing twice.
_espdock_double_prefix=/opt/ros/jazzy
_espdock_double_add() {
  # $1: variable name, $2: entry
  eval "_espdock_double_value=\${$1:-}"
  case ":$_espdock_double_value:" in
    *":$2:"*) ;;
    *) eval "export $1=\"$2\${_espdock_double_value:+:\$_espdock_double_value}\"" ;;
  esac
}
_espdock_double_add AMENT_PREFIX_PATH "$_espdock_double_prefix"
_espdock_double_add CMAKE_PREFIX_PATH "$_espdock_double_prefix"
_espdock_double_add PATH "$_espdock_double_prefix/bin"
_espdock_double_add LD_LIBRARY_PATH "$_espdock_double_prefix/lib"
# The wheels vendor their libraries into <wheel>.libs directories (auditwheel) and find them
# through a .pth hook that a PYTHONPATH entry never runs; the real prefix has them in lib/.
for _espdock_double_libs in "$_espdock_double_prefix"/lib/python3.11/site-packages/*.libs; do
  _espdock_double_add LD_LIBRARY_PATH "$_espdock_double_libs"
done
unset _espdock_double_libs
_espdock_double_add PYTHONPATH "$_espdock_double_prefix/lib/python3.11/site-packages"
export ROS_VERSION=2 ROS_PYTHON_VERSION=3 ROS_DISTRO=jazzy ROS_AUTOMATIC_DISCOVERY_RANGE="${ROS_AUTOMATIC_DISCOVERY_RANGE:-SUBNET}"
unset _espdock_double_prefix _espdock_double_value
unset -f _espdock_double_add
