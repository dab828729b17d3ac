"""The floor found in every frame (issue 25): a pitching, rolling or mis-measured camera.

Scenes are issue 25's (tests/support/ground_scene.py). Scored as the issue scores: false
obstacle (or drop) slots in view and box slots at the right range. The same scenes with the
ground estimate off fail (the issue's table), so each is a test that can fail.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np
import pytest

from scanfuse.camera import CameraModel
from scanfuse.convert.ground import GroundPlane, GroundSettings, GroundTracker
from scanfuse.stream import FusionStream
from scanfuse.transforms import Transform
from tests.support.ground_scene import (
    BOX,
    BOX_FRONT,
    BOX_HALF_WIDTH,
    BOX_HEIGHT,
    CAMERA,
    HEIGHT,
    NS,
    PITCH,
    READINGS,
    config,
    lidar_scan,
    optical_pose,
    score,
)
from tests.support.render import box_depth, ground_depth, millimetres, slope_depth

if TYPE_CHECKING:
    from scanfuse.scan import Scan


def depth_scans(depths: list[np.ndarray], **changes: object) -> tuple[Scan, FusionStream[int]]:
    """The depth scan of the last of `depths` (frames 0.1 s apart, each paired with a scan)."""
    stream: FusionStream[int] = FusionStream(config(**changes))
    stream.add_camera_info(CAMERA)
    out = None
    for index, depth in enumerate(depths):
        stamp = (index + 1) * NS // 10
        stream.add_depth(stamp, depth, stamp)
        (out,) = stream.add_scan(lidar_scan(stamp), index, stamp + 1)
    assert out is not None
    assert out.depth_scan is not None, out.passed
    return out.depth_scan, stream


TILTED = {
    'body pitched 2 deg nose-down (braking)': {'body_pitch': 2.0},
    'body pitched 2 deg nose-up': {'body_pitch': -2.0},
    'body rolled 2 deg right': {'body_roll': 2.0},
    'body rolled 2 deg left': {'body_roll': -2.0},
    'camera 2 deg steeper and 5 cm higher than its parameters': {
        'pitch': PITCH + math.radians(2.0),
        'height': HEIGHT + 0.05,
    },
    'camera 2 deg shallower and 5 cm lower than its parameters': {
        'pitch': PITCH - math.radians(2.0),
        'height': HEIGHT - 0.05,
    },
}


@pytest.mark.parametrize('pose', TILTED.values(), ids=TILTED.keys())
def test_a_tilted_body_or_a_mis_measured_mount_reports_the_box_and_not_the_floor(pose):
    depth = millimetres(box_depth(CAMERA, optical_pose(**pose), [BOX]))
    scan, stream = depth_scans([depth] * 3)
    false, right = score(scan)
    assert false <= 0.005
    assert right >= 0.95
    assert stream.ground is not None
    assert stream.ground.counts.estimated == 3


@pytest.mark.parametrize('pose', TILTED.values(), ids=TILTED.keys())
def test_the_same_scenes_fail_with_the_ground_estimate_off(pose):
    depth = millimetres(box_depth(CAMERA, optical_pose(**pose), [BOX]))
    scan, _ = depth_scans([depth], ground_estimate=False)
    false, right = score(scan)
    assert false > 0.1 or right < 0.5


def test_a_single_frame_is_enough():
    depth = millimetres(box_depth(CAMERA, optical_pose(body_pitch=2.0), [BOX]))
    false, right = score(depth_scans([depth])[0])
    assert (false, right) == (0.0, 1.0)


def test_a_flat_floor_with_the_right_mounting_gives_exactly_the_mountings_scan():
    depth = millimetres(box_depth(CAMERA, optical_pose(), [BOX]))
    on, stream = depth_scans([depth] * 2)
    off, _ = depth_scans([depth] * 2, ground_estimate=False)
    np.testing.assert_array_equal(on.ranges, off.ranges)
    assert stream.ground is not None
    assert stream.ground.counts.estimated == 2


def test_the_estimate_finds_the_true_mounting_above_the_floor():
    pose = optical_pose(body_pitch=2.0, body_roll=-1.0)
    depth = millimetres(box_depth(CAMERA, pose, [BOX]))
    prior = GroundPlane.of_mounting(optical_pose())
    truth = GroundPlane.of_mounting(pose)
    plane = GroundTracker(GroundSettings()).update(depth, CAMERA, prior)
    # Within a tenth of a degree (5 mm at 3 m, the projector's GROUND_TOLERANCE) and 2 mm,
    # from millimetre depth of the floor within a metre of where it is first seen.
    assert math.degrees(plane.tilt_from(truth)) < 0.1
    assert plane.offset == pytest.approx(truth.offset, abs=0.002)
    assert math.degrees(plane.camera_pitch) == pytest.approx(22.0, abs=0.1)


def test_a_step_up_higher_than_the_slab_bottom_stays_an_obstacle():
    step = (BOX_FRONT, 6.0, -6.0, 6.0, 0.0, 0.10)  # 10 cm up from 1.5 m on, wall to wall
    depth = millimetres(box_depth(CAMERA, optical_pose(body_pitch=2.0), [step]))
    scan, _ = depth_scans([depth] * 2)
    _, right = score(scan)
    assert right >= 0.95


def test_a_slope_steeper_than_max_slope_is_an_obstacle():
    # 1:5 from 1.2 m. The ground may follow it at 1:8 (max_slope) at most, so it stands 3 cm
    # (the slab's bottom) above that ground at the latest (0.2 - 0.125) d = 0.03: d = 0.4 m in.
    depth = millimetres(slope_depth(CAMERA, optical_pose(), start=1.2, rise=0.2))
    scan, _ = depth_scans([depth] * 2)
    ahead = scan.ranges[READINGS // 2 - 2 : READINGS // 2 + 3]
    assert np.all((ahead >= 1.2) & (ahead <= 1.6 + 0.05 + 0.02 * 1.6))


def test_a_ledge_stays_a_drop_with_the_ground_estimate_on():
    # The floor ends 1.5 m ahead and goes on 0.5 m lower: lines of sight past the edge cross
    # the floor plane just beyond it.
    depth = millimetres(slope_depth(CAMERA, optical_pose(), start=1.5, rise=-50.0, length=0.01))
    scan, stream = depth_scans([depth] * 2)
    ahead = scan.ranges[READINGS // 2 - 2 : READINGS // 2 + 3]
    assert np.all((ahead >= 1.5 - 0.08) & (ahead <= 1.5 + 0.08))
    assert stream.ground is not None
    assert stream.ground.counts.estimated == 2


def test_facing_a_wall_the_estimate_falls_back_and_counts_it():
    wall = (0.45, 1.0, -6.0, 6.0, 0.0, 3.0)  # 5 cm of floor in front of it
    depth = millimetres(box_depth(CAMERA, optical_pose(), [wall]))
    scan, stream = depth_scans([depth] * 2)
    assert stream.ground is not None
    assert stream.ground.counts.fell_back == 2
    assert 'fewer than' in stream.ground.counts.last_reason or 'line' in (
        stream.ground.counts.last_reason
    )
    finite = scan.ranges[np.isfinite(scan.ranges)]
    assert finite.size > 0
    assert finite.min() >= 0.45 - 0.05


def test_a_frame_without_floor_keeps_the_last_estimate():
    pose = optical_pose(body_pitch=2.0)
    floor = millimetres(box_depth(CAMERA, pose, [BOX]))
    blank = np.zeros_like(floor)  # no return at all (a covered lens)
    scan, stream = depth_scans([floor, blank, floor])
    assert stream.ground is not None
    assert (stream.ground.counts.estimated, stream.ground.counts.fell_back) == (2, 1)
    false, right = score(scan)
    assert (false, right) == (0.0, 1.0)


def test_while_no_floor_is_found_the_learnt_tilt_fades_back_to_the_prior():
    # A plane held for good would keep a ramp's half-climbed tilt at its foot, where the
    # camera sees only ramp: it fades by FALLBACK_FADE (0.5) a frame, half each frame.
    floor = millimetres(box_depth(CAMERA, optical_pose(body_pitch=2.0), [BOX]))
    prior = GroundPlane.of_mounting(optical_pose())
    tracker = GroundTracker(GroundSettings())
    learnt = math.degrees(tracker.update(floor, CAMERA, prior).tilt_from(prior))
    assert learnt == pytest.approx(2.0, abs=0.1)
    blank = np.zeros_like(floor)
    tilt = math.degrees(tracker.update(blank, CAMERA, prior).tilt_from(prior))
    assert tilt == pytest.approx(learnt * 0.5, abs=0.01)
    for _ in range(6):
        tilt = math.degrees(tracker.update(blank, CAMERA, prior).tilt_from(prior))
    assert tilt == pytest.approx(learnt * 0.5**7, abs=0.01)
    assert tilt < 0.02
    assert tracker.counts.fell_back == 7


def test_with_an_imu_while_no_floor_is_found_the_estimate_is_the_plane_the_wheels_stand_on():
    # Turned across a 1:8 ramp (7.1 degrees), facing its side wall: the IMU's level floor is
    # rolled 7.1 degrees from the ramp the robot stands on, which is the floor around it.
    level = GroundPlane.of_mounting(optical_pose(body_roll=math.degrees(math.atan(1 / 8))))
    wheels = GroundPlane.of_mounting(optical_pose())
    floor = millimetres(box_depth(CAMERA, optical_pose(), [BOX]))
    tracker = GroundTracker(GroundSettings())
    found = tracker.update(floor, CAMERA, level, wheels)
    assert math.degrees(found.tilt_from(wheels)) < 0.1
    blank = np.zeros_like(floor)
    for _ in range(3):
        held = tracker.update(blank, CAMERA, level, wheels)
        assert math.degrees(held.tilt_from(wheels)) < 1e-6
        assert held.offset == pytest.approx(wheels.offset, abs=1e-9)
    assert tracker.counts.fell_back == 3


def test_a_platform_as_wide_as_the_view_is_not_taken_for_the_floor():
    # A 6 cm platform from 0.8 m on fills most of the view: its top is a plane within the
    # bounds (6 cm above the floor) with more points than the floor, but the floor lies below
    # it, so the floor wins and the platform's edge is an obstacle at 0.8 m.
    platform = (0.8, 6.0, -6.0, 6.0, 0.0, 0.06)
    depth = millimetres(box_depth(CAMERA, optical_pose(), [platform]))
    scan, _ = depth_scans([depth])
    ahead = scan.ranges[READINGS // 2 - 2 : READINGS // 2 + 3]
    assert np.all(np.abs(ahead - 0.8) <= 0.05 + 0.02 * 0.8)


def ramp_depth(rise: float, pose: Transform | None = None) -> np.ndarray:
    """A ramp from 1.2 m ahead rising `rise` per metre (falling, if negative), with the box
    standing on it: its front face 1.8 m ahead, 6 cm above the ramp there."""
    under = rise * (RAMP_BOX - RAMP_START)
    box = (RAMP_BOX, RAMP_BOX + 0.3, -0.3, 0.3, under - 0.05, under + BOX_HEIGHT)
    return millimetres(
        slope_depth(CAMERA, pose or optical_pose(), start=RAMP_START, rise=rise, boxes=[box])
    )


RAMP_START, RAMP_BOX = 1.2, 1.8
RAMPS = {
    '1:12 up': 1.0 / 12.0,
    '1:12 down': -1.0 / 12.0,
    '1:8 up': 1.0 / 8.0,
    '1:8 down': -1.0 / 8.0,
}


def ramp_score(scan: Scan) -> tuple[float, float]:
    """`score` for the box on the ramp (front face RAMP_BOX ahead)."""
    ranges = scan.ranges.astype(np.float64)
    angles = scan.angle_min + np.arange(ranges.size) * scan.angle_increment
    half = 0.5 * scan.angle_increment
    ahead = np.cos(angles) > 0
    on_face = ahead & (np.abs(np.tan(np.abs(angles) + half)) * RAMP_BOX <= BOX_HALF_WIDTH)
    off_face = ~(ahead & (np.abs(np.tan(angles)) * RAMP_BOX <= BOX_HALF_WIDTH + 0.05))
    in_view = ~np.isnan(ranges)
    false = in_view & off_face & (ranges < scan.range_max)
    truth = RAMP_BOX / np.cos(angles)
    right = on_face & (np.abs(ranges - truth) <= 0.05 + 0.02 * truth)
    return float(false.sum() / in_view.sum()), float(right.sum() / on_face.sum())


@pytest.mark.parametrize('rise', RAMPS.values(), ids=RAMPS.keys())
def test_a_ramp_within_max_slope_is_floor_and_the_box_on_it_an_obstacle(rise):
    scan, stream = depth_scans([ramp_depth(rise)] * 2)
    false, right = ramp_score(scan)
    assert false <= 0.005
    assert right >= 0.95
    assert stream.ground is not None
    assert stream.ground.profile is not None


@pytest.mark.parametrize('rise', RAMPS.values(), ids=RAMPS.keys())
@pytest.mark.parametrize(
    'changes', [{'max_slope': 0.0}, {'ground_estimate': False}], ids=['one plane', 'mounting']
)
def test_the_ramp_is_a_wall_or_a_drop_with_one_plane(rise, changes):
    scan, _ = depth_scans([ramp_depth(rise)], **changes)
    false, _ = ramp_score(scan)
    assert false > 0.1


@pytest.mark.parametrize('rise', [1.0 / 12.0, 1.0 / 8.0], ids=['1:12', '1:8'])
def test_the_ground_in_front_of_a_box_on_a_ramp_is_the_ramp(rise):
    # The bin of the profile that holds the box's face does not rise to the face's foot; held
    # at the bin before, the ground there stood up to a bin's rise (1.9 cm on 1:8) below the
    # ramp, and the ramp in front of the box at the slab's bottom. Once the ramp has stood off
    # the plane (by PROFILE_DEADBAND at a bin's centre) for PROFILE_EVIDENCE bins, the face's
    # bin goes on at the ramp's rise: 1 cm in front of the face, wherever it falls in its bin,
    # the ground is the ramp's height within 1 cm (held, it misses by up to 2.1 cm on 1:8,
    # 1.4 cm on 1:12).
    from scanfuse.convert.ground import (
        PROFILE_BIN,
        PROFILE_DEADBAND,
        PROFILE_EVIDENCE,
        GroundSample,
        ground_profile,
    )

    settings = GroundSettings()
    pose = optical_pose()  # the camera above the base's origin: bins start there
    plane = GroundPlane.of_mounting(pose)
    sample = GroundSample.build(CAMERA, plane, settings.samples, settings.hypotheses)
    ahead = int(np.argmin(np.abs(sample.profile_columns - CAMERA.width / 2)))
    off = math.floor((RAMP_START + PROFILE_DEADBAND / rise) / PROFILE_BIN - 0.5) + 1
    fronts = np.arange((off + PROFILE_EVIDENCE) * PROFILE_BIN, 2.41, 0.025)
    for front in fronts:
        under = rise * (front - RAMP_START)
        box = (front, front + 0.3, -0.3, 0.3, under - 0.05, under + BOX_HEIGHT)
        depth = slope_depth(CAMERA, pose, start=RAMP_START, rise=rise, boxes=[box])
        profile = ground_profile(millimetres(depth), sample, plane, settings)
        assert profile is not None
        centres = (np.arange(profile.heights.shape[1]) + 0.5) * PROFILE_BIN
        at = front - 0.01
        ground = np.interp(at, centres, profile.heights[ahead])
        assert ground == pytest.approx(rise * (at - RAMP_START), abs=0.01), front
    assert fronts.size >= 18


def test_a_ramp_seen_from_a_pitching_body_is_floor_too():
    scan, _ = depth_scans([ramp_depth(1.0 / 12.0, optical_pose(body_pitch=2.0))] * 2)
    false, right = ramp_score(scan)
    assert false <= 0.005
    assert right >= 0.95


# A camera whose ramp lifts come in blocks of 3 pixels a side (`ground.lift_stride`), the
# last row and column of blocks cut short.
ODD_CAMERA = CameraModel.from_intrinsics(1000, 701, 500.0, 500.0, 499.5, 350.0)


@pytest.mark.parametrize('bottom_noise', [0.0, 0.03], ids=['slab', 'slab raised by noise'])
@pytest.mark.parametrize('camera', [CAMERA, ODD_CAMERA], ids=['848x480', '1000x701'])
@pytest.mark.parametrize('ramp', [False, True], ids=['plane', 'ramp'])
def test_the_compiled_height_tables_are_the_numpy_ones(ramp, camera, bottom_noise):
    from scanfuse.convert.obstacle import DropLimits, ObstacleProjector
    from scanfuse.scan import AngleGrid
    from scanfuse.transforms import Extrinsics

    extrinsics = Extrinsics.from_mounting(camera_height=HEIGHT, camera_pitch=PITCH)
    pose = optical_pose(body_pitch=1.5, body_roll=-1.0)
    rise = 1.0 / 12.0
    box = (RAMP_BOX, RAMP_BOX + 0.3, -0.3, 0.3, rise * (RAMP_BOX - RAMP_START) - 0.05, 0.2)
    depth = millimetres(
        slope_depth(camera, pose, start=RAMP_START, rise=rise, boxes=[box])
        if ramp
        else box_depth(camera, pose, [BOX])
    )
    tracker = GroundTracker(GroundSettings())
    plane = tracker.update(depth, camera, GroundPlane.of_mounting(optical_pose()))
    assert (tracker.profile is not None) == ramp
    if ramp:
        assert tracker.profile is not None
        assert tracker.profile.slab_lifts(camera, 3.0, 0.03, 0.5).stride == (
            2 if camera is CAMERA else 3
        )
    grid = AngleGrid(-math.pi, 2.0 * math.pi / READINGS, READINGS)
    projectors = [
        ObstacleProjector(
            camera, extrinsics, grid, min_obstacle_height=0.03, max_obstacle_height=0.5,
            range_min=0.2, range_max=3.0, drops=DropLimits(0.05, 0.02, 0.01), use_kernel=kernel,
            bottom_noise=bottom_noise,
        )
        for kernel in (True, False)
    ]  # fmt: skip
    compiled, reference = projectors
    assert compiled.uses_kernel
    for projector in projectors:
        assert projector.use_ground(plane, tracker.profile)
    for ours, theirs in zip(
        (*compiled._metres, *compiled._millimetres),
        (*reference._metres, *reference._millimetres),
        strict=True,
    ):
        np.testing.assert_allclose(ours, theirs, rtol=1e-6, atol=1e-6)
    # The blocks' extremes as numpy finds them from the compiled pass's tables.
    for dtype, extremes in compiled._extremes().items():
        for ours, theirs in zip(compiled._block_extremes[dtype], extremes, strict=True):
            np.testing.assert_array_equal(ours, theirs)


@pytest.mark.parametrize('rise', [1.0 / 12.0, -1.0 / 8.0], ids=['1:12 up', '1:8 down'])
def test_the_memory_remembers_no_ramp(rise):
    from scanfuse.motion import PlanarPose

    def remembered(**changes: object) -> int:
        stream: FusionStream[int] = FusionStream(config(memory=True, **changes))
        stream.add_camera_info(CAMERA)
        depth = millimetres(slope_depth(CAMERA, optical_pose(), start=1.2, rise=rise))
        for index in range(1, 4):
            stamp = index * NS // 10
            for odometry_ns in range(stamp - NS // 20, stamp + NS // 20, NS // 50):
                stream.add_odometry(odometry_ns, PlanarPose(0.0, 0.0, 0.0))
            stream.add_depth(stamp, depth, stamp)
            stream.add_scan(lidar_scan(stamp), index, stamp + 1)
        assert stream.memory is not None
        return len(stream.memory)

    assert remembered() == 0
    assert remembered(max_slope=0.0) > 0  # the ramp, as one plane's obstacle


def test_the_camera_clears_a_remembered_box_from_a_ramp_it_no_longer_stands_on():
    from scanfuse.motion import PlanarPose

    # The ramp stands 8.75 cm high under the box (within memory_radius, 2 m). (The clearing's
    # margins, 20 cm of depth there, would let a flat floor's clearing see past it too: this
    # shows the remembered box goes, not which ground cleared it.)
    rise, front = 1.0 / 8.0, 1.9
    under = rise * (front - 1.2)
    box = (front, front + 0.3, -0.3, 0.3, under - 0.05, under + BOX_HEIGHT)
    with_box = millimetres(slope_depth(CAMERA, optical_pose(), start=1.2, rise=rise, boxes=[box]))
    without = millimetres(slope_depth(CAMERA, optical_pose(), start=1.2, rise=rise))
    stream: FusionStream[int] = FusionStream(config(memory=True))
    stream.add_camera_info(CAMERA)
    counts = []
    for index, depth in enumerate([with_box] * 3 + [without] * 3, start=1):
        stamp = index * NS // 10
        for odometry_ns in range(stamp - NS // 20, stamp + NS // 20, NS // 50):
            stream.add_odometry(odometry_ns, PlanarPose(0.0, 0.0, 0.0))
        stream.add_depth(stamp, depth, stamp)
        stream.add_scan(lidar_scan(stamp), index, stamp + 1)
        assert stream.memory is not None
        counts.append(len(stream.memory))
    assert counts[2] > 0  # the box, remembered
    assert counts[-1] == 0  # seen gone: the ramp under it is floor


@pytest.mark.parametrize('pitch', [2.0, -2.0], ids=['nose-down', 'nose-up'])
def test_a_sudden_pitch_shows_no_floor_from_its_first_frame(pitch):
    # The smoothed plane lags the body by (1 - ground_smoothing) of the change; what is left
    # is a tilt of the floor ahead, well within max_slope: the profile takes it.
    level = millimetres(box_depth(CAMERA, optical_pose(), [BOX]))
    pitched = millimetres(box_depth(CAMERA, optical_pose(body_pitch=pitch), [BOX]))
    stream: FusionStream[int] = FusionStream(config())
    stream.add_camera_info(CAMERA)
    for index, depth in enumerate([level] * 3 + [pitched] * 3, start=1):
        stamp = index * NS // 10
        stream.add_depth(stamp, depth, stamp)
        (out,) = stream.add_scan(lidar_scan(stamp), index, stamp + 1)
        assert out.depth_scan is not None
        assert score(out.depth_scan) == (0.0, 1.0), index


# Ramps met near the robot (issue 25): the plane is the floor the robot stands on, however
# much of the view the ramp fills.
NEAR_RAMPS = {
    '1:12 up from 0.9 m': (0.9, 1.0 / 12.0),
    '1:12 down from 0.9 m': (0.9, -1.0 / 12.0),
    '1:8 up from 0.9 m': (0.9, 1.0 / 8.0),
    '1:8 down from 0.9 m': (0.9, -1.0 / 8.0),
}


@pytest.mark.parametrize(('start', 'rise'), NEAR_RAMPS.values(), ids=NEAR_RAMPS.keys())
def test_a_ramp_starting_near_the_robot_does_not_tilt_the_floor_plane(start, rise):
    # The floor is first seen 0.34 m ahead (the view's lowest ray, 49.5 deg down from 0.4 m):
    # the ramp fills the view from 0.56 m beyond that on.
    depth = millimetres(slope_depth(CAMERA, optical_pose(), start=start, rise=rise))
    prior = GroundPlane.of_mounting(optical_pose())
    plane = GroundTracker(GroundSettings()).update(depth, CAMERA, prior)
    assert math.degrees(plane.tilt_from(prior)) < 0.1
    assert plane.offset == pytest.approx(prior.offset, abs=0.002)


@pytest.mark.parametrize('rise', [1.0 / 12.0, 1.0 / 8.0], ids=['1:12', '1:8'])
def test_a_ramp_from_under_the_robots_front_is_floor_and_the_box_on_it_an_obstacle(rise):
    # The ramp's foot 0.2 m ahead: the camera sees no floor that is not ramp; its plane
    # (7.1 deg for 1:8, within ground_max_tilt) is the floor.
    under = rise * (RAMP_BOX - 0.2)
    box = (RAMP_BOX, RAMP_BOX + 0.3, -0.3, 0.3, under - 0.05, under + BOX_HEIGHT)
    depth = millimetres(slope_depth(CAMERA, optical_pose(), start=0.2, rise=rise, boxes=[box]))
    scan, _ = depth_scans([depth] * 2)
    false, right = ramp_score(scan)
    assert false <= 0.005
    assert right >= 0.95


def noisy(depth_m: np.ndarray, seed: int, sigma_per_m2: float = 0.01) -> np.ndarray:
    """`depth_m` (metres, inf: none) with a D435's noise along the optical axis (sigma =
    0.01 Z^2, the simulator's), in millimetres."""
    rng = np.random.default_rng(seed)
    noise = (
        rng.standard_normal(depth_m.shape)
        * sigma_per_m2
        * np.where(np.isfinite(depth_m), depth_m, 0.0) ** 2
    )
    return millimetres(depth_m + noise)


