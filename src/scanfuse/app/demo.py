"""`make demo`: a quick evaluation of every method, a Foxglove-ready bag, the core on a real frame.

1. The core on one depth frame: the real Kinect frame of
   ../shared/data/real/pcl_grabber (or $SCANFUSE_REAL_DATA) when it is there,
   else a synthetic frame of the same camera looking at a floor, a low box and a
   wall (`demo_core.png`).
2. The quick evaluation's trials (bookshelf, barricade, two clutter worlds, the
   ledge, the memory and turning trials: scan metrics, maps, closed-loop trials of
   LiDAR alone against the obstacle scan) for four methods (`DEMO_METHODS`), in two
   processes, written as `evaluation/report.md` with figures. Each method is scored
   on its own stream over the same drives, so these rows are those of
   `scanfuse evaluate --quick`, which adds eight methods, the closed loop of
   `obstacle-no-memory` and the AMR trial (the README's table).
3. A simulated drive at the bookshelf recorded as a ROS 2 bag and fused with
   `fuse_bag`: `/scan`, `/scan_fused`, `/scan_depth`, depth, TF, odometry and
   ground truth, in one MCAP file that Foxglove opens.
"""

from __future__ import annotations

import math
import os
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from rich.table import Table

from scanfuse.camera import CameraModel
from scanfuse.config import FusionConfig
from scanfuse.convert.floor import FloorGuard
from scanfuse.convert.floor_fit import fit_floor
from scanfuse.convert.obstacle import obstacle_scan
from scanfuse.convert.row import row_scan
from scanfuse.scan import AngleGrid, Scan
from scanfuse.transforms import Extrinsics

if TYPE_CHECKING:
    import numpy.typing as npt
    from rich.console import Console

    from scanfuse.evaluate.figures import SensorMark
    from scanfuse.evaluate.runner import EvaluationSettings

REAL_FRAME = Path('pcl_grabber') / 'frame_20121214T142255.814212_depth.tiff'
# The pcl_grabber frame's intrinsics (its README): fx = fy = 525, cx = 320, cy = 240.
KINECT = CameraModel.from_intrinsics(640, 480, 525.0, 525.0, 320.0, 240.0)
RPLIDAR_GRID = AngleGrid(-math.pi, 2 * math.pi / 1080, 1080)


@dataclass(frozen=True)
class DemoFrame:
    depth: npt.NDArray[np.uint16]
    camera: CameraModel
    source: str


def real_data_dir() -> Path:
    """$SCANFUSE_REAL_DATA, else ../shared/data/real beside the working directory."""
    env = os.environ.get('SCANFUSE_REAL_DATA')
    return Path(env) if env else Path.cwd().parent / 'shared' / 'data' / 'real'


def synthetic_frame(camera: CameraModel = KINECT) -> DemoFrame:
    """Camera 0.7 m above a floor, pitched 45 deg down, a 10 cm box 1 m ahead, a wall at 2 m."""
    height, pitch = 0.7, math.radians(45.0)
    x_n, y_n = camera.normalized_coordinates
    # Per unit Z, a ray drops by `down` and advances by `ahead` (base frame).
    down = y_n * math.cos(pitch) + math.sin(pitch)
    ahead = math.cos(pitch) - y_n * math.sin(pitch)
    with np.errstate(divide='ignore'):
        floor = np.where(down > 0, height / down, np.inf)
        wall = np.where(ahead > 0, 2.0 / ahead, np.inf)
        box_face = np.where(ahead > 0, 1.0 / ahead, np.inf)
    box_seen = (height - box_face * down <= 0.10) & (np.abs(x_n * box_face) <= 0.2)
    depth = np.minimum(floor, wall)
    depth = np.where(box_seen & (box_face < depth), box_face, depth)
    depth_mm = np.where(np.isfinite(depth), np.round(depth * 1000), 0).astype(np.uint16)
    return DemoFrame(depth_mm, camera, 'synthetic: floor, 10 cm box at 1 m, wall at 2 m')


def load_frame() -> DemoFrame:
    path = real_data_dir() / REAL_FRAME
    if not path.is_file():
        return synthetic_frame()
    import tifffile  # noqa: PLC0415

    depth = np.asarray(tifffile.imread(path), dtype=np.uint16)
    return DemoFrame(depth, KINECT, f'real Kinect frame {path.name}')


def summarize(scan: Scan) -> tuple[str, str, str]:
    finite = scan.ranges[np.isfinite(scan.ranges)]
    nearest = f'{finite.min():.2f} m' if finite.size else '-'
    return str(finite.size), nearest, str(int(np.isnan(scan.ranges).sum()))


