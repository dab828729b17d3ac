"""Pairing LiDAR scans with depth frames by stamp: arrays and streams."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scanfuse import InputError
from scanfuse.ros.sync import UNPAIRED, StreamPairer, pair_nearest, seconds_to_ns

MS = 1_000_000


def _brute_force(scans, depths, max_offset):
    """O(N*M) reference: nearest frame, earlier on a tie, first listed among equal stamps."""
    out = []
    for scan in scans:
        best = UNPAIRED
        for index, depth in enumerate(depths):
            if abs(depth - scan) > max_offset:
                continue
            if best == UNPAIRED:
                best = index
                continue
            old = depths[best]
            closer = abs(depth - scan) < abs(old - scan)
            tie_earlier = abs(depth - scan) == abs(old - scan) and depth < old
            if closer or tie_earlier:
                best = index
        out.append(best)
    return out


def test_pairs_each_scan_with_the_nearest_frame():
    scans = [0, 100, 200, 300, 1000]
    depths = [90, 30, 210, 500]
    # 0 -> 30 (30 away); 100 -> 90; 200 -> 210; 300: 210 is 90 away, 500 is 200; 1000: none.
    assert pair_nearest(scans, depths, 95).tolist() == [1, 0, 2, 2, UNPAIRED]


def test_offset_limit_is_inclusive():
    assert pair_nearest([100], [200], 100).tolist() == [0]
    assert pair_nearest([100], [201], 100).tolist() == [UNPAIRED]


def test_tie_goes_to_the_earlier_frame():
    assert pair_nearest([100], [150, 50], 60).tolist() == [1]


def test_equal_stamps_pick_the_first_listed():
    assert pair_nearest([100], [120, 120, 80, 80], 50).tolist() == [2]
    assert pair_nearest([100], [120, 120], 50).tolist() == [0]


def test_empty_inputs():
    assert pair_nearest([], [1, 2], 5).tolist() == []
    assert pair_nearest([1, 2], [], 5).tolist() == [UNPAIRED, UNPAIRED]


def test_negative_offset_is_an_input_error():
    with pytest.raises(InputError, match='max_offset_ns must not be negative'):
        pair_nearest([1], [1], -1)


def test_seconds_to_ns():
    assert seconds_to_ns(0.1) == 100 * MS


stamps = st.lists(st.integers(0, 2000), max_size=40)


@settings(max_examples=200, deadline=None)
@given(stamps, stamps, st.integers(0, 300))
def test_matches_brute_force_in_any_order(scans, depths, max_offset):
    assert pair_nearest(scans, depths, max_offset).tolist() == _brute_force(
        scans, depths, max_offset
    )


def _stream(scans, depths, jitter_scans, jitter_depths, max_offset, reorder):
    """Feed both streams in arrival order (stamp + jitter) and collect the pairs."""
    arrivals = [(s + j, 0, i) for i, (s, j) in enumerate(zip(scans, jitter_scans, strict=True))]
    arrivals += [(d + j, 1, i) for i, (d, j) in enumerate(zip(depths, jitter_depths, strict=True))]
    arrivals.sort()
    pairer: StreamPairer[int, int] = StreamPairer(max_offset, reorder)
    pairs = []
    depth_order = []
    for _, kind, index in arrivals:
        if kind == 0:
            pairs += pairer.add_scan(scans[index], index)
        else:
            depth_order.append(index)
            pairs += pairer.add_depth(depths[index], index)
    pairs += pairer.finish()
    return pairs, depth_order, pairer


@settings(max_examples=200, deadline=None)
@given(
    st.lists(st.tuples(st.integers(0, 5000), st.integers(0, 99)), max_size=40),
    st.lists(st.tuples(st.integers(0, 5000), st.integers(0, 99)), max_size=60),
    st.integers(0, 400),
)
def test_stream_pairs_like_the_whole_arrays(scan_items, depth_items, max_offset):
    # Arrival disorder below reorder (100): the stream must give the global answer.
    scans = [s for s, _ in scan_items]
    depths = [d for d, _ in depth_items]
    pairs, depth_order, _ = _stream(
        scans, depths, [j for _, j in scan_items], [j for _, j in depth_items], max_offset, 100
    )
    assert sorted(pair.scan for pair in pairs) == list(range(len(scans)))
    # The global reference sees frames in their arrival order (its tie rule: first listed).
    arrived = [depths[i] for i in depth_order]
    expected = pair_nearest(scans, arrived, max_offset).tolist()
    for pair in pairs:
        want = expected[pair.scan]
        assert pair.scan_stamp_ns == scans[pair.scan]
        if want == UNPAIRED:
            assert pair.depth is None
            assert pair.depth_stamp_ns is None
        else:
            assert pair.depth == depth_order[want]
            assert pair.depth_stamp_ns == arrived[want]


def test_stream_holds_only_a_short_window_of_frames():
    # 60 s of 30 Hz depth and 10 Hz scans, camera 20 ms late. Pending scans reach back
    # max_offset (plus one scan period) behind the watermark (newest - reorder), and
    # frames are kept max_offset before the oldest pending scan: a window of
    # 0.5 + 0.1 + 0.1 + 0.1 = 0.8 s, 24 frames at 30 Hz (+2 for the ends).
    second = 1000 * MS
    scans = [i * second // 10 for i in range(600)]
    depths = [i * second // 30 for i in range(1800)]
    pairs, _, pairer = _stream(scans, depths, [0] * 600, [20 * MS] * 1800, 100 * MS, second // 2)
    assert len(pairs) == 600
    assert all(pair.depth_stamp_ns == pair.scan_stamp_ns for pair in pairs)
    assert pairer.peak_frames <= 0.8 * 30 + 2
    assert pairer.buffered_frames == 0


def test_unpaired_scan_passes_with_no_frame():
    pairer: StreamPairer[str, str] = StreamPairer(10, 0)
    assert pairer.add_scan(0, 'scan') == []
    (pair,) = pairer.add_depth(100, 'far frame')
    assert (pair.scan, pair.depth, pair.depth_stamp_ns) == ('scan', None, None)


def test_stream_negative_parameters_are_input_errors():
    with pytest.raises(InputError, match='must not be negative'):
        StreamPairer(-1)
    with pytest.raises(InputError, match='must not be negative'):
        StreamPairer(1, -1)


def test_pair_indices_are_int64():
    assert pair_nearest(np.array([1, 2]), np.array([1]), 0).dtype == np.int64
