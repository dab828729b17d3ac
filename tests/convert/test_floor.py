"""Range trade-off (equations 4-6), exact floor intersection, and the row method's floor guard."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from scanfuse.camera import CameraModel
from scanfuse.convert.floor import (
    FloorGuard,
    floor_range_limit,
    paper_max_range,
    paper_max_range_closed_form,
)
from scanfuse.convert.row import row_scan
from scanfuse.errors import ConfigError

# cx, cy integers: the centre column's ray has x_n = 0 exactly.
CAMERA = CameraModel.from_intrinsics(640, 480, 525.0, 525.0, 320.0, 240.0)


def test_equation_4_by_hand() -> None:
    # h = 0.5 m, pitched 30 deg down, the centre row: l' = 0.5 / sin(30 deg) = 1 m.
    assert paper_max_range(0.5, math.radians(30.0), 0.0) == pytest.approx(1.0)
    # 20 deg pitch plus a row 10 deg below the axis: 0.5 / sin(30 deg) again.
    assert paper_max_range(0.5, math.radians(20.0), math.radians(10.0)) == pytest.approx(1.0)


def test_equation_4_is_infinite_when_the_sight_line_does_not_descend() -> None:
    assert paper_max_range(0.5, 0.0, 0.0) == math.inf
    assert paper_max_range(0.5, math.radians(10.0), math.radians(-10.0)) == math.inf
    assert paper_max_range(0.5, math.radians(10.0), math.radians(-25.0)) == math.inf


@given(
    height=st.floats(0.05, 3.0),
    pitch=st.floats(-1.2, 1.2),
    v=st.floats(0.0, 1079.0),
    cy=st.floats(200.0, 800.0),
    fy=st.floats(200.0, 1500.0),
)
def test_equation_6_equals_equation_4(
    height: float, pitch: float, v: float, cy: float, fy: float
) -> None:
    row_angle = math.atan((v - cy) / fy)
    expected = paper_max_range(height, pitch, row_angle)
    closed = paper_max_range_closed_form(height, pitch, v, cy, fy)
    if math.isinf(expected) or math.isinf(closed):
        # Both agree the line does not descend, up to rounding at exactly horizontal.
        assert abs(math.sin(pitch + row_angle)) < 1e-9 or math.isinf(expected) == math.isinf(closed)
    else:
        assert closed == pytest.approx(expected, rel=1e-9)


@pytest.mark.parametrize('pitch_deg', [0.0, 10.0, 25.0, 45.0])
@pytest.mark.parametrize('v', [250, 300, 400, 479, 120])
def test_equation_4_agrees_with_the_exact_floor_intersection_at_the_centre_column(
    pitch_deg: float, v: int
) -> None:
    """Equation 4 gives the slant distance l' along the centre column's sight line; the
    row method's range (equation 3) is r = sqrt(X^2 + Z^2) = Z there (X = 0). The sight
    line leaves the optical axis by beta, so Z = l' cos(beta): r = l' cos(beta).
    """
    height, pitch = 0.45, math.radians(pitch_deg)
    beta = math.atan((v - CAMERA.cy) / CAMERA.fy)
    slant = paper_max_range(height, pitch, beta)
    exact = floor_range_limit(CAMERA, height, pitch, v)[320]
    if math.isinf(slant):
        assert exact == math.inf
    else:
        assert exact == pytest.approx(slant * math.cos(beta), rel=1e-6)


def test_exact_floor_limit_by_hand_off_centre() -> None:
    # fx = fy = 100, principal point (50, 50), camera 1 m up, level. Pixel (150, 150):
    # x_n = y_n = 1, the ray (1, 1, 1) meets the floor at Z = 1, X = 1: r = sqrt(2).
    camera = CameraModel.from_intrinsics(200, 200, 100.0, 100.0, 50.0, 50.0)
    limits = floor_range_limit(camera, 1.0, 0.0, 150)
    assert limits[150] == pytest.approx(math.sqrt(2.0), rel=1e-6)
    assert limits[50] == pytest.approx(1.0, rel=1e-6)
    # Looking 45 deg down, the centre pixel's ray meets the floor sqrt(2) m away: Z = sqrt(2).
    assert floor_range_limit(camera, 1.0, math.radians(45.0), 50)[50] == pytest.approx(
        math.sqrt(2.0), rel=1e-6
    )
    # A level camera's rows above the centre never meet the floor.
    assert np.all(np.isinf(floor_range_limit(camera, 1.0, 0.0, 20)))


def test_floor_functions_reject_bad_poses() -> None:
    with pytest.raises(ConfigError, match='camera_height must be a positive number'):
        paper_max_range(0.0, 0.3, 0.0)
    with pytest.raises(ConfigError, match='camera_pitch must be finite'):
        paper_max_range_closed_form(0.5, math.nan, 100.0, 240.0, 525.0)
    with pytest.raises(ConfigError, match=r'scan_row 480 is outside the image rows 0\.\.479'):
        floor_range_limit(CAMERA, 0.5, 0.3, 480)


# --- the floor guard on a synthetic flat floor -------------------------------------------


def _floor_image(camera: CameraModel, height: float, pitch: float) -> np.ndarray:
    """Depth of a flat floor seen by a camera `height` up, pitched down by `pitch`.

    The ray (x_n, y_n, 1) descends by y_n cos(p) + sin(p) per metre of Z, so it meets the
    floor at Z = h / (y_n cos p + sin p); +Inf where it never does.
    """
    v = np.arange(camera.height, dtype=np.float64)[:, None]
    y_n = (v - camera.cy) / camera.fy
    descent = y_n * math.cos(pitch) + math.sin(pitch)
    with np.errstate(divide='ignore'):
        depth = np.where(descent > 0.0, height / descent, np.inf)
    return np.broadcast_to(depth, (camera.height, camera.width)).astype(np.float32)


CASES = [
    (pitch_deg, v)
    for pitch_deg in (0.0, 5.0, 15.0, 30.0, 45.0)
    for v in (100, 200, 260, 300, 380, 470)
]


@pytest.mark.parametrize(('pitch_deg', 'v'), CASES)
def test_floor_guard_never_reports_the_floor(pitch_deg: float, v: int) -> None:
    height, pitch = 0.45, math.radians(pitch_deg)
    depth = _floor_image(CAMERA, height, pitch)
    guard = FloorGuard(camera_height=height, camera_pitch=pitch)
    guarded = row_scan(depth, CAMERA, scan_row=v, range_min=0.1, range_max=10.0, floor_guard=guard)
    assert not np.isfinite(guarded.ranges).any()
    assert np.all(guarded.ranges == np.inf)

    plain = row_scan(depth, CAMERA, scan_row=v, range_min=0.1, range_max=10.0)
    centre_floor = height / ((v - CAMERA.cy) / CAMERA.fy * math.cos(pitch) + math.sin(pitch))
    if 0.0 < centre_floor < 10.0:
        # Without the guard the floor straight ahead is an obstacle (the paper's Figure 10).
        assert np.isfinite(plain.ranges).any()


def test_floor_guard_keeps_a_real_obstacle_on_the_floor() -> None:
    height, pitch, v = 0.45, math.radians(30.0), 300
    depth = _floor_image(CAMERA, height, pitch)
    box = slice(300, 341)
    depth[:, box] *= 0.5  # a box standing at half the floor distance in the middle columns
    guard = FloorGuard(camera_height=height, camera_pitch=pitch)
    scan = row_scan(depth, CAMERA, scan_row=v, range_min=0.1, range_max=10.0, floor_guard=guard)
    finite = scan.ranges[np.isfinite(scan.ranges)]
    assert finite.size > 0
    floor_z = height / ((v - CAMERA.cy) / CAMERA.fy * math.cos(pitch) + math.sin(pitch))
    # Columns 300..340: x_n at most 20/525, so r within 0.1 % of Z = floor_z / 2.
    np.testing.assert_allclose(finite, 0.5 * floor_z, rtol=2e-3)


def test_floor_guard_margin_keeps_points_just_short_of_the_floor() -> None:
    height, pitch, v = 0.45, math.radians(30.0), 300
    depth = _floor_image(CAMERA, height, pitch)
    depth[v, 320] -= 0.10  # 10 cm short of the floor in the centre column
    for margin, reported in ((0.05, True), (0.15, False)):
        guard = FloorGuard(camera_height=height, camera_pitch=pitch, margin=margin)
        scan = row_scan(depth, CAMERA, scan_row=v, range_min=0.1, range_max=10.0, floor_guard=guard)
        assert np.isfinite(scan.ranges).any() == reported


@pytest.mark.parametrize('dtype', [np.uint16, np.float32])
def test_margin_wider_than_the_floor_distance_cuts_every_pixel(dtype: type) -> None:
    # 0.1 m up, looking 60 deg down: the floor is about 0.11 m away straight ahead, less
    # than the 0.25 m margin, so every measured pixel of the row counts as floor.
    guard = FloorGuard(camera_height=0.1, camera_pitch=math.radians(60.0), margin=0.25)
    depth = np.full((CAMERA.height, CAMERA.width), 3, dtype=dtype)  # 3 mm or 3 m
    scan = row_scan(depth, CAMERA, range_min=0.0, range_max=5.0, floor_guard=guard)
    assert np.all(scan.ranges == np.inf)
