"""Hypothesis strategies for scans with every REP-117 kind of value."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from scanfuse import Scan

RANGE_VALUES = st.one_of(
    st.floats(min_value=0.0, max_value=30.0, width=32),
    st.sampled_from([np.nan, np.inf, -np.inf, 0.0]),
)


@st.composite
def scans(draw: st.DrawFn, size: int | None = None, range_min: float = 0.15) -> Scan:
    count = size if size is not None else draw(st.integers(1, 64))
    ranges = draw(hnp.arrays(np.float32, count, elements=RANGE_VALUES))
    increment = draw(st.sampled_from([0.01, 0.0058, -0.0058]))
    angle_min = draw(st.sampled_from([-np.pi, 0.0, 0.7]))
    return Scan(
        angle_min=angle_min,
        angle_max=angle_min + increment * (count - 1),
        angle_increment=increment,
        range_min=range_min,
        range_max=draw(st.sampled_from([10.0, 12.0])),
        ranges=ranges,
        stamp_ns=draw(st.integers(0, 2**40)),
        frame_id='laser',
    )


@st.composite
def scan_pairs(draw: st.DrawFn) -> tuple[Scan, Scan]:
    """A LiDAR scan and a depth scan already on its grid."""
    lidar = draw(scans())
    depth_ranges = draw(hnp.arrays(np.float32, len(lidar), elements=RANGE_VALUES))
    depth = lidar.with_ranges(depth_ranges, range_min=0.2, range_max=10.0, frame_id='camera')
    return lidar, depth
