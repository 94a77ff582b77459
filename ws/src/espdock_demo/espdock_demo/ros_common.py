"""What every demo node shares: QoS profiles, conversions, heartbeat, diagnostics, the main loop."""

from __future__ import annotations

import math
import os
import pathlib
import signal
import sys
import threading
import time
from collections.abc import Callable, Mapping

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.context import Context
from rclpy.event_handler import SubscriptionEventCallbacks
from rclpy.exceptions import InvalidHandle, ParameterException
from rclpy.executors import (
    Executor,
    ExternalShutdownException,
    ShutdownException,
    SingleThreadedExecutor,
    TimeoutException,
)
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.utilities import get_default_context
from std_msgs.msg import String

from espdock_demo.names import DIAGNOSTICS_TOPIC, HEARTBEAT_FILE_DEFAULT

# Image subscribers keep only the newest frame and never ask for resends: a
# subscriber that falls behind skips to the latest frame instead of building a backlog.
IMAGE_SUB_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.BEST_EFFORT,
    durability=DurabilityPolicy.VOLATILE,
)
# As the firmware's rclc_publisher_init_default: reliable, volatile (matches best-effort readers too).
IMAGE_PUB_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=2,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
TEXT_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
# The LED colour is state: a late subscriber gets the colour the strip shows now.
LATCHED_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)

HEARTBEAT_FILE = os.environ.get("ESPDOCK_HEARTBEAT", HEARTBEAT_FILE_DEFAULT)


def subscribe_text(node: Node, topic: str, callback: Callable[[String], None]) -> None:
    """CALLBACK for TOPIC's texts (TEXT_QOS: any publisher's, `ros2 topic pub`'s too) and, once, for
    the last one a latched publisher (qr_detector's, LATCHED_QOS) sent before NODE started: a node
    restarted while one QR code stayed in view showed nothing (an LED strip left dark) until the
    code changed, qr_detector publishing only changes. The catch-up ends with its first text."""
    node.create_subscription(String, topic, callback, TEXT_QOS)
    catch_up = []

    def first(msg: String) -> None:
        if catch_up:  # a live text may come through both: taken twice, as a repeat, which changes nothing
            node.destroy_subscription(catch_up.pop())
            callback(msg)

    # A volatile publisher (the probe's, `ros2 topic pub`'s) is no match for it, and rclpy's default
    # warned "No messages will be received from it", which the other subscription receives.
    quiet = SubscriptionEventCallbacks(incompatible_qos=lambda _status: None)
    catch_up.append(node.create_subscription(String, topic, first, LATCHED_QOS, event_callbacks=quiet))


def config_to_dict(msg: object) -> dict[str, int]:
    """A CameraConfig message as a field -> value dict."""
    return {name: int(getattr(msg, name)) for name in msg.get_fields_and_field_types()}


def start_heartbeat(node: Node, period: float = 1.0) -> Callable[[], float]:
    """Touch HEARTBEAT_FILE from the executor every PERIOD s (the container healthcheck reads it).

    Returns a function giving the seconds since the last beat.
    """
    path = pathlib.Path(HEARTBEAT_FILE)
    last = [time.monotonic()]

    def beat() -> None:
        last[0] = time.monotonic()
        try:
            path.touch()
        except OSError:
            pass  # outside a container, e.g. a read-only /tmp: the healthcheck is not used there

    beat()
    node.create_timer(period, beat)
    return lambda: time.monotonic() - last[0]


def start_diagnostics(node: Node, values: Callable[[], Mapping[str, object]], period: float = 1.0) -> None:
    """Publish VALUES() as this node's DiagnosticStatus on /diagnostics every PERIOD seconds."""
    publisher = node.create_publisher(DiagnosticArray, DIAGNOSTICS_TOPIC, 10)
    name = node.get_fully_qualified_name()

    def publish() -> None:
        array = DiagnosticArray()
        array.header.stamp = node.get_clock().now().to_msg()
        status = DiagnosticStatus(level=DiagnosticStatus.OK, name=name, hardware_id="espdock_demo", message="running")
        status.values = [KeyValue(key=str(k), value=str(v)) for k, v in values().items()]
        array.status = [status]
        publisher.publish(array)

    node.create_timer(period, publish)


def run_ready(executor: Executor) -> None:
    """Run every callback whose message, timer or response has already come, without waiting for more."""
    while True:
        try:
            handler, _, _ = executor.wait_for_ready_callbacks(timeout_sec=0)
        except TimeoutException:
            return
        handler()
        if handler.exception() is not None:
            raise handler.exception()


# The signals _request_stop took: a stop, however its KeyboardInterrupt surfaced (or was dropped).
_stop_requested: list[int] = []
# Set until the node is made: a stop is raised only while the process starts and makes its node,
# where nothing else would end what it does. After it, rclpy's handler thread shuts the context
# down as the signal comes, which ends the spin, and the interpreter runs _request_stop late, at
# its next Python call: raised there, the KeyboardInterrupt cut short whatever that was (the
# clean-up, a polling node's round inside rclpy's Task constructor), exit 130 with a traceback.
_raise_stops = threading.Event()


def _stopped_by_signal(exc: BaseException, context: Context, started: bool = True) -> bool:
    """Whether EXC is how a stop request surfaced rather than a fault.

    rclpy's signal handler shuts the context down from its own thread, at any moment: between
    a check of context.ok() and the wait set that follows (RCLError: "the given context is not
    valid"), in a timer's publish, while a node is still being made (InvalidHandle, RCLError),
    or as ExternalShutdownException. Once the context is down, an rclpy error is that stop; no
    check before a call can close the gap, since the signal may come right after the check.
    The KeyboardInterrupt _request_stop raises may surface as something else: raised while
    pybind11 converts an argument (rclpy's take_message), it comes out as a RuntimeError.
    Before rclpy.init succeeded (not STARTED) the context was never up: its error is a fault
    (arguments rcl cannot parse), which exited 0 and was restarted, over and over, unsaid.
    """
    if isinstance(exc, (KeyboardInterrupt, ExternalShutdownException, ShutdownException)) or _stop_requested:
        return True
    return started and isinstance(exc, (_rclpy.RCLError, InvalidHandle, RuntimeError)) and not context.ok()


