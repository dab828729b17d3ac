"""`scanfuse play BAG`: a recording on DDS at its recorded pace, and what came back.

Each topic is published with the QoS it was recorded with (`scanfuse.ros.playback`), raw
CDR as stored (ROS 1 bags converted), so any type with a Python message package plays.
With `listen`, `play` first waits for those topics' publishers (the node) and for
subscribers on the sensor topics, then counts what arrives on them: rate, and for
LaserScans the latency from publishing the scan with the same stamp.
"""

from __future__ import annotations

import importlib
import signal
import sys
import threading
import time
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import ok

from scanfuse.errors import ScanfuseError
from scanfuse.ros.messages import CAMERA_INFO, IMAGE, LASER_SCAN, POINT_CLOUD
from scanfuse.ros.playback import (
    NANOSECONDS,
    HeardTopic,
    PlaybackReport,
    Recording,
    TopicQos,
    choose_topics,
    read_recording,
    scan_stamp,
)

if TYPE_CHECKING:
    from collections.abc import Callable, Sequence
    from pathlib import Path

# The node's inputs: with `listen`, play waits until something subscribes to these.
SENSOR_TYPES = frozenset({LASER_SCAN, IMAGE, CAMERA_INFO, POINT_CLOUD})
PROGRESS_PERIOD_S = 0.5
# Seconds without a new subscriber on the recording's sensor topics before play starts.
SUBSCRIPTIONS_SETTLE = 1.0


class StopRequest:
    """Ctrl-C as a request that the play loop reads between messages: the first stops the
    playing (and `--loop`) cleanly, with the summary; a second one raises KeyboardInterrupt.

    Raised as KeyboardInterrupt at any point, the first Ctrl-C was lost now and then (one run
    in a few of `make test`): `--loop` played on, its stack in rclpy's wait on the DDS wait
    set. A flag set by the handler cannot be lost."""

    def __init__(self) -> None:
        self.requested = False

    def __call__(self, _signum: int, _frame: object) -> None:
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True


class PlayError(ScanfuseError):
    """The recording cannot be played (no node to listen to, no message package)."""


@dataclass(frozen=True)
class PlayOptions:
    rate: float = 1.0  # playback speed: 2.0 plays twice as fast
    loop: bool = False
    topics: Sequence[str] = ()  # empty: every topic of the bag
    start: float = 0.0  # seconds into the bag
    listen: Sequence[str] = ()  # topics whose messages are counted, e.g. /scan_fused
    wait: float = 30.0  # seconds to wait for the node (publishers of `listen`)
    linger: float = 1.0  # seconds of listening after the last message

    def __post_init__(self) -> None:
        if not self.rate > 0:
            msg = f'--rate must be above 0 (1.0 plays at the recorded pace), not {self.rate}'
            raise PlayError(msg)
        if not self.start >= 0:
            msg = f'--start must be 0 or more seconds into the bag, not {self.start}'
            raise PlayError(msg)


def qos_profile(qos: TopicQos) -> QoSProfile:
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=qos.depth,
        reliability=ReliabilityPolicy.RELIABLE if qos.reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=(
            DurabilityPolicy.TRANSIENT_LOCAL if qos.transient_local else DurabilityPolicy.VOLATILE
        ),
    )


def message_class(msgtype: str) -> Any:
    """The Python class of a ROS 2 type name such as sensor_msgs/msg/LaserScan, or None."""
    package, _, name = msgtype.split('/')
    try:
        return getattr(importlib.import_module(f'{package}.msg'), name, None)
    except ImportError:
        return None


@dataclass
class _Progress:
    """One line on stderr, rewritten in place on a terminal, every PROGRESS_PERIOD_S."""

    duration: float
    rate: float
    enabled: bool = field(default_factory=sys.stderr.isatty)
    shown_at: float = 0.0

    def show(
        self, position: float, sent: int, heard: dict[str, HeardTopic], *, final: bool
    ) -> None:
        now = time.monotonic()
        if not self.enabled or (not final and now - self.shown_at < PROGRESS_PERIOD_S):
            return
        self.shown_at = now
        back = ''.join(f' | {name} {len(topic.received)}' for name, topic in heard.items())
        line = f'\rplaying {position:6.1f}/{self.duration:.1f} s x{self.rate:g}: {sent} sent{back}'
        sys.stderr.write(line + ('\n' if final else ''))
        sys.stderr.flush()


