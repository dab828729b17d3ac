"""Planar robot motion: poses in the odometry frame, their history, and the moves between stamps.

A ground robot's odometry (REP-105 `odom -> base_link`) is planar: x, y and yaw. Between
two stamps the base moves by `PlanarPose.between`; seen from a sensor mounted on the
base, that move is `PlanarMotion`, the rigid transform in the sensor's own xy plane that
takes points measured at the earlier stamp to where they lie relative to the sensor at
the later one. Motion compensation (the depth frame to the scan's stamp) and LiDAR
de-skew (each beam to the scan's stamp) are both that transform applied to points.

`OdometryHistory` keeps recent samples, interpolates between them (linear in x, y and in
the shortest yaw difference), extrapolates at most `max_extrapolation` seconds past the
newest, and breaks the history at gaps and jumps (a reset or relocalisation), across which
no motion is known.
"""

from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING

import numpy as np

from scanfuse.errors import InputError

if TYPE_CHECKING:
    import numpy.typing as npt

    from scanfuse.transforms import Transform

    Matrix = npt.NDArray[np.float64]


def wrap_angle(angle: float) -> float:
    """`angle` in [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


@dataclass(frozen=True)
class PlanarPose:
    """A planar pose: position (metres) and heading (radians, counter-clockwise from +x)."""

    x: float
    y: float
    yaw: float

    def compose(self, other: PlanarPose) -> PlanarPose:
        """`other` (a pose in this pose's frame) in the frame this pose is in."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return PlanarPose(
            self.x + c * other.x - s * other.y,
            self.y + s * other.x + c * other.y,
            wrap_angle(self.yaw + other.yaw),
        )

    def inverse(self) -> PlanarPose:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return PlanarPose(-c * self.x - s * self.y, s * self.x - c * self.y, -self.yaw)

    def between(self, later: PlanarPose) -> PlanarPose:
        """The pose `later` seen from this one (both in one frame): this^-1 * later."""
        return self.inverse().compose(later)

    def matrix(self) -> Matrix:
        """The homogeneous 4 x 4 matrix (rotation about z, translation in xy)."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return np.array(
            [[c, -s, 0.0, self.x], [s, c, 0.0, self.y], [0.0, 0.0, 1.0, 0.0], [0.0, 0.0, 0.0, 1.0]]
        )

    def is_finite(self) -> bool:
        return math.isfinite(self.x) and math.isfinite(self.y) and math.isfinite(self.yaw)


@dataclass(frozen=True)
class PlanarMotion:
    """A rigid move in a sensor's xy plane: p' = R p + t with R = [[cos, -sin], [sin, cos]].

    Takes a point measured in the sensor frame at one stamp to the sensor frame at
    another stamp (the compensated position). The identity is `IDENTITY_MOTION`.
    """

    cos: float = 1.0
    sin: float = 0.0
    tx: float = 0.0
    ty: float = 0.0

    @property
    def is_identity(self) -> bool:
        return self.cos == 1.0 and self.sin == 0.0 and self.tx == 0.0 and self.ty == 0.0

    @property
    def angle(self) -> float:
        return math.atan2(self.sin, self.cos)

    @classmethod
    def of_base_move(cls, earlier_to_later: PlanarPose, base_to_sensor: Transform) -> PlanarMotion:
        """The sensor-frame motion of points when the base moved by `earlier_to_later`.

        `earlier_to_later` is the base's pose at the later stamp in the base frame of the
        earlier stamp. A point p in the sensor frame at the earlier stamp is at
        S^-1 M^-1 S p in the sensor frame at the later stamp (S: base -> sensor, M: the move).
        The sensor may be tilted or upside down: the xy block of that matrix is taken, which
        is exact for a sensor whose z axis is vertical (up or down).
        """
        sensor = base_to_sensor.matrix
        moved = np.linalg.inv(sensor) @ np.linalg.inv(earlier_to_later.matrix()) @ sensor
        return cls(
            cos=float(moved[0, 0]),
            sin=float(moved[1, 0]),
            tx=float(moved[0, 3]),
            ty=float(moved[1, 3]),
        )

    def apply(
        self, x: npt.NDArray[np.floating], y: npt.NDArray[np.floating]
    ) -> tuple[Matrix, Matrix]:
        """Points (x, y) moved."""
        x64, y64 = np.asarray(x, dtype=np.float64), np.asarray(y, dtype=np.float64)
        return (
            self.cos * x64 - self.sin * y64 + self.tx,
            self.sin * x64 + self.cos * y64 + self.ty,
        )


IDENTITY_MOTION = PlanarMotion()


class PoseQuery(str, Enum):
    """Why `OdometryHistory.pose_at` found no pose (or how it found one)."""

    INTERPOLATED = 'interpolated'
    EXTRAPOLATED = 'extrapolated'
    NO_ODOMETRY = 'no odometry yet'
    TOO_OLD = 'older than the odometry kept'
    TOO_NEW = 'past the newest odometry by more than max_odometry_extrapolation'
    ACROSS_BREAK = 'odometry jumped or paused between the two stamps'


@dataclass(frozen=True)
class PoseAt:
    """A pose found at a stamp, how, and in which unbroken stretch of odometry."""

    pose: PlanarPose | None
    how: PoseQuery
    segment: int  # stretches between breaks (jumps, gaps) count up; poses compare within one


class OdometryHistory:
    """Recent odometry samples (stamp ns, pose in odom), for poses at any stamp between them.

    A sample whose implied speed exceeds `max_speed` (m/s) or `max_turn_rate` (rad/s), or
    that follows the previous one by more than `max_gap` seconds, starts a new segment:
    poses are only compared within one segment. Samples older than `keep` seconds behind the
    newest are dropped; a sample older than the newest is ignored (counted in `out_of_order`).
    """

    def __init__(
        self,
        *,
        keep: float = 2.0,
        max_extrapolation: float = 0.1,
        max_gap: float = 0.5,
        max_speed: float = 10.0,
        max_turn_rate: float = 4.0 * math.pi,
    ) -> None:
        for name, value in (
            ('keep', keep),
            ('max_extrapolation', max_extrapolation),
            ('max_gap', max_gap),
            ('max_speed', max_speed),
            ('max_turn_rate', max_turn_rate),
        ):
            if not (math.isfinite(value) and value >= 0.0):
                msg = f'{name} must be a finite non-negative number, got {value}'
                raise InputError(msg)
        self.keep_ns = round(keep * 1e9)
        self.max_extrapolation_ns = round(max_extrapolation * 1e9)
        self.max_gap_ns = round(max_gap * 1e9)
        self.max_speed = max_speed
        self.max_turn_rate = max_turn_rate
        self._stamps: list[int] = []
        self._poses: list[PlanarPose] = []
        self._segments: list[int] = []
        self._segment = 0
        self.out_of_order = 0
        self.breaks = 0
        self.rejected = 0

    def __len__(self) -> int:
        return len(self._stamps)

    @property
    def newest_ns(self) -> int | None:
        return self._stamps[-1] if self._stamps else None

    def clear(self) -> None:
        self._stamps.clear()
        self._poses.clear()
        self._segments.clear()
        self._segment += 1

    def add(self, stamp_ns: int, pose: PlanarPose) -> bool:
        """Keep one sample; False (and nothing kept) for a non-finite or out-of-order one."""
        if not pose.is_finite():
            self.rejected += 1
            return False
        if self._stamps and stamp_ns <= self._stamps[-1]:
            if stamp_ns == self._stamps[-1]:
                # The same instant twice: /odom and TF odom -> base_link carry one estimate
                # (their quaternions may differ in the last bit). The first one stands.
                return True
            self.out_of_order += 1
            return False
        if self._stamps and self._breaks_from(self._stamps[-1], self._poses[-1], stamp_ns, pose):
            self._segment += 1
            self.breaks += 1
        self._stamps.append(stamp_ns)
        self._poses.append(pose)
        self._segments.append(self._segment)
        horizon = stamp_ns - self.keep_ns
        drop = bisect.bisect_left(self._stamps, horizon) - 1  # keep one sample before horizon
        if drop > 0:
            del self._stamps[:drop], self._poses[:drop], self._segments[:drop]
        return True

    def _breaks_from(
        self, stamp: int, pose: PlanarPose, new_stamp: int, new_pose: PlanarPose
    ) -> bool:
        dt = (new_stamp - stamp) / 1e9
        if new_stamp - stamp > self.max_gap_ns:
            return True
        distance = math.hypot(new_pose.x - pose.x, new_pose.y - pose.y)
        turn = abs(wrap_angle(new_pose.yaw - pose.yaw))
        return distance > self.max_speed * dt + 1e-9 or turn > self.max_turn_rate * dt + 1e-9

    def pose_at(self, stamp_ns: int) -> PoseAt:
        """The base's pose at `stamp_ns`, interpolated or (briefly) extrapolated."""
        stamps = self._stamps
        if not stamps:
            return PoseAt(None, PoseQuery.NO_ODOMETRY, self._segment)
        index = bisect.bisect_left(stamps, stamp_ns)
        if index < len(stamps) and stamps[index] == stamp_ns:
            return PoseAt(self._poses[index], PoseQuery.INTERPOLATED, self._segments[index])
        if index == 0:
            return PoseAt(None, PoseQuery.TOO_OLD, self._segments[0])
        if index == len(stamps):
            return self._extrapolate(stamp_ns)
        before, after = index - 1, index
        if self._segments[before] != self._segments[after]:
            return PoseAt(None, PoseQuery.ACROSS_BREAK, self._segments[after])
        fraction = (stamp_ns - stamps[before]) / (stamps[after] - stamps[before])
        return PoseAt(
            _lerp(self._poses[before], self._poses[after], fraction),
            PoseQuery.INTERPOLATED,
            self._segments[after],
        )

    def _extrapolate(self, stamp_ns: int) -> PoseAt:
        stamps, last = self._stamps, len(self._stamps) - 1
        if stamp_ns - stamps[last] > self.max_extrapolation_ns:
            return PoseAt(None, PoseQuery.TOO_NEW, self._segments[last])
        if last == 0 or self._segments[last - 1] != self._segments[last]:
            return PoseAt(self._poses[last], PoseQuery.EXTRAPOLATED, self._segments[last])
        fraction = (stamp_ns - stamps[last - 1]) / (stamps[last] - stamps[last - 1])
        return PoseAt(
            _lerp(self._poses[last - 1], self._poses[last], fraction),
            PoseQuery.EXTRAPOLATED,
            self._segments[last],
        )

    def move_between(self, earlier_ns: int, later_ns: int) -> tuple[PlanarPose | None, PoseQuery]:
        """The base's pose at `later_ns` in its own frame at `earlier_ns`, or why not known."""
        first, second = self.pose_at(earlier_ns), self.pose_at(later_ns)
        for found in (first, second):
            if found.pose is None:
                return None, found.how
        assert first.pose is not None
        assert second.pose is not None
        if first.segment != second.segment:
            return None, PoseQuery.ACROSS_BREAK
        how = (
            PoseQuery.EXTRAPOLATED
            if PoseQuery.EXTRAPOLATED in (first.how, second.how)
            else PoseQuery.INTERPOLATED
        )
        return first.pose.between(second.pose), how


def _lerp(a: PlanarPose, b: PlanarPose, fraction: float) -> PlanarPose:
    return PlanarPose(
        a.x + (b.x - a.x) * fraction,
        a.y + (b.y - a.y) * fraction,
        wrap_angle(a.yaw + wrap_angle(b.yaw - a.yaw) * fraction),
    )
