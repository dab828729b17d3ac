"""`scanfuse evaluate --params`: the parameter file mounts the robot and bases every method."""

from __future__ import annotations

import math

import pytest
import yaml

from scanfuse.cli import main
from scanfuse.config import FusionConfig
from scanfuse.evaluate.cli import settings_of
from scanfuse.evaluate.closed_loop import TURNING_TRIALS
from scanfuse.evaluate.mapping import GridSpec, OccupancyGrid, compare_maps, rasterize_footprints
from scanfuse.evaluate.methods import METHODS
from scanfuse.evaluate.runner import Evaluation, EvaluationSettings, base_config, make_simulation
from scanfuse.evaluate.terrain_trials import TERRAIN_FAMILIES
from scanfuse.sim.errors import SimError
from scanfuse.sim.sensors import camera_profile

# None of these is a default (RobotSpec: camera 20 degrees down at 0.45 m; FusionConfig:
# slab top 0.5 m, obstacle_min_points 16, memory_radius 2 m), so seeing one proves the file.
FILE_VALUES = {
    'camera_pitch': 0.45,
    'camera_height': 0.40,
    'max_obstacle_height': 0.25,
    'obstacle_min_points': 5,
    'memory_radius': 1.5,
}


def parameter_file(tmp_path, values):
    path = tmp_path / 'robot.yaml'
    path.write_text(yaml.safe_dump({'scanfuse': {'ros__parameters': values}}), encoding='utf-8')
    return path


def test_parameters_mount_the_simulated_robot_and_base_every_method():
    settings = EvaluationSettings.quick(params=dict(FILE_VALUES))
    sim = make_simulation(TURNING_TRIALS['turn-in-place'], settings)
    try:
        assert sim.robot.camera_pitch == pytest.approx(0.45)
        assert sim.robot.camera_height == pytest.approx(0.40)
        # The ground truth's slab is the file's too, so the score asks what the file asks.
        assert sim.config.max_obstacle_height == pytest.approx(0.25)
        base = base_config(sim, settings)
    finally:
        sim.close()
    assert (base.camera_pitch, base.obstacle_min_points, base.memory_radius) == (0.45, 5, 1.5)
    camera = camera_profile('d435').model(256, 144)
    obstacle = METHODS['obstacle'].config(base, camera)
    assert (obstacle.obstacle_min_points, obstacle.camera_height) == (5, pytest.approx(0.40))
    # A method keeps what defines it whatever the file says.
    with_memory = EvaluationSettings.quick(params={**FILE_VALUES, 'memory': True})
    sim = make_simulation(TURNING_TRIALS['turn-in-place'], with_memory)
    try:
        no_memory = METHODS['obstacle-no-memory'].config(base_config(sim, with_memory), camera)
    finally:
        sim.close()
    assert no_memory.memory is False


def test_without_parameters_the_robot_is_the_simulators_own():
    settings = EvaluationSettings.quick()
    assert settings.fusion_base() is None
    sim = make_simulation(TURNING_TRIALS['turn-in-place'], settings)
    try:
        # RobotSpec's camera: 20 degrees down.
        assert sim.robot.camera_pitch == pytest.approx(math.radians(20.0), abs=1e-3)
    finally:
        sim.close()


def test_a_mounting_the_simulator_cannot_build_is_refused_before_any_trial():
    with pytest.raises(SimError, match=r'camera_y=0\.1.*set camera_y to 0'):
        Evaluation(EvaluationSettings.quick(params={'camera_y': 0.1}))
    # Only the default robot follows the file: AMR trials alone keep the AMR as built.
    amr_only = EvaluationSettings.quick(worlds=(), turning=(), params={'camera_y': 0.1})
    assert Evaluation(amr_only).amr_specs


def test_a_lidar_off_the_centre_line_is_mounted_there():
    settings = EvaluationSettings.quick(params={'lidar_y': 0.1})
    sim = make_simulation(TURNING_TRIALS['turn-in-place'], settings)
    try:
        assert sim.robot.lidar_y == pytest.approx(0.1)
        assert base_config(sim, settings).lidar_y == pytest.approx(0.1)
        # The LiDAR's origin in the world: 0.1 m to the left of the base (the robot faces +x).
        frame = sim.lidar_frame()
        assert frame.origin[1] - frame.pose.y == pytest.approx(0.1, abs=2e-3)
    finally:
        sim.close()


