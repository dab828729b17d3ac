"""The compiled floor fit of `ground.fit_ground`: one pass of plain loops, no temporaries.

numpy spends more time dispatching the fit's few dozen operations on ~1500 points than
computing them (about 0.5 ms a frame, more than the obstacle scan of a 640x480 frame);
these loops do the same arithmetic in tens of microseconds. Without numba they run as
plain Python (`compiled`), slowly but with the same numbers.

The refinement is a least-squares fit of the inliers' heights above the current plane as
a + b u + c v, (u, v) their coordinates along two axes in the plane: for planes within a
few degrees of each other it is the total least-squares plane to far below a millimetre,
and it needs no eigen-solver (numba's needs SciPy).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from scanfuse.compiled import compiled

# `fit` writes its result into `out`: normal (3), offset, inlier count, least spread, status.
OK, FEW_CANDIDATES, FEW_INLIERS, ALONG_A_LINE, OUT_OF_BOUNDS = 0, 1, 2, 3, 4
# The plane is fitted to the floor candidates within FIT_RUN_LONG metres (horizontally from
# the camera) beyond the NEAREST_SHARE quantile of their runs, and within FIT_RUN.
FIT_RUN = 0.5
FIT_RUN_LONG = 1.25
# The long run's plane is kept when it is within BEND radians and BEND_OFFSET metres of the
# short run's: the floor is one plane that far.
BEND = math.radians(1.0)
BEND_OFFSET = 0.01
NEAREST_SHARE = 0.05
# Hypotheses are scored on every SCORE_STRIDE-th candidate; the refinement uses them all.
SCORE_STRIDE = 2
# Random triples stop once one of them holds only inliers with this probability, given the
# best hypothesis's share of inliers w: after log(1 - p) / log(1 - w^3) of them (adaptive
# RANSAC, Hartley and Zisserman, Algorithm 4.5). Where the floor fills the candidates (the
# tracked plane holds 90 % of them), 6 triples; where a box or a wall's foot takes half, all.
CONFIDENCE = 0.999
# Metres above the plane (beyond the depth's noise) an inlier of the refinement may lie.
ABOVE = 0.003
# Metres above the steepest floor's rise (beyond 3 sigma of noise) a point of an obstacle's
# face stands in the profile's walk: clear of a noisy ramp's own points.
FACE = 0.01
# Sampled columns either side a profile bin without ground looks for one that saw it.
FILL_COLUMNS = 2
# Bins in a row a column's ground must have stood off the plane (as many as make a frame's
# profile at all, `ground.PROFILE_EVIDENCE`) before the bin of an obstacle's face goes on at
# its last rise: with one, a flat floor's noise 2-3 m out lifted the ground under low boxes.
RAMP_BINS = 3
# The steepest floor, widened by the plane's tilt from level (`_profile`), at most this.
MAX_WIDENED = math.radians(60.0)


def _axes(normal: Any) -> tuple[Any, Any]:
    """Two unit vectors orthogonal to `normal` and to each other."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    first = np.cross(normal, helper)
    first /= math.sqrt(first[0] ** 2 + first[1] ** 2 + first[2] ** 2)
    return first, np.cross(normal, first)


def _determinant(m: Any) -> float:
    value: float = (
        m[0, 0] * (m[1, 1] * m[2, 2] - m[1, 2] * m[2, 1])
        - m[0, 1] * (m[1, 0] * m[2, 2] - m[1, 2] * m[2, 0])
        + m[0, 2] * (m[1, 0] * m[2, 1] - m[1, 1] * m[2, 0])
    )
    return value


