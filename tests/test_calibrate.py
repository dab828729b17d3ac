"""`scanfuse calibrate` on bags of a room recorded with known mountings (issue 25, item 4).

The bags (tests.support.calibration) hold 2 s of a robot standing in a room: 10 Hz LiDAR
scans and 15 Hz depth frames (320x240, depth noise 0.01 Z^2 as a RealSense D435's, LiDAR
noise 5 mm), rendered from the geometry with the camera at the true mounting; the starting
mounting given to
`calibrate` (parameters or /tf_static) is wrong by centimetres and degrees. Done when:
height within 1 cm, pitch and roll within 0.3 deg, yaw within 0.5 deg, x and y within 2 cm
of the true mounting.
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
import pytest
import yaml

from scanfuse.calibrate import Mounting, body_to_optical_command
from scanfuse.cli import main
from scanfuse.config import FusionConfig
from scanfuse.errors import BagError, CalibrationError
from scanfuse.ros.calibration import calibrate_bag
from scanfuse.transforms import BODY_TO_OPTICAL, Extrinsics, Transform
from tests.support.calibration import LIDAR, LOW_BOX, PILLAR, ROOM, WALL, Room, room_messages
from tests.support.synthetic import write_bag

if TYPE_CHECKING:
    from collections.abc import Callable
    from pathlib import Path

DEG = math.radians
HEIGHT_TOLERANCE, XY_TOLERANCE = 0.01, 0.02
TILT_TOLERANCE, YAW_TOLERANCE = DEG(0.3), DEG(0.5)
NOMINAL = Mounting(0.10, 0.0, 0.50, 0.0, DEG(20.0), 0.0)  # what a drawing would say


def params_of(mounting: Mounting, lidar: Mounting = LIDAR) -> dict[str, float]:
    """The parameters of a camera mounting and a level LiDAR."""
    return {
        **mounting.parameters(),
        'lidar_x': lidar.x,
        'lidar_y': lidar.y,
        'lidar_height': lidar.height,
        'lidar_roll': lidar.roll,
        'lidar_yaw': lidar.yaw,
    }


def config_of(mounting: Mounting, lidar: Mounting = LIDAR) -> FusionConfig:
    return FusionConfig(**params_of(mounting, lidar))  # type: ignore[arg-type]


def errors(found: Mounting, true: Mounting) -> dict[str, float]:
    """Absolute error per parameter: metres and radians."""
    return {
        'x': abs(found.x - true.x),
        'y': abs(found.y - true.y),
        'height': abs(found.height - true.height),
        'roll': abs(math.remainder(found.roll - true.roll, math.tau)),
        'pitch': abs(math.remainder(found.pitch - true.pitch, math.tau)),
        'yaw': abs(math.remainder(found.yaw - true.yaw, math.tau)),
    }


LIMITS = {
    'x': XY_TOLERANCE,
    'y': XY_TOLERANCE,
    'height': HEIGHT_TOLERANCE,
    'roll': TILT_TOLERANCE,
    'pitch': TILT_TOLERANCE,
    'yaw': YAW_TOLERANCE,
}


def within_done_when(found: Mounting, true: Mounting) -> bool:
    error = errors(found, true)
    return all(error[name] <= limit for name, limit in LIMITS.items())


def assert_within_done_when(found: Mounting, true: Mounting) -> None:
    assert within_done_when(found, true), (errors(found, true), found, true)


# (true camera mounting, LiDAR mounting, given camera mounting, given through TF (else the
# parameters))
CASES = {
    'level, ahead': (
        Mounting(0.12, 0.0, 0.45, 0.0, DEG(20.0), 0.0),
        LIDAR,
        NOMINAL,
        False,
    ),
    'rolled, yawed left, off centre': (
        Mounting(0.15, -0.05, 0.40, DEG(2.0), DEG(15.0), DEG(6.0)),
        LIDAR,
        NOMINAL,
        False,
    ),
    'rolled the other way, yawed right, steep; wrong TF': (
        Mounting(0.05, 0.08, 0.55, DEG(-3.0), DEG(25.0), DEG(-8.0)),
        LIDAR,
        Mounting(0.10, 0.0, 0.48, DEG(1.0), DEG(21.5), DEG(-2.0)),
        True,
    ),
    'LiDAR off the origin and turned': (
        Mounting(0.20, 0.06, 0.42, DEG(1.5), DEG(18.0), DEG(4.0)),
        Mounting(0.08, -0.04, 0.28, 0.0, 0.0, DEG(90.0)),
        NOMINAL,
        False,
    ),
    'LiDAR upside down, turned back': (
        Mounting(0.12, 0.03, 0.46, DEG(-1.0), DEG(21.0), DEG(-3.0)),
        Mounting(-0.05, 0.0, 0.33, math.pi, 0.0, DEG(180.0)),
        NOMINAL,
        False,
    ),
    'far from the given mounting (20 cm, 11 deg)': (
        Mounting(0.15, -0.05, 0.40, DEG(2.0), DEG(15.0), DEG(6.0)),
        LIDAR,
        Mounting(0.25, 0.10, 0.20, DEG(6.0), DEG(4.0), DEG(17.0)),
        False,
    ),
}


def record(tmp_path: Path, room: Room, *, tf_camera: Mounting | None = None) -> Path:
    return write_bag(tmp_path / 'room', room_messages(room, tf_camera=tf_camera))


@pytest.mark.parametrize('case', CASES)
def test_calibrate_recovers_the_true_mounting_within_the_done_when_tolerances(case, tmp_path):
    true, lidar, given, through_tf = CASES[case]
    bag = record(tmp_path, Room(true, lidar=lidar), tf_camera=given if through_tf else None)
    # The parameters say `given`, or the nominal mounting when TF has the camera at `given`.
    found = calibrate_bag(bag, config=config_of(NOMINAL if through_tf else given, lidar))
    result = found.calibration
    assert result.given.parameters() == pytest.approx(given.parameters(), abs=1e-9)
    assert found.given_source.startswith('TF' if through_tf else 'the camera_* parameters')
    # The TF tree's body frame (camera_link) when the bag has one, else a name and the turn.
    assert (found.body_frame, found.body_in_tf) == (
        ('camera_link', True) if through_tf else ('camera_depth_frame', False)
    )
    assert len(found.commands()) == (1 if through_tf else 2)
    assert found.lidar_source.startswith('TF')
    assert_within_done_when(result.mounting, true)
    # The given mounting was off by more than the tolerances somewhere; the estimate is not.
    assert not within_done_when(result.given, true)
    # Residuals: the floor's within its noise (0.01 Z^2 within 3 m, clipped at 3 cm); the
    # match's as the sensors' noise says (1 sigma, less the 3-sigma gate's tails) and below
    # the given mounting's, with more points matched.
    assert result.floor_frames == result.frames == 30
    assert 0.0 < result.floor_rms < 0.015
    assert 0.8 < result.match_sigmas < 1.1
    assert result.match_sigmas < result.match_sigmas_given
    assert result.matched_given < result.matched_points
    assert result.matched_points > 0.7 * result.camera_count


def test_the_printed_transform_is_the_mounting_in_rep_103():
    """The two static_transform_publisher lines (base -> body, body -> optical) compose to
    the optical pose `Extrinsics.from_mounting` gives for the printed parameters."""
    mounting = Mounting(0.15, -0.05, 0.40, DEG(2.0), DEG(15.0), DEG(6.0))
    body_line = mounting.static_transform_command('base_link', 'camera_depth_frame')
    optical_line = body_to_optical_command('camera_depth_frame', 'camera_depth_optical_frame')

    def transform_of(line: str) -> Transform:
        value = {name: float(number) for name, number in re.findall(r'--(\w+) (-?[\d.]+)', line)}
        return Transform.from_rpy(
            value.get('roll', 0.0),
            value.get('pitch', 0.0),
            value.get('yaw', 0.0),
            (value.get('x', 0.0), value.get('y', 0.0), value.get('z', 0.0)),
        )

    published = transform_of(body_line) @ transform_of(optical_line)
    expected = Extrinsics.from_mounting(
        camera_x=0.15,
        camera_y=-0.05,
        camera_height=0.40,
        camera_roll=DEG(2.0),
        camera_pitch=DEG(15.0),
        camera_yaw=DEG(6.0),
    ).base_to_camera_optical
    np.testing.assert_allclose(published.matrix, expected.matrix, atol=1e-4)
    assert '--frame-id base_link --child-frame-id camera_depth_frame' in body_line
    assert Mounting.of_optical(expected).parameters() == pytest.approx(mounting.parameters())


def test_the_command_prints_the_parameters_and_writes_the_figure(tmp_path, capsys):
    true = Mounting(0.15, -0.05, 0.40, DEG(2.0), DEG(15.0), DEG(6.0))
    bag = record(tmp_path, Room(true))
    params = tmp_path / 'params.yaml'
    params.write_text(yaml.safe_dump({'scanfuse': {'ros__parameters': params_of(NOMINAL)}}))
    out = tmp_path / 'out'
    code = main(['calibrate', str(bag), '--params', str(params), '--out', str(out)])
    printed = capsys.readouterr().out
    assert code == 0, printed
    snippet = printed[printed.index('scanfuse:\n') : printed.index('ros2 run')]
    values = yaml.safe_load(snippet)['scanfuse']['ros__parameters']
    assert set(values) == set(true.parameters())
    assert_within_done_when(
        Mounting(*(values[f'camera_{n}'] for n in ('x', 'y', 'height', 'roll', 'pitch', 'yaw'))),
        true,
    )
    # No body frame in the bag's TF: base -> body, then body -> optical.
    commands = [line for line in printed.splitlines() if line.startswith('ros2 run tf2_ros')]
    assert len(commands) == 2
    assert '--frame-id base_link --child-frame-id camera_depth_frame' in commands[0]
    assert commands[1].endswith(
        '--frame-id camera_depth_frame --child-frame-id camera_depth_optical_frame'
    )
    figure = out / 'calibration.png'
    assert figure.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'
    saved = json.loads((out / 'calibration.json').read_text())
    assert saved['estimated'] == pytest.approx(values, abs=1e-4)
    assert yaml.safe_load((out / 'calibration.yaml').read_text()) == {
        'scanfuse': {'ros__parameters': values}
    }


def test_a_bag_without_depth_images_is_refused(tmp_path):
    room = Room(NOMINAL)
    messages = [m for m in room_messages(room) if not m[0].startswith('/camera')]
    bag = write_bag(tmp_path / 'lidar_only', messages)
    with pytest.raises(BagError, match=r'no depth images in bag .* record /scan /camera/depth'):
        calibrate_bag(bag, config=config_of(NOMINAL))


def test_a_bag_without_lidar_is_refused(tmp_path):
    bag = write_bag(tmp_path / 'camera_only', room_messages(Room(NOMINAL), with_lidar=False))
    with pytest.raises(BagError, match=r'no LiDAR scans \(LaserScan\) in bag'):
        calibrate_bag(bag, config=config_of(NOMINAL))


def test_a_mounting_given_too_far_from_the_floor_finds_too_little_floor(tmp_path):
    bag = record(tmp_path, Room(NOMINAL))
    far = Mounting(NOMINAL.x, NOMINAL.y, NOMINAL.height + 0.5, 0.0, NOMINAL.pitch, 0.0)
    with pytest.raises(CalibrationError, match=r'too little floor: 0 of 30 depth frames'):
        calibrate_bag(bag, config=config_of(far))


def test_one_straight_wall_cannot_fix_x_and_y(tmp_path):
    """Only the wall ahead (no side walls in view, no pillar): the match slides along it."""
    x_max = ROOM[1]
    wall = (x_max, x_max + WALL, -10.0, 10.0, 0.0, 2.0)
    bag = record(tmp_path, Room(NOMINAL, boxes=(wall,)))
    slides = r'walls too few to fix x, y: .* along 90 deg \(from the base frame x axis\)'
    with pytest.raises(CalibrationError, match=slides):
        calibrate_bag(bag, config=config_of(NOMINAL))
    assert PILLAR[4] < LIDAR.height < PILLAR[5]  # the room's pillar would have fixed it


@pytest.mark.parametrize(
    ('storage', 'metres'), [('sqlite3', False), ('ros1', False), ('mcap', True)]
)
def test_sqlite3_and_ros1_bags_and_float_depth_calibrate_as_mcap_does(storage, metres, tmp_path):
    true = Mounting(0.15, -0.05, 0.40, DEG(2.0), DEG(15.0), DEG(6.0))
    path = tmp_path / ('room.bag' if storage == 'ros1' else 'room')
    bag = write_bag(path, room_messages(Room(true, metres=metres)), storage=storage)
    found = calibrate_bag(bag, config=config_of(NOMINAL))
    assert_within_done_when(found.calibration.mounting, true)


def test_nothing_at_the_lidars_height_in_view_is_refused(tmp_path):
    """Only a 10 cm box: the floor gives height, pitch, roll, but nothing fixes yaw."""
    bag = record(tmp_path, Room(NOMINAL, boxes=(LOW_BOX,)))
    with pytest.raises(CalibrationError, match=r'sees only 0 points within 0.05 m of the LiDAR'):
        calibrate_bag(bag, config=config_of(NOMINAL))


def test_a_tilted_lidar_is_refused(tmp_path):
    bag = record(tmp_path, Room(NOMINAL))
    config = config_of(NOMINAL).with_changes(lidar_pitch=DEG(5.0), use_tf=False)
    with pytest.raises(CalibrationError, match=r"LiDAR's plane is tilted 5.0 deg from level"):
        calibrate_bag(bag, config=config)


def test_one_wall_and_a_short_wall_across_it_fix_x_and_y(tmp_path):
    """The wall ahead and 30 cm of wall across it (a cabinet's side, a recess): its face,
    seen 2 m away through the depth's 4 cm of noise, pins the match along the wall."""
    true = Mounting(0.15, -0.05, 0.40, DEG(2.0), DEG(15.0), DEG(6.0))
    x_max = ROOM[1]
    wall = (x_max, x_max + WALL, -10.0, 10.0, 0.0, 2.0)
    stub = (x_max - 0.3, x_max, 0.9, 1.0, 0.0, 2.0)
    bag = record(tmp_path, Room(true, boxes=(wall, stub)))
    found = calibrate_bag(bag, config=config_of(NOMINAL))
    assert_within_done_when(found.calibration.mounting, true)


def test_a_bag_of_the_simulator_calibrates_within_the_done_when_tolerances(tmp_path):
    """The MuJoCo robot standing 2 s in the bookshelf world (walls, shelves the LiDAR sees
    through, a low box; D435 noise 0.01 Z^2 on rendered depth, LiDAR noise 1 cm), its
    camera mounted 4 cm ahead, 3 cm lower and 3 deg less steep than the parameters say.
    The simulated robot turns its camera by pitch only (no roll or yaw: the room bags
    above cover those)."""
    pytest.importorskip('mujoco')
    from scanfuse.sim.headless_gl import choose_headless_gl

    choose_headless_gl()
    from scanfuse.sim import SimConfig, record
    from scanfuse.sim.cli import robot_spec

    true = Mounting(0.16, 0.0, 0.42, 0.0, DEG(17.0), 0.0)
    spec = robot_spec('default')
    robot = replace(spec, camera_x=true.x, camera_height=true.height, camera_pitch=true.pitch)
    config = SimConfig(world='bookshelf', seed=0, resolution=(424, 240), robot=robot)
    bag = tmp_path / 'standing.mcap'
    record(config, lambda _observation: (0.0, 0.0), 2.0, bag)
    lidar = Mounting(spec.lidar_x, spec.lidar_y, spec.lidar_height, 0.0, 0.0, spec.lidar_yaw)
    parameters = config_of(Mounting(0.12, 0.0, 0.45, 0.0, DEG(20.0), 0.0), lidar)
    found = calibrate_bag(bag, config=parameters.with_changes(use_tf=False))
    assert found.given_source == 'the camera_* parameters'
    assert_within_done_when(found.calibration.mounting, true)


def test_a_camera_hung_from_a_mount_frame_is_printed_under_it(tmp_path):
    """TF: base_link -> camera_mount -> camera_link -> optical, camera_link wrong. The
    command publishes camera_mount -> camera_link, which composed with the mount's pose is
    the true body pose."""
    true = Mounting(0.15, -0.05, 0.40, DEG(2.0), DEG(15.0), DEG(6.0))
    mount = Transform.from_rpy(0.0, 0.0, DEG(10.0), (0.05, 0.02, 0.30))
    room = Room(true)
    bag = write_bag(tmp_path / 'room', room_messages(room, tf_camera=NOMINAL, mount=mount))
    found = calibrate_bag(bag, config=config_of(NOMINAL))
    assert found.given_source.startswith('TF')
    assert found.calibration.given.parameters() == pytest.approx(NOMINAL.parameters(), abs=1e-9)
    (command,) = found.commands()
    assert command.endswith('--frame-id camera_mount --child-frame-id camera_link')
    value = {name: float(number) for name, number in re.findall(r'--(\w+) (-?[\d.]+)', command)}
    published = mount @ Transform.from_rpy(
        value['roll'], value['pitch'], value['yaw'], (value['x'], value['y'], value['z'])
    )
    assert_within_done_when(Mounting.of_optical(published @ BODY_TO_OPTICAL), true)


def test_frames_taken_while_odometry_says_the_robot_turned_are_left_out(tmp_path):
    """/odom: the base turns at 0.5 rad/s for 1 s, then stands. Depth frames (15 Hz, 5 ms
    after the 10 Hz scans' grid) are each at least 5 ms from their scan, 0.14 deg of turn
    at that rate, more than `still_turn` (0.1 deg): the 15 frames of the first second are
    left out; the 15 after it are used."""
    true = Mounting(0.15, -0.05, 0.40, DEG(2.0), DEG(15.0), DEG(6.0))
    turning = record_with_heading(tmp_path / 'turning', true, lambda t: 0.5 * min(t, 1.0))
    found = calibrate_bag(turning, config=config_of(NOMINAL))
    assert (found.odometry_topic, found.moving_frames) == ('/odom', 15)
    assert found.calibration.frames == 15
    assert_within_done_when(found.calibration.mounting, true)
    always = record_with_heading(tmp_path / 'always', true, lambda t: 0.5 * t)
    with pytest.raises(CalibrationError, match=r'the robot moved between every depth frame'):
        calibrate_bag(always, config=config_of(NOMINAL))


def record_with_heading(path: Path, true: Mounting, heading: Callable[[float], float]) -> Path:
    return write_bag(path, room_messages(Room(true), heading=heading))


def test_the_command_turns_a_refusal_into_one_line_and_exit_code_1(tmp_path, capsys):
    bag = write_bag(tmp_path / 'camera_only', room_messages(Room(NOMINAL), with_lidar=False))
    assert main(['calibrate', str(bag), '--out', str(tmp_path / 'out')]) == 1
    error = capsys.readouterr().err
    assert 'error: no LiDAR scans (LaserScan) in bag' in error
    assert 'Traceback' not in error
    assert not (tmp_path / 'out').exists()


def test_a_round_room_around_the_camera_cannot_fix_yaw(tmp_path):
    """A round wall centred on the camera (no boxes): turned about itself, the camera sees
    the same wall, so its yaw is free."""
    true = Mounting(0.15, -0.05, 0.40, DEG(2.0), DEG(15.0), DEG(6.0))
    room = Room(true, boxes=(), round_wall=(true.x, true.y, 1.8))
    bag = record(tmp_path, room)
    fits_as_well = r'walls too few to fix yaw: moved .* along its weakest direction, .* as well'
    with pytest.raises(CalibrationError, match=fits_as_well):
        calibrate_bag(bag, config=config_of(NOMINAL))
