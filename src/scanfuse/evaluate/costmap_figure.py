"""The costmap figure: what a Nav2-like obstacle layer holds after a turn, memory on and off."""

from __future__ import annotations

from typing import TYPE_CHECKING

import matplotlib as mpl

mpl.use('Agg')
import matplotlib.pyplot as plt
import numpy as np
from matplotlib.colors import ListedColormap
from matplotlib.patches import Circle, Patch

from scanfuse.evaluate.planner import inflate

if TYPE_CHECKING:
    from pathlib import Path

    from scanfuse.evaluate.costmap import Costmap
    from scanfuse.sim.worlds import Obstacle

# free, inflated (the robot's centre may not enter), lethal
COLOURS = ListedColormap(['white', '#f4c27a', '#c0392b'])


def costmaps_figure(
    panels: list[tuple[str, Costmap]],
    obstacles: tuple[Obstacle, ...],
    robot: tuple[float, float, float, float],
    title: str,
    path: Path,
) -> Path:
    """One panel per costmap: lethal cells, their inflation by `robot`'s radius, true outlines.

    `robot` is (x, y, yaw, radius) in the world frame at the end of the trial; the true
    footprints of the obstacles are drawn as outlines (low ones dashed).
    """
    figure, axes_row = plt.subplots(
        1, len(panels), figsize=(5.2 * len(panels), 5.0), layout='constrained', squeeze=False
    )
    x, y, yaw, radius = robot
    for axes, (label, costmap) in zip(axes_row[0], panels, strict=True):
        spec = costmap.spec
        inflated = inflate(costmap.lethal, radius / spec.resolution)
        image = np.where(costmap.lethal, 2, np.where(inflated, 1, 0))
        extent = (
            spec.origin[0],
            spec.origin[0] + spec.width * spec.resolution,
            spec.origin[1],
            spec.origin[1] + spec.height * spec.resolution,
        )
        axes.imshow(
            image, origin='lower', extent=extent, cmap=COLOURS, vmin=0, vmax=2, interpolation='none'
        )
        for obstacle in obstacles:
            polygon = np.vstack([obstacle.footprint, obstacle.footprint[:1]])
            low = obstacle.z_max < 0.3
            axes.plot(
                polygon[:, 0],
                polygon[:, 1],
                color='black',
                linewidth=0.8,
                linestyle='--' if low else '-',
            )
        axes.add_patch(Circle((x, y), radius, fill=False, color='#1f4e9c', linewidth=1.5))
        axes.plot([x, x + radius * np.cos(yaw)], [y, y + radius * np.sin(yaw)], color='#1f4e9c')
        axes.set_title(label, fontsize=10)
        axes.set_xlabel('x (m, world)')
        axes.set_ylabel('y (m, world)')
        axes.set_aspect('equal')
    axes_row[0][-1].legend(
        handles=[
            Patch(color=COLOURS(2), label='lethal (marked, not cleared)'),
            Patch(color=COLOURS(1), label='inflated by the robot radius'),
            Patch(fill=False, edgecolor='black', linestyle='--', label='true low obstacle'),
        ],
        loc='upper right',
        fontsize=7,
    )
    figure.suptitle(title, fontsize=11)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path
