"""Peers of the live node for tests and benchmarks, each run as its own process over DDS.

    python -m tests.support.loopback play BAG [--garbage-at S]   replay a bag at real time
    python -m tests.support.loopback record OUT.mcap --topic T... --duration S [--ready FILE]
    python -m tests.support.loopback set-param NAME VALUE --out RESULT.json
    python -m tests.support.loopback get-params NAME... --out RESULT.json
    python -m tests.support.loopback flood --seconds S [--done FILE]   malformed messages
    python -m tests.support.loopback relay FROM TO      republish LaserScan bytes (baseline)
    python -m tests.support.loopback qos-probe --out RESULT.json   endpoints of incompatible QoS

Data topics are published best effort (like Gazebo and camera drivers), /tf_static
transient local. `record` writes what it received to an MCAP bag whose log times
are the monotonic receive times (comparable across processes on one machine).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

import rclpy
import rclpy.executors
import rclpy.utilities
from rclpy.qos import QoSProfile, qos_profile_sensor_data
from rosbags.highlevel import AnyReader
from rosbags.rosbag2 import StoragePlugin, Writer
from sensor_msgs.msg import CameraInfo, Image, LaserScan, PointCloud2

from scanfuse.ros.messages import (
    CAMERA_INFO,
    IMAGE,
    LASER_SCAN,
    ODOMETRY,
    POINT_CLOUD,
    TF_MESSAGE,
    depth_to_cdr,
    typestore,
)
from tests.support.malformed import garbage_messages

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence

DIAGNOSTICS = 'diagnostic_msgs/msg/DiagnosticArray'
DRAIN_TIMEOUT_S = 30.0
DISCOVERY_TIMEOUT_S = 20.0


def _ros_types() -> dict[str, Any]:
    from diagnostic_msgs.msg import DiagnosticArray

    types: dict[str, Any] = {
        LASER_SCAN: LaserScan,
        IMAGE: Image,
        CAMERA_INFO: CameraInfo,
        DIAGNOSTICS: DiagnosticArray,
        POINT_CLOUD: PointCloud2,
    }
    try:
        from tf2_msgs.msg import TFMessage
    except ImportError:
        pass
    else:
        types[TF_MESSAGE] = TFMessage
    try:
        from nav_msgs.msg import Odometry
    except ImportError:
        pass
    else:
        types[ODOMETRY] = Odometry
    return types


def _qos(topic: str) -> QoSProfile:
    if topic == '/tf_static':
        from scanfuse.ros.node import TF_STATIC_QOS

        return TF_STATIC_QOS
    return qos_profile_sensor_data


def _spin_until(node: Any, done: Callable[[], bool], timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while not done():
        if time.monotonic() > deadline:
            return False
        rclpy.spin_once(node, timeout_sec=0.05)
    return True


GARBAGE_ROUNDS = 5


def play(
    bag: Path,
    *,
    garbage_at: float | None = None,
    wait_for: Sequence[str] = (),
    started: Path | None = None,
) -> int:
    """Publish every message of `bag` at its recorded pace; 0, or 2 when nobody subscribed."""
    types = _ros_types()
    node = rclpy.create_node('scanfuse_player')
    with AnyReader([bag]) as reader:
        publishers = {}
        for connection in reader.connections:
            if connection.msgtype in types and connection.topic not in publishers:
                publishers[connection.topic] = node.create_publisher(
                    types[connection.msgtype], connection.topic, _qos(connection.topic)
                )
        waited = [publishers[topic] for topic in wait_for if topic in publishers]
        if not _spin_until(
            node, lambda: all(p.get_subscription_count() > 0 for p in waited), DISCOVERY_TIMEOUT_S
        ):
            print('play: the node did not subscribe in time', file=sys.stderr)
            return 2
        messages = [
            (connection.topic, log_time, raw)
            for connection, log_time, raw in reader.messages()
            if connection.topic in publishers
        ]
    if started is not None:
        started.write_text('started', encoding='utf-8')
    start_wall = time.monotonic()
    start_log = messages[0][1] if messages else 0
    garbage = garbage_messages() if garbage_at is not None else []
    # Best effort with a shallow reader queue may drop any one sample under load, so the
    # malformed images go out with several messages in a row, not once.
    garbage_rounds = GARBAGE_ROUNDS
    depth_topic = next((t for t, _, _ in messages if t.endswith('image_raw')), None)
    for topic, log_time, raw in messages:
        due = start_wall + (log_time - start_log) / 1e9
        while (delay := due - time.monotonic()) > 0:
            time.sleep(min(delay, 0.01))
        due_garbage = garbage_at is not None and time.monotonic() - start_wall >= garbage_at
        if garbage and depth_topic is not None and due_garbage and garbage_rounds > 0:
            for _, bad in garbage:
                publishers[depth_topic].publish(bad)
            garbage_rounds -= 1
        publishers[topic].publish(bytes(raw))
    # Let best-effort samples leave before the participant goes away.
    time.sleep(0.2)
    node.destroy_node()
    return 0


def flood_messages(seed: int = 0, *, sources: bool = False) -> dict[str, list[bytes]]:
    """Malformed messages per topic of the scene, the kinds drivers and attackers send:
    random bytes, truncated CDR, and well-formed CDR with values that make no sense. With
    `sources`, also on the rear LiDAR's topic and /odom (issue 26)."""
    import math

    import numpy as np

    from scanfuse.ros.messages import camera_to_cdr, scan_to_cdr
    from scanfuse.scan import Scan
    from tests.support.synthetic import Scene

    rng = np.random.default_rng(seed)
    store = typestore()
    scene = Scene()
    scan = Scan(
        angle_min=-1.0,
        angle_max=1.0,
        angle_increment=0.01,
        range_min=0.05,
        range_max=10.0,
        ranges=np.ones(201, dtype=np.float32),
        frame_id='laser',
    )
    good_scan = scan_to_cdr(scan, store)
    nan_grid: Any = store.deserialize_cdr(good_scan, LASER_SCAN)
    nan_grid.angle_min = math.nan
    tiny_increment: Any = store.deserialize_cdr(good_scan, LASER_SCAN)
    tiny_increment.angle_increment = 1e-9
    good_info = camera_to_cdr(scene.camera, stamp_ns=1, store=store)
    nan_info: Any = store.deserialize_cdr(good_info, CAMERA_INFO)
    nan_info.d = np.array([math.nan, 0.0, 0.0, 0.0, 0.0])
    huge: Any = store.deserialize_cdr(
        depth_to_cdr(np.zeros((4, 4), dtype=np.uint16), frame_id='cam', stamp_ns=1, store=store),
        IMAGE,
    )
    huge.width = huge.height = 100_000  # claims 20 GB of pixels, carries 32 bytes

    def noise() -> bytes:
        return rng.integers(0, 256, int(rng.integers(0, 400)), dtype=np.uint8).tobytes()

    messages = {
        '/scan': [
            noise(),
            good_scan[: len(good_scan) // 2],
            bytes(store.serialize_cdr(nan_grid, LASER_SCAN)),
            bytes(store.serialize_cdr(tiny_increment, LASER_SCAN)),
        ],
        '/camera/depth/image_raw': [
            noise(),
            *(bad for _, bad in garbage_messages()),
            bytes(store.serialize_cdr(huge, IMAGE)),
        ],
        '/camera/depth/camera_info': [
            noise(),
            good_info[: len(good_info) // 3],
            bytes(store.serialize_cdr(nan_info, CAMERA_INFO)),
        ],
    }
    if sources:
        messages.update(_source_flood(store, good_scan, noise))
    return messages


def _source_flood(
    store: Any, good_scan: bytes, noise: Callable[[], bytes]
) -> dict[str, list[bytes]]:
    """Issue 26's scans on the rear LiDAR's topic (increments that would size gigabytes,
    angles and times that break a turn's arithmetic, a Hokuyo's zeros) and bad odometry."""
    import math

    import numpy as np

    from scanfuse.motion import PlanarPose
    from scanfuse.ros.messages import OdometrySample, odometry_to_cdr
    from tests.support.synthetic import REAR_TOPIC

    odd = []
    for field, value in (
        ('angle_increment', 1e-7),
        ('angle_increment', 1e-9),
        ('angle_min', -1e12),
        ('time_increment', math.nan),
        ('angle_increment', 13.0),
    ):
        message: Any = store.deserialize_cdr(good_scan, LASER_SCAN)
        setattr(message, field, value)
        message.header.frame_id = 'rear_laser'
        odd.append(bytes(store.serialize_cdr(message, LASER_SCAN)))
    zeros: Any = store.deserialize_cdr(good_scan, LASER_SCAN)
    zeros.range_min = 0.0
    zeros.ranges = np.zeros(len(zeros.ranges), dtype=np.float32)
    zeros.header.frame_id = 'rear_laser'
    odd.append(bytes(store.serialize_cdr(zeros, LASER_SCAN)))
    sample = OdometrySample(1, 'odom', 'base_link', PlanarPose(0.0, 0.0, 0.0))
    odometry = odometry_to_cdr(sample, store)
    nan_pose: Any = store.deserialize_cdr(odometry, ODOMETRY)
    nan_pose.pose.pose.orientation.w = math.nan
    return {
        REAR_TOPIC: [noise(), *odd],
        '/odom': [
            noise(),
            odometry[: len(odometry) // 2],
            bytes(store.serialize_cdr(nan_pose, ODOMETRY)),
        ],
    }


def flood(seconds: float, *, done: Path | None = None, sources: bool = False) -> int:
    """Publish `flood_messages` round after round for `seconds` (0 when someone listened)."""
    from tests.support.synthetic import REAR_TOPIC

    types = _ros_types()
    kinds = {'/scan': LASER_SCAN, '/camera/depth/image_raw': IMAGE}
    kinds['/camera/depth/camera_info'] = CAMERA_INFO
    if sources:
        kinds.update({REAR_TOPIC: LASER_SCAN, '/odom': ODOMETRY})
    node = rclpy.create_node('scanfuse_flooder')
    publishers = {
        topic: node.create_publisher(types[kind], topic, qos_profile_sensor_data)
        for topic, kind in kinds.items()
    }
    if not _spin_until(
        node,
        lambda: all(p.get_subscription_count() > 0 for p in publishers.values()),
        DISCOVERY_TIMEOUT_S,
    ):
        print('flood: the node did not subscribe in time', file=sys.stderr)
        return 2
    bad = flood_messages(sources=sources)
    sent = 0
    end = time.monotonic() + seconds
    while time.monotonic() < end:
        for topic, messages in bad.items():
            for raw in messages:
                publishers[topic].publish(raw)
                sent += 1
        time.sleep(0.001)  # pacing, a few thousand messages a second
    print(f'flood: {sent} malformed messages', file=sys.stderr)
    node.destroy_node()
    if done is not None:
        done.write_text(str(sent), encoding='utf-8')
    return 0


def relay(source: str, target: str) -> int:
    """A do-nothing node: every LaserScan on `source` republished as is on `target`, with
    the node's QoS (sensor data in, reliable out), to measure what DDS and rclpy cost."""
    from scanfuse.ros.node import OUTPUT_QOS

    node = rclpy.create_node('scanfuse_relay')
    publisher = node.create_publisher(LaserScan, target, OUTPUT_QOS)
    node.create_subscription(
        LaserScan, source, publisher.publish, qos_profile_sensor_data, raw=True
    )
    with contextlib.suppress(KeyboardInterrupt, rclpy.executors.ExternalShutdownException):
        rclpy.spin(node)
    return 0


def qos_probe(out: Path, timeout: float = DISCOVERY_TIMEOUT_S) -> int:
    """Endpoints whose QoS the node's cannot match in one policy each: a best-effort
    transient-local /tf_static publisher (the node asks for reliable, transient local) and a
    reliable transient-local /scan_fused subscription (the node offers reliable, volatile).
    Waits for this side's own incompatible-QoS event on /scan_fused and writes the policy it
    named to `out`; 0, or 2 on timeout."""
    from rclpy.event_handler import SubscriptionEventCallbacks
    from rclpy.qos import DurabilityPolicy, ReliabilityPolicy, qos_policy_name_from_kind
    from tf2_msgs.msg import TFMessage

    from scanfuse.ros.node import OUTPUT_QOS

    node = rclpy.create_node('scanfuse_qos_probe')
    best_effort = QoSProfile(
        depth=1,
        reliability=ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )
    node.create_publisher(TFMessage, '/tf_static', best_effort)
    policies: list[str] = []
    late_joiner = QoSProfile(
        depth=OUTPUT_QOS.depth,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )
    node.create_subscription(
        LaserScan,
        '/scan_fused',
        lambda _raw: None,
        late_joiner,
        raw=True,
        event_callbacks=SubscriptionEventCallbacks(
            incompatible_qos=lambda event: policies.append(
                qos_policy_name_from_kind(event.last_policy_kind)
            )
        ),
    )
    if not _spin_until(node, lambda: bool(policies), timeout):
        print('qos-probe: no incompatible-QoS event on /scan_fused', file=sys.stderr)
        return 2
    out.write_text(json.dumps({'scan_fused_policy': policies[0]}), encoding='utf-8')
    # Stay discoverable while the node reports the /tf_static publisher.
    _spin_until(node, lambda: False, timeout)
    node.destroy_node()
    return 0


def _diagnostic_level(raw: bytes, store: Any) -> int:
    statuses = store.deserialize_cdr(raw, DIAGNOSTICS).status
    return max((int(status.level) for status in statuses), default=0)


def record(
    out: Path,
    topics: Sequence[str],
    duration: float,
    *,
    ready: Path | None = None,
    stop: Path | None = None,
    expect_publisher: bool = False,
    drain_until_level: int | None = None,
) -> int:
    """Write what arrives on `topics` into an MCAP bag at `out`.

    Records for at most `duration` seconds, or until the file `stop` exists; with
    `drain_until_level`, after `stop` appears it goes on until a /diagnostics status of at
    least that level arrives (at most DRAIN_TIMEOUT_S), so a test waits on the node's report
    instead of guessing how long the node's timers take.
    """
    types = _ros_types()
    node = rclpy.create_node('scanfuse_recorder')
    store = typestore()
    kinds = {topic: (DIAGNOSTICS if topic == '/diagnostics' else LASER_SCAN) for topic in topics}
    received: list[tuple[str, int, bytes]] = []

    def callback(topic: str) -> Callable[[bytes], None]:
        return lambda raw: received.append((topic, time.monotonic_ns(), bytes(raw)))

    for topic, msgtype in kinds.items():
        node.create_subscription(types[msgtype], topic, callback(topic), 10, raw=True)
    if expect_publisher:
        _spin_until(
            node, lambda: all(node.count_publishers(t) > 0 for t in topics), DISCOVERY_TIMEOUT_S
        )
    if ready is not None:
        ready.write_text('ready', encoding='utf-8')
    deadline = time.monotonic() + duration
    while time.monotonic() < deadline and not (stop is not None and stop.exists()):
        rclpy.spin_once(node, timeout_sec=0.05)
    if drain_until_level is not None:
        stopped_at = len(received)

        def reported() -> bool:
            return any(
                topic == '/diagnostics' and _diagnostic_level(raw, store) >= drain_until_level
                for topic, _, raw in received[stopped_at:]
            )

        _spin_until(node, reported, DRAIN_TIMEOUT_S)
    node.destroy_node()
    with Writer(out, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
        connections = {
            topic: writer.add_connection(topic, msgtype, typestore=store)
            for topic, msgtype in kinds.items()
        }
        for topic, stamp, raw in received:
            writer.write(connections[topic], stamp, raw)
    return 0


def set_param(
    name: str,
    value: str,
    out: Path,
    *,
    go: Path | None = None,
    after: float = 0.0,
    node_name: str = 'scanfuse',
) -> int:
    """`ros2 param set` through the node's set_parameters service; the result as JSON.

    With `go`, the request is sent `after` seconds after that file appears (the
    service is found before, so the moment of the change is known to the caller).
    """
    from rcl_interfaces.srv import SetParameters
    from rclpy.parameter import Parameter

    node = rclpy.create_node('scanfuse_param_setter')
    client = node.create_client(SetParameters, f'/{node_name}/set_parameters')
    if not client.wait_for_service(timeout_sec=DISCOVERY_TIMEOUT_S):
        print('set-param: no set_parameters service', file=sys.stderr)
        return 2
    while go is not None and not go.exists():
        time.sleep(0.01)
    time.sleep(after)
    request = SetParameters.Request()
    request.parameters = [Parameter(name, value=_parse_value(value)).to_parameter_msg()]
    sent = time.monotonic()
    future = client.call_async(request)
    rclpy.spin_until_future_complete(node, future, timeout_sec=DISCOVERY_TIMEOUT_S)
    done = time.monotonic()
    result = future.result()
    answer = result.results[0] if result is not None else None
    out.write_text(
        json.dumps(
            {
                'successful': bool(answer.successful) if answer else False,
                'reason': str(answer.reason) if answer else 'no answer',
                'sent': sent,
                'done': done,
            }
        ),
        encoding='utf-8',
    )
    node.destroy_node()
    return 0


def get_params(names: Sequence[str], out: Path, *, node_name: str = 'scanfuse') -> int:
    """`ros2 param get` through the node's get_parameters service; {name: value} as JSON."""
    from rcl_interfaces.srv import GetParameters
    from rclpy.parameter import parameter_value_to_python

    node = rclpy.create_node('scanfuse_param_getter')
    client = node.create_client(GetParameters, f'/{node_name}/get_parameters')
    if not client.wait_for_service(timeout_sec=DISCOVERY_TIMEOUT_S * 3):
        print('get-params: no get_parameters service', file=sys.stderr)
        return 2
    request = GetParameters.Request()
    request.names = list(names)
    future = client.call_async(request)
    rclpy.spin_until_future_complete(node, future, timeout_sec=DISCOVERY_TIMEOUT_S)
    result = future.result()
    if result is None:
        print('get-params: no answer', file=sys.stderr)
        return 2
    values = {
        name: parameter_value_to_python(value)
        for name, value in zip(names, result.values, strict=True)
    }
    out.write_text(json.dumps(values), encoding='utf-8')
    node.destroy_node()
    return 0


def _parse_value(text: str) -> Any:
    """A parameter value from text as `ros2 param set` reads it (YAML scalars)."""
    import yaml

    return yaml.safe_load(text)


def main(argv: Sequence[str] | None = None) -> int:  # noqa: PLR0911 - one return per command
    parser = argparse.ArgumentParser(prog='python -m tests.support.loopback')
    commands = parser.add_subparsers(dest='command', required=True)
    play_cmd = commands.add_parser('play')
    play_cmd.add_argument('bag', type=Path)
    play_cmd.add_argument('--garbage-at', type=float, default=None)
    play_cmd.add_argument('--wait-for', action='append', default=[])
    play_cmd.add_argument('--started', type=Path, default=None)
    record_cmd = commands.add_parser('record')
    record_cmd.add_argument('out', type=Path)
    record_cmd.add_argument('--topic', action='append', required=True)
    record_cmd.add_argument('--duration', type=float, required=True)
    record_cmd.add_argument('--ready', type=Path, default=None)
    record_cmd.add_argument('--stop', type=Path, default=None)
    record_cmd.add_argument('--expect-publisher', action='store_true')
    record_cmd.add_argument('--drain-until-level', type=int, default=None)
    flood_cmd = commands.add_parser('flood')
    flood_cmd.add_argument('--seconds', type=float, required=True)
    flood_cmd.add_argument('--done', type=Path, default=None)
    flood_cmd.add_argument('--sources', action='store_true', help='also the rear LiDAR, /odom')
    relay_cmd = commands.add_parser('relay')
    relay_cmd.add_argument('source')
    relay_cmd.add_argument('target')
    probe_cmd = commands.add_parser('qos-probe')
    probe_cmd.add_argument('--out', type=Path, required=True)
    get_cmd = commands.add_parser('get-params')
    get_cmd.add_argument('names', nargs='+')
    get_cmd.add_argument('--out', type=Path, required=True)
    param_cmd = commands.add_parser('set-param')
    param_cmd.add_argument('name')
    param_cmd.add_argument('value')
    param_cmd.add_argument('--out', type=Path, required=True)
    param_cmd.add_argument('--go', type=Path, default=None)
    param_cmd.add_argument('--after', type=float, default=0.0)
    args = parser.parse_args(argv)
    rclpy.init()
    try:
        if args.command == 'play':
            return play(
                args.bag, garbage_at=args.garbage_at, wait_for=args.wait_for, started=args.started
            )
        if args.command == 'relay':
            return relay(args.source, args.target)
        if args.command == 'qos-probe':
            return qos_probe(args.out)
        if args.command == 'flood':
            return flood(args.seconds, done=args.done, sources=args.sources)
        if args.command == 'record':
            return record(
                args.out,
                args.topic,
                args.duration,
                ready=args.ready,
                stop=args.stop,
                expect_publisher=args.expect_publisher,
                drain_until_level=args.drain_until_level,
            )
        if args.command == 'get-params':
            return get_params(args.names, args.out)
        return set_param(args.name, args.value, args.out, go=args.go, after=args.after)
    finally:
        if rclpy.utilities.ok():
            rclpy.shutdown()


if __name__ == '__main__':
    sys.exit(main())
