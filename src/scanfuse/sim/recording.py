"""Recording a simulated run as a ROS 2 bag (rosbags Writer, MCAP storage, version 8).

Topics (frames as REP-105; stamps are simulated time from EPOCH_NS). Header stamps are
the sensors' (a scan's first beam, an image's exposure); the log time of a scan or an
image is when the simulated driver delivered it (the end of the sweep; the exposure plus
the camera's latency), as `ros2 bag record` would log it; odometry, TF and the true pose
are logged at their stamps, 50 Hz:

| topic | type | frame |
| --- | --- | --- |
| /scan | sensor_msgs/LaserScan | laser |
| /scan_truth | sensor_msgs/LaserScan (ground-truth obstacle scan, same slots) | laser |
| /camera/depth/image_raw | sensor_msgs/Image, 16UC1 mm | camera_depth_optical_frame |
| /camera/depth/camera_info | sensor_msgs/CameraInfo | camera_depth_optical_frame |
| /tf | tf2_msgs/TFMessage: odom -> base_link (wheel odometry) | |
| /tf_static | tf2_msgs/TFMessage, transient local (see `static_transforms`) | |
| /odom | nav_msgs/Odometry | odom -> base_link |
| /ground_truth/pose | geometry_msgs/PoseStamped | world |
| /collisions | std_msgs/String holding JSON (see `collision_json`) | |
| /imu | sensor_msgs/Imu, 100 Hz (`SimConfig.imu_rate`; 0: no topic) | base_link |

/tf_static holds base_link -> laser and base_link -> camera_link ->
camera_depth_optical_frame (REP-103 optical rotation).

A robot with several sensors (the `amr`) has one LaserScan topic (and its `_truth` twin) per
LiDAR and one Image + CameraInfo pair per camera, as examples/scanfuse_multi.yaml names
them (`/front/scan`, `/rear/scan`, `/front_camera/depth/image_rect_raw`, ...; see
`RobotSpec.lidars()` and `cameras()`), each in its own frame, all in /tf_static.

/collisions is a `std_msgs/String` because every ROS 2 store has it and any tool
prints it; each message lists the robot-obstacle contacts of one instant.

Messages are built and serialized with the rosbags typestore of ROS 2 Humble
through `scanfuse.ros.messages`; nothing is written as hand-made CDR.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError

from scanfuse.errors import BagError
from scanfuse.frames import StampedTransform
from scanfuse.ros.messages import (
    CAMERA_INFO,
    IMAGE,
    LASER_SCAN,
    POINT_CLOUD,
    TF_MESSAGE,
    camera_to_cdr,
    cloud_to_cdr,
    depth_to_cdr,
    scan_to_cdr,
    serialize,
    tf_message_to_cdr,
    typestore,
)
from scanfuse.ros.staging import Staging, output_error
from scanfuse.sim.errors import SimError
from scanfuse.sim.simulation import (
    EPOCH_NS,
    NANOSECONDS,
    CloudFrame,
    Contact,
    Controller,
    DepthFrame,
    ImuNoise,
    ImuSample,
    LidarFrame,
    SimConfig,
    Simulation,
    StateSample,
)

if TYPE_CHECKING:
    from rosbags.interfaces import Connection

    from scanfuse.progress import Progress
    from scanfuse.sim.robot import RobotSpec

BASE_FRAME = 'base_link'
ODOM_FRAME = 'odom'
WORLD_FRAME = 'world'
ODOMETRY = 'nav_msgs/msg/Odometry'
POSE_STAMPED = 'geometry_msgs/msg/PoseStamped'
STRING = 'std_msgs/msg/String'
IMU = 'sensor_msgs/msg/Imu'
IMU_TOPIC = '/imu'
COMMON_TOPICS = {
    '/tf': TF_MESSAGE,
    '/tf_static': TF_MESSAGE,
    '/odom': ODOMETRY,
    '/ground_truth/pose': POSE_STAMPED,
    '/collisions': STRING,
}


def robot_topics(robot: RobotSpec, *, imu: bool = True) -> dict[str, str]:
    """Every topic a recording of `robot` holds, with its message type (`imu`: with /imu)."""
    topics: dict[str, str] = {}
    for lidar in robot.lidars():
        topics[lidar.topic] = LASER_SCAN
        topics[truth_topic(lidar.topic)] = LASER_SCAN
    for camera in robot.cameras():
        topics[camera.depth_topic] = IMAGE
        topics[camera.info_topic] = CAMERA_INFO
    if robot.cloud is not None:
        topics[robot.cloud.topic] = POINT_CLOUD
    topics.update(COMMON_TOPICS)
    if imu:
        topics[IMU_TOPIC] = IMU
    return topics


def truth_topic(scan_topic: str) -> str:
    """The ground-truth scan's topic beside a LiDAR's: /scan -> /scan_truth."""
    return f'{scan_topic}_truth'


_FOREVER = QosTime(2147483647, 4294967295)
LATCHED = Qos(
    QosHistory.KEEP_LAST,
    1,
    QosReliability.RELIABLE,
    QosDurability.TRANSIENT_LOCAL,
    _FOREVER,
    _FOREVER,
    QosLiveliness.AUTOMATIC,
    _FOREVER,
    avoid_ros_namespace_conventions=False,
)
# REP-103: the optical frame (z forward, x right, y down) in camera_link (x forward, z up).
OPTICAL_ROTATION = (-0.5, 0.5, -0.5, 0.5)


def _yawed_mount(
    frame: str, position: tuple[float, float, float], yaw: float, stamp_ns: int
) -> StampedTransform:
    """base_link -> a sensor mounted level, turned `yaw` about z (a LiDAR, a 3D LiDAR)."""
    half_yaw = yaw / 2
    return StampedTransform(
        BASE_FRAME, frame, position, (0.0, 0.0, math.sin(half_yaw), math.cos(half_yaw)), stamp_ns
    )


def static_transforms(robot: RobotSpec, stamp_ns: int = EPOCH_NS) -> list[StampedTransform]:
    """base_link -> each laser, base_link -> each camera_link, camera_link -> optical frame."""
    mounts = (*robot.lidars(), *((robot.cloud,) if robot.cloud is not None else ()))
    transforms = [
        _yawed_mount(mount.frame, (mount.x, mount.y, mount.z), mount.yaw, stamp_ns)
        for mount in mounts
    ]
    for camera in robot.cameras():
        transforms.append(
            StampedTransform(
                BASE_FRAME,
                camera.link,
                (camera.x, camera.y, camera.z),
                _yaw_pitch_quaternion(camera.yaw, camera.pitch),
                stamp_ns,
            )
        )
        transforms.append(
            StampedTransform(camera.link, camera.frame, (0.0, 0.0, 0.0), OPTICAL_ROTATION, stamp_ns)
        )
    return transforms


def _yaw_pitch_quaternion(yaw: float, pitch: float) -> tuple[float, float, float, float]:
    """x, y, z, w of the rotation yaw about z after pitch about y (R = Rz(yaw) Ry(pitch))."""
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    return (-sy * sp, cy * sp, sy * cp, cy * cp)


def collision_json(stamp_ns: int, contacts: list[Contact]) -> str:
    """{"stamp_ns", "time", "contacts": [{"position", "robot_geom", "obstacle_geom", "kind"}]}."""
    return json.dumps(
        {
            'stamp_ns': stamp_ns,
            'time': (stamp_ns - EPOCH_NS) / NANOSECONDS,
            'contacts': [
                {
                    'position': list(contact.position),
                    'robot_geom': contact.robot_geom,
                    'obstacle_geom': contact.obstacle_geom,
                    'kind': contact.kind,
                }
                for contact in contacts
            ],
        }
    )


def _time(stamp_ns: int) -> Any:
    sec, nanosec = divmod(stamp_ns, NANOSECONDS)
    return typestore().types['builtin_interfaces/msg/Time'](sec=sec, nanosec=nanosec)


def _header(stamp_ns: int, frame_id: str) -> Any:
    return typestore().types['std_msgs/msg/Header'](stamp=_time(stamp_ns), frame_id=frame_id)


def _pose(
    position: tuple[float, float, float], orientation: tuple[float, float, float, float]
) -> Any:
    types = typestore().types
    return types['geometry_msgs/msg/Pose'](
        position=types['geometry_msgs/msg/Point'](*position),
        orientation=types['geometry_msgs/msg/Quaternion'](*orientation),
    )


def odometry_cdr(sample: StateSample) -> bytes:
    import numpy as np  # noqa: PLC0415

    types = typestore().types
    odom = sample.odometry
    orientation = (0.0, 0.0, math.sin(odom.yaw / 2), math.cos(odom.yaw / 2))
    vector = types['geometry_msgs/msg/Vector3']
    message = types[ODOMETRY](
        header=_header(sample.stamp_ns, ODOM_FRAME),
        child_frame_id=BASE_FRAME,
        pose=types['geometry_msgs/msg/PoseWithCovariance'](
            pose=_pose((odom.x, odom.y, 0.0), orientation), covariance=np.zeros(36)
        ),
        twist=types['geometry_msgs/msg/TwistWithCovariance'](
            twist=types['geometry_msgs/msg/Twist'](
                linear=vector(sample.v, 0.0, 0.0), angular=vector(0.0, 0.0, sample.omega)
            ),
            covariance=np.zeros(36),
        ),
    )
    return serialize(message, ODOMETRY)


def ground_truth_cdr(sample: StateSample) -> bytes:
    message = typestore().types[POSE_STAMPED](
        header=_header(sample.stamp_ns, WORLD_FRAME),
        pose=_pose(sample.position, sample.orientation),
    )
    return serialize(message, POSE_STAMPED)


def imu_cdr(sample: ImuSample, noise: ImuNoise) -> bytes:
    """A sensor_msgs/Imu in base_link; the covariances are the noise's variances."""
    import numpy as np  # noqa: PLC0415

    types = typestore().types
    vector = types['geometry_msgs/msg/Vector3']

    def diagonal(sigma: float) -> Any:
        return np.diag([sigma * sigma] * 3).ravel()

    message = types[IMU](
        header=_header(sample.stamp_ns, BASE_FRAME),
        orientation=types['geometry_msgs/msg/Quaternion'](*sample.orientation),
        orientation_covariance=diagonal(noise.orientation),
        angular_velocity=vector(*sample.angular_velocity),
        angular_velocity_covariance=diagonal(noise.angular_velocity),
        linear_acceleration=vector(*sample.linear_acceleration),
        linear_acceleration_covariance=diagonal(noise.linear_acceleration),
    )
    return serialize(message, IMU)