def test_noise_over_a_ramp_rising_ahead_costs_about_what_it_costs_over_a_flat_floor(
    monkeypatch,
):
    # Noise moves a reading along its ray: short of a rising ramp it lands above lower
    # ground, by up to twice as much as over a flat floor at 3 m. The slab's bottom is raised
    # there by 3 sigma of that extra (ground.SLOPE_NOISE_SIGMAS). What noise costs over a
    # flat floor in this 848x480 scene (about 9 % of the slots in view: single readings the
    # k-nearest rule keeps, as it keeps a thin obstacle's) is the measure.
    from scanfuse.convert import ground

    def worst(depths: list[np.ndarray], score_of) -> tuple[float, float]:
        scores = [score_of(depth_scans(depths[: index + 1])[0]) for index in range(3)]
        return max(false for false, _ in scores), min(right for _, right in scores)

    flat = box_depth(CAMERA, optical_pose(), [BOX])
    flat_false, _ = worst([noisy(flat, seed) for seed in range(3)], score)
    rise = 1.0 / 12.0
    under = rise * (RAMP_BOX - RAMP_START)
    box = (RAMP_BOX, RAMP_BOX + 0.3, -0.3, 0.3, under - 0.05, under + BOX_HEIGHT)
    clean = slope_depth(CAMERA, optical_pose(), start=RAMP_START, rise=rise, boxes=[box])
    ramp = [noisy(clean, seed) for seed in range(3)]
    false, right = worst(ramp, ramp_score)
    assert false <= 2.0 * flat_false
    assert right >= 0.85
    # Without the slope margin nor the profile's doubt (`PROFILE_DOUBT_SIGMAS`, which also
    # raises the slab over the ramp's sparse far bins) the ramp's noise costs far more.
    monkeypatch.setattr(ground, 'SLOPE_NOISE_SIGMAS', 0.0)
    monkeypatch.setattr(ground, 'PROFILE_DOUBT_SIGMAS', 0.0)
    unraised, _ = worst(ramp, ramp_score)
    assert false <= 0.6 * unraised


