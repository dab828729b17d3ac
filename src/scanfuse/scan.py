"""`Scan`, the twin of `sensor_msgs/LaserScan`, and REP-117 helpers.

REP-117 range semantics used throughout scanfuse:
+Inf: no return within range (free space), -Inf: object too close to measure,
NaN: no valid measurement (no information).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np

from scanfuse.errors import InputError

if TYPE_CHECKING:
    import numpy.typing as npt

    FloatArray = npt.NDArray[np.float32]
    AngleArray = npt.NDArray[np.float64]

TWO_PI = 2.0 * math.pi
# Limits of the numbers of a LaserScan that size what scanfuse allocates for it (its own
# readings, a 360-degree grid of its increment, the obstacle memory's projection of a turn):
# beyond them a scan is malformed (`check_scan_limits`). 2^17 readings a turn is an
# increment of 0.0027 degrees, ten times finer than any scanner's.
MAX_READINGS = 1 << 17
MAX_SCAN_ANGLE = 4.0 * math.pi  # radians either way: two turns
MAX_TIME_INCREMENT = 1.0  # seconds between two beams


@dataclass(frozen=True)
class Scan:
    """A planar range scan with the fields of `sensor_msgs/LaserScan`.

    `ranges[i]` is measured at `angle_min + i * angle_increment` (radians,
    counter-clockwise about +z of `frame_id`, REP-103). `angle_increment` may be
    negative (a LiDAR that sweeps clockwise).
    """

    angle_min: float
    angle_max: float
    angle_increment: float
    range_min: float
    range_max: float
    ranges: FloatArray
    time_increment: float = 0.0
    scan_time: float = 0.0
    intensities: FloatArray | None = None
    frame_id: str = ''
    stamp_ns: int = 0

    def __post_init__(self) -> None:
        ranges = np.asarray(self.ranges)
        if ranges.ndim != 1:
            msg = f'Scan.ranges must be one-dimensional, got shape {ranges.shape}'
            raise InputError(msg)
        if ranges.dtype != np.float32:
            ranges = ranges.astype(np.float32)
        object.__setattr__(self, 'ranges', ranges)
        if self.intensities is not None:
            intensities = np.asarray(self.intensities, dtype=np.float32)
            if intensities.size and intensities.shape != ranges.shape:
                msg = (
                    f'Scan.intensities has {intensities.size} values for {ranges.size} ranges; '
                    'give one intensity per range or none'
                )
                raise InputError(msg)
            object.__setattr__(self, 'intensities', intensities)
        if not math.isfinite(self.angle_increment) or self.angle_increment == 0.0:
            msg = f'Scan.angle_increment must be finite and non-zero, got {self.angle_increment}'
            raise InputError(msg)
        if not (math.isfinite(self.angle_min) and math.isfinite(self.angle_max)):
            # A NaN angle also makes every grid unequal to itself (a cache miss per scan).
            msg = (
                f'Scan.angle_min and angle_max must be finite radians, got {self.angle_min} and '
                f'{self.angle_max}; the driver publishes a malformed LaserScan'
            )
            raise InputError(msg)
        # range_max may be +Inf (a driver with no upper limit); NaN limits mean nothing.
        if not math.isfinite(self.range_min) or not self.range_min <= self.range_max:
            msg = (
                f'Scan.range_min must be finite and at most range_max, got {self.range_min} and '
                f'{self.range_max}; the driver publishes a malformed LaserScan'
            )
            raise InputError(msg)

    def __len__(self) -> int:
        return int(self.ranges.size)

    def angles(self) -> AngleArray:
        """Angle of every reading, radians (float64)."""
        return self.angle_min + self.angle_increment * np.arange(self.ranges.size, dtype=np.float64)

    @cached_property
    def grid(self) -> AngleGrid:
        """The angular grid of this scan."""
        return AngleGrid(self.angle_min, self.angle_increment, self.ranges.size)

    def with_ranges(self, ranges: FloatArray, **changes: object) -> Scan:
        """A copy with new ranges (same length) and optionally other fields changed."""
        return replace(self, ranges=ranges, **changes)  # type: ignore[arg-type]


@dataclass(frozen=True)
class AngleGrid:
    """The angular layout of a scan: where reading `i` points."""

    angle_min: float
    angle_increment: float
    count: int

    def __post_init__(self) -> None:
        if self.count <= 0:
            msg = f'an angle grid needs at least one reading, got count={self.count}'
            raise InputError(msg)
        if not math.isfinite(self.angle_increment) or self.angle_increment == 0.0:
            msg = f'angle_increment must be finite and non-zero, got {self.angle_increment}'
            raise InputError(msg)
        if not math.isfinite(self.angle_min):
            msg = f'angle_min must be finite, got {self.angle_min}'
            raise InputError(msg)

    @property
    def angle_max(self) -> float:
        return self.angle_min + self.angle_increment * (self.count - 1)

    @property
    def full_turn(self) -> bool:
        """The slots go all the way round: the last one's neighbour is the first."""
        step = abs(self.angle_increment)
        return self.count * step >= TWO_PI - 0.5 * step

    def angles(self) -> AngleArray:
        return self._angles

    @cached_property
    def _angles(self) -> AngleArray:
        # Built on first use: grids are made per scan (as dictionary keys) far more often.
        angles = self.angle_min + self.angle_increment * np.arange(self.count, dtype=np.float64)
        angles.setflags(write=False)
        return angles

    def slot_of(self, angle: AngleArray) -> npt.NDArray[np.int64]:
        """Index of the slot whose interval (centre +- increment/2) holds `angle`; -1 if none.

        Works for any angle convention ([-pi, pi], [0, 2 pi)) and either sign of the
        increment: the angle is wrapped into the turn that starts half a slot before
        `angle_min`.
        """
        offset = np.mod(angle - self.angle_min + 0.5 * self.angle_increment, TWO_PI)
        if self.angle_increment < 0.0:
            # Sweeping clockwise: measure the offset the other way round the circle.
            offset = np.mod(-(angle - self.angle_min) - 0.5 * self.angle_increment, TWO_PI)
        index = np.floor(offset / abs(self.angle_increment)).astype(np.int64)
        index[index >= self.count] = -1
        return index


