"""Occupancy grid mapping from scans and poses, the map_server format, and map comparison.

The grid is the classic log-odds one: every scan marks the cell of each return
occupied and the cells its ray crossed free. Rays are traced by sampling every
half cell along them (vectorised over the whole scan), and each cell is updated
at most once per scan, occupied winning over free, so cells near the sensor
(crossed by many rays) are not over-counted.

`save_map` writes what Nav2's map_saver writes and map_server loads: a binary
PGM (occupied 0, free 254, unknown 205) with row 0 at the top (largest y) and a
YAML file with image, mode trinary, resolution, origin, negate, occupied_thresh
and free_thresh.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import yaml
from matplotlib.path import Path as PolygonPath

from scanfuse.errors import InputError

if TYPE_CHECKING:
    from collections.abc import Iterable
    from pathlib import Path

    import numpy.typing as npt

    from scanfuse.scan import Scan

    Mask = npt.NDArray[np.bool_]

# Nav2 map_server defaults; also the thresholds the saved YAML declares.
OCCUPIED_THRESH = 0.65
FREE_THRESH = 0.25
PGM_OCCUPIED = 0
PGM_FREE = 254
PGM_UNKNOWN = 205


@dataclass(frozen=True)
class GridSpec:
    """Where a grid lies: cell size (m), lower-left corner (m), size in cells."""

    resolution: float
    origin: tuple[float, float]
    width: int
    height: int

    def __post_init__(self) -> None:
        if not self.resolution > 0.0 or not math.isfinite(self.resolution):
            msg = f'grid resolution must be a positive number of metres, got {self.resolution}'
            raise InputError(msg)
        if self.width <= 0 or self.height <= 0:
            msg = f'grid size must be positive, got {self.width} x {self.height} cells'
            raise InputError(msg)

    @classmethod
    def covering(
        cls, bounds: tuple[float, float, float, float], resolution: float, margin: float = 0.5
    ) -> GridSpec:
        """A grid over x_min, x_max, y_min, y_max (metres) plus `margin` on every side."""
        x_min, x_max, y_min, y_max = bounds
        width = math.ceil((x_max - x_min + 2 * margin) / resolution)
        height = math.ceil((y_max - y_min + 2 * margin) / resolution)
        return cls(resolution, (x_min - margin, y_min - margin), width, height)

    def cell_of(
        self, x: npt.NDArray[np.float64], y: npt.NDArray[np.float64]
    ) -> tuple[npt.NDArray[np.intp], npt.NDArray[np.intp], Mask]:
        """Column, row of the cells holding points (x, y), and which points lie on the grid."""
        column = np.floor((x - self.origin[0]) / self.resolution).astype(np.intp)
        row = np.floor((y - self.origin[1]) / self.resolution).astype(np.intp)
        inside = (column >= 0) & (column < self.width) & (row >= 0) & (row < self.height)
        return column, row, inside

    def centres(self) -> tuple[npt.NDArray[np.float64], npt.NDArray[np.float64]]:
        """x and y of every cell centre, each shaped (height, width); row 0 is the lowest y."""
        xs = self.origin[0] + (np.arange(self.width) + 0.5) * self.resolution
        ys = self.origin[1] + (np.arange(self.height) + 0.5) * self.resolution
        return np.meshgrid(xs, ys)


@dataclass
class OccupancyGrid:
    """A log-odds occupancy grid; `log_odds[row, column]`, row 0 at the lowest y."""

    spec: GridSpec
    hit: float = 0.85  # log-odds added to a cell a return ends in (p = 0.7)
    miss: float = -0.4  # log-odds added to a cell a ray crosses (p = 0.4)
    clamp: float = 4.0
    free_range: float = 5.0  # how far a +Inf (no return) reading clears, metres
    log_odds: npt.NDArray[np.float64] = field(init=False)

    def __post_init__(self) -> None:
        self.log_odds = np.zeros((self.spec.height, self.spec.width))

    def integrate(self, scan: Scan, x: float, y: float, yaw: float) -> None:
        """Add one scan taken from a sensor at (x, y) heading `yaw` (world frame)."""
        ranges = scan.ranges.astype(np.float64)
        angles = scan.angles() + yaw
        returns = np.isfinite(ranges) & (ranges >= scan.range_min) & (ranges <= scan.range_max)
        free_length = np.where(returns, ranges, np.nan)
        # +Inf is REP-117 "nothing within range": the whole ray up to free_range is free.
        free_length[np.isposinf(ranges)] = min(self.free_range, scan.range_max)
        free = self._traced_cells(x, y, angles, free_length)
        ends_x = x + ranges[returns] * np.cos(angles[returns])
        ends_y = y + ranges[returns] * np.sin(angles[returns])
        column, row, inside = self.spec.cell_of(ends_x, ends_y)
        occupied = self._cells(row[inside] * self.spec.width + column[inside])
        free &= ~occupied
        flat = self.log_odds.reshape(-1)
        flat[free] += self.miss
        flat[occupied] += self.hit
        np.clip(flat, -self.clamp, self.clamp, out=flat)

    def _cells(self, flat_indices: npt.NDArray[np.intp]) -> Mask:
        """The grid's cells (flat, one flag each) that `flat_indices` name, each once: a mask
        instead of `np.unique`, whose sort cost most of an evaluation's mapping time."""
        cells = np.zeros(self.spec.width * self.spec.height, dtype=np.bool_)
        cells[flat_indices] = True
        return cells

    def _traced_cells(
        self, x: float, y: float, angles: npt.NDArray[np.float64], lengths: npt.NDArray[np.float64]
    ) -> Mask:
        """The cells (flat mask) that rays cross before their end (half-cell sampling)."""
        usable = np.isfinite(lengths) & (lengths > 0.0)
        if not usable.any():
            return self._cells(np.zeros(0, dtype=np.intp))
        step = self.spec.resolution / 2
        lengths = lengths[usable]
        angles = angles[usable]
        samples = np.arange(0.0, float(lengths.max()), step)
        # Stop half a cell short of the return so its own cell is not cleared.
        reach = samples[np.newaxis, :] < (lengths[:, np.newaxis] - step)
        distance = np.broadcast_to(samples, reach.shape)[reach]
        ray = np.nonzero(reach)[0]
        column, row, inside = self.spec.cell_of(
            x + distance * np.cos(angles)[ray], y + distance * np.sin(angles)[ray]
        )
        return self._cells(row[inside] * self.spec.width + column[inside])

    def probability(self) -> npt.NDArray[np.float64]:
        probability: npt.NDArray[np.float64] = 1.0 / (1.0 + np.exp(-self.log_odds))
        return probability

    def occupied(self) -> Mask:
        occupied: Mask = self.probability() >= OCCUPIED_THRESH
        return occupied

    def free(self) -> Mask:
        free: Mask = self.probability() <= FREE_THRESH
        return free


