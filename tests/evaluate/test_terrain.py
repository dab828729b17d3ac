"""Terrain trials: seeded families, mounting errors injected, a quick run end to end."""

from __future__ import annotations

import math
from dataclasses import asdict, replace

import numpy as np
import pytest

from scanfuse.config import FusionConfig
from scanfuse.errors import ConfigError
from scanfuse.evaluate.cli import parse_worlds, with_scored
from scanfuse.evaluate.groundtruth import SlotTruthBuilder
from scanfuse.evaluate.report import terrain_source_rows
from scanfuse.evaluate.results import EvaluationResult
from scanfuse.evaluate.runner import Evaluation, EvaluationSettings, terrain_simulation
from scanfuse.evaluate.terrain_trials import (
    BRAKE_GAP,
    TERRAIN_FAMILIES,
    terrain_specs,
    terrain_trial,
)
from scanfuse.evaluate.write import run_evaluation
from scanfuse.scan import Scan
from scanfuse.sim.robot import SPRUNG
from scanfuse.sim.sensors import camera_profile, lidar_profile
from scanfuse.sim.simulation import ImuNoise, LidarFrame
from scanfuse.sim.worlds import TERRAIN_WORLDS, Ground, Pose2D, box_on_ground
from scanfuse.transforms import Extrinsics


def test_the_full_run_holds_at_least_30_seeded_terrain_trials():
    settings = EvaluationSettings()
    assert 'terrain' in settings.worlds
    evaluation = Evaluation(settings)
    assert len(evaluation.terrain_specs) >= 30
    assert {spec.world for spec in evaluation.terrain_specs} == set(TERRAIN_FAMILIES)
    # Seeded variants differ: the boxes move.
    first, second = (terrain_trial('terrain-ramp-12', seed).world for seed in (0, 1))
    boxes = [
        [(o.name, o.footprint.mean(axis=0).tolist(), o.z_max) for o in world.obstacles]
        for world in (first, second)
    ]
    assert boxes[0] != boxes[1]
    # `obstacle` with the ground estimate off is a method of its own, driven on terrain.
    assert 'obstacle-no-ground' in settings.terrain_methods


def test_ramp_goals_lie_past_the_ramp_and_brake_goals_short_of_the_box():
    for name in ('terrain-ramp-12', 'terrain-ramp-8', 'terrain-ledge', 'terrain-mount'):
        trial = terrain_trial(name, 0)
        end = max(piece.rectangle[1] for piece in trial.world.ground)
        assert trial.goal[0] > end
    for seed in (0, 1):
        trial = terrain_trial('terrain-brake', seed)
        assert trial.brake
        # The stop point: half the allowed gap short of the box, the robot's radius before.
        assert trial.box_face - trial.goal[0] == pytest.approx(SPRUNG.body_radius + BRAKE_GAP / 2)
    # Odd seeds brake on a 1:12 ramp's platform.
    assert terrain_trial('terrain-brake', 1).world.ground


@pytest.mark.parametrize(
    ('seed', 'pitch', 'height'),
    [(0, 2.0, -0.03), (1, -2.0, -0.03), (2, 2.0, 0.03), (3, -2.0, 0.03)],
)
def test_the_mount_trials_camera_is_off_what_its_parameters_say(seed, pitch, height):
    spec = terrain_specs(('terrain-mount',), 4)[seed]
    sim, described, transforms = terrain_simulation(spec, EvaluationSettings.quick())
    try:
        simulated = sim.robot
        # The parameters (and /tf_static) say the sprung robot's mounting ...
        assert described.camera_pitch == pytest.approx(SPRUNG.camera_pitch)
        assert described.camera_height == pytest.approx(SPRUNG.camera_height)
        camera_link = next(t for t in transforms if t.child == 'camera_link')
        assert camera_link.translation[2] == pytest.approx(SPRUNG.camera_height)
        # ... the simulated camera sits 2 degrees and 3 cm off it.
        assert math.degrees(simulated.camera_pitch - described.camera_pitch) == pytest.approx(pitch)
        assert simulated.camera_height - described.camera_height == pytest.approx(height)
        assert simulated.suspension == SPRUNG.suspension
    finally:
        sim.close()


def test_terrain_names_are_checked():
    assert parse_worlds('terrain,ledge') == ('terrain', 'ledge')
    # The terrain worlds are the terrain trials' own, not evaluation worlds of their own.
    for name in TERRAIN_WORLDS:
        with pytest.raises(ConfigError, match=rf'unknown world\(s\) {name}; choose from'):
            parse_worlds(name)
    with pytest.raises(ConfigError, match=r"unknown terrain trial 'terrain-moon'; choose from"):
        Evaluation(EvaluationSettings.quick(terrain=('terrain-moon',)))
    with pytest.raises(ConfigError, match=r"unknown terrain method 'sonar'; choose from lidar"):
        Evaluation(EvaluationSettings.quick(terrain_methods=('sonar',)))
    with pytest.raises(ConfigError, match=r"unknown method 'sonar'; choose from lidar"):
        Evaluation(EvaluationSettings.quick(terrain_scored=('sonar',)))


