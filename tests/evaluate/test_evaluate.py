"""The method registry, ground truth per slot, results files, and `scanfuse evaluate --quick`."""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanfuse.cli import main
from scanfuse.config import FusionConfig, Method, Resampler
from scanfuse.errors import ConfigError
from scanfuse.evaluate.closed_loop import clutter_goal, map_to_odom, odom_to_world, world_to_odom
from scanfuse.evaluate.groundtruth import SlotTruthBuilder
from scanfuse.evaluate.methods import METHODS, MethodStream, method_spec
from scanfuse.evaluate.results import EvaluationResult, ResultsError
from scanfuse.scan import Scan
from scanfuse.sim.sensors import camera_profile, lidar_profile
from scanfuse.sim.simulation import DepthFrame, LidarFrame
from scanfuse.sim.worlds import Pose2D, barricade_world, make_world
from scanfuse.transforms import Extrinsics

CAMERA = camera_profile('d435').model(640, 480)
BASE = FusionConfig(camera_x=0.12, camera_height=0.45, lidar_height=0.30)


def test_methods_are_config_variants_of_the_one_pipeline():
    assert METHODS['lidar'].fuses is False
    centre = METHODS['row-centre'].config(BASE, CAMERA)
    assert (centre.method, centre.resample, centre.scan_row) == (
        Method.ROW,
        Resampler.CONSERVATIVE,
        None,
    )
    assert METHODS['row-centre-linear'].config(BASE, CAMERA).resample is Resampler.LINEAR
    low = METHODS['row-low'].config(BASE, CAMERA)
    # Half way from the centre row (cy = 239.5 -> 240) to the last row (479): row 360.
    assert low.scan_row == 360
    assert low.floor_guard is True
    d2l = METHODS['d2l'].config(BASE, CAMERA)
    assert d2l.d2l_compat is True
    assert d2l.scan_height == 10
    assert METHODS['obstacle'].config(BASE, CAMERA).method is Method.OBSTACLE
    assert METHODS['obstacle'].config(BASE, CAMERA).motion_compensation is True
    uncompensated = METHODS['obstacle-uncompensated'].config(BASE, CAMERA)
    assert (uncompensated.method, uncompensated.motion_compensation) == (Method.OBSTACLE, False)
    # The robot's mounting is kept by every variant.
    assert all(METHODS[n].config(BASE, CAMERA).camera_x == 0.12 for n in METHODS)


def test_unknown_method():
    with pytest.raises(ConfigError, match="unknown method 'nope'"):
        method_spec('nope')


def test_a_method_with_parameters_changed_is_its_base_with_them():
    variant = method_spec('obstacle[memory=false, ground_smoothing=0.5]')
    config = variant.config(BASE, CAMERA)
    assert config == METHODS['obstacle'].config(BASE, CAMERA).with_changes(
        memory=False, ground_smoothing=0.5
    )
    assert config.range_max == 3.0  # the base's own change kept
    assert variant.imu is True
    assert 'memory=false' in variant.description
    # A change of one of the base's own parameters replaces it.
    assert method_spec('obstacle[range_max=4.0]').config(BASE, CAMERA).range_max == 4.0
    # The base's IMU choice is kept.
    assert method_spec('obstacle-no-ground[memory=false]').imu is False


@pytest.mark.parametrize(
    ('name', 'message'),
    [
        ('obstacle[memroy=false]', 'did you mean memory'),
        ('obstacle[ground_smoothing=2.0]', 'ground_smoothing'),
        ('obstacle[memory]', "'memory' is not NAME=VALUE"),
        ('lidar[memory=false]', "unknown method 'lidar\\[memory=false\\]'"),
        ('sonar[memory=false]', 'unknown method'),
    ],
)
def test_a_wrong_parameter_change_is_refused_by_name(name, message):
    with pytest.raises(ConfigError, match=message):
        method_spec(name)


def wall_scan(distance: float) -> Scan:
    grid = lidar_profile('rplidar-a2').grid
    return Scan(
        grid.angle_min,
        grid.angle_max,
        grid.angle_increment,
        0.15,
        12.0,
        np.full(grid.count, distance, dtype=np.float32),
    )


