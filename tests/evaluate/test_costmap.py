"""The navigator's Nav2-like obstacle layer: marking and raytrace clearing on hand-worked rays."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanfuse.errors import InputError
from scanfuse.evaluate.costmap import Costmap
from scanfuse.evaluate.mapping import GridSpec
from scanfuse.scan import Scan

# 0.1 m cells from -3.5 m to 3.5 m: the cell of x is floor((x + 3.5) / 0.1).
SPEC = GridSpec(0.1, (-3.5, -3.5), 70, 70)
ORIGIN = (0.05, 0.05)  # the centre of cell (row 35, column 35)


def cross_scan(ahead: float, left: float, behind: float, right: float) -> Scan:
    """Four rays: +x, +y, -x, -y of the scan's frame; range_max 12 m like the LiDAR's."""
    ranges = np.array([ahead, left, behind, right], dtype=np.float32)
    return Scan(0.0, 1.5 * math.pi, 0.5 * math.pi, 0.15, 12.0, ranges)


def test_rays_clear_to_their_end_and_mark_it_within_obstacle_max_range():
    costmap = Costmap(SPEC)
    # Low obstacles marked earlier (as the camera saw them), all on the four rays' lines.
    before = {
        (35, 37): False,  # x = 0.25 m, before the +x ray's end at 0.55 m: cleared
        (35, 42): True,  # x = 0.75 m, past that end: kept
        (64, 35): False,  # y = 2.95 m on the +Inf ray: inside raytrace_max_range (3 m): cleared
        (67, 35): True,  # y = 3.25 m: beyond 3 m of ray: kept
        (35, 30): True,  # x = -0.45 m on the NaN ray: no information, kept
        (25, 35): False,  # y = -0.95 m on the 2.7 m ray: cleared
        (5, 35): True,  # y = -2.95 m, past that ray's end (-2.65 m): kept
    }
    for cell in before:
        costmap.lethal[cell] = True
    costmap.update(cross_scan(0.5, math.inf, math.nan, 2.7), *ORIGIN, 0.0)
    for cell, kept in before.items():
        assert costmap.lethal[cell] == kept, cell
    # The 0.5 m ray ends at x = 0.55 m, column 40: marked. The 2.7 m ray ends at
    # y = -2.65 m (row 8), beyond obstacle_max_range 2.5 m: cleared, never marked; the
    # +Inf ray (range_max - 0.1 mm = 12 m) is never marked either.
    assert costmap.lethal[35, 40]
    assert not costmap.lethal[8, 35]
    assert costmap.lethal.sum() == 1 + sum(before.values())


def test_rays_turn_with_the_pose():
    costmap = Costmap(SPEC)
    # Facing +y (yaw 90 degrees) the 0.5 m "ahead" ray ends at y = 0.55 m: row 40.
    costmap.update(cross_scan(0.5, math.nan, math.nan, math.nan), *ORIGIN, 0.5 * math.pi)
    assert np.argwhere(costmap.lethal).tolist() == [[40, 35]]
    # -Inf (too close) is dropped as laser_geometry drops it: nothing changes.
    costmap.update(cross_scan(-math.inf, math.nan, math.nan, math.nan), *ORIGIN, 0.5 * math.pi)
    assert np.argwhere(costmap.lethal).tolist() == [[40, 35]]


def test_footprint_clearing():
    costmap = Costmap(SPEC)
    costmap.lethal[35, 37] = True  # centre (0.25, 0.05): 0.2 m from the robot's centre
    costmap.lethal[35, 39] = True  # centre (0.45, 0.05): 0.4 m away
    costmap.clear_disk(*ORIGIN, 0.25)
    assert not costmap.lethal[35, 37]
    assert costmap.lethal[35, 39]


def test_costmap_ranges_must_be_sane():
    with pytest.raises(InputError, match='costmap ranges must be finite and not negative'):
        Costmap(SPEC, raytrace_max_range=-1.0)