def test_a_quick_terrain_evaluation_runs_end_to_end(tmp_path):
    # Braking hard before a low box on a flat floor (seed 0): the fused robot stops short of
    # it; the LiDAR alone cannot see it (6-12 cm, under its plane) and drives into it.
    settings = EvaluationSettings.quick(
        worlds=('terrain',),
        terrain=('terrain-brake',),
        terrain_methods=('lidar', 'obstacle'),
        methods=('lidar', 'obstacle', 'obstacle-no-ground'),
        closed_loop_methods=(),
        turning=(),
        amr=(),
    )
    result = run_evaluation(tmp_path, settings)
    assert {o.method for o in result.terrain_trials} == {'lidar', 'obstacle'}
    fused = next(o for o in result.terrain_trials if o.method == 'obstacle')
    lidar = next(o for o in result.terrain_trials if o.method == 'lidar')
    assert not fused.collided
    assert fused.reached
    assert 0.0 <= fused.final_distance <= BRAKE_GAP
    assert lidar.collided
    assert lidar.first_contact_kind == 'low_box'
    # The body pitched braking (and setting off) 1.5-3 degrees. This is the IMU's peak
    # reading over the trial, which its noise (0.1 degree a sample) lifts above the body's
    # peak: up to 3 sigmas more is allowed here. The body's own pitch is held to <= 3.0 by
    # test_the_sprung_body_pitches_1_5_to_3_degrees_braking_hard_and_setting_off
    # (tests/sim/test_sim_terrain.py).
    noise = math.degrees(ImuNoise().orientation)
    assert 1.5 <= fused.peak_pitch <= 3.0 + 3.0 * noise
    # Every scored method has terrain scan metrics; the drivers have their closed loop.
    assert set(result.terrain) == {'lidar', 'obstacle', 'obstacle-no-ground'}
    assert result.terrain['obstacle'].scan.slots > 0
    assert result.terrain['obstacle-no-ground'].closed_loop is None
    loop = result.terrain['obstacle'].closed_loop
    assert loop is not None
    assert (loop.trials, loop.collisions, loop.falls, loop.reached) == (1, 0, 0, 1)
    # Not on a slope (a flat corridor): no scan counts as on one.
    assert result.terrain['obstacle'].scan_slopes.slots == 0
    # Written, and read back the same.
    report = (tmp_path / 'report.md').read_text(encoding='utf-8')
    assert '## Terrain' in report
    assert 'terrain-brake-0' in report
    assert (tmp_path / 'terrain.png').is_file()
    assert (tmp_path / 'terrain_pitch.png').is_file()
    loaded = EvaluationResult.load(tmp_path / 'results.json')
    assert loaded.terrain['obstacle'].closed_loop == loop
    assert [o.trial for o in loaded.terrain_trials] == [o.trial for o in result.terrain_trials]
    assert replace(loaded.terrain_trials[0]).peak_pitch == pytest.approx(
        result.terrain_trials[0].peak_pitch
    )


def test_a_scored_method_with_parameters_changed_is_scored_on_the_same_drives(tmp_path):
    # The variants restate `obstacle` and `obstacle-no-memory`: scored on the same scans,
    # they must tally to the slot what those do (a drive of their own would differ).
    settings = with_scored(
        EvaluationSettings.quick(
            worlds=('terrain',),
            terrain=('terrain-brake',),
            terrain_methods=('obstacle',),
            methods=('obstacle', 'obstacle-no-memory'),
            terrain_scored=('obstacle', 'obstacle-no-memory'),
            closed_loop_methods=(),
            turning=(),
            amr=(),
        ),
        ['obstacle[memory=true]', 'obstacle[memory=false]', 'obstacle[memory=false]'],
    )
    assert settings.terrain_scored == (
        'obstacle',
        'obstacle-no-memory',
        'obstacle[memory=true]',
        'obstacle[memory=false]',
    )
    result = run_evaluation(tmp_path, settings)
    assert result.terrain['obstacle'].scan.slots > 0
    for variant, method in (
        ('obstacle[memory=true]', 'obstacle'),
        ('obstacle[memory=false]', 'obstacle-no-memory'),
    ):
        for metrics in ('scan', 'scan_slopes'):
            np.testing.assert_equal(  # NaN (no low obstacle near) equals NaN
                asdict(getattr(result.terrain[variant], metrics)),
                asdict(getattr(result.terrain[method], metrics)),
            )
    # Scored, not driven.
    assert result.terrain['obstacle[memory=false]'].closed_loop is None
    assert {o.method for o in result.terrain_trials} == {'obstacle'}


