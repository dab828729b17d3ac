"""Scan metrics on hand-built scans; expected values worked out by hand."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from scanfuse.errors import InputError
from scanfuse.evaluate.metrics import (
    ScanTally,
    SlotTruth,
    Tolerance,
    detected_slots,
    false_obstacle_slots,
    low_obstacle_slots,
    scan_metrics,
)

INF = np.inf


def f32(*values: float) -> np.ndarray:
    return np.array(values, dtype=np.float32)


def truth_of(truth, plane, kinds=None, in_view=None) -> SlotTruth:
    truth = f32(*truth)
    count = truth.size
    return SlotTruth(
        truth,
        f32(*plane),
        np.array(kinds if kinds is not None else ['x'] * count, dtype=np.str_),
        np.array(in_view if in_view is not None else [True] * count, dtype=bool),
    )


def test_tolerance_is_5_cm_plus_2_percent():
    # 0.05 + 0.02 * 2.0 = 0.09; +Inf truth keeps only the absolute part.
    assert Tolerance().of(np.array([0.0, 2.0, INF])) == pytest.approx([0.05, 0.09, 0.05])


def test_negative_tolerance_is_rejected():
    with pytest.raises(InputError, match='must not be negative'):
        Tolerance(absolute=-0.01)


def test_low_obstacle_slot_needs_truth_shorter_than_plane_by_more_than_tolerance():
    # Truth 1.0 (tolerance 0.07): plane 1.2 is low, 1.05 is not, Inf is low; no truth is not.
    low = low_obstacle_slots(f32(1.0, 1.0, 1.0, INF), f32(1.2, 1.05, INF, INF))
    assert low.tolist() == [True, False, True, False]


def test_recall_is_one_when_fused_equals_truth():
    truth = truth_of([1.0, 2.0, 3.0, 4.0], [3.0, INF, 3.0, 4.0])
    metrics = scan_metrics(truth.truth.copy(), truth)
    assert metrics.low_slots == 2
    assert metrics.recall == 1.0
    assert metrics.false_obstacle_rate == 0.0
    assert metrics.median_error == 0.0


def test_false_obstacles_counted_when_a_slot_is_too_short():
    # Truth 2.0 has tolerance 0.09: 1.90 is too short (false), 1.95 is not.
    truth = truth_of([2.0, 2.0, 2.0, 2.0], [2.0, 2.0, 2.0, 2.0])
    fused = f32(1.90, 1.95, 2.0, 2.5)
    assert false_obstacle_slots(fused, truth.truth).tolist() == [True, False, False, False]
    assert scan_metrics(fused, truth).false_obstacle_rate == 0.25


def test_hand_computed_recall_error_and_kinds():
    # Four low slots (plane sees the wall at 3 m): two boxes, two shelf boards.
    truth = truth_of(
        [1.0, 1.0, 2.0, 2.0, 3.0],
        [3.0, 3.0, 3.0, 3.0, 3.0],
        kinds=['box', 'box', 'board', 'board', 'wall'],
    )
    # box 1: 1.03 within 0.07 -> detected, error 0.03; box 2: 3.0 missed;
    # board 1: 1.99 detected, error 0.01; board 2: NaN missed; wall slot not low.
    fused = f32(1.03, 3.0, 1.99, np.nan, 3.0)
    metrics = scan_metrics(fused, truth)
    assert metrics.low_slots == 4
    assert metrics.recall == 0.5
    assert metrics.recall_by_kind == {'board': 0.5, 'box': 0.5}
    assert metrics.low_slots_by_kind == {'board': 2, 'box': 2}
    assert metrics.median_error == pytest.approx(0.02, abs=1e-6)
    assert metrics.false_obstacle_rate == 0.0


def test_recall_counts_only_slots_in_the_cameras_view():
    truth = truth_of([1.0, 1.0], [3.0, 3.0], in_view=[True, False])
    metrics = scan_metrics(f32(1.0, 3.0), truth)
    assert metrics.recall == 1.0  # the missed slot is outside the view
    assert metrics.recall_all == 0.5


def test_rep117_readings():
    truth = truth_of([1.0, 1.0, 1.0, INF], [3.0, 3.0, 3.0, INF])
    fused = f32(np.nan, INF, -INF, 2.0)
    # NaN and +Inf miss the obstacle; -Inf (too close) is an obstacle nearer than the truth.
    assert detected_slots(fused, truth.truth).tolist() == [False, False, True, True]
    # -Inf at a 1 m obstacle is short by more than 0.07: false; 2.0 where nothing is: false.
    assert false_obstacle_slots(fused, truth.truth).tolist() == [False, False, True, True]


def test_no_low_slots_gives_nan_recall():
    truth = truth_of([2.0], [2.0])
    assert math.isnan(scan_metrics(f32(2.0), truth).recall)


def test_tally_accumulates_over_scans():
    tally = ScanTally()
    truth = truth_of([1.0, 2.0], [3.0, 2.0])
    tally.add(f32(1.0, 2.0), truth)  # low slot detected
    tally.add(f32(3.0, 1.0), truth)  # low slot missed, slot 2 false
    summary = tally.summary()
    assert summary.slots == 4
    assert summary.recall == 0.5
    assert summary.false_obstacle_rate == 0.25


def test_mismatched_lengths_are_rejected():
    with pytest.raises(InputError, match='one length per slot'):
        detected_slots(f32(1.0, 2.0), f32(1.0))
    with pytest.raises(InputError, match='one length per slot'):
        truth_of([1.0, 2.0], [1.0])


@given(
    st.lists(st.floats(0.25, 10.0, width=32), min_size=1, max_size=50),
    st.floats(0.0, 0.04),
)
def test_fused_within_tolerance_is_never_false_and_always_detected(ranges, shift):
    truth = np.array(ranges, dtype=np.float32)
    fused = (truth - np.float32(shift)).astype(np.float32)
    assert not false_obstacle_slots(fused, truth).any()
    assert detected_slots(fused, truth).all()
