"""Where is the floor? Camera height, pitch and roll from one depth image, to check extrinsics.

The obstacle method measures heights from the floor through the extrinsics; a
camera mounted 2 cm lower or 1 deg steeper than configured turns the floor far
ahead into obstacles. `fit_floor` finds the dominant plane of a depth image by
RANSAC, refines it by least squares on its inliers, and reads the camera's pose
above it; `check_extrinsics` says in words where configuration and image disagree.

The floor must be the largest plane in view (point the camera at open floor).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from scanfuse.camera import depth_in_metres
from scanfuse.errors import InputError

if TYPE_CHECKING:
    import numpy.typing as npt

    from scanfuse.camera import CameraModel

    Points = npt.NDArray[np.float64]

# Three points closer to a line than this (|cross product|, m^2) give no plane.
_DEGENERATE_AREA = 1e-9


@dataclass(frozen=True)
class FloorFit:
    """The camera's pose above the fitted floor plane.

    `normal` is the plane's unit normal in the camera's optical frame, pointing
    from the floor towards the camera (up); `camera_pitch` is positive looking
    down and `camera_roll` positive with the camera's right side down (REP-103,
    as `Extrinsics.from_mounting` takes them).
    """

    camera_height: float
    camera_pitch: float
    camera_roll: float
    inlier_share: float
    normal: tuple[float, float, float]
    inlier_count: int
    point_count: int


def _sample_points(
    depth: npt.NDArray[np.generic],
    camera: CameraModel,
    *,
    range_min: float,
    range_max: float,
    max_points: int,
    rng: np.random.Generator,
) -> Points:
    """Back-projected valid pixels (optical frame), at most `max_points` of them, at random."""
    camera.check_depth(depth)
    z = depth_in_metres(depth).ravel()
    with np.errstate(invalid='ignore'):
        valid = np.flatnonzero((z >= range_min) & (z <= range_max))
    if valid.size > max_points:
        valid = np.sort(rng.choice(valid, size=max_points, replace=False))
    x_n, y_n = camera.normalized_coordinates
    z_valid = z[valid].astype(np.float64)
    points = np.empty((valid.size, 3), dtype=np.float64)
    points[:, 0] = x_n.ravel()[valid] * z_valid
    points[:, 1] = y_n.ravel()[valid] * z_valid
    points[:, 2] = z_valid
    return points[np.isfinite(points).all(axis=1)]


def _ransac_plane(
    points: Points, *, iterations: int, inlier_distance: float, rng: np.random.Generator
) -> npt.NDArray[np.bool_]:
    """Inliers of the plane through three random points that has the most inliers."""
    samples = rng.integers(0, points.shape[0], size=(iterations, 3))
    p0, p1, p2 = points[samples[:, 0]], points[samples[:, 1]], points[samples[:, 2]]
    normals = np.cross(p1 - p0, p2 - p0)
    lengths = np.linalg.norm(normals, axis=1)
    usable = lengths > _DEGENERATE_AREA
    normals = normals[usable] / lengths[usable, None]
    offsets = -np.einsum('ij,ij->i', normals, p0[usable])
    best_inliers = np.zeros(points.shape[0], dtype=np.bool_)
    for normal, offset in zip(normals, offsets, strict=True):
        inliers = np.abs(points @ normal + offset) <= inlier_distance
        if inliers.sum() > best_inliers.sum():
            best_inliers = inliers
    return best_inliers


def _least_squares_plane(points: Points) -> tuple[npt.NDArray[np.float64], float]:
    """Unit normal and offset (n . p + d = 0) minimising squared distances (total least squares)."""
    centroid = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centroid, full_matrices=False)
    normal = vt[-1]
    return normal, float(-normal @ centroid)


def fit_floor(
    depth: npt.NDArray[np.generic],
    camera: CameraModel,
    *,
    range_min: float = 0.2,
    range_max: float = 8.0,
    max_points: int = 20_000,
    iterations: int = 200,
    inlier_distance: float = 0.02,
    min_points: int = 500,
    min_inlier_share: float = 0.2,
    seed: int = 0,
) -> FloorFit:
    """Camera height, pitch and roll above the largest plane of a depth image.

    RANSAC (`iterations` random triples, seeded: the same image gives the same fit)
    on at most `max_points` back-projected pixels with depth in [range_min,
    range_max]; the winning plane is refitted by least squares on its inliers
    twice (the second time with the inliers of the refined plane).
    """
    rng = np.random.default_rng(seed)
    points = _sample_points(
        depth, camera, range_min=range_min, range_max=range_max, max_points=max_points, rng=rng
    )
    if points.shape[0] < max(min_points, 3):
        msg = (
            f'only {points.shape[0]} valid depth pixels between {range_min} m and {range_max} m; '
            f'fitting the floor needs at least {max(min_points, 3)}: point the camera at the floor'
        )
        raise InputError(msg)
    inliers = _ransac_plane(points, iterations=iterations, inlier_distance=inlier_distance, rng=rng)
    if inliers.sum() < 3:
        msg = 'no plane found in the depth image: the valid points are not near any plane'
        raise InputError(msg)
    for _ in range(2):
        normal, offset = _least_squares_plane(points[inliers])
        inliers = np.abs(points @ normal + offset) <= inlier_distance
    share = float(inliers.mean())
    if share < min_inlier_share:
        msg = (
            f'no floor plane found: the largest plane holds {share:.0%} of the valid points, '
            f'less than min_inlier_share={min_inlier_share:.0%}; point the camera at open floor'
        )
        raise InputError(msg)
    normal, offset = _least_squares_plane(points[inliers])
    # Orient the normal towards the camera (the optical origin is on its positive side).
    if offset < 0.0:
        normal, offset = -normal, -offset
    return _pose_above(normal, offset, share, int(inliers.sum()), points.shape[0])


def _pose_above(
    normal: npt.NDArray[np.float64], offset: float, share: float, inliers: int, total: int
) -> FloorFit:
    """Height, pitch, roll of a camera whose floor has upward unit normal `normal` (optical).

    The base frame's up axis seen in the optical frame of a camera with roll r and
    pitch p is (-cos p sin r, -cos p cos r, -sin p) (R = Rz Ry Rx, then body to optical).
    """
    n_x, n_y, n_z = (float(value) for value in normal)
    pitch = math.asin(max(-1.0, min(1.0, -n_z)))
    roll = math.atan2(-n_x, -n_y)
    return FloorFit(
        camera_height=offset,
        camera_pitch=pitch,
        camera_roll=roll,
        inlier_share=share,
        normal=(n_x, n_y, n_z),
        inlier_count=inliers,
        point_count=total,
    )


def _angle_difference(a: float, b: float) -> float:
    return abs(math.remainder(a - b, 2.0 * math.pi))


def check_extrinsics(
    fit: FloorFit,
    camera_height: float,
    camera_pitch: float,
    camera_roll: float,
    *,
    height_tolerance: float = 0.02,
    angle_tolerance: float = math.radians(1.0),
) -> list[str]:
    """Warnings, one per configured value that the floor fit contradicts; empty when all agree."""
    warnings = []
    height_error = abs(fit.camera_height - camera_height)
    if height_error > height_tolerance:
        warnings.append(
            f'camera_height is {camera_height:.3f} m but the floor is {fit.camera_height:.3f} m '
            f'below the camera (off by {height_error:.3f} m, tolerance {height_tolerance:.3f} m)'
        )
    for name, configured, fitted in (
        ('camera_pitch', camera_pitch, fit.camera_pitch),
        ('camera_roll', camera_roll, fit.camera_roll),
    ):
        error = _angle_difference(configured, fitted)
        if error > angle_tolerance:
            warnings.append(
                f'{name} is {math.degrees(configured):.2f} deg but the floor says '
                f'{math.degrees(fitted):.2f} deg (off by {math.degrees(error):.2f} deg, '
                f'tolerance {math.degrees(angle_tolerance):.2f} deg)'
            )
    return warnings
