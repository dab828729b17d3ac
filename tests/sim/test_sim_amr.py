"""The simulated AMR: two 270-degree LiDARs at opposite corners, a front and a rear camera.

Expected values are worked out by hand from the AMR's mounting (`scanfuse.sim.robot.AMR`):
the front LiDAR at (0.25, 0.17, 0.30) facing +45 degrees, the rear one at (-0.25, -0.17,
0.30) facing -135 degrees, the rear camera at (-0.25, 0, 0.45) looking back, pitched 20
degrees down; the fused scan is in the front LiDAR's frame on 360 degrees of its 0.25-degree
increment.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import pytest
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from scanfuse.cli import main
from scanfuse.evaluate.closed_loop import StreamFeed
from scanfuse.evaluate.methods import MethodStream
from scanfuse.sim import SimConfig, SimError, Simulation, Trace, fusion_config
from scanfuse.sim.recording import robot_topics, static_transforms
from scanfuse.sim.robot import AMR, AMR_CHASSIS, Mount, RobotSpec, robot_spec
from scanfuse.sim.worlds import ROBOT_AT_ORIGIN, World, box, room_walls
from tests.support import REPOSITORY
from tests.support.render import square_room_ranges

if TYPE_CHECKING:
    from pathlib import Path

    from scanfuse.scan import Scan
    from scanfuse.sim.simulation import LidarFrame

HALF = 2.0  # the square room's walls: x = +-2, y = +-2
FRONT = (0.25, 0.17)  # the front LiDAR in base_link, facing pi / 4
KERB_X = -AMR_CHASSIS[0] - 1.0  # a low wall 1 m behind the AMR's rear face
KERB_HEIGHT = 0.15  # under both LiDARs' 0.30 m plane, inside the collision slab
STEP = math.radians(0.25)


def amr_config(**changes) -> SimConfig:
    values = {
        'world': 'room',
        'robot': AMR,
        'lidar': 'hokuyo-ust10lx',
        'resolution': (256, 144),
        'noise': False,
        'depth_backend': 'multiray',
        'depth_rate': 15.0,
        **changes,
    }
    return SimConfig(**values)


def square_room(*, kerb: bool = False) -> World:
    bounds = (-HALF, HALF, -HALF, HALF)
    obstacles = room_walls(bounds)
    if kerb:
        # 0.2 m deep, across the room: its face at x = KERB_X.
        obstacles.append(
            box('kerb', 'low_box', (KERB_X - 0.1, 0.0), (0.1, HALF), (0.0, KERB_HEIGHT))
        )
    return World('square', 0, tuple(obstacles), ROBOT_AT_ORIGIN, bounds)


def fused_scans(
    world: World, methods: tuple[str, ...], duration: float, **fusion: object
) -> dict[str, list[Scan]]:
    """Each method's fused scans of a standing AMR, fed as the evaluation feeds them;
    `fusion`: parameters changed from the simulator's."""
    config = amr_config()
    sim = Simulation(config, world)
    base = fusion_config(config)
    base = base.with_changes(**fusion) if fusion else base
    streams = [
        MethodStream(name, base, sim.camera, static_transforms(config.robot)) for name in methods
    ]
    out: dict[str, list[Scan]] = {name: [] for name in methods}

    def released(stream: MethodStream, _frame: LidarFrame, scan: Scan) -> None:
        out[stream.name].append(scan)

    feed = StreamFeed(streams, released)
    try:
        sim.run(duration, None, feed)
        feed.finish()
    finally:
        sim.close()
    return out


def reading(scan: Scan, bearing: float) -> float:
    """The nearest reading within one slot of `bearing`."""
    slot = int(scan.grid.slot_of(np.array([bearing]))[0])
    window = scan.ranges[[(slot + k) % len(scan) for k in (-1, 0, 1)]]
    return float(np.where(np.isfinite(window), window, np.inf).min())