def test_lidar_method_passes_the_scan_through_and_fusion_only_adds():
    scan = wall_scan(5.0)
    frame = LidarFrame(2_000_000_000, scan, scan, Pose2D(0.0, 0.0, 0.0), (0.0, 0.0, 0.3))
    # A wall at Z = 1 m filling the image reaches into the collision slab:
    # fusion shortens slots in view, and never lengthens any.
    depth = np.full((CAMERA.height, CAMERA.width), 1000, dtype=np.uint16)
    image = DepthFrame(1_980_000_000, depth, CAMERA, delivered_ns=1_990_000_000)
    lidar = MethodStream('lidar', BASE, CAMERA)
    assert lidar.add_depth(image, 'camera_depth_optical_frame') == []
    # The LiDAR alone: the driver's scan, released as it arrives.
    assert lidar.add_scan(frame) == [(frame, scan)]
    obstacle = MethodStream('obstacle', BASE, CAMERA)
    # No image yet: the LiDAR scan as it is (no CameraInfo: passed through).
    assert obstacle.add_scan(frame) == [(frame, scan)]
    assert obstacle.add_depth(image, 'camera_depth_optical_frame') == []
    later = LidarFrame(
        2_010_000_000,
        scan.with_ranges(scan.ranges, stamp_ns=2_010_000_000),
        scan,
        Pose2D(0.0, 0.0, 0.0),
        (0.0, 0.0, 0.3),
    )
    [(released, fused)] = obstacle.add_scan(later)
    assert released is later
    assert np.all(fused.ranges <= scan.ranges)
    assert np.any(fused.ranges < 2.0)
    counts = obstacle.counts
    assert counts is not None
    # Fused once (30 ms between the image and the scan, within max_time_offset), no odometry.
    assert (counts.scans, counts.fused, counts.compensated, counts.passed_through) == (2, 1, 0, 1)


def test_slot_truth_in_the_barricade_world():
    world = barricade_world()
    grid = lidar_profile('rplidar-a2').grid
    builder = SlotTruthBuilder(
        world.obstacles,
        grid,
        min_obstacle_height=0.03,
        max_obstacle_height=0.5,
        range_max=12.0,
        camera=CAMERA,
        extrinsics=Extrinsics.from_config(BASE),
    )
    scan = wall_scan(5.0)
    frame = LidarFrame(0, scan, scan, Pose2D(0.0, 0.0, 0.0), (0.0, 0.0, 0.30))
    truth = builder.build(frame)
    ahead = int(np.argmin(np.abs(grid.angles())))
    behind = int(np.argmin(np.abs(np.abs(grid.angles()) - math.pi)))
    # The base's vertex points at the robot: 2.0 - 0.35 m; the LiDAR plane cuts the
    # cylinder of radius 0.12: 1.88 m.
    assert truth.truth[ahead] == pytest.approx(1.65, abs=1e-3)
    assert truth.plane[ahead] == pytest.approx(1.88, abs=1e-3)
    assert truth.kinds[ahead] == 'barricade_base'
    assert truth.in_view[ahead]
    # Behind: the wall at x = -1.5, seen by both, not in the camera's view.
    assert truth.truth[behind] == pytest.approx(1.5, abs=1e-3)
    assert truth.plane[behind] == pytest.approx(1.5, abs=1e-3)
    assert truth.kinds[behind] == 'wall'
    assert not truth.in_view[behind]


def test_odometry_frame_round_trip():
    start = Pose2D(-2.2, 0.5, math.pi / 2)
    x, y = world_to_odom(start, -2.2, 1.5)
    # One metre along the start heading (+y in the world) is x = 1 in odometry.
    assert (x, y) == pytest.approx((1.0, 0.0))
    back = odom_to_world(start, Pose2D(x, y, 0.0))
    assert (back.x, back.y) == pytest.approx((-2.2, 1.5))


def test_a_map_goal_follows_the_robot_into_a_drifted_odometry_frame():
    # On the map the robot is at (1, 2) facing +y; its odometry says (0.5, 0) facing +x.
    to_odom = map_to_odom(Pose2D(1.0, 2.0, math.pi / 2), Pose2D(0.5, 0.0, 0.0))
    assert to_odom(1.0, 3.0) == pytest.approx((1.5, 0.0))  # 1 m ahead of the robot
    assert to_odom(0.0, 2.0) == pytest.approx((0.5, 1.0))  # 1 m to its left
    assert to_odom(1.0, 2.0) == pytest.approx((0.5, 0.0))  # where it stands


