"""Matplotlib figures (PNG, labelled axes with units) for reports and the demo."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import matplotlib as mpl

mpl.use('Agg')  # files only: robots and CI have no screen
import matplotlib.pyplot as plt
import numpy as np

from scanfuse.camera import depth_in_metres

if TYPE_CHECKING:
    from pathlib import Path

    import numpy.typing as npt

    from scanfuse.scan import Scan


@dataclass(frozen=True)
class ScanLayer:
    """One scan to draw top-down, with where its origin sits in the plot's frame."""

    label: str
    scan: Scan
    color: str
    origin_xy: tuple[float, float] = (0.0, 0.0)
    origin_yaw: float = 0.0
    size: float = 6.0


def scan_points(layer: ScanLayer) -> npt.NDArray[np.float64]:
    """Finite readings of a scan as (N, 2) x, y points in the plot's frame."""
    ranges = layer.scan.ranges.astype(np.float64)
    finite = np.isfinite(ranges)
    angles = layer.scan.angles()[finite] + layer.origin_yaw
    x = layer.origin_xy[0] + ranges[finite] * np.cos(angles)
    y = layer.origin_xy[1] + ranges[finite] * np.sin(angles)
    return np.column_stack([x, y])


def draw_scans(axes: plt.Axes, layers: list[ScanLayer], *, title: str) -> None:
    """Top-down view, REP-103: x forward (up the page), y left (to the left)."""
    for layer in layers:
        points = scan_points(layer)
        axes.scatter(points[:, 1], points[:, 0], s=layer.size, c=layer.color, label=layer.label)
    axes.scatter([0.0], [0.0], marker='^', s=80, c='black', label='sensor origin')
    if not axes.xaxis_inverted():
        axes.invert_xaxis()  # y points left, as seen from above with x up the page
    axes.set_xlabel('y (m, robot left)')
    axes.set_ylabel('x (m, forward)')
    axes.set_aspect('equal', adjustable='datalim')
    axes.grid(visible=True, alpha=0.3)
    axes.legend(loc='upper right', fontsize=8)
    axes.set_title(title)


def depth_and_scans_figure(
    depth: npt.NDArray[np.generic],
    rows: dict[str, int],
    layers: list[ScanLayer],
    path: Path,
    *,
    title: str,
) -> Path:
    """Depth image with the chosen rows marked, beside a top-down plot of the scans."""
    figure, (left, right) = plt.subplots(1, 2, figsize=(14, 6), layout='constrained')
    metres = depth_in_metres(depth)
    image = left.imshow(metres, cmap='viridis')
    figure.colorbar(image, ax=left, label='depth Z (m)', shrink=0.8)
    colors = plt.get_cmap('tab10')
    for index, (label, row) in enumerate(rows.items()):
        left.axhline(row, color=colors(index), linewidth=1.5, label=f'{label} (row {row})')
    left.set_xlabel('u (pixel column)')
    left.set_ylabel('v (pixel row)')
    left.set_title('depth image; NaN/0 = no measurement (white)')
    if rows:
        left.legend(loc='lower right', fontsize=8)
    draw_scans(right, layers, title=title)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path
