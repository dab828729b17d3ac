"""Range trade-off of the row method: equations 4-6 and the exact floor intersection.

A row below the optical centre looks down. Past the distance where its line of
sight meets a flat floor, the row sees the floor, which a scan would report as an
obstacle (the paper's Figure 10). The paper limits the row's maximum range to the
slant distance l' of equation 4; `floor_range_limit` gives the exact limit of every
pixel column, in the range of equation 3, for a camera of known height and pitch.

Geometry: the optical frame is z forward, x right, y down (REP-103); the camera
has no roll and is pitched down by `camera_pitch` radians at `camera_height`
metres above the floor. The optical ray (x_n, y_n, 1) then descends by
y_n cos(p) + sin(p) per metre of depth Z, so it meets the floor at
Z = h / (y_n cos(p) + sin(p)), where that is positive.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from scanfuse.errors import ConfigError

if TYPE_CHECKING:
    import numpy.typing as npt

    from scanfuse.camera import CameraModel


@dataclass(frozen=True)
class FloorGuard:
    """A camera of known height and pitch above a flat floor (row method's floor guard)."""

    camera_height: float
    camera_pitch: float  # radians, positive looks down
    margin: float = 0.05  # metres kept short of the floor intersection


def check_floor_pose(camera_height: float, camera_pitch: float) -> None:
    """Raise ConfigError unless the camera is above the floor with a sensible pitch."""
    if not math.isfinite(camera_height) or camera_height <= 0.0:
        msg = (
            f'camera_height must be a positive number of metres above the floor, '
            f'got {camera_height}'
        )
        raise ConfigError(msg)
    if not math.isfinite(camera_pitch) or abs(camera_pitch) >= math.pi / 2:
        msg = (
            f'camera_pitch must be finite and within (-pi/2, pi/2) radians '
            f'(positive looks down), got {camera_pitch}'
        )
        raise ConfigError(msg)


def paper_max_range(camera_height: float, camera_pitch: float, row_angle: float) -> float:
    """Equation 4: l' = h / sin(alpha + beta), the row's usable slant distance.

    alpha is the camera pitch (down), beta the row's angle below the optical axis
    (atan((v - cy) / fy)). l' is measured along the sight line of the centre column
    from the camera to the floor. +Inf when that line does not descend.
    """
    check_floor_pose(camera_height, camera_pitch)
    descent = math.sin(camera_pitch + row_angle)
    if descent <= 0.0:
        return math.inf
    return camera_height / descent


def paper_max_range_closed_form(
    camera_height: float, camera_pitch: float, v: float, cy: float, fy: float
) -> float:
    """Equation 6 in pixel terms: l' = h sqrt(fy^2 + (v-cy)^2) / (fy sin a + (v-cy) cos a).

    The paper's own derivation is not at hand; this is the closed form obtained by
    expanding sin(alpha + atan((v - cy) / fy)) in equation 4 with
    sin(atan(t)) = t / sqrt(1 + t^2) and cos(atan(t)) = 1 / sqrt(1 + t^2). Like
    equation 4, l' is the slant distance along the sight line of the centre column.
    +Inf when that line does not descend.
    """
    check_floor_pose(camera_height, camera_pitch)
    offset = v - cy
    denominator = fy * math.sin(camera_pitch) + offset * math.cos(camera_pitch)
    if denominator <= 0.0:
        return math.inf
    return camera_height * math.hypot(fy, offset) / denominator


def floor_range_limits(
    x_n: npt.NDArray[np.floating],
    y_n: npt.NDArray[np.floating],
    camera_height: float,
    camera_pitch: float,
) -> npt.NDArray[np.float64]:
    """Range (equation 3) at which each ray (x_n, y_n, 1) meets the floor; +Inf if never.

    Elementwise over ray tables of any shape.
    """
    x = np.asarray(x_n, dtype=np.float64)
    y = np.asarray(y_n, dtype=np.float64)
    descent = y * math.cos(camera_pitch) + math.sin(camera_pitch)
    with np.errstate(divide='ignore'):
        depth = np.where(descent > 0.0, camera_height / descent, np.inf)
    # Equation 3: r = sqrt(X^2 + Z^2) with X = x_n Z.
    return depth * np.sqrt(1.0 + x * x)


def floor_range_limit(
    camera: CameraModel, camera_height: float, camera_pitch: float, scan_row: int
) -> npt.NDArray[np.float64]:
    """Per pixel column of `scan_row`: the range r = sqrt(X^2 + Z^2) where its sight line
    meets a flat floor, exact for any pitch; +Inf where the ray does not descend.
    """
    check_floor_pose(camera_height, camera_pitch)
    if not 0 <= scan_row < camera.height:
        msg = f'scan_row {scan_row} is outside the image rows 0..{camera.height - 1}'
        raise ConfigError(msg)
    x_n, y_n = camera.normalized_coordinates
    return floor_range_limits(x_n[scan_row], y_n[scan_row], camera_height, camera_pitch)
