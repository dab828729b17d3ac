"""Scan matching: the relative pose of two scans of one LiDAR, refined from odometry's guess.

Wheel odometry over-counts turns (wheel slip: about 3 % in the simulator, as real robots do),
and whatever is kept in the odometry frame (the obstacle memory) drifts with it. The walls a
2D LiDAR sees do not drift: matching the scan of now against an earlier one gives the
sensor's true move between them, and the stream keeps the difference as a correction.

Method: point-to-line ICP (Censi 2008, PL-ICP) with projective association (as PSM,
Diosi & Kleeman 2005): a current point, moved into the reference frame by the estimate, is
paired with the reference reading on its bearing, and its residual is its distance to the
line through that reading (the normal fitted over ~`NORMAL_SPAN` of neighbouring readings:
one reading's neighbours are millimetres apart, closer than the LiDAR's noise). Gauss-Newton
on (yaw, tx, ty), Huber-weighted and gated (pairs farther than the gate are left out: a
person who moved, a reading the other scan does not have), the gate shrinking each step.

Observability (the normal equations' information matrix H = J^T W J, yaw scaled by
`LEVER` metres so that its eigenvalues compare with those of translation): only the
directions with enough information are updated, the others keep odometry's value (a
corridor's length, a single wall's direction along it). When yaw itself is not observable,
too few readings pair, the residual stays large, or the correction exceeds what odometry can
plausibly be wrong by, the match is refused and odometry's guess is returned.
`DriftCorrection` also refuses a scan whose residual stands far above the recent matches'
(`DISTORTION_RATIO`): one swept while the wheels slipped, bent by its de-skew.
"""

from __future__ import annotations

import math
import statistics
from collections import deque
from dataclasses import dataclass
from enum import Enum
from typing import TYPE_CHECKING, Any

import numpy as np

from scanfuse.bearing import fast_atan2
from scanfuse.compiled import compiled
from scanfuse.errors import InputError
from scanfuse.motion import PlanarPose, wrap_angle
from scanfuse.scan import TWO_PI

if TYPE_CHECKING:
    import numpy.typing as npt

    from scanfuse.scan import Scan
    from scanfuse.transforms import Transform

    F64 = npt.NDArray[np.float64]

# Metres of a wall the line through a reading is fitted over (window of neighbours).
NORMAL_SPAN = 0.3
# Most neighbours on each side of a reading its line is fitted with.
MAX_NEIGHBOURS = 24
# A fitted line is kept when the points scatter across it at most this share of along it
# (sqrt of the eigenvalue ratio): corners and clutter are left out.
MAX_FLATNESS = 0.3
# Metres that make yaw (radians) comparable with translation in the information matrix:
# a yaw error of 1 rad moves a wall 1 m away by about 1 m.
LEVER = 1.0


class Refusal(str, Enum):
    """Why a match was refused (odometry's guess is kept)."""

    TOO_FEW_PAIRS = 'too few readings pair with the reference scan'
    RESIDUAL = 'the scans do not agree (residual too large after matching)'
    YAW_UNOBSERVABLE = 'the scene does not fix the turn (no walls across the view)'
    IMPLAUSIBLE = 'the correction is larger than odometry can plausibly be wrong by'
    DISTORTED = 'the residual is far above the recent matches (scan swept while wheels slipped)'
    TILTED = "the LiDAR's plane is tilted beyond what levelling it takes (or no IMU says how)"


