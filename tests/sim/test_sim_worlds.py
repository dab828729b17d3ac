"""Worlds: generated MJCF, true geometry and kind labels."""

from __future__ import annotations

import math

import mujoco
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scanfuse.sim import KINDS, WORLDS, SimConfig, SimError, Simulation, make_world
from scanfuse.sim.worlds import BOARD_THICKNESS, MAX_SAGITTA, bookshelf, circle, room_walls

SMALL = (256, 144)


@pytest.mark.parametrize('name', sorted(WORLDS))
def test_every_world_compiles_and_labels_every_obstacle_geom(name):
    simulation = Simulation(SimConfig(world=name, resolution=SMALL, noise=False))
    model = simulation.model
    names = {model.geom(i).name for i in range(model.ngeom)}
    for obstacle in simulation.world.obstacles:
        assert obstacle.name in names
        assert obstacle.kind in KINDS
        geom = model.geom(obstacle.name).id
        assert simulation.geom_kind(geom) == obstacle.kind
    assert simulation.geom_kind(model.geom('floor').id) == 'floor'
    assert simulation.geom_kind(model.geom('robot/chassis').id) == ''


@pytest.mark.parametrize('name', sorted(WORLDS))
def test_mujoco_geoms_sit_where_the_footprints_say(name):
    # A vertical ray at each footprint's centroid, from above, must hit that geom's top
    # at z_max (or something above it); one just outside every footprint must not hit it.
    world = make_world(name)
    simulation = Simulation(SimConfig(world=name, resolution=SMALL, noise=False), world=world)
    model, data = simulation.model, simulation.data
    geomid = np.zeros(1, dtype=np.int32)
    for obstacle in world.obstacles:
        x, y = obstacle.footprint.mean(axis=0)
        target = model.geom(obstacle.name).id
        groups = np.zeros(6, dtype=np.uint8)
        groups[model.geom_group[target]] = 1
        # Only this geom: cast from just above its top, straight down.
        others = [g for g in range(model.ngeom) if g != target]
        saved = model.geom_rgba[others, 3].copy()
        model.geom_rgba[others, 3] = 0.0
        top = obstacle.z_max + 1.0
        distance = mujoco.mj_ray(
            model, data, np.array([x, y, top]), np.array([0.0, 0.0, -1.0]), None, 1, -1, geomid
        )
        model.geom_rgba[others, 3] = saved
        assert geomid[0] == target, obstacle.name
        assert distance == pytest.approx(1.0, abs=1e-6), obstacle.name


def test_unknown_world_is_refused():
    with pytest.raises(SimError, match=r'unknown world .*choose one of room, bookshelf'):
        make_world('garage')


def test_bookshelf_boards_leave_the_default_lidar_plane_free():
    world = make_world('bookshelf')
    boards = [o for o in world.obstacles if o.kind == 'shelf_board']
    sides = [o for o in world.obstacles if o.kind == 'shelf_side']
    lidar_height = 0.30
    assert len(sides) == 2
    assert all(o.z_max - o.z_min == pytest.approx(BOARD_THICKNESS) for o in boards)
    assert not any(o.z_min <= lidar_height <= o.z_max for o in boards)
    assert any(o.z_max < lidar_height for o in boards)
    assert any(o.z_min > lidar_height for o in boards)
    assert all(o.z_min <= lidar_height <= o.z_max for o in sides)
    # No back panel: nothing between the boards' back edge and the wall behind.
    back = max(o.footprint[:, 0].max() for o in boards)
    east_wall = next(o for o in world.obstacles if o.name == 'wall_east')
    assert east_wall.footprint[:, 0].min() - back == pytest.approx(0.5)


def test_a_board_that_does_not_fit_the_shelf_is_refused():
    with pytest.raises(SimError, match=r'board at 0\.99 m does not fit in a 1\.0 m bookshelf'):
        bookshelf('shelf', 2.0, 0.0, board_bottoms=(0.99,))


def test_barricade_base_is_wider_than_its_top_and_the_lidar_plane_cuts_the_top():
    world = make_world('barricade')
    base = next(o for o in world.obstacles if o.kind == 'barricade_base')
    top = next(o for o in world.obstacles if o.kind == 'barricade_top')
    centre = np.array([2.0, 0.0])
    assert len(base.footprint) == 6
    assert np.linalg.norm(base.footprint - centre, axis=1) == pytest.approx(np.full(6, 0.35))
    assert np.linalg.norm(top.footprint - centre, axis=1).max() == pytest.approx(0.12)
    assert base.z_max == pytest.approx(0.2)
    assert top.z_min <= 0.30 <= top.z_max


def test_clutter_is_reproducible_by_seed_and_holds_the_required_objects():
    first, again, other = (
        make_world('clutter', 3),
        make_world('clutter', 3),
        make_world('clutter', 4),
    )
    footprints = [o.footprint for o in first.obstacles]
    assert all(
        np.array_equal(a, o.footprint) for a, o in zip(footprints, again.obstacles, strict=True)
    )
    assert not all(
        np.array_equal(a.footprint, b.footprint)
        for a, b in zip(first.obstacles, other.obstacles, strict=False)
    )
    kinds = {o.kind for o in first.obstacles}
    assert {'chair_leg', 'chair_seat', 'lamp_base', 'lamp_pole', 'low_box', 'cable_tray'} <= kinds
    assert {'shelf_board', 'barricade_base'} <= kinds
    for box in (o for o in first.obstacles if o.kind == 'low_box'):
        assert 0.05 <= box.z_max <= 0.15
    start = np.array([first.start.x, first.start.y])
    for obstacle in first.obstacles:
        if obstacle.kind != 'wall':
            assert np.linalg.norm(obstacle.footprint - start, axis=1).min() > 0.5


def test_door_gap_is_cut_into_the_north_wall():
    walls = room_walls((-3.0, 3.0, -2.5, 2.5), door=(1.5, 0.9))
    north = [w for w in walls if w.name.startswith('wall_north')]
    assert len(north) == 2
    gap_left = north[0].footprint[:, 0].max()
    gap_right = north[1].footprint[:, 0].min()
    assert gap_left == pytest.approx(1.05)
    assert gap_right == pytest.approx(1.95)


@settings(max_examples=30, deadline=None)
@given(radius=st.floats(0.005, 2.0), cx=st.floats(-5, 5), cy=st.floats(-5, 5))
def test_circle_polygon_lies_within_the_sagitta_of_the_true_circle(radius, cx, cy):
    polygon = circle(cx, cy, radius)
    centre = np.array([cx, cy])
    assert np.linalg.norm(polygon - centre, axis=1) == pytest.approx(np.full(len(polygon), radius))
    midpoints = (polygon + np.roll(polygon, -1, axis=0)) / 2
    inside_by = radius - np.linalg.norm(midpoints - centre, axis=1)
    assert inside_by.max() <= MAX_SAGITTA + 1e-12
    # Counter-clockwise and regular: the signed area of a regular n-gon inscribed in the circle.
    x, y = polygon[:, 0] - cx, polygon[:, 1] - cy
    area = 0.5 * np.sum(x * np.roll(y, -1) - np.roll(x, -1) * y)
    count = len(polygon)
    assert area == pytest.approx(count / 2 * radius**2 * math.sin(2 * math.pi / count), rel=1e-6)
