"""Where the depth camera really sits: its mounting estimated from the floor and the LiDAR.

`calibrate` takes depth frames, each paired with a LiDAR scan taken at about the same time,
the LiDAR's mounting (trusted) and the camera's given mounting (a starting point, perhaps
wrong), and estimates the camera body's pose in the base frame:

1. **Height, pitch, roll from the floor.** In every frame `fit_ground` (the ground estimate
   of the obstacle scan: RANSAC over pixels that look down, the lowest large surface wins,
   least squares on its inliers) finds the floor, first with wide bounds around the given
   mounting (`max_tilt`, `max_offset`), then again with tight bounds around the median of
   the first pass. The median over frames of the floor's normal and offset, refined by
   weighted least squares over the floor's pixels of a few frames, gives roll, pitch and
   height (the camera's height above the floor); yaw and x, y leave the floor's plane
   unchanged, so it cannot give them.
2. **Yaw, x, y against the LiDAR.** The camera's points are placed in a level frame (the
   camera body turned by the floor's roll and pitch, at the floor's height); those within
   `band` of the LiDAR's height, on surfaces that cross its plane, lie where the LiDAR's
   plane cuts walls and tall obstacles. A 2D point-to-line ICP (the lines: the LiDAR's
   scan, fitted reading by reading; each camera point paired with the reading on its
   bearing and weighed by the depth noise at its distance) finds the rotation about z
   (yaw) and the shift (x, y) that lay them on that scan, from a few starting yaws around
   the given one; only x, y, yaw are free. The walls must fix all three: if the camera
   sees one straight wall only, the match could slide along it (a round wall about the
   camera: turn), and `calibrate` says so instead of returning a guess.

The depth's noise (`depth_noise` Z^2, 4 cm at 2 m for a RealSense D435) is weighed at the
depth a point would have on the floor or on the LiDAR's line, never at its measured depth:
a reading pushed nearer by noise would weigh more than one pushed farther, and pull the
floor's tilt and the walls' distance towards the camera.

Arrays and frozen dataclasses in, a frozen `Calibration` out; no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from scanfuse.camera import depth_in_metres
from scanfuse.convert.ground import GroundPlane, GroundSample, GroundSettings, fit_ground
from scanfuse.errors import CalibrationError, InputError
from scanfuse.transforms import BODY_TO_OPTICAL, Transform

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy.typing as npt

    from scanfuse.camera import CameraModel
    from scanfuse.scan import Scan

    F64 = npt.NDArray[np.float64]

# How far `_Matcher.check_profile` moves the estimate along its weakest direction (metres;
# radians of yaw count as metres 1 m away), and how much worse the fit must get there.
PROFILE_STEP = 0.08
PROFILE_RISE = 100.0  # the truncated chi-square summed over the probe's points
# Degrees the LiDAR's plane may tilt (upside down is level too).
LEVEL_TOLERANCE = 2.0
# Rotation by +90 deg in the plane: d(R(yaw) p)/d(yaw) = J R(yaw) p.
_J = np.array([[0.0, -1.0], [1.0, 0.0]])


@dataclass(frozen=True)
class Mounting:
    """The camera body's pose in the base frame (REP-103): metres and radians, as the
    `camera_*` parameters and `Extrinsics.from_mounting` take them (R = Rz(yaw) Ry(pitch)
    Rx(roll); positive pitch looks down, positive yaw looks left)."""

    x: float
    y: float
    height: float
    roll: float
    pitch: float
    yaw: float

    @classmethod
    def of_optical(cls, base_to_camera_optical: Transform) -> Mounting:
        """The body pose whose optical frame is `base_to_camera_optical`."""
        body = base_to_camera_optical @ BODY_TO_OPTICAL.inverse()
        roll, pitch, yaw = body.rpy()
        x, y, z = body.translation
        return cls(x, y, z, roll, pitch, yaw)

    @property
    def body(self) -> Transform:
        """base -> camera body."""
        return Transform.from_rpy(self.roll, self.pitch, self.yaw, (self.x, self.y, self.height))

    @property
    def optical(self) -> Transform:
        """base -> camera optical frame."""
        return self.body @ BODY_TO_OPTICAL

    def parameters(self) -> dict[str, float]:
        """The `camera_*` parameters of this mounting."""
        return {
            'camera_x': self.x,
            'camera_y': self.y,
            'camera_height': self.height,
            'camera_roll': self.roll,
            'camera_pitch': self.pitch,
            'camera_yaw': self.yaw,
        }

    def parameters_yaml(self) -> str:
        """A parameter file snippet (`scanfuse: ros__parameters:`), radians and metres."""
        lines = ['scanfuse:', '  ros__parameters:']
        lines += [f'    {name}: {value:.4f}' for name, value in self.parameters().items()]
        return '\n'.join(lines) + '\n'

    def static_transform_command(self, parent: str, child: str) -> str:
        """The `static_transform_publisher` line that publishes this body pose (parent ->
        child, child the camera's body frame: x forward, y left, z up)."""
        return static_transform_command(self.body, parent, child)


def static_transform_command(pose: Transform, parent: str, child: str) -> str:
    """`ros2 run tf2_ros static_transform_publisher` with the pose of `child` in `parent`
    (its --roll --pitch --yaw are tf2's setRPY: R = Rz(yaw) Ry(pitch) Rx(roll))."""
    x, y, z = pose.translation
    roll, pitch, yaw = pose.rpy()
    return (
        'ros2 run tf2_ros static_transform_publisher '
        f'--x {x:.4f} --y {y:.4f} --z {z:.4f} '
        f'--roll {roll:.5f} --pitch {pitch:.5f} --yaw {yaw:.5f} '
        f'--frame-id {parent} --child-frame-id {child}'
    )


def body_to_optical_command(body: str, optical: str) -> str:
    """The fixed turn from a camera body frame to its optical frame (setRPY(-pi/2, 0, -pi/2))."""
    return (
        'ros2 run tf2_ros static_transform_publisher --roll -1.5707963 --yaw -1.5707963 '
        f'--frame-id {body} --child-frame-id {optical}'
    )


@dataclass(frozen=True)
class CalibrationFrame:
    """One depth image and the LiDAR scan taken with it (in the LiDAR's frame)."""

    depth: npt.NDArray[np.generic]
    scan: Scan


@dataclass(frozen=True)
class CalibrationSettings:
    """How `calibrate` finds the floor and matches the camera to the LiDAR."""

    max_tilt: float = math.radians(15.0)  # first floor pass: radians from the given mounting
    max_offset: float = 0.25  # first floor pass: metres of height from the given mounting
    refine_tilt: float = math.radians(2.0)  # second pass: radians from the first's median
    refine_offset: float = 0.03  # second pass: metres from the first's median
    reach: float = 3.0  # metres: floor farther from the camera is not used
    depth_noise: float = 0.01  # sigma of depth = depth_noise * Z^2 (1/m): the weights
    lidar_noise: float = 0.01  # metres: sigma of the LiDAR's ranges (and its lines)
    floor_window: float = 0.03  # metres either side of the floor: the refinement's points
    min_floor_frames: int = 3  # frames that must show floor
    band: float = 0.05  # metres above and below the LiDAR's plane: camera points matched
    match_reach: float = 4.0  # metres of depth: farther camera points are too noisy to match
    crossing: float = 0.04  # metres below and above the plane a surface must reach, and
    cell: float = 0.04  # metres: the top-view cells in which it must reach them
    max_yaw_error: float = math.radians(12.0)  # starts of the match: given yaw +- this
    start_distance: float = 0.5  # metres: pairs farther apart are not matched at first
    inlier_distance: float = 0.03  # metres (or 3 sigma): pairs within it match in the end
    match_frames: int = 10  # frames (spread over the recording) the scan match uses
    min_matched: int = 60  # matched camera points needed
    min_constraint: float = 0.015  # least share of the match's information in one direction
    still_shift: float = 0.005  # metres the base may move between a frame and its scan, and
    still_turn: float = math.radians(0.1)  # radians it may turn (by odometry, if recorded)

    def __post_init__(self) -> None:
        checks = (
            ('max_tilt', 0.0 < self.max_tilt < math.pi / 4),
            ('max_offset', 0.0 < self.max_offset <= 1.0),
            ('refine_tilt', 0.0 < self.refine_tilt < math.pi / 4),
            ('refine_offset', 0.0 < self.refine_offset <= 1.0),
            ('reach', self.reach > 0.0),
            ('depth_noise', self.depth_noise >= 0.0),
            ('lidar_noise', self.lidar_noise > 0.0),
            ('floor_window', self.floor_window > 0.0),
            ('min_floor_frames', self.min_floor_frames >= 1),
            ('band', self.band > 0.0),
            ('match_reach', self.match_reach > 0.0),
            ('crossing', self.crossing >= 0.0),
            ('cell', self.cell > 0.0),
            ('max_yaw_error', 0.0 <= self.max_yaw_error <= math.pi),
            ('start_distance', self.start_distance > 0.0),
            ('inlier_distance', 0.0 < self.inlier_distance <= self.start_distance),
            ('match_frames', self.match_frames >= 1),
            ('min_matched', self.min_matched >= 3),
            ('min_constraint', 0.0 <= self.min_constraint < 1.0),
            ('still_shift', self.still_shift >= 0.0),
            ('still_turn', self.still_turn >= 0.0),
        )
        for name, valid in checks:
            value = getattr(self, name)
            if not (valid and math.isfinite(value)):
                msg = f'calibration setting {name} = {value} is out of its range'
                raise InputError(msg)


@dataclass(frozen=True)
class Calibration:
    """The estimated mounting, the given one, and how well the data agree with each.

    The points are top views in the base frame, metres: the LiDAR's (of the frames the scan
    match used) and the camera's within the LiDAR's band, placed with the given mounting
    (`camera_given`) and with the estimate (`camera_points`).
    """

    mounting: Mounting
    given: Mounting
    frames: int  # depth frames handed in
    floor_frames: int  # frames that showed floor
    floor_rms: float  # metres: floor points from the estimated floor (within 3 cm of it)
    match_frames: int  # frames the scan match used
    matched_points: int  # camera points within `inlier_distance` of the LiDAR's lines
    match_rms: float  # metres: point-to-line distance of the matched points, estimate
    match_rms_given: float  # the same with the given mounting (NaN: nothing matched)
    match_sigmas: float  # the estimate's residual RMS in sigmas of the sensors' noise (~1)
    match_sigmas_given: float  # the same with the given mounting
    matched_given: int  # camera points on the LiDAR's lines with the given mounting
    camera_count: int  # camera points in the LiDAR's band (the scan match's frames)
    lidar_points: F64
    camera_points: F64
    camera_given: F64
    frame_spread: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Standard deviation of x, y (metres) and yaw (radians) matched frame by frame: the
    estimate's own standard error is about this over the square root of `match_frames`."""

    @property
    def corrections(self) -> Mounting:
        """Estimate minus given, per parameter (angles wrapped to [-pi, pi])."""
        m, g = self.mounting, self.given
        return Mounting(
            m.x - g.x,
            m.y - g.y,
            m.height - g.height,
            _wrap(m.roll - g.roll),
            _wrap(m.pitch - g.pitch),
            _wrap(m.yaw - g.yaw),
        )


def _wrap(angle: float) -> float:
    return math.remainder(angle, 2.0 * math.pi)


def pair_motion(
    first_ns: npt.ArrayLike,
    second_ns: npt.ArrayLike,
    odometry_ns: npt.ArrayLike,
    poses: npt.ArrayLike,
) -> tuple[F64, F64]:
    """How far the base moved (metres) and turned (radians) between the stamps of each pair
    (a depth frame and its scan), by odometry (`poses`: x, y, yaw per stamp, in time order)
    interpolated linearly; NaN where a stamp lies outside the odometry's time span."""
    times = np.asarray(odometry_ns, dtype=np.int64)
    pose = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    first = np.asarray(first_ns, dtype=np.int64)
    second = np.asarray(second_ns, dtype=np.int64)
    if times.size < 2:
        nothing = np.full(first.shape, np.nan)
        return nothing, nothing.copy()
    base = times[0]
    span = (times - base).astype(np.float64)
    yaw = np.unwrap(pose[:, 2])

    def at(stamps: npt.NDArray[np.int64]) -> F64:
        t = (stamps - base).astype(np.float64)
        values = np.stack([np.interp(t, span, column) for column in (pose[:, 0], pose[:, 1], yaw)])
        values[:, (t < span[0]) | (t > span[-1])] = np.nan
        return values

    a, b = at(first), at(second)
    return np.hypot(b[0] - a[0], b[1] - a[1]), np.abs(b[2] - a[2])


def calibrate(
    frames: Sequence[CalibrationFrame],
    camera: CameraModel,
    base_to_laser: Transform,
    given: Mounting,
    settings: CalibrationSettings | None = None,
) -> Calibration:
    """The camera's mounting from depth frames paired with LiDAR scans (module docstring)."""
    settings = settings or CalibrationSettings()
    if not frames:
        msg = 'no depth frames paired with LiDAR scans to calibrate from; record both together'
        raise CalibrationError(msg)
    for frame in frames:
        camera.check_depth(frame.depth)
    _check_level(base_to_laser)
    chosen = _spread(len(frames), settings.match_frames)
    optical = [_optical_points(frames[i].depth, camera) for i in chosen]
    floor, floor_frames = _floor(frames, camera, optical, given, settings)
    roll, pitch = floor.camera_roll, floor.camera_pitch
    level = Transform.from_rpy(roll, pitch, 0.0, (0.0, 0.0, floor.offset)) @ BODY_TO_OPTICAL
    lidar_height = float(base_to_laser.translation[2])
    clouds = [_band_points(points, level, lidar_height, settings) for points in optical]
    scans = [_scan_lines(frames[i].scan, base_to_laser) for i in chosen]
    matcher = _Matcher(clouds, scans, settings)
    if sum(len(c) for c in clouds) < settings.min_matched:
        msg = (
            f'the camera sees only {sum(len(c) for c in clouds)} points within '
            f'{settings.band} m of the LiDAR plane (height {lidar_height:.2f} m) in '
            f'{len(chosen)} frames, fewer than {settings.min_matched}: yaw and x, y need walls '
            'or tall obstacles that both sensors see; record facing a corner of a room'
        )
        raise CalibrationError(msg)
    yaw, shift = matcher.coarse().best_start(given.yaw, (given.x, given.y))
    yaw, shift, _ = matcher.refine(yaw, shift, 4.0 * settings.inlier_distance)
    pairs = matcher.pairs(yaw, shift, settings.inlier_distance)
    weakest = matcher.check_constraints(pairs)
    matcher.check_profile(yaw, shift, weakest)
    mounting = Mounting(float(shift[0]), float(shift[1]), floor.offset, roll, pitch, yaw)
    spread = matcher.spread(yaw, shift)
    given_cloud = [
        _band_points(points, _level_of(given), lidar_height, settings) for points in optical
    ]
    given_pairs = _Matcher(given_cloud, scans, settings).pairs(
        given.yaw, np.array([given.x, given.y]), settings.inlier_distance
    )
    return Calibration(
        mounting=mounting,
        given=given,
        frames=len(frames),
        floor_frames=floor_frames,
        floor_rms=_floor_rms(optical, floor, settings),
        match_frames=len(chosen),
        matched_points=pairs.count,
        match_rms=pairs.rms,
        match_rms_given=given_pairs.rms,
        match_sigmas=pairs.normalised_rms,
        match_sigmas_given=given_pairs.normalised_rms,
        matched_given=given_pairs.count,
        camera_count=sum(len(c) for c in matcher.clouds),
        lidar_points=np.concatenate([s.readings for s in scans]),
        camera_points=_placed(clouds, yaw, shift),
        camera_given=_placed(given_cloud, given.yaw, np.array([given.x, given.y])),
        frame_spread=spread,
    )


def _check_level(base_to_laser: Transform) -> None:
    """The LiDAR's plane must be level: the band of camera points is a height band."""
    axis = base_to_laser.rotation_matrix[:, 2]  # the LiDAR's z axis in the base frame
    tilt = math.degrees(math.acos(min(1.0, abs(float(axis[2])))))
    if tilt > LEVEL_TOLERANCE:
        msg = (
            f"the LiDAR's plane is tilted {tilt:.1f} deg from level (its mounting's roll and "
            f'pitch); calibrate matches the camera at one height and needs a level LiDAR '
            f'(within {LEVEL_TOLERANCE:g} deg): check lidar_roll / lidar_pitch or the TF'
        )
        raise CalibrationError(msg)


# ------------------------------------------------------------------ floor


def _floor(
    frames: Sequence[CalibrationFrame],
    camera: CameraModel,
    optical: list[F64],
    given: Mounting,
    settings: CalibrationSettings,
) -> tuple[GroundPlane, int]:
    """The median floor of two passes: wide bounds around `given`, then tight ones."""
    prior = GroundPlane.of_mounting(given.optical)
    wide = GroundSettings(
        max_tilt=settings.max_tilt,
        max_offset=settings.max_offset,
        reach=settings.reach,
        smoothing=1.0,
        hypotheses=80,
    )
    planes, reasons = _planes(frames, camera, prior, wide)
    if len(planes) < settings.min_floor_frames:
        _too_little_floor(len(planes), len(frames), reasons, settings)
    first = _median_plane(planes)
    tight = GroundSettings(
        max_tilt=settings.refine_tilt,
        max_offset=settings.refine_offset,
        reach=settings.reach,
        smoothing=1.0,
    )
    planes, reasons = _planes(frames, camera, first, tight)
    if len(planes) < settings.min_floor_frames:
        _too_little_floor(len(planes), len(frames), reasons, settings)
    return _refine_floor(optical, _median_plane(planes), settings), len(planes)


def _refine_floor(
    optical: list[F64], plane: GroundPlane, settings: CalibrationSettings
) -> GroundPlane:
    """Weighted least squares over every third pixel near `plane` in the frames the scan
    match uses (`optical`, their points in the optical frame): heights h = a + b u + c v
    along two axes of the plane, weight 1 / sigma^2 with sigma = 2 mm + `depth_noise` Z^2,
    window 2.5 sigma (at most `floor_window`) either side.

    The per-frame fit keeps inliers asymmetric (the floor is the lowest surface), which
    costs a few tenths of a degree on a noisy far floor; with the median plane as the
    start a symmetric window is safe, and unbiased."""
    points = np.concatenate([points[::3] for points in optical])
    points = points[np.linalg.norm(points, axis=1) <= settings.reach]
    normal, offset = plane.vector, plane.offset
    for _ in range(4):
        helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
        first = np.cross(normal, helper)
        first /= np.linalg.norm(first)
        second = np.cross(normal, first)
        heights = points @ normal + offset
        # sigma from the depth the pixel would have on the plane, not the measured one: a
        # reading pushed nearer by its noise would otherwise weigh more than one pushed
        # farther, and the floor would tilt towards the camera.
        with np.errstate(divide='ignore', invalid='ignore'):
            expected = points[:, 2] * offset / (offset - heights)
            sigma = 0.002 + settings.depth_noise * expected**2
            window = np.minimum(2.5 * sigma, settings.floor_window)
            near = (expected > 0.0) & (np.abs(heights) <= window)
        if near.sum() < 3:
            break
        weight = 1.0 / sigma[near] ** 2
        design = np.column_stack(
            [np.ones(int(near.sum())), points[near] @ first, points[near] @ second]
        )
        a = design * weight[:, None]
        solution = np.linalg.solve(a.T @ design, a.T @ heights[near])
        # h' = h - (a + b u + c v): the new plane's normal and offset, normalised.
        raw = normal - solution[1] * first - solution[2] * second
        length = float(np.linalg.norm(raw))
        normal, offset = raw / length, (offset - solution[0]) / length
    return GroundPlane((float(normal[0]), float(normal[1]), float(normal[2])), float(offset))


def _planes(
    frames: Sequence[CalibrationFrame],
    camera: CameraModel,
    prior: GroundPlane,
    ground: GroundSettings,
) -> tuple[list[GroundPlane], list[str]]:
    sample = GroundSample.build(camera, prior, ground.samples, ground.hypotheses)
    planes, reasons = [], []
    for frame in frames:
        plane, reason = fit_ground(frame.depth, sample, prior, prior, ground)
        if plane is None:
            reasons.append(reason)
        else:
            planes.append(plane)
    return planes, reasons


def _too_little_floor(
    found: int, frames: int, reasons: list[str], settings: CalibrationSettings
) -> None:
    why = f' (last: {reasons[-1]})' if reasons else ''
    msg = (
        f'too little floor: {found} of {frames} depth frames show floor within '
        f'{math.degrees(settings.max_tilt):.0f} deg and {settings.max_offset} m of the given '
        f'mounting{why}, {settings.min_floor_frames} needed; record with open floor in front '
        'of the camera, and give a mounting (--params or /tf_static) within those bounds'
    )
    raise CalibrationError(msg)


def _median_plane(planes: list[GroundPlane]) -> GroundPlane:
    normals = np.array([p.normal for p in planes])
    normal = np.median(normals, axis=0)
    normal /= np.linalg.norm(normal)
    offset = float(np.median([p.offset for p in planes]))
    return GroundPlane((float(normal[0]), float(normal[1]), float(normal[2])), offset)


def _optical_points(depth: npt.NDArray[np.generic], camera: CameraModel) -> F64:
    """Every valid pixel back-projected into the optical frame, (N, 3)."""
    z = depth_in_metres(depth).astype(np.float64).ravel()
    x_n, y_n = camera.normalized_coordinates
    points = np.stack([x_n.ravel() * z, y_n.ravel() * z, z], axis=1)
    with np.errstate(invalid='ignore'):
        valid = np.isfinite(points).all(axis=1) & (z > 0.0)
    return points[valid]


def _floor_rms(optical: list[F64], floor: GroundPlane, settings: CalibrationSettings) -> float:
    """RMS height above `floor` of the points near it (within 3 cm, within reach)."""
    squares, count = 0.0, 0
    for points in optical:
        heights = points @ floor.vector + floor.offset
        near = (np.abs(heights) <= 0.03) & (np.linalg.norm(points, axis=1) <= settings.reach)
        squares += float(np.sum(heights[near] ** 2))
        count += int(near.sum())
    return math.sqrt(squares / count) if count else math.nan


# ------------------------------------------------------------------ scan match


def _spread(count: int, wanted: int) -> list[int]:
    """Up to `wanted` indices spread evenly over range(count)."""
    if count <= wanted:
        return list(range(count))
    return (
        sorted({round(i * (count - 1) / (wanted - 1)) for i in range(wanted)})
        if wanted > 1
        else [0]
    )


def _level_of(mounting: Mounting) -> Transform:
    """The level frame (yaw 0, at x = y = 0) of a mounting -> its optical frame."""
    body = Transform.from_rpy(mounting.roll, mounting.pitch, 0.0, (0.0, 0.0, mounting.height))
    return body @ BODY_TO_OPTICAL


def _band_points(
    optical: F64,
    level_to_optical: Transform,
    lidar_height: float,
    settings: CalibrationSettings,
) -> F64:
    """The camera's points within `band` of the LiDAR's height on surfaces that cross the
    LiDAR's plane: x, y in the level frame, the depth Z and the distance from the camera
    in the top view (their ratio scales Z to the LiDAR's line, for the noise's sigma).

    A surface crosses the plane where a `cell` of the top view holds points from at least
    `crossing` below the plane to at least `crossing` above it: walls, pillars, a chair's
    legs. A shelf board or a box top at the plane's height is flat (the LiDAR passes over
    or under it) and a box lower than the plane does not reach above it: neither is what
    the LiDAR sees, and both are left out.
    """
    near = optical[optical[:, 2] <= settings.match_reach]
    points = level_to_optical.apply(near)
    height = points[:, 2] - lidar_height
    wide = np.abs(height) <= max(settings.band, settings.crossing) + settings.cell
    points, height, depths = points[wide], height[wide], near[wide, 2]
    if not points.size:
        return np.empty((0, 3))
    _, cell, counts = np.unique(
        _cell_keys(points[:, :2], settings.cell), return_inverse=True, return_counts=True
    )
    low = np.full(counts.size, np.inf)
    high = np.full(counts.size, -np.inf)
    np.minimum.at(low, cell, height)
    np.maximum.at(high, cell, height)
    crossing = (low <= -settings.crossing) & (high >= settings.crossing)
    keep = crossing[cell] & (np.abs(height) <= settings.band)
    flat = points[keep, :2]
    if not flat.size:
        return np.empty((0, 3))
    return np.column_stack([flat, depths[keep], np.hypot(flat[:, 0], flat[:, 1])])


def _cell_keys(points: F64, size: float) -> npt.NDArray[np.int64]:
    """One integer per top-view cell of side `size` (cells within 2^31 of the origin)."""
    cells = np.floor(points / size).astype(np.int64)
    keys: npt.NDArray[np.int64] = (cells[:, 0] << 32) + cells[:, 1]
    return keys


@dataclass(frozen=True)
class _Lines:
    """A LiDAR scan in the base frame, reading by reading: the line through each reading
    and its neighbours (a point on it, the centroid, and its unit normal; NaN where the
    reading is invalid or its neighbourhood no line), the valid readings themselves, and
    what finds the reading on a bearing (the scan's grid, base -> laser)."""

    points: F64
    normals: F64
    readings: F64
    angle_min: float
    increment: float
    base_to_laser: Transform

    def reading_at(self, placed: F64) -> npt.NDArray[np.intp]:
        """Index of the reading on the bearing of each point (base frame x, y); -1 if the
        bearing is outside the scan."""
        height = self.base_to_laser.translation[2]
        flat = np.column_stack([placed, np.full(len(placed), height)])
        local = self.base_to_laser.inverse().apply(flat)
        bearing = np.arctan2(local[:, 1], local[:, 0])
        step = abs(self.increment)
        sign = 1.0 if self.increment > 0.0 else -1.0
        offset = np.mod(sign * (bearing - self.angle_min) + 0.5 * step, 2.0 * math.pi)
        index = np.floor(offset / step).astype(np.intp)
        index[index >= len(self.points)] = -1
        return index


def _scan_lines(scan: Scan, base_to_laser: Transform) -> _Lines:
    ranges = scan.ranges.astype(np.float64)
    angles = scan.angles()
    with np.errstate(invalid='ignore'):
        valid = np.isfinite(ranges) & (ranges >= scan.range_min) & (ranges <= scan.range_max)
    local = np.stack([ranges * np.cos(angles), ranges * np.sin(angles), np.zeros(ranges.size)])
    points = base_to_laser.apply(local.T[valid])[:, :2]
    # The line through each reading and its neighbours (two each side, within 15 cm):
    # the scatter's eigenvector of the smaller eigenvalue; none where it is no line.
    count = points.shape[0]
    index = np.arange(count)[:, None] + np.arange(-2, 3)[None, :]
    inside = (index >= 0) & (index < count)
    window = points[np.clip(index, 0, max(count - 1, 0))]
    near = inside & (np.linalg.norm(window - points[:, None, :], axis=2) <= 0.15)
    weight = near.astype(np.float64)[:, :, None]
    members = np.maximum(near.sum(axis=1), 1)[:, None]
    mean = (window * weight).sum(axis=1) / members
    centred = (window - mean[:, None, :]) * weight
    scatter = np.einsum('nki,nkj->nij', centred, centred)
    values, vectors = np.linalg.eigh(scatter)
    line = (near.sum(axis=1) >= 3) & (values[:, 0] <= 0.04 * values[:, 1])
    centres = np.full((ranges.size, 2), np.nan)
    normals = np.full((ranges.size, 2), np.nan)
    centres[np.flatnonzero(valid)[line]] = mean[line]
    normals[np.flatnonzero(valid)[line]] = vectors[line, :, 0]
    return _Lines(
        centres, normals, points, float(scan.angle_min), float(scan.angle_increment), base_to_laser
    )


@dataclass(frozen=True)
class _Pairs:
    """Matched camera points: their rows of the linearised problem and residuals."""

    rows: F64  # (N, 3): d(residual)/d(x, y, yaw)
    residuals: F64
    sigmas: F64  # expected spread of each residual, metres
    positions: F64  # (N, 2): the camera points, placed in the base frame

    @property
    def count(self) -> int:
        return int(self.residuals.size)

    @property
    def rms(self) -> float:
        return float(np.sqrt(np.mean(self.residuals**2))) if self.count else math.nan

    @property
    def normalised_rms(self) -> float:
        """RMS of the residuals in units of their sigma: about 1 when only noise is left."""
        if not self.count:
            return math.nan
        return float(np.sqrt(np.mean((self.residuals / self.sigmas) ** 2)))


def _rotation(yaw: float) -> F64:
    c, s = math.cos(yaw), math.sin(yaw)
    return np.array([[c, -s], [s, c]])


def _placed(clouds: list[F64], yaw: float, shift: F64) -> F64:
    if not clouds:
        return np.empty((0, 2))
    placed: F64 = np.concatenate(clouds)[:, :2] @ _rotation(yaw).T + shift
    return placed


class _Matcher:
    """Point-to-line ICP of camera clouds (level frame) onto LiDAR lines (base frame)."""

    def __init__(
        self,
        clouds: list[F64],
        scans: list[_Lines],
        settings: CalibrationSettings,
        most: int = 1000,
    ) -> None:
        rng = np.random.default_rng(0)
        self.clouds = [
            c if len(c) <= most else c[np.sort(rng.choice(len(c), most, replace=False))]
            for c in clouds
        ]
        self.scans = scans
        self.settings = settings

    def coarse(self, frames: int = 2, most: int = 250) -> _Matcher:
        """The same match on fewer frames and points: to try several starts quickly."""
        chosen = _spread(len(self.clouds), frames)
        clouds = [self.clouds[i] for i in chosen]
        return _Matcher(clouds, [self.scans[i] for i in chosen], self.settings, most)

    def pairs(self, yaw: float, shift: F64, distance: float) -> _Pairs:
        """Each camera point, placed by (yaw, shift), with the LiDAR reading on its bearing
        when that reading has a line and the point lies within `distance` of it, or within
        3 sigma of the sensors' noise."""
        rotation = _rotation(yaw)
        rows, residuals, sigmas, positions = [], [], [], []
        for cloud, scan in zip(self.clouds, self.scans, strict=True):
            if not cloud.size or not scan.points.size:
                continue
            turned = cloud[:, :2] @ rotation.T
            placed = turned + shift
            # Projective association (as PSM, PL-ICP): the reading on the point's bearing
            # from the LiDAR. The depth's noise moves a point along the camera's ray, nearly
            # along that bearing, so a noisy point keeps its reading (the nearest reading
            # would change with the noise, and on which side of a wall it fell).
            index = scan.reading_at(placed)
            known = index >= 0
            found = np.where(known, index, 0)
            line = scan.points[found]
            gap = np.where(known[:, None], placed - line, np.nan)
            normal = scan.normals[found]
            # The depth's sigma at the depth the point would have on the LiDAR's line (the
            # measured depth is noisy: nearer readings would weigh more, and pull).
            with np.errstate(invalid='ignore', divide='ignore'):
                expected = cloud[:, 2] * np.hypot(*(line - shift).T) / cloud[:, 3]
            sigma = np.hypot(self.settings.lidar_noise, self.settings.depth_noise * expected**2)
            gate = np.maximum(distance, 3.0 * sigma)
            with np.errstate(invalid='ignore'):
                along = np.abs(np.einsum('ij,ij->i', normal, gap))
                keep = np.isfinite(along) & np.isfinite(sigma) & (along <= gate)
            normal, gap, turned = normal[keep], gap[keep], turned[keep]
            residuals.append(np.einsum('ij,ij->i', normal, gap))
            rows.append(np.column_stack([normal, np.einsum('ij,ij->i', normal, turned @ _J.T)]))
            sigmas.append(sigma[keep])
            positions.append(placed[keep])
        if not rows:
            return _Pairs(np.empty((0, 3)), np.empty(0), np.empty(0), np.empty((0, 2)))
        return _Pairs(
            np.concatenate(rows),
            np.concatenate(residuals),
            np.concatenate(sigmas),
            np.concatenate(positions),
        )

    def refine(
        self, yaw: float, shift: F64, distance: float, basis: F64 | None = None
    ) -> tuple[float, F64, int]:
        """ICP from (yaw, shift): the pair distance shrinks from `distance` to
        `inlier_distance`; returns the pose and the matched count at the end. With `basis`
        (3 x k, columns in (x, y, yaw)), only steps within its span are taken."""
        settings = self.settings
        for _ in range(60):
            pairs = self.pairs(yaw, shift, distance)
            if pairs.count < 3:
                return yaw, shift, 0
            # Weighed by 1 / sigma^2 (a far point's depth is noisier), Huber beyond 1.5 sigma.
            normalised = np.abs(pairs.residuals) / pairs.sigmas
            weights = 1.0 / (pairs.sigmas**2 * np.maximum(1.0, normalised / 1.5))
            a = pairs.rows * weights[:, None]
            information, gradient = a.T @ pairs.rows, -(a.T @ pairs.residuals)
            if basis is None:
                step = np.linalg.lstsq(information, gradient, rcond=None)[0]
            else:
                reduced = basis.T @ information @ basis
                step = basis @ np.linalg.lstsq(reduced, basis.T @ gradient, rcond=None)[0]
            shift = shift + step[:2]
            yaw += float(step[2])
            small = abs(step[2]) < 1e-5 and float(np.hypot(step[0], step[1])) < 1e-4
            if small:
                if distance <= settings.inlier_distance:
                    break
                distance = max(settings.inlier_distance, distance / 2.0)
        return _wrap(yaw), shift, self.pairs(yaw, shift, settings.inlier_distance).count

    def spread(self, yaw: float, shift: F64) -> tuple[float, float, float]:
        """Standard deviation over frames of (x, y, yaw) matched frame by frame from the
        joint estimate: how much the depth's noise moves one frame's answer (0: one frame)."""
        found = []
        for cloud, scan in zip(self.clouds, self.scans, strict=True):
            single = _Matcher([cloud], [scan], self.settings)
            one_yaw, one_shift, count = single.refine(yaw, shift, self.settings.inlier_distance)
            if count >= self.settings.min_matched:
                found.append((float(one_shift[0]), float(one_shift[1]), one_yaw))
        if len(found) < 2:
            return (0.0, 0.0, 0.0)
        deviation = np.std(np.array(found), axis=0, ddof=1)
        return (float(deviation[0]), float(deviation[1]), float(deviation[2]))

    def cost(self, yaw: float, shift: F64) -> float:
        """Mean truncated squared residual in sigmas: min((r / sigma)^2, 9) per camera point,
        9 for a point that pairs with nothing (lower is better)."""
        pairs = self.pairs(yaw, shift, self.settings.inlier_distance)
        total = sum(len(cloud) for cloud in self.clouds)
        if not total:
            return math.inf
        squares = np.minimum((pairs.residuals / pairs.sigmas) ** 2, 9.0)
        return float((squares.sum() + 9.0 * (total - pairs.count)) / total)

    def check_profile(self, yaw: float, shift: F64, weakest: F64) -> None:
        """Refuse when moving the estimate along its weakest direction barely worsens the
        fit: started `PROFILE_STEP` along it (each way; yaw counted as the shift it makes
        1 m away) and refined in the other two directions only, the match's `cost` summed
        over its points (a truncated chi-square) must rise by `PROFILE_RISE` at least.
        Walls that fix the direction make it rise several times that; one straight wall
        (along it), or a round wall about the camera (in yaw), leave it where the noise
        has it. The information matrix alone cannot tell the latter: the noise of the
        fitted lines gives a round wall some yaw information.
        """
        probe = self.coarse(frames=3, most=400)
        base = probe.cost(yaw, shift)
        points = sum(len(cloud) for cloud in probe.clouds)
        others = np.linalg.svd(weakest.reshape(1, 3))[2][1:].T  # 3 x 2, orthogonal to it
        rises = []
        for sign in (1.0, -1.0):
            step = sign * PROFILE_STEP * weakest
            found_yaw, found_shift, _ = probe.refine(
                yaw + float(step[2]), shift + step[:2], 4.0 * self.settings.inlier_distance, others
            )
            rises.append((probe.cost(found_yaw, found_shift) - base) * points)
        if min(rises) >= PROFILE_RISE:
            return
        what = 'yaw' if abs(weakest[2]) > math.hypot(weakest[0], weakest[1]) else 'x, y'
        msg = (
            f'walls too few to fix {what}: moved {PROFILE_STEP * 100:.0f} cm (or '
            f'{math.degrees(PROFILE_STEP):.1f} deg) along its weakest direction, the match fits '
            f'as well (its chi-square rises by {min(rises):.0f} only, over {points} points); '
            'record facing a corner of a room, or put a box taller than the LiDAR plane in '
            'view of both'
        )
        raise CalibrationError(msg)

    def best_start(self, yaw: float, shift: tuple[float, float]) -> tuple[float, F64]:
        """The ICP result that matches the most points, of starts around the given yaw."""
        limit = self.settings.max_yaw_error
        steps = max(0, math.ceil(limit / math.radians(4.0)))
        offsets = [0.0] + [
            sign * limit * k / steps for k in range(1, steps + 1) for sign in (1, -1)
        ]
        best: tuple[int, float, F64] | None = None
        for offset in offsets:
            start = np.array(shift, dtype=float)
            found_yaw, found_shift, count = self.refine(
                yaw + offset, start, self.settings.start_distance
            )
            if best is None or count > best[0]:
                best = (count, found_yaw, found_shift)
        assert best is not None
        if best[0] < self.settings.min_matched:
            msg = (
                f'only {best[0]} camera points lie on what the LiDAR sees (within '
                f'{self.settings.inlier_distance} m or 3 sigma of the noise), fewer than '
                f'{self.settings.min_matched}: '
                'the camera and the LiDAR must see the same walls or tall obstacles; '
                'record facing a corner of a room, and give camera_yaw within '
                f'{math.degrees(limit):.0f} deg'
            )
            raise CalibrationError(msg)
        return best[1], best[2]

    def check_constraints(self, pairs: _Pairs) -> F64:
        """Refuse when the matched walls leave a direction of (x, y, yaw) nearly free; the
        weakest direction (unit, yaw counted as the shift it makes 1 m away) otherwise.

        The information matrix of the match (yaw weighed as the shift it makes 1 m away),
        per metre of wall seen: its least eigenvalue is the share of the walls that pin the
        weakest direction. One straight wall 2 m ahead leaves 0.3 % along it (the noise of
        the fitted lines), and the match slides there by decimetres; 30 cm of wall across it
        gives 3 % and pins it within a few millimetres (depth noise 0.01 Z^2).
        `min_constraint` is between.
        """
        rows = pairs.rows.copy()
        lever = 1.0  # metres: yaw is weighed as the shift it makes 1 m from the camera
        rows[:, 2] /= lever
        # Each point weighs 1 / (matched points in its 5 cm cell): shares of the walls'
        # length, not of pixels (a near wall has many more pixels per metre than a far one).
        _, cell, counts = np.unique(
            _cell_keys(pairs.positions, 0.05), return_inverse=True, return_counts=True
        )
        weight = 1.0 / counts[cell]
        information = (rows * weight[:, None]).T @ rows / max(float(weight.sum()), 1e-12)
        values, vectors = np.linalg.eigh(information)
        weak: F64 = vectors[:, 0]
        if values[0] >= self.settings.min_constraint * max(float(values[-1]), 1e-12):
            return weak
        if abs(weak[2]) > math.hypot(weak[0], weak[1]):
            what = 'walls too few to fix yaw'
        else:
            angle = math.degrees(math.atan2(weak[1], weak[0])) % 180.0
            what = (
                f'walls too few to fix x, y: the match can slide along {angle:.0f} deg '
                '(from the base frame x axis)'
            )
        msg = (
            f'{what} (the camera and the LiDAR see {pairs.count} common points, nearly all on '
            'parallel lines); record facing a corner of a room, or put a box taller than '
            'the LiDAR plane in view of both'
        )
        raise CalibrationError(msg)