def _refine(
    points: Any, tolerance: Any, noise: Any, count: int, plane: Any, out: Any, lowest: bool
) -> int:
    """Least squares on the inliers of `plane` (normal, offset): the refined plane into
    `plane`, the least spread of the inliers along the plane's axes into out[5]; returns the
    number of inliers.

    An inlier lies at most its `tolerance` below the plane and, with `lowest`, only its
    depth noise (`noise`, 3 sigma) plus `ABOVE` above it: the floor is the lowest surface,
    and a slope or an obstacle's foot that rises out of it would otherwise tilt the fit
    towards itself a little more with every refinement. Without, as far above as below:
    the first refinement of a hypothesis (the prior, say) that is a few centimetres off the
    floor everywhere."""
    normal = plane[:3].copy()
    first, second = axes(normal)
    # Normal equations of h = a + b u + c v, and the (u, v) moments for the spread, summed
    # in scalars (array elements are stored back every point: twice the loop's time).
    s_1 = s_u = s_v = s_uu = s_uv = s_vv = s_h = s_hu = s_hv = 0.0
    inliers = 0
    for i in range(count):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        h = normal[0] * x + normal[1] * y + normal[2] * z + plane[3]
        if h < -tolerance[i] or h > (noise[i] + ABOVE if lowest else tolerance[i]):
            continue
        u = first[0] * x + first[1] * y + first[2] * z
        v = second[0] * x + second[1] * y + second[2] * z
        inliers += 1
        s_1 += 1.0
        s_u += u
        s_v += v
        s_uu += u * u
        s_uv += u * v
        s_vv += v * v
        s_h += h
        s_hu += h * u
        s_hv += h * v
    if inliers < 3:
        return inliers
    m = np.empty((3, 3))
    m[0, 0], m[0, 1], m[0, 2] = s_1, s_u, s_v
    m[1, 1], m[1, 2], m[2, 2] = s_uu, s_uv, s_vv
    rhs = np.array([s_h, s_hu, s_hv])
    n = m[0, 0]
    mean_u, mean_v = m[0, 1] / n, m[0, 2] / n
    var_u = m[1, 1] / n - mean_u * mean_u
    var_v = m[2, 2] / n - mean_v * mean_v
    cov = m[1, 2] / n - mean_u * mean_v
    # The smaller eigenvalue of the 2 x 2 covariance of (u, v): the narrower spread.
    half_trace = 0.5 * (var_u + var_v)
    gap = math.sqrt(max(0.0, 0.25 * (var_u - var_v) ** 2 + cov * cov))
    out[5] = math.sqrt(max(0.0, half_trace - gap))
    m[1, 0], m[2, 0], m[2, 1] = m[0, 1], m[0, 2], m[1, 2]
    determinant = determinant3(m)
    if abs(determinant) < 1e-12 * max(1.0, n**3):
        out[5] = 0.0
        return inliers
    # Cramer's rule (numba's np.linalg needs SciPy's LAPACK).
    solution = np.empty(3)
    for column in range(3):
        swapped = m.copy()
        swapped[:, column] = rhs
        solution[column] = determinant3(swapped) / determinant
    # h_new = h - (a + b u + c v) = (normal - b first - c second) . p + offset - a
    new_normal = normal - solution[1] * first - solution[2] * second
    length = math.sqrt(new_normal[0] ** 2 + new_normal[1] ** 2 + new_normal[2] ** 2)
    plane[:3] = new_normal / length
    plane[3] = (plane[3] - solution[0]) / length
    return inliers


