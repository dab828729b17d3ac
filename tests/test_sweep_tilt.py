"""A body that rocks within one LiDAR sweep (issue 25): each beam set down with its own tilt.

A 10 Hz LiDAR takes a tenth of a second over its turn. A sprung body rocking over a ramp's
foot or crest, or setting off on one, pitches 2-5 degrees in that time (the simulator's IMU
shows 5.5 -> 10.5 degrees within one sweep half-way up its 1:8 ramp). A beam's point lies
where the body's tilt at the beam's own time puts it: levelled with the tilt at the scan's
stamp, a floor return 2.4 m out stands 4 cm off the floor per degree of difference.

Here the body's pitch runs linearly across the sweep, the IMU sampled at 200 Hz; where each
beam meets the floor is worked out from the geometry alone.
"""

from __future__ import annotations

import math
from dataclasses import replace
from typing import TYPE_CHECKING

import numpy as np
import pytest

from scanfuse.camera import CameraModel
from scanfuse.config import FusionConfig
from scanfuse.imu import ImuHistory, tilt_matrices
from scanfuse.motion import PlanarPose
from scanfuse.scan_matching import levelled
from scanfuse.stream import FusionStream, beam_stamps
from scanfuse.transforms import BODY_TO_OPTICAL, Transform
from tests.support.ground_scene import NS, READINGS, lidar_scan
from tests.support.render import depth_image, square_room_ranges, tilted_room_ranges
from tests.test_trail import HALF_WIDTH, LIDAR_HEIGHT, SLOPE, driven_trail, height_at, path

if TYPE_CHECKING:
    from scanfuse.scan import Scan

SWEEP_NS = NS // 10  # a 10 Hz LiDAR
TIME_INCREMENT = SWEEP_NS / NS / READINGS
IMU_PERIOD_NS = 5_000_000  # 200 Hz
STAMP = 10 * NS


def sweep_scan(stamp_ns: int, ranges: np.ndarray, *, timed: bool = True) -> Scan:
    """`tests/support/ground_scene.py`'s 360-degree scan from -pi with `ranges`; its beam i
    measured at stamp + i time_increment (`timed`), or saying nothing of when (0)."""
    return replace(
        lidar_scan(stamp_ns),
        ranges=ranges.astype(np.float32),
        time_increment=TIME_INCREMENT if timed else 0.0,
    )


def pitch_over(first: float, last: float, stamp_ns: int):
    """The body's pitch (radians, REP-103: nose down positive) at a time: `first` at
    `stamp_ns`, `last` one sweep later, linear between and beyond."""

    def pitch(t_ns: float) -> float:
        return first + (last - first) * (t_ns - stamp_ns) / SWEEP_NS

    return pitch


def beam_times(stamp_ns: int) -> np.ndarray:
    return stamp_ns + np.arange(READINGS) * TIME_INCREMENT * NS


# ---------------------------------------------------------------- the IMU across a sweep


def test_each_beam_gets_the_tilt_at_its_own_time():
    pitch = pitch_over(math.radians(5.5), math.radians(10.5), STAMP)
    history = ImuHistory()
    for t in range(STAMP - SWEEP_NS, STAMP + 2 * SWEEP_NS, IMU_PERIOD_NS):
        history.add(t, Transform.from_rpy(math.radians(1.0), pitch(t), 0.0))
    stamps = beam_stamps(sweep_scan(STAMP, np.ones(READINGS)))
    assert stamps is not None
    tilts = history.tilts_over(stamps)
    assert tilts is not None
    assert tilts.shape == (READINGS, 3, 3)
    # R = Ry(pitch) Rx(roll): R[2, 0] = -sin(pitch), R[2, 1] / R[2, 2] = tan(roll). `tilt_at`
    # averages the samples within 20 ms; on a 5 ms grid their mean time lies up to half a
    # period from the stamp asked for: the pitch may be off by its rate times that.
    rate = math.radians(5.0) / SWEEP_NS
    np.testing.assert_allclose(
        np.arcsin(-tilts[:, 2, 0]),
        [pitch(t) for t in beam_times(STAMP)],
        atol=rate * IMU_PERIOD_NS / 2 + 1e-9,
    )
    np.testing.assert_allclose(np.arctan2(tilts[:, 2, 1], tilts[:, 2, 2]), math.radians(1.0))


