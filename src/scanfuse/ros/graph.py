"""The node's view of what it was given and of the ROS graph, in plain Python (no rclpy):
the `-p` names on its command line, and the topics that could stand in for an input
nothing publishes."""

from __future__ import annotations

import difflib
from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from collections.abc import Iterable, Sequence

PARAM_FLAGS = frozenset({'-p', '--param'})


def override_names(argv: Sequence[str], node_name: str) -> list[str]:
    """Parameter names given with `-p [node:]name:=value` after `--ros-args` (rcl's syntax),
    for this node: names prefixed with another node's name are that node's business."""
    names: list[str] = []
    inside = False
    items = iter(argv)
    for arg in items:
        if arg == '--ros-args':
            inside = True
        elif arg == '--':
            inside = False
        elif inside and arg in PARAM_FLAGS:
            item = next(items, '')
            name, assigned, _ = item.partition(':=')
            if not assigned:
                continue  # rcl refuses it with its own message
            node, _, bare = name.rpartition(':')
            if node in {'', node_name, f'/{node_name}', '*', '/**'}:
                names.append(bare)
    return names


def nearest(name: str, known: Iterable[str]) -> str | None:
    matches = difflib.get_close_matches(name, list(known), n=1, cutoff=0.6)
    return matches[0] if matches else None


def unknown_names_message(unknown: Sequence[str], known: Iterable[str], where: str) -> str:
    """`min_obstacle_heigth (did you mean min_obstacle_height?)`, for each unknown name."""
    known = list(known)
    parts = []
    for name in unknown:
        guess = nearest(name, known)
        parts.append(f'{name} (did you mean {guess}?)' if guess else name)
    return (
        f'unknown parameter{"s" if len(unknown) > 1 else ""} {where}: {", ".join(parts)}; '
        '`scanfuse params` lists every parameter'
    )


@dataclass(frozen=True)
class SilentInput:
    """A topic the node subscribes to that nothing publishes, and what could stand in."""

    topic: str
    msgtype: str  # e.g. sensor_msgs/msg/Image
    parameter: str  # the parameter that names the topic, e.g. depth_topic
    published: tuple[str, ...]  # topics of that type that something publishes

    def describe(self) -> str:
        kind = self.msgtype.rsplit('/', 1)[-1]
        if self.published:
            others = f'{kind} topics published now: {", ".join(self.published)}'
            fix = f'set {self.parameter} or remap'
        else:
            others = f'no {kind} topic is published at all'
            fix = 'is the driver running, in this ROS_DOMAIN_ID?'
        return f'nothing publishes {self.topic} ({self.parameter}); {others}: {fix}'


def silent_inputs(
    inputs: dict[str, tuple[str, str]],
    publishers: dict[str, int],
    graph: Sequence[tuple[str, Sequence[str]]],
) -> list[SilentInput]:
    """`inputs` (topic -> (type, parameter)) that have no publisher, with the topics of the
    same type in `graph` (rclpy's get_topic_names_and_types) that have one (`publishers`:
    topic -> publisher count)."""
    silent = []
    for topic, (msgtype, parameter) in inputs.items():
        if publishers.get(topic, 0) > 0:
            continue
        alike = tuple(
            sorted(
                name
                for name, types in graph
                if msgtype in types and name != topic and publishers.get(name, 0) > 0
            )
        )
        silent.append(SilentInput(topic, msgtype, parameter, alike))
    return silent