@dataclass(frozen=True)
class MatchSettings:
    """Tuning of `match`; defaults suit a 360-degree LiDAR with centimetre noise indoors."""

    iterations: int = 8
    gate: float = 0.3  # metres: pairs farther from their line are left out (first step)
    gate_floor: float = 0.08  # metres: the gate shrinks by half a step down to this
    huber: float = 0.03  # metres: residuals beyond weigh less (Huber)
    min_pairs: int = 40  # pairs needed, and
    min_share: float = 0.3  # share of the current scan's readings that pair
    max_rms: float = 0.05  # metres: inlier residual RMS beyond which the scans disagree
    min_information: float = 10.0  # effective pairs a direction needs to be corrected, and
    min_ratio: float = 0.02  # share of the best direction's information
    turn_share: float = 0.2  # a yaw correction is plausible up to this share of the turn
    turn_floor: float = 0.1  # radians, plus this: wheels slip that much when a turn reverses
    shift_share: float = 0.2  # a translation correction: this share of the move
    shift_floor: float = 0.1  # metres, plus this
    max_tilt: float = math.radians(2.0)  # radians: a plane tilted further is levelled first
    # Radians: a plane tilted further is not matched even levelled (a 1:8 ramp is 7.1).
    max_levelled_tilt: float = math.radians(12.0)

    def __post_init__(self) -> None:
        if self.iterations < 1:
            msg = f'scan matching needs at least 1 iteration, got {self.iterations}'
            raise InputError(msg)
        if self.min_pairs < 3:
            msg = f'scan matching min_pairs must be >= 3 (three unknowns), got {self.min_pairs}'
            raise InputError(msg)
        for name in (
            'gate', 'gate_floor', 'huber', 'max_rms', 'min_information',
            'turn_floor', 'shift_floor', 'max_tilt', 'max_levelled_tilt',
        ):  # fmt: skip
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                msg = f'scan matching {name} must be a positive finite number, got {value}'
                raise InputError(msg)
        for name in ('min_share', 'min_ratio', 'turn_share', 'shift_share'):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                msg = f'scan matching {name} must be a share in [0, 1], got {value}'
                raise InputError(msg)
        if self.gate_floor > self.gate:
            msg = f'scan matching gate_floor {self.gate_floor} m exceeds gate {self.gate} m'
            raise InputError(msg)


@dataclass(frozen=True)
class RelativePose:
    """Points of the current scan to the reference scan's frame: p_ref = R(yaw) p + (tx, ty)."""

    yaw: float
    tx: float
    ty: float

    def is_finite(self) -> bool:
        return math.isfinite(self.yaw) and math.isfinite(self.tx) and math.isfinite(self.ty)


@dataclass(frozen=True)
class Match:
    """The refined relative pose, or odometry's guess with the reason it was refused."""

    pose: RelativePose
    refused: Refusal | None
    pairs: int
    rms: float  # metres, inlier residual RMS (NaN: no pairs)
    fixed: int  # directions corrected (3: yaw and translation, 1: yaw alone, 0: refused)

    @property
    def accepted(self) -> bool:
        return self.refused is None


@dataclass(frozen=True)
class Reference:
    """A scan prepared to be matched against: points, their lines' normals, its grid."""

    x: F64  # a point of each reading's line (NaN: no line fitted there)
    y: F64
    nx: F64  # the line's unit normal
    ny: F64
    lined: npt.NDArray[np.bool_]  # readings with a line
    angle_min: float
    increment: float
    count: int
    lines: int  # readings with a line


def _points_loop(
    ranges: Any, angle_min: float, increment: float, low: float, high: float, x: Any, y: Any
) -> int:
    """Readings within [low, high] as points (x, y), NaN else; returns how many."""
    valid = 0
    for i in range(ranges.shape[0]):
        r = float(ranges[i])
        if np.isfinite(r) and low <= r <= high:
            angle = angle_min + i * increment
            x[i] = r * math.cos(angle)
            y[i] = r * math.sin(angle)
            valid += 1
        else:
            x[i] = np.nan
            y[i] = np.nan
    return valid


_POINTS = compiled(_points_loop)


# Metres above the base's origin (its ground) that a levelled reading must stand: lower ones
# are the floor, which a tilted plane meets (`levelled`).
LEVELLED_FLOOR = 0.05


