"""Range trade-off of the row method: equations 4-6 and the exact floor intersection."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class FloorGuard:
    """A camera of known height and pitch above a flat floor (row method's floor guard)."""

    camera_height: float
    camera_pitch: float  # radians, positive looks down
    margin: float = 0.05  # metres kept short of the floor intersection
