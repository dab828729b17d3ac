"""Named sensor sources, listed the way Nav2 lists `observation_sources`.

A parameter file may name several LiDARs, depth cameras and point clouds:

    scanfuse:
      ros__parameters:
        lidars: [front, rear]
        front: {topic: /front/scan}
        rear: {topic: /rear/scan, assemble_fragments: true}
        cameras: [front_depth, rear_depth]
        front_depth: {depth_topic: /front/depth/image_raw,
                      camera_info_topic: /front/depth/camera_info}
        clouds: [livox]
        livox: {topic: /livox/points, min_height: 0.05}

The first LiDAR (or the one `trigger` names) triggers every output scan and gives its
frame and grid unless `output_frame` and `angle_increment` set them (slam_toolbox needs a
constant reading count); every other source, every camera alike, contributes by one rule
(`scanfuse.feeds`): its message within its own `max_time_offset`, moved to the output stamp.
Without a LiDAR (`scan_topic: ''`) the camera listed first (or the `trigger` one) makes the
outputs, without LiDAR and camera the cloud listed first. The
single-LiDAR, single-camera parameters (`scan_topic`, `depth_topic`, `lidar_*`, `camera_*`)
are the one-source case: a named first LiDAR or camera takes their place; an empty topic
is no such sensor.

Each source's mounting is a full pose in the base frame (x, y, z, roll, pitch, yaw;
REP-103), used when TF does not give it: an upside-down scanner is `roll: pi`.
"""

from __future__ import annotations

import math
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, model_validator

from scanfuse.errors import ConfigError

KINDS = ('lidars', 'cameras', 'clouds')
# Metres from the base frame, per axis: a sensor farther is a typo or an overflow.
MAX_MOUNTING_OFFSET = 100.0
_REACH = MAX_MOUNTING_OFFSET


# The fragment options of a LiDAR, the same for the one-source parameters (FusionConfig)
# and a named source: one description, one set of bounds.
def assemble_fragments_field() -> Any:
    return Field(
        default=False,
        description=(
            'assemble scans that each cover part of one revolution (a PSENscan publishes 6 per '
            'turn) into one, fused once per revolution'
        ),
    )


def fragment_timeout_field() -> Any:
    return Field(0.2, gt=0.0, le=10.0, description='seconds a revolution may take to complete')


class Mounting(BaseModel):
    """Pose of a sensor (its body frame; for a camera, the camera_link) in the base frame."""

    model_config = ConfigDict(frozen=True, extra='forbid')

    x: float = Field(
        0.0, ge=-MAX_MOUNTING_OFFSET, le=MAX_MOUNTING_OFFSET, description='metres, forward'
    )
    y: float = Field(
        0.0, ge=-MAX_MOUNTING_OFFSET, le=MAX_MOUNTING_OFFSET, description='metres, left'
    )
    z: float = Field(
        0.0, ge=-MAX_MOUNTING_OFFSET, le=MAX_MOUNTING_OFFSET, description='metres above the floor'
    )
    roll: float = Field(0.0, ge=-2 * math.pi, le=2 * math.pi, description='radians')
    pitch: float = Field(0.0, ge=-2 * math.pi, le=2 * math.pi, description='radians, + down')
    yaw: float = Field(0.0, ge=-2 * math.pi, le=2 * math.pi, description='radians, + left')


class LidarSource(Mounting):
    name: str
    topic: str = Field(description='sensor_msgs/LaserScan topic')
    max_time_offset: float | None = Field(
        None,
        gt=0.0,
        le=10.0,
        description='freshest scan used within this many seconds (default: max_time_offset)',
    )
    assemble_fragments: bool = assemble_fragments_field()
    fragment_timeout: float = fragment_timeout_field()


class CameraSource(Mounting):
    name: str
    depth_topic: str = Field(description='depth Image topic (16UC1 mm or 32FC1 m)')
    camera_info_topic: str = Field(description='CameraInfo topic')
    max_time_offset: float | None = Field(
        None, gt=0.0, le=10.0, description='seconds (default: max_time_offset)'
    )
    min_obstacle_height: float | None = Field(
        None, ge=-_REACH, le=_REACH, description='own slab bottom, metres (default: global)'
    )
    max_obstacle_height: float | None = Field(
        None, ge=-_REACH, le=_REACH, description='own slab top, metres (default: global)'
    )


