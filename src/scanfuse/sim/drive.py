"""Scripted paths: controllers that ignore the scans and follow a plan on odometry.

A controller is any callable taking an `Observation` (LiDAR scan, latest depth
image, camera model, odometry) and returning (v, omega): forward speed (m/s) and
turn rate (rad/s). The evaluation plugs its own in; these are the scripted ones.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from scanfuse.sim.errors import SimError

if TYPE_CHECKING:
    from collections.abc import Callable

    from scanfuse.pipeline import FusionPipeline
    from scanfuse.scan import Scan
    from scanfuse.sim.simulation import Controller, Observation

    Policy = Callable[[Scan, Observation], tuple[float, float]]


@dataclass
class Straight:
    """Drive straight ahead at a constant speed (into whatever is there)."""

    speed: float = 0.3

    def __call__(self, _observation: Observation) -> tuple[float, float]:
        return self.speed, 0.0


@dataclass
class Rotate:
    """Turn in place at a constant rate."""

    rate: float = 0.5

    def __call__(self, _observation: Observation) -> tuple[float, float]:
        return 0.0, self.rate


@dataclass
class Arc:
    """Drive an arc: constant speed and turn rate (radius speed / rate, to the left if rate > 0)."""

    speed: float = 0.3
    rate: float = 0.6

    def __call__(self, _observation: Observation) -> tuple[float, float]:
        return self.speed, self.rate


@dataclass
class Lap:
    """Drive a rectangle with left turns, leg by leg, measuring progress with odometry.

    The default legs fit the `room` world from its start pose (4 m by 3 m).
    """

    legs: tuple[float, ...] = (4.0, 3.0, 4.0, 3.0)
    speed: float = 0.3
    turn_rate: float = 0.6
    gain: float = 2.0

    def __post_init__(self) -> None:
        self._leg = 0
        self._turning = False
        self._anchor: tuple[float, float, float] | None = None

    def __call__(self, observation: Observation) -> tuple[float, float]:
        odometry = observation.odometry
        if self._leg >= len(self.legs):
            return 0.0, 0.0
        if self._anchor is None:
            self._anchor = (odometry.x, odometry.y, odometry.yaw)
        x0, y0, yaw0 = self._anchor
        if not self._turning:
            remaining = self.legs[self._leg] - math.hypot(odometry.x - x0, odometry.y - y0)
            if remaining > 0.01:
                heading_error = _wrap(yaw0 - odometry.yaw)
                return min(self.speed, max(0.05, self.gain * remaining)), self.gain * heading_error
            self._turning = True
            self._anchor = (odometry.x, odometry.y, _wrap(yaw0 + math.pi / 2))
            x0, y0, yaw0 = self._anchor
        remaining_turn = _wrap(yaw0 - odometry.yaw)
        if abs(remaining_turn) > 0.01:
            rate = min(self.turn_rate, max(0.1, self.gain * abs(remaining_turn)))
            return 0.0, math.copysign(rate, remaining_turn)
        self._turning = False
        self._leg += 1
        self._anchor = (odometry.x, odometry.y, yaw0)
        return 0.0, 0.0


@dataclass
class FusedController:
    """A controller that fuses each scan with the latest depth image before deciding.

    `policy` gets the fused scan (the LiDAR scan alone until a depth image exists)
    and the observation. Build `pipeline` from `fusion_config(sim_config)` so the
    fusion uses the simulated robot's mounting.
    """

    policy: Policy
    pipeline: FusionPipeline
    last_fused: Scan | None = None

    def __call__(self, observation: Observation) -> tuple[float, float]:
        fused = observation.scan
        if observation.depth is not None:
            fused = self.pipeline.fuse(
                observation.scan, observation.depth, observation.camera
            ).fused
        self.last_fused = fused
        return self.policy(fused, observation)


def _wrap(angle: float) -> float:
    return math.atan2(math.sin(angle), math.cos(angle))


PATHS: dict[str, Callable[[], Controller]] = {
    'straight': Straight,
    'rotate': Rotate,
    'rotate-fast': lambda: Rotate(1.5),
    'arc': Arc,
    'lap': Lap,
}


def scripted_path(name: str) -> Controller:
    """A fresh controller for the scripted path `name` (one of `PATHS`)."""
    factory = PATHS.get(name)
    if factory is None:
        msg = f'unknown path {name!r}; choose one of {", ".join(PATHS)}'
        raise SimError(msg)
    return factory()
