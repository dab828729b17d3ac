"""Fragments of a revolution (issue 12) read only the part of the image that can land in them.

A fragment's projector skips the image columns whose points cannot reach its grid; what it
reports must not change for that. Its slots are slots of the whole turn's grid (same
increment, same phase), so every slot must read as the whole turn's projector reads it, and
as the numpy reference (which reads every pixel); its scan as the numpy-only projector's.
Scenes are ray-cast as in test_obstacle.py.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanfuse.convert.obstacle import ObstacleProjector, _tile_gaps
from scanfuse.motion import PlanarMotion
from scanfuse.scan import AngleGrid
from scanfuse.transforms import Extrinsics
from tests.convert.test_obstacle import (
    AHEAD_MOUNTING,
    BOX_5CM,
    CAMERA,
    GRID,
    GRID_CLOCKWISE,
    INCREMENT,
    LIMITS,
    WALL_AHEAD,
    render,
)
from tests.convert.test_obstacle_drops import DEFAULT_DROPS, as_millimetres, ledge_depth

AHEAD = Extrinsics.from_mounting(**AHEAD_MOUNTING)
# The camera above the LiDAR: each pixel sees along one bearing, so a tile's arc is as narrow
# as its pixels, and a tile left out lies just beside the grid (a motion too small by a
# slot would lose points).
ABOVE = Extrinsics.from_mounting(
    camera_height=0.4, camera_pitch=math.radians(20.0), lidar_height=0.2
)
# A box left of ahead (bearings 9-19 deg) and one right of it (-9 to -23 deg), 1.5-2.2 m away,
# so both fragments the camera sees hold points, and walls behind them.
BOX_LEFT = (1.8, 2.1, 0.3, 0.6, 0.0, 0.2)
BOX_RIGHT = (1.5, 1.8, -0.6, -0.25, 0.0, 0.3)
SCENE = (BOX_5CM, BOX_LEFT, BOX_RIGHT, WALL_AHEAD)
TURN = PlanarMotion(cos=math.cos(0.05), sin=math.sin(0.05), tx=0.03, ty=-0.02)
# Turned both ways (a robot at 1.5 rad/s over 33 ms), turned and moved (and at 1 m/s),
# driven back, drifted sideways (the box ahead, at bearings -7.6 to 7.6 deg 1.5 m away,
# shifts by 1.9 deg, across 0 deg).
MOTIONS = [
    PlanarMotion(),
    PlanarMotion(cos=math.cos(0.05), sin=math.sin(0.05)),
    PlanarMotion(cos=math.cos(-0.05), sin=math.sin(-0.05)),
    TURN,
    PlanarMotion(tx=-0.1),
    PlanarMotion(ty=0.05),
]


def fragment(first_slot: int, count: int) -> AngleGrid:
    """Slots first_slot, ... of GRID (-pi + k INCREMENT), as a grid of their own."""
    return AngleGrid(-math.pi + first_slot * INCREMENT, INCREMENT, count)


def make(grid, extrinsics=AHEAD, **changes) -> ObstacleProjector:
    return ObstacleProjector(CAMERA, extrinsics, grid, **{**LIMITS, 'min_points': 3, **changes})


def assert_fragment_reads_as_the_whole_turn(
    part: ObstacleProjector, whole: ObstacleProjector, slots: np.ndarray, image: np.ndarray
) -> None:
    flat = image.ravel()
    reference = make(part.grid, part.extrinsics, use_kernel=False, drops=part.drops)
    for motion in MOTIONS:
        whole_best = whole.nearest_squared(flat, motion=motion)[slots].copy()
        whole_drops = whole.drop_slots[slots]
        best = part.nearest_squared(flat, motion=motion).copy()
        np.testing.assert_array_equal(best, whole_best)
        np.testing.assert_array_equal(part.drop_slots, whole_drops)
        np.testing.assert_array_equal(
            part.nearest_squared(flat, reference=True, motion=motion), best
        )
        np.testing.assert_array_equal(
            part.scan(image, motion).ranges, reference.scan(image, motion).ranges
        )


@pytest.mark.parametrize('threads', [1, 2])
@pytest.mark.parametrize('millimetres', [True, False])
@pytest.mark.parametrize('extrinsics', [AHEAD, ABOVE], ids=['ahead', 'above'])
def test_partly_seen_fragments_read_as_the_whole_turn(threads, millimetres, extrinsics):
    # CAMERA sees 31.4 deg either side of ahead: fragments [-60, 0) and [0, 60) deg (slots
    # 240 and 360 on) each hold only their part of it, the rest of them is out of view.
    image = render(CAMERA, extrinsics, SCENE, millimetres=millimetres)
    whole = make(GRID, extrinsics, threads=threads)
    for first in (240, 360):
        part = make(fragment(first, 120), extrinsics, threads=threads)
        assert 40 < part.in_view.sum() < 100
        assert_fragment_reads_as_the_whole_turn(part, whole, np.arange(first, first + 120), image)
    # Not vacuous: each fragment has finite readings (the boxes) where the camera sees it.
    right, left = (make(fragment(first, 120), extrinsics) for first in (240, 360))
    assert np.isfinite(right.scan(image).ranges).sum() > 20
    assert np.isfinite(left.scan(image).ranges).sum() > 20


@pytest.mark.parametrize('threads', [1, 2])
def test_partly_seen_fragments_read_as_the_whole_turn_with_drops(threads):
    # A ledge 1.2 m ahead across the whole view (camera above the LiDAR): drop edges in both
    # fragments, read through the kernel's drop pass.
    extrinsics = Extrinsics.from_mounting(
        camera_height=0.4, camera_pitch=math.radians(20.0), lidar_height=0.3
    )
    depth = ledge_depth(CAMERA, edge=1.2, drop=0.3)
    depth[100:200, 200:440] = 1.0  # something standing in the slab too
    whole = make(GRID, extrinsics, threads=threads, drops=DEFAULT_DROPS)
    for image in (depth.astype(np.float32), as_millimetres(depth)):
        for first in (240, 360):
            part = make(fragment(first, 120), extrinsics, threads=threads, drops=DEFAULT_DROPS)
            slots = np.arange(first, first + 120)
            assert_fragment_reads_as_the_whole_turn(part, whole, slots, image)
            part.nearest_squared(image.ravel())
            assert part.drop_slots.sum() > 20


@pytest.mark.parametrize('threads', [1, 2])
def test_partly_seen_clockwise_fragment_reads_as_the_whole_turn(threads):
    # Clockwise slot k is at pi - k INCREMENT: slots 330..449 are 15 deg down to -44.5 deg,
    # the camera's view covers 15 deg down to about -38 deg of them (31.4 deg either side at
    # the image's centre row, wider below it: those rays, pitched down, are nearer the
    # vertical); the box on the left (9.5 to 18.4 deg) lies across the fragment's start.
    image = render(CAMERA, ABOVE, SCENE)
    whole = make(GRID_CLOCKWISE, ABOVE, threads=threads)
    part = make(AngleGrid(math.pi - 330 * INCREMENT, -INCREMENT, 120), ABOVE, threads=threads)
    assert 100 < part.in_view.sum() < 115
    assert_fragment_reads_as_the_whole_turn(part, whole, np.arange(330, 450), image)


@pytest.mark.parametrize('threads', [1, 2])
def test_fragment_seen_only_at_its_edge(threads):
    image = render(CAMERA, AHEAD, SCENE)
    whole = make(GRID, threads=threads)
    # The last slot the camera covers on the left (about 31 deg: slot 360 + 62), and a
    # fragment starting five slots before it: it sees six slots, the rest of the image is
    # out of its reach but for the columns at the image's left edge.
    last = int(np.flatnonzero(whole.in_view)[-1])
    assert 415 < last < 430
    part = make(fragment(last - 5, 120), threads=threads)
    assert part.in_view.sum() == 6
    assert_fragment_reads_as_the_whole_turn(part, whole, np.arange(last - 5, last + 115), image)
    # Not vacuous: the wall at 3.4 m (3 / cos 29 deg) reaches into its first slots.
    assert np.isfinite(part.nearest_squared(image.ravel())[:6]).any()


@pytest.mark.parametrize('threads', [1, 2])
def test_fragment_across_the_seam_behind(threads):
    # A camera looking backwards sees about 28 deg either side of pi from the LiDAR: the
    # fragment [175, 235) deg (slots 710..719 and 0..109 of the turn) holds its first 72 slots.
    extrinsics = Extrinsics.from_mounting(
        camera_x=-0.2, camera_height=0.3, camera_yaw=math.pi, lidar_height=0.2
    )
    wall_behind = (-2.2, -2.0, -5.0, 5.0, 0.0, 2.0)
    box_behind = (-1.8, -1.5, -0.5, -0.1, 0.0, 0.2)
    image = render(CAMERA, extrinsics, [wall_behind, box_behind])
    whole = make(GRID, extrinsics, threads=threads)
    part = make(fragment(710, 120), extrinsics, threads=threads)
    assert 60 < part.in_view.sum() < 80
    slots = (710 + np.arange(120)) % 720
    assert_fragment_reads_as_the_whole_turn(part, whole, slots, image)
    assert np.isfinite(part.nearest_squared(image.ravel())).sum() > 30


@pytest.mark.parametrize('threads', [1, 2])
def test_fragment_inside_the_view_reads_as_the_whole_turn(threads):
    # [-10, 10) deg, well inside the +-31 deg view: every slot in view.
    image = render(CAMERA, AHEAD, SCENE)
    whole = make(GRID, threads=threads)
    part = make(fragment(340, 40), threads=threads)
    assert part.in_view.all()
    assert_fragment_reads_as_the_whole_turn(part, whole, np.arange(340, 380), image)


def test_a_fragment_reads_only_its_side_of_the_image():
    # The camera looks along the LiDAR's x axis from 0.1 m ahead of it, without roll or yaw:
    # an image column right of the centre sees points of negative bearing, left of it of
    # positive bearing. So the fragment [0, 60) deg reads the left half (with a margin of a
    # slot and a tile) and [-60, 0) the right half, in every row that sees the slab.
    left, right = make(fragment(360, 120)), make(fragment(240, 120))
    width = CAMERA.width
    spans = {}
    for part, reads_left in ((left, True), (right, False)):
        spans[part] = still = part._spans(*part._margin(PlanarMotion())).copy()
        sees = still[:, 1] > still[:, 0]
        assert sees.sum() > 0.9 * CAMERA.height
        if reads_left:
            assert (still[sees, 0] == 0).all()
            assert (still[sees, 1] < 0.55 * width).all()
        else:
            assert (still[sees, 0] > 0.45 * width).all()
            assert (still[sees, 1] == width).all()
    # Turned by +0.05 rad (5.7 slots, counter-clockwise) the points just right of 0 deg turn
    # into [0, 60): it reads further right; [-60, 0) loses them: it reads less.
    turned = PlanarMotion(cos=math.cos(0.05), sin=math.sin(0.05))
    assert left._margin(turned) == pytest.approx((0.05 / INCREMENT, 1.0))
    wider = left._spans(*left._margin(turned))
    assert (wider[:, 1] >= spans[left][:, 1]).all()
    assert (wider[:, 1] > spans[left][:, 1]).sum() > 0.9 * CAMERA.height
    narrower = right._spans(*right._margin(turned))
    assert (narrower[:, 0] >= spans[right][:, 0]).all()
    assert (narrower[:, 0] > spans[right][:, 0]).sum() > 0.9 * CAMERA.height


def test_tile_gaps_are_the_distances_around_the_turn():
    # A grid of 10 slots at 0.5 deg: the turn is 720 slots; the grid is [0, 10).
    grid = AngleGrid(0.0, INCREMENT, 10)
    first = np.array([5.0, 12.0, 700.0, 715.0, -3.0, 1440.0 + 14.0, np.nan])
    last = np.array([8.0, 13.0, 705.0, 725.0, -1.0, 1440.0 + 16.0, np.nan])
    # Inside; 2 past the end, 707 short of slot 0 one turn on (720 - 13); 690 past, 15
    # short; across slot 0 one turn on; -3 is 717: 707 past, 1 short (-1 is 719); two turns
    # on, 4 past the end and 704 short; no arc.
    after, before = _tile_gaps(first, last, grid)
    np.testing.assert_allclose(after, [0, 2, 690, 0, 707, 4, np.inf], rtol=0, atol=1e-9)
    np.testing.assert_allclose(before, [0, 707, 15, 0, 1, 704, np.inf], rtol=0, atol=1e-9)


def test_two_threads_share_the_columns_a_fragment_reads():
    # [-60, 0) deg reads the right half of the image (above): its two threads split that
    # half, near three quarters of the width, not the image at its middle (where one thread
    # would get nothing to do). The whole turn's split stays at the middle.
    width = CAMERA.width
    right = make(fragment(240, 120), threads=2)
    assert 0.7 * width < right._bands[1, 0] < 0.8 * width
    assert (right._bands[0, 0], right._bands[1, 1]) == (0, width)
    assert make(GRID, threads=2)._bands[1, 0] == width // 2