def check_scan_limits(scan: Scan) -> None:
    """Refuse (InputError) a scan whose numbers would size allocations without bound or
    break the arithmetic of a turn: more than MAX_READINGS readings, or a turn of them; an
    increment beyond a turn; angles beyond MAX_SCAN_ANGLE; a time_increment that is not a
    finite number of at most MAX_TIME_INCREMENT seconds."""
    step = abs(scan.angle_increment)
    problems = []
    if len(scan) > MAX_READINGS:
        problems.append(f'{len(scan)} readings (at most {MAX_READINGS})')
    if step > TWO_PI:
        problems.append(f'angle_increment {scan.angle_increment:g} rad is more than a turn')
    elif TWO_PI / step > MAX_READINGS:
        problems.append(
            f'angle_increment {scan.angle_increment:g} rad makes {TWO_PI / step:.3g} readings '
            f'a turn (at most {MAX_READINGS})'
        )
    if max(abs(scan.angle_min), abs(scan.angle_max)) > MAX_SCAN_ANGLE:
        problems.append(
            f'angle_min {scan.angle_min:g} and angle_max {scan.angle_max:g} rad are not both '
            f'within +-{MAX_SCAN_ANGLE:.4g} rad (two turns)'
        )
    if not abs(scan.time_increment) <= MAX_TIME_INCREMENT:
        problems.append(
            f'time_increment {scan.time_increment:g} s is not a number of at most '
            f'{MAX_TIME_INCREMENT:g} s'
        )
    if problems:
        msg = f'{"; ".join(problems)}; the driver publishes a malformed LaserScan'
        raise InputError(msg)


def full_circle(scan: Scan) -> Scan | None:
    """`scan` on a 360-degree grid of its own increment, NaN where it has no reading.

    Its readings keep their exact angles (the grid is shifted by whole increments to start
    within one increment of -pi, or of +pi for a clockwise scan), so nothing is resampled:
    another source can fill the field of view this LiDAR lacks (a 270-degree scanner's
    90 degrees behind it). None when the scan covers the circle already.
    """
    step = abs(scan.angle_increment)
    count = math.floor(TWO_PI / step + 1e-9)
    if len(scan) >= count:
        return None
    sign = 1.0 if scan.angle_increment > 0.0 else -1.0
    # Whole increments between the scan's first angle and the circle's start.
    shift = math.floor((sign * scan.angle_min + math.pi) / step + 1e-9)
    # A grid beyond +-pi: keep every reading, start earlier (or, beyond -pi, where it starts).
    shift = min(max(shift, 0), count - len(scan))
    angle_min = scan.angle_min - sign * shift * step
    ranges = np.full(count, np.nan, dtype=np.float32)
    ranges[shift : shift + len(scan)] = scan.ranges
    intensities = None
    if scan.intensities is not None and scan.intensities.size:
        intensities = np.zeros(count, dtype=np.float32)
        intensities[shift : shift + len(scan)] = scan.intensities
    return replace(
        scan,
        angle_min=angle_min,
        angle_max=angle_min + scan.angle_increment * (count - 1),
        ranges=ranges,
        intensities=intensities,
        # The readings moved by `shift` places: the beams' times are the de-skew's to use
        # (the stream widens after it), not the published message's.
        time_increment=0.0,
    )


def normalized_ranges(scan: Scan) -> FloatArray:
    """Ranges with every finite value that is not a real reading turned into NaN.

    A real reading lies inside the scan's own [range_min, range_max] and is positive:
    no sensor measures its own origin, and drivers write 0 for a failed return (the
    Hokuyo URG recording in the tests: 35 of 681 readings a scan on average), which a
    published range_min of 0 would otherwise let through. Other error values (below
    range_min, a code past range_max) say nothing about the scene either, so they
    become NaN, not +-Inf: a LaserScan has no field telling "too close" from "no
    return", and a driver that means "too close" publishes -Inf (REP-117). +-Inf and
    NaN keep their REP-117 meaning.
    """
    ranges = scan.ranges
    # Comparisons with NaN are False without a warning, so NaN and +-Inf stay.
    real = (ranges >= scan.range_min) & (ranges <= scan.range_max) & (ranges > 0.0)
    return np.where(real | np.isinf(ranges), ranges, np.float32(np.nan))


def to_rep117(values: FloatArray, range_min: float, range_max: float) -> FloatArray:
    """Map raw ranges to REP-117: above range_max -> +Inf, below range_min -> -Inf.

    NaN stays NaN (no valid measurement). Values in range are unchanged.
    """
    with np.errstate(invalid='ignore'):
        out = np.where(values > range_max, np.float32(np.inf), values)
        return np.where(out < range_min, np.float32(-np.inf), out).astype(np.float32, copy=False)
