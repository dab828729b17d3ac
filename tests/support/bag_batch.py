"""A folder of bags for the batch tests: two small scene bags (one mcap, one sqlite3 folder)
written with rosbags, and one malformed .mcap; and how to read a bag's messages back."""

from __future__ import annotations

from typing import TYPE_CHECKING

from rosbags.highlevel import AnyReader

from tests.support.synthetic import Scene, write_scene_bag

if TYPE_CHECKING:
    from pathlib import Path


def bag_folder(folder: Path) -> tuple[Path, Path, Path]:
    """`folder` with good (an mcap bag folder), other (a sqlite3 bag folder) and broken.mcap
    (not a bag)."""
    folder.mkdir()
    good = write_scene_bag(folder / 'good', Scene(duration=1.0))
    other = write_scene_bag(folder / 'other', Scene(duration=1.0, box_x=0.9), storage='sqlite3')
    broken = folder / 'broken.mcap'
    broken.write_bytes(b'\x89MCAP0\r\n' + b'not a bag at all' * 8)
    return good, other, broken


def messages(path: Path) -> list[tuple[str, str, int, bytes]]:
    with AnyReader([path]) as reader:
        return [(c.topic, c.msgtype, t, bytes(raw)) for c, t, raw in reader.messages()]