def test_noise_beyond_a_ramp_falling_ahead_costs_less_than_twice_a_flat_floors(
    monkeypatch,
):
    # A 1:8 ramp down from 1 m to a floor 0.15 m lower: 2-3 m out the profile's bins hold a
    # noisy point or two, and a bin's ground drawn low put the floor beyond in the slab. The
    # slab stands PROFILE_DOUBT_SIGMAS sigmas of each bin's mean higher above it.
    from scanfuse.convert import ground

    def worst_false(depths: list[np.ndarray]) -> float:
        worst = 0.0
        for index in range(3):
            scan, _ = depth_scans(depths[: index + 1])
            in_view = ~np.isnan(scan.ranges)
            false = in_view & (scan.ranges < scan.range_max)
            worst = max(worst, float(false.sum() / in_view.sum()))
        return worst

    flat = box_depth(CAMERA, optical_pose(), [])
    flat_false = worst_false([noisy(flat, seed) for seed in range(3)])
    pieces = [(-math.inf, 1.0, 0.0, 0.0), (1.0, 2.2, 0.0, -1.0 / 8.0), (2.2, math.inf, -0.15, 0.0)]
    clean = ground_depth(CAMERA, optical_pose(), pieces)
    ramp = [noisy(clean, seed) for seed in range(3)]
    assert worst_false(ramp) <= 2.0 * flat_false
    monkeypatch.setattr(ground, 'PROFILE_DOUBT_SIGMAS', 0.0)
    assert worst_false(ramp) > 2.5 * flat_false


