"""scanfuse: depth camera + 2D LiDAR fusion into one LaserScan."""

import logging

from scanfuse.camera import CameraModel, decode_depth
from scanfuse.config import FusionConfig, Method, Resampler
from scanfuse.errors import (
    BagError,
    CalibrationError,
    ConfigError,
    DepthEncodingError,
    InputError,
    MessageError,
    ScanfuseError,
    TransformError,
)
from scanfuse.pipeline import FusedResult, FusionPipeline, StageTimings
from scanfuse.scan import AngleGrid, Scan

logging.getLogger(__name__).addHandler(logging.NullHandler())

__all__ = [
    'AngleGrid',
    'BagError',
    'CalibrationError',
    'CameraModel',
    'ConfigError',
    'DepthEncodingError',
    'FusedResult',
    'FusionConfig',
    'FusionPipeline',
    'InputError',
    'MessageError',
    'Method',
    'Resampler',
    'Scan',
    'ScanfuseError',
    'StageTimings',
    'TransformError',
    'decode_depth',
]
