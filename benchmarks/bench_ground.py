"""The floor found in every frame (issue 25) on the realistic room frames (`scenes.py`).

Per size: the ground estimate alone (`GroundTracker.update`: the plane, and the profile's
walk of the image's columns); the obstacle scan with it (estimate, then the scan above the
estimated ground) against the scan above the mounting's plane, drop detection on in both
(the pipeline's default), in interleaved batches: on the room as mounted (issue 25's
budget: 1.15), seen from a body pitching by 0, +2 and -2 deg in turn (the estimate moves
every frame, so the height tables are rebuilt every frame), and with a 1:12 ramp rising
from 1.2 m ahead (a ramp rebuilds them every frame, with its profile); and on a stream of
the room, fresh noise in every frame. And the ground driven over (`scanfuse.trail`): one
scan's advance and look-up of its readings.
"""

from __future__ import annotations

import itertools
import math
import statistics
import time
from typing import TYPE_CHECKING

import numpy as np

from benchmarks import scenes
from benchmarks.common import Row, median_seconds
from scanfuse.config import FusionConfig
from scanfuse.convert.ground import GroundPlane, GroundSettings, GroundTracker
from scanfuse.convert.obstacle import DropLimits, ObstacleProjector
from scanfuse.imu import ImuHistory
from scanfuse.motion import PlanarPose
from scanfuse.trail import GroundTrail
from scanfuse.transforms import Transform

if TYPE_CHECKING:
    from collections.abc import Callable

    from scanfuse.camera import CameraModel

SECTION = 'ground'
_CONFIG = FusionConfig()
DROPS = DropLimits(_CONFIG.drop_min_depth, _CONFIG.drop_min_width, _CONFIG.depth_noise)
PRIOR = GroundPlane.of_mounting(scenes.EXTRINSICS.base_to_camera_optical)


def _interleaved(calls: dict[str, Callable[[], object]], repeat: int = 31) -> dict[str, float]:
    """Median seconds per call of each, batches of the calls interleaved (the same load)."""
    for call in calls.values():
        call()
    slowest = max(median_seconds(call, repeat=3) for call in calls.values())
    number = max(1, round(0.01 / slowest))
    samples: dict[str, list[float]] = {name: [] for name in calls}
    for _ in range(repeat):
        for name, call in calls.items():
            start = time.perf_counter()
            for _ in range(number):
                call()
            samples[name].append((time.perf_counter() - start) / number)
    return {name: statistics.median(times) for name, times in samples.items()}


def _with_ground(
    projector: ObstacleProjector, tracker: GroundTracker, frames: itertools.cycle[np.ndarray]
) -> Callable[[], object]:
    def call() -> object:
        depth = next(frames)
        plane = tracker.update(depth, projector.camera, PRIOR)
        return projector.scan(depth, ground=plane, profile=tracker.profile)

    return call


STREAM_FRAMES = 10  # seeds of the room's noise in the stream rows


def _whole_stream(
    projector: ObstacleProjector, tracker: GroundTracker, frames: list[np.ndarray]
) -> Callable[[], object]:
    """Every frame of `frames` in turn: estimate, then the scan above the estimated ground."""
    single = _with_ground(projector, tracker, itertools.cycle(frames))

    def call() -> object:
        return [single() for _ in frames]

    return call


TRAIL_READINGS = 1440  # a Hokuyo-class LiDAR's readings a scan
IMU_PERIOD_NS = 5_000_000  # 200 Hz
IMU_SPAN_NS = 1_000_000_000  # the IMU's samples: 2 s (`imu.MAX_SAMPLES` of them at 200 Hz)
TRAIL_STEP = 0.035  # metres a scan: 0.35 m/s at 10 Hz


