"""Where the floor really is, from every depth frame: the mounting is a prior, not the truth.

A robot that dips 2 deg when it brakes, or a camera whose pitch was measured 2 deg off,
moves the floor 10 cm at 3 m: with heights measured from the mounting's plane the floor
there is an obstacle (or a drop). `GroundTracker` finds the floor plane in each frame, in
the camera's optical frame, with the mounting's plane as the prior:

- a fixed sample of pixels (`GroundSample`, about `samples` of them, on a regular grid of
  the pixels that look below the horizon) is back-projected; only points that an
  admissible plane could hold are candidates: within `max_offset` + r sin(`max_tilt`) of
  the prior's plane, r their distance from the camera, at most `reach` metres away, and
  within `ground_kernel.FIT_RUN_LONG` (horizontally) of where the floor is first seen; the
  plane of that run is kept where it agrees with the plane of the first
  `ground_kernel.FIT_RUN` metres, else the latter's (the floor the robot stands on, not a
  ramp's foot or a crest ahead: that is the profile's);
- RANSAC over those candidates (hypotheses: the prior, the last estimate and random
  triples, at most `hypotheses` of them and no more once one held only inliers with
  probability `ground_kernel.CONFIDENCE`; seeded, so a frame gives the same plane every
  time) keeps the admissible plane
  (normal within `max_tilt` of the prior's, offset within `max_offset`; with an IMU, of the
  prior's or of the mounting's own plane: on a ramp the wheels stand on the ramp, the IMU's
  level floor is the ramp's slope away from it) with the best score:
  points within the inlier distance (`inlier_distance` + 3 sigma of the depth noise) minus
  points more than that below it. The floor is the lowest large surface the robot stands
  on: a box top or a step is a plane with the floor under it, and loses;
- least squares on the winner's inliers (`ground_kernel.refine`: within the inlier distance
  below the plane, only the depth's noise above it), three times, checked against the
  bounds again;
- too few inliers (fewer than `min_points`) or inliers along a line (their spread across
  either in-plane axis below `min_spread`: a strip of floor under a wall fixes only one
  tilt) make the frame fall back, counted: with an IMU (the prior then the level floor)
  the estimate is the plane the wheels stand on (`base`: on a ramp, the ramp); without,
  what was learnt fades towards the prior (`FALLBACK_FADE` a frame), not held for good;
- the estimate's offset from the prior is smoothed over frames (`smoothing`: the weight of
  the new frame), so a prior that moves (an IMU's tilt) carries the learnt error along;
- ground that leaves the plane ahead within `max_slope` (a ramp; with an IMU, `max_slope`
  above level: from a ramp, the ramp down past its top) is the profile's
  (`ground_profile`, `ground_kernel.profile`): per image column, walked outwards; with it
  the lowest the ground may be where a column saw none (behind a crest: falling at
  `max_slope` from the last ground seen), which drops are measured below.

The heights of the collision slab and of drops are then measured above this ground
(`ObstacleProjector.scan(ground=..., profile=...)`; the slab above a profile's ground also
by `PROFILE_DOUBT_SIGMAS` of each bin's mean, and above a rising one by the extra height
its noise gives, `SLOPE_NOISE_SIGMAS`); `MountCheck` compares it with the
mounting over many frames. On a flat floor with the right mounting the estimate stays
within the projector's GROUND_TOLERANCE of the prior, and the projector keeps its tables.
"""

from __future__ import annotations

import functools
import math
from collections import deque
from dataclasses import astuple, dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from scanfuse.camera import MILLIMETRE
from scanfuse.convert import ground_kernel
from scanfuse.errors import InputError
from scanfuse.transforms import Transform

if TYPE_CHECKING:
    import numpy.typing as npt

    from scanfuse.camera import CameraModel
    from scanfuse.config import FusionConfig

    F64 = npt.NDArray[np.float64]
    Vector = tuple[float, float, float]

_UP = np.array([0.0, 0.0, 1.0])


