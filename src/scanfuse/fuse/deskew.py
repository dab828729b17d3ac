"""LiDAR de-skew: every beam of a rotating scanner moved to the scan's stamp.

A rotating LiDAR measures beam i at `stamp + i * time_increment` (sensor_msgs/LaserScan);
while it sweeps (about 0.1 s) the robot moves, so the beams of one scan are taken from
different poses: at 1.5 rad/s the last beam of a 0.1 s sweep is 8.6 degrees off. Each
beam's point is moved by its own `PlanarMotion` (from the sensor at its time to the sensor
at the stamp) and the scan is laid out again on its own grid.

Laying out again: beam i lands at the continuous slot position u_i of its moved bearing. A
slot gets the nearest (REP-117 order, NaN never hiding a reading: `np.fmin`) of the beams
landing in it; a slot no beam lands in (the sweep stretched) gets the nearer of the two
beams either side of it where both lie on one surface (`_one_surface`), never an
interpolation. Across a depth edge it stays NaN (no reading): at 0.35 m/s, 75 ms into a
sweep, the beams of a post 0.6 m to the side move 2.5 degrees and those of a wall 1.3 m away
1.2, and the slots between them were measured by no beam (the wall there was hidden when the
beams were taken; the post's edge is where its own beams landed). Beams without a point
(+-Inf, NaN) keep their value and only turn with the motion.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from scanfuse.scan import TWO_PI, Scan, normalized_ranges, to_rep117

if TYPE_CHECKING:
    import numpy.typing as npt

    F64 = npt.NDArray[np.float64]

# Two points lie on one surface when no farther apart than a surface seen at this
# incidence, or steeper, would put them, plus three sigma of a LiDAR's range noise: the
# adaptive breakpoint detector (Borges and Aldon 2004, their lambda and sigma_r).
BREAKPOINT_INCIDENCE = math.radians(10.0)
BREAKPOINT_NOISE = 0.01  # metres, one sigma


def deskew_scan(scan: Scan, angle: F64, tx: F64, ty: F64) -> Scan:
    """`scan` with beam i moved by the rotation `angle[i]` and translation (tx[i], ty[i]).

    The motions take each beam's point from the sensor frame at its measurement time to
    the sensor frame at `scan.stamp_ns`. Length, grid and header stay.
    """
    count = len(scan)
    ranges = normalized_ranges(scan).astype(np.float64)
    bearings = scan.angles()
    finite = np.isfinite(ranges)
    reach = np.where(finite, ranges, 0.0)
    x, y = reach * np.cos(bearings), reach * np.sin(bearings)
    cos, sin = np.cos(angle), np.sin(angle)
    moved_x = cos * x - sin * y + tx
    moved_y = sin * x + cos * y + ty
    moved_range = np.where(finite, np.hypot(moved_x, moved_y), ranges)
    turned = np.where(
        finite, np.arctan2(moved_y, moved_x) - bearings, angle
    )  # how far each beam's bearing moved
    turned = np.mod(turned + np.pi, TWO_PI) - np.pi
    position = np.arange(count) + turned / scan.angle_increment
    slot = np.rint(position).astype(np.int64)
    fills_turn = abs(count * scan.angle_increment) >= TWO_PI - abs(scan.angle_increment) / 2
    if fills_turn:
        slot = np.mod(slot, count)
    out = np.full(count, np.nan)
    inside = (slot >= 0) & (slot < count)
    np.fmin.at(out, slot[inside], moved_range[inside])

    # Slots no beam landed in: the nearer of the beams either side (positions ascend
    # with the beam index for any motion slower than the sweep itself).
    empty = np.flatnonzero(np.bincount(slot[inside], minlength=count) == 0)
    if empty.size:
        ascending = np.maximum.accumulate(position)
        after = np.searchsorted(ascending, empty, side='left')
        has_both = (after > 0) & (after < count)
        before = np.clip(after - 1, 0, count - 1)
        after = np.clip(after, 0, count - 1)
        near, far = moved_range[before], moved_range[after]
        apart = (position[after] - position[before]) * abs(scan.angle_increment)
        fill = has_both & _one_surface(near, far, apart)
        out[empty[fill]] = np.fmin(near, far)[fill]
    # A moved point may leave the sensor's limits: REP-117 says how to report it then.
    return scan.with_ranges(to_rep117(out.astype(np.float32), scan.range_min, scan.range_max))


def _one_surface(first: F64, second: F64, apart: F64) -> npt.NDArray[np.bool_]:
    """Whether two beams' points, at ranges `first` and `second` and `apart` radians apart,
    lie on one surface (module doc); two equal readings without a point (+Inf: nothing in
    range either side) count as one too, NaN never."""
    with np.errstate(invalid='ignore'):
        gap = np.sqrt(first**2 + second**2 - 2.0 * first * second * np.cos(apart))
        steepest = BREAKPOINT_INCIDENCE - apart
        reach = np.fmin(first, second) * np.sin(apart) / np.sin(np.maximum(steepest, 1e-9))
        near = (steepest > 0.0) & (gap <= reach + 3.0 * BREAKPOINT_NOISE)
        same: npt.NDArray[np.bool_] = near | (first == second)
    return same
