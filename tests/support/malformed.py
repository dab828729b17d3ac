"""Malformed messages the node must count and survive (no rclpy needed to make them)."""

from __future__ import annotations

from typing import Any

import numpy as np

from scanfuse.ros.messages import IMAGE, depth_to_cdr, typestore


def garbage_messages() -> list[tuple[str, bytes]]:
    """Malformed depth images: truncated CDR, and a valid Image with the wrong encoding."""
    store = typestore()
    good = depth_to_cdr(np.zeros((4, 4), dtype=np.uint16), frame_id='cam', stamp_ns=1, store=store)
    wrong: Any = store.deserialize_cdr(good, IMAGE)
    wrong.encoding = 'rgb8'
    return [
        ('truncated', good[: len(good) // 2]),
        ('rgb8', bytes(store.serialize_cdr(wrong, IMAGE))),
    ]