def levelled(scan: Scan, tilt: F64, base_to_laser: Transform) -> Scan:
    """`scan`, taken with the base tilted by `tilt` (3x3: the base's axes in a level frame of
    the same heading, an IMU's roll and pitch; or N x 3 x 3, one per reading: the tilt when
    its beam was measured), as a level LiDAR at `base_to_laser` would have it: each
    reading's point placed in the level frame, readings lower than `LEVELLED_FLOOR` above
    the base's origin left out (the floor), the rest put in the slot of their horizontal
    bearing, the nearest per slot. Upright walls stay where they are: a tilted plane slices
    them at other heights, and makes them longer along the tilt."""
    x, y = points(scan)
    sensor = base_to_laser.matrix
    p = sensor[:3, :3] @ np.vstack([x, y, np.zeros_like(x)]) + sensor[:3, 3:4]
    level = tilt @ p if tilt.ndim == 2 else np.einsum('nij,jn->in', tilt, p)
    # Back into the level sensor's frame: its mounting's heading, at its mounted place.
    yaw = math.atan2(sensor[1, 0], sensor[0, 0])
    cos, sin = math.cos(yaw), math.sin(yaw)
    dx, dy = level[0] - sensor[0, 3], level[1] - sensor[1, 3]
    hx, hy = cos * dx + sin * dy, -sin * dx + cos * dy
    with np.errstate(invalid='ignore'):
        keep = np.isfinite(hx) & (level[2] >= LEVELLED_FLOOR)
    bearing = np.arctan2(hy[keep], hx[keep])
    reach = np.hypot(hx[keep], hy[keep])
    count = len(scan)
    # Radians from angle_min the way the scan turns (clockwise when its increment is
    # negative), from half a slot before it: a slot's bearing, whatever angle_min's turn.
    step, turn = abs(scan.angle_increment), math.copysign(1.0, scan.angle_increment)
    along = np.mod(turn * (bearing - scan.angle_min) + step / 2, TWO_PI) - step / 2
    slot = np.round(along / step).astype(np.int64)
    full = scan.grid.full_turn
    slot = np.mod(slot, count) if full else slot
    inside = (slot >= 0) & (slot < count)
    ranges = np.full(count, np.inf)
    np.minimum.at(ranges, slot[inside], reach[inside])
    ranges[~np.isfinite(ranges)] = np.nan
    return scan.with_ranges(ranges.astype(np.float32))


def points(scan: Scan) -> tuple[F64, F64]:
    """The scan's readings (within range_min..range_max) as sensor-frame points, NaN else."""
    x = np.empty(len(scan))
    y = np.empty(len(scan))
    _POINTS(scan.ranges, scan.angle_min, scan.angle_increment, scan.range_min, scan.range_max, x, y)
    return x, y


def _normals_loop(
    x: Any, y: Any, increment: float, full: bool, span: float, most: int, flat: float,
    nx: Any, ny: Any, cx: Any, cy: Any,
) -> int:  # fmt: skip
    """Line through each reading's neighbours within `span` metres (PCA of the window:
    normal (nx, ny) the eigenvector of the scatter's smaller eigenvalue, through the
    window's centroid (cx, cy), which averages the readings' noise away); NaN when the
    window is not a line (a corner, a gap, clutter). Returns how many readings have a line."""
    count = x.shape[0]
    lines = 0
    for j in range(count):
        nx[j] = np.nan
        ny[j] = np.nan
        cx[j] = np.nan
        cy[j] = np.nan
        if not np.isfinite(x[j]):
            continue
        r = math.sqrt(x[j] * x[j] + y[j] * y[j])
        half = int(0.5 * span / max(r * abs(increment), 1e-6) + 0.5)
        half = max(2, min(most, half))
        # One pass of moments about the reading itself (small numbers: no cancellation).
        n = 0
        sx = 0.0
        sy = 0.0
        sxx = 0.0
        sxy = 0.0
        syy = 0.0
        for k in range(-half, half + 1):
            i = j + k
            if full:
                i = i % count
            elif i < 0 or i >= count:
                continue
            if not np.isfinite(x[i]):
                continue
            dx = x[i] - x[j]
            dy = y[i] - y[j]
            if dx * dx + dy * dy > span * span:
                continue  # across a gap: another surface
            n += 1
            sx += dx
            sy += dy
            sxx += dx * dx
            sxy += dx * dy
            syy += dy * dy
        if n < 4:
            continue
        mx = sx / n
        my = sy / n
        sxx = sxx / n - mx * mx
        sxy = sxy / n - mx * my
        syy = syy / n - my * my
        # Eigenvalues of [[sxx, sxy], [sxy, syy]]; the line runs along the larger one.
        mean = 0.5 * (sxx + syy)
        spread = math.sqrt(0.25 * (sxx - syy) ** 2 + sxy * sxy)
        big = mean + spread
        small = mean - spread
        if big <= 0.0 or small > flat * flat * big:
            continue
        along = 0.5 * math.atan2(2.0 * sxy, sxx - syy)
        nx[j] = -math.sin(along)
        ny[j] = math.cos(along)
        cx[j] = x[j] + mx
        cy[j] = y[j] + my
        lines += 1
    return lines