def save_map(grid: OccupancyGrid, path_stem: Path) -> tuple[Path, Path]:
    """Write `<stem>.pgm` and `<stem>.yaml` in the map_server format (mode trinary)."""
    pgm = path_stem.with_suffix('.pgm')
    description = path_stem.with_suffix('.yaml')
    pixels = np.full(grid.log_odds.shape, PGM_UNKNOWN, dtype=np.uint8)
    pixels[grid.free()] = PGM_FREE
    pixels[grid.occupied()] = PGM_OCCUPIED
    # Image row 0 is the top of the map, the largest y.
    pixels = pixels[::-1]
    height, width = grid.spec.height, grid.spec.width
    header = f'P5\n# scanfuse occupancy grid\n{width} {height}\n255\n'.encode('ascii')
    pgm.write_bytes(header + pixels.tobytes())
    document = {
        'image': pgm.name,
        'mode': 'trinary',
        'resolution': grid.spec.resolution,
        'origin': [grid.spec.origin[0], grid.spec.origin[1], 0.0],
        'negate': 0,
        'occupied_thresh': OCCUPIED_THRESH,
        'free_thresh': FREE_THRESH,
    }
    description.write_text(yaml.safe_dump(document, sort_keys=False), encoding='utf-8')
    return pgm, description


def read_pgm(path: Path) -> npt.NDArray[np.uint8]:
    """A binary (P5) 8-bit PGM as a (height, width) array, row 0 at the top of the image."""
    data = path.read_bytes()
    fields: list[bytes] = []
    position = 0
    while len(fields) < 4:
        while data[position : position + 1].isspace():
            position += 1
        if data[position : position + 1] == b'#':
            position = data.index(b'\n', position) + 1
            continue
        end = position
        while not data[end : end + 1].isspace():
            end += 1
        fields.append(data[position:end])
        position = end
    if fields[0] != b'P5' or int(fields[3]) > 255:
        msg = f'{path} is not an 8-bit binary PGM (P5); map_server maps are written that way'
        raise InputError(msg)
    width, height = int(fields[1]), int(fields[2])
    pixels = np.frombuffer(data, dtype=np.uint8, count=width * height, offset=position + 1)
    return pixels.reshape(height, width)


