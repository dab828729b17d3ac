"""The memory trials' worlds: low boxes under the LiDAR plane, routes that start and end clear."""

from __future__ import annotations

import numpy as np
import pytest

from scanfuse.errors import ConfigError
from scanfuse.evaluate.closed_loop import evaluation_world, memory_specs
from scanfuse.evaluate.memory_trials import MEMORY_FAMILIES, memory_trial

ROBOT_RADIUS = 0.18
LIDAR_HEIGHT = 0.30
SLAB = (0.03, 0.5)


def clearance(world, point):
    """Distance from a point to the nearest obstacle footprint's vertex or inside it (0)."""
    best = np.inf
    for obstacle in world.obstacles:
        polygon = obstacle.footprint
        lo, hi = polygon.min(axis=0), polygon.max(axis=0)
        if np.all(point >= lo) and np.all(point <= hi):
            return 0.0
        # Distance to each edge of the polygon.
        a, b = polygon, np.roll(polygon, -1, axis=0)
        ab = b - a
        t = np.clip(np.einsum('ij,ij->i', point - a, ab) / np.einsum('ij,ij->i', ab, ab), 0, 1)
        nearest = a + t[:, None] * ab
        best = min(best, float(np.min(np.hypot(*(nearest - point).T))))
    return best


@pytest.mark.parametrize('name', list(MEMORY_FAMILIES))
@pytest.mark.parametrize('seed', [0, 1, 7])
def test_memory_worlds_hold_low_boxes_and_clear_routes(name, seed):
    trial = memory_trial(name, seed)
    world = trial.world
    low = [o for o in world.obstacles if o.kind == 'low_box']
    assert len(low) >= 3
    for obstacle in low:
        # Under the LiDAR's plane (it passes over them), inside the collision slab.
        assert obstacle.z_max < LIDAR_HEIGHT
        assert SLAB[0] < obstacle.z_max <= 0.15 + 1e-9
    start = np.array([world.start.x, world.start.y])
    # The robot starts clear (it may turn in place) and every point of its route is
    # reachable: clear of every footprint by more than its radius.
    assert clearance(world, start) > ROBOT_RADIUS
    for point in (*trial.waypoints, trial.goal):
        assert clearance(world, np.array(point)) > ROBOT_RADIUS + 0.05
    # The evaluation builds the same world for the trial's name and seed.
    built = evaluation_world(name, seed)
    assert [o.name for o in built.obstacles] == [o.name for o in world.obstacles]
    assert all(
        np.array_equal(a.footprint, b.footprint)
        for a, b in zip(built.obstacles, world.obstacles, strict=True)
    )


def test_memory_specs_are_seeded_variants_per_family():
    specs = memory_specs(list(MEMORY_FAMILIES), 15)
    assert len(specs) == 60
    assert all(spec.memory for spec in specs)
    assert len({spec.label for spec in specs}) == 60
    # Seeds move the boxes: two variants of one family differ.
    first, second = (memory_trial('memory-slalom', seed).world for seed in (0, 1))
    assert not np.allclose(first.obstacles[-1].footprint, second.obstacles[-1].footprint)
    shelf = memory_trial('memory-shelf', 0)
    assert shelf.waypoints == ((2.5, 0.0),)


def test_unknown_memory_trial_is_refused():
    from scanfuse.evaluate.runner import Evaluation, EvaluationSettings

    with pytest.raises(ConfigError, match=r"unknown memory trial 'maze'; choose from memory-turn"):
        Evaluation(EvaluationSettings.quick(memory=('maze',)))
