"""Live view of the node in the Foxglove app: its CDR messages forwarded over foxglove-sdk.

`scanfuse node --foxglove [PORT]` serves the LiDAR scan, the depth image, the
fused (and depth) scan and the transforms on a Foxglove WebSocket server
(loopback by default). Messages go out as the CDR bytes the node already has,
with `ros2msg` schemas from the rosbags typestore, so nothing is converted.
Without --foxglove a do-nothing view stands in, so the node never branches on it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

from scanfuse.errors import ConfigError
from scanfuse.ros.messages import IMAGE, LASER_SCAN, TF_MESSAGE, typestore

if TYPE_CHECKING:
    from scanfuse.config import FusionConfig
    from scanfuse.ros.messages import RawMessage

DEFAULT_PORT = 8765
DEFAULT_HOST = '127.0.0.1'


class LiveView(Protocol):
    """Where the node shows what it receives and publishes."""

    def log(self, topic: str, raw: RawMessage) -> None: ...

    def close(self) -> None: ...


class NullView:
    """The view when none was asked for."""

    def log(self, topic: str, raw: RawMessage) -> None:
        pass

    def close(self) -> None:
        pass


def view_topics(config: FusionConfig) -> dict[str, str]:
    """Topic -> message type of what the live view shows."""
    topics = {
        config.scan_topic: LASER_SCAN,
        config.fused_topic: LASER_SCAN,
        config.depth_topic: IMAGE,
        '/tf': TF_MESSAGE,
        '/tf_static': TF_MESSAGE,
    }
    if config.publish_depth_scan:
        topics[config.depth_scan_topic] = LASER_SCAN
    return topics


class FoxgloveView:
    """A foxglove-sdk WebSocket server with one CDR channel per topic."""

    def __init__(self, topics: dict[str, str], *, host: str = DEFAULT_HOST, port: int) -> None:
        try:
            import foxglove  # noqa: PLC0415 - optional: only with --foxglove
        except ImportError as err:
            msg = "--foxglove needs the foxglove-sdk package: pip install 'scanfuse[foxglove]'"
            raise ConfigError(msg) from err
        self.host = host
        store = typestore()
        try:
            self.server = foxglove.start_server(name='scanfuse', host=host, port=port)
        except Exception as err:  # the SDK raises its own error types for bind failures
            msg = f'cannot serve Foxglove on {host}:{port}: {err}; choose another --foxglove port'
            raise ConfigError(msg) from err
        self.channels: dict[str, Any] = {}
        for topic, msgtype in topics.items():
            definition, _ = store.generate_msgdef(msgtype, ros_version=2)
            schema = foxglove.Schema(
                name=msgtype, encoding='ros2msg', data=definition.encode('utf-8')
            )
            self.channels[topic] = foxglove.Channel(topic, schema=schema, message_encoding='cdr')

    @property
    def url(self) -> str:
        return f'ws://{self.host}:{self.server.port}'

    def log(self, topic: str, raw: RawMessage) -> None:
        channel = self.channels.get(topic)
        if channel is not None:
            channel.log(bytes(raw))

    def close(self) -> None:
        for channel in self.channels.values():
            channel.close()
        self.server.stop()


def make_view(
    config: FusionConfig, port: int | None, host: str = DEFAULT_HOST
) -> FoxgloveView | NullView:
    """A Foxglove view on `host`:`port` (0: any free port), or the do-nothing view for None."""
    if port is None:
        return NullView()
    return FoxgloveView(view_topics(config), host=host, port=port)