def test_slot_truth_on_a_platform_the_lidars_plane_lies_higher():
    # A platform 0.15 m high from x = 1 to 4; a box on it 0.15-0.40 m in the world's z (0.25 m
    # above the platform), its near face at x = 2.5. From the floor the LiDAR's plane (0.30 m)
    # crosses the box: the plane sees it, no low obstacle. From the platform (LiDAR at 0.45 m)
    # the plane passes over it: it is a low obstacle, seen by the slab alone.
    platform = Ground('platform', 'platform', (1.0, 4.0, -1.0, 1.0), 0.15, 0.15)
    on_top = box_on_ground('box', (platform,), (2.65, 0.0), (0.15, 0.2), 0.25)
    assert (on_top.z_min, on_top.z_max, on_top.ground) == pytest.approx((0.15, 0.40, 0.15))
    grid = lidar_profile('rplidar-a2').grid
    builder = SlotTruthBuilder(
        (on_top,),
        grid,
        min_obstacle_height=0.03,
        max_obstacle_height=0.5,
        range_max=12.0,
        camera=camera_profile('d435').model(640, 480),
        extrinsics=Extrinsics.from_config(FusionConfig(camera_x=0.12, lidar_height=0.30)),
    )
    ahead = int(np.argmin(np.abs(grid.angles())))
    scan = Scan(
        angle_min=grid.angle_min,
        angle_max=grid.angle_min + grid.angle_increment * (grid.count - 1),
        angle_increment=grid.angle_increment,
        range_min=0.15,
        range_max=12.0,
        ranges=np.full(grid.count, np.inf, dtype=np.float32),
    )
    floor = builder.build(LidarFrame(0, scan, scan, Pose2D(0.5, 0.0, 0.0), (0.5, 0.0, 0.30)))
    assert floor.truth[ahead] == pytest.approx(2.0, abs=1e-6)
    assert floor.plane[ahead] == pytest.approx(2.0, abs=1e-6)
    on_platform = builder.build(LidarFrame(0, scan, scan, Pose2D(1.5, 0.0, 0.0), (1.5, 0.0, 0.45)))
    assert on_platform.truth[ahead] == pytest.approx(1.0, abs=1e-6)
    assert math.isinf(on_platform.plane[ahead])
    # The box's top, 0.40 m, is 0.05 m below the LiDAR there: the camera (0.60 m up,
    # pitched 20 degrees down) sees it 1 m ahead.
    assert on_platform.in_view[ahead]


@pytest.mark.parametrize('family', sorted(TERRAIN_FAMILIES))
def test_every_full_run_variant_builds_with_its_start_and_goal_clear(family):
    for spec in terrain_specs((family,), EvaluationSettings().terrain_trials):
        trial = terrain_trial(spec.world, spec.seed)
        world = trial.world
        for point, clearance in (
            ((world.start.x, world.start.y), SPRUNG.body_radius + 0.1),
            (trial.goal, 0.0 if trial.brake else SPRUNG.body_radius),
        ):
            for obstacle in world.obstacles:
                footprint = obstacle.footprint
                nearest = np.min(np.hypot(*(footprint - np.asarray(point)).T))
                inside = np.all(point >= footprint.min(axis=0)) and np.all(
                    point <= footprint.max(axis=0)
                )
                assert nearest > clearance, (spec.label, obstacle.name)
                assert not inside, (spec.label, obstacle.name)
        x_min, x_max, y_min, y_max = world.bounds
        assert x_min < trial.goal[0] < x_max
        assert y_min < trial.goal[1] < y_max
        # Every variant compiles in MuJoCo, the sprung robot settled at its start.
        sim, _, _ = terrain_simulation(spec, EvaluationSettings.quick())
        try:
            assert sim.base_drop() == pytest.approx(0.0, abs=1e-9)
            assert not sim.contacts()
        finally:
            sim.close()


def test_false_obstacles_on_slopes_add_up_over_the_sources_that_made_them(tmp_path):
    # Braking on a 1:12 ramp's platform (seed 1): every scan lies on or near the ramp.
    settings = EvaluationSettings.quick(
        worlds=('terrain',),
        terrain=('terrain-brake',),
        terrain_trials=2,
        terrain_methods=('obstacle',),
        methods=('lidar', 'obstacle', 'obstacle-no-memory'),
        terrain_scored=('lidar', 'obstacle', 'obstacle-no-memory'),
        closed_loop_methods=(),
        turning=(),
        amr=(),
    )
    evaluation = Evaluation(settings)
    evaluation.terrain_specs = [spec for spec in evaluation.terrain_specs if spec.seed == 1]
    assert terrain_trial('terrain-brake', 1).world.ground  # the ramp is there
    evaluation.run()
    result = evaluation.result([])
    for name in ('obstacle', 'obstacle-no-memory'):
        terrain = result.terrain[name]
        slots = terrain.scan_slopes.slots
        assert slots > 0
        false = round(terrain.scan_slopes.false_obstacle_rate * slots)
        assert set(terrain.slope_false_sources) == {'LiDAR', 'camera', 'memory'}
        assert sum(terrain.slope_false_sources.values()) == false
    # Without memory, the memory makes none; the LiDAR alone is no fusion to split.
    assert result.terrain['obstacle-no-memory'].slope_false_sources['memory'] == 0
    assert result.terrain['lidar'].slope_false_sources == {}
    # In the report, and read back the same.
    assert [row[0] for row in terrain_source_rows(result)] == ['obstacle', 'obstacle-no-memory']
    loaded = EvaluationResult.load(result.save(tmp_path / 'results.json'))
    assert loaded.terrain['obstacle'].slope_false_sources == (
        result.terrain['obstacle'].slope_false_sources
    )