def test_the_amrs_sensors_have_their_names_frames_and_staggered_clocks():
    sim = Simulation(amr_config(), square_room())
    trace = Trace()
    try:
        sim.run(0.2, None, trace)
    finally:
        sim.close()
    front = [f for f in trace.lidar if f.source == 'front']
    rear = [f for f in trace.lidar if f.source == 'rear']
    assert {f.scan.frame_id for f in front} == {'front_laser'}
    assert {f.scan.frame_id for f in rear} == {'rear_laser'}
    # 40 Hz sweeps (two periods: 50 ms, 25 physics steps of 2 ms), the rear one half a period
    # later: 12.5 ms is 6.25 steps, the nearest step 6 (12 ms).
    assert front[2].stamp_ns - front[0].stamp_ns == 50_000_000
    assert rear[0].stamp_ns - front[0].stamp_ns == 12_000_000
    # time_increment = scan_time * angle_increment / (2 pi) = 0.025 / 1440 s.
    assert front[0].scan.time_increment == pytest.approx(0.025 / 1440)
    assert len(front[0].scan) == 1081
    # Headings: +45 and -135 degrees from the base's +x.
    assert front[0].heading == pytest.approx(math.pi / 4, abs=1e-3)
    assert rear[0].heading == pytest.approx(-3 * math.pi / 4, abs=1e-3)
    cameras = {f.source: f.camera.frame_id for f in trace.depth}
    assert cameras == {
        'front_depth': 'front_camera_depth_optical_frame',
        'rear_depth': 'rear_camera_depth_optical_frame',
    }
    # 15 Hz images, the rear camera half a period (33.3 ms, to the step: 34) after the front.
    stamps = {s: [f.stamp_ns for f in trace.depth if f.source == s] for s in cameras}
    assert stamps['rear_depth'][0] - stamps['front_depth'][0] == 34_000_000


def test_the_two_lidars_merged_give_a_360_degree_scan_of_a_square_room_within_1_cm():
    scans = fused_scans(square_room(), ('lidar',), 0.2)['lidar']
    scan = scans[-1]
    assert scan.frame_id == 'front_laser'
    # 360 degrees on the UST-10LX's 0.25-degree increment, from -180 degrees.
    assert len(scan) == 1440
    assert scan.angle_min == pytest.approx(-math.pi)
    truth = square_room_ranges(FRONT, math.pi / 4, scan.angles(), HALF)
    assert np.isfinite(scan.ranges).all()  # the rear LiDAR fills the front one's blind sector
    np.testing.assert_allclose(scan.ranges, truth, atol=0.01)


def test_a_low_wall_1_m_behind_the_amr_is_seen_by_the_rear_camera_behind_it():
    scans = fused_scans(square_room(kerb=True), ('lidar', 'obstacle'), 0.5)
    # Straight behind the base (bearing pi in base_link) the kerb's face is at (KERB_X, 0):
    # from the front LiDAR that is (KERB_X - 0.25, -0.17), at this range and bearing in its
    # frame (heading pi / 4), in its blind sector (beyond +135 degrees).
    dx, dy = KERB_X - FRONT[0], -FRONT[1]
    kerb_range = math.hypot(dx, dy)  # 1.5096 m
    bearing = math.atan2(dy, dx) - math.pi / 4
    bearing = math.atan2(math.sin(bearing), math.cos(bearing))  # 2.469 rad, 141.5 degrees
    assert bearing > math.radians(135.0)
    # The LiDARs pass over the 0.15 m kerb and see the room's wall at x = -2 beyond it.
    world = math.atan2(dy, dx)
    wall_range = (HALF + FRONT[0]) / abs(math.cos(world))  # 2.264 m
    lidar = scans['lidar'][-1]
    assert reading(lidar, bearing) == pytest.approx(wall_range, abs=0.02)
    fused = scans['obstacle'][-1]
    assert len(fused) == 1440
    assert reading(fused, bearing) == pytest.approx(kerb_range, abs=0.02)


