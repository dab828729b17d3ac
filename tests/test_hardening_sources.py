"""Regression tests of issue 26 through the stream's API: what named sources, clouds,
fragments and pass-through publish from a driver's error values and odd scans."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from scanfuse.stream import FusionStream
from tests.support.render import square_room_ranges
from tests.test_sources import (
    HALF,
    NS,
    base_lidar,
    cloud_config,
    lidar_scan,
    reading,
    two_lidars,
)

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


def test_a_clouds_zero_points_are_no_returns_dropped_and_counted():
    """Issue 26.4: Ouster, Hesai and Livox drivers write (0, 0, 0) for a beam with no return;
    those points made an obstacle at the cloud sensor's own mount (here 0.5 m behind the
    LiDAR, its height inside the slab)."""
    config = cloud_config(points={'topic': '/points', 'x': -0.5, 'z': 0.3})
    stream: FusionStream[int] = FusionStream(config)
    ys = np.linspace(-0.1, 0.1, 21)
    heights = np.linspace(0.05, 0.2, 6)
    # A box face 1.5 m ahead of the base: x 2.0 m and z (height - 0.3) m in the cloud's frame.
    face = np.array([(2.0, y, h - 0.3) for y in ys for h in heights])
    no_return = np.zeros((500, 3))
    stream.add_cloud(NS, np.vstack([no_return, face, no_return]), NS, 'livox', 'points')
    (out,) = stream.add_scan(base_lidar(), 1, NS + 1)
    assert out.fused is not None
    assert reading(out.fused, 0.0) == pytest.approx(1.5, abs=0.01)
    assert reading(out.fused, math.pi) == math.inf  # nothing behind: no obstacle at 0.5 m
    assert np.nanmin(out.fused.ranges) == pytest.approx(1.5, abs=0.01)
    assert stream.extras.counts.no_return == {'points': 1000}
