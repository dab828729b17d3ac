"""The row method on a real Kinect-class depth frame (PCL grabber test sequence).

The camera looks down at a carpet, a laptop and a box; every row is converted and
each slot is checked against the back-projection of that row's own pixels,
computed here independently of scanfuse.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import pytest
import tifffile

from scanfuse.camera import CameraModel
from scanfuse.convert.row import row_scan

if TYPE_CHECKING:
    from pathlib import Path

FRAME = 'pcl_grabber/frame_20121214T142255.814212_depth.tiff'
CAMERA = CameraModel.from_intrinsics(640, 480, 525.0, 525.0, 320.0, 240.0)
RANGE_MIN, RANGE_MAX = 0.2, 10.0


@pytest.fixture(scope='module')
def depth(real_data: Path) -> np.ndarray:
    image = tifffile.imread(real_data / FRAME)
    assert image.shape == (480, 640)
    assert image.dtype == np.uint16
    return image


def _back_projected_ranges(row: np.ndarray) -> np.ndarray:
    """Equation 3 from the pixels: X = (u - cx) Z / fx, r = sqrt(X^2 + Z^2); NaN if invalid."""
    z = np.where(row > 0, row.astype(np.float64) / 1000.0, np.nan)
    x = (np.arange(row.size) - CAMERA.cx) * z / CAMERA.fx
    return np.sqrt(x * x + z * z)


@pytest.mark.real_data
def test_every_row_matches_its_back_projected_pixels(depth: np.ndarray) -> None:
    pixel_angles = -np.arctan((np.arange(CAMERA.width) - CAMERA.cx) / CAMERA.fx)
    finite_slots = 0
    for v in range(CAMERA.height):
        scan = row_scan(depth, CAMERA, scan_row=v, range_min=RANGE_MIN, range_max=RANGE_MAX)
        ranges = scan.ranges.astype(np.float64)
        pixels = _back_projected_ranges(depth[v])
        in_limits = (pixels >= RANGE_MIN) & (pixels <= RANGE_MAX)
        # Slot of each pixel: the nearest centre, leaving out pixels within rounding of a
        # boundary between two slots.
        position = (pixel_angles - scan.angle_min) / scan.angle_increment
        slot = np.rint(position).astype(int)
        clear = np.abs(position - slot) < 0.5 - 1e-6

        winners = ranges[np.isfinite(ranges)]
        # Every winner is the range of a pixel of this row...
        candidates = np.sort(pixels[np.isfinite(pixels)])
        above = np.clip(np.searchsorted(candidates, winners), 0, candidates.size - 1)
        below = np.clip(above - 1, 0, candidates.size - 1)
        nearest = np.minimum(
            np.abs(candidates[above] - winners), np.abs(candidates[below] - winners)
        )
        assert np.all(nearest <= 2e-6 * winners), v
        # ...and no in-limits pixel of its slot is nearer.
        nearest_member = np.full(len(scan), np.inf)
        members = clear & in_limits & (slot >= 0) & (slot < len(scan))
        np.minimum.at(nearest_member, slot[members], pixels[members])
        assert np.all(
            ranges[np.isfinite(ranges)] <= nearest_member[np.isfinite(ranges)] * (1 + 1e-6)
        )
        # A slot with an in-limits pixel reports a finite range.
        with_values = np.unique(slot[clear & in_limits])
        assert np.all(np.isfinite(ranges[with_values])), v
        finite_slots += int(np.isfinite(ranges).sum())
    # The frame is mostly valid: most slots of most rows are finite.
    assert finite_slots > 0.5 * CAMERA.height * len(scan)
