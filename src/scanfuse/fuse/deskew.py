"""LiDAR de-skew: every beam of a rotating scanner moved to the scan's stamp.

A rotating LiDAR measures beam i at `stamp + i * time_increment` (sensor_msgs/LaserScan);
while it sweeps (about 0.1 s) the robot moves, so the beams of one scan are taken from
different poses: at 1.5 rad/s the last beam of a 0.1 s sweep is 8.6 degrees off. Each
beam's point is moved by its own `PlanarMotion` (from the sensor at its time to the sensor
at the stamp) and the scan is laid out again on its own grid.

Laying out again: beam i lands at the continuous slot position u_i of its moved bearing.
A slot gets the nearest (REP-117 order, NaN never hiding a reading: `np.fmin`) of the
beams landing in it; a slot no beam lands in (the sweep stretched) gets the nearer of the
two beams either side of it, never an interpolation across a depth edge. Beams without a
point (+-Inf, NaN) keep their value and only turn with the motion.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from scanfuse.scan import TWO_PI, Scan, normalized_ranges, to_rep117

if TYPE_CHECKING:
    import numpy.typing as npt

    F64 = npt.NDArray[np.float64]


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
        between = np.fmin(moved_range[before], moved_range[after])
        out[empty[has_both]] = between[has_both]
    # A moved point may leave the sensor's limits: REP-117 says how to report it then.
    return scan.with_ranges(to_rep117(out.astype(np.float32), scan.range_min, scan.range_max))