def sensor_marks(extrinsics: Extrinsics) -> tuple[SensorMark, SensorMark]:
    """The camera's and the LiDAR's marks for a top-down plot in the base frame: each at
    its x, y, its height in its label (the two may share x, y and differ only in height)."""
    from scanfuse.evaluate.figures import SensorMark  # noqa: PLC0415

    camera = extrinsics.base_to_camera_optical.translation
    lidar = extrinsics.base_to_laser.translation
    return (
        SensorMark(
            f'camera (row scans from here), {camera[2]:.2f} m up', (camera[0], camera[1]), 's'
        ),
        SensorMark(
            f'LiDAR (obstacle scan from here), {lidar[2]:.2f} m up',
            (lidar[0], lidar[1]),
            '^',
            'tab:blue',
        ),
    )


def core_demo(out: Path, console: Console) -> Path:
    """Write `out/demo_core.png` and print what each method reports on one frame."""
    # Imported here: the figures import the simulator, hence MuJoCo, which must not be
    # imported before `run_demo` has chosen its GL backend.
    from scanfuse.evaluate.figures import ScanLayer, depth_and_scans_figure  # noqa: PLC0415

    out.mkdir(parents=True, exist_ok=True)
    frame = load_frame()
    config = FusionConfig()
    console.print(f'[bold]scanfuse demo[/] on the {frame.source}')
    fit = fit_floor(frame.depth, frame.camera)
    console.print(
        f'floor fit: camera {fit.camera_height:.3f} m above the floor, pitched '
        f'{math.degrees(fit.camera_pitch):.1f} deg down, roll '
        f'{math.degrees(fit.camera_roll):.1f} deg ({fit.inlier_share:.0%} of points on the floor)'
    )
    guard = FloorGuard(fit.camera_height, fit.camera_pitch, config.floor_margin)
    range_min, range_max = 0.5, 8.0  # the Kinect's working range
    centre_row = round(frame.camera.cy)
    low_row = frame.camera.height - 60
    scans = {
        'row, centre (paper)': row_scan(
            frame.depth, frame.camera, range_min=range_min, range_max=range_max
        ),
        'row, centre + floor_guard': row_scan(
            frame.depth, frame.camera, range_min=range_min, range_max=range_max, floor_guard=guard
        ),
        'row, low + floor_guard': row_scan(
            frame.depth,
            frame.camera,
            scan_row=low_row,
            range_min=range_min,
            range_max=range_max,
            floor_guard=guard,
        ),
    }
    # A LiDAR under the camera, 0.3 m above the floor, as on a small robot.
    extrinsics = Extrinsics.from_mounting(
        camera_height=fit.camera_height,
        camera_pitch=fit.camera_pitch,
        camera_roll=fit.camera_roll,
        lidar_height=0.3,
    )
    scans['obstacle (scanfuse)'] = obstacle_scan(
        frame.depth,
        frame.camera,
        extrinsics,
        RPLIDAR_GRID,
        min_obstacle_height=config.min_obstacle_height,
        max_obstacle_height=config.max_obstacle_height,
        range_min=range_min,
        range_max=range_max,
    )
    colors = ('tab:red', 'tab:orange', 'tab:purple', 'tab:blue')
    # Top-down in the base frame: the row scans from the camera, the obstacle scan from the
    # LiDAR, each drawn from where its sensor sits (`sensor_marks`).
    camera_mark, lidar_mark = sensor_marks(extrinsics)
    layers = [
        ScanLayer(
            label,
            scan,
            color,
            origin_xy=(lidar_mark if 'obstacle' in label else camera_mark).xy,
            size=10.0 if 'obstacle' in label else 5.0,
        )
        for (label, scan), color in zip(scans.items(), colors, strict=True)
    ]
    figure = depth_and_scans_figure(
        frame.depth,
        {'centre row': centre_row, 'low row': low_row},
        layers,
        out / 'demo_core.png',
        title='top-down (row: from the camera; obstacle: from the LiDAR)',
        sensors=[camera_mark, lidar_mark],
    )
    table = Table(title='what each method reports')
    for column in ('method', 'finite slots', 'nearest', 'NaN slots'):
        table.add_column(column)
    for label, scan in scans.items():
        table.add_row(label, *summarize(scan))
    console.print(table)
    console.print(
        "The paper's centre row of a camera looking 45 deg down meets the carpet: without "
        'the floor guard the floor becomes an obstacle (its Figure 10).'
    )
    console.print(f'figure: [bold]{figure}[/]')
    return figure


DEMO_CLUTTER_WORLDS = 2
# Four of the README's results table's methods, and the closed loop of the LiDAR alone
# against the default: `scanfuse evaluate --quick`'s rows of these methods, exactly.
DEMO_METHODS = ('lidar', 'row-centre', 'd2l', 'obstacle')
DEMO_CLOSED_LOOP = ('lidar', 'obstacle')
DEMO_JOBS = 2  # trials in parallel: `make demo` within 4 minutes on a 2-core machine
BAG_DURATION = 8.0  # simulated seconds of the recorded drive
RECORDING_NAME = 'bookshelf_drive.mcap'


