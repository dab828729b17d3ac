"""Which source each reading of a fused scan came from, to tell where false obstacles arise.

A fused scan is the nearest, slot by slot, of the LiDARs' readings, the cameras' and the
memory's (`scanfuse.fuse.merge`), so each reading equals the source that made it. The
memory is merged last, into the scan without it (`StreamOutput.instant`): a slot the memory
made nearer is the memory's; of the rest, one equal to the cameras' scan is a camera's; the
others are a LiDAR's (or a cloud's).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    import numpy.typing as npt

    from scanfuse.scan import Scan

    Sources = npt.NDArray[np.uint8]

# `slot_sources`' codes, indices into SOURCES.
LIDAR, CAMERA, MEMORY = 0, 1, 2
SOURCES = ('LiDAR', 'camera', 'memory')


def slot_sources(fused: Scan, depth_scan: Scan | None, instant: Scan | None) -> Sources:
    """Per slot of `fused`, the code of the source its reading came from (see the module):
    `depth_scan` the cameras' readings on the same grid (None: no camera), `instant` the
    fused scan before the memory was merged (None: no memory)."""
    ranges = fused.ranges
    sources = np.full(ranges.shape, LIDAR, dtype=np.uint8)
    if depth_scan is not None:
        sources[np.isfinite(ranges) & (ranges == depth_scan.ranges)] = CAMERA
    if instant is not None:
        before = np.where(np.isnan(instant.ranges), np.inf, instant.ranges)
        with np.errstate(invalid='ignore'):
            sources[ranges < before] = MEMORY
    return sources


def count_sources(sources: Sources, mask: npt.NDArray[np.bool_]) -> list[int]:
    """How many of the slots in `mask` each source made, in SOURCES' order."""
    return [int(n) for n in np.bincount(sources[mask], minlength=len(SOURCES))[: len(SOURCES)]]
