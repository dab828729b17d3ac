"""Fragmented LiDARs: the angular pieces of one revolution assembled into one scan.

Some scanners publish a revolution as several LaserScans, each covering part of it (a
PSENscan: 5 x 500 + 1 x 250 readings per 30 ms). slam_toolbox refuses scans whose reading
count changes and Nav2's collision monitor keeps only the latest message, so it sees a
sixth of the field. Fragments of one revolution tile the field of view: each starts one
increment after the previous one ends. A revolution is complete when the next fragment
does not continue it (the scanner starts over), when it covers the whole turn, or, once one
revolution has been seen, when it holds as many readings as that one did. A revolution
still incomplete after `timeout` is given out padded with NaN to the learned length, so
the reading count never changes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Generic, TypeVar

import numpy as np

from scanfuse.scan import TWO_PI, Scan

if TYPE_CHECKING:
    import numpy.typing as npt

T = TypeVar('T')
# Fragments continue each other when the next starts within this share of an increment.
CONTIGUOUS = 0.01


@dataclass
class _Revolution(Generic[T]):
    pieces: list[Scan] = field(default_factory=list)
    tokens: list[T] = field(default_factory=list)

    @property
    def readings(self) -> int:
        return sum(len(piece) for piece in self.pieces)

    def continues(self, scan: Scan) -> bool:
        last = self.pieces[-1]
        if not math.isclose(scan.angle_increment, last.angle_increment, rel_tol=1e-6):
            return False
        expected = last.angle_min + len(last) * last.angle_increment
        gap = math.remainder(scan.angle_min - expected, TWO_PI)
        return abs(gap) <= CONTIGUOUS * abs(last.angle_increment)


class FragmentAssembler(Generic[T]):
    """Collects fragments (with the adapter's tokens); gives out whole revolutions."""

    def __init__(self, timeout: float = 0.2) -> None:
        self.timeout_ns = round(timeout * 1e9)
        self._current: _Revolution[T] = _Revolution()
        self.readings: int | None = None  # learned from the first complete revolution
        self.start: float | None = None  # angle_min of that revolution
        self.padded = 0

    def add(self, scan: Scan, token: T) -> list[tuple[Scan, T]]:
        """Revolutions completed by this fragment, each with the token of its last piece."""
        out = []
        current = self._current
        if current.pieces and (
            not current.continues(scan)
            or scan.stamp_ns - current.pieces[0].stamp_ns > self.timeout_ns
        ):
            out.append(self._give_out())
        self._current.pieces.append(scan)
        self._current.tokens.append(token)
        if self._complete():
            out.append(self._give_out())
        return out

    def flush(self) -> list[tuple[Scan, T]]:
        """The revolution begun, as far as it came (the end of a recording), with the token
        of its last piece; padded with NaN to the learned length once one is known."""
        return [self._give_out()] if self._current.pieces else []

    def _complete(self) -> bool:
        current = self._current
        readings = current.readings
        increment = abs(current.pieces[0].angle_increment)
        if readings * increment >= TWO_PI - increment / 2:
            return True
        return self.readings is not None and readings >= self.readings

    def _give_out(self) -> tuple[Scan, T]:
        revolution, self._current = self._current, _Revolution()
        if self.readings is None and len(revolution.pieces) > 1:
            self.readings = revolution.readings
            self.start = revolution.pieces[0].angle_min
        return self._joined(revolution.pieces), revolution.tokens[-1]

    def _joined(self, pieces: list[Scan]) -> Scan:
        """The pieces side by side; on the learned revolution's grid (NaN where a piece is
        missing) once one is known, so the grid and the reading count never change."""
        first = pieces[0]
        increment = first.angle_increment
        count = self.readings if self.readings is not None else sum(len(p) for p in pieces)
        start = self.start if self.start is not None else first.angle_min
        ranges = np.full(count, np.nan, dtype=np.float32)
        with_intensities = all(p.intensities is not None and len(p.intensities) for p in pieces)
        intensities = np.zeros(count, dtype=np.float32) if with_intensities else None
        turn = round(TWO_PI / abs(increment))
        filled = 0
        for piece in pieces:
            offset = round(math.remainder(piece.angle_min - start, TWO_PI) / increment) % turn
            end = min(offset + len(piece), count)
            if offset >= count:
                continue
            ranges[offset:end] = piece.ranges[: end - offset]
            if intensities is not None and piece.intensities is not None:
                intensities[offset:end] = piece.intensities[: end - offset]
            filled += end - offset
        if filled < count:
            self.padded += 1
        return self._scan(pieces, start, ranges, intensities)

    @staticmethod
    def _scan(
        pieces: list[Scan],
        start: float,
        ranges: npt.NDArray[np.float32],
        intensities: npt.NDArray[np.float32] | None,
    ) -> Scan:
        first = pieces[0]
        increment = first.angle_increment
        # The revolution began before this piece when one went missing at its start.
        offset = round(math.remainder(first.angle_min - start, TWO_PI) / increment)
        begun = first.stamp_ns - round(offset * first.time_increment * 1e9)
        return Scan(
            angle_min=start,
            angle_max=start + increment * (ranges.size - 1),
            angle_increment=increment,
            range_min=min(piece.range_min for piece in pieces),
            range_max=max(piece.range_max for piece in pieces),
            ranges=ranges,
            time_increment=first.time_increment,
            scan_time=first.scan_time,
            intensities=intensities,
            frame_id=first.frame_id,
            stamp_ns=begun,
        )
