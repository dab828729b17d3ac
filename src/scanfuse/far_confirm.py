"""Far camera readings kept only when the frame before showed them too (issue 25).

Far out, a depth camera's noise lifts single floor pixels into the slab: sigma = depth_noise
Z^2 along the line of sight, 6 cm at 2.5 m on a D435, and more where the floor lies lower
than the one the robot stands on (past a ramp's foot its lines of sight meet it more
steeply). Each frame's noise is its own, so such a reading seldom stands where the camera's
frame before had one; an obstacle's does. A slab reading farther than `far_confirm_range` is
kept when the previous frame had a slab reading within `FAR_CONFIRM_ABSOLUTE` plus
`FAR_CONFIRM_SIGMAS` sigmas of its place in the odometry frame; a nearer one, at once. An
obstacle's reading is the near edge of many pixels (`obstacle_min_points`), far steadier
from frame to frame than one pixel, so the window need not be wide. The robot, still more
than that range away, sees a far obstacle one frame later. Pure numpy.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from scanfuse.scan_matching import points

if TYPE_CHECKING:
    import numpy.typing as npt

    from scanfuse.memory import Placement
    from scanfuse.scan import Scan

    F64 = npt.NDArray[np.float64]
    Mask = npt.NDArray[np.bool_]

# The window: metres, plus this many sigmas of the depth noise at the reading. Measured by
# `scanfuse evaluate` on the terrain trials: 5 cm + 1 sigma gave 0.75 % false obstacles on
# slopes, 3 cm + 0.5 sigma 0.67 % (recall on slopes 0.915 -> 0.904).
FAR_CONFIRM_ABSOLUTE = 0.03
FAR_CONFIRM_SIGMAS = 0.5


def far_readings(scan: Scan, slab_slots: Mask, far: float) -> Mask:
    """The slots of `scan` holding a slab reading farther than `far` metres."""
    ranges = scan.ranges
    with np.errstate(invalid='ignore'):
        found: Mask = slab_slots & np.isfinite(ranges) & (ranges > far)
    return found


def places(scan: Scan, slots: Mask, placement: Placement) -> F64:
    """The (N, 2) odometry-frame points of `scan`'s readings in `slots`, seen from `placement`."""
    x, y = points(scan)
    odom_x, odom_y = placement.to_odom(x[slots], y[slots])
    return np.column_stack([odom_x, odom_y])


def confirmed(
    points: F64, ranges: F64, before: F64, depth_noise: float, origin: tuple[float, float]
) -> Mask:
    """Per point (readings `ranges` metres from `origin`), whether a point of `before` lies
    within FAR_CONFIRM_ABSOLUTE + FAR_CONFIRM_SIGMAS * depth_noise * range^2 of it.

    Only the points of `before` whose bearing from `origin` lies within the angle that
    circle subtends are measured (sorted by bearing): a wall 2-3 m out fills a frame's every
    slot, and measuring every pair took a millisecond."""
    near = np.zeros(len(points), dtype=np.bool_)
    if len(points) == 0 or len(before) == 0:
        return near
    tolerance = FAR_CONFIRM_ABSOLUTE + FAR_CONFIRM_SIGMAS * depth_noise * ranges * ranges
    bearing = np.arctan2(points[:, 1] - origin[1], points[:, 0] - origin[0])
    width = np.arcsin(np.minimum(tolerance / np.maximum(ranges, 1e-9), 1.0))
    seen = np.arctan2(before[:, 1] - origin[1], before[:, 0] - origin[0])
    order = np.argsort(seen)
    # Once more a turn below and above, so that a window across +-pi finds its points.
    bearings = np.concatenate([seen[order] - 2.0 * np.pi, seen[order], seen[order] + 2.0 * np.pi])
    around = np.concatenate([before[order]] * 3)
    first = np.searchsorted(bearings, bearing - width, side='left')
    last = np.searchsorted(bearings, bearing + width, side='right')
    most = int((last - first).max())
    if most <= 0:
        return near
    index = first[:, None] + np.arange(most)
    inside = index < last[:, None]
    index = np.minimum(index, len(bearings) - 1)
    gaps = np.hypot(points[:, 0, None] - around[index, 0], points[:, 1, None] - around[index, 1])
    found: Mask = np.any(inside & (gaps <= tolerance[:, None]), axis=1)
    return found
