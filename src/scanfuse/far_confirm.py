"""Far camera readings kept only when the frame before showed them too (issue 25).

Far out, a depth camera's noise lifts single floor pixels into the slab: sigma = depth_noise
Z^2 along the line of sight, 6 cm at 2.5 m on a D435, and more where the floor lies lower
than the one the robot stands on (past a ramp's foot its lines of sight meet it more
steeply). Each frame's noise is its own, so such a reading seldom stands where the camera's
frame before had one; an obstacle's does. A slab reading farther than `far_confirm_range` is
kept when the previous frame had a slab reading within `FAR_CONFIRM_ABSOLUTE` plus one sigma
of its place in the odometry frame; a nearer one, at once. The robot, still more than that
range away, sees a far obstacle one frame later. Pure numpy.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import numpy.typing as npt

    from scanfuse.memory import Placement
    from scanfuse.scan import Scan

    F64 = npt.NDArray[np.float64]
    Mask = npt.NDArray[np.bool_]

FAR_CONFIRM_ABSOLUTE = 0.05  # metres, plus one sigma of the depth noise at the reading


def far_readings(scan: Scan, slab_slots: Mask, far: float) -> Mask:
    """The slots of `scan` holding a slab reading farther than `far` metres."""
    ranges = scan.ranges
    with np.errstate(invalid='ignore'):
        found: Mask = slab_slots & np.isfinite(ranges) & (ranges > far)
    return found


def places(scan: Scan, slots: Mask, placement: Placement) -> F64:
    """The (N, 2) odometry-frame points of `scan`'s readings in `slots`, seen from `placement`."""
    index = np.flatnonzero(slots)
    angles = scan.angle_min + index * scan.angle_increment
    ranges = scan.ranges[index].astype(np.float64)
    x, y = placement.to_odom(ranges * np.cos(angles), ranges * np.sin(angles))
    return np.column_stack([x, y])


def confirmed(points: F64, ranges: F64, before: F64, depth_noise: float) -> Mask:
    """Per point (readings `ranges` metres away), whether a point of `before` lies within
    FAR_CONFIRM_ABSOLUTE + depth_noise * range^2 of it."""
    if len(points) == 0 or len(before) == 0:
        return np.zeros(len(points), dtype=np.bool_)
    gaps = np.hypot(
        points[:, 0, None] - before[None, :, 0], points[:, 1, None] - before[None, :, 1]
    ).min(axis=1)
    near: Mask = gaps <= FAR_CONFIRM_ABSOLUTE + depth_noise * ranges * ranges
    return near
