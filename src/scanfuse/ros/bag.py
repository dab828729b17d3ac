"""Offline fusion of recorded bags: every input message kept, /scan_fused and /scan_depth added.

`fuse_bag` reads a ROS 2 bag (sqlite3 or MCAP, directory or single file) or a
ROS 1 bag with rosbags' `AnyReader` and writes a ROS 2 bag (format version 8,
readable by Humble's `ros2 bag`) that holds every input message unchanged (ROS 1
messages converted to CDR) plus the fused scan and the depth scan of each LiDAR
scan, stamped (header and log time) like that LiDAR scan. The fusion itself is
`FusionPipeline.fuse`; this module only moves messages.

Steps: check paths -> open -> choose topics -> read TF and the first CameraInfo
(extrinsics, camera) -> one pass in log-time order (copy every message, pair
scans with depth frames in a short window, fuse, write) -> rename into place.
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import sqlite3
import struct
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from enum import Enum
from functools import partial
from pathlib import Path
from typing import TYPE_CHECKING, Any

import apsw
import numpy as np
import yaml
from rosbags.convert.converter import (
    LATCH,
    STATIC_MSGTYPE_RENAMES,
    is_same_wireformat,
    migrate_bytes,
)
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import ConnectionExtRosbag2, MessageDefinitionFormat
from rosbags.rosbag1 import ReaderError as Ros1ReaderError
from rosbags.rosbag2 import ReaderError as Ros2ReaderError
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, TypesysError, get_types_from_msg, get_typestore

from scanfuse.camera import CameraModel
from scanfuse.config import FusionConfig
from scanfuse.errors import BagError, MessageError, ScanfuseError, TransformError
from scanfuse.frames import frame_name
from scanfuse.progress import NullProgress, Progress
from scanfuse.ros.messages import (
    CAMERA_INFO,
    IMAGE,
    IMU,
    LASER_SCAN,
    ODOMETRY,
    POINT_CLOUD,
    TF_MESSAGE,
    Distro,
    camera_from_msg,
    check_depth_matches_camera,
    cloud_from_msg,
    depth_from_msg,
    deserialize,
    imu_from_msg,
    is_depth_encoding,
    odometry_from_msg,
    scan_from_msg,
    scan_to_cdr,
    transforms_from_msg,
)
from scanfuse.ros.staging import STAGING_OVERHEAD, Staging, output_error
from scanfuse.stream import FusionStream
from scanfuse.tables import TextTable

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator

    from rosbags.interfaces import Connection
    from rosbags.typesys.store import Typestore

    from scanfuse.stream import StreamOutput

logger = logging.getLogger(__name__)

TF_STATIC_TOPIC = '/tf_static'
TF_TOPIC = '/tf'
# How much later than its stamp order a depth frame may be logged and still be paired.
REORDER_S = 0.5
# Every error a damaged or unreadable bag can raise inside rosbags and its storage back ends.
_READ_ERRORS = (
    AnyReaderError,
    Ros1ReaderError,
    Ros2ReaderError,
    SerdeError,
    TypesysError,
    apsw.Error,  # rosbags reads sqlite3 bags with apsw (a corrupt page: apsw.CorruptError)
    sqlite3.Error,
    struct.error,
    EOFError,
    KeyError,
    ValueError,
)
_DISTRO_STORES = {Distro.HUMBLE: Stores.ROS2_HUMBLE, Distro.JAZZY: Stores.ROS2_JAZZY}


class Storage(str, Enum):
    """Storage plugin of the output bag."""

    MCAP = 'mcap'
    SQLITE3 = 'sqlite3'


_PLUGINS = {Storage.MCAP: StoragePlugin.MCAP, Storage.SQLITE3: StoragePlugin.SQLITE3}


# The simulator's ground truth beside a sensor (/scan_truth beside /scan, /ground_truth/...):
# evaluation data a recording carries, never a sensor to fuse.
def is_ground_truth(topic: str) -> bool:
    return topic.endswith('_truth') or topic.startswith('/ground_truth/')


@dataclass(frozen=True)
class Intrinsics:
    """A pinhole depth camera's focal lengths and principal point, pixels (CameraInfo's K)."""

    fx: float
    fy: float
    cx: float
    cy: float

    def describe(self) -> str:
        return f'fx {self.fx:g}, fy {self.fy:g}, cx {self.cx:g}, cy {self.cy:g}'


GIVEN_INTRINSICS = '(intrinsics given)'


@dataclass(frozen=True)
class TopicChoice:
    """The input topics fused: the primary three, the other named sources, and what else the
    bag holds that could have been a source."""

    scan: str
    depth: str
    camera_info: str
    sources: tuple[tuple[str, str, str], ...] = ()  # (topic, source name, message type)
    unused: tuple[tuple[str, str], ...] = ()  # (topic, type) of sensors nobody named
    imu: str = ''  # the sensor_msgs/Imu topic giving the base's tilt ('' none)

    def source_of(self, topic: str) -> tuple[str, str] | None:
        """(source name, type) of an extra source's topic."""
        return next(((name, kind) for t, name, kind in self.sources if t == topic), None)


