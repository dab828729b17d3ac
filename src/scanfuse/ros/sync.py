"""Pairing of LiDAR scans with depth frames by header stamp.

Each scan is paired with the depth frame whose stamp is nearest to its own,
when that frame is at most `max_offset` away; otherwise the scan stays
unpaired and passes through unchanged. `pair_nearest` does this for whole
arrays with one sort and one `np.searchsorted` (O((N + M) log M)), and
`StreamPairer` gives the same answer for messages that arrive one at a time
(a bag read in log-time order) while holding only a short window of frames.
"""

from __future__ import annotations

import heapq
import itertools
from dataclasses import dataclass
from typing import TYPE_CHECKING, Generic, TypeVar

import numpy as np

from scanfuse.errors import InputError

if TYPE_CHECKING:
    import numpy.typing as npt

    IntArray = npt.NDArray[np.int64]

S = TypeVar('S')
D = TypeVar('D')

NANOSECONDS = 1_000_000_000
UNPAIRED = -1


def seconds_to_ns(seconds: float) -> int:
    return round(seconds * NANOSECONDS)


def pair_nearest(
    scan_stamps_ns: npt.ArrayLike, depth_stamps_ns: npt.ArrayLike, max_offset_ns: int
) -> IntArray:
    """Index into `depth_stamps_ns` of the frame nearest each scan, or -1 (UNPAIRED).

    Stamps may come in any order. A frame pairs when |scan - frame| <= max_offset_ns;
    of two frames equally near, the earlier one wins (then the one listed first).
    """
    if max_offset_ns < 0:
        msg = f'max_offset_ns must not be negative, got {max_offset_ns}'
        raise InputError(msg)
    scans = np.asarray(scan_stamps_ns, dtype=np.int64).reshape(-1)
    depths = np.asarray(depth_stamps_ns, dtype=np.int64).reshape(-1)
    result = np.full(scans.size, UNPAIRED, dtype=np.int64)
    if depths.size == 0 or scans.size == 0:
        return result
    order = np.argsort(depths, kind='stable')
    sorted_depths = depths[order]
    # right: first frame at or after the scan (leftmost of equal stamps); left: the one before.
    right = np.searchsorted(sorted_depths, scans, side='left')
    left = right - 1
    right_clipped = np.minimum(right, depths.size - 1)
    left_clipped = np.maximum(left, 0)
    # Of equal stamps before the scan, the first listed is at the start of its run.
    left_first = np.searchsorted(sorted_depths, sorted_depths[left_clipped], side='left')
    after = np.where(
        right < depths.size, sorted_depths[right_clipped] - scans, np.iinfo(np.int64).max
    )
    before = np.where(left >= 0, scans - sorted_depths[left_clipped], np.iinfo(np.int64).max)
    take_before = before <= after
    nearest = np.where(take_before, left_first, right_clipped)
    offset = np.minimum(before, after)
    paired = offset <= max_offset_ns
    result[paired] = order[nearest[paired]]
    return result


@dataclass(frozen=True)
class Pair(Generic[S, D]):
    """A scan and the depth frame it was paired with (None: passes through unchanged)."""

    scan: S
    scan_stamp_ns: int
    depth: D | None
    depth_stamp_ns: int | None


class StreamPairer(Generic[S, D]):
    """Pairs scans with depth frames as they arrive, with the result of `pair_nearest`.

    Messages may arrive out of stamp order by up to `reorder_ns`: once the newest
    stamp seen minus `reorder_ns` (the watermark) is more than `max_offset_ns` past
    a scan, no frame still to come can pair with it and its pair is final. Frames
    too old for every pending and future scan are dropped, so only the frames of
    about `reorder_ns + 2 max_offset_ns` plus one scan period of recording are held.
    """

    def __init__(self, max_offset_ns: int, reorder_ns: int = NANOSECONDS // 2) -> None:
        if max_offset_ns < 0 or reorder_ns < 0:
            msg = (
                f'max_offset_ns ({max_offset_ns}) and reorder_ns ({reorder_ns}) '
                'must not be negative'
            )
            raise InputError(msg)
        self.max_offset_ns = max_offset_ns
        self.reorder_ns = reorder_ns
        self._newest: int | None = None
        self._pending: list[tuple[int, int, S]] = []  # heap of (stamp, arrival, scan)
        self._frames: list[tuple[int, D]] = []  # arrival order
        self._arrivals = itertools.count()
        self.peak_frames = 0

    @property
    def buffered_frames(self) -> int:
        return len(self._frames)

    def add_scan(self, stamp_ns: int, scan: S) -> list[Pair[S, D]]:
        heapq.heappush(self._pending, (stamp_ns, next(self._arrivals), scan))
        return self._advance(stamp_ns)

    def add_depth(self, stamp_ns: int, frame: D) -> list[Pair[S, D]]:
        self._frames.append((stamp_ns, frame))
        self.peak_frames = max(self.peak_frames, len(self._frames))
        return self._advance(stamp_ns)

    def finish(self) -> list[Pair[S, D]]:
        """Pairs of every scan still pending (end of the recording)."""
        ready = [heapq.heappop(self._pending) for _ in range(len(self._pending))]
        pairs = self._pair(ready)
        self._frames.clear()
        return pairs

    def _advance(self, stamp_ns: int) -> list[Pair[S, D]]:
        self._newest = stamp_ns if self._newest is None else max(self._newest, stamp_ns)
        watermark = self._newest - self.reorder_ns
        ready = []
        while self._pending and self._pending[0][0] + self.max_offset_ns < watermark:
            ready.append(heapq.heappop(self._pending))
        pairs = self._pair(ready) if ready else []
        oldest_scan = min(watermark, self._pending[0][0]) if self._pending else watermark
        if self._frames and self._frames[0][0] + self.max_offset_ns < oldest_scan:
            self._frames = [f for f in self._frames if f[0] + self.max_offset_ns >= oldest_scan]
        return pairs

    def _pair(self, ready: list[tuple[int, int, S]]) -> list[Pair[S, D]]:
        if not ready:
            return []
        stamps = np.array([stamp for stamp, _, _ in ready], dtype=np.int64)
        frame_stamps = np.array([stamp for stamp, _ in self._frames], dtype=np.int64)
        chosen = pair_nearest(stamps, frame_stamps, self.max_offset_ns)
        pairs: list[Pair[S, D]] = []
        for (stamp, _, scan), index in zip(ready, chosen.tolist(), strict=True):
            if index == UNPAIRED:
                pairs.append(Pair(scan, stamp, None, None))
            else:
                frame_stamp, frame = self._frames[index]
                pairs.append(Pair(scan, stamp, frame, frame_stamp))
        return pairs
