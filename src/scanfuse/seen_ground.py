"""LiDAR readings on the ground a depth camera sees: a tilted LiDAR's plane meets the floor.

A 2D LiDAR 0.3 m up a body pitched 7 degrees nose down (going down a 1:8 ramp) sweeps the
floor below the ramp 2.4 m ahead, and reports it as a wall. Its readings there lie on the
ground the depth camera sees in the same place, below the collision slab's bottom; an
obstacle the plane crosses stands higher (a level LiDAR's points all stand its height above
the floor). So a LiDAR reading whose point lies in the camera's view, within its range, not
hidden behind something nearer, and less than the slab's bottom above the camera's ground
(its plane, raised by its ramps: `GroundProfile`) is ground, not an obstacle: the stream
drops it (`FusionStream._off_the_seen_ground`), and the camera's scan stands for that slot.
Below the ground counts too: a plane pitched down past a ledge meets the floor beneath it,
and the camera reports the edge as a drop.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from scanfuse.compiled import compiled
from scanfuse.memory import ground_under, lens_and_depth, pixel_of, profile_arrays

if TYPE_CHECKING:
    import numpy.typing as npt

    from scanfuse.camera import CameraModel
    from scanfuse.convert.ground import GroundPlane, GroundProfile

    F64 = npt.NDArray[np.float64]

# Metres a reading's point may lie nearer than the camera's pixel there and still be seen
# (the pixel's depth noise and the time between the frame and the scan): 5 cm and 2 %.
SEEN_MARGIN = (0.05, 0.02)


def _on_ground_loop(
    points: Any,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    d: Any,
    depth: Any,
    scale: float,
    range_min: float,
    range_max: float,
    normal: Any,
    offset: float,
    below: float,
    margin: Any,
    out: Any,
    profile_columns: Any,
    profile: Any,
    bin_size: float,
    forward: Any,
    left: Any,
) -> int:
    """`on_seen_ground` one point at a time; how many are on the ground."""
    rows, columns = depth.shape
    found = 0
    for i in range(points.shape[0]):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        out[i] = False
        if not range_min <= z <= range_max:
            continue
        u, v = pixel_of(x, y, z, fx, fy, cx, cy, d)
        if not (0 <= u < columns and 0 <= v < rows):
            continue
        measured = depth[v, u] * scale
        # Seen: the pixel shows the place, not something nearer in front of it.
        if not measured >= z - margin[0] - margin[1] * z:
            continue
        height = normal[0] * x + normal[1] * y + normal[2] * z + offset
        # The ground under the point: the plane's foot of it, raised by the ramps there.
        foot = height
        lift = ground_under(
            x - normal[0] * foot, y - normal[1] * foot, z - normal[2] * foot,
            fx, cx, profile_columns, profile, bin_size, forward, left,
        )  # fmt: skip
        if height - lift < below:
            out[i] = True
            found += 1
    return found


_ON_GROUND = compiled(_on_ground_loop)


def on_seen_ground(
    points: F64,
    depth: npt.NDArray[np.generic],
    camera: CameraModel,
    plane: GroundPlane,
    profile: GroundProfile | None,
    *,
    below: float,
    range_min: float,
    range_max: float,
) -> npt.NDArray[np.bool_]:
    """Which `points` (N x 3, the camera's optical frame) the camera sees in `depth` (uint16
    millimetres or float metres) within [range_min, range_max] of depth, less than `below`
    metres above the ground of `plane` and `profile` (or beneath it)."""
    out = np.zeros(len(points), dtype=np.bool_)
    if not len(points):
        return out
    coefficients, pixels, scale = lens_and_depth(camera, depth)
    _ON_GROUND(
        np.ascontiguousarray(points, dtype=np.float64),
        camera.fx,
        camera.fy,
        camera.cx,
        camera.cy,
        coefficients,
        pixels,
        scale,
        range_min,
        range_max,
        np.asarray(plane.normal, dtype=np.float64),
        plane.offset,
        below,
        np.asarray(SEEN_MARGIN),
        out,
        *profile_arrays(profile),
    )
    return out