def _fit(
    depth: Any,
    scale: float,
    indices: Any,
    rays: Any,
    prior: Any,
    start: Any,
    base: Any,
    max_offset: float,
    max_tilt: float,
    reach: float,
    inlier_distance: float,
    noise: float,
    draws: Any,
    min_points: int,
    min_spread: float,
    out: Any,
) -> None:
    """`ground.fit_ground`'s arithmetic: see that module's docstring. `depth` is the flat
    image (uint16 millimetres, 0 invalid, with `scale` 0.001; float32 metres, NaN invalid,
    with `scale` 1); `prior`, `start` are (normal, offset); `draws` (hypotheses x 3) numbers
    in [0, 1) pick each hypothesis's three candidates. `base` (normal, offset) is the plane
    the robot's wheels stand on when `prior` is tilted by an IMU (on a ramp the level floor the
    IMU gives is the ramp's slope away from it): a plane within the bounds of either is
    admissible. Without an IMU it is the prior. `out` as the module's constants say."""
    size = min(indices.size, rays.shape[0])
    points = np.empty((size, 3))
    tolerance = np.empty(size)
    noise_band = np.empty(size)
    runs = np.empty(size)
    sin_tilt = math.sin(max_tilt)
    count = 0
    for i in range(size):
        index = indices[i]
        if not 0 <= index < depth.size:
            continue
        z = np.float64(depth[index]) * scale
        if not z > 0.0:  # 0 (no return) and NaN
            continue
        x, y = rays[i, 0] * z, rays[i, 1] * z
        distance = math.sqrt(x * x + y * y + z * z)
        if not distance <= reach:  # also NaN and Inf (a depth of +Inf)
            continue
        slope = prior[0] * rays[i, 0] + prior[1] * rays[i, 1] + prior[2]
        # Noise along the ray moves the height by |slope| per metre of depth.
        spread = 3.0 * noise * z * z * abs(slope)
        allowed = inlier_distance + spread
        height = slope * z + prior[3]
        bound = max_offset + distance * sin_tilt + allowed
        if abs(height) > bound:
            on_base = (base[0] * rays[i, 0] + base[1] * rays[i, 1] + base[2]) * z + base[3]
            if abs(on_base) > bound:
                continue
        points[count, 0], points[count, 1], points[count, 2] = x, y, z
        tolerance[count] = allowed
        noise_band[count] = spread
        drop = height - prior[3]  # below the camera, along the prior's normal
        runs[count] = math.sqrt(max(distance * distance - drop * drop, 0.0))
        count += 1
    if count == 0:
        out[:] = 0.0
        out[6] = FEW_CANDIDATES
        return
    # The floor where the robot stands: beyond where it is first seen (a low percentile of
    # the candidates' runs, clear of a stray near point), over FIT_RUN_LONG metres where the
    # floor is one plane there (the longer the run, the truer the tilt), else over FIT_RUN:
    # a long run takes in a ramp's foot (or a crest) well before the robot gets there, and
    # the plane tilts towards it. A ramp farther ahead is the profile's (`_profile`).
    share = int(NEAREST_SHARE * (count - 1))
    nearest = np.partition(runs[:count], share)[share]
    near = np.empty(7)
    fit_within(
        points, tolerance, noise_band, runs, count, nearest + FIT_RUN, prior, start, base,
        max_offset, max_tilt, draws, min_points, min_spread, near,
    )  # fmt: skip
    fit_within(
        points, tolerance, noise_band, runs, count, nearest + FIT_RUN_LONG, prior, start, base,
        max_offset, max_tilt, draws, min_points, min_spread, out,
    )  # fmt: skip
    if out[6] != OK:
        if near[6] == OK:
            out[:] = near
        return
    if near[6] == OK:
        cosine = out[0] * near[0] + out[1] * near[1] + out[2] * near[2]
        if cosine < math.cos(BEND) or abs(out[3] - near[3]) > BEND_OFFSET:
            out[:] = near


