"""scanfuse: depth camera + 2D LiDAR fusion into one LaserScan.

The names below are imported when first used (PEP 562), so that `scanfuse` itself starts in
milliseconds: the command line takes SIGTERM from its first instant (`scanfuse.__main__`),
not only once numpy and the compiled kernels have loaded.
"""

from __future__ import annotations

import importlib
import logging
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
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

_HOMES = {
    'AngleGrid': 'scanfuse.scan',
    'BagError': 'scanfuse.errors',
    'CalibrationError': 'scanfuse.errors',
    'CameraModel': 'scanfuse.camera',
    'ConfigError': 'scanfuse.errors',
    'DepthEncodingError': 'scanfuse.errors',
    'FusedResult': 'scanfuse.pipeline',
    'FusionConfig': 'scanfuse.config',
    'FusionPipeline': 'scanfuse.pipeline',
    'InputError': 'scanfuse.errors',
    'MessageError': 'scanfuse.errors',
    'Method': 'scanfuse.config',
    'Resampler': 'scanfuse.config',
    'Scan': 'scanfuse.scan',
    'ScanfuseError': 'scanfuse.errors',
    'StageTimings': 'scanfuse.pipeline',
    'TransformError': 'scanfuse.errors',
    'decode_depth': 'scanfuse.camera',
}

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


def __getattr__(name: str) -> Any:
    home = _HOMES.get(name)
    if home is None:
        msg = f'module {__name__!r} has no attribute {name!r}'
        raise AttributeError(msg)
    value = getattr(importlib.import_module(home), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted([*globals(), *__all__])