_NORMALS = compiled(_normals_loop)


def reference(scan: Scan) -> Reference:
    """`scan` prepared as the reference of later matches (its lines fitted once)."""
    x, y = points(scan)
    increment = float(scan.angle_increment)
    full = scan.grid.full_turn
    nx, ny, cx, cy = (np.empty_like(x) for _ in range(4))
    lines = int(
        _NORMALS(x, y, increment, full, NORMAL_SPAN, MAX_NEIGHBOURS, MAX_FLATNESS, nx, ny, cx, cy)
    )
    return Reference(
        cx, cy, nx, ny, np.isfinite(nx), float(scan.angle_min), increment, len(scan), lines
    )


def _accumulate_loop(
    qx: Any, qy: Any, nx: Any, ny: Any, lined: Any, angle_min: float, increment: float,
    count: int, px: Any, py: Any, yaw: float, tx: float, ty: float, gate: float, huber: float,
    lever: float, out: Any,
) -> None:  # fmt: skip
    """Normal equations of point-to-line ICP at (yaw, tx, ty) (Censi 2008, eq. 6 linearised):
    out[0:6] H (upper triangle, yaw scaled by `lever`), out[6:9] J^T W e, out[9] pairs,
    out[10] sum of squared inlier residuals. A point (all finite) pairs with the reference
    reading whose slot holds its bearing (projective association), when that reading has a
    line (`lined`) and the point lies within `gate` of it."""
    for k in range(11):
        out[k] = 0.0
    c = math.cos(yaw)
    s = math.sin(yaw)
    step = abs(increment)
    sign = 1.0 if increment > 0.0 else -1.0
    for i in range(px.shape[0]):
        x = px[i]
        y = py[i]
        rx = c * x - s * y
        ry = s * x + c * y
        ux = rx + tx
        uy = ry + ty
        # fast_atan2 is within 2e-4 rad: at worst the neighbouring reading's line, which
        # is the same wall.
        offset = (sign * (fast_atan2(uy, ux) - angle_min) + 0.5 * step) % (2.0 * math.pi)
        j = int(offset / step)
        if j >= count or not lined[j]:
            continue
        ax = nx[j]
        ay = ny[j]
        e = ax * (ux - qx[j]) + ay * (uy - qy[j])
        if abs(e) > gate:
            continue
        w = 1.0 if abs(e) <= huber else huber / abs(e)
        # d e / d yaw = n . (dR/dyaw p) = n . (-ry, rx); scaled by the lever.
        ja = (ax * -ry + ay * rx) / lever
        out[0] += w * ja * ja
        out[1] += w * ja * ax
        out[2] += w * ja * ay
        out[3] += w * ax * ax
        out[4] += w * ax * ay
        out[5] += w * ay * ay
        out[6] += w * ja * e
        out[7] += w * ax * e
        out[8] += w * ay * e
        out[9] += 1.0
        out[10] += e * e


_ACCUMULATE = compiled(_accumulate_loop, fastmath=True)


