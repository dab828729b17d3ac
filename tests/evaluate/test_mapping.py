"""Occupancy grid mapping, the map_server files and map comparison, on hand-built geometry."""

from __future__ import annotations

import math

import numpy as np
import pytest
import yaml

from scanfuse.errors import InputError
from scanfuse.evaluate.mapping import (
    PGM_FREE,
    PGM_OCCUPIED,
    PGM_UNKNOWN,
    GridSpec,
    OccupancyGrid,
    compare_maps,
    dilate,
    rasterize_footprints,
    read_pgm,
    save_map,
)
from scanfuse.scan import Scan

HALF = 1.0  # the square room's inner faces are at x, y = +-1 m


def square_room_scan(count: int = 720) -> Scan:
    """A 360-degree scan from the centre of the square: r = 1 / max(|cos|, |sin|)."""
    angles = -math.pi + 2 * math.pi / count * np.arange(count)
    ranges = HALF / np.maximum(np.abs(np.cos(angles)), np.abs(np.sin(angles)))
    return Scan(-math.pi, angles[-1], 2 * math.pi / count, 0.1, 10.0, ranges.astype(np.float32))


def room_walls() -> list[np.ndarray]:
    t = 0.1

    def rect(x0, x1, y0, y1):
        return np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]])

    return [
        rect(HALF, HALF + t, -HALF - t, HALF + t),
        rect(-HALF - t, -HALF, -HALF - t, HALF + t),
        rect(-HALF, HALF, HALF, HALF + t),
        rect(-HALF, HALF, -HALF - t, -HALF),
    ]


SPEC = GridSpec(0.05, (-1.5, -1.5), 60, 60)