def test_a_flat_floors_noise_makes_no_profile_and_a_ramp_from_2_m_still_does(monkeypatch):
    # Far out a bin of the profile holds a point or two, each a centimetre or more off in
    # height (sigma = 0.01 Z^2 along the ray): with the deadband alone, some frames of a flat
    # floor made a profile (and rebuilt the tables, twice). Off the plane by 3 sigma of the
    # bin's mean as well, none does; a ramp leaves the plane by more than that.
    from scanfuse.convert import ground
    from tests.support import room

    mounting = room.MOUNTING.base_to_camera_optical
    prior = GroundPlane.of_mounting(mounting)

    def profiled(depth: np.ndarray, camera: CameraModel, prior: GroundPlane) -> bool:
        tracker = GroundTracker(GroundSettings())
        tracker.update(depth, camera, prior)
        return tracker.profile is not None

    def room_profiles() -> int:
        count = 0
        for width, height in ((848, 480), (1280, 720)):
            camera = room.d435(width, height)
            walls = box_depth(camera, mounting, room.WALLS)
            count += sum(profiled(noisy(walls, seed), camera, prior) for seed in range(40))
        return count

    assert room_profiles() == 0
    level = GroundPlane.of_mounting(optical_pose())
    for rise in (1.0 / 12.0, -1.0 / 12.0):
        ramp = slope_depth(CAMERA, optical_pose(), start=2.0, rise=rise)
        assert all(profiled(noisy(ramp, seed), CAMERA, level) for seed in range(10))
    monkeypatch.setattr(ground, 'PROFILE_EVIDENCE_SIGMAS', 0.0)  # the deadband alone
    assert room_profiles() > 0