class CloudSource(Mounting):
    name: str
    topic: str = Field(description='sensor_msgs/PointCloud2 topic')
    max_time_offset: float | None = Field(
        None, gt=0.0, le=10.0, description='seconds (default: max_time_offset)'
    )
    min_height: float | None = Field(
        None, ge=-_REACH, le=_REACH, description='slab bottom, metres (default: global)'
    )
    max_height: float | None = Field(
        None, ge=-_REACH, le=_REACH, description='slab top, metres (default: global)'
    )
    range_max: float = Field(10.0, gt=0.0, le=1000.0, description='metres from the output origin')


class SourceSet(BaseModel):
    """The named sources beyond the one-source parameters (empty: only those)."""

    model_config = ConfigDict(frozen=True, extra='forbid')

    lidars: tuple[LidarSource, ...] = ()
    cameras: tuple[CameraSource, ...] = ()
    clouds: tuple[CloudSource, ...] = ()

    @model_validator(mode='after')
    def _check(self) -> SourceSet:
        every: list[LidarSource | CameraSource | CloudSource] = [
            *self.lidars,
            *self.cameras,
            *self.clouds,
        ]
        names = [s.name for s in every]
        repeated = sorted({n for n in names if names.count(n) > 1})
        if repeated:
            msg = f'source names must be unique, {", ".join(repeated)} used twice'
            raise ValueError(msg)
        topics = [
            *(s.topic for s in self.lidars),
            *(t for s in self.cameras for t in (s.depth_topic, s.camera_info_topic)),
            *(s.topic for s in self.clouds),
        ]
        shared = sorted({t for t in topics if topics.count(t) > 1})
        if shared:
            msg = (
                f'two sources listen on {", ".join(shared)}: give each source its own topic '
                '(one message cannot come from two sensors)'
            )
            raise ValueError(msg)
        return self

    @property
    def empty(self) -> bool:
        return not (self.lidars or self.cameras or self.clouds)


def split_sources(values: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any] | None]:
    """Plain parameters and the source sections, from a parameter file's or node's values.

    Sections come either nested (`front: {topic: ...}`, a YAML file) or flat with dots
    (`front.topic`, how rclpy names them). Returns (the other values, the SourceSet input
    or None when no source is listed).
    """
    rest = dict(values)
    lists = {kind: rest.pop(kind, None) for kind in KINDS}
    if not any(lists.values()):
        for kind in KINDS:
            if lists[kind] is not None and not isinstance(lists[kind], list | tuple):
                rest[kind] = lists[kind]  # a wrong type: let validation name it
        return rest, None
    sections: dict[str, dict[str, Any]] = {}
    for key in list(rest):
        value = rest[key]
        if isinstance(value, dict):
            sections[key] = dict(value)
            del rest[key]
        elif '.' in key:
            name, field = key.split('.', 1)
            sections.setdefault(name, {})[field] = value
            del rest[key]
    listed_names = [
        (kind, str(name))
        for kind in KINDS
        if isinstance(lists[kind], list | tuple)
        for name in lists[kind]
    ]
    seen: dict[str, str] = {}
    for kind, name in listed_names:
        if name in seen:
            where = kind if seen[name] == kind else f'{seen[name]} and {kind}'
            msg = (
                f'source name {name!r} is listed twice ({where}); every source needs its own '
                'name and section'
            )
            raise ConfigError(msg)
        seen[name] = kind
    sources: dict[str, Any] = {}
    for kind in KINDS:
        names = lists[kind] or []
        if not isinstance(names, list | tuple):
            sources[kind] = names  # validation names the wrong type
            continue
        sources[kind] = [{'name': name, **sections.pop(str(name), {})} for name in names]
    if sections:
        # A section nobody lists is a typo, or a source left out of its list: say so.
        listed = ', '.join(f'{kind}: {lists[kind] or []}' for kind in KINDS)
        msg = (
            f'source sections {", ".join(sorted(sections))} are not listed in lidars, cameras '
            f'or clouds ({listed}); add them to a list or remove them'
        )
        raise ConfigError(msg)
    return rest, sources


def sources_to_params(sources: SourceSet) -> dict[str, Any]:
    """The parameter-file form: the lists and one section per source."""
    out: dict[str, Any] = {}
    for kind in KINDS:
        items = getattr(sources, kind)
        if items:
            out[kind] = [item.name for item in items]
            for item in items:
                out[item.name] = item.model_dump(exclude={'name'}, exclude_none=True)
    return out
