"""Simulated LiDAR and depth camera against geometry worked out by hand."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from scanfuse.sim import (
    CAMERAS,
    LIDARS,
    DepthNoise,
    LidarNoise,
    RobotSpec,
    SimConfig,
    SimError,
    Simulation,
    make_world,
)
from scanfuse.sim.sensors import camera_profile, depth_edges, depth_image, lidar_profile
from scanfuse.sim.worlds import ROBOT_AT_ORIGIN, World, box

SMALL = (256, 144)
RNG = np.random.default_rng(0)


def quiet(world: str = 'bookshelf', **changes) -> Simulation:
    return Simulation(SimConfig(world=world, resolution=SMALL, noise=False, **changes))


def slot_angles(frame):
    return frame.scan.angles() + frame.pose.yaw


def wall_world(distance: float) -> World:
    """One wide wall whose face (normal -x) is `distance` m ahead of the robot's origin."""
    wall = box('wall_ahead', 'wall', (distance + 0.05, 0.0), (0.05, 20.0), (0.0, 3.0))
    return World('wall', 0, (wall,), ROBOT_AT_ORIGIN, (-1.0, distance, -3.0, 3.0))


# ---------------------------------------------------------------- profiles


def test_lidar_profiles_have_the_datasheet_grids():
    rplidar, hokuyo = LIDARS['rplidar-a2'], LIDARS['hokuyo-ust10lx']
    assert rplidar.count == 1080
    assert rplidar.angle_increment * rplidar.count == pytest.approx(2 * math.pi)
    assert (rplidar.rate, rplidar.range_min, rplidar.range_max) == (10.0, 0.15, 12.0)
    assert hokuyo.count == 1081
    assert math.degrees(hokuyo.angle_min) == pytest.approx(-135.0)
    assert math.degrees(hokuyo.angle_max) == pytest.approx(135.0)
    assert (hokuyo.rate, hokuyo.range_min, hokuyo.range_max) == (40.0, 0.02, 10.0)


def test_d435_field_of_view_follows_its_modes():
    d435 = CAMERAS['d435']
    wide = d435.model(1280, 720)
    # 16:9 modes span the nominal 87 x 58 degrees (square pixels: within 2.5 degrees).
    assert math.degrees(2 * math.atan(360 / wide.fy)) == pytest.approx(58.0)
    assert math.degrees(2 * math.atan(640 / wide.fx)) == pytest.approx(87.0, abs=2.5)
    for width, height in ((640, 480), (848, 480)):
        model = d435.model(width, height)
        assert math.degrees(2 * math.atan((height / 2) / model.fy)) == pytest.approx(58.0)
        assert model.frame_id == 'camera_depth_optical_frame'


def test_unknown_profiles_and_modes_are_refused():
    with pytest.raises(SimError, match=r'unknown LiDAR profile .*rplidar-a2, hokuyo-ust10lx'):
        lidar_profile('velodyne')
    with pytest.raises(SimError, match=r'unknown camera profile .*d435'):
        camera_profile('kinect')
    with pytest.raises(SimError, match='d435 has no 123x45 mode'):
        CAMERAS['d435'].model(123, 45)
    with pytest.raises(SimError, match='lidar_height 5 m is outside'):
        RobotSpec(lidar_height=5)


# ---------------------------------------------------------------- LiDAR geometry