def test_the_slope_margin_is_three_sigma_of_the_extra_noise_above_the_ramp():
    from scanfuse.convert.ground_kernel import slope_margin

    # A ray falling 0.1 m per metre of depth over ground rising 0.05 m per metre of depth,
    # at a depth of noise 0.04 m: 0.04 * 0.05 = 2 mm of extra height above the ramp; the
    # tables hold the ground where the ray crosses, so the lift is 2 mm * 0.1 / 0.15.
    assert slope_margin(0.04, 0.05, -0.1) == pytest.approx(0.002 * 0.1 / 0.15)
    assert slope_margin(0.04, 0.0, -0.1) == 0.0  # flat
    assert slope_margin(0.04, -0.05, -0.1) == 0.0  # falling away: readings land lower
    assert slope_margin(0.04, 0.05, 0.1) == 0.0  # a ray looking up
    assert slope_margin(0.0, 0.05, -0.1) == 0.0  # no noise


def test_random_triples_stop_once_one_held_only_inliers_with_999_in_1000():
    from scanfuse.convert.ground_kernel import triples_needed

    # Hartley and Zisserman's N = log(1 - p) / log(1 - w^3), p = 0.999, rounded up:
    # w = 0.9: -6.908 / log(0.271) = -6.908 / -1.306 = 5.29, so 6;
    # w = 0.5: -6.908 / log(0.875) = -6.908 / -0.1335 = 51.7, so 52 (more than the 40 drawn).
    assert triples_needed(0.9) == 6
    assert triples_needed(0.5) == 52
    assert triples_needed(1.0) == 0  # the hypothesis already holds every candidate
    assert triples_needed(0.0) > 10**6  # no inlier: every triple drawn


