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
# Hypotheses are scored on every SCORE_STRIDE-th candidate; the refinement uses them all.
SCORE_STRIDE = 2
# Metres above the plane (beyond the depth's noise) an inlier of the refinement may lie.
ABOVE = 0.003


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


def _refine(points: Any, tolerance: Any, noise: Any, count: int, plane: Any, out: Any) -> int:
    """Least squares on the inliers of `plane` (normal, offset): the refined plane into
    `plane`, the least spread of the inliers along the plane's axes into out[5]; returns the
    number of inliers.

    An inlier lies at most its `tolerance` below the plane but only its depth noise
    (`noise`, 3 sigma) plus `ABOVE` above it: the floor is the lowest surface, and a slope
    or an obstacle's foot that rises out of it would otherwise tilt the fit towards itself
    a little more with every refinement."""
    normal = plane[:3].copy()
    first, second = axes(normal)
    # Normal equations of h = a + b u + c v, and the (u, v) moments for the spread.
    m = np.zeros((3, 3))
    rhs = np.zeros(3)
    inliers = 0
    for i in range(count):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        h = normal[0] * x + normal[1] * y + normal[2] * z + plane[3]
        if h < -tolerance[i] or h > noise[i] + ABOVE:
            continue
        u = first[0] * x + first[1] * y + first[2] * z
        v = second[0] * x + second[1] * y + second[2] * z
        inliers += 1
        m[0, 0] += 1.0
        m[0, 1] += u
        m[0, 2] += v
        m[1, 1] += u * u
        m[1, 2] += u * v
        m[2, 2] += v * v
        rhs[0] += h
        rhs[1] += h * u
        rhs[2] += h * v
    if inliers < 3:
        return inliers
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
    in [0, 1) pick each hypothesis's three candidates. `out` as the module's constants say."""
    size = min(indices.size, rays.shape[0])
    points = np.empty((size, 3))
    tolerance = np.empty(size)
    noise_band = np.empty(size)
    sin_tilt, cos_tilt = math.sin(max_tilt), math.cos(max_tilt)
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
        if distance > reach:
            continue
        slope = prior[0] * rays[i, 0] + prior[1] * rays[i, 1] + prior[2]
        # Noise along the ray moves the height by |slope| per metre of depth.
        spread = 3.0 * noise * z * z * abs(slope)
        allowed = inlier_distance + spread
        height = slope * z + prior[3]
        if abs(height) > max_offset + distance * sin_tilt + allowed:
            continue
        points[count, 0], points[count, 1], points[count, 2] = x, y, z
        tolerance[count] = allowed
        noise_band[count] = spread
        count += 1
    out[:] = 0.0
    out[4] = count
    if count < max(min_points, 3):
        out[6] = FEW_CANDIDATES
        return
    best = np.empty(4)
    best_score = -(2**62)
    candidate = np.empty(4)
    for h in range(draws.shape[0] + 2):
        if h == 0:
            candidate[:] = prior
        elif h == 1:
            candidate[:] = start
        else:
            row = draws[h - 2]
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
        cosine = candidate[0] * prior[0] + candidate[1] * prior[1] + candidate[2] * prior[2]
        if cosine < cos_tilt or abs(candidate[3] - prior[3]) > max_offset:
            continue
        score = 0
        for i in range(0, count, SCORE_STRIDE):
            height = (
                candidate[0] * points[i, 0]
                + candidate[1] * points[i, 1]
                + candidate[2] * points[i, 2]
                + candidate[3]
            )
            # The floor is the lowest large surface: points below a plane count against it.
            score += (abs(height) <= tolerance[i]) - (height < -tolerance[i])
        if score > best_score:
            best_score = score
            best[:] = candidate
    if best_score == -(2**62):
        out[6] = OUT_OF_BOUNDS
        return
    inliers = 0
    for _ in range(3):
        inliers = refine(points, tolerance, noise_band, count, best, out)
        if inliers < min_points:
            out[4] = inliers
            out[6] = FEW_INLIERS
            return
    out[:4] = best
    out[4] = inliers
    cosine = best[0] * prior[0] + best[1] * prior[1] + best[2] * prior[2]
    if out[5] < min_spread:
        out[6] = ALONG_A_LINE
    elif cosine < cos_tilt or abs(best[3] - prior[3]) > max_offset:
        out[6] = OUT_OF_BOUNDS
    else:
        out[6] = OK


axes = compiled(_axes)
determinant3 = compiled(_determinant)
refine = compiled(_refine)
fit = compiled(_fit)