def test_lidar_sees_side_panels_and_wall_through_the_bookshelf_but_truth_sees_boards():
    simulation = quiet('bookshelf')
    frame = simulation.lidar_frame()
    ox, oy, oz = frame.origin
    assert oz == pytest.approx(0.30, abs=1e-3)
    angles = slot_angles(frame)
    tan = np.tan(angles)
    half = np.abs(simulation.lidar_profile.angle_increment) / 2
    forward = np.cos(angles) > 0
    # Rays that cross the whole shelf depth (front x = 2.0, back x = 2.3) inside the gap
    # between the side panels (inner faces at |y| = 0.382) reach the wall at x = 2.8.
    through = forward & (np.abs(oy + tan * (2.3 - ox)) < 0.382 - 1e-3)
    assert through.sum() > 40
    expected_wall = (2.8 - ox) / np.cos(angles[through])
    assert frame.scan.ranges[through] == pytest.approx(expected_wall, abs=1e-4)
    # Rays that meet the front edge of a side panel (x = 2.0, 0.382 < |y| < 0.4).
    at_panel = forward & (np.abs(np.abs(oy + tan * (2.0 - ox)) - 0.391) < 0.008)
    assert at_panel.sum() >= 1
    expected_panel = (2.0 - ox) / np.cos(angles[at_panel])
    assert frame.scan.ranges[at_panel] == pytest.approx(expected_panel, abs=1e-4)
    # The truth sees the board fronts at x = 2.0: the nearest point of each slot's interval.
    front = forward & (np.abs(oy + np.tan(angles + np.sign(angles) * half) * (2.0 - ox)) < 0.382)
    nearest_angle = np.maximum(np.abs(angles[front]) - half, 0.0)
    expected_truth = (2.0 - ox) / np.cos(nearest_angle)
    assert frame.truth.ranges[front] == pytest.approx(expected_truth, abs=1e-4)
    assert np.all(frame.scan.ranges[through] > frame.truth.ranges[through] + 0.7)


def _circle_distance(ox, oy, angles, centre, radius):
    cx, cy = centre
    dx, dy = cx - ox, cy - oy
    along = dx * np.cos(angles) + dy * np.sin(angles)
    across2 = dx * dx + dy * dy - along * along
    return along - np.sqrt(radius * radius - across2)


def test_lidar_sees_the_barricade_cylinder_and_truth_its_polygonal_base():
    simulation = quiet('barricade')
    frame = simulation.lidar_frame()
    ox, oy, _ = frame.origin
    angles = slot_angles(frame)
    ahead = int(np.argmin(np.abs(angles)))
    distance = math.hypot(2.0 - ox, 0.0 - oy)
    assert frame.scan.ranges[ahead] == pytest.approx(distance - 0.12, abs=1e-3)
    # The hexagon's vertex points at the robot: the truth ahead is centre distance - 0.35.
    assert frame.truth.ranges[ahead] == pytest.approx(distance - 0.35, abs=1e-4)
    # Every slot whose ray meets the cylinder reads the ray-circle distance.
    dx, dy = 2.0 - ox, -oy
    across = np.abs(-dx * np.sin(angles) + dy * np.cos(angles))
    on_cylinder = (np.cos(angles) > 0) & (across < 0.12 - 0.005)
    assert on_cylinder.sum() >= 8
    expected = _circle_distance(ox, oy, angles[on_cylinder], (2.0, 0.0), 0.12)
    # The cylinder is a polygon only for the truth; MuJoCo's is round.
    assert frame.scan.ranges[on_cylinder] == pytest.approx(expected, abs=1e-4)
    assert np.all(frame.truth.ranges[on_cylinder] < frame.scan.ranges[on_cylinder] - 0.15)


def test_lidar_reports_rep117_limits():
    simulation = Simulation(
        SimConfig(world='barricade', lidar='hokuyo-ust10lx', resolution=SMALL, noise=False),
        world=make_world('barricade'),
    )
    frame = simulation.lidar_frame()
    assert len(frame.scan) == 1081
    assert frame.scan.range_max == 10.0
    assert np.all(np.isfinite(frame.scan.ranges))  # a closed room: every ray returns


# ---------------------------------------------------------------- depth geometry


