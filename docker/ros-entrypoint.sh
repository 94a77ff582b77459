#!/bin/sh
# Put the built workspace on the ament and Python paths, then run the command.
# ESPDOCK_WS_INSTALL names the install space to use (the image's own by
# default; `espdock` points it at the mounted workspace's).
set -e
prefix="${ESPDOCK_WS_INSTALL:-/opt/espdock/ws/install}"
if [ -f "$prefix/local_setup.sh" ]; then
  COLCON_CURRENT_PREFIX="$prefix"
  export COLCON_CURRENT_PREFIX
  . "$prefix/local_setup.sh"
  unset COLCON_CURRENT_PREFIX
fi
exec "$@"