def centre_cell(x: float, y: float) -> tuple[int, int]:
    return int((y + 1.5) // 0.05), int((x + 1.5) // 0.05)


@pytest.fixture
def room_map() -> OccupancyGrid:
    grid = OccupancyGrid(SPEC)
    # Three misses (3 x -0.4 = -1.2 < logit(0.25) = -1.10) make a cell free.
    for _ in range(3):
        grid.integrate(square_room_scan(), 0.0, 0.0, 0.0)
    return grid


def test_two_misses_are_not_yet_free_three_are():
    grid = OccupancyGrid(SPEC)
    for _ in range(2):
        grid.integrate(square_room_scan(), 0.0, 0.0, 0.0)
    assert grid.probability()[centre_cell(0.0, 0.0)] == pytest.approx(1 / (1 + math.exp(0.8)))
    assert not grid.free()[centre_cell(0.0, 0.0)]
    grid.integrate(square_room_scan(), 0.0, 0.0, 0.0)
    assert grid.free()[centre_cell(0.0, 0.0)]


def test_square_room_from_its_centre(room_map):
    occupied, free = room_map.occupied(), room_map.free()
    # Inside the room: free; the wall cells just past each face: occupied; behind: unknown.
    assert free[centre_cell(0.0, 0.0)]
    assert free[centre_cell(0.5, -0.5)]
    assert occupied[centre_cell(1.02, 0.0)]
    assert occupied[centre_cell(-0.98, 0.3)]  # the -x face at -1.0 lies in the cell [-1.0, -0.95)
    assert occupied[centre_cell(0.3, 1.02)]
    behind = centre_cell(1.3, 0.0)
    assert not occupied[behind]
    assert not free[behind]
    # Every occupied cell touches the square's boundary |x| = 1 or |y| = 1.
    xs, ys = SPEC.centres()
    edge = np.maximum(np.abs(xs), np.abs(ys))
    assert np.all(np.abs(edge[occupied] - HALF) <= 0.05)


def test_yaw_turns_the_scan(room_map):
    # The square is symmetric under a quarter turn: the same map.
    turned = OccupancyGrid(SPEC)
    for _ in range(3):
        turned.integrate(square_room_scan(), 0.0, 0.0, math.pi / 2)
    assert np.array_equal(turned.occupied(), room_map.occupied())


def test_no_return_clears_up_to_free_range():
    grid = OccupancyGrid(SPEC, free_range=0.5, miss=-2.0)
    scan = square_room_scan()
    grid.integrate(scan.with_ranges(np.full(len(scan), np.inf, dtype=np.float32)), 0.0, 0.0, 0.0)
    assert not grid.occupied().any()
    assert grid.free()[centre_cell(0.4, 0.0)]
    assert not grid.free()[centre_cell(0.7, 0.0)]


def test_save_map_writes_what_map_server_loads(room_map, tmp_path):
    pgm, description = save_map(room_map, tmp_path / 'room')
    document = yaml.safe_load(description.read_text())
    assert document == {
        'image': 'room.pgm',
        'mode': 'trinary',
        'resolution': 0.05,
        'origin': [-1.5, -1.5, 0.0],
        'negate': 0,
        'occupied_thresh': 0.65,
        'free_thresh': 0.25,
    }
    pixels = read_pgm(pgm)
    assert pixels.shape == (60, 60)
    assert set(np.unique(pixels)) == {PGM_OCCUPIED, PGM_FREE, PGM_UNKNOWN}
    # Row 0 of the image is the top of the map (largest y).
    row, column = centre_cell(0.3, 1.02)
    assert pixels[59 - row, column] == PGM_OCCUPIED
    row, column = centre_cell(0.0, 0.0)
    assert pixels[59 - row, column] == PGM_FREE


def test_read_pgm_rejects_other_formats(tmp_path):
    path = tmp_path / 'ascii.pgm'
    path.write_bytes(b'P2\n2 1\n255\n0 0\n')
    with pytest.raises(InputError, match='binary PGM'):
        read_pgm(path)


def test_rasterize_a_square_and_a_thin_leg():
    spec = GridSpec(0.1, (0.0, 0.0), 10, 10)
    square = np.array([[0.2, 0.2], [0.5, 0.2], [0.5, 0.5], [0.2, 0.5]])
    leg = np.array([[0.81, 0.81], [0.83, 0.81], [0.83, 0.83], [0.81, 0.83]])
    truth = rasterize_footprints(spec, [square, leg])
    # Square [0.2, 0.5]^2: cells 2..4 inside, plus cell 5 that its far edges at 0.5 touch.
    expected = np.zeros((10, 10), dtype=bool)
    expected[2:6, 2:6] = True
    expected[8, 8] = True  # a leg thinner than a cell still marks its cell
    assert np.array_equal(truth, expected)


def test_compare_maps_of_the_room(room_map):
    truth = rasterize_footprints(SPEC, room_walls())
    agreement = compare_maps(room_map, truth)
    assert agreement.precision == 1.0
    assert agreement.recall == 1.0
    # Walls are two cells thick and the scan sees only the inner one: IoU about a half.
    assert 0.4 < agreement.iou < 0.6


def test_compare_maps_counts_a_phantom():
    grid = OccupancyGrid(SPEC)
    for _ in range(3):
        grid.integrate(square_room_scan(), 0.0, 0.0, 0.0)
    grid.log_odds[centre_cell(0.0, 0.5)] = 4.0  # an obstacle that is not there
    agreement = compare_maps(grid, rasterize_footprints(SPEC, room_walls()))
    occupied = agreement.occupied_cells
    assert agreement.precision == pytest.approx((occupied - 1) / occupied)


def test_compare_maps_needs_the_same_grid(room_map):
    with pytest.raises(InputError, match='same GridSpec'):
        compare_maps(room_map, np.zeros((5, 5), dtype=bool))


def test_dilate_by_one_cell_is_a_plus_and_by_1_5_a_square():
    mask = np.zeros((5, 5), dtype=bool)
    mask[2, 2] = True
    assert dilate(mask, 1).sum() == 5
    assert dilate(mask, 1.5).sum() == 9


def test_grid_spec_errors():
    with pytest.raises(InputError, match='positive number of metres'):
        GridSpec(0.0, (0.0, 0.0), 10, 10)
    with pytest.raises(InputError, match='grid size must be positive'):
        GridSpec(0.05, (0.0, 0.0), 0, 10)


def test_covering_spans_bounds_and_margin():
    spec = GridSpec.covering((-1.0, 2.0, 0.0, 1.0), 0.1, margin=0.5)
    assert spec.origin == (-1.5, -0.5)
    assert (spec.width, spec.height) == (40, 20)