def _fit_within(
    candidates: Any,
    candidate_tolerance: Any,
    candidate_noise: Any,
    runs: Any,
    count: int,
    limit: float,
    prior: Any,
    start: Any,
    base: Any,
    max_offset: float,
    max_tilt: float,
    draws: Any,
    min_points: int,
    min_spread: float,
    out: Any,
) -> None:
    """RANSAC and least squares (`_fit`) on the first `count` candidates whose run is at
    most `limit` metres."""
    points = np.empty((count, 3))
    tolerance = np.empty(count)
    noise_band = np.empty(count)
    kept = 0
    for i in range(count):
        if runs[i] <= limit:
            points[kept, 0] = candidates[i, 0]
            points[kept, 1] = candidates[i, 1]
            points[kept, 2] = candidates[i, 2]
            tolerance[kept] = candidate_tolerance[i]
            noise_band[kept] = candidate_noise[i]
            kept += 1
    count = kept
    cos_tilt = math.cos(max_tilt)
    out[:] = 0.0
    out[4] = count
    if count < max(min_points, 3):
        out[6] = FEW_CANDIDATES
        return
    best = np.empty(4)
    best_score = -(2**62)
    scored = (count + SCORE_STRIDE - 1) // SCORE_STRIDE
    needed = draws.shape[0]
    candidate = np.empty(4)
    for h in range(draws.shape[0] + 3):
        if h - 3 >= needed:
            break
        if h == 0:
            candidate[:] = prior
        elif h == 1:
            candidate[:] = start
        elif h == 2:
            if base[0] == prior[0] and base[1] == prior[1] and base[2] == prior[2]:
                continue  # no IMU: the base is the prior
            candidate[:] = base
        else:
            row = draws[h - 3]
            p0 = points[min(int(row[0] * count), count - 1)]
            p1 = points[min(int(row[1] * count), count - 1)]
            p2 = points[min(int(row[2] * count), count - 1)]
            normal = np.cross(p1 - p0, p2 - p0)
            length = math.sqrt(normal[0] ** 2 + normal[1] ** 2 + normal[2] ** 2)
            if not length > 1e-6:
                continue
            normal /= length
            if normal[0] * prior[0] + normal[1] * prior[1] + normal[2] * prior[2] < 0.0:
                normal = -normal
            candidate[:3] = normal
            candidate[3] = -(normal[0] * p0[0] + normal[1] * p0[1] + normal[2] * p0[2])
        if not admissible(candidate, prior, base, cos_tilt, max_offset):
            continue
        inliers, below = 0, 0
        for i in range(0, count, SCORE_STRIDE):
            height = (
                candidate[0] * points[i, 0]
                + candidate[1] * points[i, 1]
                + candidate[2] * points[i, 2]
                + candidate[3]
            )
            inliers += int(abs(height) <= tolerance[i])
            below += int(height < -tolerance[i])
        # The floor is the lowest large surface: points below a plane count against it.
        score = inliers - below
        if score > best_score:
            best_score = score
            best[:] = candidate
            needed = min(needed, triples_needed(inliers / scored))
    if best_score == -(2**62):
        out[6] = OUT_OF_BOUNDS
        return
    inliers = 0
    for round_ in range(3):
        inliers = refine(points, tolerance, noise_band, count, best, out, round_ > 0)
        if inliers < min_points:
            out[4] = inliers
            out[6] = FEW_INLIERS
            return
    out[:4] = best
    out[4] = inliers
    if out[5] < min_spread:
        out[6] = ALONG_A_LINE
    elif not admissible(best, prior, base, cos_tilt, max_offset):
        out[6] = OUT_OF_BOUNDS
    else:
        out[6] = OK


def _triples_needed(share: float) -> int:
    """Random triples after which one of them held only inliers with probability
    CONFIDENCE, `share` of the candidates being inliers."""
    all_in = share**3
    if all_in >= 1.0:
        return 0
    if all_in <= 0.0:
        return 2**31
    return math.ceil(math.log(1.0 - CONFIDENCE) / math.log(1.0 - all_in))


def _admissible(plane: Any, prior: Any, base: Any, cos_tilt: float, max_offset: float) -> bool:
    """Whether `plane` (normal, offset) is within the bounds of the prior or of `base`."""
    for reference in (prior, base):
        cosine = plane[0] * reference[0] + plane[1] * reference[1] + plane[2] * reference[2]
        if cosine >= cos_tilt and abs(plane[3] - reference[3]) <= max_offset:
            return True
    return False


admissible = compiled(_admissible)
triples_needed = compiled(_triples_needed)
axes = compiled(_axes)
fit_within = compiled(_fit_within)
determinant3 = compiled(_determinant)
refine = compiled(_refine)
fit = compiled(_fit)


def _candidate(rise: float, run: float, up: float, down: float, sigma: float) -> bool:
    """Whether a point `rise` metres above the last ground, `run` metres beyond it, may be
    ground: within the steepest floor's rise (`up` per metre) or fall (`down`) plus 2 sigma
    of its noise (a low box's top, a little past its face, is not)."""
    margin = ABOVE + 2.0 * sigma
    run = max(run, 0.0)
    return -down * run - margin <= rise <= up * run + margin


