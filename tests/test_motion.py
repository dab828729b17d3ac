"""Planar poses, odometry history and the de-skew layout, on hand-worked values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanfuse.errors import InputError
from scanfuse.fuse.deskew import deskew_scan
from scanfuse.motion import OdometryHistory, PlanarMotion, PlanarPose, PoseQuery
from scanfuse.scan import Scan
from scanfuse.transforms import Transform

NS = 1_000_000_000


def test_between_is_the_later_pose_seen_from_the_earlier():
    earlier = PlanarPose(1.0, 0.0, math.pi / 2)  # at (1, 0) facing +y
    later = PlanarPose(1.0, 2.0, math.pi)  # 2 m further along +y, facing -x
    move = earlier.between(later)
    assert (move.x, move.y, move.yaw) == pytest.approx((2.0, 0.0, math.pi / 2))
    back = earlier.compose(move)
    assert (back.x, back.y) == pytest.approx((later.x, later.y))


def test_a_point_ahead_moves_back_when_the_base_drives_forward():
    # Base drove 0.5 m forward: a point 2 m ahead of a LiDAR 0.2 m ahead of the base is 1.5 m.
    motion = PlanarMotion.of_base_move(
        PlanarPose(0.5, 0.0, 0.0), Transform.from_rpy(0.0, 0.0, 0.0, (0.2, 0.0, 0.3))
    )
    x, y = motion.apply(np.array([2.0]), np.array([0.0]))
    assert (x[0], y[0]) == pytest.approx((1.5, 0.0))


def test_a_point_ahead_turns_right_when_the_base_turns_left():
    motion = PlanarMotion.of_base_move(PlanarPose(0.0, 0.0, 0.1), Transform())
    assert motion.angle == pytest.approx(-0.1)
    # An upside-down LiDAR (roll pi) sees the same turn mirrored: +0.1 in its own frame.
    upside_down = PlanarMotion.of_base_move(
        PlanarPose(0.0, 0.0, 0.1), Transform.from_rpy(math.pi, 0.0, 0.0)
    )
    assert upside_down.angle == pytest.approx(0.1)


def test_history_interpolates_position_and_the_shortest_yaw():
    history = OdometryHistory()
    history.add(0, PlanarPose(0.0, 0.0, math.pi - 0.1))
    history.add(NS // 10, PlanarPose(1.0, 0.0, -math.pi + 0.1))  # +0.2 rad across +-pi
    found = history.pose_at(NS // 20)
    assert found.how is PoseQuery.INTERPOLATED
    assert found.pose is not None
    assert found.pose.x == pytest.approx(0.5)
    assert abs(found.pose.yaw) == pytest.approx(math.pi)


def test_history_extrapolates_only_up_to_its_limit():
    history = OdometryHistory(max_extrapolation=0.05)
    history.add(0, PlanarPose(0.0, 0.0, 0.0))
    history.add(NS // 50, PlanarPose(0.02, 0.0, 0.0))  # 1 m/s
    ahead = history.pose_at(NS // 50 + NS // 25)  # 40 ms past the newest
    assert ahead.how is PoseQuery.EXTRAPOLATED
    assert ahead.pose is not None
    assert ahead.pose.x == pytest.approx(0.06)
    assert history.pose_at(NS // 50 + NS // 10).how is PoseQuery.TOO_NEW
    assert history.pose_at(-1).how is PoseQuery.TOO_OLD


def test_a_jump_starts_a_new_segment():
    history = OdometryHistory(max_speed=5.0)
    history.add(0, PlanarPose(0.0, 0.0, 0.0))
    history.add(NS // 50, PlanarPose(3.0, 0.0, 0.0))  # 150 m/s
    assert history.breaks == 1
    move, how = history.move_between(0, NS // 50)
    assert move is None
    assert how is PoseQuery.ACROSS_BREAK


def test_out_of_order_samples_are_ignored_and_counted():
    history = OdometryHistory()
    history.add(NS, PlanarPose(0.0, 0.0, 0.0))
    assert not history.add(NS // 2, PlanarPose(1.0, 0.0, 0.0))
    assert history.out_of_order == 1
    assert len(history) == 1


def test_bad_limits_are_errors():
    with pytest.raises(InputError, match='max_extrapolation must be a finite non-negative'):
        OdometryHistory(max_extrapolation=math.inf)


def scan_of(ranges) -> Scan:
    count = len(ranges)
    return Scan(
        angle_min=-math.pi,
        angle_max=math.pi - 2 * math.pi / count,
        angle_increment=2 * math.pi / count,
        range_min=0.1,
        range_max=10.0,
        ranges=np.asarray(ranges, dtype=np.float32),
    )


def test_deskew_without_motion_keeps_every_reading():
    ranges = np.array([1.0, 2.0, np.inf, np.nan, 3.0, -np.inf, 4.0, 5.0], dtype=np.float32)
    zero = np.zeros(8)
    out = deskew_scan(scan_of(ranges), zero, zero, zero)
    np.testing.assert_array_equal(out.ranges, ranges)


def test_deskew_by_whole_slots_shifts_the_readings():
    ranges = np.arange(1.0, 9.0, dtype=np.float32)
    turn = np.full(8, 2 * (2 * math.pi / 8))  # every beam turned two slots to the left
    out = deskew_scan(scan_of(ranges), turn, np.zeros(8), np.zeros(8))
    np.testing.assert_allclose(out.ranges, np.roll(ranges, 2), rtol=1e-6)


SLOT = 2 * math.pi / 1080  # an RPLIDAR A2's third of a degree


def test_a_stretched_sweep_fills_a_gap_on_one_surface_with_the_nearer_neighbour():
    # A wall 2 m away; beams 540 on turned one slot on: slot 540 gets no beam and takes the
    # nearer of beams 539 and 540, 1 mm apart.
    ranges = np.full(1080, 2.0, dtype=np.float32)
    ranges[540:] = 2.001
    turn = np.where(np.arange(1080) >= 540, SLOT, 0.0)
    out = deskew_scan(scan_of(ranges), turn, np.zeros(1080), np.zeros(1080))
    assert out.ranges[540] == pytest.approx(2.0)
    assert out.ranges[541] == pytest.approx(2.001)


def test_a_gap_across_a_depth_edge_stays_without_a_reading():
    # A post 0.6 m away (beams up to 539) before a wall 1.3 m away: the post's beams moved
    # four slots more than the wall's (driving past it), so slots 536-539 were measured by no
    # beam. Filled with the post, they made it four slots (1.4 cm) wider than it is.
    ranges = np.where(np.arange(1080) < 540, 0.6, 1.3).astype(np.float32)
    turn = np.where(np.arange(1080) < 540, -4 * SLOT, 0.0)
    out = deskew_scan(scan_of(ranges), turn, np.zeros(1080), np.zeros(1080))
    assert np.isnan(out.ranges[536:540]).all()
    np.testing.assert_allclose(out.ranges[530:536], 0.6, rtol=1e-6)
    np.testing.assert_allclose(out.ranges[540:546], 1.3, rtol=1e-6)


def test_the_same_stamp_twice_is_one_sample_not_out_of_order():
    history = OdometryHistory()
    assert history.add(NS, PlanarPose(1.0, 0.0, 0.5))
    assert history.add(NS, PlanarPose(1.0, 0.0, 0.5 + 1e-16))  # /odom after TF
    assert history.out_of_order == 0
    assert len(history) == 1
