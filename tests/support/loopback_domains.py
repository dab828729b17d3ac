"""DDS domains for the play and node-graph tests, apart from tests/ros/test_node_dds.py's
(120-219): each xdist worker has its own 30, so two tests never share a domain (a node there
would hear the other test's messages)."""

from __future__ import annotations

import itertools
import os

FIRST, PER_WORKER = 10, 30
_counter = itertools.count()


def domain_id() -> int:
    worker = os.environ.get('PYTEST_XDIST_WORKER', 'gw0').removeprefix('gw')
    index = int(worker) if worker.isdigit() else 0
    return FIRST + index * PER_WORKER + next(_counter) % PER_WORKER