@dataclass(frozen=True)
class BagReport:
    """What `fuse_bag` read, wrote and how fast it fused."""

    input: Path
    output: Path
    storage: Storage
    topics: TopicChoice
    extrinsics_source: str
    messages_read: int
    messages_written: int
    scans: int
    scans_paired: int
    scans_passed_through: int
    depth_frames: int
    peak_depth_frames: int
    bag_duration_s: float
    wall_time_s: float
    scan_times_s: tuple[float, ...] = field(repr=False)
    scans_compensated: int = 0
    malformed: tuple[MalformedMessage, ...] = ()

    @property
    def median_scan_time_s(self) -> float:
        return float(np.median(self.scan_times_s)) if self.scan_times_s else math.nan

    @property
    def p99_scan_time_s(self) -> float:
        return float(np.percentile(self.scan_times_s, 99)) if self.scan_times_s else math.nan

    @property
    def real_time_factor(self) -> float:
        """Seconds of recording processed per second of wall time."""
        return self.bag_duration_s / self.wall_time_s if self.wall_time_s > 0 else math.inf

    def table(self) -> TextTable:
        table = TextTable(title=f'scanfuse bag: {self.output}', show_header=False)
        table.add_column('what')
        table.add_column('value', justify='right', overflow='fold')
        rows = [
            ('input', str(self.input)),
            ('topics', self._topics()),
            *(
                (f'  source {name}', f'{topic} ({kind.rsplit("/", 1)[-1]})')
                for topic, name, kind in self.topics.sources
            ),
            *(
                ('  not fused', f'{topic} ({kind.rsplit("/", 1)[-1]}): name it to fuse it')
                for topic, kind in self.topics.unused
            ),
            ('extrinsics from', self.extrinsics_source),
            ('messages read', str(self.messages_read)),
            ('messages written', str(self.messages_written)),
            ('scans paired with depth', str(self.scans_paired)),
            ('scans passed through (no depth)', str(self.scans_passed_through)),
            (
                'scans motion-compensated',
                f'{self.scans_compensated}' + ('' if self.scans_compensated else ' (no odometry)'),
            ),
            ('malformed messages skipped', str(len(self.malformed))),
            ('depth frames', str(self.depth_frames)),
            ('median time per scan', f'{self.median_scan_time_s * 1e3:.2f} ms'),
            ('p99 time per scan', f'{self.p99_scan_time_s * 1e3:.2f} ms'),
            ('wall time', f'{self.wall_time_s:.2f} s'),
            ('real-time factor', f'{self.real_time_factor:.1f}x'),
        ]
        rows += [(f'  skipped: {item.topic}', item.describe()) for item in self.malformed[:10]]
        if len(self.malformed) > 10:
            rows.append(('  skipped', f'... and {len(self.malformed) - 10} more'))
        for name, value in rows:
            table.add_row(name, value)
        return table

    def _topics(self) -> str:
        topics = self.topics
        camera = f'{topics.depth} ({topics.camera_info})' if topics.depth else ''
        return ' + '.join(t for t in (topics.scan, camera) if t) or 'named sources only'


def fuse_bag(
    input: str | Path,  # noqa: A002 - the name the CLI shows
    output: str | Path,
    *,
    config: FusionConfig | None = None,
    scan_topic: str | None = None,
    depth_topic: str | None = None,
    camera_info_topic: str | None = None,
    storage: Storage | str = Storage.MCAP,
    overwrite: bool = False,
    write_depth_scan: bool = True,
    require_tf: bool = False,
    distro: Distro = Distro.HUMBLE,
    progress: Progress | None = None,
    strict: bool = False,
    intrinsics: Intrinsics | None = None,
) -> BagReport:
    """Fuse the LiDAR scans of a recorded bag with its depth images into a new ROS 2 bag.

    A malformed message is copied through when it can be, skipped by the fusion and listed in
    the report; with `strict` it stops the run with an error naming it. `intrinsics` stand
    for the depth camera's CameraInfo (a bag recorded without it, or with a wrong one).
    """
    config = config or FusionConfig()
    source, target = Path(input), Path(output)
    storage = _storage(storage)
    _check_paths(source, target, overwrite=overwrite)
    started = time.perf_counter()
    # Written in a locked staging folder beside the target, renamed into place when complete;
    # the folder goes on any exit (SIGTERM included: the CLI turns it into an exception).
    with Staging(target) as staging:
        with _open_reader(source, distro) as reader:
            job = _BagJob(reader, config, distro, write_depth_scan=write_depth_scan)
            job.intrinsics = intrinsics
            with _located(job), _writing(target):
                topics = job.choose_topics(scan_topic, depth_topic, camera_info_topic)
                job.read_static(require_tf=require_tf)
                counts = job.run(staging.output, storage, progress or NullProgress(), strict=strict)
        with _writing(target):
            _move_into_place(staging.output, target, overwrite=overwrite)
    return BagReport(
        input=source,
        output=target,
        storage=storage,
        topics=topics,
        extrinsics_source=job.extrinsics_source,
        bag_duration_s=job.duration_ns / 1e9,
        wall_time_s=time.perf_counter() - started,
        **counts,
    )


def _storage(storage: Storage | str) -> Storage:
    try:
        return Storage(storage)
    except ValueError:
        choices = ', '.join(item.value for item in Storage)
        msg = f'output storage {storage!r} is not supported; use one of {choices}'
        raise BagError(msg) from None


def _check_paths(source: Path, target: Path, *, overwrite: bool) -> None:
    if not source.exists():
        msg = f'input bag {source} does not exist'
        raise BagError(msg)
    src, dst = source.resolve(), target.resolve()
    if src == dst or src.is_relative_to(dst) or dst.is_relative_to(src):
        msg = (
            f'output {target} overlaps the input bag {source}; '
            'write the fused bag somewhere else (the input is never modified)'
        )
        raise BagError(msg)
    if target.exists() or target.is_symlink():
        if not overwrite:
            msg = f'output {target} exists already; choose another path or pass --overwrite'
            raise BagError(msg)
        _check_replaceable(target)
    if not target.parent.is_dir():
        msg = f'folder {target.parent} of the output bag does not exist; create it first'
        raise BagError(msg)
    _check_name_length(target)


def _check_name_length(target: Path) -> None:
    """The staging folder `.NAME.XXXXXXXX.partial` must fit the filesystem's NAME_MAX too."""
    try:
        limit = os.pathconf(target.parent, 'PC_NAME_MAX')
    except (OSError, ValueError):
        return  # no limit reported: mkdtemp's own error says it, if there is one
    length = len(os.fsencode(target.name))
    if length + STAGING_OVERHEAD > limit:
        shown = target.name if len(target.name) <= 40 else f'{target.name[:40]}...'
        msg = (
            f'output name {shown} is {length} bytes long; this filesystem allows {limit} bytes '
            f'per name and the staging folder adds {STAGING_OVERHEAD}: choose a name of at most '
            f'{limit - STAGING_OVERHEAD} bytes'
        )
        raise BagError(msg)


