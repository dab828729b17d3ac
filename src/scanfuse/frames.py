"""A small TF tree: sensor mounting poses from /tf_static and /tf, looked up like tf2.

tf2 stores, for every frame, the pose of that frame in its one parent; any two frames of
one tree are related through their closest common ancestor. Mounting poses are fixed, so
one pose per child frame is kept: the latest one received (a `/tf_static` pose is not
replaced by a `/tf` one). `add` says whether a pose changed, so that a cache of extrinsics
is cleared only when a transform it was built from changes, not at every odometry sample.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from scanfuse.errors import TransformError
from scanfuse.transforms import Transform

if TYPE_CHECKING:
    from collections.abc import Iterable

    import numpy.typing as npt

    Matrix = npt.NDArray[np.float64]


def frame_name(frame_id: str) -> str:
    """A TF frame id without the leading slash ROS 1 allowed ('/laser' is 'laser' in tf2)."""
    return frame_id.lstrip('/')


@dataclass(frozen=True)
class StampedTransform:
    """One `geometry_msgs/TransformStamped`: the pose of `child` in `parent`.

    `rotation` is the unit quaternion (x, y, z, w), `translation` metres.
    """

    parent: str
    child: str
    translation: tuple[float, float, float]
    rotation: tuple[float, float, float, float]
    stamp_ns: int = 0

    def matrix(self) -> Matrix:
        """4x4 homogeneous matrix mapping child coordinates to parent coordinates."""
        return Transform.from_quaternion(self.rotation, self.translation).matrix


class TransformStore:
    """Mounting poses of frames, looked up along the tree like tf2's `lookupTransform`."""

    def __init__(self) -> None:
        self._parent: dict[str, str] = {}
        self._pose_in_parent: dict[str, Matrix] = {}
        self._static: set[str] = set()

    def __len__(self) -> int:
        return len(self._parent)

    def add(self, transform: StampedTransform, *, static: bool) -> bool:
        """Record the pose of `transform.child` in `transform.parent`; True when it changed."""
        child = frame_name(transform.child)
        parent = frame_name(transform.parent)
        if child == parent:
            msg = f'transform from frame {child!r} to itself; a frame cannot be its own parent'
            raise TransformError(msg)
        if not static and child in self._static:
            return False
        if self._parent.get(child) != parent and child in self._ancestors(parent):
            msg = (
                f'transform {parent!r} -> {child!r} would close a loop in the TF tree '
                f'({child!r} is already an ancestor of {parent!r}); a frame has one parent'
            )
            raise TransformError(msg)
        pose = transform.matrix()
        if self._parent.get(child) == parent and np.array_equal(self._pose_in_parent[child], pose):
            return False
        if static:
            self._static.add(child)
        self._parent[child] = parent
        self._pose_in_parent[child] = pose
        return True

    def add_all(self, transforms: Iterable[StampedTransform], *, static: bool) -> set[str]:
        """Record every transform; the child frames whose pose changed.

        A bad transform (a loop, a frame its own parent) raises TransformError after the
        good ones before it were kept.
        """
        return {t.child for t in transforms if self.add(t, static=static)}

    @property
    def frames(self) -> list[str]:
        """Every frame named in the store, sorted."""
        return sorted(set(self._parent) | set(self._parent.values()))

    def roots(self) -> list[str]:
        """Frames with no parent: the roots of the trees in the store, sorted."""
        return sorted(set(self._parent.values()) - set(self._parent))

    def root_of(self, frame: str) -> str:
        return self._chain_to_root(frame_name(frame))[-1]

    def chain(self, target: str, source: str) -> set[str]:
        """The child frames whose poses `lookup(target, source)` uses."""
        target_chain = self._chain_to_root(frame_name(target))
        source_chain = self._chain_to_root(frame_name(source))
        common = next((frame for frame in source_chain if frame in target_chain), None)
        if common is None:
            return set(target_chain) | set(source_chain)
        upto = (
            target_chain[: target_chain.index(common)] + source_chain[: source_chain.index(common)]
        )
        return set(upto)

    def _ancestors(self, frame: str) -> set[str]:
        seen = {frame}
        while frame in self._parent and self._parent[frame] not in seen:
            frame = self._parent[frame]
            seen.add(frame)
        return seen

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
