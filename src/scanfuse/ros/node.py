"""The live ROS 2 node `scanfuse`: rclpy in, `LiveFusion` decides, rclpy out.

    python -m scanfuse.ros.node [--params-file FILE] [--ros-args -r /scan:=/lidar -p name:=value]
    scanfuse node ...            (the same)

Subscriptions are raw (CDR bytes), so messages are decoded and encoded by
`scanfuse.ros.messages` exactly as the bag processor does. Inputs use the
sensor-data QoS (best effort, keep last 5), which matches both best-effort
(Gazebo, camera drivers) and reliable publishers; outputs are reliable, keep
last 10, which slam_toolbox's, Nav2's and RViz's subscribers (reliable or best
effort) all accept. The inputs keep rclpy's default QoS event handlers (a publisher the
node cannot hear is logged); the outputs have none, to keep the executor's wait set small.
Only rclpy API that Humble has is used.

Named sources (`lidars`, `cameras`, `clouds`: string arrays; `NAME.field` parameters from
the models of `scanfuse.sources`) are declared at start-up; every source beyond the first
LiDAR and camera gets its own subscriptions (LaserScan, depth Image + CameraInfo,
PointCloud2) and is fed to the stream under its name.
"""

from __future__ import annotations

import argparse
import logging
import math
import re
import sys
import time
from typing import TYPE_CHECKING, Any

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    ParameterType,
    SetParametersResult,
)
from rclpy.exceptions import (
    NameValidationException,
    ParameterException,
    ParameterUninitializedException,
)
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.parameter import Parameter
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)
from rclpy.utilities import ok, remove_ros_args
from sensor_msgs.msg import CameraInfo, Image, Imu, LaserScan, PointCloud2

from scanfuse.config import NODE_NAME, FusionConfig, read_ros_params
from scanfuse.errors import ConfigError, ScanfuseError
from scanfuse.ros.graph import SilentInput, override_names, silent_inputs, unknown_names_message
from scanfuse.ros.live import Level, LiveFusion
from scanfuse.ros.live_view import (
    DEFAULT_HOST,
    DEFAULT_PORT,
    FoxgloveView,
    LiveView,
    make_view,
)
from scanfuse.ros.messages import CAMERA_INFO, IMAGE, LASER_SCAN
from scanfuse.ros.params import (
    Kind,
    NodeSettings,
    ParamSpec,
    all_param_specs,
    check_change,
    config_from_ros,
    settings_from_ros,
    source_list_spec,
    source_param_specs,
)
from scanfuse.sources import KINDS

try:  # Iron and later; Humble has the same class in rclpy.qos_event (deprecated since Iron)
    from rclpy.event_handler import PublisherEventCallbacks
except ImportError:  # pragma: no cover - Humble
    from rclpy.qos_event import PublisherEventCallbacks

if TYPE_CHECKING:
    from collections.abc import Sequence

    from scanfuse.ros.live import Health, Output

logger = logging.getLogger('scanfuse')

OUTPUT_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
TF_STATIC_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=100,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
TF_QOS = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=100)
# Best effort matches reliable and best-effort odometry publishers alike.
ODOMETRY_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST, depth=50, reliability=ReliabilityPolicy.BEST_EFFORT
)
# An input with no publisher this long after start-up is reported (discovery takes seconds).
SILENT_INPUT_GRACE_S = 5.0
GRAPH_PERIOD_S = 2.0  # how often the diagnostics timer asks the graph for publishers
# Fire just after a deadline, so `now >= deadline` holds when the timer runs.
DEADLINE_SLACK_S = 0.0005
_ROS_TYPES = {
    Kind.BOOL: ParameterType.PARAMETER_BOOL,
    Kind.INTEGER: ParameterType.PARAMETER_INTEGER,
    Kind.DOUBLE: ParameterType.PARAMETER_DOUBLE,
    Kind.STRING: ParameterType.PARAMETER_STRING,
    Kind.STRING_ARRAY: ParameterType.PARAMETER_STRING_ARRAY,
}


def descriptor(spec: ParamSpec) -> Any:
    """The rclpy `ParameterDescriptor` of a parameter (fields that exist in Humble only)."""
    result = ParameterDescriptor(
        name=spec.name,
        type=_ROS_TYPES[spec.kind],
        description=spec.description,
        additional_constraints=spec.constraints,
        # Doubles accept integers too (`-p camera_x:=0`); FusionConfig converts and checks.
        dynamic_typing=spec.kind is Kind.DOUBLE,
    )
    bounds = spec.value_range
    if bounds is not None and spec.kind is Kind.INTEGER:
        result.integer_range = [IntegerRange(from_value=int(bounds[0]), to_value=int(bounds[1]))]
    elif bounds is not None and spec.kind is Kind.DOUBLE:
        result.floating_point_range = [
            FloatingPointRange(from_value=float(bounds[0]), to_value=float(bounds[1]))
        ]
    return result