# First bytes of the storage files a bag can hold (the MCAP magic; SQLite's header string).
_BAG_MAGIC = {'.mcap': b'\x89MCAP0\r\n', '.db3': b'SQLite format 3\x00'}
_SQLITE_SIDECARS = ('.db3-journal', '.db3-wal', '.db3-shm')


def _check_replaceable(target: Path) -> None:
    """--overwrite replaces a bag (folder or single file) and nothing else."""
    reason = _not_a_bag(target)
    if reason is not None:
        msg = (
            f'--overwrite replaces only a bag, and {target} is not one: {reason}; '
            'remove it yourself or choose another output'
        )
        raise BagError(msg)


def _not_a_bag(path: Path) -> str | None:
    """Why `path` is not a bag scanfuse could have written, or None when it is one."""
    if path.is_symlink():
        return 'it is a symbolic link'
    if path.is_file():
        return _not_a_storage_file(path)
    if not path.is_dir():
        return 'it is neither a file nor a folder'
    entries = sorted(path.iterdir())
    names = {entry.name for entry in entries}
    if 'metadata.yaml' not in names:
        return 'it has no metadata.yaml'
    storage = 0
    for entry in entries:
        if entry.name == 'metadata.yaml':
            problem = _not_bag_metadata(entry)
        elif entry.name.endswith(_SQLITE_SIDECARS) and not entry.is_symlink() and entry.is_file():
            continue
        else:
            problem = _not_a_storage_file(entry)
            storage += 1
        if problem is not None:
            return problem
    return None if storage else 'it holds no .mcap or .db3 file'


def _not_a_storage_file(path: Path) -> str | None:
    magic = _BAG_MAGIC.get(path.suffix)
    if magic is None or path.is_symlink() or not path.is_file():
        return f'{path.name} is not a .mcap or .db3 file'
    with path.open('rb') as stream:
        if stream.read(len(magic)) != magic:
            return f'{path.name} does not start like a {path.suffix} file'
    return None


def _not_bag_metadata(path: Path) -> str | None:
    if path.is_symlink() or not path.is_file():
        return 'its metadata.yaml is not a file'
    try:
        content = yaml.safe_load(path.read_text(encoding='utf-8'))
    except (OSError, UnicodeDecodeError, yaml.YAMLError):
        content = None
    if not isinstance(content, dict) or 'rosbag2_bagfile_information' not in content:
        return 'its metadata.yaml is not rosbag2 metadata'
    return None


def _move_into_place(written: Path, target: Path, *, overwrite: bool) -> None:
    if target.exists() or target.is_symlink():
        if not overwrite:
            msg = f'output {target} appeared while fusing; not overwriting it'
            raise BagError(msg)
        _check_replaceable(target)  # again: it may have changed while fusing
        if target.is_dir():
            shutil.rmtree(target)
        else:
            target.unlink()
    written.rename(target)


@contextmanager
def _writing(target: Path) -> Iterator[None]:
    """Failures to write the output (disk full, read-only, too long a name) as one BagError."""
    try:
        yield
    except OSError as err:
        raise output_error(target, err) from err
    except sqlite3.Error as err:
        # The sqlite3 writer's own words ("database or disk is full"); reads never get here:
        # rosbags reads with apsw, and `_guard_read` wraps those errors.
        full = 'full' in str(err)
        hint = 'free space or write somewhere else' if full else 'choose another output path'
        msg = f'cannot write the output {target}: sqlite3: {err}; {hint}'
        raise BagError(msg) from err


@dataclass(frozen=True)
class MessagePosition:
    """Where a message is in a bag: its topic, its index on that topic (from 0), its times."""

    topic: str
    index: int
    log_time_ns: int
    msgtype: str
    raw: bytes = field(repr=False)
    is_cdr: bool = True

    @property
    def stamp_ns(self) -> int | None:
        """The header stamp read straight from the bytes (so known even when decoding fails)."""
        return header_stamp_ns(self.raw, self.msgtype, is_cdr=self.is_cdr)

    def describe(self) -> str:
        """'/scan message 17 (log time 1700000001.700000000 s, stamp ...)'."""
        times = [f'log time {format_ns(self.log_time_ns)} s']
        stamp = self.stamp_ns
        if stamp is not None:
            times.append(f'header stamp {format_ns(stamp)} s')
        return f'{self.topic} message {self.index} ({", ".join(times)})'


# Types whose serialized form starts with a std_msgs/Header (ROS 1: after a uint32 seq).
_HEADER_FIRST = frozenset({LASER_SCAN, IMAGE, CAMERA_INFO})


def format_ns(stamp_ns: int) -> str:
    sec, nanosec = divmod(stamp_ns, 1_000_000_000)
    return f'{sec}.{nanosec:09d}'


def header_stamp_ns(raw: bytes, msgtype: str, *, is_cdr: bool = True) -> int | None:
    """The stamp of a message whose first field is a Header, from its first 12 bytes."""
    if msgtype not in _HEADER_FIRST or len(raw) < 12:
        return None
    if is_cdr:
        # CDR: 4-byte encapsulation (00 00 big endian, 00 01 little endian), then sec, nanosec.
        if raw[0] != 0 or raw[1] not in {0, 1}:
            return None
        order = '<' if raw[1] == 1 else '>'
    else:
        order = '<'  # ROS 1: little endian seq, then sec, nsec
    sec, nanosec = struct.unpack_from(f'{order}iI', raw, 4)
    if not 0 <= nanosec < 1_000_000_000:
        return None
    return int(sec) * 1_000_000_000 + int(nanosec)


