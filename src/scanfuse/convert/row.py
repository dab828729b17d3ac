"""Algorithm 1 (depth row to scan). STUB: being implemented."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from scanfuse.camera import CameraModel
    from scanfuse.convert.floor import FloorGuard
    from scanfuse.scan import Scan


def row_scan(
    depth: npt.NDArray[np.generic],
    camera: CameraModel,
    *,
    scan_row: int | None = None,
    scan_height: int = 1,
    range_min: float,
    range_max: float,
    d2l_compat: bool = False,
    floor_guard: FloorGuard | None = None,
) -> Scan:
    raise NotImplementedError
