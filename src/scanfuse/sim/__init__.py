"""MuJoCo simulation of the paper's indoor worlds: robot, sensors, ground truth, bags."""

from scanfuse.sim.drive import PATHS, Arc, FusedController, Lap, Rotate, Straight, scripted_path
from scanfuse.sim.errors import SimError
from scanfuse.sim.record import RecordSummary, record, static_transforms
from scanfuse.sim.robot import RobotSpec, WheelOdometry
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
from scanfuse.sim.worlds import DROP_KINDS, KINDS, WORLDS, Drop, Obstacle, Pose2D, World, make_world

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