def test_the_fit_without_numba_gives_the_compiled_fits_plane():
    from scanfuse.convert import ground_kernel
    from scanfuse.convert.ground import GroundSample, _kernel_depth

    depth = millimetres(box_depth(CAMERA, optical_pose(body_pitch=2.0), [BOX]))
    prior = GroundPlane.of_mounting(optical_pose())
    settings = GroundSettings()
    sample = GroundSample.build(CAMERA, prior, settings.samples, settings.hypotheses)
    flat, scale = _kernel_depth(depth)
    results = []
    for fit in (ground_kernel.fit, ground_kernel._fit):
        out = np.empty(7)
        fit(
            flat, scale, sample.indices, sample.rays, np.array([*prior.normal, prior.offset]),
            np.array([*prior.normal, prior.offset]), np.array([*prior.normal, prior.offset]),
            settings.max_offset, settings.max_tilt,
            settings.reach, settings.inlier_distance, settings.depth_noise, sample.draws,
            settings.min_points, settings.min_spread, out,
        )  # fmt: skip
        results.append(out)
    compiled, plain = results
    assert compiled[6] == ground_kernel.OK
    np.testing.assert_allclose(plain, compiled, rtol=1e-9, atol=1e-12)


def platform_depth(start: float, platform: float, *, ledge: float = 0.0) -> np.ndarray:
    """A 1:8 ramp from `start` up 0.15 m to a platform `platform` long, and past its end an
    equal ramp down to the floor; or with `ledge`, ground that many metres lower."""
    run = 0.15 * 8.0
    end = start + run + platform
    pieces = [
        (-math.inf, start, 0.0, 0.0),
        (start, start + run, 0.0, 1.0 / 8.0),
        (start + run, end, 0.15, 0.0),
    ]
    if ledge:
        pieces.append((end, math.inf, 0.15 - ledge, 0.0))
    else:
        pieces += [(end, end + run, 0.15, -1.0 / 8.0), (end + run, math.inf, 0.0, 0.0)]
    return millimetres(ground_depth(CAMERA, optical_pose(), pieces))


