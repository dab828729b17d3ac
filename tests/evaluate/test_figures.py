"""The figures' texts and marks: nothing overlaps, every sensor is drawn where it sits."""

from __future__ import annotations

import itertools
import math

import matplotlib.pyplot as plt
import numpy as np
import pytest

from scanfuse.app.demo import sensor_marks
from scanfuse.evaluate.figures import ScanLayer, bars_plot, draw_scans
from scanfuse.evaluate.methods import METHODS
from scanfuse.scan import Scan
from scanfuse.transforms import Extrinsics


def visible_texts(figure):
    """Every non-empty text the figure shows, with its box in pixels (drawn first)."""
    figure.canvas.draw()
    renderer = figure.canvas.get_renderer()
    return [
        (text.get_text(), text.get_window_extent(renderer))
        for text in figure.findobj(plt.Text)
        if text.get_visible() and text.get_text().strip()
    ]


@pytest.mark.parametrize('count', [4, len(METHODS)])
def test_no_text_of_the_metrics_figure_overlaps_another(count):
    methods = list(METHODS)[:count]
    # Values of every size the report gives: tiny, n/a, large percentages, shares.
    rng = np.random.default_rng(1)
    metrics = {
        'recall of low obstacles in view': list(rng.uniform(0.0, 1.0, count)),
        'false obstacles (% of slots)': list(rng.uniform(0.0, 40.0, count)),
        'goals reached (share of trials)': [math.nan if i % 2 else 1.0 for i in range(count)],
        'collisions (share of trials)': [math.nan if i % 3 else 0.889 for i in range(count)],
    }
    figure = bars_plot(methods, metrics, title='scanfuse: methods compared')
    try:
        texts = visible_texts(figure)
        shown = {text for text, _ in texts}
        assert set(methods) <= shown
        overlapping = [
            (a, b)
            for (a, box_a), (b, box_b) in itertools.combinations(texts, 2)
            if box_a.overlaps(box_b)
        ]
        assert overlapping == []
    finally:
        plt.close(figure)


def test_the_camera_and_the_lidar_are_marked_each_where_it_sits():
    # A camera 0.3 m ahead of and 0.4 m above a LiDAR (base frame, metres).
    extrinsics = Extrinsics.from_mounting(
        camera_x=0.3, camera_height=0.7, camera_pitch=0.5, lidar_height=0.3
    )
    camera, lidar = sensor_marks(extrinsics)
    assert camera.xy == pytest.approx((0.3, 0.0))
    assert lidar.xy == pytest.approx((0.0, 0.0))
    assert 'camera' in camera.label
    assert '0.70 m' in camera.label
    assert 'LiDAR' in lidar.label
    assert '0.30 m' in lidar.label
    # Drawn top-down (x up the page, y to the left): each mark at its own place, both named.
    scan = Scan(-0.5, 0.5, 0.5, 0.1, 5.0, np.full(3, 1.0, dtype=np.float32))
    figure, axes = plt.subplots()
    try:
        draw_scans(axes, [ScanLayer('scan', scan, 'tab:red')], title='t', sensors=[camera, lidar])
        labels = [text.get_text() for text in axes.get_legend().get_texts()]
        assert camera.label in labels
        assert lidar.label in labels
        marks = {
            collection.get_label(): tuple(np.asarray(collection.get_offsets())[0])
            for collection in axes.collections
            if collection.get_label() in {camera.label, lidar.label}
        }
        assert marks[camera.label] == pytest.approx((0.0, 0.3))  # (y, x) on the page
        assert marks[lidar.label] == pytest.approx((0.0, 0.0))
    finally:
        plt.close(figure)
