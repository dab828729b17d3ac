"""Bags of a robot standing in a room, its camera mounted at a known (odd) pose, for
`scanfuse calibrate`.

The room (base frame, metres): walls at x = -1.5 and 2.2, y = -1.3 and 1.6, 2 m high; a
pillar 0.25 m square and 0.8 m high (it crosses the LiDAR's plane); a 10 cm box below the
LiDAR's plane (only the camera sees it). The LiDAR at `lidar` sees walls and pillar in its
plane; the camera, at `mounting` (x, y, height, roll, pitch, yaw), sees floor, walls, pillar
and box. Depth images (analytic, `tests.support.render.box_depth`) and LiDAR ranges (the
same boxes cut by the LiDAR's plane, a ray meeting a rectangle) come from the geometry, with
seeded Gaussian noise: depth sigma `depth_noise` Z^2, LiDAR sigma `lidar_noise`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from scanfuse.calibrate import Mounting
from scanfuse.camera import CameraModel
from scanfuse.frames import StampedTransform
from scanfuse.motion import PlanarPose
from scanfuse.ros.messages import (
    CAMERA_INFO,
    IMAGE,
    LASER_SCAN,
    ODOMETRY,
    TF_MESSAGE,
    OdometrySample,
    camera_to_cdr,
    depth_to_cdr,
    odometry_to_cdr,
    scan_to_cdr,
    tf_message_to_cdr,
    typestore,
)
from scanfuse.scan import Scan
from scanfuse.transforms import BODY_TO_OPTICAL

if TYPE_CHECKING:
    from collections.abc import Callable

    from scanfuse.transforms import Transform
from tests.support.render import Bounds, box_depth, millimetres

NANOSECONDS = 1_000_000_000
WALL = 0.2
ROOM = (-1.5, 2.2, -1.3, 1.6)  # x_min, x_max, y_min, y_max of the free floor
PILLAR: Bounds = (1.2, 1.45, 0.3, 0.55, 0.0, 0.8)
LOW_BOX: Bounds = (1.0, 1.3, -0.5, -0.2, 0.0, 0.1)
Circle = tuple[float, float, float]  # centre x, y and radius, metres
LIDAR = Mounting(0.0, 0.0, 0.30, 0.0, 0.0, 0.0)  # base_link -> laser: 0.3 m up, level


def room_boxes() -> list[Bounds]:
    x0, x1, y0, y1 = ROOM
    top = 2.0
    return [
        (x1, x1 + WALL, y0 - WALL, y1 + WALL, 0.0, top),
        (x0 - WALL, x0, y0 - WALL, y1 + WALL, 0.0, top),
        (x0 - WALL, x1 + WALL, y1, y1 + WALL, 0.0, top),
        (x0 - WALL, x1 + WALL, y0 - WALL, y0, 0.0, top),
        PILLAR,
        LOW_BOX,
    ]


def ray_to_boxes(
    origin: tuple[float, float], angles: np.ndarray, height: float, boxes: list[Bounds]
) -> np.ndarray:
    """Distance along horizontal rays from `origin` at `height` (world bearings `angles`) to
    the nearest box side that the plane z = `height` cuts; +Inf where none."""
    dx, dy = np.cos(angles), np.sin(angles)
    ranges = np.full(angles.shape, np.inf)
    with np.errstate(divide='ignore', invalid='ignore'):
        for x0, x1, y0, y1, z0, z1 in boxes:
            if not z0 <= height <= z1:
                continue
            tx0, tx1 = (x0 - origin[0]) / dx, (x1 - origin[0]) / dx
            ty0, ty1 = (y0 - origin[1]) / dy, (y1 - origin[1]) / dy
            enter = np.maximum(np.minimum(tx0, tx1), np.minimum(ty0, ty1))
            leave = np.minimum(np.maximum(tx0, tx1), np.maximum(ty0, ty1))
            hit = (enter <= leave) & (enter > 0.0) & (enter < ranges)
            ranges = np.where(hit, enter, ranges)
    return ranges


def round_wall_depth(camera: CameraModel, optical_pose: Transform, wall: Circle) -> np.ndarray:
    """Depth along the optical axis (metres, inf: none) of the inside of a vertical round
    wall (centre x, y and radius, base frame) seen from inside: where a ray leaves the
    circle, x^2 + y^2 = r^2 solved for the far root."""
    x_n, y_n = (np.asarray(c, dtype=np.float64) for c in camera.normalized_coordinates)
    origin = np.asarray(optical_pose.translation)
    rays = np.stack([x_n, y_n, np.ones_like(x_n)], axis=-1) @ optical_pose.rotation_matrix.T
    ox, oy = origin[0] - wall[0], origin[1] - wall[1]
    a = rays[..., 0] ** 2 + rays[..., 1] ** 2
    b = ox * rays[..., 0] + oy * rays[..., 1]
    c = ox * ox + oy * oy - wall[2] ** 2
    with np.errstate(divide='ignore', invalid='ignore'):
        t = (-b + np.sqrt(b * b - a * c)) / a  # per unit of the optical z: the depth itself
    return np.where(np.isfinite(t) & (t > 0.0), t, np.inf)


def ray_out_of_circle(origin: tuple[float, float], angles: np.ndarray, wall: Circle) -> np.ndarray:
    """Distance along horizontal rays from `origin`, inside the circle, to where they leave
    it."""
    dx, dy = np.cos(angles), np.sin(angles)
    ox, oy = origin[0] - wall[0], origin[1] - wall[1]
    b = ox * dx + oy * dy
    return -b + np.sqrt(b * b - (ox * ox + oy * oy - wall[2] ** 2))


@dataclass(frozen=True)
class Room:
    """A recording of the room: the true mounting, the sensors, the timing."""

    mounting: Mounting
    lidar: Mounting = LIDAR
    width: int = 320
    height: int = 240
    focal: float = 200.0
    readings: int = 720
    lidar_range_max: float = 12.0
    duration: float = 2.0
    scan_hz: float = 10.0
    depth_hz: float = 15.0
    depth_noise: float = 0.01
    lidar_noise: float = 0.005
    seed: int = 0
    boxes: tuple[Bounds, ...] = field(default_factory=lambda: tuple(room_boxes()))
    start_ns: int = 1_700_000_000 * NANOSECONDS
    metres: bool = False  # depth as 32FC1 metres (NaN: none), not 16UC1 millimetres
    round_wall: Circle | None = None  # a round room's wall (centre x, y, radius) as well

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

    def depth_image(self, rng: np.random.Generator) -> np.ndarray:
        """16UC1 millimetres (0: none) or, with `metres`, 32FC1 metres (NaN: none)."""
        millimetre = self.depth_mm(rng)
        if not self.metres:
            return millimetre
        return np.where(millimetre > 0, millimetre / 1000.0, np.nan).astype(np.float32)

    def depth_mm(self, rng: np.random.Generator) -> np.ndarray:
        depth = box_depth(self.camera, self.mounting.optical, list(self.boxes))
        if self.round_wall is not None:
            round_wall = round_wall_depth(self.camera, self.mounting.optical, self.round_wall)
            depth = np.minimum(depth, round_wall)
        noise = rng.normal(0.0, 1.0, depth.shape)
        finite = np.isfinite(depth)
        noisy = np.where(
            finite, depth + noise * self.depth_noise * np.where(finite, depth, 0.0) ** 2, depth
        )
        return millimetres(noisy, far=10.0)

    def scan(self, stamp_ns: int, rng: np.random.Generator) -> Scan:
        increment = 2.0 * math.pi / self.readings
        angles = -math.pi + increment * np.arange(self.readings)
        lidar = self.lidar
        # A LiDAR mounted upside down (roll pi) sweeps the other way round in the base frame.
        sense = -1.0 if math.isclose(abs(lidar.roll), math.pi) else 1.0
        bearings = lidar.yaw + sense * angles
        ranges = ray_to_boxes((lidar.x, lidar.y), bearings, lidar.height, list(self.boxes))
        if self.round_wall is not None:
            round_wall = ray_out_of_circle((lidar.x, lidar.y), bearings, self.round_wall)
            ranges = np.minimum(ranges, round_wall)
        ranges = ranges + rng.normal(0.0, self.lidar_noise, ranges.shape)
        ranges[ranges > self.lidar_range_max] = np.inf
        return Scan(
            angle_min=-math.pi,
            angle_max=-math.pi + increment * (self.readings - 1),
            angle_increment=increment,
            range_min=0.05,
            range_max=self.lidar_range_max,
            ranges=ranges.astype(np.float32),
            scan_time=1.0 / self.scan_hz,
            frame_id='laser',
            stamp_ns=stamp_ns,
        )


def mounting_transforms(
    lidar: Mounting, camera: Mounting | None, mount: Transform | None = None
) -> list[StampedTransform]:
    """/tf_static: base_link -> laser, and (if given) base_link -> camera_link ->
    camera_depth_optical_frame; with `mount`, base_link -> camera_mount (at `mount`) ->
    camera_link."""
    transforms = [
        StampedTransform(
            'base_link', 'laser', (lidar.x, lidar.y, lidar.height), lidar.body.rotation
        )
    ]
    if camera is not None:
        body = camera.body
        parent = 'base_link'
        if mount is not None:
            transforms.append(
                StampedTransform('base_link', 'camera_mount', mount.translation, mount.rotation)
            )
            body, parent = mount.inverse() @ body, 'camera_mount'
        transforms += [
            StampedTransform(parent, 'camera_link', body.translation, body.rotation),
            StampedTransform(
                'camera_link',
                'camera_depth_optical_frame',
                (0.0, 0.0, 0.0),
                BODY_TO_OPTICAL.rotation,
            ),
        ]
    return transforms


def room_messages(
    room: Room,
    *,
    tf_camera: Mounting | None = None,
    mount: Transform | None = None,
    with_lidar: bool = True,
    heading: Callable[[float], float] | None = None,
) -> list[tuple[str, str, int, bytes]]:
    """(topic, type, log time, CDR) of the recording; /tf_static holds the LiDAR's true
    mounting and, if `tf_camera` is given, that camera mounting (right or wrong), hung from
    `mount` if given (`mounting_transforms`). With `heading` (seconds -> yaw), /odom at
    50 Hz says the base turned so (the images and scans stay those of the standing robot)."""
    store = typestore()
    rng = np.random.default_rng(room.seed)
    tf = tf_message_to_cdr(mounting_transforms(room.lidar, tf_camera, mount), store)
    messages = [('/tf_static', TF_MESSAGE, room.start_ns, tf)]
    if with_lidar:
        for i in range(round(room.duration * room.scan_hz)):
            stamp = room.start_ns + round(i * NANOSECONDS / room.scan_hz)
            raw = scan_to_cdr(room.scan(stamp, rng), store)
            messages.append(('/scan', LASER_SCAN, stamp + 1_000_000, raw))
    camera = room.camera
    for i in range(round(room.duration * room.depth_hz)):
        stamp = room.start_ns + round(i * NANOSECONDS / room.depth_hz) + 5_000_000
        image = depth_to_cdr(
            room.depth_image(rng), frame_id=camera.frame_id, stamp_ns=stamp, store=store
        )
        info = camera_to_cdr(camera, stamp_ns=stamp, store=store)
        messages.append(('/camera/depth/image_raw', IMAGE, stamp + 30_000_000, image))
        messages.append(('/camera/depth/camera_info', CAMERA_INFO, stamp + 30_000_000, info))
    if heading is not None:
        for i in range(round(room.duration * 50) + 1):
            stamp = room.start_ns + i * NANOSECONDS // 50
            pose = PlanarPose(0.0, 0.0, heading(i / 50))
            raw = odometry_to_cdr(OdometrySample(stamp, 'odom', 'base_link', pose), store)
            messages.append(('/odom', ODOMETRY, stamp, raw))
    messages.sort(key=lambda item: item[2])
    return messages