def _expected_depth(simulation: Simulation, wall_x: float, pitch: float):
    """Depth of every pixel from plane geometry: the wall x = wall_x or the floor z = 0."""
    camera = simulation.camera
    origin, _ = simulation.camera_pose()
    u = (np.arange(camera.width) - camera.cx) / camera.fx
    v = (np.arange(camera.height) - camera.cy) / camera.fy
    _, y_n = np.meshgrid(u, v)
    # Optical z is (cos p, 0, -sin p) in the world and optical y is (-sin p, 0, -cos p):
    # a pixel's point at depth Z moves Z (cos p - y_n sin p) along x, -Z (y_n cos p + sin p) in z.
    with np.errstate(divide='ignore'):
        along_x = math.cos(pitch) - y_n * math.sin(pitch)
        down = y_n * math.cos(pitch) + math.sin(pitch)
        to_wall = np.where(along_x > 0, (wall_x - origin[0]) / along_x, np.inf)
        to_floor = np.where(down > 0, origin[2] / down, np.inf)
    return np.minimum(to_wall, to_floor), np.abs(to_wall - to_floor)


@pytest.mark.parametrize(('distance', 'pitch_deg'), [(2.0, 0.0), (1.5, 20.0)])
def test_depth_of_a_flat_wall_is_exact_to_a_millimetre(distance, pitch_deg):
    pitch = math.radians(pitch_deg)
    simulation = Simulation(
        SimConfig(resolution=SMALL, noise=False, robot=RobotSpec(camera_pitch=pitch)),
        world=wall_world(distance),
    )
    _, rotation = simulation.base_pose()
    assert rotation[2, 2] == pytest.approx(1.0, abs=1e-8)  # the robot stands level
    image = simulation.depth_frame().depth
    expected, wall_floor_gap = _expected_depth(simulation, distance, pitch)
    in_range = (expected >= 0.2) & (expected <= 10.0) & (wall_floor_gap > 0.005)
    assert in_range.sum() > 0.5 * image.size
    error_mm = image[in_range].astype(np.float64) - expected[in_range] * 1000.0
    assert np.abs(error_mm).max() <= 1.0
    assert np.all(image[expected > 10.0] == 0)


def test_depth_noise_has_the_model_standard_deviation():
    noise = DepthNoise()
    for distance in (1.0, 2.0):
        world = wall_world(distance)
        robot = RobotSpec(camera_pitch=0.0, camera_x=0.0)
        quiet_sim = Simulation(SimConfig(resolution=SMALL, noise=False, robot=robot), world=world)
        noisy_sim = Simulation(SimConfig(resolution=SMALL, noise=True, robot=robot), world=world)
        truth = quiet_sim.true_depth()
        noisy = noisy_sim.depth_frame().depth.astype(np.float64) / 1000.0
        on_wall = np.abs(truth - distance) < 0.01
        valid = on_wall & (noisy > 0)
        assert valid.sum() > 5000
        error = noisy[valid] - truth[valid]
        sigma = noise.k * distance**2
        assert error.std() == pytest.approx(sigma, rel=0.1)
        assert abs(error.mean()) < 4 * sigma / math.sqrt(valid.sum()) + 0.0005


def test_lidar_noise_and_dropouts_match_the_model():
    noise = LidarNoise()
    quiet_sim = quiet('room')
    noisy_sim = Simulation(SimConfig(world='room', resolution=SMALL, noise=True))
    truth = quiet_sim.lidar_frame().scan.ranges.astype(np.float64)
    frames = np.array([noisy_sim.lidar_frame().scan.ranges for _ in range(40)], dtype=np.float64)
    # Rays out through the door gap never return; dropouts are counted where the wall is.
    returns = np.broadcast_to(np.isfinite(truth), frames.shape)
    assert returns.mean() > 0.9
    dropped = np.isinf(frames) & returns
    readings = returns.sum()
    expected = noise.dropout * readings
    assert abs(dropped.sum() - expected) < 4 * math.sqrt(expected)
    with np.errstate(invalid='ignore'):  # inf - inf through the door gap
        error = (frames - truth)[returns & ~dropped]
    assert error.std() == pytest.approx(noise.sigma, rel=0.1)
    assert abs(error.mean()) < 4 * noise.sigma / math.sqrt(error.size)