def odom_transform(sample: StateSample) -> StampedTransform:
    odom = sample.odometry
    return StampedTransform(
        ODOM_FRAME,
        BASE_FRAME,
        (odom.x, odom.y, 0.0),
        (0.0, 0.0, math.sin(odom.yaw / 2), math.cos(odom.yaw / 2)),
        sample.stamp_ns,
    )


@dataclass
class BagSink:
    """Writes every frame of a simulation into an open rosbags Writer."""

    writer: Writer
    connections: dict[str, Connection] = field(default_factory=dict)
    counts: dict[str, int] = field(default_factory=dict)
    contacts: list[Contact] = field(default_factory=list)
    first_lidar: LidarFrame | None = None
    states: list[StateSample] = field(default_factory=list)
    scan_topics: dict[str, str] = field(default_factory=dict)  # LiDAR source -> topic
    camera_topics: dict[str, tuple[str, str]] = field(default_factory=dict)  # source -> topics
    camera_frames: dict[str, str] = field(default_factory=dict)  # source -> optical frame
    cloud_topic: str | None = None
    imu_noise: ImuNoise | None = None  # None: no IMU topic

    def open(self, robot: RobotSpec) -> None:
        store = typestore()
        self.scan_topics = {lidar.source: lidar.topic for lidar in robot.lidars()}
        self.camera_topics = {
            camera.source: (camera.depth_topic, camera.info_topic) for camera in robot.cameras()
        }
        self.camera_frames = {camera.source: camera.frame for camera in robot.cameras()}
        self.cloud_topic = robot.cloud.topic if robot.cloud is not None else None
        for topic, msgtype in robot_topics(robot, imu=self.imu_noise is not None).items():
            qos = [LATCHED] if topic == '/tf_static' else []
            self.connections[topic] = self.writer.add_connection(
                topic, msgtype, typestore=store, offered_qos_profiles=qos
            )
        self._write('/tf_static', EPOCH_NS, tf_message_to_cdr(static_transforms(robot)))

    def _write(self, topic: str, stamp_ns: int, data: bytes) -> None:
        self.writer.write(self.connections[topic], stamp_ns, data)
        self.counts[topic] = self.counts.get(topic, 0) + 1

    def on_lidar(self, frame: LidarFrame) -> None:
        if self.first_lidar is None and frame.source == next(iter(self.scan_topics)):
            self.first_lidar = frame
        topic = self.scan_topics[frame.source]
        self._write(topic, frame.arrival_ns, scan_to_cdr(frame.scan))
        self._write(truth_topic(topic), frame.arrival_ns, scan_to_cdr(frame.truth))

    def on_depth(self, frame: DepthFrame) -> None:
        depth_topic, info_topic = self.camera_topics[frame.source]
        optical = self.camera_frames[frame.source]
        image = depth_to_cdr(frame.depth, frame_id=optical, stamp_ns=frame.stamp_ns)
        self._write(depth_topic, frame.arrival_ns, image)
        info = camera_to_cdr(frame.camera, stamp_ns=frame.stamp_ns)
        self._write(info_topic, frame.arrival_ns, info)

    def on_cloud(self, frame: CloudFrame) -> None:
        assert self.cloud_topic is not None  # only a robot with a 3D LiDAR makes clouds
        cloud = cloud_to_cdr(frame.points, frame_id=frame.frame_id, stamp_ns=frame.stamp_ns)
        self._write(self.cloud_topic, frame.arrival_ns, cloud)

    def on_state(self, sample: StateSample) -> None:
        self.states.append(sample)
        self._write('/tf', sample.stamp_ns, tf_message_to_cdr([odom_transform(sample)]))
        self._write('/odom', sample.stamp_ns, odometry_cdr(sample))
        self._write('/ground_truth/pose', sample.stamp_ns, ground_truth_cdr(sample))

    def on_imu(self, sample: ImuSample) -> None:
        if self.imu_noise is not None:
            self._write(IMU_TOPIC, sample.stamp_ns, imu_cdr(sample, self.imu_noise))

    def on_contacts(self, stamp_ns: int, contacts: list[Contact]) -> None:
        self.contacts.extend(contacts)
        message = typestore().types[STRING](data=collision_json(stamp_ns, contacts))
        self._write('/collisions', stamp_ns, serialize(message, STRING))