def test_a_sweep_the_imu_does_not_cover_gets_no_tilts():
    history = ImuHistory()
    for t in range(STAMP - SWEEP_NS, STAMP + 30_000_000, IMU_PERIOD_NS):  # stopped 30 ms in
        history.add(t, Transform.from_rpy(0.0, 0.1, 0.0))
    stamps = beam_stamps(sweep_scan(STAMP, np.ones(READINGS)))
    assert stamps is not None
    assert history.tilts_over(stamps) is None  # its last beams lie 70 ms past the last sample


def test_beam_stamps_follow_the_sweep_and_find_the_beam_along_a_bearing():
    scan = sweep_scan(STAMP, np.ones(READINGS))
    stamps = beam_stamps(scan)
    assert stamps is not None
    np.testing.assert_array_equal(stamps, np.rint(beam_times(STAMP)).astype(np.int64))
    # Beam 0 points at -pi, beam READINGS / 2 ahead, the last just short of +pi; a bearing of +pi is
    # beam 0's (the turn closes there), half a beam either side of a beam is that beam.
    half = 0.49 * scan.angle_increment
    bearings = np.array([0.0, -math.pi, math.pi, math.pi - 2 * half, 0.0 + half, -half])
    along = beam_stamps(scan, bearings)
    assert along is not None
    ahead = READINGS // 2
    np.testing.assert_array_equal(along, stamps[[ahead, 0, 0, READINGS - 1, ahead, ahead]])
    assert beam_stamps(sweep_scan(STAMP, np.ones(READINGS), timed=False)) is None


def test_tilt_matrices_are_the_rotations_from_roll_and_pitch():
    roll, pitch = np.array([0.1, -0.3, 0.0]), np.array([-0.2, 0.05, 0.4])
    for index, matrix in enumerate(tilt_matrices(roll, pitch)):
        expected = Transform.from_rpy(roll[index], pitch[index], 0.0).rotation_matrix
        np.testing.assert_allclose(matrix, expected, atol=1e-12)


# ---------------------------------------------------------------- the ground driven over

# Half-way up `tests/test_trail.py`'s 1:8 ramp, the body's nose-up pitch runs from the ramp's
# 7.1 degrees less ROCK[0] at the sweep's first beam to it plus ROCK[1] at its last.
ROCK = (math.radians(1.6), math.radians(3.4))


def floor_behind(x: float, angles: np.ndarray, nose_up: np.ndarray) -> np.ndarray:
    """Points (base frame, N x 3) where the beams at `angles` of the LiDAR LIDAR_HEIGHT up a
    base at x on the ramp, pitched nose-up by `nose_up` each, meet the level floor behind
    (R = Ry(-pitch): a point's height is base + sin(p) x + cos(p) z, with x = r cos(a))."""
    reach = (height_at(x) + LIDAR_HEIGHT * np.cos(nose_up)) / (-np.cos(angles) * np.sin(nose_up))
    return np.stack(
        [reach * np.cos(angles), reach * np.sin(angles), np.full(angles.size, LIDAR_HEIGHT)], 1
    )