def test_depth_edges_flag_the_far_side_of_a_jump_only():
    depth = np.full((5, 6), 2.0)
    depth[:, 3:] = 1.0  # a near object from column 3 on
    edges = depth_edges(depth, 0.05)
    expected = np.zeros((5, 6), dtype=bool)
    expected[:, 2] = True  # the background pixel next to the object
    assert np.array_equal(edges, expected)
    # A one-pixel-high board in front of a wall keeps its depth; the wall around it does not.
    board = np.full((5, 4), 2.8)
    board[2, :] = 2.0
    edges = depth_edges(board, 0.05)
    assert not edges[2].any()
    assert edges[1].all()
    assert edges[3].all()
    # A gentle slope (1 % per pixel) is no edge; next to no return (NaN) is.
    slope = np.tile(2.0 * 1.01 ** np.arange(6), (5, 1))
    assert not depth_edges(slope, 0.05).any()
    hole = np.full((3, 3), 2.0)
    hole[1, 1] = np.nan
    assert depth_edges(hole, 0.05).sum() == 5  # the hole and its four neighbours


def test_depth_image_is_millimetres_with_zero_outside_range_and_at_edges():
    profile = CAMERAS['d435']
    depth = np.array([[0.1, 0.5, 1.2345, 9.9994, 10.5, np.nan]])
    image = depth_image(depth, profile, None, RNG)
    assert image.dtype == np.uint16
    assert image.tolist() == [[0, 500, 1234, 9999, 0, 0]] or image.tolist() == [
        [0, 500, 1235, 9999, 0, 0]
    ]
    stepped = np.array([[2.0, 2.0, 2.0, 1.0, 1.0, 1.0]] * 3)
    noisy = depth_image(stepped, profile, DepthNoise(k=0.0), RNG)
    assert noisy[:, 2].tolist() == [0] * 3
    assert noisy[:, [0, 1, 3, 4, 5]].tolist() == [[2000, 2000, 1000, 1000, 1000]] * 3


def test_renderer_depth_agrees_with_ray_casting():
    """The one test that needs OpenGL; it runs in a child process with MUJOCO_GL=egl."""
    script = textwrap.dedent(
        """
        import numpy as np
        from scanfuse.sim import SimConfig, Simulation, DepthBackend, SimError
        try:
            rendered = Simulation(SimConfig(world='clutter', resolution=(256, 144), noise=False,
                                            depth_backend=DepthBackend.RENDERER))
        except SimError as err:
            print('NO-GL', err)
            raise SystemExit(0)
        # Named: with MUJOCO_GL=egl set, the automatic choice would be the renderer again.
        cast = Simulation(SimConfig(world='clutter', resolution=(256, 144), noise=False,
                                    depth_backend=DepthBackend.MULTIRAY))
        a, b = rendered.true_depth(), cast.true_depth()
        from scanfuse.sim.sensors import depth_edges
        smooth = ~depth_edges(b, 0.02) & np.isfinite(a) & np.isfinite(b) & (b < 8)
        same_hits = (np.isfinite(a) == np.isfinite(b)).mean()
        diff = np.abs(a - b)[smooth]
        print('DIFF', same_hits, smooth.mean(), diff.max(), np.median(diff))
        """
    )
    environment = {**os.environ, 'MUJOCO_GL': os.environ.get('MUJOCO_GL', 'egl')}
    result = subprocess.run(
        [sys.executable, '-c', script],
        capture_output=True,
        text=True,
        env=environment,
        timeout=300,
        check=False,
    )
    if 'NO-GL' in result.stdout:
        pytest.skip(f'no OpenGL for mujoco.Renderer: {result.stdout.strip()}')
    assert result.returncode == 0, result.stderr
    _, same_hits, fraction, worst, median = result.stdout.split()
    # Both see the same pixels hit (the walls are 1.2 m high: no ceiling above them).
    assert float(same_hits) > 0.995
    assert float(fraction) > 0.6
    assert float(median) < 1e-4
    assert float(worst) < 0.005
