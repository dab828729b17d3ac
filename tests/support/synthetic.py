"""Bags of a scene with known geometry, for tests, benchmarks and trying the `bag` command.

The scene: a flat floor (base z = 0), a wall across the robot's path at
x = `wall_x`, and a low box (front face at x = `box_x`, |y| <= box_half_width,
height `box_height`) below the LiDAR's plane. The LiDAR sees only the wall; the
depth camera, looking down from above the LiDAR, sees floor, box and wall.
Scans and depth images are rendered by ray casting that geometry; the mounting
is published on /tf_static as base_link -> laser and base_link -> camera_link ->
camera_depth_optical_frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from rosbags.rosbag1 import Writer as Ros1Writer
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from scanfuse.camera import CameraModel
from scanfuse.frames import StampedTransform
from scanfuse.ros.messages import (
    CAMERA_INFO,
    IMAGE,
    LASER_SCAN,
    TF_MESSAGE,
    camera_to_cdr,
    depth_to_cdr,
    scan_to_cdr,
    tf_message_to_cdr,
    typestore,
)
from scanfuse.scan import Scan
from scanfuse.transforms import BODY_TO_OPTICAL, Transform
from tests.support.render import box_depth, millimetres

if TYPE_CHECKING:
    from pathlib import Path

    import numpy.typing as npt

NANOSECONDS = 1_000_000_000


@dataclass(frozen=True)
class Scene:
    """Geometry, sensors and timing of a synthetic recording (metres, radians, seconds)."""

    wall_x: float = 2.0
    box_x: float = 1.2
    box_depth: float = 0.3
    box_half_width: float = 0.15
    box_height: float = 0.2
    lidar_height: float = 0.3
    readings: int = 360
    fov: float = 1.5 * math.pi
    lidar_range_max: float = 10.0
    camera_x: float = 0.1
    camera_height: float = 0.45
    camera_pitch: float = math.radians(20.0)
    width: int = 160
    height: int = 120
    focal: float = 100.0
    duration: float = 2.0
    scan_hz: float = 10.0
    depth_hz: float = 30.0
    start_ns: int = 1_700_000_000 * NANOSECONDS
    depth_gap: tuple[float, float] | None = None
    log_delay: float = 0.01
    publish_tf: bool = True
    publish_camera_info: bool = True

    @property
    def camera(self) -> CameraModel:
        return CameraModel.from_intrinsics(
            self.width,
            self.height,
            self.focal,
            self.focal,
            (self.width - 1) / 2,
            (self.height - 1) / 2,
            frame_id='camera_depth_optical_frame',
        )

    @property
    def angle_increment(self) -> float:
        return self.fov / (self.readings - 1)

    @property
    def angle_min(self) -> float:
        return -self.fov / 2

    def lidar_angles(self) -> npt.NDArray[np.float64]:
        return self.angle_min + self.angle_increment * np.arange(self.readings, dtype=np.float64)

    def lidar_ranges(self) -> npt.NDArray[np.float32]:
        """The wall in the LiDAR's plane: r = wall_x / cos(theta); +Inf where it is out of range."""
        cos = np.cos(self.lidar_angles())
        with np.errstate(divide='ignore'):
            ranges = np.where(cos > 0.0, self.wall_x / np.maximum(cos, 1e-12), np.inf)
        ranges[ranges > self.lidar_range_max] = np.inf
        return ranges.astype(np.float32)

    def transforms(self) -> list[StampedTransform]:
        camera_body = Transform.from_rpy(
            0.0, self.camera_pitch, 0.0, (self.camera_x, 0.0, self.camera_height)
        )
        return [
            StampedTransform(
                'base_link', 'laser', (0.0, 0.0, self.lidar_height), (0.0, 0.0, 0.0, 1.0)
            ),
            StampedTransform(
                'base_link', 'camera_link', camera_body.translation, camera_body.rotation
            ),
            StampedTransform(
                'camera_link',
                'camera_depth_optical_frame',
                (0.0, 0.0, 0.0),
                BODY_TO_OPTICAL.rotation,
            ),
        ]

    def depth_mm(self) -> npt.NDArray[np.uint16]:
        """The depth image (16UC1 millimetres, 0 = no return) of floor, box and wall."""
        camera_body = Transform.from_rpy(
            0.0, self.camera_pitch, 0.0, (self.camera_x, 0.0, self.camera_height)
        )
        wall = (self.wall_x, self.wall_x + 1.0, -100.0, 100.0, -1.0, 100.0)
        box = (
            self.box_x,
            self.box_x + self.box_depth,
            -self.box_half_width,
            self.box_half_width,
            0.0,
            self.box_height,
        )
        depth = box_depth(self.camera, camera_body @ BODY_TO_OPTICAL, [wall, box])
        return millimetres(depth, far=65.535)

    def scan_stamps(self) -> list[int]:
        count = round(self.duration * self.scan_hz)
        return [self.start_ns + round(i * NANOSECONDS / self.scan_hz) for i in range(count)]

    def depth_stamps(self) -> list[int]:
        count = round(self.duration * self.depth_hz)
        # Offset by a third of a frame so scans and frames never share a stamp.
        offset = NANOSECONDS / self.depth_hz / 3
        stamps = [
            self.start_ns + round(offset + i * NANOSECONDS / self.depth_hz) for i in range(count)
        ]
        if self.depth_gap is not None:
            lo, hi = (self.start_ns + round(s * NANOSECONDS) for s in self.depth_gap)
            stamps = [stamp for stamp in stamps if not lo <= stamp < hi]
        return stamps