def _trail_scan(pitch: float, *, by_beam: bool = False) -> Callable[[], object]:
    """One scan's work of `GroundTrail` (advance, then look up every reading) on a robot
    driving straight with its body pitched `pitch` (radians, nose-up), 8 m of path kept.
    `by_beam`: each reading with the tilt of its beam's time, from an IMU at 200 Hz across a
    0.1 s sweep (`ImuHistory.tilts_over`, worked out in the call, as the stream does)."""
    trail = GroundTrail()
    tilt = Transform.from_rpy(0.0, -pitch, 0.0).rotation_matrix
    for index in range(round(trail.settings.length / TRAIL_STEP)):
        trail.advance(PlanarPose(index * TRAIL_STEP, 0.0, 0.0), tilt, 0)
    angles = np.linspace(-math.pi, math.pi, TRAIL_READINGS, endpoint=False)
    # Readings 2 m away in the LiDAR's plane, 0.30 m above the base.
    points = np.stack([2.0 * np.cos(angles), 2.0 * np.sin(angles), np.full_like(angles, 0.3)], 1)
    place = [round(trail.settings.length / TRAIL_STEP)]
    history = ImuHistory()
    for stamp in range(0, 2 * IMU_SPAN_NS, IMU_PERIOD_NS):  # rocking 2 degrees either way
        rock = math.radians(2.0) * math.sin(stamp / IMU_SPAN_NS * 2.0 * math.pi)
        history.add(stamp, Transform.from_rpy(0.0, -pitch + rock, 0.0))
    beams = IMU_SPAN_NS + np.arange(TRAIL_READINGS) * (IMU_SPAN_NS // 10 // TRAIL_READINGS)

    def call() -> object:
        place[0] += 1
        pose = PlanarPose(place[0] * TRAIL_STEP, 0.0, 0.0)
        trail.advance(pose, tilt, 0)
        each = history.tilts_over(beams) if by_beam else None
        return trail.on_ground(points, pose, tilt, each)

    return call


def run() -> list[Row]:
    rows = []
    for pitch, by_beam, note in (
        (0.0, False, 'level: no reading near the ground'),
        (math.radians(7.0), False, 'pitched 7 deg nose-up: every reading looked up'),
        (math.radians(7.0), True, "pitched 7 deg, each beam with its own time's tilt"),
    ):
        rows.append(
            Row(
                SECTION,
                f'ground trail per scan, {TRAIL_READINGS} readings',
                median_seconds(_trail_scan(pitch, by_beam=by_beam)),
                f'advance + look-up; body {note}',
            )
        )
    settings = GroundSettings.from_config(_CONFIG)
    for width, height in scenes.SIZES:
        size = f'{width}x{height}'
        camera = scenes.camera_for(width, height)
        room = scenes.frame(camera)[0]
        pitching = [
            scenes.frame(camera, body_pitch=math.radians(pitch))[0] for pitch in (0.0, 2.0, -2.0)
        ]
        ramp = scenes.frame(camera, ramp=1.0 / 12.0)[0]
        # A camera's stream: every frame the room with fresh noise (both scans cycle them).
        stream = [scenes.frame(camera, seed)[0] for seed in range(STREAM_FRAMES)]

        def projector(camera: CameraModel = camera) -> ObstacleProjector:
            return ObstacleProjector(
                camera, scenes.EXTRINSICS, scenes.GRID, **scenes.SETTINGS, drops=DROPS
            )

        plain = projector()
        tracker = GroundTracker(settings)
        estimate = median_seconds(
            lambda t=tracker, d=room, c=camera: t.update(d, c, PRIOR), repeat=51
        )
        tracker.update(room, camera, PRIOR)
        profiled = tracker.profile is not None
        rows.append(
            Row(
                SECTION,
                f'ground estimate {size}',
                estimate,
                f'plane + profile walk; the room is {"not " if profiled else ""}one plane',
            )
        )
        times = _interleaved(
            {
                'off': lambda p=plain, d=room: p.scan(d),
                'room': _with_ground(projector(), GroundTracker(settings), itertools.cycle([room])),
                'pitching': _with_ground(
                    projector(), GroundTracker(settings), itertools.cycle(pitching)
                ),
                'ramp': _with_ground(projector(), GroundTracker(settings), itertools.cycle([ramp])),
                # A call is the whole stream: a median of single frames would hide the
                # frames that rebuild the tables.
                'off, stream': lambda p=plain, f=stream: [p.scan(d) for d in f],
                'stream': _whole_stream(projector(), GroundTracker(settings), stream),
            }
        )
        rows.append(
            Row(
                SECTION,
                f'obstacle with ground, room stream {size}',
                times['stream'] / STREAM_FRAMES,
                f'{times["stream"] / times["off, stream"]:.2f}x the scan above the mounting '
                f'({times["off, stream"] / STREAM_FRAMES * 1e3:.2f} ms a frame); the room with '
                f'fresh noise in each of {STREAM_FRAMES} frames, the whole stream a call (a '
                'spurious profile rebuilds the tables)',
            )
        )
        off = times['off']
        for name, note in (
            ('room', 'the room as mounted (one frame repeated); budget 1.15'),
            ('pitching', 'body pitched 0, +2, -2 deg in turn: tables rebuilt every frame'),
            ('ramp', '1:12 ramp from 1.2 m: profile and tables every frame'),
        ):
            rows.append(
                Row(
                    SECTION,
                    f'obstacle with ground, {name} {size}',
                    times[name],
                    f'{times[name] / off:.2f}x the scan above the mounting ({off * 1e3:.2f} ms); '
                    + note,
                )
            )
    return rows