class _RosLogHandler(logging.Handler):
    """Sends the library's `logging` records to the node's rclpy logger (/rosout)."""

    def __init__(self, ros_logger: Any) -> None:
        super().__init__()
        self.ros_logger = ros_logger

    def emit(self, record: logging.LogRecord) -> None:
        message = self.format(record)
        if record.levelno >= logging.ERROR:
            self.ros_logger.error(message)
        elif record.levelno >= logging.WARNING:
            self.ros_logger.warning(message)
        elif record.levelno >= logging.INFO:
            self.ros_logger.info(message)
        else:
            self.ros_logger.debug(message)


def _load_defaults(params_file: str | None) -> tuple[FusionConfig, NodeSettings]:
    """Defaults from the parameter file: fusion settings and the node's own."""
    if params_file is None:
        return FusionConfig(), NodeSettings()
    values = read_ros_params(params_file)
    node_values: dict[str, Any] = {
        name: values.pop(name) for name in NodeSettings.model_fields if name in values
    }
    return FusionConfig.from_dict(values), settings_from_ros(node_values)


class ScanfuseNode:
    """The rclpy node: declares parameters, wires topics to a `LiveFusion`, reports health."""

    def __init__(
        self,
        defaults: FusionConfig,
        settings: NodeSettings,
        *,
        foxglove_port: int | None = None,
        foxglove_host: str = DEFAULT_HOST,
        overrides: Sequence[str] = (),
    ) -> None:
        self.node = rclpy.create_node(NODE_NAME)
        self.rosout = self.node.get_logger()
        self.specs = {spec.name: spec for spec in all_param_specs(defaults, settings)}
        for spec in self.specs.values():
            self.node.declare_parameter(spec.name, spec.default, descriptor(spec))
        self.specs.update(self._declare_sources(defaults))
        # rclpy keeps a -p override of an undeclared name unused and says nothing; a typo in
        # the parameter file is refused, so the same typo on the command line is too.
        unknown = [name for name in overrides if not self.node.has_parameter(name)]
        if unknown:
            raise ConfigError(unknown_names_message(unknown, self.specs, 'given with -p'))
        values = self.parameter_values()
        config = config_from_ros(values)
        settings = settings_from_ros(values)
        self.live = LiveFusion(
            config, pair_wait=settings.pair_wait, lidar_timeout=settings.lidar_timeout
        )
        self.live.warm_up()
        self.topics = config  # topic names are fixed at start-up
        self.view: LiveView = make_view(config, foxglove_port, foxglove_host)
        self.node.add_on_set_parameters_callback(self._on_set_parameters)
        sensor_qos = qos_profile_sensor_data
        # No LiDAR (scan_topic empty) or no camera (depth_topic empty): nothing to hear there.
        subscribed = []
        if config.has_lidar:
            subscribed.append(
                (LaserScan, LASER_SCAN, 'scan_topic', config.scan_topic, self._on_scan)
            )
        if config.has_camera:
            subscribed.append((Image, IMAGE, 'depth_topic', config.depth_topic, self._on_depth))
            subscribed.append(
                (
                    CameraInfo,
                    CAMERA_INFO,
                    'camera_info_topic',
                    config.camera_info_topic,
                    self._on_camera_info,
                )
            )
        # Resolved names (after remapping) -> (type, parameter), watched for publishers.
        self.inputs: dict[str, tuple[str, str]] = {}
        for kind, msgtype, parameter, topic, callback in subscribed:
            subscription = self.node.create_subscription(
                kind, topic, callback, sensor_qos, raw=True
            )
            self.inputs[subscription.topic_name] = (msgtype, parameter)
        self.started = time.monotonic()
        self.silent_since: dict[str, float] = {}
        self.silent_reported: dict[str, str] = {}
        self.graph_checked = -math.inf
        self.silent_due: list[SilentInput] = []
        self._subscribe_sources(config, sensor_qos)
        self.odometry_source = self._subscribe_odometry(config.odom_topic)
        if config.imu_topic:
            self.node.create_subscription(
                Imu, config.imu_topic, self._on_imu, qos_profile_sensor_data, raw=True
            )
        self.fused_pub = self._output_publisher(LaserScan, config.fused_topic)
        self.depth_pub = (
            self._output_publisher(LaserScan, config.depth_scan_topic)
            if config.publish_depth_scan
            else None
        )
        # The memory's outputs: the scan without it (SLAM) and the remembered points alone.
        self.instant_pub = self._optional_scan_publisher(config.memory, config.instant_topic)
        self.memory_pub = self._optional_scan_publisher(config.memory, config.memory_scan_topic)
        self.diagnostics_pub = self._output_publisher(DiagnosticArray, '/diagnostics')
        self.tf_source = self._subscribe_tf()
        self.node.create_timer(1.0, self._publish_diagnostics)
        # One-shot timers at the waiting scans' deadlines (no polling: it cost CPU all the time).
        self.deadline_timer: Any = None
        self.deadline_due: float | None = None
        inputs = ' + '.join(t for t in (config.scan_topic, config.depth_topic) if t)
        self.rosout.info(
            f'fusing {inputs or "named clouds"} -> {config.fused_topic} '
            f'(method {config.method.value}; extrinsics: {self.tf_source}; '
            f'odometry: {self.odometry_source})'
        )
        if isinstance(self.view, FoxgloveView):
            self.rosout.info(f'Foxglove live view on {self.view.url}')

    def _optional_scan_publisher(self, wanted: bool, topic: str) -> Any:
        if not (wanted and topic):
            return None
        return self._output_publisher(LaserScan, topic)

    def _output_publisher(self, msg_type: Any, topic: str) -> Any:
        """A publisher without rclpy's default QoS event handlers (issue 12): each is a
        waitable that the executor adds to its wait set at every wake-up, and the warning they
        give ("subscription requesting incompatible QoS") the subscriber's own node gives too
        (rclpy's and rclcpp's default on the subscription side, RViz's topic status). The
        inputs keep theirs: there the warning is ours to give."""
        quiet = PublisherEventCallbacks(use_default_callbacks=False)
        return self.node.create_publisher(msg_type, topic, OUTPUT_QOS, event_callbacks=quiet)

    def parameter_values(self) -> dict[str, Any]:
        return {name: self.node.get_parameter(name).value for name in self.specs}

    # ------------------------------------------------------------ named sources

    def _declare_sources(self, defaults: FusionConfig) -> dict[str, ParamSpec]:
        """`lidars`, `cameras`, `clouds` and, for every name listed, its section's fields."""
        specs: dict[str, ParamSpec] = {}
        seen: set[str] = set()
        for kind in KINDS:
            known = {source.name: source for source in getattr(defaults.sources, kind)}
            spec = source_list_spec(kind, list(known))
            specs[kind] = spec
            names = self._declare_list(spec)
            for name in names:
                if name in seen:
                    continue  # a name listed twice: the config names the repetition
                seen.add(name)
                for field in source_param_specs(kind, name, known.get(name)):
                    self.node.declare_parameter(field.name, field.default, descriptor(field))
                    specs[field.name] = field
        return specs

    def _declare_list(self, spec: ParamSpec) -> list[str]:
        """A string-array parameter; rclpy cannot infer the type of an empty default."""
        if spec.default:
            self.node.declare_parameter(spec.name, list(spec.default), descriptor(spec))
        else:
            untyped = descriptor(spec)
            untyped.type = ParameterType.PARAMETER_NOT_SET
            self.node.declare_parameter(spec.name, Parameter.Type.STRING_ARRAY, untyped)
        try:
            value = self.node.get_parameter(spec.name).value
        except ParameterUninitializedException:
            self.node.set_parameters([Parameter(spec.name, Parameter.Type.STRING_ARRAY, [])])
            value = []
        return [str(name) for name in value]

    def _subscribe_sources(self, config: FusionConfig, qos: Any) -> None:
        """Every named source not on the one-source topics (`scan_topic`, `depth_topic`,
        subscribed already), fed with its name."""
        sources = config.sources
        for lidar in (s for s in sources.lidars if s.topic != config.scan_topic):
            self.node.create_subscription(
                LaserScan, lidar.topic, self._source_callback('scan', lidar.name), qos, raw=True
            )
        for camera in (s for s in sources.cameras if s.depth_topic != config.depth_topic):
            self.node.create_subscription(
                Image,
                camera.depth_topic,
                self._source_callback('depth image', camera.name),
                qos,
                raw=True,
            )
            self.node.create_subscription(
                CameraInfo,
                camera.camera_info_topic,
                self._source_callback('camera info', camera.name),
                qos,
                raw=True,
            )
        for cloud in sources.clouds:
            self.node.create_subscription(
                PointCloud2, cloud.topic, self._source_callback('cloud', cloud.name), qos, raw=True
            )

    def _source_callback(self, kind: str, name: str) -> Any:
        live = self.live
        handlers = {
            'scan': live.on_scan,
            'depth image': live.on_depth,
            'cloud': live.on_cloud,
        }

        def on_message(raw: bytes) -> None:
            if kind == 'camera info':
                self._guard(
                    f'camera info ({name})',
                    lambda: live.on_camera_info(raw, time.monotonic(), source=name),
                )
                return
            handler = handlers[kind]
            self._publish(
                self._guard(f'{kind} ({name})', lambda: handler(raw, time.monotonic(), source=name))
            )
            self._arm_deadline()

        return on_message

    # ------------------------------------------------------------ TF

    def _subscribe_tf(self) -> str:
        try:
            from tf2_msgs.msg import TFMessage  # noqa: PLC0415 - not among the PyPI wheels
        except ImportError:
            return 'parameters (tf2_msgs is not installed: see tools/build_tf2_msgs.py)'
        self.node.create_subscription(
            TFMessage, '/tf_static', self._on_tf_static, TF_STATIC_QOS, raw=True
        )
        self.node.create_subscription(TFMessage, '/tf', self._on_tf, TF_QOS, raw=True)
        return '/tf_static and /tf, else parameters'

    def _subscribe_odometry(self, topic: str) -> str:
        try:
            from nav_msgs.msg import Odometry  # noqa: PLC0415 - the ros extra has it
        except ImportError:
            return f'TF only (nav_msgs is not installed, {topic} is not read)'
        self.node.create_subscription(Odometry, topic, self._on_odometry, ODOMETRY_QOS, raw=True)
        return f'{topic} and TF'

    def _on_odometry(self, raw: bytes) -> None:
        self._guard('odometry', lambda: self.live.on_odometry(raw))
        self._on_motion()

    def _on_motion(self) -> None:
        """With publish_rate, odometry reaching an output's stamp releases it."""
        if self.live.config.publish_rate > 0.0:
            self._on_tick()

    def _on_imu(self, raw: bytes) -> None:
        self._guard('imu', lambda: self.live.on_imu(raw))

    def _on_tf_static(self, raw: bytes) -> None:
        self.live.on_tf(raw, static=True)
        self.view.log('/tf_static', raw)

    def _on_tf(self, raw: bytes) -> None:
        self.live.on_tf(raw, static=False)
        self.view.log('/tf', raw)
        self._on_motion()

    # ------------------------------------------------------------ data

    def _on_scan(self, raw: bytes) -> None:
        self._publish(self._guard('scan', lambda: self.live.on_scan(raw, time.monotonic()), raw))
        self._arm_deadline()
        self.view.log(self.topics.scan_topic, raw)

    def _on_depth(self, raw: bytes) -> None:
        self._publish(self._guard('depth image', lambda: self.live.on_depth(raw, time.monotonic())))
        self._arm_deadline()
        self.view.log(self.topics.depth_topic, raw)

    def _on_camera_info(self, raw: bytes) -> None:
        self._guard('camera info', lambda: self.live.on_camera_info(raw, time.monotonic()))

    def _on_tick(self) -> None:
        self._disarm_deadline()
        self._publish(self._guard('tick', lambda: self.live.on_tick(time.monotonic())))
        self._arm_deadline()

    def _arm_deadline(self) -> None:
        """A timer at the oldest waiting scan's deadline (rclpy timers repeat: it is destroyed)."""
        due = self.live.next_deadline()
        if due is None:
            self._disarm_deadline()
            return
        if self.deadline_due is not None and self.deadline_due <= due:
            return
        self._disarm_deadline()
        self.deadline_due = due
        delay = max(due - time.monotonic(), 0.0) + DEADLINE_SLACK_S
        self.deadline_timer = self.node.create_timer(delay, self._on_tick)

    def _disarm_deadline(self) -> None:
        if self.deadline_timer is not None:
            self.node.destroy_timer(self.deadline_timer)
        self.deadline_timer = None
        self.deadline_due = None

    def _guard(self, kind: str, action: Any, lidar_raw: bytes | None = None) -> Any:
        """Run a callback; an unexpected error is counted and logged, never kills the node."""
        try:
            return action()
        # A robot's scan must keep flowing whatever went wrong: any error is caught here.
        except Exception:
            self.live.malformed[f'internal ({kind})'] = (
                self.live.malformed.get(f'internal ({kind})', 0) + 1
            )
            if self.live.malformed[f'internal ({kind})'] == 1:
                logger.exception('unexpected error handling a %s; the LiDAR passes through', kind)
            # The LiDAR's scan is always safe to publish (its error values as NaN).
            return [] if lidar_raw is None else self._passed_through(lidar_raw)

    def _passed_through(self, raw: bytes) -> list[Output]:
        try:
            return [_raw_output(self.live.passthrough(raw))]
        except Exception:  # noqa: BLE001 - undecodable: nothing is safe to publish
            return []

    def _publish(self, outputs: list[Output] | None) -> None:
        topics = self.topics
        for output in outputs or []:
            self.fused_pub.publish(output.fused)
            self.view.log(topics.fused_topic, output.fused)
            extras = (
                (self.depth_pub, topics.depth_scan_topic, output.depth_scan),
                (self.instant_pub, topics.instant_topic, output.instant),
                (self.memory_pub, topics.memory_scan_topic, output.memory_scan),
            )
            for publisher, topic, raw in extras:
                if publisher is not None and raw is not None:
                    publisher.publish(raw)
                    self.view.log(topic, raw)

    # ------------------------------------------------------------ parameters

    def _on_set_parameters(self, parameters: list[Any]) -> Any:
        changes = {p.name: p.value for p in parameters if p.name in self.specs}
        current = self.parameter_values()
        reason = check_change(current, changes)
        if reason is not None:
            self.rosout.warning(f'parameter change rejected: {reason}')
            return SetParametersResult(successful=False, reason=reason)
        merged = {**current, **changes}
        try:
            config = config_from_ros(merged)
            settings = settings_from_ros(merged)
            self.live.reconfigure(config)
        # A change the checks let through but the stream cannot take is refused, never
        # ends the node: the stream keeps its old configuration (`FusionStream.reconfigure`).
        except Exception as err:  # noqa: BLE001
            reason = f'cannot apply {changes}: {err}'
            self.rosout.warning(f'parameter change rejected: {reason}')
            return SetParametersResult(successful=False, reason=reason)
        self.live.pair_wait = settings.pair_wait
        self.live.lidar_timeout = settings.lidar_timeout
        self.rosout.info(f'parameters changed: {changes}')
        return SetParametersResult(successful=True, reason='')

    # ------------------------------------------------------------ diagnostics

    def _publish_diagnostics(self) -> None:
        now = time.monotonic()
        health = self.live.health(now)
        self.diagnostics_pub.publish(self.diagnostics_message(health, self.silent_inputs(now)))

    def silent_inputs(self, now: float) -> list[SilentInput]:
        """Inputs nothing has published for SILENT_INPUT_GRACE_S, each logged once (again when
        what could stand in for it changes). The graph is asked every GRAPH_PERIOD_S."""
        if now - self.graph_checked < GRAPH_PERIOD_S:
            return self.silent_due
        self.graph_checked = now
        self.silent_due = self._silent_inputs(now)
        return self.silent_due

    def _silent_inputs(self, now: float) -> list[SilentInput]:
        graph = self.node.get_topic_names_and_types()
        publishers = {name: self.node.count_publishers(name) for name, _ in graph}
        publishers.update({name: self.node.count_publishers(name) for name in self.inputs})
        found = silent_inputs(self.inputs, publishers, graph)
        silent = {item.topic for item in found}
        self.silent_since = {topic: self.silent_since.get(topic, now) for topic in silent}
        due = [
            item
            for item in found
            if now - max(self.silent_since[item.topic], self.started) >= SILENT_INPUT_GRACE_S
        ]
        for item in due:
            text = item.describe()
            if self.silent_reported.get(item.topic) != text:
                self.silent_reported[item.topic] = text
                self.rosout.warning(text)
        self.silent_reported = {
            topic: text for topic, text in self.silent_reported.items() if topic in silent
        }
        return due

    def diagnostics_message(self, health: Health, silent: Sequence[SilentInput] = ()) -> Any:
        level, message, values = health.level, health.message, dict(health.values)
        if silent:
            # The missing publisher explains the rest (no CameraInfo, LiDAR passed through).
            level = max(level, Level.WARN)
            message = '; '.join(item.describe() for item in silent) + f' ({message})'
            values.update({f'no publisher: {item.topic}': item.describe() for item in silent})
        status = DiagnosticStatus(
            level=bytes([int(level)]),
            name=f'{self.node.get_name()}: fusion',
            message=message,
            hardware_id=self.node.get_fully_qualified_name(),
            values=[KeyValue(key=key, value=value) for key, value in values.items()],
        )
        array = DiagnosticArray(status=[status])
        array.header.stamp = self.node.get_clock().now().to_msg()
        return array


