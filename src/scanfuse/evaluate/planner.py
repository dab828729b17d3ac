"""Planning and safety for the closed-loop trials: A* on an inflated grid, stop/slow zones.

The controller is deliberately simple, the way a Nav2 setup with a collision
monitor behaves: whatever the scan shows inside a stop zone around the
footprint halts forward motion, inside a slow zone it slows, and the path is
replanned on a grid of everything the scans have shown, inflated by the robot's
radius. A robot driven this way is as safe as its scan: what the scan misses,
it hits.
"""

from __future__ import annotations

import heapq
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from scanfuse.compiled import compiled
from scanfuse.errors import InputError
from scanfuse.evaluate.mapping import dilate

if TYPE_CHECKING:
    import numpy.typing as npt

    Mask = npt.NDArray[np.bool_]

Cell = tuple[int, int]  # (row, column)
_SQRT2 = math.sqrt(2.0)


def disk_offsets(radius_cells: float) -> list[Cell]:
    """Cell offsets within `radius_cells` of the centre (Euclidean)."""
    reach = math.floor(radius_cells)
    return [
        (dy, dx)
        for dy in range(-reach, reach + 1)
        for dx in range(-reach, reach + 1)
        if dx * dx + dy * dy <= radius_cells * radius_cells
    ]


def inflate(blocked: Mask, radius_cells: float) -> Mask:
    """Cells within `radius_cells` of a blocked cell: where the robot's centre must not go."""
    return dilate(blocked, radius_cells)


def _astar_loop(blocked: Any, start: int, goal: int, width: int, parent: Any) -> bool:
    """A* over flat cell indices; fills `parent`, True when `goal` was reached.

    Plain Python over arrays so that numba can compile it; runs as is without numba.
    """
    height = blocked.size // width
    best = np.full(blocked.size, np.inf)
    best[start] = 0.0
    goal_row, goal_column = goal // width, goal % width
    rows = (-1, 1, 0, 0, -1, -1, 1, 1)
    columns = (0, 0, -1, 1, -1, 1, -1, 1)
    steps = (1.0, 1.0, 1.0, 1.0, _SQRT2, _SQRT2, _SQRT2, _SQRT2)
    frontier = [(0.0, 0.0, start)]
    while frontier:
        _, cost, cell = heapq.heappop(frontier)
        if cell == goal:
            return True
        if cost > best[cell]:
            continue
        row, column = cell // width, cell % width
        for k in range(8):
            nr, nc = row + rows[k], column + columns[k]
            if nr < 0 or nr >= height or nc < 0 or nc >= width or blocked[nr * width + nc]:
                continue
            # A diagonal step may not cut the corner of a blocked cell.
            if k >= 4 and (blocked[row * width + nc] or blocked[nr * width + column]):
                continue
            new_cost = cost + steps[k]
            neighbour = nr * width + nc
            if new_cost < best[neighbour]:
                best[neighbour] = new_cost
                parent[neighbour] = cell
                dy, dx = abs(nr - goal_row), abs(nc - goal_column)
                # Octile distance: exact on an empty grid, so admissible and consistent.
                heuristic = max(dy, dx) + (_SQRT2 - 1.0) * min(dy, dx)
                heapq.heappush(frontier, (new_cost + heuristic, new_cost, neighbour))
    return False


_KERNEL = compiled(_astar_loop)


def astar(blocked: Mask, start: Cell, goal: Cell, *, compiled: bool = True) -> list[Cell] | None:
    """Shortest 8-connected path of free cells from `start` to `goal` (both included).

    Diagonal steps cost sqrt(2) and may not cut the corner of a blocked cell.
    None when no path exists. A blocked start is allowed (the robot may stand in
    inflation) so that it can drive out. `compiled=False` runs the same loop
    without numba.
    """
    height, width = blocked.shape
    for name, cell in (('start', start), ('goal', goal)):
        if not (0 <= cell[0] < height and 0 <= cell[1] < width):
            msg = f'A* {name} cell {cell} lies outside the {height}x{width} grid'
            raise InputError(msg)
    if blocked[goal]:
        return None
    flat = np.ascontiguousarray(blocked, dtype=np.bool_).reshape(-1)
    parent = np.full(flat.size, -1, dtype=np.int64)
    first, last = start[0] * width + start[1], goal[0] * width + goal[1]
    kernel = _KERNEL if compiled else _astar_loop
    if not kernel(flat, first, last, width, parent):
        return None
    path = [last]
    while path[-1] != first:
        path.append(int(parent[path[-1]]))
    return [(cell // width, cell % width) for cell in reversed(path)]


def path_length(path: list[Cell], resolution: float = 1.0) -> float:
    """Length of a cell path, metres when `resolution` is the cell size."""
    cells = np.asarray(path, dtype=np.float64)
    if cells.shape[0] < 2:
        return 0.0
    return float(np.hypot(*np.diff(cells, axis=0).T).sum() * resolution)


@dataclass(frozen=True)
class SafetyZones:
    """Collision-monitor-style zones ahead of a round footprint (robot frame, metres).

    A point ahead of the robot (x > 0) within `stop` of the footprint's edge
    and inside the corridor the footprint sweeps stops forward motion; within
    `slow` it limits the speed to `slow_factor` of the command.
    """

    radius: float
    stop: float = 0.08
    slow: float = 0.45
    slow_factor: float = 0.4
    corridor_margin: float = 0.04

    def limit(self, v: float, points: npt.NDArray[np.float64]) -> float:
        """The forward speed allowed with obstacle points (N, 2) around the robot."""
        if v <= 0.0 or points.size == 0:
            return v
        x, y = points[:, 0], points[:, 1]
        ahead = (x > 0.0) & (np.abs(y) <= self.radius + self.corridor_margin)
        # Distance from the footprint's front edge along the direction of travel.
        gap = x - np.sqrt(np.maximum(self.radius**2 - y**2, 0.0))
        if np.any(ahead & (gap <= self.stop)):
            return 0.0
        if np.any(ahead & (gap <= self.slow)):
            return v * self.slow_factor
        return v