@dataclass(frozen=True)
class RecordSummary:
    """What a recording produced and how fast."""

    path: Path
    sim_time: float
    wall_time: float
    counts: dict[str, int]
    contacts: int
    final_odometry_error: float  # metres between odometry and true displacement at the end
    fell_at: float | None = None  # seconds into the drive when the base fell (a drop), or None

    @property
    def real_time_factor(self) -> float:
        """Simulated seconds per wall-clock second (> 1: faster than real time)."""
        return self.sim_time / self.wall_time if self.wall_time > 0 else math.inf


def record(
    config: SimConfig,
    controller: Controller,
    duration: float,
    out: Path,
    *,
    snapshot: Path | None = None,
    progress: Progress | None = None,
) -> RecordSummary:
    """Simulate for `duration` seconds and write a ROS 2 bag to `out`.

    `out` ending in `.mcap` becomes one MCAP file (readable by rosbags and by the
    `mcap` tools); any other name becomes a rosbag2 directory with metadata.yaml.
    The bag is written in a staging folder beside `out` (`scanfuse.ros.staging`) and
    renamed into place when complete, so an interrupted run leaves no half bag at `out`.
    """
    out = Path(out)
    if out.exists() or out.is_symlink():
        msg = f'{out} exists already; remove it or choose another --out'
        raise SimError(msg)
    single_file = out.suffix == '.mcap'
    simulation = Simulation(config)
    start_pose = simulation.true_pose()
    start_ns = simulation.stamp_ns
    started = time.perf_counter()
    try:
        out.parent.mkdir(parents=True, exist_ok=True)
        with Staging(out) as staging:
            with Writer(staging.output, version=8, storage_plugin=StoragePlugin.MCAP) as writer:
                imu = config.imu_noise if config.imu_rate > 0.0 else None
                sink = BagSink(writer, imu_noise=imu)
                sink.open(simulation.robot)
                simulation.run(duration, controller, sink, progress)
            written = staging.output / f'{out.name}.mcap' if single_file else staging.output
            if out.exists() or out.is_symlink():
                msg = f'{out} appeared while recording; not overwriting it'
                raise SimError(msg)
            written.rename(out)
    except WriterError as err:
        msg = f'cannot write the bag {out}: {err}'
        raise SimError(msg) from err
    except OSError as err:
        raise SimError(*output_error(out, err).args) from err
    except BagError as err:  # the staging folder could not be made
        raise SimError(*err.args) from err
    finally:
        simulation.close()
    wall_time = time.perf_counter() - started
    if snapshot is not None and sink.first_lidar is not None:
        from scanfuse.sim.snapshot import save_snapshot  # noqa: PLC0415

        save_snapshot(
            simulation.world, sink.first_lidar, snapshot, states=sink.states, start=start_pose
        )
    error = 0.0
    if sink.states:
        last = sink.states[-1]
        truth = last.true_pose
        dx, dy = truth.x - start_pose.x, truth.y - start_pose.y
        c, s = math.cos(start_pose.yaw), math.sin(start_pose.yaw)
        true_x, true_y = c * dx + s * dy, -s * dx + c * dy
        error = math.hypot(last.odometry.x - true_x, last.odometry.y - true_y)
    fell_ns = simulation.fell_ns
    return RecordSummary(
        out,
        simulation.time,
        wall_time,
        dict(sink.counts),
        len(sink.contacts),
        error,
        fell_at=None if fell_ns is None else (fell_ns - start_ns) / 1e9,
    )