def test_a_rocking_body_s_floor_behind_is_found_with_each_beam_s_tilt():
    x = path()[-1]
    pose = PlanarPose(float(x), 0.0, 0.0)
    # The beams behind: those just past -pi come first in a sweep from -pi, those just
    # short of +pi last, when the body has rocked furthest; each beam's pitch is the one at
    # its share of the sweep.
    angles = np.radians(
        np.concatenate([np.arange(-180.0, -173.0, 0.5), np.arange(174.0, 180.0, 0.5)])
    )
    share = (angles + math.pi) / (2.0 * math.pi)
    nose_up = SLOPE - ROCK[0] + (ROCK[0] + ROCK[1]) * share
    floor = floor_behind(x, angles, nose_up)
    assert np.all(np.abs(floor[:, 1]) < 0.9 * HALF_WIDTH)  # on the ground driven over
    beams = tilt_matrices(np.zeros(angles.size), -nose_up)
    trail = driven_trail()
    assert trail.on_ground(floor, pose, beams[0], beams).all()
    # Set down with the tilt at the sweep's first beam alone, the floor the last beams met
    # 2.3 m off, 5 degrees further pitched, stands 20 cm off its cells: not found.
    found = driven_trail().on_ground(floor, pose, beams[0])
    late = share > 0.9
    assert late.sum() >= 10
    assert found[~late].all()
    assert not found[late].any()


# ---------------------------------------------------------------- the stream

BRAKE = (math.radians(6.0), math.radians(11.0))  # nose down, at the sweep's first and last beam
CAMERA = CameraModel.from_intrinsics(320, 240, 200.0, 200.0, 159.5, 119.5, frame_id='optical')
CAMERA_HEIGHT, CAMERA_PITCH = 0.4, math.radians(15.0)


def rocking_output(*, timed: bool) -> tuple[Scan, Scan, FusionStream[None]]:
    """A robot standing in `tests/test_seen_ground.py`'s room of walls at +-3 m, its body
    pitching nose down from BRAKE[0] to BRAKE[1] across the sweep (the IMU at 200 Hz). The
    camera's frame is taken at the sweep's first beam, at BRAKE[0]; the LiDAR's beams ahead,
    half-way through the sweep, meet the floor at the pitch of their own time. Returns the
    scan as sent, the published one and the stream."""
    config = FusionConfig(
        use_tf=False, camera_height=CAMERA_HEIGHT, camera_pitch=CAMERA_PITCH,
        lidar_height=LIDAR_HEIGHT, obstacle_min_points=1, memory=False, ground_trail=False,
    )  # fmt: skip
    stream: FusionStream[None] = FusionStream(config)
    stream.add_camera_info(CAMERA)
    imu_ns = STAMP - 2 * SWEEP_NS
    stream.add_odometry(imu_ns, PlanarPose(0.0, 0.0, 0.0))
    out = sent = None
    for scan_ns in (STAMP - SWEEP_NS, STAMP):
        pitch = pitch_over(*BRAKE, scan_ns)
        # The IMU up to this scan's stamp; for the scan scored, across its sweep and beyond.
        end = scan_ns + (2 * SWEEP_NS if scan_ns == STAMP else 0)
        while imu_ns <= end:
            stream.add_imu(
                imu_ns, Transform.from_rpy(0.0, pitch(imu_ns), 0.0).rotation, 'base_link'
            )
            imu_ns += IMU_PERIOD_NS
        at_frame = Transform.from_rpy(0.0, pitch(scan_ns), 0.0)
        view = at_frame @ Transform.from_rpy(0.0, CAMERA_PITCH, 0.0, (0.0, 0.0, CAMERA_HEIGHT))
        stream.add_depth(scan_ns, depth_image(CAMERA, view @ BODY_TO_OPTICAL, []), scan_ns)
        ranges = np.array(
            [
                tilted_room_ranges(
                    (0.0, 0.0, 0.0),
                    Transform.from_rpy(0.0, pitch(t), 0.0).rotation_matrix,
                    np.array([angle]),
                    height=LIDAR_HEIGHT,
                    half=3.0,
                )[0]
                for angle, t in zip(
                    sweep_scan(0, np.ones(READINGS)).angles(), beam_times(scan_ns), strict=True
                )
            ]
        )
        sent = sweep_scan(scan_ns, ranges, timed=timed)
        stream.add_odometry(scan_ns + SWEEP_NS + 1, PlanarPose(0.0, 0.0, 0.0))
        (out,) = stream.add_scan(sent, None, scan_ns + SWEEP_NS + 1)
    assert out is not None
    assert sent is not None
    return sent, out.fused if out.fused is not None else out.lidar, stream