def _raw_output(raw: bytes) -> Output:
    from scanfuse.ros.live import Output  # noqa: PLC0415

    return Output(raw, None, time.monotonic(), with_camera=False)


def _parse(argv: Sequence[str]) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog='scanfuse node',
        description='The scanfuse ROS 2 node. ROS arguments follow --ros-args.',
    )
    parser.add_argument('--params-file', help='ROS 2 parameter file (scanfuse: ros__parameters)')
    parser.add_argument(
        '--foxglove',
        nargs='?',
        type=int,
        const=DEFAULT_PORT,
        default=None,
        metavar='PORT',
        help=f'serve a Foxglove live view on PORT (default {DEFAULT_PORT}; 0: any free port)',
    )
    parser.add_argument(
        '--foxglove-host',
        default=DEFAULT_HOST,
        help=f'address the Foxglove server listens on (default {DEFAULT_HOST}: this machine only)',
    )
    return parser.parse_args(remove_ros_args(args=list(argv))[1:])


def _one_line(err: Exception) -> str:
    """rclpy's multi-line messages (a caret under a bad name, rcl's file:line) on one line."""
    lines = [line.strip() for line in str(err).splitlines()]
    text = ' '.join(line for line in lines if line and set(line) != {'^'})
    return text.split(', at /', 1)[0]  # rcl appends ", at /path/file.c:LINE" per frame


