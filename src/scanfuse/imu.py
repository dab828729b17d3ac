"""The body's tilt from an IMU: pitch and roll of the base between depth frames.

A robot rocks faster than a camera's frames (braking, a caster over a sill); an IMU's
orientation (sensor_msgs/Imu, REP-145: the IMU frame's attitude in a frame whose z is up
against gravity) says how the base is tilted at a depth frame's stamp. The floor is then
expected where the mounting, so tilted, puts it: the ground estimate's prior, or the
ground itself with the estimate off. Yaw is not used (odometry has it).

On a ramp an IMU gives the slope, not the floor under the wheels: the ground estimate
(bounded near the tilted prior) finds the ramp's plane again.
"""

from __future__ import annotations

import bisect
import functools
import math
from collections import deque
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from scanfuse.errors import InputError
from scanfuse.transforms import Transform

if TYPE_CHECKING:
    import numpy.typing as npt

    F64 = npt.NDArray[np.float64]

# Orientations whose quaternion's norm is this far from 1 are refused (a driver's float
# rounding is far less; a zero quaternion is REP-145's "no orientation").
QUATERNION_NORM_TOLERANCE = 0.05
# Samples kept: 2 s of a 200 Hz IMU.
MAX_SAMPLES = 400
# The most an IMU sample may lie from a depth frame's stamp and still tell its tilt.
MAX_AGE_NS = 50_000_000
# Samples this near a depth frame's stamp are averaged (at 100-200 Hz, 5-9 of them).
AVERAGE_NS = 20_000_000
# Tilts beyond this are no floor a robot drives on: the orientation is refused.
MAX_TILT = math.radians(45.0)
# A LiDAR's sweep is given the IMU's tilt at this many stamps across it (`tilts_over`), each
# beam's interpolated between: a sprung body rocks 2-5 degrees within one 0.1 s sweep of a
# 10 Hz LiDAR (the simulator's, over a ramp's foot and crest and setting off on one).
SWEEP_SAMPLES = 9


@dataclass(frozen=True)
class ImuSample:
    stamp_ns: int
    tilt: Transform  # the base's roll and pitch against gravity, yaw 0

    @functools.cached_property
    def roll_pitch(self) -> tuple[float, float]:
        roll, pitch, _ = self.tilt.rpy()
        return roll, pitch


def base_tilt(orientation: tuple[float, float, float, float], base_to_imu: Transform) -> Transform:
    """The base's roll and pitch (a rotation, yaw 0) from the IMU frame's orientation
    (x, y, z, w) and the IMU's mounting on the base; InputError for an unusable one.

    Remembered for the last few samples: streams fed the same IMU (the evaluation runs one
    per method) each ask for the same tilt.
    """
    x, y, z, w = orientation
    return _base_tilt((float(x), float(y), float(z), float(w)), base_to_imu)


@functools.lru_cache(maxsize=64)
def _base_tilt(orientation: tuple[float, float, float, float], base_to_imu: Transform) -> Transform:
    values = np.asarray(orientation, dtype=np.float64)
    norm = float(np.linalg.norm(values)) if np.isfinite(values).all() else math.nan
    if not abs(norm - 1.0) <= QUATERNION_NORM_TOLERANCE:
        msg = (
            f'IMU orientation {tuple(orientation)} is not a unit quaternion (norm {norm:.3g}); '
            'an IMU without orientation (REP-145: all zero, covariance[0] = -1) gives no tilt'
        )
        raise InputError(msg)
    x, y, z, w = (float(v) for v in values / norm)
    world_to_base = Transform(rotation=(x, y, z, w)) @ base_to_imu.inverse()
    roll, pitch, _ = world_to_base.rpy()
    if max(abs(roll), abs(pitch)) > MAX_TILT:
        msg = (
            f'IMU says the base is rolled {math.degrees(roll):.1f} deg and pitched '
            f'{math.degrees(pitch):.1f} deg, beyond {math.degrees(MAX_TILT):.0f} deg: check '
            "the IMU's frame and its mounting on the base"
        )
        raise InputError(msg)
    return Transform.from_rpy(roll, pitch, 0.0)


