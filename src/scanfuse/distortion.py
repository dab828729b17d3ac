"""Lens distortion of `sensor_msgs/CameraInfo`: inverting it for the per-pixel rays.

The models are OpenCV's, with the coefficient order of CameraInfo's D:

- `plumb_bob`: (k1, k2, p1, p2, k3);
- `rational_polynomial`: (k1, k2, p1, p2, k3, k4, k5, k6).

For an undistorted normalized point (x, y), r^2 = x^2 + y^2, the distorted one is

    x_d = x (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)
          + 2 p1 x y + p2 (r^2 + 2 x^2)
    y_d = y (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)
          + p1 (r^2 + 2 y^2) + 2 p2 x y

There is no closed-form inverse; like OpenCV's `undistortPoints` we iterate
x <- (x_d - tangential(x)) / radial(x) from x = x_d, but until the step is
negligible rather than a fixed five times, so the rays are exact to float64.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from scanfuse.errors import InputError

if TYPE_CHECKING:
    from collections.abc import Sequence

    import numpy.typing as npt

    Array = npt.NDArray[np.float64]

COEFFICIENT_NAMES: dict[str, tuple[str, ...]] = {
    'plumb_bob': ('k1', 'k2', 'p1', 'p2', 'k3'),
    'rational_polynomial': ('k1', 'k2', 'p1', 'p2', 'k3', 'k4', 'k5', 'k6'),
}
MAX_ITERATIONS = 200
TOLERANCE = 1e-12


def _coefficients(model: str, coeffs: Sequence[float]) -> Array:
    """The eight rational-polynomial coefficients (k1, k2, p1, p2, k3, k4, k5, k6)."""
    names = COEFFICIENT_NAMES.get(model)
    if names is None:
        supported = ', '.join(sorted(COEFFICIENT_NAMES))
        msg = (
            f'distortion model {model!r} is not supported; use one of {supported}, or publish '
            'rectified depth with D all zero'
        )
        raise InputError(msg)
    values = [float(value) for value in coeffs]
    if not all(np.isfinite(values)):
        msg = f'{model} distortion coefficients must be finite, got {tuple(values)}'
        raise InputError(msg)
    extra = values[len(names) :]
    if any(value != 0.0 for value in extra):
        msg = (
            f'{model} takes {len(names)} coefficients ({", ".join(names)}), got {len(values)} '
            'with non-zero extra terms (thin prism or tilt); those are not supported'
        )
        raise InputError(msg)
    full = np.zeros(8, dtype=np.float64)
    full[: min(len(values), len(names))] = values[: len(names)]
    return full


def distortion_coefficients(model: str, coeffs: Sequence[float]) -> Array:
    """(k1, k2, p1, p2, k3, k4, k5, k6) of a CameraInfo's model and D, for compiled loops."""
    return _coefficients(model, coeffs)


def distort_normalized(
    x: npt.ArrayLike, y: npt.ArrayLike, model: str, coeffs: Sequence[float]
) -> tuple[Array, Array]:
    """The forward model: undistorted normalized coordinates in, distorted out."""
    k1, k2, p1, p2, k3, k4, k5, k6 = _coefficients(model, coeffs)
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    r2 = x * x + y * y
    radial = (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    x_d = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    y_d = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    return x_d, y_d


def undistort_normalized(
    x_n: npt.ArrayLike, y_n: npt.ArrayLike, model: str, coeffs: Sequence[float]
) -> tuple[Array, Array]:
    """Undistorted normalized coordinates from distorted ones (the pixel's (u - cx) / fx ...).

    Points where the iteration does not settle (far outside the calibrated field,
    where the model is not invertible) come back as NaN: no ray for that pixel.
    """
    k1, k2, p1, p2, k3, k4, k5, k6 = _coefficients(model, coeffs)
    x0 = np.asarray(x_n, dtype=np.float64)
    y0 = np.asarray(y_n, dtype=np.float64)
    x = x0.copy()
    y = y0.copy()
    step = np.full(x.shape, np.inf)
    with np.errstate(all='ignore'):
        for _ in range(MAX_ITERATIONS):
            r2 = x * x + y * y
            inverse_radial = (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6))) / (
                1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            )
            delta_x = 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
            delta_y = p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
            x_next = (x0 - delta_x) * inverse_radial
            y_next = (y0 - delta_y) * inverse_radial
            step = np.maximum(np.abs(x_next - x), np.abs(y_next - y))
            x, y = x_next, y_next
            if not (step > TOLERANCE).any():
                break
    unsettled = ~(step <= TOLERANCE * 1e3)
    if unsettled.any():
        x = np.where(unsettled, np.nan, x)
        y = np.where(unsettled, np.nan, y)
    return x, y