@pytest.mark.parametrize('timed', [True, False], ids=['beam by beam', 'at the stamp'])
def test_a_body_pitching_within_the_sweep_has_its_floor_ahead_dropped_beam_by_beam(timed):
    sent, published, stream = rocking_output(timed=timed)
    angles = sent.angles()
    ahead = np.flatnonzero(np.abs(angles) <= math.radians(30.0))
    # What the beams ahead read is the floor (worked out: 0.3 cos(p) / (sin(p) cos(a)) at the
    # pitch p of each beam's time, 1.9-2.3 m), not the walls 3 m off.
    pitch = pitch_over(*BRAKE, sent.stamp_ns)
    at = np.array([pitch(t) for t in beam_times(sent.stamp_ns)])[ahead]
    expected = LIDAR_HEIGHT * np.cos(at) / (np.sin(at) * np.cos(angles[ahead]))
    np.testing.assert_allclose(sent.ranges[ahead], expected, rtol=1e-5)
    assert np.all(expected < 2.5)
    kept = np.isfinite(published.ranges[ahead])
    if timed:
        # Each set down with its own time's tilt, turned back to the frame's: on the floor
        # the camera saw, dropped, every one.
        assert not kept.any()
        assert stream.counts.lidar_on_seen_ground >= len(ahead)
    else:
        # Without the sweep's timing every beam is taken at the frame's tilt: a beam pitched
        # 2.5 degrees further meets the floor 2 m out some 9 cm nearer than that tilt puts the
        # floor, which stands it above the slab's bottom: kept, a false wall.
        assert kept.mean() > 0.9


# ---------------------------------------------------------------- scan matching


def test_a_rocking_body_s_scan_levelled_beam_by_beam_keeps_only_the_walls():
    # The room of walls at +-3 m; the body pitches nose down from 3 to 9 degrees across the
    # sweep, so the beams ahead (half-way through it, at 6) meet the floor 2.9 m out.
    pitch = pitch_over(math.radians(3.0), math.radians(9.0), STAMP)
    angles = sweep_scan(0, np.ones(READINGS)).angles()
    tilts = np.stack(
        [Transform.from_rpy(0.0, pitch(t), 0.0).rotation_matrix for t in beam_times(STAMP)]
    )
    ranges = np.array(
        [
            tilted_room_ranges((0.0, 0.0, 0.0), tilt, np.array([a]), height=LIDAR_HEIGHT, half=3.0)[
                0
            ]
            for a, tilt in zip(angles, tilts, strict=True)
        ]
    )
    scan = sweep_scan(STAMP, ranges)
    laser = Transform.from_rpy(0.0, 0.0, 0.0, (0.0, 0.0, LIDAR_HEIGHT))
    walls = square_room_ranges((0.0, 0.0), 0.0, angles, half=3.0)
    # A kept reading lands in the slot of its horizontal bearing: half a slot off at most,
    # worth 3 sin(a) / cos(a)^2 m a radian on a wall 3 m off, 4.2 m a radian at a corner.
    slack = 3.0 * math.sin(math.pi / 4) / math.cos(math.pi / 4) ** 2 * scan.angle_increment / 2
    level = levelled(scan, tilts, laser)
    kept = np.isfinite(level.ranges)
    assert kept.sum() > READINGS / 2
    np.testing.assert_allclose(level.ranges[kept], walls[kept], atol=slack)
    # Levelled with the stamp's tilt alone, the floor the beams ahead met 3 degrees further
    # pitched stands 15 cm up: kept, as a wall short of the real ones.
    at_stamp = levelled(scan, tilts[0], laser)
    short = np.isfinite(at_stamp.ranges) & (at_stamp.ranges < walls - 0.1)
    assert short.sum() >= 20
