"""Rigid transforms (REP-103) and the extrinsics of the depth camera and the LiDAR.

Conventions (REP-103, REP-105):

- body frames (base_link, laser, camera_link): x forward, y left, z up;
- camera optical frames: z forward, x right, y down;
- quaternions are stored as (x, y, z, w), the order of `geometry_msgs/Quaternion`;
- roll, pitch, yaw are rotations about the fixed x, y, z axes applied in that
  order, R = Rz(yaw) Ry(pitch) Rx(roll), as in tf2's `setRPY`. A positive pitch
  turns the body's x axis towards -z: it looks down.

A `Transform` named `a_to_b` is the pose of frame b in frame a (TF parent a,
child b): `a_to_b.apply(points_in_b)` gives the same points in frame a.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from scanfuse.errors import TransformError
from scanfuse.sources import MAX_MOUNTING_OFFSET

if TYPE_CHECKING:
    from collections.abc import Iterable

    import numpy.typing as npt

    from scanfuse.config import FusionConfig

    Matrix = npt.NDArray[np.float64]

Quaternion = tuple[float, float, float, float]
Vector3 = tuple[float, float, float]

_NORM_TOLERANCE = 1e-6
# No frame of a robot's TF tree is this far from its parent (UTM northings stay below 1e7 m),
# and the float32 arithmetic of the conversions stays far from overflow below it.
MAX_TRANSLATION = 1.0e9
# A sensor further than this from the base frame is a typo or a corrupt transform, not a
# mounting (the bound of the `camera_*` and `lidar_*` parameters too).


def _quaternion_to_matrix(q: Quaternion) -> Matrix:
    x, y, z, w = q
    return np.array(
        [
            [1.0 - 2.0 * (y * y + z * z), 2.0 * (x * y - z * w), 2.0 * (x * z + y * w)],
            [2.0 * (x * y + z * w), 1.0 - 2.0 * (x * x + z * z), 2.0 * (y * z - x * w)],
            [2.0 * (x * z - y * w), 2.0 * (y * z + x * w), 1.0 - 2.0 * (x * x + y * y)],
        ],
        dtype=np.float64,
    )


def _matrix_to_quaternion(rotation: Matrix) -> Quaternion:
    """Shepperd's method: branch on the largest diagonal term for numerical stability."""
    m = rotation
    trace = m[0, 0] + m[1, 1] + m[2, 2]
    if trace > 0.0:
        s = 2.0 * math.sqrt(1.0 + trace)
        q = ((m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4)
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = (s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s)
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = ((m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s)
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = ((m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4, (m[1, 0] - m[0, 1]) / s)
    return (float(q[0]), float(q[1]), float(q[2]), float(q[3]))


@dataclass(frozen=True)
class Transform:
    """A rigid transform: rotation quaternion (x, y, z, w) and translation, metres.

    Frozen and hashable (the pipeline caches work per extrinsics); the 4x4 matrix
    is computed on first use.
    """

    rotation: Quaternion = (0.0, 0.0, 0.0, 1.0)
    translation: Vector3 = (0.0, 0.0, 0.0)

    def __post_init__(self) -> None:
        if len(self.rotation) != 4 or len(self.translation) != 3:
            msg = (
                f'a transform needs a 4-value quaternion (x, y, z, w) and a 3-value translation, '
                f'got {len(self.rotation)} and {len(self.translation)} values'
            )
            raise TransformError(msg)
        values = (*self.rotation, *self.translation)
        if not all(math.isfinite(value) for value in values):
            msg = f'transform values must be finite, got rotation {self.rotation}, '
            msg += f'translation {self.translation}'
            raise TransformError(msg)
        if max(abs(value) for value in self.translation) > MAX_TRANSLATION:
            msg = (
                f'transform translation {self.translation} is more than {MAX_TRANSLATION:g} m '
                'from its parent frame; the transform is corrupt'
            )
            raise TransformError(msg)
        # Scaled by the largest value first: squaring 1e300 would overflow the norm to Inf
        # (and the quaternion to zero), squaring 1e-170 underflow it.
        largest = max(abs(float(value)) for value in self.rotation)
        scaled = [float(value) / largest for value in self.rotation] if largest else [0.0] * 4
        unit_norm = math.sqrt(sum(value * value for value in scaled))
        if largest * unit_norm < _NORM_TOLERANCE:
            msg = f'rotation quaternion {self.rotation} has zero length; use (0, 0, 0, 1) for none'
            raise TransformError(msg)
        # One canonical sign (w >= 0): q and -q are the same rotation and must hash equal.
        sign = -1.0 if self.rotation[3] < 0.0 else 1.0
        rotation = tuple(sign * value / unit_norm for value in scaled)
        object.__setattr__(self, 'rotation', rotation)
        object.__setattr__(self, 'translation', tuple(float(v) for v in self.translation))

    @classmethod
    def identity(cls) -> Transform:
        return cls()

    @classmethod
    def from_quaternion(
        cls, quaternion: Iterable[float], translation: Iterable[float] = (0.0, 0.0, 0.0)
    ) -> Transform:
        """From a quaternion in ROS order (x, y, z, w); it is normalised."""
        q = tuple(float(v) for v in quaternion)
        t = tuple(float(v) for v in translation)
        return cls(q, t)  # type: ignore[arg-type]

    @classmethod
    def from_rpy(
        cls,
        roll: float,
        pitch: float,
        yaw: float,
        translation: Iterable[float] = (0.0, 0.0, 0.0),
    ) -> Transform:
        """R = Rz(yaw) Ry(pitch) Rx(roll), as tf2's `Quaternion::setRPY`."""
        cr, sr = math.cos(roll / 2), math.sin(roll / 2)
        cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
        cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
        quaternion = (
            sr * cp * cy - cr * sp * sy,
            cr * sp * cy + sr * cp * sy,
            cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy,
        )
        return cls.from_quaternion(quaternion, translation)

    @classmethod
    def from_matrix(cls, matrix: npt.ArrayLike) -> Transform:
        """From a 4x4 homogeneous matrix (or a 3x4 one) whose 3x3 block is a rotation."""
        m = np.asarray(matrix, dtype=np.float64)
        if m.shape not in ((4, 4), (3, 4)):
            msg = f'a transform matrix must be 4x4 or 3x4, got shape {m.shape}'
            raise TransformError(msg)
        rotation = m[:3, :3]
        if (
            not np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-6)
            or np.linalg.det(rotation) <= 0.0
        ):
            msg = 'the 3x3 block of a transform matrix must be a rotation (orthonormal, det +1)'
            raise TransformError(msg)
        return cls.from_quaternion(_matrix_to_quaternion(rotation), m[:3, 3])

    @cached_property
    def rotation_matrix(self) -> Matrix:
        """The 3x3 rotation matrix (read-only)."""
        matrix = _quaternion_to_matrix(self.rotation)
        matrix.setflags(write=False)
        return matrix

    @cached_property
    def matrix(self) -> Matrix:
        """The 4x4 homogeneous matrix (read-only)."""
        matrix = np.eye(4, dtype=np.float64)
        matrix[:3, :3] = self.rotation_matrix
        matrix[:3, 3] = self.translation
        matrix.setflags(write=False)
        return matrix

    def rpy(self) -> tuple[float, float, float]:
        """(roll, pitch, yaw) with R = Rz(yaw) Ry(pitch) Rx(roll); pitch in [-pi/2, pi/2]."""
        m = self.rotation_matrix
        pitch = math.asin(max(-1.0, min(1.0, -m[2, 0])))
        roll = math.atan2(m[2, 1], m[2, 2])
        yaw = math.atan2(m[1, 0], m[0, 0])
        return roll, pitch, yaw

    def compose(self, other: Transform) -> Transform:
        """`self` then `other`: a_to_b.compose(b_to_c) is a_to_c."""
        x1, y1, z1, w1 = self.rotation
        x2, y2, z2, w2 = other.rotation
        quaternion = (
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        )
        translation = self.rotation_matrix @ np.asarray(other.translation) + self.translation
        return Transform.from_quaternion(quaternion, translation)

    def __matmul__(self, other: Transform) -> Transform:
        return self.compose(other)

    def inverse(self) -> Transform:
        """b_to_a from a_to_b (computed on first use: per-message work asks for it)."""
        return self._inverse

    @cached_property
    def _inverse(self) -> Transform:
        x, y, z, w = self.rotation
        translation = -(self.rotation_matrix.T @ np.asarray(self.translation))
        return Transform.from_quaternion((-x, -y, -z, w), translation)

    def apply(self, points: npt.ArrayLike) -> Matrix:
        """Points (N, 3) or one point (3,) of the child frame, expressed in the parent frame."""
        array = np.asarray(points, dtype=np.float64)
        if array.shape[-1:] != (3,) or array.ndim > 2:
            msg = f'points must be shaped (N, 3) or (3,), got {array.shape}'
            raise TransformError(msg)
        result: Matrix = array @ self.rotation_matrix.T + np.asarray(self.translation)
        return result


# Pose of the optical frame (z forward, x right, y down) in its body frame
# (x forward, y left, z up): optical z = body x, optical x = body -y, optical y = body -z.
# Same as tf2's setRPY(-pi/2, 0, -pi/2), the static transform of every ROS camera driver.
BODY_TO_OPTICAL = Transform.from_quaternion((-0.5, 0.5, -0.5, 0.5))


@dataclass(frozen=True)
class Extrinsics:
    """Where the LiDAR and the depth camera sit on the robot.

    The base frame's z = 0 plane is the floor (heights of the collision slab are
    measured from it).
    """

    base_to_laser: Transform = Transform()
    """Pose of the LiDAR in the base frame (TF parent base_link, child laser)."""
    base_to_camera_optical: Transform = BODY_TO_OPTICAL
    """Pose of the camera's optical frame in the base frame."""

    def __post_init__(self) -> None:
        for name in ('base_to_laser', 'base_to_camera_optical'):
            translation = getattr(self, name).translation
            if max(abs(value) for value in translation) > MAX_MOUNTING_OFFSET:
                sensor = 'LiDAR' if name == 'base_to_laser' else 'depth camera'
                msg = (
                    f'the {sensor} is mounted at {translation} m in the base frame, more than '
                    f'{MAX_MOUNTING_OFFSET:g} m from it along an axis; check the mounting '
                    'parameters or the transforms on /tf_static'
                )
                raise TransformError(msg)

    @property
    def laser_to_camera_optical(self) -> Transform:
        """Pose of the camera's optical frame in the LiDAR frame."""
        return self.base_to_laser.inverse() @ self.base_to_camera_optical

    @classmethod
    def from_mounting(
        cls,
        *,
        camera_x: float = 0.0,
        camera_y: float = 0.0,
        camera_height: float,
        camera_roll: float = 0.0,
        camera_pitch: float = 0.0,
        camera_yaw: float = 0.0,
        lidar_x: float = 0.0,
        lidar_y: float = 0.0,
        lidar_height: float = 0.0,
        lidar_roll: float = 0.0,
        lidar_pitch: float = 0.0,
        lidar_yaw: float = 0.0,
    ) -> Extrinsics:
        """From positions in the base frame and the camera body's roll, pitch, yaw.

        `camera_pitch` is positive when the camera looks down, `camera_yaw`
        positive when it looks left (REP-103); a LiDAR with roll pi is mounted upside down.
        """
        camera_body = Transform.from_rpy(
            camera_roll, camera_pitch, camera_yaw, (camera_x, camera_y, camera_height)
        )
        laser = Transform.from_rpy(
            lidar_roll, lidar_pitch, lidar_yaw, (lidar_x, lidar_y, lidar_height)
        )
        return cls(base_to_laser=laser, base_to_camera_optical=camera_body @ BODY_TO_OPTICAL)

    @classmethod
    def from_config(cls, config: FusionConfig) -> Extrinsics:
        """The mounting given by the `camera_*` and `lidar_*` parameters."""
        return cls.from_mounting(
            camera_x=config.camera_x,
            camera_y=config.camera_y,
            camera_height=config.camera_height,
            camera_roll=config.camera_roll,
            camera_pitch=config.camera_pitch,
            camera_yaw=config.camera_yaw,
            lidar_x=config.lidar_x,
            lidar_y=config.lidar_y,
            lidar_height=config.lidar_height,
            lidar_roll=config.lidar_roll,
            lidar_pitch=config.lidar_pitch,
            lidar_yaw=config.lidar_yaw,
        )