def rasterize_footprints(spec: GridSpec, polygons: Iterable[npt.NDArray[np.float64]]) -> Mask:
    """True occupancy: cells whose centre lies in a footprint or that a footprint's edge crosses.

    Edges are sampled every quarter cell so that a chair leg thinner than a
    cell still marks the cell it stands in.
    """
    occupied: Mask = np.zeros((spec.height, spec.width), dtype=bool)
    xs, ys = spec.centres()
    centres = np.column_stack([xs.ravel(), ys.ravel()])
    for polygon in polygons:
        closed = np.vstack([polygon, polygon[:1]])
        lo, hi = polygon.min(axis=0), polygon.max(axis=0)
        near = (
            (centres[:, 0] >= lo[0] - spec.resolution)
            & (centres[:, 0] <= hi[0] + spec.resolution)
            & (centres[:, 1] >= lo[1] - spec.resolution)
            & (centres[:, 1] <= hi[1] + spec.resolution)
        )
        inside = np.zeros(centres.shape[0], dtype=bool)
        inside[near] = PolygonPath(closed).contains_points(centres[near])
        occupied |= inside.reshape(occupied.shape)
        for start, end in itertools.pairwise(closed):
            count = max(2, math.ceil(np.hypot(*(end - start)) / (spec.resolution / 4)) + 1)
            t = np.linspace(0.0, 1.0, count)[:, np.newaxis]
            points = start + t * (end - start)
            column, row, on_grid = spec.cell_of(points[:, 0], points[:, 1])
            occupied[row[on_grid], column[on_grid]] = True
    return occupied


def dilate(mask: Mask, radius_cells: float) -> Mask:
    """Every cell within `radius_cells` (Euclidean, in cells) of a set cell, set."""
    out: Mask = mask.copy()
    height, width = mask.shape
    reach = math.floor(radius_cells)
    for dy in range(-reach, reach + 1):
        for dx in range(-reach, reach + 1):
            if dx * dx + dy * dy > radius_cells * radius_cells or (dx == 0 and dy == 0):
                continue
            source = mask[max(0, -dy) : height - max(0, dy), max(0, -dx) : width - max(0, dx)]
            out[max(0, dy) : height - max(0, -dy), max(0, dx) : width - max(0, -dx)] |= source
    return out


@dataclass(frozen=True)
class MapAgreement:
    """Occupied cells of an estimated map against the true footprint map.

    precision: estimated occupied cells with a true one within the tolerance;
    recall: true occupied cells that were observed (a known cell of the
    estimated map within the tolerance) with an estimated occupied one within
    the tolerance; iou: intersection over union of the occupied cells, exact,
    inside the observed region.
    """

    precision: float
    recall: float
    iou: float
    occupied_cells: int
    true_cells: int


def compare_maps(estimated: OccupancyGrid, truth: Mask, tolerance_cells: int = 1) -> MapAgreement:
    """How well the occupied cells of `estimated` match the true footprint map `truth`."""
    if truth.shape != estimated.log_odds.shape:
        msg = (
            f'the true map is {truth.shape[1]}x{truth.shape[0]} cells, the estimated '
            f'{estimated.spec.width}x{estimated.spec.height}; rasterize it with the same GridSpec'
        )
        raise InputError(msg)
    occupied = estimated.occupied()
    known = occupied | estimated.free()
    observed = dilate(known, tolerance_cells)
    true_seen = truth & observed
    near_truth = dilate(truth, tolerance_cells)
    near_estimate = dilate(occupied, tolerance_cells)
    precision = _share(occupied & near_truth, occupied)
    recall = _share(true_seen & near_estimate, true_seen)
    union = (occupied | truth) & observed
    iou = _share(occupied & truth & observed, union)
    return MapAgreement(precision, recall, iou, int(occupied.sum()), int(true_seen.sum()))


def _share(part: Mask, whole: Mask) -> float:
    total = int(whole.sum())
    return int(part.sum()) / total if total else float('nan')