_OUT_OF_RANGE = re.compile(r'Parameter (\w+) out of range.*value: (-?[\d.eE+-]+)')


def _unit_hint(message: str) -> str:
    """An angle out of range was most likely given in degrees: its value in radians."""
    found = _OUT_OF_RANGE.search(message)
    if found is None:
        return ''
    field = FusionConfig.model_fields.get(found.group(1))
    if field is None or 'radians' not in (field.description or ''):
        return ''
    value = float(found.group(2))
    return f' (radians: {value:g} deg = {math.radians(value):.3f})'


def _start_error(err: Exception) -> int:
    if isinstance(err, ParameterException):
        # rclpy checks -p overrides against the descriptors' ranges and types at declaration.
        hint = 'fix the -p override or the parameter file' + _unit_hint(str(err))
    elif isinstance(err, NameValidationException):
        hint = 'fix the topic name in the -p override or the parameter file'
    elif isinstance(err, rclpy_implementation.RCLInvalidROSArgsError):
        hint = 'ROS arguments are: --ros-args -r from:=to -p name:=value --params-file FILE'
    else:
        hint = ''
    print(f'scanfuse node: {_one_line(err)}' + (f'; {hint}' if hint else ''), file=sys.stderr)
    return 1


# Start-up errors of rclpy that a user's arguments cause; they end the node with one line.
_START_ERRORS = (
    ScanfuseError,
    ParameterException,
    NameValidationException,
    rclpy_implementation.RCLInvalidROSArgsError,
)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the node until Ctrl-C or shutdown; 0 on a clean stop, 1 on a configuration error."""
    argv = list(sys.argv if argv is None else ['scanfuse', *argv])
    try:
        options = _parse(argv)
        defaults, settings = _load_defaults(options.params_file)
    except _START_ERRORS as err:
        return _start_error(err)
    try:
        rclpy.init(args=argv)
    except _START_ERRORS as err:
        return _start_error(err)
    try:
        try:
            fusion = ScanfuseNode(
                defaults,
                settings,
                foxglove_port=options.foxglove,
                foxglove_host=options.foxglove_host,
                overrides=override_names(argv, NODE_NAME),
            )
        except _START_ERRORS as err:
            return _start_error(err)
        handler = _RosLogHandler(fusion.rosout)
        library_logger = logging.getLogger('scanfuse')
        library_logger.addHandler(handler)
        library_logger.setLevel(logging.INFO)
        library_logger.propagate = False  # rclpy's logger already prints and sends to /rosout
        executor = SingleThreadedExecutor()
        executor.add_node(fusion.node)
        try:
            executor.spin()
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        finally:
            executor.shutdown()
            fusion.view.close()
            fusion.node.destroy_node()
    finally:
        if ok():
            rclpy.shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