def match(
    ref: Reference,
    current: Scan,
    prediction: RelativePose,
    settings: MatchSettings | None = None,
) -> Match:
    """The pose of `current` in `ref`'s frame, starting from odometry's `prediction`.

    Refused (the prediction returned, `refused` saying why) when the match cannot be
    trusted; see the module docstring.
    """
    if not prediction.is_finite():
        msg = f'scan matching needs a finite predicted pose, got {prediction}'
        raise InputError(msg)
    settings = settings or MatchSettings()
    px, py = points(current)
    valid = np.isfinite(px)
    px, py = px[valid], py[valid]
    readings = px.size
    if readings < settings.min_pairs or ref.lines < settings.min_pairs:
        return Match(prediction, Refusal.TOO_FEW_PAIRS, 0, math.nan, 0)
    out = np.zeros(11)
    yaw, tx, ty = prediction.yaw, prediction.tx, prediction.ty
    gate = settings.gate
    basis: F64 | None = None
    for _ in range(settings.iterations):
        _ACCUMULATE(
            ref.x, ref.y, ref.nx, ref.ny, ref.lined, ref.angle_min, ref.increment, ref.count,
            px, py, yaw, tx, ty, gate, settings.huber, LEVER, out,
        )  # fmt: skip
        if _too_few(int(out[9]), readings, settings):
            return Match(prediction, Refusal.TOO_FEW_PAIRS, int(out[9]), math.nan, 0)
        information = _information(out)
        if basis is None:
            # The directions the scene fixes, chosen once at odometry's guess: updating a
            # direction the walls do not fix would follow noise.
            basis = _observable(information, settings)
            if basis is None:
                return Match(prediction, Refusal.YAW_UNOBSERVABLE, int(out[9]), math.nan, 0)
        reduced = basis.T @ information @ basis
        step = -basis @ np.linalg.solve(reduced, basis.T @ out[6:9])
        yaw += float(step[0]) / LEVER
        tx += float(step[1])
        ty += float(step[2])
        gate = max(settings.gate_floor, 0.5 * gate)
        if max(abs(step[0]), abs(step[1]), abs(step[2])) < 1e-5:
            break
    # The residual at the final estimate, within the final gate.
    _ACCUMULATE(
        ref.x, ref.y, ref.nx, ref.ny, ref.lined, ref.angle_min, ref.increment, ref.count,
        px, py, yaw, tx, ty, gate, settings.huber, LEVER, out,
    )  # fmt: skip
    assert basis is not None  # at least one iteration ran
    return _verdict(
        prediction, RelativePose(wrap_angle(yaw), tx, ty), out, readings, basis.shape[1], settings
    )


def _verdict(
    prediction: RelativePose,
    estimate: RelativePose,
    out: F64,
    readings: int,
    fixed: int,
    settings: MatchSettings,
) -> Match:
    """The estimate, or the prediction when the final pairs do not support it."""
    pairs = int(out[9])
    if _too_few(pairs, readings, settings):
        return Match(prediction, Refusal.TOO_FEW_PAIRS, pairs, math.nan, 0)
    rms = math.sqrt(out[10] / pairs)
    if rms > settings.max_rms:
        return Match(prediction, Refusal.RESIDUAL, pairs, rms, 0)
    if not _plausible(prediction, estimate, settings):
        return Match(prediction, Refusal.IMPLAUSIBLE, pairs, rms, 0)
    return Match(estimate, None, pairs, rms, fixed)


def _too_few(pairs: int, readings: int, settings: MatchSettings) -> bool:
    return pairs < settings.min_pairs or pairs < settings.min_share * readings


def _information(out: F64) -> F64:
    a, b, c, d, e, f = out[0:6]
    return np.array([[a, b, c], [b, d, e], [c, e, f]])


