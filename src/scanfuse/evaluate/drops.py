"""False drop slots: what reporting drop-offs costs on worlds that have none.

Definition (the report states it too): on a world without drop-offs, a slot of a
method that reports drops (`detect_drops: true`) is a **false drop slot** when its
fused range is

1. shorter than the ground-truth obstacle scan by more than the tolerance (a false
   obstacle, `metrics.false_obstacle_slots`), and
2. shorter by more than the same tolerance than what the same method, fed the same
   events, gives with `detect_drops: false`.

On such a world every drop reported is false, and condition 2 keeps exactly the
slots that drops moved closer: floor noise inside the slab, mixed pixels and phantom
edges are there with drops off as well and are not counted. Methods without drops
have no false drop slots by construction and no count.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

from scanfuse.config import Method
from scanfuse.evaluate.metrics import Tolerance, false_obstacle_slots

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from scanfuse.config import FusionConfig

    F32 = npt.NDArray[np.float32]


def reports_drops(config: FusionConfig, *, fuses: bool = True) -> bool:
    """Whether a method reports drop-offs: the obstacle method with `detect_drops` on (False
    for every method before drops existed)."""
    return (
        fuses and config.method is Method.OBSTACLE and bool(getattr(config, 'detect_drops', False))
    )


def false_drop_slots(
    with_drops: F32, without_drops: F32, truth: F32, tolerance: Tolerance | None = None
) -> npt.NDArray[np.bool_]:
    """Slots that drops made false: short of the truth and of the drop-free scan (module doc)."""
    tolerance = tolerance or Tolerance()
    short = false_obstacle_slots(with_drops, truth, tolerance)
    # The same tolerance as the truth's, at the drop-free range (+Inf: the absolute part).
    closer = false_obstacle_slots(with_drops, without_drops, tolerance)
    found: npt.NDArray[np.bool_] = short & closer
    return found


@dataclass
class DropTally:
    """False drop slots and all slots counted, over the scans of worlds without drop-offs."""

    slots: int = 0
    false_drops: int = 0

    def add(self, mask: npt.NDArray[np.bool_]) -> None:
        self.slots += int(mask.size)
        self.false_drops += int(mask.sum())

    @property
    def rate(self) -> float:
        return self.false_drops / self.slots if self.slots else math.nan
