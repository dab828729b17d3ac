"""Analytic depth images and LiDAR scans of boxes and posts on a floor, from any pose.

Expected values of the geometry tests come from these closed forms (a ray meets a plane or
a circle), independent of the code under test.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from scanfuse.transforms import BODY_TO_OPTICAL, Transform

if TYPE_CHECKING:
    from collections.abc import Iterable

    from scanfuse.camera import CameraModel


@dataclass(frozen=True)
class Box:
    """An axis-aligned box standing on the floor (world frame, metres)."""

    x_min: float
    x_max: float
    y_min: float
    y_max: float
    height: float


def camera_in_world(
    x: float, y: float, yaw: float, *, height: float, pitch: float, forward: float = 0.0
) -> Transform:
    """World pose of the optical frame of a camera `forward` m ahead of a base at (x, y, yaw)."""
    base = Transform.from_rpy(0.0, 0.0, yaw, (x, y, 0.0))
    body = Transform.from_rpy(0.0, pitch, 0.0, (forward, 0.0, height))
    return base @ body @ BODY_TO_OPTICAL


Bounds = tuple[float, float, float, float, float, float]  # x0, x1, y0, y1, z0, z1


def box_depth(
    camera: CameraModel, optical_pose: Transform, boxes: Iterable[Bounds], *, floor: bool = True
) -> np.ndarray:
    """Depth along the optical axis of the nearest surface per pixel, metres (inf: none).

    `optical_pose` places the optical frame in the frame the floor (z = 0) and the
    axis-aligned `boxes` are given in. A ray meets a box where it is inside all three of its
    slabs (enter = max of the near planes, leave = min of the far ones).
    """
    x_n, y_n = (np.asarray(c, dtype=np.float64) for c in camera.normalized_coordinates)
    origin = np.asarray(optical_pose.translation)
    rays = np.stack([x_n, y_n, np.ones_like(x_n)], axis=-1) @ optical_pose.rotation_matrix.T
    depth = np.full(x_n.shape, np.inf)
    with np.errstate(divide='ignore', invalid='ignore'):
        if floor:
            at_floor = -origin[2] / rays[..., 2]
            depth = np.where(at_floor > 0.0, at_floor, depth)
        for box in boxes:
            low, high = np.array(box[0::2]), np.array(box[1::2])
            t_low, t_high = (low - origin) / rays, (high - origin) / rays
            enter = np.nanmax(np.minimum(t_low, t_high), axis=-1)
            leave = np.nanmin(np.maximum(t_low, t_high), axis=-1)
            depth = np.where((enter <= leave) & (enter > 0.0) & (enter < depth), enter, depth)
    return depth


def millimetres(depth: np.ndarray, *, far: float = 60.0) -> np.ndarray:
    """16UC1 of depths in metres: rounded millimetres, 0 where none (or beyond `far`)."""
    return np.where(np.isfinite(depth) & (depth < far), np.round(depth * 1000.0), 0).astype(
        np.uint16
    )


def depth_image(
    camera: CameraModel, world_to_optical: Transform, boxes: list[Box], *, floor: bool = True
) -> np.ndarray:
    """16UC1 millimetres of the floor (z = 0) and `boxes` seen by `camera`; 0 = no return."""
    bounds = [(b.x_min, b.x_max, b.y_min, b.y_max, 0.0, b.height) for b in boxes]
    return millimetres(box_depth(camera, world_to_optical, bounds, floor=floor))


def ray_to_circle(
    origin: tuple[float, float], angle: np.ndarray, centre: tuple[float, float], radius: float
) -> np.ndarray:
    """Distance along rays from `origin` at `angle` to a circle; +Inf where they miss it."""
    dx, dy = np.cos(angle), np.sin(angle)
    ox, oy = origin[0] - centre[0], origin[1] - centre[1]
    b = ox * dx + oy * dy
    c = ox * ox + oy * oy - radius * radius
    disc = b * b - c
    t = -b - np.sqrt(np.maximum(disc, 0.0))
    return np.where((disc >= 0) & (t > 0), t, np.inf)


def turning_sweep(
    count: int,
    sweep_time: float,
    omega: float,
    centre: tuple[float, float],
    radius: float,
    *,
    range_max: float,
) -> tuple[np.ndarray, float, float]:
    """Ranges of a 360-degree LiDAR at the origin turning at `omega` while it sweeps.

    Beam i (angle -pi + i * 2 pi / count in the sensor frame) is measured at i * dt, when the
    sensor's yaw is omega * i * dt (yaw 0 at the stamp). Returns (ranges, angle_min,
    angle_increment).
    """
    increment = 2.0 * math.pi / count
    beams = np.arange(count)
    angle_min = -math.pi
    sensor_angle = angle_min + beams * increment
    world_angle = sensor_angle + omega * beams * (sweep_time / count)
    ranges = ray_to_circle((0.0, 0.0), world_angle, centre, radius)
    ranges[ranges > range_max] = np.inf
    return ranges.astype(np.float32), angle_min, increment


def square_room_ranges(origin, yaw: float, angles: np.ndarray, half: float = 2.0) -> np.ndarray:
    """Distance from `origin` (x, y) along world bearings yaw + angles to the walls of the
    square room x = +-half, y = +-half: the nearer of the two walls each ray meets."""
    world = yaw + angles
    dx, dy = np.cos(world), np.sin(world)
    with np.errstate(divide='ignore'):
        tx = np.where(dx > 0, (half - origin[0]) / dx, (-half - origin[0]) / dx)
        ty = np.where(dy > 0, (half - origin[1]) / dy, (-half - origin[1]) / dy)
    return np.minimum(np.abs(tx), np.abs(ty))


def tilted_room_ranges(
    base: tuple[float, float, float],
    tilt: np.ndarray,
    angles: np.ndarray,
    *,
    height: float,
    half: float = 2.0,
) -> np.ndarray:
    """Ranges of a LiDAR `height` up on a base at `base` (x, y, yaw; its origin on the floor)
    tilted by `tilt` (3x3: the base's axes in a level frame of its heading), in the square
    room of upright walls x, y = +-half: each beam at `angles` runs to the walls or, pointing
    down, to the floor z = 0, whichever it meets first."""
    x, y, yaw = base
    origin = tilt @ np.array([0.0, 0.0, height])
    beams = tilt @ np.vstack([np.cos(angles), np.sin(angles), np.zeros(angles.size)])
    c, s = math.cos(yaw), math.sin(yaw)
    at = (x + c * origin[0] - s * origin[1], y + s * origin[0] + c * origin[1])
    across = np.hypot(beams[0], beams[1])
    walls = square_room_ranges(at, yaw, np.arctan2(beams[1], beams[0]), half=half) / across
    with np.errstate(divide='ignore'):
        floor = np.where(beams[2] < 0.0, origin[2] / -beams[2], np.inf)
    return np.minimum(walls, floor)


def slope_depth(
    camera: CameraModel,
    optical_pose: Transform,
    *,
    start: float,
    rise: float,
    length: float = math.inf,
    boxes: Iterable[Bounds] = (),
) -> np.ndarray:
    """Depth (metres, inf: none) of a floor z = 0 that from x = `start` on rises by `rise`
    metres per metre (falls, if negative) for `length` metres, then runs level; and `boxes`."""
    end = start + length
    top = rise * length if math.isfinite(length) else 0.0
    pieces = [(-math.inf, start, 0.0, 0.0), (start, end, 0.0, rise), (end, math.inf, top, 0.0)]
    return ground_depth(camera, optical_pose, pieces, boxes)


def ground_depth(
    camera: CameraModel,
    optical_pose: Transform,
    pieces: Iterable[tuple[float, float, float, float]],
    boxes: Iterable[Bounds] = (),
) -> np.ndarray:
    """Depth (metres, inf: none) of ground made of `pieces` (x from, x to, height at x from,
    slope: metres of rise per metre of x) and `boxes`.

    Each piece of ground is a plane met where the ray crosses it inside the piece's x range.
    """
    x_n, y_n = (np.asarray(c, dtype=np.float64) for c in camera.normalized_coordinates)
    origin = np.asarray(optical_pose.translation)
    rays = np.stack([x_n, y_n, np.ones_like(x_n)], axis=-1) @ optical_pose.rotation_matrix.T
    depth = box_depth(camera, optical_pose, boxes, floor=False)
    with np.errstate(divide='ignore', invalid='ignore'):
        for x_from, x_to, z_from, slope in pieces:
            # origin_z + t r_z = z_from + slope (origin_x + t r_x - x_from)
            rise_to_origin = slope * (origin[0] - x_from) if slope else 0.0
            t = (z_from + rise_to_origin - origin[2]) / (rays[..., 2] - slope * rays[..., 0])
            x = origin[0] + t * rays[..., 0]
            hit = (t > 0.0) & (x >= x_from) & (x <= x_to) & (t < depth)
            depth = np.where(hit, t, depth)
    return depth
