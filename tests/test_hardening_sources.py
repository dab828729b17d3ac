"""Regression tests of issue 26 through the stream's API: what named sources, clouds,
fragments and pass-through publish from a driver's error values and odd scans."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from scanfuse.stream import FusionStream
from tests.support.render import square_room_ranges
from tests.test_sources import HALF, NS, lidar_scan, two_lidars

FRONT, FRONT_YAW = (0.3, 0.2), math.pi / 4
REAR, REAR_YAW = (-0.3, -0.2), -3 * math.pi / 4


def test_a_second_lidars_zero_no_return_is_not_an_obstacle_at_its_mount():
    """Issue 26.3: a rear LiDAR publishing range_min 0 and 0.0 for a failed return (a
    Hokuyo) put an obstacle at its own mount, 0.72 m behind the front one; its 0.0 is no
    reading, as the first LiDAR's is."""
    stream: FusionStream[int] = FusionStream(two_lidars())
    fov = math.radians(270)
    front = lidar_scan(FRONT, FRONT_YAW, 3600, fov, 'front', grid_fov=2 * math.pi)
    rear = lidar_scan(REAR, REAR_YAW, 5400, fov, 'rear')
    ranges = rear.ranges.copy()
    ranges[::10] = 0.0  # every tenth return failed
    rear = replace(rear, range_min=0.0, ranges=ranges)
    stream.add_scan(rear, 0, NS, source='rear')
    (out,) = stream.add_scan(front, 1, NS + 1)
    assert out.fused is not None
    truth = square_room_ranges(FRONT, FRONT_YAW, front.angles(), HALF)
    # The rear LiDAR still fills the front one's gap (its other nine readings in ten).
    assert np.isfinite(out.fused.ranges).all()
    np.testing.assert_allclose(out.fused.ranges, truth, atol=0.01)