def _observable(information: F64, settings: MatchSettings) -> F64 | None:
    """Unit directions (columns, in (yaw * LEVER, tx, ty)) with enough information; None
    when yaw is not among them. A direction is kept when its eigenvalue has both
    `min_information` effective pairs and `min_ratio` of the largest."""
    values, vectors = np.linalg.eigh(information)
    keep = (values >= settings.min_information) & (values >= settings.min_ratio * values[-1])
    basis = vectors[:, keep]
    if basis.shape[1] == 0:
        return None
    if basis.shape[1] < 3:
        # Yaw is fixed only if it lies (nearly) within the kept directions; otherwise a
        # turn and a shift along the unfixed direction trade against each other.
        if float(np.linalg.norm(basis[0, :])) < 0.9:
            return None
        if basis.shape[1] == 2:
            return basis
        return np.array([[1.0], [0.0], [0.0]])  # yaw alone: translation stays odometry's
    return basis


def _plausible(prediction: RelativePose, estimate: RelativePose, settings: MatchSettings) -> bool:
    turn = abs(wrap_angle(estimate.yaw - prediction.yaw))
    shift = math.hypot(estimate.tx - prediction.tx, estimate.ty - prediction.ty)
    moved = math.hypot(prediction.tx, prediction.ty)
    return turn <= settings.turn_share * abs(prediction.yaw) + settings.turn_floor and (
        shift <= settings.shift_share * moved + settings.shift_floor
    )


# The reference scan is kept until the sensor has moved this far from it (radians, metres):
# matching every scan against the one before would add each match's noise to the
# correction, scan after scan; against a kept scan a standing robot adds none.
KEYFRAME_TURN = 0.35
KEYFRAME_SHIFT = 0.3
# A scan swept while the wheels slipped (a turn starting or reversing) was de-skewed with the
# slip's wrong turn, and bent so its match is off by about the slip (measured in the
# simulator: 0.05 rad, at twice the median residual of the scans around it). Such a scan's
# match is refused when its residual exceeds this many times the median of the last
# `RECENT_MATCHES`; the reference is kept, so the next, straight scan recovers the slip.
DISTORTION_RATIO = 1.6
RECENT_MATCHES = 16
# Level scans after a tilted stretch (a ramp) are also matched against the last reference a
# level scan made (the anchor), at most this many of them: see `DriftCorrection`.
ANCHOR_TRIES = 5


@dataclass
class _Keyframe:
    ref: Reference
    frame_id: str
    odometry: PlanarPose  # the base's odometry pose at the reference scan
    corrected: PlanarPose  # the same, corrected
    stamp_ns: int  # the reference scan's


