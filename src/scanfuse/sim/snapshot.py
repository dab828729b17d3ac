"""A top-down picture of a world with the robot, its LiDAR scan and the ground-truth scan."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np

from scanfuse.sim.simulation import EPOCH_NS
from scanfuse.sim.worlds import DROP_KINDS

if TYPE_CHECKING:
    from pathlib import Path

    import numpy.typing as npt

    from scanfuse.scan import Scan
    from scanfuse.sim.simulation import LidarFrame, StateSample
    from scanfuse.sim.worlds import Pose2D, World

KIND_COLOURS = {
    'wall': '#9e9e9e',
    'shelf_board': '#8d6e63',
    'shelf_side': '#4e342e',
    'barricade_base': '#e65100',
    'barricade_top': '#ffb74d',
    'chair_leg': '#6a1b9a',
    'chair_seat': '#ce93d8',
    'lamp_base': '#37474f',
    'lamp_pole': '#90a4ae',
    'low_box': '#fbc02d',
    'cable_tray': '#212121',
}
ROBOT_RADIUS = 0.18


def scan_points(scan: Scan, frame: LidarFrame) -> npt.NDArray[np.float64]:
    """World (x, y) of every finite reading of `scan` taken at `frame`'s pose."""
    ranges = scan.ranges.astype(np.float64)
    # The LiDAR's own heading: the AMR's LiDARs are turned 45 and -135 degrees on the base.
    heading = frame.pose.yaw if frame.heading is None else frame.heading
    angles = scan.angles() + heading
    keep = np.isfinite(ranges)
    x = frame.origin[0] + ranges[keep] * np.cos(angles[keep])
    y = frame.origin[1] + ranges[keep] * np.sin(angles[keep])
    return np.column_stack([x, y])


def draw_footprints(axes: Any, footprints: list[tuple[str, npt.NDArray[np.float64]]]) -> None:
    """Obstacles from above in their kind's colour (one legend entry per kind), and drops
    (where the floor is missing) hatched, so the scans on their edges stay visible."""
    from matplotlib.patches import Polygon  # noqa: PLC0415

    drawn: set[str] = set()
    for kind, polygon in footprints:
        label = None if kind in drawn else kind
        drawn.add(kind)
        if kind in DROP_KINDS:
            patch = Polygon(
                polygon,
                closed=True,
                fill=False,
                hatch='//',
                edgecolor='#ef6c00',
                linewidth=0.8,
                label=f'{kind} (floor missing)' if label else None,
                zorder=1,
            )
        else:
            patch = Polygon(
                polygon,
                closed=True,
                facecolor=KIND_COLOURS.get(kind, '#607d8b'),
                edgecolor='black',
                linewidth=0.4,
                alpha=0.55,
                label=label,
                zorder=1,
            )
        axes.add_patch(patch)


def save_snapshot(
    world: World,
    frame: LidarFrame,
    path: Path,
    *,
    states: list[StateSample] | None = None,
    start: Pose2D | None = None,
) -> Path:
    """Write a PNG: obstacles by kind, robot, LiDAR rays and points, truth points, paths."""
    import matplotlib as mpl  # noqa: PLC0415

    mpl.use('Agg')
    import matplotlib.pyplot as plt  # noqa: PLC0415
    from matplotlib.patches import Circle  # noqa: PLC0415

    figure, axes = plt.subplots(figsize=(9, 8), dpi=110)
    draw_footprints(
        axes,
        [
            *((o.kind, o.footprint) for o in world.obstacles),
            *((d.kind, d.footprint) for d in world.drops),
        ],
    )
    lidar = scan_points(frame.scan, frame)
    truth = scan_points(frame.truth, frame)
    origin = frame.origin[:2]
    segments = [[origin, point] for point in lidar[::3]]
    from matplotlib.collections import LineCollection  # noqa: PLC0415

    axes.add_collection(
        LineCollection(segments, colors='#1e88e5', linewidths=0.3, alpha=0.35, zorder=2)
    )
    axes.scatter(
        lidar[:, 0], lidar[:, 1], s=3, color='#1565c0', label='LiDAR scan (/scan)', zorder=4
    )
    axes.scatter(
        truth[:, 0],
        truth[:, 1],
        s=3,
        color='#d50000',
        marker='x',
        linewidths=0.6,
        label='truth obstacle scan (/scan_truth)',
        zorder=3,
    )
    if states:
        true_xy = np.array([state.position[:2] for state in states])
        axes.plot(
            true_xy[:, 0],
            true_xy[:, 1],
            color='#2e7d32',
            linewidth=1.2,
            label='true path',
            zorder=5,
        )
        if start is not None:
            c, s = math.cos(start.yaw), math.sin(start.yaw)
            odom = np.array([(state.odometry.x, state.odometry.y) for state in states])
            odom_world = odom @ np.array([[c, s], [-s, c]]) + (start.x, start.y)
            axes.plot(
                odom_world[:, 0],
                odom_world[:, 1],
                color='#2e7d32',
                linestyle='--',
                linewidth=1.0,
                label='wheel odometry',
                zorder=5,
            )
    pose = frame.pose
    axes.add_patch(
        Circle(
            (pose.x, pose.y),
            ROBOT_RADIUS,
            facecolor='#1e88e5',
            edgecolor='black',
            alpha=0.8,
            label='robot',
            zorder=6,
        )
    )
    axes.arrow(
        pose.x,
        pose.y,
        0.3 * math.cos(pose.yaw),
        0.3 * math.sin(pose.yaw),
        width=0.02,
        color='black',
        zorder=7,
    )
    if states:
        last = states[-1].true_pose
        axes.add_patch(
            Circle(
                (last.x, last.y),
                ROBOT_RADIUS,
                fill=False,
                edgecolor='black',
                linestyle=':',
                label='robot at the end',
                zorder=6,
            )
        )
    x_min, x_max, y_min, y_max = world.bounds
    axes.set_xlim(x_min - 0.3, x_max + 0.3)
    axes.set_ylim(y_min - 0.3, y_max + 0.3)
    axes.set_aspect('equal')
    axes.set_xlabel('x (m)')
    axes.set_ylabel('y (m)')
    seconds = (frame.stamp_ns - EPOCH_NS) / 1e9
    axes.set_title(
        f'world "{world.name}" (seed {world.seed}) from above: scans at t = {seconds:.1f} s'
    )
    axes.grid(visible=True, linewidth=0.3)
    axes.legend(loc='upper left', fontsize=7, framealpha=0.9)
    figure.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path)
    plt.close(figure)
    return path