def cdr_problem(raw: bytes, msgtype: str, err: BaseException) -> str:
    """What is wrong with CDR bytes rosbags could not decode as `msgtype`, in words."""
    text = str(err)
    if len(raw) < 4:
        return f'{len(raw)} bytes are fewer than the 4-byte CDR header: the message is truncated'
    if raw[0] != 0 or raw[1] not in {0, 1}:
        return (
            f'it starts with {raw[:2].hex(" ")}, not a plain CDR header (00 01 little endian, '
            '00 00 big endian): the bytes are not CDR or not a ROS 2 message'
        )
    if 'size mismatch' in text:
        return (
            f'{len(raw)} bytes hold more than one {msgtype}: bytes are left over at the end, so '
            'they are another type or were written with another definition'
        )
    if 'UnicodeDecodeError' in repr(err.__cause__) or "codec can't decode" in text:
        return f'a string field is not UTF-8 ({text})'
    if any(word in text for word in ('Invalid sequence length', 'Invalid string length', 'unpack')):
        return (
            f'a length field asks for more than the {len(raw)} bytes hold ({text}): '
            f'the message is truncated, or is not a {msgtype}'
        )
    return text


@contextmanager
def _located(job: _BagJob) -> Iterator[None]:
    """Message errors name the message (topic, index on it, log time, stamp) they came from."""
    try:
        yield
    except MessageError as err:
        position = job.position
        if position is None:
            raise
        msg = f'{position.describe()} in {job.source}: {problem_of(position, err)}'
        raise MessageError(msg) from err


def problem_of(position: MessagePosition, err: Exception) -> str:
    """What is wrong with the message at `position`, in words."""
    cause = err if isinstance(err, SerdeError) else err.__cause__
    if isinstance(cause, SerdeError) and position.is_cdr:
        return (
            f'cannot decode a {position.msgtype} from {len(position.raw)} CDR bytes: '
            f'{cdr_problem(position.raw, position.msgtype, cause)}'
        )
    return str(err) or type(err).__name__


class _ReaderScope:
    """`AnyReader` as a context whose failures (damaged bags) become BagError."""

    def __init__(self, source: Path, distro: Distro) -> None:
        self.source = source
        self.reader = _guard_read(
            source, lambda: AnyReader([source], default_typestore=_fresh_store(distro))
        )

    def __enter__(self) -> AnyReader:
        _guard_read(self.source, self.reader.open)
        reader: AnyReader = self.reader
        return reader

    def __exit__(self, *exc: object) -> None:
        if self.reader.stack is not None:
            self.reader.close()


def _open_reader(source: Path, distro: Distro) -> _ReaderScope:
    return _ReaderScope(source, distro)


def _guard_read(
    source: Path, action: Callable[[], Any], after: MessagePosition | None = None
) -> Any:
    """Run a read; a damaged bag's error becomes a BagError naming the last good message."""
    try:
        return action()
    except ScanfuseError:
        raise
    except (*_READ_ERRORS, OSError) as err:
        where = f' after {after.describe()}' if after is not None else ''
        msg = (
            f'cannot read bag {source}{where}: {err or type(err).__name__}; '
            'is it complete and a bag?'
        )
        raise BagError(msg) from err


def _check_stored(source: Path, topic: str, index: int, log_time: int, raw: object) -> None:
    """A message as its storage holds it: bytes at a log time of zero or later. A db3 whose
    data column holds TEXT, or whose timestamp is negative, is no bag rosbags wrote."""
    problem = None
    if not isinstance(raw, bytes | bytearray | memoryview):
        problem = f'its data is {type(raw).__name__}, not bytes'
    elif not isinstance(log_time, int) or log_time < 0:
        problem = f'its log time is {log_time} ns, before 1970'
    if problem is not None:
        msg = (
            f'cannot read bag {source}: {topic} message {index}: {problem}; '
            'is it complete and a bag?'
        )
        raise BagError(msg)


def _fresh_store(distro: Distro) -> Typestore:
    """A private typestore of `distro` (types of ROS 1 bags may be added to it)."""
    store = get_typestore(Stores.EMPTY)
    store.register(dict(get_typestore(_DISTRO_STORES[Distro(distro)]).fielddefs))
    return store


def describe_topics(topics: dict[str, str]) -> str:
    return ', '.join(f'{name} ({msgtype})' for name, msgtype in sorted(topics.items())) or 'none'


@dataclass(frozen=True)
class MalformedMessage:
    """An input message the fusion could not use: where it is and why."""

    topic: str
    where: str  # `MessagePosition.describe()`
    reason: str

    def describe(self) -> str:
        return f'{self.where}: {self.reason}'


class CdrConverter:
    """A bag's messages as ROS 2 CDR: unchanged for ROS 2 bags, converted for ROS 1."""

    def __init__(self, reader: AnyReader, store: Typestore) -> None:
        self.reader = reader
        self.store = store  # ROS 2 types; ROS 1 types ROS 2 lacks are registered into it
        self.converters: dict[str, Callable[[bytes], bytes]] = {}

    def msgtype(self, connection: Connection) -> str:
        """The ROS 2 name of the connection's type (ROS 1's tf/tfMessage is tf2_msgs')."""
        return STATIC_MSGTYPE_RENAMES.get(connection.msgtype, connection.msgtype)

    def to_cdr(self, connection: Connection, raw: bytes) -> bytes:
        if self.reader.is2:
            return raw
        convert = self.converters.get(connection.msgtype)
        if convert is None:
            convert = self.converters[connection.msgtype] = self._ros1_converter(connection)
        try:
            return convert(raw)
        except (SerdeError, ValueError, struct.error) as err:
            msg = (
                f'cannot convert a ROS 1 {connection.msgtype} on {connection.topic} to ROS 2: {err}'
            )
            raise MessageError(msg) from err

    def _ros1_converter(self, connection: Connection) -> Callable[[bytes], bytes]:
        src_type, dst_type = connection.msgtype, self.msgtype(connection)
        if dst_type not in self.store.fielddefs:
            # A type ROS 2 does not ship: keep its ROS 1 fields, with the ROS 2 header.
            definition, _ = self.reader.typestore.generate_msgdef(src_type, ros_version=2)
            types = get_types_from_msg(definition, dst_type)
            types.pop('std_msgs/msg/Header', None)
            self.store.register(types)
        if is_same_wireformat(self.reader.typestore, self.store, src_type, dst_type):
            return lambda raw: bytes(self.store.ros1_to_cdr(raw, dst_type))
        migrate = partial(migrate_bytes, self.reader.typestore, self.store, src_type, dst_type, {})
        return lambda raw: bytes(migrate(raw, src_is2=False, dst_is2=True))