class ImuHistory:
    """Recent tilts of the base, by stamp; `tilt_at` the nearest within `MAX_AGE_NS`."""

    def __init__(self) -> None:
        self._samples: deque[ImuSample] = deque(maxlen=MAX_SAMPLES)

    def __len__(self) -> int:
        return len(self._samples)

    def add(self, stamp_ns: int, tilt: Transform) -> None:
        """A new tilt; one older than the newest is dropped (an IMU's stamps ascend)."""
        if self._samples and stamp_ns < self._samples[-1].stamp_ns:
            return
        self._samples.append(ImuSample(stamp_ns, tilt))

    def tilt_at(self, stamp_ns: int) -> Transform | None:
        """The mean roll and pitch of the samples within AVERAGE_NS of `stamp_ns` (an IMU's
        noise, not the body's rocking, changes within it), else of the nearest one; None when
        none is within MAX_AGE_NS (no IMU, or it stopped)."""
        if not self._samples:
            return None
        angles = self._roll_pitch_at([sample.stamp_ns for sample in self._samples], stamp_ns)
        return None if angles is None else Transform.from_rpy(*angles, 0.0)

    def tilts_over(self, stamps_ns: npt.NDArray[np.int64]) -> F64 | None:
        """The base's tilt (N x 3 x 3: base to a level frame of its heading, as `tilt_at`'s)
        at each of `stamps_ns` (the beams of one LiDAR sweep): `tilt_at`'s roll and pitch at
        `SWEEP_SAMPLES` stamps across them, interpolated between; None when one of those has
        no sample within MAX_AGE_NS."""
        if not self._samples or not stamps_ns.size:
            return None
        stamps = [sample.stamp_ns for sample in self._samples]
        first, last = int(stamps_ns.min()), int(stamps_ns.max())
        at = np.linspace(first, last, SWEEP_SAMPLES if last > first else 1)
        angles = [self._roll_pitch_at(stamps, round(float(t))) for t in at]
        if any(a is None for a in angles):
            return None
        roll_pitch = np.array(angles, dtype=np.float64)
        times = stamps_ns.astype(np.float64)
        roll = np.interp(times, at, roll_pitch[:, 0])
        pitch = np.interp(times, at, roll_pitch[:, 1])
        return tilt_matrices(roll, pitch)

    def _roll_pitch_at(self, stamps: list[int], stamp_ns: int) -> tuple[float, float] | None:
        """`tilt_at`'s roll and pitch (radians); `stamps` the samples' stamps."""
        index = bisect.bisect_left(stamps, stamp_ns)
        nearest = min(
            (i for i in (index - 1, index) if 0 <= i < len(stamps)),
            key=lambda i: abs(stamps[i] - stamp_ns),
        )
        if abs(stamps[nearest] - stamp_ns) > MAX_AGE_NS:
            return None
        first = bisect.bisect_left(stamps, stamp_ns - AVERAGE_NS)
        last = bisect.bisect_right(stamps, stamp_ns + AVERAGE_NS)
        near = [self._samples[i].roll_pitch for i in range(first, last)] or [
            self._samples[nearest].roll_pitch
        ]
        roll = sum(angles[0] for angles in near) / len(near)
        pitch = sum(angles[1] for angles in near) / len(near)
        return roll, pitch


def tilt_matrices(roll: F64, pitch: F64) -> F64:
    """N rotations (N x 3 x 3) of `Transform.from_rpy(roll, pitch, 0)`: Ry(pitch) Rx(roll)."""
    cr, sr, cp, sp = np.cos(roll), np.sin(roll), np.cos(pitch), np.sin(pitch)
    matrices = np.zeros((roll.size, 3, 3))
    matrices[:, 0, 0], matrices[:, 0, 1], matrices[:, 0, 2] = cp, sp * sr, sp * cr
    matrices[:, 1, 1], matrices[:, 1, 2] = cr, -sr
    matrices[:, 2, 0], matrices[:, 2, 1], matrices[:, 2, 2] = -sp, cp * sr, cp * cr
    return matrices
