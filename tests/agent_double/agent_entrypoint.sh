#!/bin/sh
# contract double of the micro-ROS agent's entrypoint and command line (micro_ros_agent, built on
# Micro XRCE-DDS Agent's CLI): checks the arguments espdock gives it the way the agent does,
# says what it would serve, then runs until SIGINT or SIGTERM as the agent does.
set -u
usage() { echo "micro-ros-agent double: usage: {serial --dev DEV [-b BAUD] | udp4 --port PORT}" >&2; exit 1; }
[ $# -ge 1 ] || usage
transport=$1
shift
dev="" baud=115200 port=""
while [ $# -gt 0 ]; do
    case $1 in
        -D|--dev) dev=${2:-}; shift 2 ;;
        -b|--baudrate) baud=${2:-}; shift 2 ;;
        -p|--port) port=${2:-}; shift 2 ;;
        -v*|--verbose) shift ;;
        *) echo "micro-ros-agent double: unknown option $1" >&2; usage ;;
    esac
done
stop() { echo "micro-ros-agent double: stopped"; exit 0; }
trap stop INT TERM
case $transport in
    serial)
        [ -n "$dev" ] || usage
        # The real agent waits for a missing device ("Serial port not found"); espdock checks
        # the port before starting it, so here a missing one is a failure the test sees.
        if [ ! -c "$dev" ]; then echo "micro-ros-agent double: $dev is not a character device" >&2; exit 3; fi
        echo "micro-ros-agent double: serial $dev at $baud baud, ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-0}, uid $(id -u)"
        ;;
    udp4)
        [ -n "$port" ] || usage
        echo "micro-ros-agent double: udp4 port $port, ROS_DOMAIN_ID=${ROS_DOMAIN_ID:-0}"
        ;;
    --help|-h) usage ;;
    *) echo "micro-ros-agent double: unknown transport $transport" >&2; usage ;;
esac
while :; do sleep 0.1; done
