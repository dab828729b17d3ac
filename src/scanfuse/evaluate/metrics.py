"""Scan metrics against the ground-truth obstacle scan (DESIGN.md "Evaluation vocabulary").

Per LiDAR slot the simulator knows two true ranges: `truth`, the nearest surface
inside the collision slab, and `plane`, the nearest surface the LiDAR's own plane
crosses. A slot holds a low obstacle when `truth` is shorter than `plane` by more
than the tolerance: something the LiDAR cannot see is in the robot's way.

- recall: share of low-obstacle slots inside the camera's view where the fused
  range is within tolerance of the truth or shorter;
- false obstacle rate: share of all slots where the fused range is shorter
  than the truth by more than the tolerance (floor, phantom edges, noise);
- all-around recall: share of low-obstacle slots whose true point lies within 1.0 m
  of the robot's footprint, in every direction (in the camera's view or not): what
  the obstacle memory is for;
- all-around recall of seen slots: the same over those of them whose true point a
  depth image had shown before (`SlotTruth.seen`). The all-around recall also counts
  low obstacles the camera never looked at (a box beside the robot at its start, seen by
  no frame yet): no camera memory can hold those, so they measure where the robot went
  and looked, not what the memory kept. This one measures the memory; both are reported;
- range error: |fused - truth| of detected low-obstacle slots.

REP-117 readings compare naturally: NaN (no information) never detects and is
never false, +Inf (free) detects nothing, -Inf (too close) is an obstacle at
range zero. Pure numpy, no I/O.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from scanfuse.errors import InputError

if TYPE_CHECKING:
    import numpy.typing as npt

    F32 = npt.NDArray[np.float32]
    Mask = npt.NDArray[np.bool_]

TOLERANCE_ABSOLUTE = 0.05  # metres
TOLERANCE_RELATIVE = 0.02  # share of the true range
ALL_AROUND_REACH = 1.0  # metres from the footprint's edge (DESIGN.md "All-around recall")


@dataclass(frozen=True)
class Tolerance:
    """How far a range may be from the truth and still count as right: a + r * range."""

    absolute: float = TOLERANCE_ABSOLUTE
    relative: float = TOLERANCE_RELATIVE

    def __post_init__(self) -> None:
        if self.absolute < 0.0 or self.relative < 0.0:
            msg = (
                f'tolerance must not be negative, got absolute={self.absolute} m, '
                f'relative={self.relative}'
            )
            raise InputError(msg)

    def of(self, truth: npt.NDArray[np.floating]) -> npt.NDArray[np.float64]:
        """Tolerance per slot; where the truth is +Inf (nothing in range) only the absolute part."""
        finite = np.where(np.isfinite(truth), truth, 0.0).astype(np.float64)
        return self.absolute + self.relative * np.abs(finite)


def _check_shapes(**arrays: npt.NDArray[np.generic]) -> int:
    sizes = {name: array.shape for name, array in arrays.items()}
    shapes = set(sizes.values())
    if len(shapes) != 1 or next(iter(shapes)) == () or len(next(iter(shapes))) != 1:
        listed = ', '.join(f'{name} {shape}' for name, shape in sizes.items())
        msg = f'scan metrics need one-dimensional arrays of one length per slot, got {listed}'
        raise InputError(msg)
    return int(next(iter(shapes))[0])


def low_obstacle_slots(truth: F32, plane: F32, tolerance: Tolerance = Tolerance()) -> Mask:
    """Slots where the collision slab holds something nearer than what the LiDAR plane sees."""
    _check_shapes(truth=truth, plane=plane)
    truth64 = truth.astype(np.float64)
    with np.errstate(invalid='ignore'):
        low: Mask = np.isfinite(truth64) & (truth64 < plane - tolerance.of(truth64))
    return low


def detected_slots(fused: F32, truth: F32, tolerance: Tolerance = Tolerance()) -> Mask:
    """Slots whose fused range is within tolerance of the truth, or shorter."""
    _check_shapes(fused=fused, truth=truth)
    truth64 = truth.astype(np.float64)
    with np.errstate(invalid='ignore'):
        hit: Mask = fused <= truth64 + tolerance.of(truth64)
    return hit


def false_obstacle_slots(fused: F32, truth: F32, tolerance: Tolerance = Tolerance()) -> Mask:
    """Slots whose fused range is shorter than the truth by more than the tolerance."""
    _check_shapes(fused=fused, truth=truth)
    truth64 = truth.astype(np.float64)
    with np.errstate(invalid='ignore'):
        short: Mask = fused < truth64 - tolerance.of(truth64)
    return short


def near_footprint_slots(
    truth: F32,
    angles: npt.NDArray[np.float64],
    centre: tuple[float, float],
    radius: float,
    reach: float = ALL_AROUND_REACH,
) -> Mask:
    """Slots whose true point lies within `reach` of a round footprint (LiDAR frame).

    The footprint is the disc of `radius` about `centre` (the base's centre in the
    LiDAR's frame); a slot's true point is `truth` along its angle from the LiDAR.
    """
    _check_shapes(truth=truth, angles=angles)
    finite = np.isfinite(truth)
    ranges = np.where(finite, truth, 0.0).astype(np.float64)
    gap = np.hypot(ranges * np.cos(angles) - centre[0], ranges * np.sin(angles) - centre[1])
    near: Mask = finite & (gap - radius <= reach)
    return near


@dataclass(frozen=True)
class SlotTruth:
    """Ground truth of one scan, per slot.

    `kinds[i]` names the obstacle kind nearest in slot i ('' where nothing is in
    range); `in_view` marks the slots the camera can see (the evaluation's
    recall counts only those); `near` the slots whose true point lies within
    `ALL_AROUND_REACH` of the robot's footprint (None: not known, counted nowhere);
    `seen` the slots whose true point some depth image before this scan showed (None:
    not known).
    """

    truth: F32
    plane: F32
    kinds: npt.NDArray[np.str_]
    in_view: Mask
    near: Mask | None = None
    seen: Mask | None = None

    def __post_init__(self) -> None:
        _check_shapes(truth=self.truth, plane=self.plane, kinds=self.kinds, in_view=self.in_view)
        if self.near is not None:
            _check_shapes(truth=self.truth, near=self.near)
        if self.seen is not None:
            _check_shapes(truth=self.truth, seen=self.seen)


@dataclass
class KindCounts:
    """Low-obstacle slots of one obstacle kind and how many of them were detected."""

    low: int = 0
    detected: int = 0

    @property
    def recall(self) -> float:
        return self.detected / self.low if self.low else float('nan')


@dataclass
class ScanTally:
    """Counts accumulated over many scans of one method; `summary()` gives the metrics."""

    tolerance: Tolerance = field(default_factory=Tolerance)
    slots: int = 0
    false_obstacles: int = 0
    low_in_view: int = 0
    detected_in_view: int = 0
    low_total: int = 0
    detected_total: int = 0
    low_near: int = 0
    detected_near: int = 0
    low_near_seen: int = 0
    detected_near_seen: int = 0
    errors: list[npt.NDArray[np.float64]] = field(default_factory=list)
    by_kind: dict[str, KindCounts] = field(default_factory=dict)

    def add(self, fused: F32, truth: SlotTruth) -> None:
        """Count one fused scan against its ground truth."""
        _check_shapes(fused=fused, truth=truth.truth)
        low = low_obstacle_slots(truth.truth, truth.plane, self.tolerance)
        hit = detected_slots(fused, truth.truth, self.tolerance) & low
        counted = low & truth.in_view
        self.slots += fused.size
        self.false_obstacles += int(false_obstacle_slots(fused, truth.truth, self.tolerance).sum())
        self.low_total += int(low.sum())
        self.detected_total += int(hit.sum())
        self.low_in_view += int(counted.sum())
        self.detected_in_view += int((hit & counted).sum())
        if truth.near is not None:
            self.low_near += int((low & truth.near).sum())
            self.detected_near += int((hit & truth.near).sum())
            if truth.seen is not None:
                seen_near = low & truth.near & truth.seen
                self.low_near_seen += int(seen_near.sum())
                self.detected_near_seen += int((hit & seen_near).sum())
        finite_hit = hit & counted & np.isfinite(fused)
        self.errors.append(np.abs(fused[finite_hit].astype(np.float64) - truth.truth[finite_hit]))
        for kind in np.unique(truth.kinds[counted]):
            of_kind = counted & (truth.kinds == kind)
            counts = self.by_kind.setdefault(str(kind), KindCounts())
            counts.low += int(of_kind.sum())
            counts.detected += int((hit & of_kind).sum())

    def merge(self, other: ScanTally) -> None:
        """Add another tally's counts (the metrics do not depend on the order of scans)."""
        for name in (
            'slots',
            'false_obstacles',
            'low_in_view',
            'detected_in_view',
            'low_total',
            'detected_total',
            'low_near',
            'detected_near',
            'low_near_seen',
            'detected_near_seen',
        ):
            setattr(self, name, getattr(self, name) + getattr(other, name))
        self.errors += other.errors
        for kind, counts in other.by_kind.items():
            mine = self.by_kind.setdefault(kind, KindCounts())
            mine.low += counts.low
            mine.detected += counts.detected

    def summary(self) -> ScanMetrics:
        errors = np.concatenate(self.errors) if self.errors else np.zeros(0)
        return ScanMetrics(
            slots=self.slots,
            low_slots=self.low_in_view,
            recall=_ratio(self.detected_in_view, self.low_in_view),
            recall_all=_ratio(self.detected_total, self.low_total),
            false_obstacle_rate=_ratio(self.false_obstacles, self.slots),
            median_error=float(np.median(errors)) if errors.size else float('nan'),
            p95_error=float(np.percentile(errors, 95)) if errors.size else float('nan'),
            recall_by_kind={kind: counts.recall for kind, counts in sorted(self.by_kind.items())},
            low_slots_by_kind={kind: counts.low for kind, counts in sorted(self.by_kind.items())},
            low_slots_near=self.low_near,
            recall_near=_ratio(self.detected_near, self.low_near),
            low_slots_near_seen=self.low_near_seen,
            recall_near_seen=_ratio(self.detected_near_seen, self.low_near_seen),
        )


def _ratio(numerator: int, denominator: int) -> float:
    return numerator / denominator if denominator else float('nan')


@dataclass(frozen=True)
class ScanMetrics:
    """The scan metrics of one method (NaN where nothing was there to count)."""

    slots: int
    low_slots: int  # low-obstacle slots inside the camera's view
    recall: float  # of low-obstacle slots inside the camera's view
    recall_all: float  # of every low-obstacle slot, seen by the camera or not
    false_obstacle_rate: float
    median_error: float  # metres, detected low-obstacle slots
    p95_error: float
    recall_by_kind: dict[str, float]
    low_slots_by_kind: dict[str, int]
    low_slots_near: int = 0  # low-obstacle slots within 1 m of the footprint, any direction
    recall_near: float = float('nan')  # all-around recall of those
    low_slots_near_seen: int = 0  # of those, the ones a depth image had shown before
    recall_near_seen: float = float('nan')  # all-around recall of seen slots


def scan_metrics(fused: F32, truth: SlotTruth, tolerance: Tolerance = Tolerance()) -> ScanMetrics:
    """The metrics of one fused scan against its ground truth."""
    tally = ScanTally(tolerance)
    tally.add(fused, truth)
    return tally.summary()