def scene_messages(scene: Scene) -> list[tuple[str, str, int, bytes]]:
    """(topic, msgtype, log time, CDR) of every message of the recording, in log-time order."""
    store = typestore()
    delay = round(scene.log_delay * NANOSECONDS)
    messages = []
    if scene.publish_tf:
        tf = tf_message_to_cdr(scene.transforms(), store)
        messages.append(('/tf_static', TF_MESSAGE, scene.start_ns, tf))
    ranges = scene.lidar_ranges()
    for stamp in scene.scan_stamps():
        scan = Scan(
            angle_min=scene.angle_min,
            angle_max=scene.angle_min + scene.angle_increment * (scene.readings - 1),
            angle_increment=scene.angle_increment,
            range_min=0.05,
            range_max=scene.lidar_range_max,
            ranges=ranges,
            scan_time=1.0 / scene.scan_hz,
            frame_id='laser',
            stamp_ns=stamp,
        )
        messages.append(('/scan', LASER_SCAN, stamp + delay, scan_to_cdr(scan, store)))
    depth = scene.depth_mm()
    camera = scene.camera
    for stamp in scene.depth_stamps():
        # Cameras deliver later than LiDARs: log time 3 delays after the stamp.
        log = stamp + 3 * delay
        image = depth_to_cdr(depth, frame_id=camera.frame_id, stamp_ns=stamp, store=store)
        info = camera_to_cdr(camera, stamp_ns=stamp, store=store)
        messages.append(('/camera/depth/image_raw', IMAGE, log, image))
        if scene.publish_camera_info:
            messages.append(('/camera/depth/camera_info', CAMERA_INFO, log, info))
    messages.sort(key=lambda item: item[2])
    return messages


def write_scene_bag(path: Path, scene: Scene | None = None, *, storage: str = 'mcap') -> Path:
    """Write the scene as a ROS 2 bag (`storage` mcap or sqlite3) or, for 'ros1', a ROS 1 bag."""
    return write_bag(path, scene_messages(scene or Scene()), storage=storage)


def write_bag(
    path: Path, messages: list[tuple[str, str, int, bytes]], *, storage: str = 'mcap'
) -> Path:
    """Write (topic, msgtype, log time, CDR) messages as a ROS 2 bag or ('ros1') a ROS 1 bag."""
    if storage == 'ros1':
        return _write_ros1(path, messages)
    plugin = {'mcap': StoragePlugin.MCAP, 'sqlite3': StoragePlugin.SQLITE3}[storage]
    store = typestore()
    with Writer(path, version=8, storage_plugin=plugin) as writer:
        connections = {}
        for topic, msgtype, _, _ in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
        for topic, _, log_time, raw in messages:
            writer.write(connections[topic], log_time, raw)
    return path


def _write_ros1(path: Path, messages: list[tuple[str, str, int, bytes]]) -> Path:
    ros2 = typestore()
    noetic = get_typestore(Stores.ROS1_NOETIC)
    # Noetic's store lacks tf2_msgs; its TFMessage is one array of TransformStamped.
    noetic.register(get_types_from_msg('geometry_msgs/TransformStamped[] transforms', TF_MESSAGE))
    with Ros1Writer(path) as writer:
        connections = {}
        for topic, msgtype, _, _ in messages:
            if topic not in connections:
                connections[topic] = writer.add_connection(
                    topic, msgtype, typestore=noetic, latching=int(topic == '/tf_static')
                )
        for topic, msgtype, log_time, raw in messages:
            writer.write(connections[topic], log_time, bytes(ros2.cdr_to_ros1(raw, msgtype)))
    return path


REAR_TOPIC = '/rear/scan'
REAR_FRAME = 'rear_laser'


def rear_scan_messages(
    scene: Scene, *, back_wall: float = 1.5, lead: float = 0.02
) -> list[tuple[str, str, int, bytes]]:
    """A second LiDAR at the base origin (height `scene.lidar_height`) turned to face back
    (yaw pi), seeing a back wall at x = -`back_wall` in the base frame: in its own frame the
    wall is at x' = +back_wall, so r = back_wall / cos(theta'). Stamped `lead` seconds
    before each front scan (it arrives first); same grid as the front LiDAR."""
    store = typestore()
    delay = round(scene.log_delay * NANOSECONDS)
    cos = np.cos(scene.lidar_angles())
    with np.errstate(divide='ignore'):
        ranges = np.where(cos > 0.0, back_wall / np.maximum(cos, 1e-12), np.inf)
    ranges[ranges > scene.lidar_range_max] = np.inf
    messages = []
    for stamp in scene.scan_stamps():
        rear_stamp = stamp - round(lead * NANOSECONDS)
        scan = Scan(
            angle_min=scene.angle_min,
            angle_max=scene.angle_min + scene.angle_increment * (scene.readings - 1),
            angle_increment=scene.angle_increment,
            range_min=0.05,
            range_max=scene.lidar_range_max,
            ranges=ranges.astype(np.float32),
            scan_time=1.0 / scene.scan_hz,
            frame_id=REAR_FRAME,
            stamp_ns=rear_stamp,
        )
        messages.append((REAR_TOPIC, LASER_SCAN, rear_stamp + delay, scan_to_cdr(scan, store)))
    return messages


def two_lidar_messages(scene: Scene, **rear: float) -> list[tuple[str, str, int, bytes]]:
    """The scene's messages and a rear LiDAR's (`rear_scan_messages`), in log-time order."""
    messages = scene_messages(scene) + rear_scan_messages(scene, **rear)
    messages.sort(key=lambda item: item[2])
    return messages