def live_commands(recording: Path) -> list[str]:
    """The two commands, each in its own terminal, that run the live node on `recording`:
    `play` waits for the node, publishes the drive and counts the node's /scan_fused.

    They name the `scanfuse` that runs the demo (`make demo`'s .venv/bin/scanfuse), so they
    work as printed without activating the environment.
    """
    beside = Path(sys.executable).parent / 'scanfuse'
    command = os.path.relpath(beside) if beside.is_file() else 'scanfuse'
    return [f'{command} node', f'{command} play {recording} --listen']


def record_demo_bag(out: Path, console: Console) -> Path:
    """Drive straight at the bookshelf, record it, fuse it; the fused MCAP file's path."""
    from scanfuse.ros.bag import fuse_bag  # noqa: PLC0415
    from scanfuse.sim.drive import scripted_path  # noqa: PLC0415
    from scanfuse.sim.recording import record  # noqa: PLC0415
    from scanfuse.sim.simulation import SimConfig  # noqa: PLC0415

    recorded = out / RECORDING_NAME
    fused = out / 'bookshelf_fused'
    for stale in (recorded, fused):
        if stale.is_dir():
            shutil.rmtree(stale)
        elif stale.exists():
            stale.unlink()
    config = SimConfig(world='bookshelf', resolution=(640, 480), depth_rate=15.0)
    with console.status('recording a drive at the bookshelf'):
        summary = record(config, scripted_path('straight'), BAG_DURATION, recorded)
    console.print(
        f'recorded {summary.sim_time:.1f} s of simulation in {summary.wall_time:.1f} s '
        f'({summary.contacts} contact samples: the LiDAR-blind robot hits the boards)'
    )
    with console.status('fusing the recording'):
        fuse_bag(recorded, fused)
    files = sorted(fused.glob('*.mcap'))
    return files[0] if files else fused


def demo_settings() -> EvaluationSettings:
    """`scanfuse evaluate --quick`'s trials (no AMR trial) for `DEMO_METHODS`.

    Each method is scored on its own stream over the same drives, and each closed-loop
    method drives its own trials, so the rows are those of `evaluate --quick`.
    """
    from scanfuse.evaluate.runner import EvaluationSettings  # noqa: PLC0415

    return EvaluationSettings.quick(
        trials=DEMO_CLUTTER_WORLDS,
        methods=DEMO_METHODS,
        closed_loop_methods=DEMO_CLOSED_LOOP,
        amr=(),
    )


def demo_jobs() -> int:
    """`DEMO_JOBS` processes, fewer on a machine with fewer cores."""
    return max(1, min(DEMO_JOBS, os.cpu_count() or 1))


def run_demo(out: Path, console: Console) -> Path:
    """The whole demo into `out`; returns the evaluation report's path."""
    from scanfuse.sim.headless_gl import choose_headless_gl  # noqa: PLC0415

    choose_headless_gl()  # before MuJoCo is imported: rendered depth where GL works
    from scanfuse.evaluate.report import table  # noqa: PLC0415
    from scanfuse.evaluate.write import run_evaluation  # noqa: PLC0415
    from scanfuse.progress import RichProgress  # noqa: PLC0415

    out.mkdir(parents=True, exist_ok=True)
    core_figure = core_demo(out, console)
    console.rule('quick evaluation: bookshelf, barricade, clutter, ledge, memory trials')
    evaluation_dir = out / 'evaluation'
    run_evaluation(evaluation_dir, demo_settings(), RichProgress(console), jobs=demo_jobs())
    console.rule('a Foxglove-ready bag')
    bag = record_demo_bag(out, console)
    result_path = evaluation_dir / 'results.json'
    from scanfuse.evaluate.results import EvaluationResult  # noqa: PLC0415

    console.print(table(EvaluationResult.load(result_path)))
    console.print(f'report:  [bold]{evaluation_dir / "report.md"}[/]')
    console.print(f'figures: [bold]{evaluation_dir}[/] (scans_*.png, maps_*.png, metrics.png)')
    console.print(f'bag:     [bold]{bag}[/] (open in Foxglove: /scan, /scan_fused, depth, /tf)')
    console.print(f'core on one frame: [bold]{core_figure}[/]')
    recording = out / RECORDING_NAME
    console.print('the live node on the recorded drive (two terminals, ROS 2 wheels installed):')
    for command in live_commands(recording):
        console.print(f'  [bold]{command}[/]')
    return evaluation_dir / 'report.md'