def test_clutter_goal_lies_behind_a_low_obstacle():
    world = make_world('clutter', 3)
    goal = np.array(clutter_goal(world))
    start = np.array([world.start.x, world.start.y])
    low = [o for o in world.obstacles if o.kind in {'low_box', 'lamp_base', 'cable_tray'}]

    # Some low obstacle's centre lies on the segment from the start to the goal.
    def on_segment(point):
        t = np.dot(point - start, goal - start) / np.dot(goal - start, goal - start)
        return 0.0 < t < 1.0 and np.linalg.norm(start + t * (goal - start) - point) < 1e-6

    assert any(on_segment(o.footprint.mean(axis=0)) for o in low)


def test_results_file_must_be_ours(tmp_path):
    with pytest.raises(ResultsError, match=r'not a scanfuse results\.json'):
        EvaluationResult.from_json('{"a": 1}')
    with pytest.raises(ResultsError, match='version 99'):
        EvaluationResult.from_json('{"version": 99}')


def test_evaluate_rejects_unknown_worlds(tmp_path):
    assert main(['evaluate', '--out', str(tmp_path), '--worlds', 'moon']) == 1


def test_evaluate_quick_runs_and_round_trips(tmp_path):
    out = tmp_path / 'eval'
    code = main(
        ['evaluate', '--out', str(out), '--quick', '--worlds', 'barricade', '--trials', '0']
    )
    assert code == 0
    for name in (
        'report.md',
        'results.json',
        'scanfuse.yaml',
        'metrics.png',
        'scans_barricade.png',
    ):
        assert (out / name).is_file(), name
    assert (out / 'maps' / 'barricade-0_obstacle.yaml').is_file()
    assert (out / 'maps_barricade-0_lidar_run.png').is_file()
    assert (out / 'map_after_collision_barricade-0.png').is_file()
    assert (out / 'costmap_turn-in-place.png').is_file()
    result = EvaluationResult.load(out / 'results.json')
    # NaN is stored as null and read back as NaN: a second round trip is the same text.
    assert EvaluationResult.from_json(result.to_json()).to_json() == result.to_json()
    assert set(result.methods) == set(METHODS)
    # The resolved configuration is a parameter file scanfuse loads again.
    assert FusionConfig.from_ros_params(out / 'scanfuse.yaml').camera_x == pytest.approx(0.12)
    # The barricade's base is a low obstacle the LiDAR misses and the obstacle scan sees.
    assert result.methods['lidar'].scan.recall < 0.2
    assert result.methods['obstacle'].scan.recall > 0.8
    # Closed loop: one trial each for lidar and obstacle; the base stops only the LiDAR robot.
    lidar_loop = result.methods['lidar'].closed_loop
    obstacle_loop = result.methods['obstacle'].closed_loop
    assert lidar_loop is not None
    assert obstacle_loop is not None
    assert (lidar_loop.trials, lidar_loop.collisions) == (1, 1)
    assert (obstacle_loop.trials, obstacle_loop.collisions) == (1, 0)
    assert result.compare(result)['obstacle']['collisions'] == 0
    report = (out / 'report.md').read_text()
    assert 'obstacle' in report
    # The report states the sensor timing the numbers were measured under.
    for fact in ('LiDAR rplidar-a2 at 10 Hz', 'depth camera at 15 Hz', '40 ms later', '50 Hz'):
        assert fact in report, fact
    # Every scored scan went through each method's stream; with the wheel odometry every
    # fused scan of `obstacle` was compensated and de-skewed, none of the uncompensated one.
    compensated = result.methods['obstacle'].stream
    uncompensated = result.methods['obstacle-uncompensated'].stream
    assert compensated['scans'] == uncompensated['scans'] > 0
    assert compensated['compensated'] == compensated['fused'] == compensated['scans']
    assert compensated['deskewed'] == compensated['scans']
    assert uncompensated['compensated'] == uncompensated['deskewed'] == 0
    assert result.methods['lidar'].stream == {}
    # Turning in place at 1.5 rad/s a scan's last beams come 0.15 rad after its first and
    # an image up to 33 ms (3 degrees) from the scan: uncompensated, walls and boxes move
    # off their true slots, compensated they do not.
    turning = {
        name: result.methods[name].scan_by_world['turn-in-place']
        for name in ('obstacle-no-memory', 'obstacle-uncompensated')
    }
    compensated_turn, uncompensated_turn = turning.values()
    assert compensated_turn.false_obstacle_rate < 0.005
    assert uncompensated_turn.false_obstacle_rate > 0.02
    assert compensated_turn.median_error < uncompensated_turn.median_error
    # Turning in place the camera's 87 degrees pass each box once a turn; with memory the
    # boxes stay in the scan out of view, so more low slots near the footprint are held.
    memory_turn = result.methods['obstacle'].scan_by_world['turn-in-place']
    assert memory_turn.low_slots_near == compensated_turn.low_slots_near > 0
    assert memory_turn.recall_near > compensated_turn.recall_near
    # The AMR backs out of its dead end (one seeded trial per method in the quick run). Its
    # box stands under both LiDARs' 0.30 m plane on the straight way out: the merged LiDARs
    # never show it and their robot backs into it; the rear camera shows it.
    assert set(result.robots) == {'amr/lidar', 'amr/obstacle'}
    amr_lidar, amr_obstacle = result.robots['amr/lidar'], result.robots['amr/obstacle']
    assert amr_lidar.scan.low_slots == amr_obstacle.scan.low_slots > 0  # the same scans
    assert amr_lidar.scan.recall < 0.05
    assert amr_obstacle.scan.recall > 0.8
    assert amr_obstacle.scan.recall_near > amr_lidar.scan.recall_near
    assert amr_lidar.closed_loop is not None
    assert amr_obstacle.closed_loop is not None
    assert (amr_lidar.closed_loop.trials, amr_lidar.closed_loop.reversing_collisions) == (1, 1)
    assert (amr_obstacle.closed_loop.trials, amr_obstacle.closed_loop.collisions) == (1, 0)
    assert result.headline()['amr/lidar']['reversing_collisions'] == 1
    assert '## Two-LiDAR AMR, reversing' in report
    assert 'collisions when reversing' in report
    # Every method is defined where its name appears: in report.md and under the terminal's
    # table, which fits 80 columns with nothing cut off.
    from scanfuse.evaluate.report import table

    terminal = str(table(result))
    assert max(len(line) for line in terminal.splitlines()) <= 80
    assert '\u2026' not in terminal  # rich's ellipsis
    flat = ' '.join(terminal.split())
    for name, spec in METHODS.items():
        assert f'- `{name}`: {spec.description}' in report
        assert f'{name}: {spec.description}' in flat


