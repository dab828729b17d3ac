"""Far camera readings kept once a second frame shows them (`scanfuse.far_confirm`).

Worked by hand: at 2.5 m the tolerance is 3 cm plus half a sigma of a D435's depth noise
(0.01 * 2.5^2 = 6.25 cm), so 6.125 cm.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanfuse.config import FusionConfig
from scanfuse.far_confirm import confirmed
from scanfuse.motion import PlanarPose
from scanfuse.stream import FusionStream
from tests.support.render import Box
from tests.test_memory import NS, Robot, config, reading_at

FAR_BOX = Box(2.5, 2.7, -0.1, 0.1, 0.2)  # straight ahead, beyond the default 1.5 m
MIDDLE_BOX = Box(1.8, 2.0, 0.5, 0.7, 0.2)  # ahead and to the left, 1.9 m: beyond it too
MIDDLE_BEARING = math.atan2(0.6, 1.8)
NEAR_BOX = Box(0.8, 1.0, -0.7, -0.5, 0.2)  # ahead and to the right, within it
NEAR_BEARING = math.atan2(-0.6, 0.8)
DEFAULT = FusionConfig.model_fields['far_confirm_range'].default


def test_a_far_reading_needs_the_frame_before_within_3_cm_and_half_a_sigma():
    points = np.array([[2.5, 0.0], [2.5, 1.0]])
    ranges = np.array([2.5, math.hypot(2.5, 1.0)])
    before = np.array([[2.5 + 0.06, 0.0], [2.5, 1.0 + 0.07]])
    # 6 cm off at 2.5 m: within 6.125 cm; 7 cm off at 2.69 m: beyond 3 + 7.25 / 2 cm.
    assert confirmed(points, ranges, before, 0.01, (0.0, 0.0)).tolist() == [True, False]
    assert confirmed(points, ranges, before, 0.0, (0.0, 0.0)).tolist() == [False, False]
    assert confirmed(points, ranges, np.zeros((0, 2)), 0.01, (0.0, 0.0)).tolist() == [False, False]


def test_a_far_box_is_reported_from_its_second_frame_a_near_one_from_its_first():
    robot = Robot(FusionStream(config(far_confirm_range=DEFAULT)), [FAR_BOX, MIDDLE_BOX, NEAR_BOX])
    first = robot.scan().depth_scan
    for bearing in (0.0, MIDDLE_BEARING):
        assert np.isnan(first.ranges[first.grid.slot_of(np.array([bearing]))[0]])
    assert reading_at(first, NEAR_BEARING)[0] == pytest.approx(
        0.8 / math.cos(NEAR_BEARING), abs=0.03
    )
    second = robot.scan().depth_scan
    assert reading_at(second, 0.0)[0] == pytest.approx(FAR_BOX.x_min, abs=0.03)
    assert reading_at(second, MIDDLE_BEARING)[0] == pytest.approx(
        1.8 / math.cos(MIDDLE_BEARING), abs=0.03
    )


def test_with_far_confirm_range_0_a_far_box_is_reported_from_its_first_frame():
    robot = Robot(FusionStream(config(far_confirm_range=0.0)), [FAR_BOX])
    first = robot.scan().depth_scan
    assert reading_at(first, 0.0)[0] == pytest.approx(FAR_BOX.x_min, abs=0.03)


def test_a_far_reading_the_frame_before_did_not_show_is_dropped():
    # The box appears in the second frame (a far speck of noise does the same): not yet
    # shown; in the third, where the second showed it, it is.
    robot = Robot(FusionStream(config(far_confirm_range=DEFAULT)), [])
    robot.scan()
    robot.world = [FAR_BOX]
    second = robot.scan().depth_scan
    assert np.isnan(second.ranges[second.grid.slot_of(np.array([0.0]))[0]])
    third = robot.scan().depth_scan
    assert reading_at(third, 0.0)[0] == pytest.approx(FAR_BOX.x_min, abs=0.03)


def test_the_bearing_windows_find_what_measuring_every_pair_finds():
    # Points all around (windows across +-pi too), each frame's a few cm from the last.
    rng = np.random.default_rng(7)
    origin = (0.3, -0.2)
    for _ in range(20):
        count = int(rng.integers(1, 300))
        bearings = rng.uniform(-math.pi, math.pi, count)
        ranges = rng.uniform(2.0, 3.0, count)
        points = np.column_stack(
            [origin[0] + ranges * np.cos(bearings), origin[1] + ranges * np.sin(bearings)]
        )
        before = points[rng.permutation(count)[: count // 2]] + rng.normal(0, 0.08, (count // 2, 2))
        gaps = np.hypot(
            points[:, 0, None] - before[None, :, 0], points[:, 1, None] - before[None, :, 1]
        )
        every_pair = (gaps <= 0.03 + 0.005 * ranges[:, None] ** 2).any(axis=1)
        np.testing.assert_array_equal(confirmed(points, ranges, before, 0.01, origin), every_pair)


def test_after_an_odometry_jump_the_frame_before_confirms_nothing():
    # The robot stands; its odometry is reset from 0 to 0.5 m (a relocalisation: 0.5 m in
    # 20 ms). A box that appears 2.0 m out then lies, in the odometry frame, where the far
    # box 2.5 m out lay before the jump. The frame before the jump lies on the other side of
    # the break: it confirms nothing, so the new box is held back once, as one first seen.
    robot = Robot(FusionStream(config(far_confirm_range=DEFAULT)), [FAR_BOX])
    robot.scan()
    assert reading_at(robot.scan().depth_scan, 0.0)[0] == pytest.approx(FAR_BOX.x_min, abs=0.03)
    robot.world = [Box(2.0, 2.2, -0.1, 0.1, 0.2)]
    jumped = PlanarPose(0.5, 0.0, 0.0)
    robot.now += NS // 50
    robot.stream.add_odometry(robot.now, jumped)
    first = robot.scan(odometry=jumped).depth_scan
    assert np.isnan(first.ranges[first.grid.slot_of(np.array([0.0]))[0]])
    second = robot.scan(odometry=jumped).depth_scan
    assert reading_at(second, 0.0)[0] == pytest.approx(2.0, abs=0.03)