def _profile(
    depth: Any,
    scale: float,
    width: int,
    columns: Any,
    rows: Any,
    x_n: Any,
    y_n: Any,
    plane: Any,
    forward: Any,
    left: Any,
    tan_slope: float,
    level: Any,
    noise: float,
    bin_size: float,
    deadband: float,
    evidence_sigmas: float,
    doubt_sigmas: float,
    profile: Any,
    evidence: Any,
    low: Any,
    doubt: Any,
    falls: Any,
) -> None:
    """Per sampled image column the ground's height above `plane` (normal, offset) in bins
    of `bin_size` metres of horizontal distance from the camera (`profile`, columns x bins).

    `x_n`, `y_n` are the rays of the grid's pixels, row by row: the j-th row's c-th column's
    at j * columns.size + c. Each column's pixels (`rows`, nearest first) become points; the bins
    are walked outwards from the camera's foot, where the ground is the plane (height 0). A
    bin's ground is the mean height of its points that may be ground (`_candidate`: within
    the steepest floor's rise or fall over run and their noise of the last ground, run their
    horizontal distance from it), clamped to that over min(run, bin_size) (over run, for a
    ramp already seen falling: below): the profile never rises or falls faster than the
    steepest floor, however the points creep (an obstacle's face, a step, a drop are not
    ground). In a bin where many points stand clearly above any
    floor's rise (an obstacle's face) it does not rise to the face's foot: it goes on at its
    last rise where the column's ground already stood off the plane for RAMP_BINS bins (a
    ramp's, under a box on it), else it is held; it does not fall in one where many stand
    below (a drop's edge). A bin without ground keeps the last ground; if it holds an
    obstacle's or a drop's points, the last ground's place moves on to it (the ground is held
    level under an obstacle and across a drop: neither a box's top nor a drop's far floor
    becomes ground by distance alone). At the end, a bin without ground takes the ground of
    the nearest column within FILL_COLUMNS that saw it there.

    The steepest floor is `tan_slope` per metre above level. `level` (the sines of the
    plane's rise along `forward` and `left` above level; zeros: the plane is taken as level)
    widens it per column where the plane is tilted (the robot stands on a ramp): from a
    ramp's foot, the level floor beyond its top falls away from the plane at the ramp's
    slope, and a down ramp beyond it at twice that. Only widened, never narrowed: the level
    (an IMU's, through the mounting) may be a mounting error off. `falls[c]` is column c's
    steepest fall per metre.

    `evidence[c]`: the most bins in a row of column c whose ground was seen (not held) off
    the plane by more than `deadband` and than `evidence_sigmas` sigmas of its points' mean.
    `doubt[c, b]`: `doubt_sigmas` sigmas of the mean that made bin b's ground (the last seen's
    where it was held or taken from a neighbour).

    `low` is the lowest the ground may be, what a drop is measured below: the profile where
    a column saw ground (or took a neighbour's), and beyond, where it saw none (behind a
    crest, past the view's reach), the last ground seen falling at the steepest floor's
    fall: a down ramp hidden behind its top is no drop, a ledge's far floor is. Each bin's
    `low` is also at most the next bin's where that bin's ground was seen, and the last
    bin's, seen, is its fall over a bin lower (a line of sight meets a bin's one height
    early where it grazes the ground).
    """
    bins = profile.shape[1]
    count = rows.size
    columns_used = min(columns.size, profile.shape[0], evidence.size)
    # Every point first, row by row (the image is read along its rows, not down its
    # columns), then each column's walk.
    radius = np.empty((columns_used, count))
    height = np.empty((columns_used, count))
    allowed = np.empty((columns_used, count))
    slot = np.full((columns_used, count), -1, np.int64)
    seen = np.zeros((columns_used, bins), np.bool_)
    heading = np.zeros((columns_used, 2))  # each column's direction on the plane, summed
    for j in range(count):
        for c in range(columns_used):
            column = columns[c]
            index = rows[j] * width + column
            ray = j * columns.size + c
            if not (
                0 <= column < width and 0 <= index < depth.size and ray < min(x_n.size, y_n.size)
            ):
                continue
            z = np.float64(depth[index]) * scale
            if not z > 0.0:
                continue
            x, y = x_n[ray] * z, y_n[ray] * z
            h = plane[0] * x + plane[1] * y + plane[2] * z + plane[3]
            along = forward[0] * x + forward[1] * y + forward[2] * z
            across = left[0] * x + left[1] * y + left[2] * z
            r = math.sqrt(along * along + across * across)
            if not (r < bins * bin_size and math.isfinite(h)):  # also NaN, before int()
                continue
            vertical = abs(plane[0] * x_n[ray] + plane[1] * y_n[ray] + plane[2])
            radius[c, j], height[c, j] = r, h
            if r > 0.0:
                heading[c, 0] += along / r
                heading[c, 1] += across / r
            slot[c, j] = min(int(r / bin_size), bins - 1)
            allowed[c, j] = noise * z * z * vertical  # 1 sigma of the point's height
    order = np.empty(count, np.int64)
    starts = np.zeros(bins + 1, np.int64)
    steepest = math.atan(tan_slope)
    for c in range(columns_used):
        # The plane's tilt above level along this column (positive: it rises away).
        norm = math.hypot(heading[c, 0], heading[c, 1])
        sine = (heading[c, 0] * level[0] + heading[c, 1] * level[1]) / norm if norm > 0.0 else 0.0
        tilt = math.asin(min(max(sine, -1.0), 1.0))
        up = math.tan(min(steepest + max(-tilt, 0.0), MAX_WIDENED))
        down = math.tan(min(steepest + max(tilt, 0.0), MAX_WIDENED))
        if c < falls.size:
            falls[c] = down
        starts[:] = 0
        for j in range(count):
            if slot[c, j] >= 0:
                starts[slot[c, j] + 1] += 1
        for b in range(bins):
            starts[b + 1] += starts[b]
        filled = starts[:bins].copy()
        for j in range(count):
            if slot[c, j] >= 0:
                order[filled[slot[c, j]]] = j
                filled[slot[c, j]] += 1
        ground, at, sigma = 0.0, 0.0, 0.0
        trend = 0.0  # the ground's last rise per metre, between the last two bins seen
        streak = 0
        evidence[c] = 0
        for b in range(bins):
            centre = (b + 0.5) * bin_size
            total, spread, found, above, below = 0.0, 0.0, 0, 0, 0
            for k in range(starts[b], starts[b + 1]):
                j = order[k]
                run = radius[c, j] - at
                rise = height[c, j] - ground
                clear = FACE + 3.0 * allowed[c, j]
                if candidate(rise, run, up, down, allowed[c, j]):
                    total += height[c, j]
                    spread += allowed[c, j] * allowed[c, j]
                    found += 1
                elif rise > up * max(run, 0.0) + clear:
                    above += 1
                elif rise < -down * max(run, 0.0) - clear:
                    below += 1
            if found > 0:
                # At most one bin's rise or fall per bin of ground seen: across a gap (no
                # points) the ground does not jump to stray points far beyond it.
                step = min(max(centre - at, 0.0), bin_size)
                top = ground + up * step
                if above >= max(2, found // 4):
                    # An obstacle's face stands in this bin: the ground does not rise to the
                    # face's foot. On a ramp already seen off the plane (beyond its noise,
                    # RAMP_BINS in a row) it goes on at the ramp's last rise (a box on a ramp
                    # stands on the ramp); elsewhere it is held.
                    top = ground
                    if streak >= RAMP_BINS:
                        top += min(max(trend, 0.0) * max(centre - at, 0.0), up * step)
                # A drop's edge (many points below) stands in this bin: the ground does not
                # fall into it.
                bottom = ground if below >= max(2, found // 4) else ground - down * step
                if bottom < ground and streak >= RAMP_BINS and trend < 0.0:
                    # Across bins no row of the image fell in (a ramp down seen at a grazing
                    # angle, 2-3 bins between two rows), a ramp already seen falling may have
                    # gone on falling at the steepest floor's fall (`low` bounds the bins
                    # between so). At its last fall (a platform's end makes it less than the
                    # ramp's), the ramp's next row was 3-7 cm below the ground there: a drop.
                    bottom = ground - down * max(centre - at, 0.0)
                last = ground
                ground = min(max(total / found, bottom), top)
                if centre > at:
                    trend = (ground - last) / (centre - at)
                at = centre
                seen[c, b] = True
                # Off by more than the deadband (what the slab's bottom can afford) and than
                # the noise of the mean: far out a bin holds a point or two, each a centimetre
                # or more off, and a flat floor's noise would make a profile.
                sigma = math.sqrt(spread) / found
                band = max(deadband, evidence_sigmas * sigma)
                streak = streak + 1 if abs(ground) > band else 0
                evidence[c] = max(evidence[c], streak)
            elif above >= 2 or below >= 2:
                # An obstacle or a drop and no ground: the ground is held level across it, so
                # the window does not widen onto a deep box's top or a drop's far floor.
                at = centre
            profile[c, b] = ground
            doubt[c, b] = doubt_sigmas * sigma
    # A bin where a column saw no ground (behind an obstacle, past a wall's foot) takes the
    # ground of the nearest column within FILL_COLUMNS that saw it there, not its own held
    # level: an image column fans out across the floor, and the pixels mapped to it beside
    # a wall still see the ramp its neighbour walked up.
    known = seen.copy()
    for b in range(bins):
        for c in range(columns_used):
            if seen[c, b]:
                continue
            for step in range(1, FILL_COLUMNS + 1):
                if c - step >= 0 and seen[c - step, b]:
                    profile[c, b] = profile[c - step, b]
                    doubt[c, b] = doubt[c - step, b]
                    known[c, b] = True
                    break
                if c + step < columns_used and seen[c + step, b]:
                    profile[c, b] = profile[c + step, b]
                    doubt[c, b] = doubt[c + step, b]
                    known[c, b] = True
                    break
    for c in range(min(columns_used, low.shape[0], falls.size)):
        last, last_at = 0.0, 0.0
        for b in range(min(bins, low.shape[1])):
            centre = (b + 0.5) * bin_size
            if known[c, b]:
                last, last_at = profile[c, b], centre
                low[c, b] = last
            else:
                low[c, b] = min(profile[c, b], last - falls[c] * (centre - last_at))
        # A bin's ground stands for the whole bin, and a line of sight grazing the ground
        # meets it early: over a ramp down, 4 cm above the ground at the bin's far end, and
        # the ramp beyond was a drop. Where the next bin's ground was seen lower, the ground
        # may be as low in this one; in the last bin, seen, as low as it falls on to.
        used = min(bins, low.shape[1])
        for b in range(used):
            if b + 1 < used and known[c, b + 1]:
                low[c, b] = min(low[c, b], low[c, b + 1])
            elif b + 1 == used and known[c, b]:
                low[c, b] -= falls[c] * bin_size


def _crossings(
    x_n: Any,
    y_n: Any,
    width: int,
    stride: int,
    plane: Any,
    forward: Any,
    left: Any,
    columns: Any,
    profile: Any,
    low: Any,
    falls: Any,
    bin_size: float,
    far: float,
    levels: Any,
    low_from: int,
    margin_sigmas: float,
    doubt: Any,
    lifts: Any,
) -> None:
    """Per level L and ray the ground's height g above the plane at the point where the
    ray is L above the ground of its column's profile (the nearest sampled column; linear
    between bin centres, level beyond the ends): lifts[level, ray]. The rays are those of
    every `stride`-th pixel of every `stride`-th row (`width` of them a row). The levels
    from index `low_from` on are measured above the lowest ground, `low` (drops: see
    `_profile`), which beyond the last bin falls on by `falls[column]` metres per metre.

    The line of sight's height above the ground falls along it (it looks down more steeply
    than any floor slopes), so the first knot below L brackets the point. A line of sight
    that stays above L within `far` metres of depth takes the ground under its point at `far`.

    Where the ground rises away from the camera, a level L > 0 is raised by
    `margin_sigmas` (noise per metre of depth squared, sigmas included) x Z^2 x the rise per
    metre of depth there (see `slope_margin`), as a lift that measures it above that ground;
    and by the ground's `doubt` there (`_profile`; none where `doubt` has no columns).
    """
    bins = min(profile.shape[1], low.shape[1])
    last = min(columns.size, profile.shape[0], low.shape[0]) - 1
    doubted = doubt.shape[0] > last and doubt.shape[1] >= bins
    first_column = columns[0]
    step = columns[1] - columns[0] if columns.size > 1 else 1
    for i in range(min(x_n.size, y_n.size, lifts.shape[1])):
        u = (i % width) * stride  # the image column of the i-th ray of every stride-th
        c = min(max(round((u - first_column) / step), 0), last)
        down = plane[0] * x_n[i] + plane[1] * y_n[i] + plane[2]  # height per metre of depth
        along = forward[0] * x_n[i] + forward[1] * y_n[i] + forward[2]
        across = left[0] * x_n[i] + left[1] * y_n[i] + left[2]
        run = math.sqrt(along * along + across * across)  # horizontal metres per metre of depth
        knot_depth = bin_size / run if run > 0.0 else far  # metres of depth from knot to knot
        # One walk along the knots serves every level: each takes the first knot where the
        # line of sight is no more than it above the ground (levels descend: so do they).
        count = min(levels.size, lifts.shape[0])
        pending = 0
        previous_gap = plane[3] - profile[c, 0]
        previous_low_gap = plane[3] - low[c, 0]
        z_before = 0.0
        g, g_low = profile[c, 0], low[c, 0]
        for b in range(bins + 1):
            # Knots at bin centres, and the far end.
            z = min((b + 0.5) * knot_depth, far) if b < bins else far
            knot, before = min(b, bins - 1), max(min(b - 1, bins - 1), 0)
            g, g_low = profile[c, knot], low[c, knot]
            if b == bins:
                g_low -= falls[min(c, falls.size - 1)] * max(z * run - (bins - 0.5) * bin_size, 0.0)
            gap = down * z + plane[3] - g  # the line of sight's height above the ground
            low_gap = down * z + plane[3] - g_low
            while pending < count:
                target = levels[pending]
                on_low = pending >= low_from
                if not (low_gap if on_low else gap) <= target:
                    break
                above = (previous_low_gap if on_low else previous_gap) - target
                below = (low_gap if on_low else gap) - target
                share = above / (above - below) if above > below else 1.0
                g_before = low[c, before] if on_low else profile[c, before]
                g_here = g_low if on_low else g
                lift = g_before + share * (g_here - g_before)
                if target > 0.0 and z > z_before:
                    depth = z_before + share * (z - z_before)
                    lift += slope_margin(
                        margin_sigmas * depth * depth, (g_here - g_before) / (z - z_before), down
                    )
                if target > 0.0 and doubted:
                    lift += doubt[c, before] + share * (doubt[c, knot] - doubt[c, before])
                lifts[pending, i] = lift
                pending += 1
            if z >= far or pending == count:
                break
            previous_gap = gap
            previous_low_gap = low_gap
            z_before = z
        for level in range(pending, count):
            # The ground at the walk's last knot: depth `far`.
            if level >= low_from:
                lifts[level, i] = g_low
            elif levels[level] > 0.0 and doubted:
                lifts[level, i] = g + doubt[c, min(b, bins - 1)]
            else:
                lifts[level, i] = g


def _slope_margin(sigma: float, rise: float, down: float) -> float:
    """How much to raise a lift where the ground rises `rise` metres per metre of depth
    along a line of sight that falls `down` (< 0) metres per metre of depth above the plane,
    at a depth of noise `sigma` (metres along the ray, sigmas included).

    Noise along a line of sight moves its point by `down` per metre over a flat floor, but
    by `down` - `rise` over a rising ramp: a reading short of the ramp lands above lower
    ground. The slab's bottom is raised by sigma x rise above the ramp, so it stands as many
    sigmas above a ramp's readings as above a flat floor's; the tables measure a lift above
    ground that stays where it is, so the lift is that margin x down / (down - rise).
    Nothing on flat or falling ground, or on a line of sight that does not look down."""
    if not (rise > 0.0 and down < 0.0 and sigma > 0.0):
        return 0.0
    return sigma * rise * -down / (rise - down)


slope_margin = compiled(_slope_margin)
candidate = compiled(_candidate)
profile = compiled(_profile, error_model='numpy')
crossings = compiled(_crossings, error_model='numpy')