class DriftCorrection:
    """A planar transform C (corrected odom <- odom) kept up to date by scan matching.

    Each scan of one LiDAR is matched against a kept reference scan (`KEYFRAME_TURN`,
    `KEYFRAME_SHIFT`), starting from odometry's move between them. With the match's move
    M the base's corrected pose is Q = Q_ref M, and C = Q P^-1 (P: the odometry pose), so
    that C P follows the LiDAR's walls where odometry drifts; with exact odometry M is
    odometry's move and C stays where it was. A refused match keeps C and starts a new
    reference at the current scan.

    A scan whose plane is tilted beyond `max_tilt` (an IMU's word) is levelled first
    (`levelled`): tilted, the plane of a LiDAR 0.3 m up meets the floor 8.6 m off at 2
    degrees and 2.4 m off at 7 (a 1:8 ramp), and it slices the walls at other heights than
    the reference did; on the simulator's ramps, matching such scans as they were moved the
    corrected pose 0.13 m along the ramp's corridor within one turn at its crest. Levelled
    by the IMU's roll and pitch, the floor is left out and the upright walls stand where a
    level LiDAR would see them, so the turns the wheels slip on a ramp are matched away as
    on the level. Beyond `max_levelled_tilt`, or with no IMU, the scan is not matched: C
    is kept and the next level scan starts a new reference.

    Between a ramp's walls the levelled scans fix the turn and the shift across the
    corridor, not the distance along it, which stays odometry's while the wheels slip
    climbing (0.17 m up the simulator's 1:8 ramp on one drive, kept in the memory's frame
    from then on). So the reference of the last level scan stays as the anchor across a
    tilted stretch, and the first level scans after it (`ANCHOR_TRIES`) are matched
    against it too: level to level, the walls at either end of the ramp fix the distance
    again. A match that fixes all three directions re-anchors C there; otherwise the scan
    goes on against the current reference as before.
    """

    def __init__(self, settings: MatchSettings | None = None) -> None:
        self.settings = settings or MatchSettings()
        self.correction = PlanarPose(0.0, 0.0, 0.0)
        self.matched = 0
        self.refused: dict[Refusal, int] = {}
        self.last: Match | None = None
        self.anchored = 0  # level scans re-anchored to the level reference before a tilt
        # The stamp of the anchor the last re-anchoring matched: what was placed in the
        # corrected frame since then was placed on the frame that re-anchoring moved.
        self.anchored_since_ns: int | None = None
        self._keyframe: _Keyframe | None = None
        self._anchor: _Keyframe | None = None  # the last level scan's reference
        self._anchor_tries = 0
        self._recent: deque[float] = deque(maxlen=RECENT_MATCHES)  # residuals of late matches

    def reset(self) -> None:
        """Back to odometry (C the identity): the odometry frame itself changed."""
        self.correction = PlanarPose(0.0, 0.0, 0.0)
        self._keyframe = None
        self._anchor = None
        self.last = None
        self._recent.clear()

    def corrected(self, pose: PlanarPose) -> PlanarPose:
        """An odometry pose of the base in the corrected frame: C composed with it."""
        return self.correction.compose(pose)

    def update(
        self,
        scan: Scan,
        base: PlanarPose,
        base_to_laser: Transform,
        *,
        tilt: float = 0.0,
        base_tilt: F64 | None = None,
    ) -> Match | None:
        """Take the LiDAR `scan` (every beam at its stamp) with the base's odometry pose
        `base` at that stamp and its plane's `tilt` from level (radians; 0: level or
        unknown); `base_tilt`, the base's roll and pitch (`levelled`: one, or one per
        reading), lets a plane tilted beyond `max_tilt` be matched levelled. Returns the
        match (None: the first scan, a reference)."""
        if not base.is_finite():
            msg = f'drift correction needs a finite odometry pose, got {base}'
            raise InputError(msg)
        settings = self.settings
        level = tilt <= settings.max_tilt
        if settings.max_tilt < tilt <= settings.max_levelled_tilt and base_tilt is not None:
            scan = levelled(scan, base_tilt, base_to_laser)
            tilt = 0.0
        if not tilt <= settings.max_tilt:
            self._keyframe = None
            self.refused[Refusal.TILTED] = self.refused.get(Refusal.TILTED, 0) + 1
            self.last = Match(RelativePose(0.0, 0.0, 0.0), Refusal.TILTED, 0, math.nan, 0)
            return self.last
        sensor = base_to_laser.matrix
        anchor = self._anchor
        if level and anchor is not None and anchor is not self._keyframe:
            anchored = self._anchored(anchor, scan, base, sensor)
            if anchored is not None:
                return anchored
        key = self._keyframe
        if key is None or key.frame_id != scan.frame_id:
            self._new_keyframe(scan, base, self.corrected(base), level=level)
            return None
        prediction = _predicted(key, base, sensor)
        result = self._screened(match(key.ref, scan, prediction, self.settings), prediction)
        self.last = result
        if result.refused is Refusal.DISTORTED:
            self.refused[result.refused] = self.refused.get(result.refused, 0) + 1
            return result  # C and the reference stay: the next scan matches against it
        if not result.accepted:
            assert result.refused is not None
            self.refused[result.refused] = self.refused.get(result.refused, 0) + 1
            self._new_keyframe(scan, base, self.corrected(base), level=level)
            return result
        self.matched += 1
        true_move = _base_move(result.pose, sensor)
        corrected = key.corrected.compose(true_move)
        self.correction = corrected.compose(base.inverse())
        if (
            abs(true_move.yaw) > KEYFRAME_TURN
            or math.hypot(true_move.x, true_move.y) > KEYFRAME_SHIFT
        ):
            self._new_keyframe(scan, base, corrected, level=level)
        return result

    def _anchored(
        self, anchor: _Keyframe, scan: Scan, base: PlanarPose, sensor: F64
    ) -> Match | None:
        """The level `scan` matched against the anchor, C re-anchored there and both
        references moved on to it; None (the anchor dropped after `ANCHOR_TRIES` level
        scans) when the match does not fix all three directions."""
        if anchor.frame_id == scan.frame_id:
            # From the corrected poses: the levelled matches since fixed the turns the
            # wheels slipped at the ramp's foot, which odometry's own move still holds.
            move = anchor.corrected.between(self.corrected(base))
            result = match(anchor.ref, scan, _sensor_move(move, sensor), self.settings)
            if result.accepted and result.fixed == 3:
                self.matched += 1
                self.anchored += 1
                self.anchored_since_ns = anchor.stamp_ns
                self.last = result
                corrected = anchor.corrected.compose(_base_move(result.pose, sensor))
                self.correction = corrected.compose(base.inverse())
                self._anchor = None  # the new reference is the anchor from now on
                self._new_keyframe(scan, base, corrected, level=True)
                return result
        self._anchor_tries += 1
        if self._anchor_tries >= ANCHOR_TRIES or anchor.frame_id != scan.frame_id:
            self._anchor = None  # the next level reference is the anchor
        return None

    def _new_keyframe(
        self, scan: Scan, base: PlanarPose, corrected: PlanarPose, *, level: bool
    ) -> None:
        """`scan` the reference from now on; a level one also the anchor, unless the
        anchor is one from before a tilted stretch still being tried (`_anchored`)."""
        key = _Keyframe(reference(scan), scan.frame_id, base, corrected, scan.stamp_ns)
        if level and (self._anchor is None or self._anchor is self._keyframe):
            self._anchor = key
            self._anchor_tries = 0
        self._keyframe = key

    def _screened(self, result: Match, prediction: RelativePose) -> Match:
        """`result`, or refused as `DISTORTED` when its residual is far above the recent
        matches' (the window holds refused ones too, so that a scene where every match is
        worse, more clutter, raises the median instead of refusing from then on)."""
        if not result.accepted:
            return result
        recent = self._recent
        typical = statistics.median(recent) if len(recent) >= RECENT_MATCHES // 2 else math.inf
        recent.append(result.rms)
        if result.rms > DISTORTION_RATIO * typical:
            return Match(prediction, Refusal.DISTORTED, result.pairs, result.rms, 0)
        return result


def _predicted(key: _Keyframe, base: PlanarPose, sensor: F64) -> RelativePose:
    """Odometry's move of the sensor (mounted at `sensor` on the base) from `key` to `base`,
    as points of the current scan to the reference's frame."""
    return _sensor_move(key.odometry.between(base), sensor)


def _sensor_move(move: PlanarPose, sensor: F64) -> RelativePose:
    """The base's `move` as the sensor's (mounted at `sensor`): S^-1 M S."""
    predicted = np.linalg.inv(sensor) @ move.matrix() @ sensor
    return RelativePose(
        math.atan2(predicted[1, 0], predicted[0, 0]),
        float(predicted[0, 3]),
        float(predicted[1, 3]),
    )


def _base_move(pose: RelativePose, sensor: F64) -> PlanarPose:
    """The sensor's matched move seen from the base (S T S^-1; exact for a sensor whose z
    axis is vertical, up or down, as `PlanarMotion.of_base_move`)."""
    moved = sensor @ PlanarPose(pose.tx, pose.ty, pose.yaw).matrix() @ np.linalg.inv(sensor)
    return PlanarPose(float(moved[0, 3]), float(moved[1, 3]), math.atan2(moved[1, 0], moved[0, 0]))
