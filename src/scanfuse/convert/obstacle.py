"""Height-filtered full-frame obstacle scan. STUB: being implemented."""

from __future__ import annotations

from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import numpy as np
    import numpy.typing as npt

    from scanfuse.camera import CameraModel
    from scanfuse.scan import AngleGrid, Scan
    from scanfuse.transforms import Extrinsics


class ObstacleProjector:
    def __init__(
        self,
        camera: CameraModel,
        extrinsics: Extrinsics,
        lidar_grid: AngleGrid,
        *,
        min_obstacle_height: float,
        max_obstacle_height: float,
        range_min: float,
        range_max: float,
    ) -> None:
        raise NotImplementedError

    def scan(self, depth: npt.NDArray[np.generic]) -> Scan:
        raise NotImplementedError
