"""The drop-in modes of issue 27 as messages: two corner LiDARs in a square room (no camera)
and depthimage_to_laserscan's test images (no LiDAR), for the bag and the node's tests.

Truth is geometry: the room's walls are at x = +-HALF and y = +-HALF around the base origin.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from scanfuse.camera import CameraModel
from scanfuse.motion import PlanarPose
from scanfuse.ros.messages import (
    CAMERA_INFO,
    IMAGE,
    LASER_SCAN,
    ODOMETRY,
    OdometrySample,
    camera_to_cdr,
    depth_to_cdr,
    odometry_to_cdr,
    scan_to_cdr,
)
from scanfuse.scan import Scan
from tests.support.render import square_room_ranges

HALF = 2.0
FOV = math.radians(270.0)
# (topic, frame, origin in base_link, yaw): 270-degree LiDARs at opposite corners.
FRONT = ('/front/scan', 'front_laser', (0.3, 0.2), math.pi / 4)
REAR = ('/rear/scan', 'rear_laser', (-0.3, -0.2), -3 * math.pi / 4)


def lidars_only_params() -> dict[str, Any]:
    """Parameters of a robot with the two LiDARs and no camera, output in base_link over
    360 degrees at half a degree (mountings as parameters, no TF)."""
    values: dict[str, Any] = {
        'use_tf': False,
        'memory': False,
        'depth_topic': '',
        'output_frame': 'base_link',
        'angle_min': -math.pi,
        'angle_max': math.pi,
        'angle_increment': math.pi / 360,
        'lidars': ['front', 'rear'],
    }
    for name, (topic, _, (x, y), yaw) in (('front', FRONT), ('rear', REAR)):
        values[name] = {'topic': topic, 'x': x, 'y': y, 'z': 0.2, 'yaw': yaw}
    return values


def room_scan(lidar: tuple[str, str, tuple[float, float], float], stamp_ns: int) -> Scan:
    """What a 1080-reading 270-degree LiDAR at its corner reads of the room."""
    _, frame, origin, yaw = lidar
    count = 1080
    increment = FOV / count
    angles = -FOV / 2 + increment * np.arange(count)
    return Scan(
        angle_min=-FOV / 2,
        angle_max=float(angles[-1]),
        angle_increment=increment,
        range_min=0.05,
        range_max=20.0,
        ranges=square_room_ranges(origin, yaw, angles, HALF).astype(np.float32),
        scan_time=0.1,
        frame_id=frame,
        stamp_ns=stamp_ns,
    )


def lidar_messages(count: int, start_ns: int = 1_000_000_000) -> list[tuple[str, str, int, bytes]]:
    """Both LiDARs at 10 Hz, the rear one stamped (and logged) 20 ms before the front one."""
    messages = []
    for k in range(count):
        stamp = start_ns + k * 100_000_000
        rear_stamp = stamp - 20_000_000
        messages.append((REAR[0], LASER_SCAN, rear_stamp, scan_to_cdr(room_scan(REAR, rear_stamp))))
        messages.append((FRONT[0], LASER_SCAN, stamp, scan_to_cdr(room_scan(FRONT, stamp))))
    return messages


def room_truth(scan: Any) -> tuple[float, float]:
    """(share of the output's slots with a finite reading, largest error of those against the
    room seen from the base origin) of a decoded LaserScan message."""
    ranges = np.asarray(scan.ranges, dtype=np.float64)
    angles = scan.angle_min + scan.angle_increment * np.arange(len(ranges))
    truth = square_room_ranges((0.0, 0.0), 0.0, angles, HALF)
    finite = np.isfinite(ranges)
    error = float(np.max(np.abs(ranges[finite] - truth[finite]))) if finite.any() else math.inf
    return float(finite.mean()), error


# ---------------------------------------------------------------- a turning robot

OMEGA = 1.0  # rad/s: the robot turns on the spot at the room's centre
LIDAR_AT = (0.2, 0.0)  # the LiDAR 0.2 m ahead of the base, so turning also moves it


def lidar_in_world(t: float) -> tuple[tuple[float, float], float]:
    """The LiDAR's position and heading in the room `t` seconds after the base's yaw 0."""
    yaw = OMEGA * t
    return (LIDAR_AT[0] * math.cos(yaw), LIDAR_AT[0] * math.sin(yaw)), yaw


def turning_scan(t_ns: int) -> Scan:
    """What a 360-degree LiDAR (0.25 degrees, all beams at the stamp) reads at `t_ns`."""
    increment = math.radians(0.25)
    angles = -math.pi + increment * np.arange(1440)
    origin, yaw = lidar_in_world(t_ns / 1e9)
    return Scan(
        angle_min=-math.pi,
        angle_max=float(angles[-1]),
        angle_increment=increment,
        range_min=0.05,
        range_max=20.0,
        ranges=square_room_ranges(origin, yaw, angles, HALF).astype(np.float32),
        frame_id='laser',
        stamp_ns=t_ns,
    )


def turning_messages(ticks: int) -> list[tuple[str, str, int, bytes]]:
    """The turning robot from 1 s on, `ticks` + 1 ticks of 10 ms: odometry at every tick
    (100 Hz), a scan at every tenth (10 Hz)."""
    messages = []
    for k in range(ticks + 1):
        t_ns = 1_000_000_000 + k * 10_000_000
        pose = PlanarPose(0.0, 0.0, OMEGA * t_ns / 1e9)
        odometry = odometry_to_cdr(OdometrySample(t_ns, 'odom', 'base_link', pose))
        messages.append(('/odom', ODOMETRY, t_ns, odometry))
        if k % 10 == 0:
            messages.append(('/scan', LASER_SCAN, t_ns, scan_to_cdr(turning_scan(t_ns))))
    return messages


# ---------------------------------------------------------------- camera only

D2L_FX, D2L_CX, D2L_CY = 570.3422241210938, 314.5, 235.5
D2L_CAMERA = CameraModel.from_intrinsics(
    640, 480, D2L_FX, D2L_FX, D2L_CX, D2L_CY, frame_id='camera_depth_frame'
)
D2L_RANGE = (0.45, 10.0)
# The same camera at a quarter of the resolution: over DDS a 640x480 float image is 1.2 MB
# of best-effort fragments, which a loaded test machine loses; 160x120 is the size the other
# DDS tests send.
SMALL_CAMERA = CameraModel.from_intrinsics(
    160, 120, D2L_FX / 4, D2L_FX / 4, (D2L_CX + 0.5) / 4 - 0.5, (D2L_CY + 0.5) / 4 - 0.5,
    frame_id='camera_depth_frame',
)  # fmt: skip


def camera_only_params() -> dict[str, Any]:
    """depthimage_to_laserscan's test fixture as scanfuse parameters: no LiDAR, row method,
    d2l_compat, ranges 0.45-10 m, one row."""
    return {
        'scan_topic': '',
        'method': 'row',
        'd2l_compat': True,
        'range_min': D2L_RANGE[0],
        'range_max': D2L_RANGE[1],
        'memory': False,
        'use_tf': False,
    }


def d2l_images(shape: tuple[int, int] = (480, 640)) -> dict[str, np.ndarray]:
    """The upstream test's images (test/DepthImageToLaserScanTest.cpp): every pixel 3.855 m
    (its fixture), random 0-0.5 m, NaN, +Inf, -Inf."""
    rng = np.random.default_rng(8675309)
    return {
        'fixture': np.full(shape, 0x0F0F, dtype=np.uint16),
        'random': rng.integers(0, 500, size=shape, endpoint=True).astype(np.uint16),
        'nan': np.full(shape, np.nan, dtype=np.float32),
        'inf': np.full(shape, np.inf, dtype=np.float32),
        'minus_inf': np.full(shape, -np.inf, dtype=np.float32),
    }


def camera_messages(
    images: list[np.ndarray],
    depth_topic: str = '/camera/depth/image_raw',
    info_topic: str = '/camera/depth/camera_info',
    start_ns: int = 1_000_000_000,
    period_ns: int = 33_333_333,
    lead: int = 0,
    camera: CameraModel = D2L_CAMERA,
) -> list[tuple[str, str, int, bytes]]:
    """CameraInfo and one depth image per entry of `images`, `period_ns` apart; `lead`
    CameraInfo messages alone before the first (over DDS the calibration then arrives
    before any image: the two topics' samples are not ordered between them)."""
    messages = []
    for k in range(-lead, len(images)):
        stamp = start_ns + k * period_ns
        messages.append((info_topic, CAMERA_INFO, stamp, camera_to_cdr(camera, stamp_ns=stamp)))
        if k >= 0:
            raw = depth_to_cdr(images[k], frame_id='camera_depth_frame', stamp_ns=stamp)
            messages.append((depth_topic, IMAGE, stamp, raw))
    return messages


def box_cloud() -> np.ndarray:
    """What a 3D sensor 1 m up at the base origin sees (N x 3, its frame = the base frame
    less (0, 0, 1)): the floor around it (z = 0) and a box 0.3 m high whose near face is at
    x = 1.5 m, 0.4 m wide."""
    xs, ys = np.meshgrid(np.linspace(-3, 3, 121), np.linspace(-3, 3, 121))
    floor = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1)
    face_y, face_z = np.meshgrid(np.linspace(-0.2, 0.2, 41), np.linspace(0.0, 0.3, 16))
    face = np.stack([np.full(face_y.size, 1.5), face_y.ravel(), face_z.ravel()], axis=1)
    return np.concatenate([floor, face]) - np.array([0.0, 0.0, 1.0])


def clouds_only_params() -> dict[str, Any]:
    """Parameters of a robot with only that 3D sensor (`box_cloud`), named `points` on /points."""
    return {
        'scan_topic': '',
        'depth_topic': '',
        'use_tf': False,
        'memory': False,
        'obstacle_min_points': 1,
        'clouds': ['points'],
        'points': {'topic': '/points', 'z': 1.0},
    }
