"""All-around recall: low obstacles within 1 m of the footprint, every direction (hand-worked)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanfuse.evaluate.metrics import ScanTally, SlotTruth, near_footprint_slots

# The LiDAR 0.1 m ahead of the base's centre: the centre is (-0.1, 0) in the LiDAR's frame;
# a round footprint of radius 0.2 m.
CENTRE, RADIUS = (-0.1, 0.0), 0.2


def test_near_slots_measure_from_the_footprint_not_from_the_lidar():
    angles = np.array([0.0, 0.0, 0.0, math.pi, math.pi, math.pi, 0.5 * math.pi, 0.5 * math.pi, 0])
    truth = np.array([1.05, 1.2, 1.25, 1.05, 1.25, 1.35, 1.1, 1.2, np.inf], dtype=np.float32)
    near = near_footprint_slots(truth, angles, CENTRE, RADIUS)
    # Ahead: 1.05 + 0.1 - 0.2 = 0.95 m from the footprint (near); 1.2 -> 1.1, 1.25 -> 1.15 (not).
    # Behind: 1.05 - 0.1 - 0.2 = 0.75, 1.25 -> 0.95 (near); 1.35 -> 1.05 (not).
    # Left: hypot(0.1, 1.1) - 0.2 = 0.905 (near); hypot(0.1, 1.2) - 0.2 = 1.004 (not).
    # +Inf: nothing there.
    expected = [True, False, False, True, True, False, True, False, False]
    assert near.tolist() == expected


def test_all_around_recall_counts_low_slots_near_the_footprint_in_every_direction():
    angles = np.array([0.0, 0.5 * math.pi, math.pi, 1.5 * math.pi])
    # Four low obstacles (the LiDAR's plane sees only the walls 3 m away); the one ahead
    # is 2 m off, the other three within 1 m of the footprint.
    truth = np.array([2.0, 0.6, 0.5, 0.7], dtype=np.float32)
    plane = np.full(4, 3.0, dtype=np.float32)
    near = near_footprint_slots(truth, angles, CENTRE, RADIUS)
    assert near.tolist() == [False, True, True, True]
    in_view = np.array([True, False, False, False])
    slot_truth = SlotTruth(truth, plane, np.array(['low_box'] * 4), in_view, near)
    # The fused scan holds the obstacle ahead and the one behind; left and right it is the
    # LiDAR's wall. Ahead is not near: of the 3 near slots only behind is detected, 1 / 3.
    fused = np.array([2.0, 3.0, 0.5, 3.0], dtype=np.float32)
    tally = ScanTally()
    tally.add(fused, slot_truth)
    metrics = tally.summary()
    assert metrics.low_slots_near == 3
    assert metrics.recall_near == pytest.approx(1 / 3)
    # In-view recall counts only the slot ahead (detected).
    assert metrics.recall == 1.0
    # Merging two tallies counts both scans: a second scan that sees all three.
    other = ScanTally()
    other.add(np.array([2.0, 0.6, 0.5, 0.7], dtype=np.float32), slot_truth)
    tally.merge(other)
    assert tally.summary().recall_near == pytest.approx(4 / 6)
    # Without `near` nothing counts as near (NaN: nothing to measure).
    bare = ScanTally()
    bare.add(fused, SlotTruth(truth, plane, np.array(['low_box'] * 4), in_view))
    assert math.isnan(bare.summary().recall_near)
