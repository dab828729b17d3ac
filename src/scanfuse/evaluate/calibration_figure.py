"""The calibration figure: the LiDAR's scan over the camera's points, before and after."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

import matplotlib as mpl

mpl.use('Agg')  # files only: robots and CI have no screen
import matplotlib.pyplot as plt

if TYPE_CHECKING:
    from pathlib import Path

    from scanfuse.calibrate import Calibration, Mounting


def _label(title: str, mounting: Mounting, rms: float) -> str:
    return (
        f'{title}: x {mounting.x:.3f} m, y {mounting.y:.3f} m, '
        f'yaw {math.degrees(mounting.yaw):.2f} deg\n'
        f'height {mounting.height:.3f} m, pitch {math.degrees(mounting.pitch):.2f} deg, '
        f'roll {math.degrees(mounting.roll):.2f} deg; match RMS {rms * 1e3:.1f} mm'
    )


def calibration_figure(result: Calibration, title: str, path: Path) -> Path:
    """Two top views in the base frame: the LiDAR's points (black) and the camera's points
    in the LiDAR's plane (orange), placed with the given mounting and with the estimate."""
    figure, axes_row = plt.subplots(1, 2, figsize=(11.0, 6.4), layout='constrained')
    panels = (
        ('given', result.given, result.camera_given, result.match_rms_given),
        ('estimated', result.mounting, result.camera_points, result.match_rms),
    )
    lidar = result.lidar_points
    for axes, (name, mounting, camera, rms) in zip(axes_row, panels, strict=True):
        axes.scatter(lidar[:, 0], lidar[:, 1], s=2, c='black', label='LiDAR scan', zorder=3)
        if camera.size:
            axes.scatter(
                camera[:, 0], camera[:, 1], s=2, c='tab:orange', alpha=0.3, zorder=2,
                label="camera points in the LiDAR's plane",
            )  # fmt: skip
        axes.plot([mounting.x], [mounting.y], marker='^', c='tab:blue', label='camera')
        axes.plot(
            [mounting.x, mounting.x + 0.3 * math.cos(mounting.yaw)],
            [mounting.y, mounting.y + 0.3 * math.sin(mounting.yaw)],
            c='tab:blue',
        )
        axes.plot([0.0], [0.0], marker='o', c='tab:green', label='base_link')
        axes.set_title(_label(name, mounting, rms), fontsize=9)
        axes.set_xlabel('x (m, base frame)')
        axes.set_ylabel('y (m, base frame)')
        axes.set_aspect('equal', adjustable='datalim')
        axes.grid(visible=True, alpha=0.3)
        axes.legend(loc='upper center', bbox_to_anchor=(0.5, -0.12), ncol=2, fontsize=8)
    figure.suptitle(title)
    figure.savefig(path, dpi=110)
    plt.close(figure)
    return path
