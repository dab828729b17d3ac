"""Matplotlib figures (PNG, labelled axes with units) for reports and the demo."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import matplotlib as mpl

mpl.use('Agg')  # files only: robots and CI have no screen
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.patches import Circle
from matplotlib.ticker import MaxNLocator

from scanfuse.camera import depth_in_metres
from scanfuse.sim.snapshot import draw_footprints

if TYPE_CHECKING:
    from pathlib import Path

    import numpy.typing as npt
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

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


@dataclass(frozen=True)
class SensorMark:
    """Where a sensor sits in a top-down plot's frame, and how it is marked and named."""

    label: str
    xy: tuple[float, float]
    marker: str = '^'
    color: str = 'black'


def draw_scans(
    axes: Axes, layers: list[ScanLayer], *, title: str, sensors: list[SensorMark] | None = None
) -> None:
    """Top-down view, REP-103: x forward (up the page), y left (to the left).

    Each of `sensors` is drawn where it sits, with its label (two sensors at one x, y get
    two markers that both show); without `sensors`, one mark at the origin.
    """
    for layer in layers:
        points = scan_points(layer)
        axes.scatter(points[:, 1], points[:, 0], s=layer.size, c=layer.color, label=layer.label)
    for sensor in sensors or [SensorMark('sensor origin', (0.0, 0.0))]:
        hollow = sensor.marker in {'s', 'o', 'D'}
        axes.scatter(
            [sensor.xy[1]],
            [sensor.xy[0]],
            marker=sensor.marker,
            s=160 if hollow else 70,
            facecolors='none' if hollow else sensor.color,
            edgecolors=sensor.color,
            linewidths=1.5,
            label=sensor.label,
            zorder=3,
        )
    if not axes.xaxis_inverted():
        axes.invert_xaxis()  # y points left, as seen from above with x up the page
    axes.set_xlabel('y (m, robot left)')
    axes.set_ylabel('x (m, forward)')
    axes.set_aspect('equal', adjustable='datalim')
    axes.grid(visible=True, alpha=0.3)
    # Under the plot: inside it, the legend would hide points.
    axes.legend(loc='upper center', bbox_to_anchor=(0.5, -0.12), ncols=2, fontsize=8)
    axes.set_title(title)


def depth_and_scans_figure(
    depth: npt.NDArray[np.generic],
    rows: dict[str, int],
    layers: list[ScanLayer],
    path: Path,
    *,
    title: str,
    sensors: list[SensorMark] | None = None,
) -> Path:
    """Depth image with the chosen rows marked, beside a top-down plot of the scans (and of
    `sensors`, where each sits)."""
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
    draw_scans(right, layers, title=title, sensors=sensors)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


# ---------------------------------------------------------------- evaluation figures

LIDAR_COLOR = 'tab:red'
FUSED_COLOR = 'tab:blue'


@dataclass(frozen=True)
class WorldView:
    """A top-down snapshot of a simulated world: footprints, robot pose, and scans from it."""

    title: str
    footprints: list[tuple[str, npt.NDArray[np.float64]]]  # (kind, polygon) in the world frame
    bounds: tuple[float, float, float, float]
    robot_xy: tuple[float, float]
    robot_yaw: float
    robot_radius: float


def _draw_footprints(axes: Axes, view: WorldView) -> None:
    draw_footprints(axes, view.footprints)  # the simulator's own picture of a world
    robot = Circle(view.robot_xy, view.robot_radius, fill=False, color='black', linewidth=1.5)
    axes.add_patch(robot)
    tip = (
        view.robot_xy[0] + view.robot_radius * np.cos(view.robot_yaw),
        view.robot_xy[1] + view.robot_radius * np.sin(view.robot_yaw),
    )
    axes.plot([view.robot_xy[0], tip[0]], [view.robot_xy[1], tip[1]], color='black')
    x_min, x_max, y_min, y_max = view.bounds
    axes.set_xlim(x_min - 0.3, x_max + 0.3)
    axes.set_ylim(y_min - 0.3, y_max + 0.3)
    axes.set_aspect('equal')
    axes.set_xlabel('x (m, world)')
    axes.set_ylabel('y (m, world)')
    axes.grid(visible=True, alpha=0.3)


def world_scans_figure(view: WorldView, layers: list[ScanLayer], path: Path) -> Path:
    """The world from above with scans drawn where they land (the paper's Figures 22-24).

    Obstacles are grey (light: walls), each layer's points in its colour; the
    layers' `origin_xy`/`origin_yaw` place them in the world frame.
    """
    figure, axes = plt.subplots(figsize=(8, 7), layout='constrained')
    _draw_footprints(axes, view)
    for layer in layers:
        points = scan_points(layer)
        axes.scatter(points[:, 0], points[:, 1], s=layer.size, c=layer.color, label=layer.label)
    axes.legend(loc='upper left', fontsize=8)
    axes.set_title(view.title)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path


