"""All-around recall: low obstacles within 1 m of the footprint, every direction (hand-worked)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanfuse.evaluate.groundtruth import SeenSurfaces
from scanfuse.evaluate.metrics import ScanTally, SlotTruth, near_footprint_slots
from scanfuse.sim.worlds import Drop, low_box
from tests.support.render import Box, camera_in_world, depth_image
from tests.test_memory import CAMERA, HEIGHT, PITCH

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


def test_all_around_recall_of_seen_slots_counts_only_what_a_depth_image_had_shown():
    angles = np.array([0.0, 0.5 * math.pi, math.pi, 1.5 * math.pi])
    truth = np.array([2.0, 0.6, 0.5, 0.7], dtype=np.float32)
    plane = np.full(4, 3.0, dtype=np.float32)
    near = near_footprint_slots(truth, angles, CENTRE, RADIUS)
    seen = np.array([True, True, False, True])  # the box behind was never in a frame
    in_view = np.zeros(4, dtype=bool)
    slot_truth = SlotTruth(truth, plane, np.array(['low_box'] * 4), in_view, near, seen)
    # Left (0.6) and behind (0.5) detected, right (0.7) not: 2 / 3 all around; of the two
    # near slots ever shown (left, right) one is detected.
    tally = ScanTally()
    tally.add(np.array([2.0, 0.6, 0.5, 3.0], dtype=np.float32), slot_truth)
    metrics = tally.summary()
    assert metrics.recall_near == pytest.approx(2 / 3)
    assert metrics.low_slots_near_seen == 2
    assert metrics.recall_near_seen == pytest.approx(1 / 2)
    other = ScanTally()
    other.merge(tally)
    assert other.summary().recall_near_seen == pytest.approx(1 / 2)


# A camera 0.4 m up at the origin, pitched 15 degrees down, looking along +x (as in
# tests/test_memory.py). Box A (front face at x = 1.5, 0.2 m tall) is in full view; box
# B (x 2.0-2.1, 0.1 m tall) stands behind it, below the line of sight over A's far top
# edge (0.4 - 0.2 (x / 1.7) m high: 0.165 m at x = 2.0); box C is 90 degrees to the left.
BOX_A = Box(1.5, 1.7, -0.1, 0.1, 0.2)
BOX_B = Box(2.0, 2.1, -0.1, 0.1, 0.1)
BOX_C = Box(-0.1, 0.1, 1.4, 1.6, 0.1)


def _obstacle(name: str, b: Box):
    centre = ((b.x_min + b.x_max) / 2, (b.y_min + b.y_max) / 2)
    return low_box(name, centre, 0.0, (b.x_max - b.x_min, b.y_max - b.y_min, b.height))


def test_seen_surfaces_are_the_places_a_depth_image_showed_not_the_hidden_ones():
    camera = CAMERA
    obstacles = tuple(_obstacle(n, b) for n, b in (('a', BOX_A), ('b', BOX_B), ('c', BOX_C)))
    ledge = Drop('ledge', 'ledge', (2.5, 3.5, -0.5, 0.5), 0.3)  # ahead, in view
    seen = SeenSurfaces(
        obstacles,
        (-1.0, 4.0, -2.0, 2.0),
        slab=(0.03, 0.5),
        range_min=0.2,
        range_max=3.0,
        drops=(ledge,),
    )
    places = (np.array([1.5, 1.5, 2.0, 0.0, 2.5]), np.array([0.0, 0.09, 0.0, 1.4, 0.4]))
    assert not seen.shown(*places).any()  # no frame yet
    view = camera_in_world(0.0, 0.0, 0.0, height=HEIGHT, pitch=PITCH)
    seen.add(depth_image(camera, view, [BOX_A, BOX_B, BOX_C]), camera, view)
    # A's front face, at its middle and by its corner: shown. B, hidden behind A, and C,
    # outside the view: not. The ledge's near edge at (2.5, 0.4), whose line of sight
    # passes beside A (y = 0.24 at x = 1.5): the floor up to it is in view (the rendered
    # floor has no hole; its pixels by the edge count).
    assert seen.shown(*places).tolist() == [True, True, False, False, True]