DOWN_RAMPS = {'top 2.3 m ahead': (0.8, 0.3), 'top 2.6 m ahead': (0.8, 0.6), 'short': (1.0, 0.1)}


@pytest.mark.parametrize(('start', 'platform'), DOWN_RAMPS.values(), ids=DOWN_RAMPS.keys())
def test_a_down_ramp_hidden_behind_its_top_is_no_drop(start, platform):
    # From 0.25 m above the platform a line of sight over its end falls less steeply than
    # 1:8: the ramp down is hidden, and the floor is seen again 0.15 m lower, far beyond.
    scan, _ = depth_scans([platform_depth(start, platform)] * 3)
    in_view = ~np.isnan(scan.ranges)
    false = in_view & (scan.ranges < scan.range_max)
    assert false.sum() <= 0.005 * in_view.sum()


def test_a_ledge_past_a_platform_is_a_drop_at_its_edge():
    # The ramp's top ends 1.8 m ahead in a ledge 0.4 m deep: a line of sight over the edge
    # falls faster than 1:8, and meets ground 0.4 m lower: deeper than any ramp's fall.
    scan, _ = depth_scans([platform_depth(0.6, 0.0, ledge=0.4)] * 3)
    ahead = scan.ranges[READINGS // 2 - 2 : READINGS // 2 + 3]
    assert np.all(np.abs(ahead - 1.8) <= 0.08)


RAMP_SLOPE = math.atan(1.0 / 8.0)


def crest_depth(crest: float, edge: float, *, ledge: float = 0.0) -> np.ndarray:
    """Seen from a robot standing on a 1:8 ramp (pitched nose up by its slope), in the base's
    frame: the ramp's top `crest` metres ahead, a level platform to `edge`, then an equal ramp
    down 1.2 m long to level floor; or with `ledge`, ground that many metres lower. Above the
    base's plane the platform falls at the ramp's slope, the ramp down at twice it."""
    platform, down = -math.tan(RAMP_SLOPE), -math.tan(2.0 * RAMP_SLOPE)
    top = platform * (edge - crest)
    pieces = [(-math.inf, crest, 0.0, 0.0), (crest, edge, 0.0, platform)]
    if ledge:
        pieces.append((edge, math.inf, top - ledge, platform))
    else:
        foot = edge + 1.2
        pieces += [(edge, foot, top, down), (foot, math.inf, top + 1.2 * down, platform)]
    return millimetres(ground_depth(CAMERA, optical_pose(), pieces))


def crest_scan(depth: np.ndarray, *, imu: bool) -> Scan:
    """The depth scan of three frames of `depth`, with the IMU's pitch (nose up by the ramp's
    slope, REP-103: negative) or without an IMU."""
    stream: FusionStream[int] = FusionStream(config())
    stream.add_camera_info(CAMERA)
    tilt = Transform.from_rpy(0.0, -RAMP_SLOPE, 0.0)
    out = None
    for index in range(3):
        stamp = (index + 1) * NS // 10
        if imu:
            stream.add_imu(stamp, tilt.rotation, 'base_link')
        stream.add_depth(stamp, depth, stamp)
        (out,) = stream.add_scan(lidar_scan(stamp), index, stamp + 1)
    assert out is not None
    assert out.depth_scan is not None, out.passed
    return out.depth_scan


def false_share(scan: Scan) -> float:
    """Share of the slots in view that hold anything (on these scenes all is floor)."""
    in_view = ~np.isnan(scan.ranges)
    return float((in_view & (scan.ranges < scan.range_max)).sum() / in_view.sum())


# The ramp's top and the platform's end, metres ahead.
CRESTS = {'top 0.6 m ahead': (0.6, 1.2), 'top 0.5 m ahead, platform 1 m': (0.5, 1.5)}


@pytest.mark.parametrize(('crest', 'edge'), CRESTS.values(), ids=CRESTS.keys())
def test_from_a_ramp_the_platform_and_the_ramp_down_past_its_top_are_floor_with_an_imu(crest, edge):
    # Judged above the ramp the robot stands on, the ramp down falls at twice max_slope: a
    # drop. Judged above level (the IMU's), it falls at max_slope: floor.
    depth = crest_depth(crest, edge)
    assert false_share(crest_scan(depth, imu=True)) <= 0.005
    assert false_share(crest_scan(depth, imu=False)) > 0.1


# The ramp's top and the platform's end, metres ahead: the end near enough that the ramp
# down past it is seen, at a grazing angle.
NEAR_ENDS = {
    'end 1.8 m ahead': (0.8, 1.8),
    'end 1.9 m ahead': (0.9, 1.9),
    'end 2.0 m ahead': (1.0, 2.0),
}


@pytest.mark.parametrize(('crest', 'edge'), NEAR_ENDS.values(), ids=NEAR_ENDS.keys())
def test_from_a_ramp_the_ramp_down_seen_past_a_near_platform_is_no_drop_ahead(crest, edge):
    # From 0.3 m above the platform a line of sight over its end falls 9-10 degrees, the
    # ramp down 7.1 above level: that ramp is seen at 2-3 degrees, the image rows sampled
    # 0.4-0.7 m apart on it. Its ground falls across the bins between them at up to the
    # steepest floor's fall, and the lowest the ground may be within a bin is at most the
    # next one's: a line of sight grazing one bin's single height met it early, 4 cm above
    # the ramp, and the ramp was a drop (13-79 % of the slots in view).
    scan = crest_scan(crest_depth(crest, edge), imu=True)
    angles = scan.angle_min + np.arange(scan.ranges.size) * scan.angle_increment
    ahead = np.abs(angles) <= math.radians(15.0)
    assert np.all(np.isinf(scan.ranges[ahead]))
    # Farther out to the sides, where the bins' radial distances cross the platform's end
    # obliquely, some slots still read a drop there.
    assert false_share(scan) <= 0.15


def test_from_a_ramp_a_ledge_past_the_platform_is_still_a_drop_with_an_imu():
    scan = crest_scan(crest_depth(0.6, 1.2, ledge=0.4), imu=True)
    ahead = scan.ranges[READINGS // 2 - 2 : READINGS // 2 + 3]
    # The platform's edge, 1.2 m ahead along the base: the LiDAR's plane is the base's.
    assert np.all(np.abs(ahead - 1.2) <= 0.08)
