"""The body of `scanfuse simulate`: options to a `SimConfig`, a progress bar, a summary table."""

from __future__ import annotations

import re
from dataclasses import replace
from typing import TYPE_CHECKING, Any

from rich.table import Table

from scanfuse.config import FusionConfig
from scanfuse.progress import RichProgress
from scanfuse.sim.drive import scripted_path
from scanfuse.sim.errors import SimError
from scanfuse.sim.recording import RecordSummary, record
from scanfuse.sim.robot import robot_spec
from scanfuse.sim.sensors import DepthBackend
from scanfuse.sim.simulation import SimConfig, robot_mounting

if TYPE_CHECKING:
    from pathlib import Path

    from rich.console import Console


def parse_resolution(text: str) -> tuple[int, int]:
    """'640x480' -> (640, 480)."""
    match = re.fullmatch(r'\s*(\d+)\s*[xX]\s*(\d+)\s*', text)
    if match is None:
        msg = f'resolution {text!r} is not WIDTHxHEIGHT, e.g. 640x480'
        raise SimError(msg)
    return int(match[1]), int(match[2])


def parse_backend(text: str) -> DepthBackend:
    try:
        return DepthBackend(text)
    except ValueError:
        choices = ', '.join(backend.value for backend in DepthBackend)
        msg = f'unknown depth backend {text!r}; choose one of {choices}'
        raise SimError(msg) from None


# Simulated seconds a recording may last: a day (at 30 Hz depth, far more than a disk holds).
MAX_DURATION = 86_400.0


def mounting_from_params(path: Path) -> dict[str, float]:
    """The simulated robot's sensor poses from a scanfuse parameter file (metres, radians)."""
    return robot_mounting(FusionConfig.from_ros_params(path))


def topics_from_params(path: Path) -> dict[str, str]:
    """The input topics of a parameter file, for a one-LiDAR, one-camera robot's recording."""
    config = FusionConfig.from_ros_params(path)
    return {
        'scan_topic': config.scan_topic,
        'depth_topic': config.depth_topic,
        'camera_info_topic': config.camera_info_topic,
    }


def run_simulate(
    *,
    out: Path,
    world: str,
    path: str,
    duration: float,
    seed: int,
    lidar: str | None,
    camera: str,
    resolution: str,
    depth_rate: float | None,
    noise: bool,
    depth_backend: str,
    snapshot: Path | None,
    console: Console,
    mounting: dict[str, float] | None = None,
    depth_latency: float = 0.040,
    robot: str = 'default',
    topics: dict[str, str] | None = None,
) -> RecordSummary:
    """Record one run of the robot called `robot` (`ROBOTS`); `mounting` changes its first
    sensors' poses (metres, radians); `lidar` None: the robot's own LiDAR model."""
    if not 0.0 < duration <= MAX_DURATION:  # also false for NaN
        msg = f'--duration must be more than 0 and at most {MAX_DURATION:g} s, got {duration}'
        raise SimError(msg)
    changes: dict[str, Any] = dict(mounting or {})
    base = robot_spec(robot)
    if not base.several:  # a robot of named sources keeps examples/scanfuse_multi.yaml's topics
        changes.update(topics or {})
    spec = replace(base, **changes)
    config = SimConfig(
        world=world,
        seed=seed,
        lidar=lidar or spec.lidar_model,
        camera=camera,
        resolution=parse_resolution(resolution),
        depth_rate=depth_rate,
        depth_latency=depth_latency,
        noise=noise,
        depth_backend=parse_backend(depth_backend),
        robot=spec,
    )
    controller = scripted_path(path)
    summary = record(
        config,
        controller,
        duration,
        out,
        snapshot=snapshot,
        progress=RichProgress(console, unit='simulated s', transient=True),
    )
    console.print(summary_table(summary, snapshot))
    return summary


def summary_table(summary: RecordSummary, snapshot: Path | None) -> Table:
    table = Table(title=f'recorded {summary.path}')
    table.add_column('topic / quantity')
    table.add_column('value', justify='right')
    for topic, count in sorted(summary.counts.items()):
        table.add_row(topic, f'{count} messages')
    table.add_row('simulated time', f'{summary.sim_time:.2f} s')
    table.add_row('wall time', f'{summary.wall_time:.2f} s')
    table.add_row('real-time factor', f'{summary.real_time_factor:.2f}')
    table.add_row('contact samples (robot touching an obstacle)', str(summary.contacts))
    fell = 'no' if summary.fell_at is None else f'yes, {summary.fell_at:.2f} s into the drive'
    table.add_row('robot fell (down a drop)', fell)
    table.add_row('final odometry error', f'{summary.final_odometry_error:.3f} m')
    if snapshot is not None:
        table.add_row('snapshot', str(snapshot))
    return table
