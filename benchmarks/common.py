"""Timing helpers shared by the benchmark sections: medians over repeated runs."""

from __future__ import annotations

import statistics
import time
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Callable


@dataclass(frozen=True)
class Row:
    """One line of the benchmark table."""

    section: str
    name: str
    median_s: float  # seconds, or a share of one core when `unit` is 'share'
    note: str = ''
    unit: str = 's'


def median_seconds(fn: Callable[[], object], *, repeat: int = 31, min_time: float = 0.02) -> float:
    """Median wall time of one call of `fn`, over `repeat` batches of enough calls each."""
    fn()  # warm caches (ray tables, plans, compiled kernels)
    number = 1
    while True:
        start = time.perf_counter()
        for _ in range(number):
            fn()
        elapsed = time.perf_counter() - start
        if elapsed >= min_time or number >= 1 << 16:
            break
        number *= 2
    samples = []
    for _ in range(repeat):
        start = time.perf_counter()
        for _ in range(number):
            fn()
        samples.append((time.perf_counter() - start) / number)
    return statistics.median(samples)