class Player:
    """The recording's publishers and the listeners on one rclpy node."""

    def __init__(
        self,
        recording: Recording,
        options: PlayOptions,
        say: Callable[[str], None],
        stop: StopRequest | None = None,
    ) -> None:
        self.recording = recording
        self.options = options
        self.say = say
        self.stop = stop or StopRequest()
        self.node = rclpy.create_node('scanfuse_play')
        self.report = PlaybackReport(recording.path, options.rate)
        self.publishers: dict[str, Any] = {}
        for name in choose_topics(recording, options.topics):
            topic = recording.topics[name]
            kind = message_class(topic.msgtype)
            if kind is None:
                self.report.skipped[name] = (
                    f'no Python package for {topic.msgtype}; source a ROS 2 install that has it'
                )
                continue
            self.publishers[name] = self.node.create_publisher(kind, name, qos_profile(topic.qos))
            self.report.published[name] = 0
        self.published_at: dict[int, float] = {}  # scan stamp -> monotonic publish time
        for name in options.listen:
            self._listen(name)

    def _listen(self, name: str) -> None:
        heard = self.report.heard[name] = HeardTopic(name)
        recorded = self.recording.topics.get(name)
        msgtype = recorded.msgtype if recorded is not None else LASER_SCAN

        def arrived(raw: bytes) -> None:
            now = time.monotonic()
            heard.received.append(now)
            stamp = scan_stamp(raw, msgtype)
            sent = self.published_at.get(stamp) if stamp is not None else None
            if sent is not None:
                heard.latencies.append(now - sent)

        reliable = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=50)
        self.node.create_subscription(message_class(msgtype), name, arrived, reliable, raw=True)

    def spin_for(self, seconds: float) -> None:
        end = time.monotonic() + seconds
        while (left := end - time.monotonic()) > 0:
            rclpy.spin_once(self.node, timeout_sec=min(left, 0.01))

    def wait_for_node(self) -> None:
        """Publishers of every listened topic, then subscribers on the sensor topics."""
        if not self.options.listen:
            return
        deadline = time.monotonic() + self.options.wait
        missing = list(self.options.listen)
        while missing := [name for name in missing if self.node.count_publishers(name) == 0]:
            if self.stop.requested:
                return
            if time.monotonic() > deadline:
                msg = (
                    f'nothing publishes {", ".join(missing)} after {self.options.wait:g} s; '
                    'start the node first (scanfuse node) in the same ROS_DOMAIN_ID, or play '
                    'without --listen'
                )
                raise PlayError(msg)
            self.spin_for(0.05)
        sensors = [
            name for name in self.publishers if self.recording.topics[name].msgtype in SENSOR_TYPES
        ]
        # A recording holds sensor topics the node does not fuse (a simulator's ground truth,
        # a second camera): once some are heard, the rest get SUBSCRIPTIONS_SETTLE seconds.
        heard: set[str] = set()
        settled = deadline
        while time.monotonic() < min(deadline, settled) and len(heard) < len(sensors):
            if self.stop.requested:
                return
            self.spin_for(0.05)
            now = {n for n in sensors if self.publishers[n].get_subscription_count() > 0}
            if now != heard:
                heard, settled = now, time.monotonic() + SUBSCRIPTIONS_SETTLE
        unheard = [name for name in sensors if name not in heard]
        if unheard:
            self.say(
                f'nothing subscribes to {", ".join(unheard)}: the node listens to other topics '
                '(its *_topic parameters or remaps)'
            )

    def play_once(self, progress: _Progress) -> None:
        options = self.options
        first = time.monotonic()
        messages = self.recording.messages(list(self.publishers), options.start)
        for sent, message in enumerate(messages):
            due = first + message.offset_ns / NANOSECONDS / options.rate
            while (delay := due - time.monotonic()) > 0 and not self.stop.requested:
                rclpy.spin_once(self.node, timeout_sec=min(delay, 0.01))
                progress.show(message.offset_ns / NANOSECONDS, sent, self.report.heard, final=False)
            if self.stop.requested:
                return
            msgtype = self.recording.topics[message.topic].msgtype
            if msgtype == LASER_SCAN and (stamp := scan_stamp(message.cdr, msgtype)) is not None:
                self.published_at[stamp] = time.monotonic()
            self.publishers[message.topic].publish(message.cdr)
            self.report.published[message.topic] += 1
        self.report.loops += 1

    def run(self) -> PlaybackReport:
        self.wait_for_node()
        progress = _Progress(self.recording.duration - self.options.start, self.options.rate)
        stopped = self.stop.requested
        try:
            if not stopped:
                self.play_once(progress)
            while self.options.loop and not self.stop.requested:
                self.play_once(progress)
            stopped = self.stop.requested
        except (KeyboardInterrupt, ExternalShutdownException):
            stopped = True
        if stopped:
            self.say('stopped')
        if ok():
            # Let the node answer the last messages, and best-effort samples leave.
            self.spin_for(self.options.linger)
        sent = sum(self.report.published.values())
        progress.show(self.recording.duration, sent, self.report.heard, final=True)
        return self.report

    def close(self) -> None:
        self.node.destroy_node()


def play_bag(bag: Path, options: PlayOptions, say: Callable[[str], None]) -> PlaybackReport:
    """Publish `bag` on DDS as recorded; what was published and heard back."""
    recording = read_recording(bag)
    # Not rclpy's handlers (they may end the process before the summary prints): Ctrl-C is a
    # `StopRequest`, which ends a --loop cleanly with the summary.
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    stop = StopRequest()
    # Signal handlers can only be set from the main thread (a caller's worker thread keeps
    # Python's: Ctrl-C as KeyboardInterrupt).
    main = threading.current_thread() is threading.main_thread()
    previous = signal.signal(signal.SIGINT, stop) if main else None
    try:
        player = Player(recording, options, say, stop)
        try:
            say(
                f'playing {bag} ({recording.duration:.1f} s, {len(player.publishers)} topics) '
                f'at x{options.rate:g}' + (', looping until Ctrl-C' if options.loop else '')
            )
            return player.run()
        finally:
            player.close()
    finally:
        if main:
            signal.signal(signal.SIGINT, previous)
        if ok():
            rclpy.shutdown()