def _request_stop(signum: int, _frame: object) -> None:
    # Remembered as well as raised: raised where the handler happens to run (a weakref callback,
    # a __del__), the KeyboardInterrupt is printed and dropped, and the stop must not be.
    _stop_requested.append(signum)
    if not _raise_stops.is_set() or sys.exc_info()[1] is not None:
        # rclpy's handler ends the spin; or an error is being handled (the rclpy error the stop
        # caused inside rclpy's C++ as the node was being made), which the remembered stop makes a
        # stop (_stopped_by_signal): raised there, the KeyboardInterrupt escaped, exit 130.
        return
    _ignore_signals()
    raise KeyboardInterrupt


def _unraisable(unraisable: sys.UnraisableHookArgs) -> None:
    # A stop cuts rclpy's objects short as they are made (a context shut down inside an Executor's
    # __init__, a KeyboardInterrupt inside a Task's): their __del__ then fails on what they lack
    # ("no attribute '_sigint_gc'"), printed as "Exception ignored in" with a traceback.
    if not _stop_requested:
        sys.__unraisablehook__(unraisable)


def _ignore_signals() -> None:
    """The stop is under way: a second SIGTERM or Ctrl-C must not cut its clean-up short."""
    for signum in (signal.SIGTERM, signal.SIGINT):
        signal.signal(signum, signal.SIG_IGN)


class SettingError(ValueError):
    """A setting (a ROS parameter) the node cannot use: said in one line as it exits (spin_node)."""


def positive_setting(node: Node, name: str, default: float, description: str) -> float:
    """NODE's parameter NAME, a number above 0 (an integer as good as a float); SettingError naming
    it where it is another value."""
    descriptor = ParameterDescriptor(description=description, dynamic_typing=True)
    value = node.declare_parameter(name, default, descriptor).value
    try:
        number = float(value)
    except (TypeError, ValueError):
        raise SettingError(f"{name}:={value!r}: {description} must be a number") from None
    if not (number > 0 and math.isfinite(number)):
        raise SettingError(f"{name}:={value!r}: {description} must be above 0 (and finite)")
    return number


def spin_node(
    make_node: Callable[[], Node],
    on_shutdown: Callable[[Node], None] | None = None,
    poll_period: float | None = None,
) -> None:
    """Init rclpy, spin the node MAKE_NODE makes until Ctrl-C or SIGTERM, then clean up.

    With POLL_PERIOD the node sleeps between rounds of its callbacks, every POLL_PERIOD
    seconds, instead of waking on each message: for nodes that only watch the control
    path, whose Python would otherwise run at the very moments the QR text and the LED
    colour go by (its DDS threads still receive each message as it comes).

    A stop (SIGTERM, SIGINT) ends the process with exit 0 whatever it interrupts. Anything
    else a node raises ends the process with an error, so the container's restart policy
    brings it back.
    """
    # SIGTERM too raises KeyboardInterrupt while the node is being made.
    _raise_stops.set()
    sys.unraisablehook = _unraisable
    context = get_default_context()
    node = None
    started = False
    try:
        # In the try: a signal the moment its handler is in runs it as signal.signal returns,
        # and its KeyboardInterrupt escaped from here (exit 130 with a traceback).
        for signum in (signal.SIGTERM, signal.SIGINT):
            signal.signal(signum, _request_stop)
        rclpy.init()
        started = True
        node = make_node()
        _raise_stops.clear()
        if _stop_requested or not context.ok():
            return  # a stop that came as the node was made, and was not raised
        executor = SingleThreadedExecutor()
        executor.add_node(node)
        if poll_period is None:
            executor.spin()
        else:
            while context.ok() and not _stop_requested:
                time.sleep(poll_period)
                run_ready(executor)
    except BaseException as exc:
        if not _stopped_by_signal(exc, context, started):
            if not started and isinstance(exc, _rclpy.RCLError):
                # rcl's words name the argument it could not parse: one line, not rclpy's traceback.
                raise SystemExit(f"error: {exc}") from None
            if not started and isinstance(exc, _rclpy.UnknownROSArgsError):
                raise SystemExit(f"error: unknown ROS arguments (after --ros-args): {exc}") from None
            if node is None and isinstance(exc, (SettingError, ParameterException)):
                # A setting it cannot use (`-p port:=abc`, ESPDOCK_DEMO_FPS=0): rclpy's words and
                # the node's name the parameter; the traceback would only bury them.
                raise SystemExit(f"error: {exc}") from None
            raise
    finally:
        _raise_stops.clear()
        _ignore_signals()
        try:
            if node is not None:
                if on_shutdown is not None:
                    on_shutdown(node)
                node.destroy_node()
        except BaseException as exc:
            if not _stopped_by_signal(exc, context):
                raise
        finally:
            _shut_down(context)


def _shut_down(context: Context) -> None:
    """rclpy.try_shutdown, whose check of the context and its shutdown rclpy's own signal handler
    may come between, shutting the context down from its thread (a stop just as the clean-up
    began: RCLError, "rcl_shutdown already called"). The context is down either way."""
    try:
        rclpy.try_shutdown()
    except _rclpy.RCLError:
        if context.ok():
            raise