def test_evaluate_params_changes_what_the_run_used(tmp_path):
    path = parameter_file(tmp_path, {'camera_pitch': 0.45, 'obstacle_min_points': 5})
    out = tmp_path / 'eval'
    argv = ['evaluate', '--out', str(out), '--quick', '--worlds', 'barricade', '--trials', '0']
    assert main([*argv, '--params', str(path)]) == 0
    # scanfuse.yaml is built from the simulated robot the trials ran with.
    used = FusionConfig.from_ros_params(out / 'scanfuse.yaml')
    assert (used.camera_pitch, used.obstacle_min_points) == (0.45, 5)
    recorded = yaml.safe_load((out / 'evaluation.yaml').read_text(encoding='utf-8'))
    assert recorded['params'] == {'camera_pitch': 0.45, 'obstacle_min_points': 5}


def test_terrain_trials_sets_the_seeded_variants_of_every_terrain_family():
    settings = settings_of(quick=False, worlds='terrain', trials=0, terrain_trials=10)
    specs = Evaluation(settings).terrain_specs
    assert len(specs) == 10 * len(TERRAIN_FAMILIES)
    assert sorted({spec.seed for spec in specs}) == list(range(10))
    # Without the option: the full run's 5, the quick run's 1.
    assert settings_of(quick=False).terrain_trials == 5
    assert settings_of(quick=True).terrain_trials == 1


def test_fewer_than_one_terrain_trial_is_refused_before_any_work(tmp_path, capsys):
    assert main(['evaluate', '--out', str(tmp_path / 'e'), '--terrain-trials', '0']) == 1
    assert '--terrain-trials must be 1 or more, got 0' in capsys.readouterr().err
    assert not (tmp_path / 'e').exists()


def test_evaluate_params_errors_are_one_line(tmp_path, capsys):
    bad = parameter_file(tmp_path, {'obstacle_min_points': 0})
    assert main(['evaluate', '--out', str(tmp_path / 'e'), '--params', str(bad)]) == 1
    assert 'obstacle_min_points' in capsys.readouterr().err
    missing = tmp_path / 'absent.yaml'
    assert main(['evaluate', '--out', str(tmp_path / 'e'), '--params', str(missing)]) == 1
    assert 'cannot read parameter file' in capsys.readouterr().err
    assert not (tmp_path / 'e').exists()


def test_maps_are_drawn_from_the_lidars_heading_not_the_robots():
    # A LiDAR mounted turned a quarter turn left (lidar_yaw from the file): its angle 0
    # points along the robot's +y. Its scan drawn at its own heading lands on the walls and
    # boxes; drawn at the robot's yaw the same scan is turned 90 degrees off them.
    settings = EvaluationSettings.quick(params={'lidar_yaw': 0.5 * math.pi}, noise=False)
    sim = make_simulation(TURNING_TRIALS['turn-in-place'], settings)
    try:
        frame = sim.lidar_frame()
        world = sim.world
    finally:
        sim.close()
    assert frame.lidar_yaw == pytest.approx(frame.pose.yaw + 0.5 * math.pi, abs=1e-6)
    spec = GridSpec.covering(world.bounds, 0.05, margin=0.3)
    truth = rasterize_footprints(spec, [o.footprint for o in world.obstacles])
    precision = {}
    for name, yaw in (('lidar', frame.lidar_yaw), ('robot', frame.pose.yaw)):
        grid = OccupancyGrid(spec)
        grid.integrate(frame.scan, frame.origin[0], frame.origin[1], yaw)
        precision[name] = compare_maps(grid, truth).precision
    assert precision['lidar'] > 0.99  # noise off: every marked cell within a cell of a surface
    # The room is a square about 0.3 m from the robot: turned 90 degrees, its walls fall partly
    # on its own walls again, so the wrong heading still scores some precision, not most.
    assert precision['robot'] < 0.8
