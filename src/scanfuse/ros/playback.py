"""What `scanfuse play` plays and what it reports, without ROS: the bag's messages in order,
each topic's recorded QoS, and the summary of what came back.

`scanfuse.ros.play` puts this on DDS with rclpy.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from rosbags.interfaces import Connection, ConnectionExtRosbag2, QosDurability, QosReliability

from scanfuse.errors import BagError
from scanfuse.ros.bag import CdrConverter, fresh_store, header_stamp_ns, open_bag

if TYPE_CHECKING:
    from collections.abc import Iterator, Sequence
    from pathlib import Path

NANOSECONDS = 1_000_000_000
# ros2 bag's convention for a topic recorded without QoS: reliable, volatile, 10 deep; the
# static transforms are latched (transient local, 1 deep) whatever was recorded, as tf2 needs.
DEFAULT_DEPTH = 10
STATIC_TF = '/tf_static'


@dataclass(frozen=True)
class TopicQos:
    """The QoS a topic is published with: as recorded where the bag says."""

    reliable: bool = True
    transient_local: bool = False
    depth: int = DEFAULT_DEPTH

    def describe(self) -> str:
        reliability = 'reliable' if self.reliable else 'best effort'
        durability = 'transient local' if self.transient_local else 'volatile'
        return f'{reliability}, {durability}, depth {self.depth}'


def recorded_qos(topic: str, connections: Sequence[Connection]) -> TopicQos:
    """The QoS of `topic`: what its publishers offered when recorded (ROS 2 bags keep it).

    Several publishers: best effort if any offered it (a reliable publisher would miss
    best-effort subscribers' expectations nowhere, but would claim a guarantee the recording
    never had), transient local only if all offered it.
    """
    profiles = [
        profile
        for connection in connections
        if isinstance(connection.ext, ConnectionExtRosbag2)
        for profile in connection.ext.offered_qos_profiles
    ]
    if topic == STATIC_TF:
        return TopicQos(reliable=True, transient_local=True, depth=1)
    if not profiles:
        return TopicQos()
    reliable = all(p.reliability != QosReliability.BEST_EFFORT for p in profiles)
    latched = all(p.durability == QosDurability.TRANSIENT_LOCAL for p in profiles)
    depth = max((p.depth for p in profiles), default=0) or DEFAULT_DEPTH
    return TopicQos(reliable=reliable, transient_local=latched, depth=depth)


@dataclass(frozen=True)
class RecordedTopic:
    name: str
    msgtype: str  # ROS 2 name
    count: int
    qos: TopicQos


@dataclass(frozen=True)
class PlayedMessage:
    topic: str
    offset_ns: int  # log time after the first played message
    cdr: bytes


@dataclass(frozen=True)
class Recording:
    """A bag as `play` sees it: its topics (ROS 2 names and QoS) and its time span."""

    path: Path
    topics: dict[str, RecordedTopic]
    start_ns: int
    end_ns: int

    @property
    def duration(self) -> float:
        return (self.end_ns - self.start_ns) / NANOSECONDS

    def messages(self, topics: Sequence[str], start: float = 0.0) -> Iterator[PlayedMessage]:
        """`topics`' messages in log-time order from `start` s into the bag, as ROS 2 CDR.

        Latched topics' messages logged before `start` come first (at offset 0), so a
        late start still has the static transforms.
        """
        begin = self.start_ns + round(start * NANOSECONDS)
        with open_bag(self.path) as reader:
            converter = CdrConverter(reader, reader.typestore if reader.is2 else fresh_store())
            chosen = [c for c in reader.connections if c.topic in set(topics)]
            if not chosen:
                return
            held: list[PlayedMessage] = []
            started = False
            for connection, log_time, raw in reader.messages(connections=chosen):
                cdr = converter.to_cdr(connection, bytes(raw))
                if log_time < begin:
                    if self.topics[connection.topic].qos.transient_local:
                        held.append(PlayedMessage(connection.topic, 0, cdr))
                    continue
                if not started:
                    yield from held
                    started = True
                yield PlayedMessage(connection.topic, log_time - begin, cdr)
            if not started:
                yield from held


def read_recording(path: Path) -> Recording:
    """The topics of the bag at `path` (a ROS 2 folder, .mcap, .db3, or a ROS 1 .bag)."""
    if not path.exists():
        msg = f'bag {path} does not exist'
        raise BagError(msg)
    with open_bag(path) as reader:
        converter = CdrConverter(reader, fresh_store())
        by_topic: dict[str, list[Connection]] = {}
        for connection in reader.connections:
            by_topic.setdefault(connection.topic, []).append(connection)
        topics = {
            name: RecordedTopic(
                name=name,
                msgtype=converter.msgtype(connections[0]),
                count=sum(c.msgcount for c in connections),
                qos=recorded_qos(name, connections),
            )
            for name, connections in sorted(by_topic.items())
        }
        if reader.message_count == 0:
            msg = f'bag {path} holds no messages; nothing to play'
            raise BagError(msg)
        return Recording(path, topics, reader.start_time, reader.end_time)


def choose_topics(recording: Recording, wanted: Sequence[str]) -> list[str]:
    """The topics to play: `wanted` (all when empty); a name the bag lacks is an error."""
    if not wanted:
        return list(recording.topics)
    missing = [name for name in wanted if name not in recording.topics]
    if missing:
        known = ', '.join(recording.topics) or 'none'
        msg = f'{", ".join(missing)} not in bag {recording.path}; its topics: {known}'
        raise BagError(msg)
    return list(dict.fromkeys(wanted))


@dataclass
class HeardTopic:
    """What arrived on one listened topic."""

    name: str
    received: list[float] = field(default_factory=list)  # monotonic receive times, s
    latencies: list[float] = field(default_factory=list)  # s, from the matching scan's publish

    def rate(self) -> float:
        if len(self.received) < 2:
            return math.nan
        return (len(self.received) - 1) / (self.received[-1] - self.received[0])

    def latency(self, share: float) -> float:
        if not self.latencies:
            return math.nan
        ordered = sorted(self.latencies)
        return ordered[min(len(ordered) - 1, round(share * (len(ordered) - 1)))]


@dataclass
class PlaybackReport:
    """What `play` published and, with listening, what the node published back."""

    bag: Path
    rate: float
    loops: int = 0
    published: dict[str, int] = field(default_factory=dict)
    heard: dict[str, HeardTopic] = field(default_factory=dict)
    skipped: dict[str, str] = field(default_factory=dict)  # topic -> why it was not played

    def lines(self) -> list[str]:
        total = sum(self.published.values())
        loops = f', {self.loops} loops' if self.loops > 1 else ''
        out = [f'published {total} messages of {self.bag} at x{self.rate:g}{loops}:']
        width = max((len(name) for name in [*self.published, *self.heard]), default=0)
        out += [f'  {name:<{width}}  {count:>6} messages' for name, count in self.published.items()]
        out += [f'  {name:<{width}}  not played: {why}' for name, why in self.skipped.items()]
        if self.heard:
            out.append('heard back:')
        for name, heard in self.heard.items():
            line = f'  {name:<{width}}  {len(heard.received):>6} messages'
            if heard.received:
                line += f', {heard.rate():.1f} Hz'
            if heard.latencies:
                line += (
                    f', latency median {heard.latency(0.5) * 1e3:.1f} ms, '
                    f'p95 {heard.latency(0.95) * 1e3:.1f} ms'
                )
            out.append(line)
        return out


def scan_stamp(raw: bytes, msgtype: str) -> int | None:
    """The header stamp of a message that has a header (the key that pairs a played scan
    with the fused scan the node publishes for it)."""
    return header_stamp_ns(raw, msgtype)
