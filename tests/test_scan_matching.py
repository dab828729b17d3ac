"""Scan matching on hand-worked rooms: the true relative pose of two scans, odometry's guess off.

The LiDAR (1080 readings, a full circle) stands in a square room whose walls are x, y = +-3 m,
off its centre. The reference scan is taken at `START`, the current one at `END` (a turn of
0.5 rad and a 12 cm shift); odometry over-counts the turn by 3 % (0.015 rad: 4.5 cm at 3 m).

Tolerances. With range noise sigma on both scans, a point-to-line residual has sigma about
sigma * sqrt(1 + 1/n) (the reference line averages n ~ 20 readings); yaw is fixed by the
N ~ 1000 pairs at lever arms r ~ 2.5 m: sigma_yaw ~ sigma / (sqrt(N) r) = 1.3e-4 rad at
sigma 1 cm, and translation by ~N/2 pairs per axis: sigma_t ~ sigma / sqrt(N / 2) = 0.45 mm.
The tests allow about 6 sigma (1e-3 rad, 3 mm): still 15 times smaller than the 3 % error.
Without noise only the float32 ranges and the lines fitted across corners remain (2e-4 rad,
1 mm).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from scanfuse.errors import InputError
from scanfuse.motion import PlanarPose
from scanfuse.scan import Scan
from scanfuse.scan_matching import (
    DriftCorrection,
    MatchSettings,
    Refusal,
    RelativePose,
    levelled,
    match,
    reference,
)
from scanfuse.transforms import Transform
from tests.support.render import square_room_ranges, tilted_room_ranges

READINGS = 1080
INCREMENT = 2 * math.pi / READINGS
ANGLES = -math.pi + INCREMENT * np.arange(READINGS)
HALF = 3.0
START = PlanarPose(0.4, -0.3, 0.1)  # the LiDAR in the room's frame
END = PlanarPose(0.5, -0.23, 0.6)
OVER_COUNT = 1.03


def lidar_scan(ranges: np.ndarray, stamp_ns: int = 0) -> Scan:
    return Scan(
        angle_min=-math.pi,
        angle_max=-math.pi + INCREMENT * (READINGS - 1),
        angle_increment=INCREMENT,
        range_min=0.1,
        range_max=12.0,
        ranges=np.asarray(ranges, dtype=np.float32),
        frame_id='laser',
        stamp_ns=stamp_ns,
    )


def room(pose: PlanarPose, noise: float = 0.0, seed: int = 0) -> Scan:
    ranges = square_room_ranges((pose.x, pose.y), pose.yaw, ANGLES, half=HALF)
    ranges = ranges + np.random.default_rng(seed).normal(0.0, noise, READINGS)
    return lidar_scan(ranges)


def relative(earlier: PlanarPose, later: PlanarPose) -> RelativePose:
    """Points of the later scan in the earlier scan's frame: the later pose seen from the
    earlier one (rotation and translation of the sensor)."""
    move = earlier.between(later)
    return RelativePose(move.yaw, move.x, move.y)


def over_counted(true: RelativePose) -> RelativePose:
    return RelativePose(true.yaw * OVER_COUNT, true.tx, true.ty)


def test_relative_pose_helper_matches_the_geometry():
    # Worked by hand: the shift (0.1, 0.07) in the room, rotated by -0.1 rad into the
    # reference frame, and the turn 0.5 rad.
    true = relative(START, END)
    c, s = math.cos(0.1), math.sin(0.1)
    assert true.yaw == pytest.approx(0.5)
    assert true.tx == pytest.approx(c * 0.1 + s * 0.07)
    assert true.ty == pytest.approx(-s * 0.1 + c * 0.07)


@pytest.mark.parametrize(
    ('noise', 'yaw_tolerance', 'shift_tolerance'), [(0.0, 2e-4, 0.001), (0.01, 1e-3, 0.003)]
)
def test_a_turn_and_shift_in_a_room_is_recovered_from_an_over_counted_turn(
    noise, yaw_tolerance, shift_tolerance
):
    true = relative(START, END)
    result = match(reference(room(START, noise, 1)), room(END, noise, 2), over_counted(true))
    assert result.accepted
    assert result.fixed == 3
    assert abs(over_counted(true).yaw - true.yaw) == pytest.approx(0.015)  # what is at stake
    assert result.pose.yaw == pytest.approx(true.yaw, abs=yaw_tolerance)
    assert result.pose.tx == pytest.approx(true.tx, abs=shift_tolerance)
    assert result.pose.ty == pytest.approx(true.ty, abs=shift_tolerance)
    assert result.rms < 2 * noise + 0.005


def test_a_person_near_the_lidar_does_not_drag_the_match():
    true = relative(START, END)
    current = room(END, 0.01, 2)
    ranges = current.ranges.copy()
    ranges[100:160] = 0.6  # 20 degrees of a person's legs 60 cm away, not in the reference
    result = match(reference(room(START, 0.01, 1)), current.with_ranges(ranges), over_counted(true))
    assert result.accepted
    assert result.pose.yaw == pytest.approx(true.yaw, abs=1e-3)
    assert result.pose.tx == pytest.approx(true.tx, abs=0.003)
    assert result.pose.ty == pytest.approx(true.ty, abs=0.003)


def test_nan_and_inf_readings_are_left_out():
    true = relative(START, END)
    current = room(END)
    ranges = current.ranges.copy()
    ranges[::3] = np.nan
    ranges[1::7] = np.inf
    result = match(reference(room(START)), current.with_ranges(ranges), over_counted(true))
    assert result.accepted
    assert result.pose.yaw == pytest.approx(true.yaw, abs=2e-4)


def test_no_readings_at_all_are_refused_with_the_prediction_kept():
    prediction = RelativePose(0.2, 0.01, 0.0)
    empty = lidar_scan(np.full(READINGS, np.nan))
    result = match(reference(empty), empty, prediction)
    assert result.refused is Refusal.TOO_FEW_PAIRS
    assert result.pose == prediction
    assert result.fixed == 0


def one_wall(pose: PlanarPose) -> Scan:
    """The wall y = 1 (room frame) alone, seen from `pose` up to range_max."""
    bearing = pose.yaw + ANGLES
    with np.errstate(divide='ignore'):
        ranges = (1.0 - pose.y) / np.sin(bearing)
    ranges[(ranges <= 0) | (ranges > 12.0)] = np.inf
    return lidar_scan(ranges)


def test_a_single_wall_corrects_the_turn_and_the_distance_to_it_but_not_the_shift_along_it():
    earlier, later = PlanarPose(0.0, 0.0, 0.0), PlanarPose(0.3, 0.05, 0.2)
    true = relative(earlier, later)  # reference yaw 0: tx runs along the wall, ty across it
    prediction = RelativePose(true.yaw * OVER_COUNT, true.tx + 0.04, true.ty + 0.01)
    result = match(reference(one_wall(earlier)), one_wall(later), prediction)
    assert result.accepted
    assert result.fixed == 2
    assert result.pose.yaw == pytest.approx(true.yaw, abs=2e-4)
    assert result.pose.ty == pytest.approx(true.ty, abs=0.001)
    # Along the wall nothing is observable: odometry's value stays (4 cm off the truth).
    assert result.pose.tx == pytest.approx(prediction.tx, abs=0.001)


def test_a_round_room_around_the_lidar_does_not_fix_the_turn():
    circle = lidar_scan(np.full(READINGS, 2.0))  # every reading 2 m: any turn fits
    prediction = RelativePose(0.3, 0.0, 0.0)
    result = match(reference(circle), circle, prediction)
    assert result.refused is Refusal.YAW_UNOBSERVABLE
    assert result.pose == prediction


def test_a_correction_beyond_odometry_s_plausible_error_is_refused():
    # Odometry says the LiDAR stood still; the scans show a turn of 0.05 rad: more than
    # 20 % of no turn plus a floor of 0.02 rad.
    turned = PlanarPose(START.x, START.y, START.yaw + 0.05)
    prediction = RelativePose(0.0, 0.0, 0.0)
    strict = MatchSettings(turn_floor=0.02)
    result = match(reference(room(START)), room(turned), prediction, strict)
    assert result.refused is Refusal.IMPLAUSIBLE
    assert result.pose == prediction
    found = match(reference(room(START)), room(turned), prediction)  # the default 0.1 rad
    assert found.accepted
    assert found.pose.yaw == pytest.approx(0.05, abs=2e-4)


def test_a_shift_beyond_odometry_s_plausible_error_is_refused():
    # The LiDAR moved 8 cm along its own x axis while odometry saw no move: more than a
    # floor of 5 cm.
    c, s = math.cos(START.yaw), math.sin(START.yaw)
    shifted = PlanarPose(START.x + 0.08 * c, START.y + 0.08 * s, START.yaw)
    prediction = RelativePose(0.0, 0.0, 0.0)
    result = match(
        reference(room(START)), room(shifted), prediction, MatchSettings(shift_floor=0.05)
    )
    assert result.refused is Refusal.IMPLAUSIBLE
    found = match(reference(room(START)), room(shifted), prediction)  # the default 0.1 m
    assert found.accepted
    assert found.pose.tx == pytest.approx(0.08, abs=0.001)
    assert found.pose.ty == pytest.approx(0.0, abs=0.001)


def test_scans_that_disagree_more_than_max_rms_are_refused():
    true = relative(START, END)
    settings = MatchSettings(max_rms=0.005)  # below the 1 cm noise of each scan
    result = match(
        reference(room(START, 0.01, 1)), room(END, 0.01, 2), over_counted(true), settings
    )
    assert result.refused is Refusal.RESIDUAL
    assert result.rms > 0.005
    assert result.pose == over_counted(true)


@pytest.mark.parametrize(
    ('changes', 'message'),
    [
        ({'iterations': 0}, 'at least 1 iteration'),
        ({'min_pairs': 2}, 'min_pairs must be >= 3'),
        ({'gate': math.nan}, 'gate must be a positive finite number'),
        ({'huber': 0.0}, 'huber must be a positive finite number'),
        ({'min_share': 1.5}, 'min_share must be a share'),
        ({'gate': 0.1, 'gate_floor': 0.2}, 'gate_floor 0.2 m exceeds gate 0.1 m'),
    ],
)
def test_bad_match_settings_are_errors(changes, message):
    with pytest.raises(InputError, match=message):
        MatchSettings(**changes)


def test_a_non_finite_prediction_is_an_error():
    scan = room(START)
    with pytest.raises(InputError, match='finite predicted pose'):
        match(reference(scan), scan, RelativePose(math.nan, 0.0, 0.0))


def test_a_non_finite_odometry_pose_is_an_error():
    with pytest.raises(InputError, match='finite odometry pose'):
        DriftCorrection().update(room(START), PlanarPose(0.0, math.inf, 0.0), Transform())


# ------------------------------------------------------------ drift correction


def base_in_room(base: PlanarPose) -> PlanarPose:
    """The LiDAR (at the base's origin) in the room: the base's odom frame is START's."""
    return START.compose(base)


def test_a_half_turn_with_over_counting_odometry_is_corrected_to_the_true_heading():
    drift = DriftCorrection()
    mount = Transform()
    steps = 20  # a scan every 0.157 rad of the true turn
    for k in range(steps + 1):
        true = PlanarPose(0.0, 0.0, math.pi * k / steps)
        odometry = PlanarPose(0.0, 0.0, true.yaw * OVER_COUNT)
        drift.update(room(base_in_room(true)), odometry, mount)
    corrected = drift.corrected(odometry)
    assert abs(math.remainder(odometry.yaw - math.pi, 2 * math.pi)) == pytest.approx(0.03 * math.pi)
    # 20 matches, each within the noise-free 2e-4 rad: the heading within 2e-3 rad.
    assert math.remainder(corrected.yaw - math.pi, 2 * math.pi) == pytest.approx(0.0, abs=2e-3)
    assert math.hypot(corrected.x, corrected.y) < 0.005
    assert drift.matched == steps
    assert not drift.refused


def test_exact_odometry_leaves_the_correction_at_the_identity():
    drift = DriftCorrection()
    for k in range(30):  # standing, then turning a little, each scan with fresh noise
        pose = PlanarPose(0.0, 0.0, 0.01 * max(0, k - 10))
        drift.update(room(base_in_room(pose), 0.01, k), pose, Transform())
    c = drift.correction
    assert abs(c.yaw) < 1e-3
    assert math.hypot(c.x, c.y) < 0.003
    drift.reset()
    assert drift.correction == PlanarPose(0.0, 0.0, 0.0)


def test_a_refused_match_keeps_the_correction_and_starts_a_new_reference():
    drift = DriftCorrection()
    drift.update(room(START), PlanarPose(0.0, 0.0, 0.0), Transform())
    empty = lidar_scan(np.full(READINGS, np.nan))
    result = drift.update(empty, PlanarPose(0.0, 0.0, 0.0), Transform())
    assert result is not None
    assert result.refused is Refusal.TOO_FEW_PAIRS
    assert drift.refused == {Refusal.TOO_FEW_PAIRS: 1}
    assert drift.correction == PlanarPose(0.0, 0.0, 0.0)


def test_a_tilted_scan_is_refused_and_the_next_level_scan_matches_the_one_before_it():
    drift = DriftCorrection()
    mount = Transform()
    drift.update(room(START), PlanarPose(0.0, 0.0, 0.0), mount)
    # Odometry over-counts a turn of 0.2 rad while a 1:8 ramp pitches the plane 7.1 degrees.
    true, odometry = PlanarPose(0.0, 0.0, 0.2), PlanarPose(0.0, 0.0, 0.2 * OVER_COUNT)
    tilted = drift.update(room(base_in_room(true)), odometry, mount, tilt=math.atan(1 / 8))
    assert tilted is not None
    assert tilted.refused is Refusal.TILTED
    assert drift.correction == PlanarPose(0.0, 0.0, 0.0)  # odometry alone meanwhile
    assert drift.refused == {Refusal.TILTED: 1}
    # (No IMU's roll and pitch to level it by.) Level again (up to `max_tilt`): the first
    # scan is matched against the last level one, before the tilt (the anchor), and the
    # correction takes out the whole over-count; the next matches it.
    level = drift.settings.max_tilt
    anchored = drift.update(room(base_in_room(true)), odometry, mount, tilt=level)
    assert anchored is not None
    assert anchored.accepted
    assert drift.anchored == 1
    assert drift.corrected(odometry).yaw == pytest.approx(0.2, abs=2e-3)
    true, odometry = PlanarPose(0.0, 0.0, 0.4), PlanarPose(0.0, 0.0, 0.4 * OVER_COUNT)
    matched = drift.update(room(base_in_room(true)), odometry, mount, tilt=level)
    assert matched is not None
    assert matched.accepted
    assert drift.anchored == 1  # matched against the reference the anchor became
    assert drift.corrected(odometry).yaw == pytest.approx(0.4, abs=2e-3)


def test_an_upside_down_lidar_s_matches_are_turned_back_into_the_base_s_turn():
    # Mounted rolled by pi: the LiDAR's angle a looks along the base's bearing -a, so the
    # scan of a base heading `yaw` holds the room's range at world bearing yaw - a.
    mount = Transform.from_rpy(math.pi, 0.0, 0.0, (0.0, 0.0, 0.3))
    drift = DriftCorrection()
    steps = 10
    for k in range(steps + 1):
        true = PlanarPose(0.0, 0.0, 0.5 * math.pi * k / steps)
        in_room = base_in_room(true)
        ranges = square_room_ranges((in_room.x, in_room.y), in_room.yaw, -ANGLES, half=HALF)
        odometry = PlanarPose(0.0, 0.0, true.yaw * OVER_COUNT)
        drift.update(lidar_scan(ranges), odometry, mount)
    corrected = drift.corrected(odometry)
    assert odometry.yaw - true.yaw == pytest.approx(0.015 * math.pi)
    assert corrected.yaw == pytest.approx(true.yaw, abs=1e-3)
    assert math.hypot(corrected.x, corrected.y) < 0.003


def test_scans_with_no_overlap_are_refused_as_too_few_pairs():
    # The reference sees only the half of the room ahead, the current scan only the half
    # behind: every reading is valid, none falls on a reference line.
    ahead = room(START).ranges.copy()
    behind = ahead.copy()
    ahead[np.abs(ANGLES) > math.pi / 2] = np.nan
    behind[np.abs(ANGLES) < math.pi / 2 + 0.1] = np.nan
    prediction = RelativePose(0.0, 0.0, 0.0)
    result = match(reference(lidar_scan(ahead)), lidar_scan(behind), prediction)
    assert result.refused is Refusal.TOO_FEW_PAIRS
    assert result.pose == prediction


def bent(first: PlanarPose, second: PlanarPose, noise: float, seed: int) -> Scan:
    """A scan whose first half was swept from `first`, the rest from `second`: what the
    de-skew leaves of a sweep during which the wheels slipped (odometry turned, the robot
    did not)."""
    ranges = room(first, noise, seed).ranges.copy()
    ranges[READINGS // 2 :] = room(second, noise, seed).ranges[READINGS // 2 :]
    return lidar_scan(ranges)


STANDING = PlanarPose(0.0, 0.0, 0.0)


def settled() -> DriftCorrection:
    """A drift correction after 12 scans of a standing robot with 5 mm noise: 12 residuals
    in its window of 16."""
    drift = DriftCorrection()
    for k in range(12):
        drift.update(room(base_in_room(STANDING), 0.005, k), STANDING, Transform())
    return drift


def test_a_scan_bent_by_a_slip_is_refused_and_the_next_straight_one_recovers_the_slip():
    drift = settled()
    mount, standing = Transform(), STANDING
    # During the next sweep the wheels turn 0.08 rad in place and the robot does not: the
    # de-skew turns the sweep's second half by that much.
    slipped = base_in_room(PlanarPose(0.0, 0.0, -0.08))
    before = drift.correction
    result = drift.update(bent(base_in_room(standing), slipped, 0.005, 12), standing, mount)
    assert result is not None
    assert result.refused is Refusal.DISTORTED
    assert drift.correction == before  # kept
    # The next sweep is straight; odometry now says 0.08 rad, matched against the kept
    # reference the turn is taken back.
    odometry = PlanarPose(0.0, 0.0, 0.08)
    result = drift.update(room(base_in_room(standing), 0.005, 13), odometry, mount)
    assert result is not None
    assert result.accepted
    assert drift.corrected(odometry).yaw == pytest.approx(0.0, abs=2e-3)


def test_a_scene_whose_matches_all_get_worse_is_refused_only_until_the_median_follows():
    drift = settled()
    mount, standing = Transform(), STANDING
    verdicts = []
    for k in range(12, 28):  # from now on three times the noise (clutter, a worse sensor)
        result = drift.update(room(base_in_room(standing), 0.015, k), standing, mount)
        assert result is not None
        verdicts.append(result.refused)
    # The window of 16 holds 12 quiet residuals: the median turns once 9 noisy ones are in.
    assert verdicts[0] is Refusal.DISTORTED
    assert verdicts[9:] == [None] * 7


# ------------------------------------------------------------ a tilted plane, levelled

LIDAR_HEIGHT = 0.3
RAMP_PITCH = math.atan(1 / 8)  # a 1:8 ramp: 7.1 degrees


def pitched(angle: float) -> np.ndarray:
    """The base's axes in a level frame of its heading, pitched by `angle` (REP-103: a
    positive pitch turns the nose down)."""
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def tilted_room(base: PlanarPose, tilt: np.ndarray, noise: float = 0.0, seed: int = 0) -> Scan:
    """The LiDAR 0.3 m up on a base at `base` (room frame) tilted by `tilt`."""
    ranges = tilted_room_ranges(
        (base.x, base.y, base.yaw), tilt, ANGLES, height=LIDAR_HEIGHT, half=HALF
    )
    return lidar_scan(ranges + np.random.default_rng(seed).normal(0.0, noise, READINGS))


def test_a_pitched_plane_levelled_gives_the_level_scan_without_the_floor():
    tilt = pitched(-RAMP_PITCH)  # nose up, as climbing the ramp
    mount = Transform.from_rpy(0.0, 0.0, 0.0, (0.0, 0.0, LIDAR_HEIGHT))
    scan = tilted_room(START, tilt)
    floor_hits = int(np.count_nonzero(np.abs(scan.ranges - room(START).ranges) > 0.05))
    assert floor_hits > 50  # behind the base, the plane meets the floor 2.4 m off
    level = levelled(scan, tilt, mount)
    # Each reading's point where it lies in the room, seen from the LiDAR's mounted place
    # over the base's origin (the tilted LiDAR stands 3.7 cm behind it: 0.3 m x sin 7.1 deg).
    expected = room(START).ranges
    finite = np.isfinite(level.ranges)
    assert np.count_nonzero(finite) > 0.8 * (READINGS - floor_hits)
    # On its wall, within a slot's bearing (0.17 degrees); no floor left.
    assert np.max(np.abs(level.ranges[finite] - expected[finite])) < 0.02


@pytest.mark.parametrize(
    ('first', 'turn'), [(0.75 * math.pi, -1.0), (0.0, 1.0)], ids=['clockwise', 'from-0-to-270']
)
def test_a_270_degree_scan_levelled_keeps_its_own_slots(first, turn):
    # 810 readings (270 degrees): sweeping clockwise from +135 degrees (an increment below
    # 0, as a LiDAR mounted upside down), or anticlockwise from 0 to 270 degrees, past the
    # +-180 where a bearing's sign flips.
    tilt = pitched(RAMP_PITCH)  # nose down, as going down the ramp: the floor ahead
    mount = Transform.from_rpy(0.0, 0.0, 0.0, (0.0, 0.0, LIDAR_HEIGHT))
    angles = first + turn * INCREMENT * np.arange(810)
    ranges = tilted_room_ranges(
        (START.x, START.y, START.yaw), tilt, angles, height=LIDAR_HEIGHT, half=HALF
    )
    scan = Scan(
        angle_min=float(angles[0]),
        angle_max=float(angles[-1]),
        angle_increment=turn * INCREMENT,
        range_min=0.1,
        range_max=12.0,
        ranges=ranges.astype(np.float32),
        frame_id='laser',
    )
    level = levelled(scan, tilt, mount)
    expected = square_room_ranges((START.x, START.y), START.yaw, angles, half=HALF)
    finite = np.isfinite(level.ranges)
    # Pitched nose down, every beam pointing backwards rises: it meets a wall, and its
    # reading lands in a slot of the scan's own.
    backwards = np.cos(angles) < 0.0
    assert np.count_nonzero(finite & backwards) > 0.9 * np.count_nonzero(backwards)
    assert np.max(np.abs(level.ranges[finite] - expected[finite])) < 0.02


def test_on_a_ramp_the_imus_tilt_lets_each_scan_be_matched_levelled():
    drift = DriftCorrection()
    mount = Transform.from_rpy(0.0, 0.0, 0.0, (0.0, 0.0, LIDAR_HEIGHT))
    tilt = pitched(-RAMP_PITCH)
    drift.update(room(START), PlanarPose(0.0, 0.0, 0.0), mount)
    # Turning on the ramp, odometry over-counting: every scan matched, the turn's true.
    for k in range(1, 5):
        true = PlanarPose(0.0, 0.0, 0.1 * k)
        odometry = PlanarPose(0.0, 0.0, true.yaw * OVER_COUNT)
        scan = tilted_room(base_in_room(true), tilt, noise=0.005, seed=k)
        result = drift.update(scan, odometry, mount, tilt=RAMP_PITCH, base_tilt=tilt)
        assert result is not None
        assert result.accepted, result.refused
    assert drift.corrected(odometry).yaw == pytest.approx(0.4, abs=2e-3)
    assert not drift.refused
    # Steeper than `max_levelled_tilt`: not matched, even with the tilt known.
    steep = pitched(-math.radians(15.0))
    refused = drift.update(
        tilted_room(base_in_room(true), steep),
        odometry,
        mount,
        tilt=math.radians(15.0),
        base_tilt=steep,
    )
    assert refused is not None
    assert refused.refused is Refusal.TILTED


def ramp_corridor(base: PlanarPose, tilt: np.ndarray) -> Scan:
    """`tilted_room` without the walls across the way (x = +-HALF in the room): up a ramp
    between walls, what a levelled scan keeps fixes the turn and the shift across the
    corridor, not the distance along it."""
    scan = tilted_room(base, tilt)
    along = base.x + scan.ranges * np.cos(base.yaw + ANGLES)
    return lidar_scan(np.where(np.abs(along) > HALF - 0.1, np.inf, scan.ranges))


def test_a_level_scan_after_a_ramp_takes_out_the_distance_the_wheels_slipped_on_it():
    drift = DriftCorrection()
    mount = Transform.from_rpy(0.0, 0.0, 0.0, (0.0, 0.0, LIDAR_HEIGHT))
    tilt = pitched(-RAMP_PITCH)
    slip = 1.1  # climbing, the wheels count 10 % more than the base moves
    drift.update(room(START), PlanarPose(0.0, 0.0, 0.0), mount)  # level, at the ramp's foot
    for k in range(1, 6):  # up the ramp, 0.2 m a scan
        true, odometry = PlanarPose(0.2 * k, 0.0, 0.0), PlanarPose(0.2 * k * slip, 0.0, 0.0)
        scan = ramp_corridor(base_in_room(true), tilt)
        result = drift.update(scan, odometry, mount, tilt=RAMP_PITCH, base_tilt=tilt)
        assert result is not None
        assert result.accepted, result.refused
        assert result.fixed == 2
    # Along the corridor the slip stays: 0.1 m of odometry's, less the part of it across
    # the walls (the base heads 0.1 rad off them).
    corrected = drift.corrected(odometry)
    assert math.hypot(corrected.x - true.x, corrected.y - true.y) > 0.09
    # Level again (the ramp's top): matched against the scan at its foot, level to level,
    # the walls across the way fix the distance again.
    true, odometry = PlanarPose(1.2, 0.0, 0.0), PlanarPose(1.2 * slip, 0.0, 0.0)
    result = drift.update(room(base_in_room(true)), odometry, mount)
    assert result is not None
    assert result.accepted
    assert result.fixed == 3
    assert drift.anchored == 1
    corrected = drift.corrected(odometry)
    assert math.hypot(corrected.x - true.x, corrected.y - true.y) < 0.005
    assert corrected.yaw == pytest.approx(0.0, abs=1e-3)


def test_level_scans_that_do_not_match_the_anchor_go_on_against_the_current_reference():
    drift = DriftCorrection()
    mount = Transform.from_rpy(0.0, 0.0, 0.0, (0.0, 0.0, LIDAR_HEIGHT))
    drift.update(room(START), PlanarPose(0.0, 0.0, 0.0), mount)  # the anchor: the room
    start = PlanarPose(0.0, 0.0, 0.0)
    # Tilted, then level, in front of one wall alone (the room's other walls out of
    # reach): the anchor's walls are not there to fix all three directions.
    drift.update(one_wall(start), start, mount, tilt=RAMP_PITCH, base_tilt=np.eye(3))
    for k in range(1, 8):
        pose = PlanarPose(0.05 * k, 0.0, 0.0)
        result = drift.update(one_wall(pose), pose, mount)
        assert result is not None
        assert result.accepted, result.refused
        assert result.fixed == 2
    assert drift.anchored == 0
