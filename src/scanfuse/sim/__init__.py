"""MuJoCo simulation of the paper's indoor worlds: robot, sensors, ground truth, bags.

Names are imported on first use (PEP 562): importing `scanfuse.sim.headless_gl` must not
import MuJoCo, which reads MUJOCO_GL once, at its own import.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from scanfuse.sim.drive import PATHS, Arc, FusedController, Lap, Rotate, Straight, scripted_path
    from scanfuse.sim.errors import SimError
    from scanfuse.sim.recording import RecordSummary, record, static_transforms
    from scanfuse.sim.robot import RobotSpec, Suspension, WheelOdometry
    from scanfuse.sim.sensors import (
        CAMERAS,
        LIDARS,
        CameraProfile,
        DepthBackend,
        DepthNoise,
        LidarNoise,
        LidarProfile,
    )
    from scanfuse.sim.simulation import (
        Contact,
        Controller,
        DepthFrame,
        ImuNoise,
        ImuSample,
        LidarFrame,
        Observation,
        SimConfig,
        Simulation,
        StateSample,
        Trace,
        fusion_config,
    )
    from scanfuse.sim.snapshot import save_snapshot
    from scanfuse.sim.truth import TruthScanner
    from scanfuse.sim.worlds import (
        DROP_KINDS,
        KINDS,
        WORLDS,
        Drop,
        Ground,
        Obstacle,
        Pose2D,
        World,
        make_world,
    )


_WHERE = {
    'Arc': 'drive',
    'CAMERAS': 'sensors',
    'CameraProfile': 'sensors',
    'Contact': 'simulation',
    'Controller': 'simulation',
    'DepthBackend': 'sensors',
    'DepthFrame': 'simulation',
    'DepthNoise': 'sensors',
    'DROP_KINDS': 'worlds',
    'Drop': 'worlds',
    'Ground': 'worlds',
    'ImuNoise': 'simulation',
    'ImuSample': 'simulation',
    'Suspension': 'robot',
    'FusedController': 'drive',
    'KINDS': 'worlds',
    'LIDARS': 'sensors',
    'Lap': 'drive',
    'LidarFrame': 'simulation',
    'LidarNoise': 'sensors',
    'LidarProfile': 'sensors',
    'Observation': 'simulation',
    'Obstacle': 'worlds',
    'PATHS': 'drive',
    'Pose2D': 'worlds',
    'RecordSummary': 'recording',
    'RobotSpec': 'robot',
    'Rotate': 'drive',
    'SimConfig': 'simulation',
    'SimError': 'errors',
    'Simulation': 'simulation',
    'StateSample': 'simulation',
    'Straight': 'drive',
    'Trace': 'simulation',
    'TruthScanner': 'truth',
    'WORLDS': 'worlds',
    'WheelOdometry': 'robot',
    'World': 'worlds',
    'fusion_config': 'simulation',
    'make_world': 'worlds',
    'record': 'recording',
    'save_snapshot': 'snapshot',
    'scripted_path': 'drive',
    'static_transforms': 'recording',
}


def __getattr__(name: str) -> Any:
    module = _WHERE.get(name)
    if module is None:
        msg = f'module {__name__!r} has no attribute {name!r}'
        raise AttributeError(msg)
    value = getattr(importlib.import_module(f'{__name__}.{module}'), name)
    globals()[name] = value
    return value


__all__ = [
    'CAMERAS',
    'DROP_KINDS',
    'KINDS',
    'LIDARS',
    'PATHS',
    'WORLDS',
    'Arc',
    'CameraProfile',
    'Contact',
    'Controller',
    'DepthBackend',
    'DepthFrame',
    'DepthNoise',
    'Drop',
    'FusedController',
    'Ground',
    'ImuNoise',
    'ImuSample',
    'Lap',
    'LidarFrame',
    'LidarNoise',
    'LidarProfile',
    'Observation',
    'Obstacle',
    'Pose2D',
    'RecordSummary',
    'RobotSpec',
    'Rotate',
    'SimConfig',
    'SimError',
    'Simulation',
    'StateSample',
    'Straight',
    'Suspension',
    'Trace',
    'TruthScanner',
    'WheelOdometry',
    'World',
    'fusion_config',
    'make_world',
    'record',
    'save_snapshot',
    'scripted_path',
    'static_transforms',
]