def test_with_output_frame_base_link_the_amr_reads_the_room_and_the_kerb_from_its_centre():
    scans = fused_scans(
        square_room(kerb=True), ('lidar', 'obstacle'), 0.5, output_frame='base_link'
    )
    lidar = scans['lidar'][-1]
    assert lidar.frame_id == 'base_link'
    assert len(lidar) == 1440  # the front LiDAR's 0.25-degree increment over 360 degrees
    # Both LiDARs re-binned from their points: the room's walls from the base's centre.
    truth = square_room_ranges((0.0, 0.0), 0.0, lidar.angles(), HALF)
    finite = np.isfinite(lidar.ranges)
    assert finite.mean() >= 0.95
    np.testing.assert_allclose(lidar.ranges[finite], truth[finite], atol=0.02)
    # Straight behind (bearing pi) the LiDARs pass over the kerb to the wall at x = -2; the
    # rear camera reports the kerb's face, 1 m behind the chassis, within the evaluation's
    # tolerance for a camera reading (0.05 m + 2 %): from the base's centre a 0.25-degree
    # slot holds fewer than obstacle_min_points (16) of the 256x144 image's face pixels, so
    # the slot's estimate takes in the kerb's top behind its face (3 cm here).
    assert reading(lidar, math.pi) == pytest.approx(HALF, abs=0.02)
    kerb = -KERB_X
    assert reading(scans['obstacle'][-1], math.pi) == pytest.approx(kerb, abs=0.05 + 0.02 * kerb)


def test_an_amr_bag_holds_the_multi_example_topics_and_scanfuse_bag_fuses_it(tmp_path: Path):
    bag = tmp_path / 'amr.mcap'
    argv = ['simulate', '--out', str(bag), '--robot', 'amr', '--world', 'room', '--path']
    assert (
        main([*argv, 'rotate', '--duration', '1.0', '--resolution', '256x144', '--no-noise']) == 0
    )
    expected = set(robot_topics(AMR)) | {'/tf_static'}
    assert {
        '/front/scan',
        '/rear/scan',
        '/front_camera/depth/image_rect_raw',
        '/front_camera/depth/camera_info',
        '/rear_camera/depth/image_rect_raw',
        '/rear_camera/depth/camera_info',
    } <= expected
    store = get_typestore(Stores.ROS2_HUMBLE)
    with AnyReader([bag], default_typestore=store) as reader:
        assert {c.topic for c in reader.connections} == expected
    out = tmp_path / 'fused'
    params = REPOSITORY / 'examples' / 'scanfuse_multi.yaml'
    assert main(['bag', str(bag), str(out), '--params', str(params)]) == 0
    fused = []
    rear_scans = 0
    with AnyReader([out], default_typestore=store) as reader:
        for connection, _, raw in reader.messages():
            if connection.topic == '/scan_fused':
                fused.append(reader.deserialize(raw, connection.msgtype))
            rear_scans += connection.topic == '/rear/scan'
    assert rear_scans > 0  # the input topics are kept
    assert fused
    # -180 to -135 degrees of the front LiDAR (180 slots): only the rear LiDAR sees there.
    blind = slice(0, 180)
    for message in fused:
        assert message.header.frame_id == 'front_laser'
        assert len(message.ranges) == 1440
        assert message.angle_min == pytest.approx(-math.pi)
        # NaN: no source had a reading. The rear LiDAR's points, moved to the front one's
        # origin and stamp while the robot turns, leave at most a few slots of the seam empty.
        assert np.isnan(np.asarray(message.ranges)[blind]).sum() <= 9
    # At rest (the first scans) every blind slot holds the rear LiDAR's reading of a wall.
    assert not np.isnan(np.asarray(fused[0].ranges)[blind]).any()


def test_a_robot_not_in_robots_or_with_a_chassis_beyond_its_radius_is_an_error():
    with pytest.raises(SimError, match=r"unknown robot 'agv'; choose one of default, amr"):
        robot_spec('agv')
    with pytest.raises(SimError, match=r'chassis reaches beyond body_radius 0.18 m'):
        RobotSpec(chassis=(0.25, 0.17), rear_lidar=Mount(0.0, 0.0, math.pi))
    with pytest.raises(SimError, match=r'sensor_stagger 1.0 must be in \[0, 1\)'):
        amr_config(sensor_stagger=1.0)
    with pytest.raises(SimError, match=r"unknown point-cloud LiDAR profile 'vlp16'"):
        Simulation(amr_config(cloud='vlp16'), square_room())
    sim = Simulation(SimConfig(resolution=(256, 144), depth_backend='multiray'), square_room())
    try:
        with pytest.raises(SimError, match='the default robot carries no 3D LiDAR'):
            sim.cloud_frame()
    finally:
        sim.close()
    assert main(['simulate', '--out', 'x.mcap', '--robot', 'agv']) == 1