def _map_image(
    probability: npt.NDArray[np.float64], occupied: float, free: float
) -> npt.NDArray[np.float64]:
    """Greyscale as map_server shows it: occupied black, free white, unknown grey."""
    image = np.full(probability.shape, 0.8)
    image[probability <= free] = 1.0
    image[probability >= occupied] = 0.0
    return image


def maps_figure(
    panels: list[tuple[str, npt.NDArray[np.float64]]],
    truth: npt.NDArray[np.bool_],
    extent: tuple[float, float, float, float],
    path: Path,
    *,
    title: str,
    thresholds: tuple[float, float] = (0.65, 0.25),
    marks: list[tuple[str, tuple[float, float]]] | None = None,
) -> Path:
    """Occupancy maps side by side, the true footprints outlined in orange on each."""
    figure, axes_row = plt.subplots(
        1, len(panels), figsize=(6.5 * len(panels), 6), layout='constrained', squeeze=False
    )
    for axes, (label, probability) in zip(axes_row[0], panels, strict=True):
        axes.imshow(
            _map_image(probability, *thresholds),
            origin='lower',
            extent=extent,
            cmap='gray',
            vmin=0.0,
            vmax=1.0,
            interpolation='nearest',
        )
        axes.contour(
            truth.astype(float),
            levels=[0.5],
            origin='lower',
            extent=extent,
            colors='tab:orange',
            linewidths=1.0,
        )
        for mark_label, (x, y) in marks or []:
            axes.scatter([x], [y], marker='x', s=120, c='tab:red', label=mark_label)
        if marks:
            axes.legend(loc='upper left', fontsize=8)
        axes.set_title(label)
        axes.set_xlabel('x (m)')
        axes.set_ylabel('y (m)')
    figure.suptitle(f'{title} (black occupied, white free, grey unknown; orange: true footprints)')
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path


def bars_figure(
    methods: list[str], metrics: dict[str, list[float]], path: Path, *, title: str
) -> Path:
    """`bars_plot` written to `path` (PNG)."""
    figure = bars_plot(methods, metrics, title=title)
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path


def bars_plot(methods: list[str], metrics: dict[str, list[float]], *, title: str) -> Figure:
    """One horizontal bar chart per metric, the methods down the shared y axis, each value
    beside its bar; `metrics` maps 'label (unit)' to values.

    Horizontal bars keep every text apart however many methods there are: the names are
    one per row on the left, the values one per row at the bars' ends, the metric under
    its own panel.
    """
    rows = len(methods)
    figure, axes_row = plt.subplots(
        1,
        len(metrics),
        figsize=(3.6 * len(metrics) + 1.6, 0.32 * rows + 1.6),
        layout='constrained',
        sharey=True,
        squeeze=False,
    )
    colors = [
        FUSED_COLOR if m == 'obstacle' else LIDAR_COLOR if m == 'lidar' else '0.55' for m in methods
    ]
    # Space between the panels: one panel's last x tick label off the next one's first.
    figure.get_layout_engine().set(wspace=0.06)  # type: ignore[union-attr, call-arg]
    positions = np.arange(rows)
    for axes, (label, values) in zip(axes_row[0], metrics.items(), strict=True):
        shown = [0.0 if np.isnan(v) else v for v in values]
        axes.barh(positions, shown, color=colors, height=0.7)
        largest = max(shown, default=0.0) or 1.0
        for index, value in enumerate(values):
            text = 'n/a' if np.isnan(value) else f'{value:.3g}'
            axes.text(
                shown[index] + 0.02 * largest, index, text, ha='left', va='center', fontsize=8
            )
        # Room right of the longest bar for its value; no tick label at the right edge,
        # where it would meet the next panel's first.
        axes.set_xlim(0.0, 1.3 * largest)
        axes.xaxis.set_major_locator(MaxNLocator(nbins=5, prune='upper'))
        axes.set_xlabel(label)
        axes.grid(visible=True, axis='x', alpha=0.3)
    first = axes_row[0][0]
    first.set_yticks(positions, methods, fontsize=8)
    first.invert_yaxis()  # the first method at the top, as in the tables
    figure.suptitle(title)
    return figure


def pitch_figure(traces: dict[str, tuple[list[float], list[float]]], path: Path) -> Path:
    """The body's pitch over time (IMU, degrees, positive nose-down) in one trial per label."""
    figure, axes = plt.subplots(figsize=(10, 4.5), layout='constrained')
    for label, (times, pitches) in traces.items():
        axes.plot(times, pitches, label=label, linewidth=1.0)
    axes.axhline(0.0, color='0.3', linewidth=0.6)
    axes.set_xlabel('time (s)')
    axes.set_ylabel('body pitch (deg, + nose-down)')
    axes.grid(visible=True, alpha=0.3)
    axes.legend(fontsize=8)
    figure.suptitle(
        "Terrain trials: the sprung robot's body pitch, from its IMU (the obstacle runs)"
    )
    figure.savefig(path, dpi=100)
    plt.close(figure)
    return path