def test_unknown_turning_trial_is_refused():
    from scanfuse.evaluate.runner import Evaluation, EvaluationSettings

    with pytest.raises(ConfigError, match=r"unknown turning trial 'spin'; choose from turn-in"):
        Evaluation(EvaluationSettings.quick(turning=('spin',)))


def test_turning_trials_pass_their_obstacles_without_touching_them():
    from scanfuse.evaluate.closed_loop import (
        ARC_RATE,
        ARC_SPEED,
        TURNING_TRIALS,
        turning_world,
    )

    assert set(TURNING_TRIALS) == {'turn-in-place', 'arc'}
    world = turning_world()
    radius = ARC_SPEED / ARC_RATE  # 0.4 / 0.8: 0.5 m, to the left of the start heading
    assert radius == pytest.approx(0.5)
    low = [o for o in world.obstacles if o.kind in {'low_box', 'lamp_base'}]
    assert len(low) == 4
    robot = 0.18
    for obstacle in world.obstacles:
        if obstacle.kind == 'wall':
            continue
        # The footprint's outline, points at most 1 cm apart.
        corners = obstacle.footprint
        edges = np.roll(corners, -1, axis=0) - corners
        t = np.linspace(0.0, 1.0, 50)[:, None, None]
        outline = (corners[None] + t * edges[None]).reshape(-1, 2)
        # Turning in place at the origin: the chassis sweeps a disc of its radius.
        assert np.hypot(*outline.T).min() > robot + 0.5
        # The arc about (0, 0.5): the chassis sweeps an annulus radius +- 0.18 m.
        off_arc = np.abs(np.hypot(outline[:, 0], outline[:, 1] - radius) - radius)
        assert off_arc.min() > robot + 0.05, obstacle.name
