"""The simulator's error: a world, robot, sensor or recording setting that cannot work."""

from __future__ import annotations

from scanfuse.errors import ScanfuseError


class SimError(ScanfuseError):
    """A simulation parameter is unknown or out of range, or a recording cannot be written."""