@dataclass(frozen=True)
class GroundPlane:
    """The floor seen from a camera: a point P of the optical frame is `normal . P + offset`
    metres above it (`normal` a unit vector, pointing up; `offset` the camera's height)."""

    normal: tuple[float, float, float]
    offset: float

    @classmethod
    def of_mounting(cls, base_to_camera_optical: Transform) -> GroundPlane:
        """The plane base z = 0 of a mounting (the prior): the base's up axis, optical."""
        row = base_to_camera_optical.rotation_matrix[2]
        return cls(
            (float(row[0]), float(row[1]), float(row[2])),
            float(base_to_camera_optical.translation[2]),
        )

    @property
    def vector(self) -> F64:
        return np.array(self.normal, dtype=np.float64)

    def tilt_from(self, other: GroundPlane) -> float:
        """Angle between the two planes' normals, radians."""
        cosine = float(np.clip(self.vector @ other.vector, -1.0, 1.0))
        return math.acos(cosine)

    def height_change(self, other: GroundPlane, reach: float) -> float:
        """An upper bound of how much a point's height differs between the two planes, for
        points within `reach` metres of the camera."""
        difference = self.vector - other.vector
        return abs(self.offset - other.offset) + reach * float(np.linalg.norm(difference))

    @property
    def camera_pitch(self) -> float:
        """The camera's pitch above this plane (positive looks down), as `fit_floor` reads it."""
        return math.asin(max(-1.0, min(1.0, -self.normal[2])))

    @property
    def camera_roll(self) -> float:
        """The camera's roll above this plane (positive: its right side down)."""
        return math.atan2(-self.normal[0], -self.normal[1])

    def mounting(self, base_to_camera_optical: Transform) -> Transform:
        """`base_to_camera_optical` turned and lifted so that its base z = 0 is this plane.

        The least rotation about the base's origin that takes this plane's normal (in the
        base frame) to the base's up axis: the camera's yaw and its x, y stay the mounting's.
        """
        rotation = base_to_camera_optical.rotation_matrix
        up = rotation @ self.vector  # the estimated up axis in the prior's base frame
        axis = np.cross(up, _UP)
        sine, cosine = float(np.linalg.norm(axis)), float(up @ _UP)
        turn = np.eye(3)
        if sine > 1e-15:
            k = axis / sine
            skew = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
            turn = np.eye(3) + sine * skew + (1.0 - cosine) * (skew @ skew)
        matrix = np.eye(4)
        matrix[:3, :3] = turn @ rotation
        moved = turn @ np.asarray(base_to_camera_optical.translation)
        matrix[:3, 3] = (moved[0], moved[1], self.offset)
        return Transform.from_matrix(matrix)


@dataclass(frozen=True)
class GroundSettings:
    """How the floor is found in each frame (see the module docstring)."""

    max_tilt: float = math.radians(10.0)  # radians the floor may tilt from the mounting's
    max_offset: float = 0.08  # metres the camera may be above or below the mounting's height
    reach: float = 3.0  # metres from the camera: farther points are not used
    inlier_distance: float = 0.02  # metres, plus 3 sigma of the depth noise at the point
    depth_noise: float = 0.01  # sigma = depth_noise * Z^2 (1/m)
    min_points: int = 80  # inliers needed for an estimate
    min_spread: float = 0.1  # metres: standard deviation of the inliers along each plane axis
    smoothing: float = 0.3  # weight of the new frame's plane
    samples: int = 1500  # pixels looked at per frame
    hypotheses: int = 40  # random triples tried per frame, at most
    max_slope: float = math.atan(1.0 / 8.0)  # radians: steeper ground is not floor; 0: one plane

    def __post_init__(self) -> None:
        checks = (
            ('ground_max_tilt', self.max_tilt, 0.0 < self.max_tilt < math.pi / 4),
            ('ground_max_offset', self.max_offset, 0.0 <= self.max_offset <= 1.0),
            ('ground_smoothing', self.smoothing, 0.0 < self.smoothing <= 1.0),
            ('reach', self.reach, self.reach > 0.0),
            ('inlier_distance', self.inlier_distance, self.inlier_distance > 0.0),
            ('depth_noise', self.depth_noise, self.depth_noise >= 0.0),
            ('min_points', self.min_points, self.min_points >= 3),
            ('min_spread', self.min_spread, self.min_spread >= 0.0),
            ('samples', self.samples, self.samples >= 3),
            ('hypotheses', self.hypotheses, self.hypotheses >= 0),
            ('max_slope', self.max_slope, 0.0 <= self.max_slope < math.pi / 4),
        )
        for name, value, valid in checks:  # (FusionConfig checks what users set)
            if not (valid and math.isfinite(value)):
                msg = f'{name} = {value} is out of its range (see GroundSettings)'
                raise InputError(msg)

    @classmethod
    def from_config(cls, config: FusionConfig) -> GroundSettings:
        """The settings `config` gives (reach: the camera's range_max)."""
        return cls(
            max_tilt=config.ground_max_tilt,
            max_offset=config.ground_max_offset,
            reach=config.range_max,
            depth_noise=config.depth_noise,
            smoothing=config.ground_smoothing,
            max_slope=config.max_slope,
        )


