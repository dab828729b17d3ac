"""One base exception, one subclass per kind of mistake the user can fix."""

from __future__ import annotations


class ScanfuseError(Exception):
    """Base of every error scanfuse raises on purpose."""


class ConfigError(ScanfuseError):
    """A parameter or parameter file is wrong."""


class InputError(ScanfuseError):
    """An array, scan or camera model handed to the core is unusable."""


class DepthEncodingError(InputError):
    """A depth image has an encoding or layout scanfuse cannot decode."""


class MessageError(ScanfuseError):
    """A ROS message cannot be converted to or from the core types."""


class TransformError(ScanfuseError):
    """A transform between two frames is missing or invalid."""


class BagError(ScanfuseError):
    """A bag cannot be read or written."""


class CalibrationError(ScanfuseError):
    """The recording cannot fix the camera's mounting (too little floor, too few walls)."""


class ClusterError(ScanfuseError):
    """A Ray cluster cannot be reached or used (not installed, no head, workers lost)."""