def open_bag(source: Path, distro: Distro = Distro.HUMBLE) -> _ReaderScope:
    """`AnyReader` over `source` as a context; a damaged bag's failure is a BagError."""
    return _ReaderScope(source, distro)


def fresh_store(distro: Distro = Distro.HUMBLE) -> Typestore:
    return _fresh_store(distro)


@dataclass(frozen=True)
class _Lidar:
    """What the stream hands back with a scan: its CDR and log time."""

    raw: bytes
    log_time: int


class _BagJob:
    """One run of `fuse_bag` over an open reader."""

    def __init__(
        self, reader: AnyReader, config: FusionConfig, distro: Distro, *, write_depth_scan: bool
    ) -> None:
        self.reader = reader
        self.config = config
        self.write_depth_scan = write_depth_scan
        self.source = Path(str(reader.paths[0]))
        # ROS 2 bags are decoded with their own definitions; ROS 1 messages become CDR first.
        self.store = reader.typestore if reader.is2 else _fresh_store(distro)
        if LASER_SCAN not in self.store.fielddefs:
            # A bag without a LiDAR (a camera-only robot) has no LaserScan definition of its
            # own for the scans written: the distribution's, with what it uses.
            known = get_typestore(_DISTRO_STORES[Distro(distro)]).fielddefs
            self.store.register({k: v for k, v in known.items() if k not in self.store.fielddefs})
        self.cdr = CdrConverter(reader, self.store)
        self.topics_types = {
            name: info.msgtype or '?'
            for name, info in _guard_read(self.source, lambda: reader.topics).items()
        }
        self.duration_ns = reader.duration if reader.message_count else 0
        self.choice: TopicChoice | None = None
        self.intrinsics: Intrinsics | None = None
        self.camera_model: CameraModel | None = None
        # Bags are read in log-time order: a scan waits for every camera's first frame stamped
        # after it, or until no frame logged up to REORDER_S late can still be near enough.
        windows = [s.max_time_offset or config.max_time_offset for s in config.sources.cameras]
        pair_wait = max(windows, default=config.max_time_offset) + REORDER_S
        self.stream: FusionStream[_Lidar] = FusionStream(
            config, pair_wait=pair_wait, release_when_silent=False
        )
        self.scan_frame = ''
        self.depth_frame = ''
        # The message being handled, so errors can name it (see `_located`).
        self.position: MessagePosition | None = None

    # ------------------------------------------------------------ reading helpers

    def msgtype(self, connection: Connection) -> str:
        return self.cdr.msgtype(connection)

    def to_cdr(self, connection: Connection, raw: bytes) -> bytes:
        return self.cdr.to_cdr(connection, raw)

    def decode(self, connection: Connection, raw: bytes) -> Any:
        return deserialize(self.to_cdr(connection, raw), self.msgtype(connection), self.store)

    def connections(self, topic: str) -> list[Connection]:
        return [c for c in self.reader.connections if c.topic == topic]

    def messages(self, connections: list[Connection]) -> Iterator[tuple[Connection, int, bytes]]:
        if not connections:  # rosbags reads every topic when given none
            return
        iterator = self.reader.messages(connections=connections)
        indices: dict[str, int] = {}
        while True:
            item = _guard_read(self.source, lambda: next(iterator, None), self.position)
            if item is None:
                return
            connection, log_time, raw = item
            index = indices.get(connection.topic, 0)
            _check_stored(self.source, connection.topic, index, log_time, raw)
            indices[connection.topic] = index + 1
            self.position = MessagePosition(
                connection.topic,
                index,
                log_time,
                self.msgtype(connection),
                raw,
                is_cdr=self.reader.is2,
            )
            yield item

    def first_message(self, topic: str) -> Any:
        connections = self.connections(topic)
        for connection, _, raw in self.messages(connections):
            return self.decode(connection, raw)
        return None

    # ------------------------------------------------------------ topics

    def choose_topics(
        self, scan: str | None, depth: str | None, camera_info: str | None
    ) -> TopicChoice:
        reserved = self._output_topics()
        clash = sorted(reserved & set(self.topics_types))
        if clash:
            msg = (
                f'the input bag already has {", ".join(clash)}; set fused_topic and '
                'depth_scan_topic in the parameters to names the bag does not use'
            )
            raise BagError(msg)
        # No LiDAR (scan_topic empty) or no camera (depth_topic empty) unless an option names
        # one: '' is no topic.
        scan_topic = ''
        if scan is not None or self.config.has_lidar:
            scan_topic = self._choose(
                scan, self.config.scan_topic, LASER_SCAN, '--scan', 'LaserScan'
            )
        images = {name: t for name, t in self.topics_types.items() if t == IMAGE}
        depth_topics = {name: t for name, t in images.items() if self._is_depth_topic(name)}
        depth_topic = info_topic = ''
        if depth is not None or self.config.has_camera:
            depth_topic = self._choose_depth(depth, images, depth_topics)
            sibling = depth_topic.rsplit('/', 1)[0] + '/camera_info'
            info_default = (
                sibling if sibling in self.topics_types else self.config.camera_info_topic
            )
            if self.intrinsics is not None and camera_info is None:
                info_topic = GIVEN_INTRINSICS  # the bag's CameraInfo, if any, is not used
            else:
                info_topic = self._choose(
                    camera_info, info_default, CAMERA_INFO, '--camera-info', 'CameraInfo'
                )
        sources = self._named_sources()
        used = {scan_topic, depth_topic, info_topic, *(t for t, _, _ in sources)}
        sensor_types = {LASER_SCAN, POINT_CLOUD} | ({IMAGE} if depth_topics else set())
        unused = tuple(
            sorted(
                (name, t)
                for name, t in self.topics_types.items()
                if t in sensor_types
                and name not in used
                and (t != IMAGE or name in depth_topics)
                and not is_ground_truth(name)
            )
        )
        imu_topic = self._choose_imu()
        self.choice = TopicChoice(scan_topic, depth_topic, info_topic, sources, unused, imu_topic)
        if unused:
            logger.info(
                'also in the bag, not fused: %s (name them in lidars / cameras / clouds)',
                describe_topics(dict(unused)),
            )
        return self.choice

    def _choose_imu(self) -> str:
        """`imu_topic` (which must be an Imu topic of the bag), else the bag's one Imu topic;
        '' when it holds none, or several and none is named."""
        imus = self._candidates(IMU)
        requested = self.config.imu_topic
        if requested:
            if requested not in imus:
                msg = f'imu_topic {requested} is not an Imu topic of the bag; Imu topics: '
                raise BagError(msg + describe_topics(imus))
            return requested
        if len(imus) == 1:
            (topic,) = imus
            logger.info("the base's tilt from %s, the bag's one Imu topic", topic)
            return topic
        if imus:
            logger.info('several Imu topics, none used: set imu_topic to one of %s', sorted(imus))
        return ''

    def _named_sources(self) -> tuple[tuple[str, str, str], ...]:
        """Topics of the named sources not on the one-source topics (`scan_topic`,
        `depth_topic`, read as those); each must be in the bag."""
        config = self.config
        lidars = [s for s in config.sources.lidars if s.topic != config.scan_topic]
        cameras = [s for s in config.sources.cameras if s.depth_topic != config.depth_topic]
        wanted = [
            *((s.topic, s.name, LASER_SCAN) for s in lidars),
            *((s.depth_topic, s.name, IMAGE) for s in cameras),
            *((s.camera_info_topic, s.name, CAMERA_INFO) for s in cameras),
            *((s.topic, s.name, POINT_CLOUD) for s in config.sources.clouds),
        ]
        for topic, name, kind in wanted:
            found = self.topics_types.get(topic)
            if found != kind:
                what = f'is a {found}' if found else 'is not in the bag'
                msg = (
                    f'source {name}: topic {topic} {what}; {kind} topics: '
                    f'{describe_topics(self._candidates(kind))}'
                )
                raise BagError(msg)
        return tuple(wanted)

    def _output_topics(self) -> set[str]:
        config = self.config
        topics = {config.fused_topic, config.depth_scan_topic}
        if config.memory:
            topics |= {config.instant_topic, config.memory_scan_topic} - {''}
        return topics

    def _candidates(self, msgtype: str) -> dict[str, str]:
        reserved = self._output_topics()
        return {
            name: t
            for name, t in self.topics_types.items()
            if t == msgtype and name not in reserved
        }

    def _choose(
        self, requested: str | None, default: str, msgtype: str, option: str, kind: str
    ) -> str:
        candidates = self._candidates(msgtype)
        if requested is not None:
            if candidates.get(requested) == msgtype:
                return requested
            found = self.topics_types.get(requested)
            what = f'is a {found}' if found else 'is not in the bag'
            msg = (
                f'{kind} topic {requested} {what}; {msgtype} topics: '
                f'{describe_topics(candidates)}; all topics: {describe_topics(self.topics_types)}'
            )
            raise BagError(msg)
        if default in candidates:
            return default
        if len(candidates) == 1:
            return next(iter(candidates))
        if not candidates:
            instead = (
                "; give the camera's intrinsics instead: --intrinsics FX FY CX CY"
                if msgtype == CAMERA_INFO
                else ''
            )
            msg = (
                f'no {kind} topic ({msgtype}) in bag {self.source}; '
                f'topics: {describe_topics(self.topics_types)}{instead}'
            )
            raise BagError(msg)
        msg = (
            f'several {kind} topics in bag {self.source}: {describe_topics(candidates)}; '
            f'choose one with {option}'
        )
        raise BagError(msg)

    def _is_depth_topic(self, topic: str) -> bool:
        first = self.first_message(topic)
        return first is not None and is_depth_encoding(str(first.encoding))

    def _choose_depth(
        self, requested: str | None, images: dict[str, str], depth_topics: dict[str, str]
    ) -> str:
        listing = (
            f'depth Image topics (16UC1/32FC1): {describe_topics(depth_topics)}; '
            f'all topics: {describe_topics(self.topics_types)}'
        )
        if requested is not None:
            if requested in depth_topics:
                return requested
            if requested in images:
                msg = f'Image topic {requested} is not a depth image (16UC1 or 32FC1); {listing}'
            else:
                found = self.topics_types.get(requested)
                what = f'is a {found}' if found else 'is not in the bag'
                msg = f'depth topic {requested} {what}; {listing}'
            raise BagError(msg)
        if self.config.depth_topic in depth_topics:
            return self.config.depth_topic
        if len(depth_topics) == 1:
            return next(iter(depth_topics))
        if not depth_topics:
            msg = (
                f'no depth Image topic (16UC1 or 32FC1) in bag {self.source}; {listing}; '
                "for LiDARs or clouds only set depth_topic: '' in the parameters"
            )
            raise BagError(msg)
        msg = f'several depth Image topics in bag {self.source}; choose one with --depth; {listing}'
        raise BagError(msg)

    # ------------------------------------------------------------ TF and camera

    def read_static(self, *, require_tf: bool) -> None:
        """Read the first CameraInfo, the sensors' frames and TF; choose the extrinsics."""
        assert self.choice is not None
        choice: TopicChoice = self.choice
        scan = self.first_message(choice.scan) if choice.scan else None
        depth = self.first_message(choice.depth) if choice.depth else None
        for topic, first in ((choice.scan, scan), (choice.depth, depth)):
            if topic and first is None:
                msg = f'topic {topic} has no messages; cannot fuse'
                raise BagError(msg)
        info_frame = ''
        if self.intrinsics is not None and depth is not None:
            given = self.intrinsics
            self.camera_model = CameraModel.from_intrinsics(
                int(depth.width), int(depth.height), given.fx, given.fy, given.cx, given.cy,
                frame_id=str(depth.header.frame_id),
            )  # fmt: skip
        else:
            info = self.first_message(choice.camera_info) if choice.camera_info else None
            if choice.camera_info and info is None:
                msg = (
                    f'CameraInfo topic {choice.camera_info} has no messages; cannot fuse '
                    "(give the camera's intrinsics instead: --intrinsics FX FY CX CY)"
                )
                raise BagError(msg)
            self.camera_model = None if info is None else camera_from_msg(info)
            info_frame = '' if info is None else str(info.header.frame_id)
        self._read_mounting()
        if scan is None or depth is None or self.camera_model is None:
            return  # one sensor: no pair whose extrinsics to check
        self.scan_frame = frame_name(str(scan.header.frame_id))
        self.depth_frame = frame_name(str(depth.header.frame_id) or info_frame)
        extrinsics = self.stream.extrinsics_for(self.scan_frame, self.depth_frame)
        if extrinsics.extrinsics is None:
            raise TransformError(extrinsics.source)
        if require_tf and not extrinsics.source.startswith('TF'):
            msg = f'--require-tf: no extrinsics from TF in {self.source}: {extrinsics.source}'
            raise TransformError(msg)
        if not extrinsics.source.startswith('TF'):
            logger.warning('extrinsics from the %s', extrinsics.source)

    @property
    def extrinsics_source(self) -> str:
        return self.stream.extrinsics_source

    def _read_mounting(self) -> None:
        """The mounting poses of /tf_static and /tf, before the pass (odometry comes in it).

        A TF message that cannot be used (a NaN quaternion) is passed over here; the pass
        skips and lists it (or, with --strict, stops at it) as it does any malformed message.
        """
        for topic, static in ((TF_STATIC_TOPIC, True), (TF_TOPIC, False)):
            connections = [c for c in self.connections(topic) if self.msgtype(c) == TF_MESSAGE]
            for connection, _, raw in self.messages(connections):
                try:
                    transforms = transforms_from_msg(self.decode(connection, raw))
                except (ScanfuseError, SerdeError, ValueError, struct.error):
                    continue
                self.stream.add_transforms(transforms, static=static, odometry=False)

    # ------------------------------------------------------------ the pass

    def run(
        self, path: Path, storage: Storage, progress: Progress, *, strict: bool = False
    ) -> dict[str, Any]:
        """Copy every message, feed the stream in log-time order, write what it releases."""
        assert self.choice is not None
        stream = self.stream
        if self.camera_model is not None:
            stream.add_camera_info(self.camera_model)
        counts = {'messages_read': 0}
        times: list[float] = []
        malformed: list[MalformedMessage] = []
        writer = Writer(path, version=8, storage_plugin=_PLUGINS[storage])
        try:
            writer.open()
            outputs = self._add_connections(writer)
            fused_conn = writer.add_connection(
                self.config.fused_topic, LASER_SCAN, typestore=self.store
            )
            depth_conn = (
                writer.add_connection(
                    self.config.depth_scan_topic, LASER_SCAN, typestore=self.store
                )
                if self.write_depth_scan
                else None
            )

            memory_conns = {
                topic: writer.add_connection(topic, LASER_SCAN, typestore=self.store)
                for topic in (self.config.instant_topic, self.config.memory_scan_topic)
                if self.config.memory and topic
            }

            def remember(result: StreamOutput[_Lidar]) -> None:
                """The memory's outputs, for the scans it was placed for (odometry known)."""
                if result.memory_scan is None:
                    return
                lidar, config = result.token, self.config
                instant = result.instant or (result.lidar if result.deskewed else None)
                outputs = {
                    config.instant_topic: lidar.raw
                    if instant is None
                    else scan_to_cdr(instant, self.store),
                    config.memory_scan_topic: scan_to_cdr(result.memory_scan, self.store),
                }
                for topic, connection in memory_conns.items():
                    writer.write(connection, lidar.log_time, outputs[topic])

            def emit(released: list[StreamOutput[_Lidar]]) -> None:
                for result in released:
                    lidar = result.token
                    remember(result)
                    if result.fused is None:
                        writer.write(fused_conn, lidar.log_time, lidar.raw)
                        continue
                    start = time.perf_counter()
                    fused = scan_to_cdr(result.fused, self.store)
                    depth_raw = (
                        scan_to_cdr(result.depth_scan, self.store)
                        if depth_conn is not None and result.depth_scan is not None
                        else None
                    )
                    if result.timings is not None:
                        times.append(result.timings.total + time.perf_counter() - start)
                    writer.write(fused_conn, lidar.log_time, fused)
                    if depth_conn is not None and depth_raw is not None:
                        writer.write(depth_conn, lidar.log_time, depth_raw)

            progress.start('fusing', self.reader.message_count)
            try:
                for connection, log_time, raw in self.messages(self.reader.connections):
                    counts['messages_read'] += 1
                    try:
                        cdr = self.to_cdr(connection, raw)
                    except MessageError as err:
                        self._malformed(malformed, err, strict=strict)
                        progress.advance()
                        continue
                    writer.write(outputs[connection.id, id(connection.owner)], log_time, cdr)
                    try:
                        emit(self._feed(connection, cdr, log_time))
                    except (ScanfuseError, SerdeError, ValueError, struct.error) as err:
                        self._malformed(malformed, err, strict=strict)
                    progress.advance()
                emit(stream.finish())
            finally:
                progress.finish()
            written = sum(writer.counts.values())
            writer.close()
        except WriterError as err:
            writer.abort()
            msg = f'cannot write the output bag: {err}'
            raise BagError(msg) from err
        except BaseException:
            if writer.storage is not None:
                writer.abort()
            raise
        stream_counts = stream.counts
        return {
            **counts,
            'messages_written': written,
            'scans': stream_counts.scans,
            'depth_frames': stream_counts.depth_frames,
            'scans_paired': stream_counts.fused,
            'scans_passed_through': stream_counts.passed_through,
            'scans_compensated': stream_counts.compensated,
            'peak_depth_frames': stream_counts.peak_frames,
            'malformed': tuple(malformed),
            'scan_times_s': tuple(times),
        }

    def _feed(
        self, connection: Connection, cdr: bytes, log_time: int
    ) -> list[StreamOutput[_Lidar]]:
        """One input message into the stream; the scans it releases."""
        assert self.choice is not None
        topic, stream = connection.topic, self.stream
        if topic == self.choice.scan:
            scan = scan_from_msg(deserialize(cdr, LASER_SCAN, self.store))
            return stream.add_scan(scan, _Lidar(cdr, log_time), log_time)
        if topic == self.choice.depth:
            image = depth_from_msg(deserialize(cdr, IMAGE, self.store))
            if stream.camera is not None:
                check_depth_matches_camera(image, stream.camera)
            # Without a LiDAR the frame makes an output, written at its log time.
            return stream.add_depth(
                image.stamp_ns, image.depth, log_time, image.frame_id, token=_Lidar(b'', log_time)
            )
        extra = self.choice.source_of(topic)
        if extra is not None:
            return self._feed_source(extra, cdr, log_time)
        if topic == self.choice.camera_info:
            stream.add_camera_info(camera_from_msg(deserialize(cdr, CAMERA_INFO, self.store)))
        elif topic == TF_TOPIC and self.msgtype(connection) == TF_MESSAGE:
            stream.add_transforms(
                transforms_from_msg(deserialize(cdr, TF_MESSAGE, self.store)), static=False
            )
        elif topic == self.config.odom_topic and self.msgtype(connection) == ODOMETRY:
            sample = odometry_from_msg(deserialize(cdr, ODOMETRY, self.store))
            stream.add_odometry(sample.stamp_ns, sample.pose)
        elif topic == self.choice.imu:
            imu = imu_from_msg(deserialize(cdr, IMU, self.store))
            stream.add_imu(imu.stamp_ns, imu.orientation, imu.frame_id)
        return stream.tick(log_time)

    def _feed_source(
        self, source: tuple[str, str], cdr: bytes, log_time: int
    ) -> list[StreamOutput[_Lidar]]:
        """A message of another named source into the stream."""
        name, kind = source
        stream = self.stream
        if kind == LASER_SCAN:
            scan = scan_from_msg(deserialize(cdr, LASER_SCAN, self.store))
            return stream.add_scan(scan, _Lidar(cdr, log_time), log_time, source=name)
        if kind == IMAGE:
            image = depth_from_msg(deserialize(cdr, IMAGE, self.store))
            return stream.add_depth(
                image.stamp_ns, image.depth, log_time, image.frame_id, source=name
            )
        if kind == CAMERA_INFO:
            camera = camera_from_msg(deserialize(cdr, CAMERA_INFO, self.store))
            stream.add_camera_info(camera, source=name)
            return stream.tick(log_time)
        cloud = cloud_from_msg(deserialize(cdr, POINT_CLOUD, self.store))
        return stream.add_cloud(
            cloud.stamp_ns, cloud.points, log_time, cloud.frame_id, name, _Lidar(b'', log_time)
        )

    def _malformed(self, found: list[MalformedMessage], err: Exception, *, strict: bool) -> None:
        """Skip and list the message being handled (or, with `strict`, stop on it)."""
        position = self.position
        assert position is not None  # set by `messages` for every message it yields
        item = MalformedMessage(position.topic, position.describe(), problem_of(position, err))
        if strict:
            msg = f'--strict: malformed {item.where} in {self.source}: {item.reason}'
            raise BagError(msg) from err
        found.append(item)
        self.stream.note_malformed(position.topic, err)

    def _add_connections(self, writer: Writer) -> dict[tuple[int, int], Connection]:
        """One output connection per input connection (ROS 1 connections of a topic merge)."""
        out: dict[tuple[int, int], Connection] = {}
        for connection in self.reader.connections:
            msgtype = self.msgtype(connection)
            ext = connection.ext
            if not isinstance(ext, ConnectionExtRosbag2):
                ext = ConnectionExtRosbag2('cdr', LATCH if ext.latching else [])
            existing = next(
                (
                    c
                    for c in writer.connections
                    if c.topic == connection.topic and c.msgtype == msgtype and c.ext == ext
                ),
                None,
            )
            if existing is None:
                keeps_definition = (
                    self.reader.is2
                    and connection.digest
                    and connection.msgdef.format != MessageDefinitionFormat.NONE
                )
                if keeps_definition:
                    existing = writer.add_connection(
                        connection.topic,
                        msgtype,
                        msgdef=connection.msgdef.data,
                        rihs01=connection.digest,
                        serialization_format=ext.serialization_format,
                        offered_qos_profiles=ext.offered_qos_profiles,
                    )
                else:
                    existing = writer.add_connection(
                        connection.topic,
                        msgtype,
                        typestore=self.store,
                        serialization_format=ext.serialization_format,
                        offered_qos_profiles=ext.offered_qos_profiles,
                    )
            out[connection.id, id(connection.owner)] = existing
        return out