@dataclass(frozen=True)
class GroundSample:
    """The pixels one camera's ground estimate looks at, their rays (x_n, y_n, 1), and the
    numbers in [0, 1) that pick each RANSAC hypothesis's three candidates (seeded: a frame
    gives the same plane every time); and the profile's grid (`profile_columns` of the
    image, `profile_rows` nearest first) with its rays' x_n, y_n, row by row (read from the
    camera's whole-image tables, they cost the profile's walk a cache miss a pixel)."""

    indices: npt.NDArray[np.intp]
    rays: F64
    draws: F64
    width: int
    profile_columns: npt.NDArray[np.int64]
    profile_rows: npt.NDArray[np.int64]
    profile_x: npt.NDArray[np.float32]
    profile_y: npt.NDArray[np.float32]

    @classmethod
    def build(
        cls, camera: CameraModel, prior: GroundPlane, samples: int, hypotheses: int
    ) -> GroundSample:
        """About `samples` pixels on a regular grid, of those whose ray looks down at all
        (ahead of a camera pitched by up to `max_tilt` more, the floor is too far to matter)."""
        x_n, y_n = (np.asarray(c, dtype=np.float64).ravel() for c in camera.normalized_coordinates)
        stride = max(1, math.floor(math.sqrt(camera.width * camera.height / samples)))
        rows = np.arange(stride // 2, camera.height, stride)
        columns = np.arange(stride // 2, camera.width, stride)
        grid = (rows[:, None] * camera.width + columns[None, :]).ravel()
        rays = np.stack([x_n[grid], y_n[grid], np.ones(grid.size)], axis=1)
        with np.errstate(invalid='ignore'):
            down = (rays @ prior.vector < 0.0) & np.isfinite(rays).all(axis=1)
        draws = np.random.default_rng(0).random((hypotheses, 3))
        profile_columns, profile_rows = _profile_grid(camera.width, camera.height)
        profile_pixels = (profile_rows[:, None] * camera.width + profile_columns[None, :]).ravel()
        x_table, y_table = (c.ravel() for c in camera.normalized_coordinates)
        return cls(
            indices=grid[down],
            rays=np.ascontiguousarray(rays[down]),
            draws=draws,
            width=camera.width,
            profile_columns=profile_columns,
            profile_rows=profile_rows,
            profile_x=x_table[profile_pixels],
            profile_y=y_table[profile_pixels],
        )


@dataclass
class GroundCounts:
    """How the frames' ground estimates went."""

    frames: int = 0
    estimated: int = 0
    fell_back: int = 0  # too little floor seen: the last estimate (or the prior) kept
    last_reason: str = ''


# Why `ground_kernel.fit` found no floor, by its status.
_REASONS = {
    ground_kernel.FEW_CANDIDATES: 'floor candidates',
    ground_kernel.FEW_INLIERS: 'floor points',
}


def _kernel_depth(depth: npt.NDArray[np.generic]) -> tuple[npt.NDArray[np.generic], float]:
    """The flat image as the kernels read it (uint16 millimetres, else float32 metres) and
    metres per unit."""
    flat = depth.ravel()
    if flat.dtype == np.uint16:
        return flat, MILLIMETRE
    return flat.astype(np.float32, copy=False), 1.0


def fit_ground(
    depth: npt.NDArray[np.generic],
    sample: GroundSample,
    prior: GroundPlane,
    start: GroundPlane,
    settings: GroundSettings,
    base: GroundPlane | None = None,
) -> tuple[GroundPlane | None, str]:
    """The floor plane of one depth image, or None and why (see the module docstring).
    `base`: the mounting's own plane when `prior` is it tilted by an IMU."""
    flat, scale = _kernel_depth(depth)
    out = np.empty(7)
    base = base or prior
    ground_kernel.fit(
        flat, scale, sample.indices, sample.rays, np.array([*prior.normal, prior.offset]),
        np.array([*start.normal, start.offset]), np.array([*base.normal, base.offset]),
        settings.max_offset, settings.max_tilt,
        settings.reach, settings.inlier_distance, settings.depth_noise, sample.draws,
        settings.min_points, settings.min_spread, out,
    )  # fmt: skip
    status = int(out[6])
    if status == ground_kernel.OK:
        return GroundPlane((float(out[0]), float(out[1]), float(out[2])), float(out[3])), ''
    if status in _REASONS:
        return None, f'{int(out[4])} {_REASONS[status]}, fewer than {settings.min_points}'
    if status == ground_kernel.ALONG_A_LINE:
        return None, (
            f'the floor points lie along a line (spread {out[5]:.2f} m across it, less than '
            f'{settings.min_spread} m)'
        )
    return None, 'the fitted floor lies outside ground_max_tilt / ground_max_offset'


# Sampled image columns of the profile, at most; rows: every ROW_STRIDE-th of this many.
PROFILE_COLUMNS = 32
PROFILE_ROWS = 160
# Metres of horizontal distance per bin of the profile.
PROFILE_BIN = 0.15
# Metres the profile must leave the plane by, in PROFILE_EVIDENCE bins in a row where ground
# was seen, to count (below, the plane holds: a flat floor's noise, a bin of an obstacle's
# foot make no profile, and the tables stay).
PROFILE_DEADBAND = 0.02
PROFILE_EVIDENCE = 3
# ... and by this many sigmas of the bin's mean height (its points' noise, depth_noise Z^2
# along each ray, over their count): 2-3 m out a bin holds a point or two, each a centimetre
# or more off, and with the deadband alone about one noisy frame of a flat room in ten made
# a profile, which rebuilt the tables twice (`make bench`'s room stream).
PROFILE_EVIDENCE_SIGMAS = 3.0
# Sigmas of a bin's mean height (its points' noise over their count) the slab stands higher
# above the profile's ground there: 2-3 m out a bin's ground is the mean of a point or two,
# each a centimetre or more off, and the floor beyond a ramp stood in the slab above a bin
# drawn low. Noisy, a 1:8 ramp down from 1 m gave false slots in 40 % of the view (a flat
# floor's noise: 14 %), 23 % with 1 sigma, 14 % with 2. In `scanfuse evaluate`, 2 sigmas took
# as much from the camera's false obstacles on slopes (0.72 against 1.13 points) as 1, but a
# drive up a 1:8 ramp stalled beside a box on it; 1 sigma kept every goal.
PROFILE_DOUBT_SIGMAS = 1.0
# Noise sigmas by which the slab's bottom is raised over a ramp rising away from the camera
# (by the extra its noise lifts readings there: `ground_kernel.slope_margin`). With the
# default depth_noise a 1:12 ramp raises it by 1 cm at 2 m, 2.3 cm at 3 m.
SLOPE_NOISE_SIGMAS = 3.0
# The ground under the lines of sight (`GroundProfile.ground_under`) is found for every
# LIFT_STRIDE-th pixel of every LIFT_STRIDE-th row, each standing for its block; an image
# wider than LIFT_WIDTH has blocks as many pixels more (the same angle: the ground under a
# line of sight moves by millimetres from one such block to the next). A narrower one keeps
# LIFT_STRIDE: finer blocks would cost more without telling more than the profile's bins.
LIFT_STRIDE = 2
LIFT_WIDTH = 640


def lift_stride(width: int) -> int:
    """Pixels a side of the blocks `GroundProfile.ground_under` finds the ground for."""
    return max(LIFT_STRIDE, LIFT_STRIDE * width // LIFT_WIDTH)


@dataclass(frozen=True, eq=False)
class Lifts:
    """The ground's height above the plane under the lines of sight of an image's pixels,
    per level (`GroundProfile.ground_under`): `coarse[level, v // stride, u // stride]` is
    pixel (u, v)'s."""

    coarse: F64  # levels x ceil(height / stride) x ceil(width / stride), read-only
    stride: int

    def per_pixel(self, height: int, width: int) -> F64:
        """Levels x pixels (flattened), each block's value repeated over its pixels."""
        fine = np.repeat(np.repeat(self.coarse, self.stride, axis=1), self.stride, axis=2)
        return np.ascontiguousarray(fine[:, :height, :width]).reshape(self.coarse.shape[0], -1)


@dataclass(frozen=True, eq=False)
class GroundProfile:
    """Ground that is not one plane (a ramp): its height above `plane` per sampled image
    column (`columns`) and bin of `bin_size` metres of horizontal distance from the camera.

    Built by `ground_kernel.profile` (see there); `ground_under` gives every pixel the
    ground's height where its line of sight meets it (`ground_kernel.crossings`).
    """

    plane: GroundPlane
    columns: npt.NDArray[np.int64]
    heights: F64  # columns x bins, metres above the plane
    bin_size: float
    # The lowest the ground may be where no column saw it (`ground_kernel.profile`): what
    # drops are measured below. None: `heights`. Beyond the last bin they fall on by
    # `falls[column]` metres per metre (the steepest floor's; None: level).
    lows: F64 | None = None
    falls: F64 | None = None
    # Depth noise (sigma = depth_noise Z^2) times `SLOPE_NOISE_SIGMAS`: how far a rising
    # ramp's noisy readings reach above it (`ground_kernel.slope_margin`); 0: no margin.
    noise_margin: float = 0.0
    # Metres the slab stands higher above each bin's ground for the doubt of its mean
    # (`PROFILE_DOUBT_SIGMAS`; columns x bins). None: none.
    doubt: F64 | None = None
    # `ground_under`'s answers: the projector and the memory ask the same of one frame.
    _lifts: dict[tuple[CameraModel, float, tuple[float, ...], int], Lifts] = field(
        default_factory=dict, repr=False
    )

    def axes(self) -> tuple[F64, F64]:
        return _plane_axes(self.plane)

    def ground_under(
        self, camera: CameraModel, far: float, levels: tuple[float, ...], lowest: int = 0
    ) -> Lifts:
        """Per level L and pixel the ground's height above the plane under the point of the
        pixel's line of sight that is L above the ground (L = 0: where it meets the ground),
        or under its point at depth `far`, found per block of `lift_stride` pixels a side.
        The last `lowest` levels are measured above the lowest ground (`lows`: drops).
        Kept: asked again for the same, it is not found again."""
        key = (camera, far, levels, lowest)
        if key in self._lifts:
            return self._lifts[key]
        stride = lift_stride(camera.width)
        x_n, y_n = (
            np.ascontiguousarray(np.asarray(c)[::stride, ::stride])
            for c in camera.normalized_coordinates
        )
        forward, left = self.axes()
        coarse = np.empty((len(levels), x_n.size))
        ground_kernel.crossings(
            x_n.ravel(), y_n.ravel(), x_n.shape[1], stride,
            np.array([*self.plane.normal, self.plane.offset]), forward, left, self.columns,
            self.heights, self.heights if self.lows is None else self.lows,
            np.zeros(1) if self.falls is None else self.falls,
            self.bin_size, far, np.array(levels, dtype=np.float64), len(levels) - lowest,
            self.noise_margin, np.zeros((0, 0)) if self.doubt is None else self.doubt, coarse,
        )  # fmt: skip
        coarse = coarse.reshape(len(levels), *x_n.shape)
        coarse.setflags(write=False)
        lifts = Lifts(coarse, stride)
        self._lifts[key] = lifts
        return lifts

    def slab_lifts(
        self, camera: CameraModel, range_max: float, min_height: float, max_height: float
    ) -> Lifts:
        """`ground_under` at the slab's top and bottom, where the line of sight meets the
        ground (a ramp's height there) and where it meets the lowest ground the ground may
        be (a drop lies beyond that): what the obstacle scan and the memory measure above."""
        return self.ground_under(camera, range_max, (max_height, min_height, 0.0, 0.0), lowest=1)


def _plane_axes(plane: GroundPlane) -> tuple[F64, F64]:
    """Horizontal unit axes of the plane: the optical axis's direction on it, and its left.

    (Plain floats: numpy's per-call cost on 3-vectors is most of this per frame.)
    """
    n_x, n_y, n_z = plane.normal
    # The optical z axis less its part along the normal.
    f_x, f_y, f_z = -n_z * n_x, -n_z * n_y, 1.0 - n_z * n_z
    length = math.sqrt(f_x * f_x + f_y * f_y + f_z * f_z)
    if length < 1e-9:  # the camera looks straight down: any horizontal axis will do
        f_x, f_y, f_z = 1.0 - n_x * n_x, -n_x * n_y, -n_x * n_z
        length = math.sqrt(f_x * f_x + f_y * f_y + f_z * f_z)
    f_x, f_y, f_z = f_x / length, f_y / length, f_z / length
    left = (n_y * f_z - n_z * f_y, n_z * f_x - n_x * f_z, n_x * f_y - n_y * f_x)
    return np.array((f_x, f_y, f_z)), np.array(left)


@functools.lru_cache(maxsize=8)
def _profile_grid(width: int, height: int) -> tuple[npt.NDArray[np.int64], ...]:
    """The sampled columns, and the rows nearest (lowest) first, of the profile's walk."""
    column_step = max(1, width // PROFILE_COLUMNS)
    columns = np.arange(column_step // 2, width, column_step, dtype=np.int64)
    row_step = max(1, height // PROFILE_ROWS)
    rows = np.arange(height - 1, -1, -row_step, dtype=np.int64)
    return columns, rows


def ground_profile(
    depth: npt.NDArray[np.generic],
    sample: GroundSample,
    plane: GroundPlane,
    settings: GroundSettings,
    level: GroundPlane | None = None,
) -> GroundProfile | None:
    """The ground of this frame where it leaves `plane` (ramps), or None where it does not
    (by more than `PROFILE_DEADBAND` and `PROFILE_EVIDENCE_SIGMAS` of a bin's noise, in
    `PROFILE_EVIDENCE` bins in a row, in any column);
    `sample` is the camera's (`GroundSample.build`). `level`: the level floor (an IMU's),
    above which `max_slope` is the steepest floor; None: `plane` is taken as level."""
    if settings.max_slope <= 0.0:
        return None
    flat, scale = _kernel_depth(depth)
    columns = sample.profile_columns
    bins = max(1, math.ceil(settings.reach / PROFILE_BIN))
    heights = np.empty((columns.size, bins))
    lows = np.empty((columns.size, bins))
    evidence = np.empty(columns.size, dtype=np.int64)
    doubt = np.empty((columns.size, bins))
    falls = np.empty(columns.size)
    forward, left = _plane_axes(plane)
    # The plane's rise above level along its axes (sines): the up of the level floor.
    up = np.zeros(3) if level is None else level.vector
    tilt = np.array([forward @ up, left @ up])
    ground_kernel.profile(
        flat, scale, sample.width, columns, sample.profile_rows, sample.profile_x,
        sample.profile_y, np.array([*plane.normal, plane.offset]), forward, left,
        math.tan(settings.max_slope), tilt, settings.depth_noise, PROFILE_BIN,
        PROFILE_DEADBAND, PROFILE_EVIDENCE_SIGMAS, PROFILE_DOUBT_SIGMAS, heights, evidence,
        lows, doubt, falls,
    )  # fmt: skip
    if evidence.max(initial=0) < PROFILE_EVIDENCE:
        return None
    return GroundProfile(
        plane=plane,
        columns=columns,
        heights=heights,
        bin_size=PROFILE_BIN,
        lows=lows,
        falls=falls,
        noise_margin=SLOPE_NOISE_SIGMAS * settings.depth_noise,
        doubt=doubt,
    )


# Share of the learnt correction that fades per frame in which no floor is found: half of it
# each frame. What was learnt may be a ramp ahead, kept in the camera's frame, so it turns
# with the robot. Fading a tenth a frame, the tilt of a down ramp learnt at its crest outlived
# the robot's turns there to face the walls, and one terrain trial stalled on the platform.
FALLBACK_FADE = 0.5

# The mount check: over this many frames whose floor was found, a mean disagreement beyond
# these between the floor and the mounting is reported.
MOUNT_CHECK_FRAMES = 60
MOUNT_CHECK_HEIGHT = 0.02  # metres
MOUNT_CHECK_ANGLE = math.radians(1.0)


@dataclass(frozen=True)
class MountPose:
    """A camera's height, pitch and roll above a plane (radians; `GroundPlane`'s reading)."""

    height: float
    pitch: float
    roll: float

    @classmethod
    def above(cls, plane: GroundPlane) -> MountPose:
        return cls(plane.offset, plane.camera_pitch, plane.camera_roll)

    def describe(self) -> str:
        return (
            f'height {self.height:.3f} m, pitch {math.degrees(self.pitch):.2f} deg, '
            f'roll {math.degrees(self.roll):.2f} deg'
        )


class MountCheck:
    """Where the floor seen puts the camera, against where the mounting says it is, over
    the last `MOUNT_CHECK_FRAMES` frames whose floor was found (`disagreement`)."""

    def __init__(self) -> None:
        # Planes, read as poses only when asked (a diagnostics period, not every frame).
        self._pairs: deque[tuple[GroundPlane, GroundPlane]] = deque(maxlen=MOUNT_CHECK_FRAMES)

    def add(self, found: GroundPlane, prior: GroundPlane) -> None:
        self._pairs.append((found, prior))

    def means(self) -> tuple[MountPose, MountPose] | None:
        """The mean pose the floor gives and the mount gives; None before any frame."""
        if not self._pairs:
            return None
        found, prior = (
            MountPose(*np.mean([astuple(MountPose.above(p)) for p in planes], axis=0).tolist())
            for planes in zip(*self._pairs, strict=True)
        )
        return found, prior

    def disagreement(self) -> str | None:
        """A warning with both poses when, over MOUNT_CHECK_FRAMES frames, they disagree by
        more than MOUNT_CHECK_HEIGHT or MOUNT_CHECK_ANGLE; None otherwise."""
        means = self.means()
        if means is None or len(self._pairs) < MOUNT_CHECK_FRAMES:
            return None
        found, prior = means
        if (
            abs(found.height - prior.height) <= MOUNT_CHECK_HEIGHT
            and abs(found.pitch - prior.pitch) <= MOUNT_CHECK_ANGLE
            and abs(found.roll - prior.roll) <= MOUNT_CHECK_ANGLE
        ):
            return None
        return (
            f'the floor puts the camera at {found.describe()}; its mounting says '
            f'{prior.describe()} (means of the last {len(self._pairs)} frames): correct '
            'camera_height / camera_pitch / camera_roll or the TF (scanfuse calibrate BAG '
            'estimates them)'
        )


@dataclass
class GroundTracker:
    """One camera's floor, frame by frame: `update` gives the plane to measure heights from.

    What is learnt and smoothed is the floor's offset from the prior (a turn of its normal
    and a change of its height), not the plane itself: a prior that moves from frame to frame
    (the mounting tilted by an IMU's pitch and roll) carries the learnt mounting error with
    it, and the smoothing never lags behind the body's rocking.
    """

    settings: GroundSettings
    counts: GroundCounts = field(default_factory=GroundCounts)
    _estimate: GroundPlane | None = None
    _correction: tuple[Vector, float] | None = None  # rotation vector, offset change
    _sample: GroundSample | None = None
    _sample_camera: CameraModel | None = None
    profile: GroundProfile | None = None  # the last frame's, where the ground is no plane
    mount: MountCheck = field(default_factory=MountCheck)

    @property
    def estimate(self) -> GroundPlane | None:
        """The last frame's smoothed plane (None before the first frame)."""
        return self._estimate

    def update(
        self,
        depth: npt.NDArray[np.generic],
        camera: CameraModel,
        prior: GroundPlane,
        base: GroundPlane | None = None,
    ) -> GroundPlane:
        """The smoothed floor plane of this frame (the prior until floor is seen); `base`:
        the mounting's own plane when `prior` is it tilted by an IMU (`fit_ground`)."""
        if camera != self._sample_camera:
            self._sample = GroundSample.build(
                camera, prior, self.settings.samples, self.settings.hypotheses
            )
            self._sample_camera = camera
        assert self._sample is not None
        camera.check_depth(depth)
        self.counts.frames += 1
        start = prior if self._correction is None else _corrected(prior, *self._correction)
        found, reason = fit_ground(depth, self._sample, prior, start, self.settings, base)
        if found is None:
            self.counts.fell_back += 1
            self.counts.last_reason = reason
            if base is not None:
                # With an IMU the prior is the level floor, which on a ramp is not the floor
                # around the robot: the plane its wheels stand on is. Turning on a 1:8 ramp to
                # face its side wall, the floor the estimate fell back to rose 7 degrees
                # uphill across the view, and the ramp stood in the slab 0.6 m out.
                self._correction = _correction_between(prior, base)
            elif self._correction is not None:
                # What was learnt fades towards the prior while no floor is found: a plane
                # held from before a ramp's foot (tilted part way up it) is not kept for good.
                turn, lift = self._correction
                self._correction = (
                    _blend(turn, (0.0, 0.0, 0.0), FALLBACK_FADE),
                    (1.0 - FALLBACK_FADE) * lift,
                )
        else:
            self.counts.estimated += 1
            self.mount.add(found, prior)
            turn, lift = _correction_between(prior, found)
            if self._correction is not None:
                weight = self.settings.smoothing
                turn = _blend(self._correction[0], turn, weight)
                lift = (1.0 - weight) * self._correction[1] + weight * lift
            self._correction = (turn, lift)
        self._estimate = prior if self._correction is None else _corrected(prior, *self._correction)
        # With an IMU the prior is the level floor: slopes are judged above it.
        level = None if base is None else prior
        self.profile = ground_profile(depth, self._sample, self._estimate, self.settings, level)
        return self._estimate


def _correction_between(prior: GroundPlane, plane: GroundPlane) -> tuple[Vector, float]:
    """The rotation vector that turns the prior's normal onto the plane's (the least turn),
    and the change of offset.

    (Plain floats, as `_corrected`: numpy's per-call cost on 3-vectors was a third of the
    tracker's time a frame.)"""
    (a_x, a_y, a_z), (b_x, b_y, b_z) = prior.normal, plane.normal
    axis = (a_y * b_z - a_z * b_y, a_z * b_x - a_x * b_z, a_x * b_y - a_y * b_x)
    sine = math.hypot(*axis)
    angle = math.atan2(sine, a_x * b_x + a_y * b_y + a_z * b_z)
    scale = angle / sine if sine > 1e-15 else 0.0
    return (axis[0] * scale, axis[1] * scale, axis[2] * scale), plane.offset - prior.offset


def _corrected(prior: GroundPlane, turn: Vector, lift: float) -> GroundPlane:
    """The prior turned by the rotation vector `turn` (Rodrigues) and lifted by `lift`."""
    angle = math.hypot(*turn)
    n_x, n_y, n_z = prior.normal
    if angle > 1e-15:
        k_x, k_y, k_z = (component / angle for component in turn)
        cosine, sine = math.cos(angle), math.sin(angle)
        along = (k_x * n_x + k_y * n_y + k_z * n_z) * (1.0 - cosine)
        n_x, n_y, n_z = (
            n_x * cosine + (k_y * n_z - k_z * n_y) * sine + k_x * along,
            n_y * cosine + (k_z * n_x - k_x * n_z) * sine + k_y * along,
            n_z * cosine + (k_x * n_y - k_y * n_x) * sine + k_z * along,
        )
    length = math.hypot(n_x, n_y, n_z)
    return GroundPlane((n_x / length, n_y / length, n_z / length), prior.offset + lift)


def _blend(old: Vector, new: Vector, weight: float) -> Vector:
    """(1 - weight) old + weight new."""
    keep = 1.0 - weight
    return (
        keep * old[0] + weight * new[0],
        keep * old[1] + weight * new[1],
        keep * old[2] + weight * new[2],
    )
