"""A small TF tree for offline use: sensor mounting poses from /tf_static (and /tf).

tf2 stores, for every frame, the pose of that frame in its one parent; any two
frames of one tree are related through their closest common ancestor. Mounting
poses of sensors are fixed, so this store keeps one transform per child frame:
/tf_static wins over /tf, and from /tf the first transform of a frame is kept.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from scanfuse.errors import TransformError
from scanfuse.ros.messages import StampedTransform, frame_name

if TYPE_CHECKING:
    from collections.abc import Iterable

    import numpy.typing as npt

    Matrix = npt.NDArray[np.float64]


def quaternion_matrix(rotation: tuple[float, float, float, float]) -> Matrix:
    """3x3 rotation matrix of a unit quaternion (x, y, z, w)."""
    x, y, z, w = rotation
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ],
        dtype=np.float64,
    )


def transform_matrix(
    translation: tuple[float, float, float], rotation: tuple[float, float, float, float]
) -> Matrix:
    """4x4 homogeneous matrix mapping child coordinates to parent coordinates."""
    matrix = np.eye(4, dtype=np.float64)
    matrix[:3, :3] = quaternion_matrix(rotation)
    matrix[:3, 3] = translation
    return matrix


class TransformStore:
    """Mounting poses of frames, looked up along the tree like tf2's `lookupTransform`."""

    def __init__(self) -> None:
        self._parent: dict[str, str] = {}
        self._pose_in_parent: dict[str, Matrix] = {}
        self._static: set[str] = set()

    def add(self, transform: StampedTransform, *, static: bool) -> None:
        """Record the pose of `transform.child` in `transform.parent`."""
        child = frame_name(transform.child)
        parent = frame_name(transform.parent)
        if child == parent:
            msg = f'transform from frame {child!r} to itself; a frame cannot be its own parent'
            raise TransformError(msg)
        if not static and child in self._parent:
            return
        if static:
            self._static.add(child)
        self._parent[child] = parent
        self._pose_in_parent[child] = transform_matrix(transform.translation, transform.rotation)

    def add_all(self, transforms: Iterable[StampedTransform], *, static: bool) -> None:
        for transform in transforms:
            self.add(transform, static=static)

    @property
    def frames(self) -> list[str]:
        """Every frame named in the store, sorted."""
        return sorted(set(self._parent) | set(self._parent.values()))

    def _chain_to_root(self, frame: str) -> list[str]:
        chain = [frame]
        while chain[-1] in self._parent:
            parent = self._parent[chain[-1]]
            if parent in chain:
                msg = f'the TF tree has a loop through {parent!r}: {" -> ".join(chain)}'
                raise TransformError(msg)
            chain.append(parent)
        return chain

    def _pose_in_ancestor(self, frame: str, ancestor: str) -> Matrix:
        pose = np.eye(4, dtype=np.float64)
        while frame != ancestor:
            pose = self._pose_in_parent[frame] @ pose
            frame = self._parent[frame]
        return pose

    def can_transform(self, target: str, source: str) -> bool:
        try:
            self.lookup(target, source)
        except TransformError:
            return False
        return True

    def lookup(self, target: str, source: str) -> Matrix:
        """4x4 pose of frame `source` in frame `target` (maps source points to target points)."""
        target, source = frame_name(target), frame_name(source)
        if target == source:
            return np.eye(4, dtype=np.float64)
        known = self.frames
        for frame in (target, source):
            if frame not in known:
                listed = ', '.join(known) or 'none'
                msg = (
                    f'frame {frame!r} is not in the TF tree (known frames: {listed}); '
                    'publish its transform on /tf_static or give the mounting in the parameters'
                )
                raise TransformError(msg)
        target_chain = self._chain_to_root(target)
        source_chain = self._chain_to_root(source)
        common = next((frame for frame in source_chain if frame in target_chain), None)
        if common is None:
            msg = (
                f'no TF chain from {target!r} to {source!r}: they are in separate trees '
                f'(rooted at {target_chain[-1]!r} and {source_chain[-1]!r}; known frames: '
                f'{", ".join(known)})'
            )
            raise TransformError(msg)
        target_in_common = self._pose_in_ancestor(target, common)
        source_in_common = self._pose_in_ancestor(source, common)
        return np.linalg.inv(target_in_common) @ source_in_common
