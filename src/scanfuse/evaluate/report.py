"""The evaluation's report: figures, report.md, and the rich table of headline numbers."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from rich.table import Table

from scanfuse.evaluate import figures
from scanfuse.evaluate.mapping import FREE_THRESH, OCCUPIED_THRESH, GridSpec, OccupancyGrid
from scanfuse.evaluate.metrics import TOLERANCE_ABSOLUTE, TOLERANCE_RELATIVE
from scanfuse.sim.robot import FALL_DEPTH
from scanfuse.tables import TextTable

if TYPE_CHECKING:
    from pathlib import Path

    from scanfuse.evaluate.results import EvaluationResult
    from scanfuse.evaluate.runner import CostmapSet, Evaluation, MapSet
    from scanfuse.sim.worlds import World

MAPS_NOTE = (
    'Occupied cells within one cell of the truth; IoU exact, inside the observed region. '
    'Maps are built from the frames of the `obstacle` runs with log-odds ray tracing, as '
    'slam_toolbox or a costmap would: a low obstacle enters the map while the camera sees '
    'it, and LiDAR rays that pass over it later (the robot beside or behind it) clear it '
    "again. The `maps_*_lidar_run.png` figures map the LiDAR-only robot's own run, "
    'which ends at the obstacle, with its scans and with the fused ones.'
)
HEADLINE_TARGETS = {'recall': 0.95, 'false_obstacle_rate': 0.005, 'false_drop_rate': 0.0005}
DROPS_NOTE = (
    'On the worlds without drop-offs (every world but ledge, stairs and hole, turning trials '
    'included), a false drop slot of a method that reports drops (`detect_drops: true`) is a '
    'slot whose fused range is shorter than the ground truth by more than the tolerance and '
    'shorter, by more than the same tolerance, than what the same method fed the same events '
    'gives with `detect_drops: false` (a twin stream): the slots that drops alone moved '
    'closer. On these worlds every reported drop is false. Methods without drops: n/a. '
    f'Target: <= {100 * HEADLINE_TARGETS["false_drop_rate"]:.2f} % of slots.'
)
STREAM_KEYS = ('scans', 'fused', 'compensated', 'deskewed', 'passed')


def _fmt(value: float, digits: int = 3) -> str:
    return 'n/a' if math.isnan(value) else f'{value:.{digits}f}'


def _percent(value: float) -> str:
    return 'n/a' if math.isnan(value) else f'{100 * value:.2f} %'


def headline_rows(result: EvaluationResult) -> list[list[str]]:
    """Method, recall, false obstacles, median error, collisions, falls, goals reached."""
    rows = []
    for name, method in result.methods.items():
        loop = method.closed_loop
        rows.append(
            [
                name,
                _fmt(method.scan.recall),
                _fmt(method.scan.recall_near),
                _percent(method.scan.false_obstacle_rate),
                _fmt(method.scan.median_error),
                f'{loop.collisions}/{loop.trials}' if loop else '-',
                f'{loop.falls}/{loop.trials}' if loop else '-',
                f'{loop.reached}/{loop.trials}' if loop else '-',
            ]
        )
    return rows


HEADERS = [
    'method',
    'recall (low, in view <= 3 m)',
    'all-around recall (low, <= 1 m of footprint)',
    'false obstacles (% of slots)',
    'median error (m)',
    'collisions',
    'falls',
    'goals reached',
]


# The terminal's headers: short enough that the table fits 80 columns (report.md has HEADERS).
SHORT_HEADERS = [
    'method',
    'recall in view',
    'recall all-around',
    'false obstacles',
    'median error (m)',
    'collisions',
    'falls',
    'goals',
]


def method_definitions(result: EvaluationResult) -> list[str]:
    """`name: what it is` for every method in the result (each table row's meaning)."""
    return [f'{name}: {method.description}' for name, method in result.methods.items()]


def table(result: EvaluationResult) -> Table:
    """The headline numbers for the terminal: within 80 columns (headers wrap, never cut),
    every method defined under it."""
    view = TextTable(
        title='scanfuse evaluation: headline numbers',
        caption='\n'.join(method_definitions(result)),
        caption_justify='left',
    )
    for header in SHORT_HEADERS:
        view.add_column(
            header,
            justify='left' if header == 'method' else 'right',
            no_wrap=header == 'method',
            overflow='fold',
        )
    for row in headline_rows(result):
        style = 'bold' if row[0] == 'obstacle' else None
        view.add_row(*row, style=style)
    return view


def _markdown_table(headers: list[str], rows: list[list[str]]) -> str:
    lines = ['| ' + ' | '.join(headers) + ' |', '|' + '---|' * len(headers)]
    lines += ['| ' + ' | '.join(row) + ' |' for row in rows]
    return '\n'.join(lines)


def timing_note(settings: dict[str, Any]) -> str:
    """The sensor rates and latencies the evaluation ran with, in one paragraph."""
    from scanfuse.sim.sensors import lidar_profile  # noqa: PLC0415

    lidar = lidar_profile(settings.get('lidar', 'rplidar-a2'))
    sweep = 1.0 / lidar.rate
    increment = sweep * abs(lidar.angle_increment) / (2 * math.pi)
    rate = settings.get('depth_rate', float('nan'))
    latency = settings.get('depth_latency', float('nan'))
    return (
        f'Sensor timing (simulated, real time): LiDAR {lidar.name} at {lidar.rate:g} Hz, '
        f'a rotating sweep of {1000 * sweep:.0f} ms, beam i measured at stamp + i * '
        f'time_increment ({1e6 * increment:.1f} us, scan_time / readings), cast in '
        f'{settings.get("lidar_chunks", "?")} chunks per sweep, the scan stamped with its first '
        f'beam and delivered at the end of the sweep; depth camera at {rate:g} Hz, stamped at '
        f'exposure and delivered {1000 * latency:.0f} ms later; wheel odometry (not ground '
        f'truth) at {settings.get("odometry_rate", 50.0):g} Hz. Every fusing method runs in its '
        'own FusionStream fed as the node is (odometry, CameraInfo and images at delivery, '
        'scans at delivery, `now` = simulated delivery time, pair_wait 0: a scan pairs with '
        'the frames already delivered); `lidar` is the raw driver scan, not de-skewed. A '
        "scan's ground truth is the exact truth from the LiDAR's true pose at the scan's "
        'stamp, the instant a compensated scan describes: a raw sweep of a turning robot, '
        'or a depth frame fused without compensation, is scored against that instant too.'
    )


MEMORY_NOTE = (
    'Memory trials (`memory-turn`, `memory-slalom`, `memory-shelf`, `memory-deadend`; seeded '
    'variants): low boxes (5-15 cm, under the LiDAR plane) beside and behind the robot while '
    'it turns in place, weaves, turns back past a shelf or backs out of a dead end. The '
    'navigator keeps a Nav2-like obstacle layer on the scan it drives with (inf_is_valid, '
    'marking to 2.5 m, raytrace clearing to 3.0 m, footprint clearing: '
    'examples/nav2_scanfuse.yaml), so a low obstacle the scan stops showing is cleared by '
    'the next ray over it, as Nav2 would. All-around recall: low-obstacle slots whose true '
    "point lies within 1.0 m of the robot's footprint, in every direction; of slots the camera "
    'had shown: the same over those whose true point some depth image before the scan showed '
    '(no camera memory can hold the others). Targets for '
    '`obstacle` (with memory): all-around recall >= 0.95, false obstacles <= 0.5 % of slots, '
    'no collisions in these trials.'
)


def memory_section(result: EvaluationResult) -> list[str]:
    """The memory trials: closed loop and scan metrics per method."""
    rows = []
    for name, method in result.methods.items():
        scan, loop = method.scan_memory, method.closed_loop_memory
        if scan is None:
            continue
        rows.append(
            [
                name,
                f'{loop.collisions}/{loop.trials}' if loop else '-',
                f'{loop.reached}/{loop.trials}' if loop else '-',
                _fmt(scan.recall_near),
                str(scan.low_slots_near),
                _fmt(scan.recall_near_seen),
                _percent(1.0 - scan.low_slots_near_seen / scan.low_slots_near)
                if scan.low_slots_near
                else '-',
                _fmt(scan.recall),
                _percent(scan.false_obstacle_rate),
            ]
        )
    if not rows:
        return []
    headers = [
        'method',
        'collisions',
        'goals reached',
        'all-around recall (<= 1 m)',
        'low slots near',
        'all-around recall of slots the camera had shown',
        'near slots never shown',
        'recall in view',
        'false obstacles',
    ]
    return ['## Memory trials', '', MEMORY_NOTE, '', _markdown_table(headers, rows), '']


AMR_NOTE = (
    'The two-LiDAR AMR (`scanfuse simulate --robot amr`): a 0.5 m x 0.34 m box chassis, two '
    '270-degree LiDARs (hokuyo-ust10lx, 40 Hz, rotating sweeps, the second half a period after '
    'the first) at its front-left and rear-right corners facing forward-left and backward-right, '
    "0.30 m above the floor, and a front and a rear depth camera (the front one's model, "
    'latency and rate), fused by one FusionStream per method into a 360-degree scan in the '
    "front LiDAR's frame (`full_circle`). Trials (`amr-deadend`, seeded): the AMR starts "
    'nose-in to a dead-end bay and must back out of it, rear first, past a low box (6-14 cm) '
    'on the line behind it, then drive to a goal beside the bay. `lidar`: both LiDARs merged, '
    'no camera; `obstacle`: both LiDARs and both cameras, memory on. Recall in view: '
    'low-obstacle slots in view of either camera (<= 3 m); all-around recall: low-obstacle '
    "slots within 1.0 m of the footprint's circumscribed disc, any direction; both on the "
    "`obstacle` runs' scans. Collisions when reversing: trials whose first contact came "
    'while the robot was driving backwards.'
)
AMR_HEADERS = [
    'method',
    'recall in view (either camera)',
    'all-around recall (<= 1 m)',
    'low slots in view',
    'false obstacles',
    'collisions',
    'collisions when reversing',
    'goals reached',
]


def amr_rows(result: EvaluationResult) -> list[list[str]]:
    """Per AMR method: recall in view, all-around recall, collisions (when reversing)."""
    rows = []
    for robot in result.robots.values():
        loop = robot.closed_loop
        rows.append(
            [
                robot.method,
                _fmt(robot.scan.recall),
                _fmt(robot.scan.recall_near),
                str(robot.scan.low_slots),
                _percent(robot.scan.false_obstacle_rate),
                f'{loop.collisions}/{loop.trials}' if loop else '-',
                f'{loop.reversing_collisions}/{loop.trials}' if loop else '-',
                f'{loop.reached}/{loop.trials}' if loop else '-',
            ]
        )
    return rows


def amr_section(result: EvaluationResult) -> list[str]:
    """The AMR's trials: its rows and every trial."""
    if not result.robots:
        return []
    trials = [
        [
            o.trial,
            o.method,
            'yes' if o.collided else 'no',
            o.first_contact_kind or '-',
            'yes' if o.reversing_contact else 'no',
            'yes' if o.reached else 'no',
            _fmt(o.path_length, 2),
            _fmt(o.duration, 1),
        ]
        for robot in result.robots.values()
        for o in robot.trials
    ]
    return [
        '## Two-LiDAR AMR, reversing',
        '',
        AMR_NOTE,
        '',
        _markdown_table(AMR_HEADERS, amr_rows(result)),
        '',
        _markdown_table(
            [
                'trial',
                'method',
                'collided',
                'hit',
                'reversing',
                'reached',
                'driven (m)',
                'time (s)',
            ],
            trials,
        ),
        '',
    ]


TERRAIN_NOTE = (
    'Terrain trials (`--worlds terrain`, evaluate/terrain_trials.py), driven by the `sprung` '
    'robot: its body sits on a pitch spring over sprung drive wheels, so it pitches about '
    "3 degrees braking hard and setting off, and rocks over a ramp's foot and crest; its "
    "IMU (100 Hz) gives each trial's peak pitch. Families (seeded variants): "
    '`terrain-ramp-12` and `terrain-ramp-8`, up a 1:12 (1:8) ramp 1.2 m wide to a platform '
    '0.15 m high and down again between walls, past low boxes (6-12 cm above the ground under '
    'them) on the ramp, on the platform and beside its mouth, to a goal past the far foot; '
    '`terrain-ledge`, a 1:8 ramp with a 0.4 m ledge along its right side, the straight line to '
    'the goal crossing the yard; `terrain-sills`, doors with bevelled sills 1-2 cm high; '
    '`terrain-brake`, straight at 0.35 m/s towards a low box across the path (flat floor, or '
    "on a 1:12 ramp's platform), braking as hard as the motors allow once the driving scan "
    'shows anything within 0.35 m of the front in the path (reached: stopped 0-0.6 m short of '
    'the box); `terrain-mount`, the 1:12 ramp with the camera 2 degrees and 3 cm off the '
    'mounting its parameters and /tf_static give (all four signs). The ground truth measures '
    'heights above the ground each obstacle stands on: a ramp is floor, a box on it an '
    'obstacle. On slopes: scans taken with the LiDAR on a ramp or within 1.5 m of one. False '
    'drops as on the other worlds (a twin stream with `detect_drops: false`), on the terrain '
    'worlds without drop-offs. Every fused method takes the IMU (its tilt at each depth '
    'frame) but `obstacle-no-ground`, which also has `ground_estimate: false`: heights above '
    "the mounting's plane, as before issue 25. Targets (issue 25): `obstacle` 0 collisions, "
    '0 falls, every ramp trial reaches its goal; false obstacles on slopes <= 0.5 %.'
)
TERRAIN_HEADERS = [
    'method',
    'false obstacles on slopes',
    'false drops on slopes',
    'recall on slopes',
    'false obstacles (all terrain)',
    'collisions',
    'falls',
    'goals reached',
    'ramp goals reached',
]


def terrain_source_rows(result: EvaluationResult) -> list[list[str]]:
    """Per fusing method: its false obstacles on slopes by the source that made them, as
    shares of the slots on slopes (they add up to its false obstacles on slopes)."""
    from scanfuse.evaluate.attribution import SOURCES  # noqa: PLC0415

    rows = []
    for name, terrain in result.terrain.items():
        slots = terrain.scan_slopes.slots
        if not (terrain.slope_false_sources and slots):
            continue
        counts = [terrain.slope_false_sources.get(source, 0) for source in SOURCES]
        rows.append([name, *(_percent(n / slots) for n in counts)])
    return rows


def terrain_rows(result: EvaluationResult) -> list[list[str]]:
    """Per method: false obstacles, false drops and recall on slopes, the closed loop."""
    from scanfuse.evaluate.terrain_trials import RAMP_FAMILIES  # noqa: PLC0415

    rows = []
    for name, terrain in result.terrain.items():
        loop = terrain.closed_loop
        ramps = [
            o
            for o in result.terrain_trials
            if o.method == name and o.trial.rsplit('-', 1)[0] in RAMP_FAMILIES
        ]
        rows.append(
            [
                name,
                _percent(terrain.scan_slopes.false_obstacle_rate),
                _percent(terrain.slope_false_drop_rate),
                _fmt(terrain.scan_slopes.recall),
                _percent(terrain.scan.false_obstacle_rate),
                f'{loop.collisions}/{loop.trials}' if loop else '-',
                f'{loop.falls}/{loop.trials}' if loop else '-',
                f'{loop.reached}/{loop.trials}' if loop else '-',
                f'{sum(o.reached for o in ramps)}/{len(ramps)}' if ramps else '-',
            ]
        )
    return rows


def terrain_section(result: EvaluationResult) -> list[str]:
    """The terrain trials: per-method rows, per-family outcomes, every trial."""
    if not result.terrain:
        return []
    families: dict[tuple[str, str], list[int]] = {}
    for o in result.terrain_trials:
        counts = families.setdefault((o.trial.rsplit('-', 1)[0], o.method), [0, 0, 0, 0])
        counts[0] += 1
        counts[1] += o.collided
        counts[2] += o.fell
        counts[3] += o.reached
    per_family = [
        [family, method, f'{c[1]}/{c[0]}', f'{c[2]}/{c[0]}', f'{c[3]}/{c[0]}']
        for (family, method), c in sorted(families.items())
    ]
    trials = [
        [
            o.trial,
            o.method,
            'yes' if o.collided else 'no',
            o.first_contact_kind or '-',
            'yes' if o.fell else 'no',
            'yes' if o.reached else 'no',
            _fmt(o.final_distance, 2),
            _fmt(o.peak_pitch, 1),
            _fmt(o.duration, 1),
        ]
        for o in result.terrain_trials
    ]
    return [
        '## Terrain: ramps, a ledge beside a ramp, sills, braking, a mounting off',
        '',
        TERRAIN_NOTE,
        '',
        _markdown_table(TERRAIN_HEADERS, terrain_rows(result)),
        '',
        *_terrain_sources(result),
        _markdown_table(['family', 'method', 'collisions', 'falls', 'reached'], per_family),
        '',
        _markdown_table(
            [
                'trial',
                'method',
                'collided',
                'hit',
                'fell',
                'reached',
                'to goal (m; brake: gap to the box)',
                'peak pitch (deg)',
                'time (s)',
            ],
            trials,
        ),
        '',
    ]


SOURCES_NOTE = (
    'False obstacles on slopes by the source whose reading the fused scan took there (% of '
    "the slots on slopes; a row adds up to its false obstacles on slopes): a LiDAR's (say "
    "its plane tilted onto the floor), a camera's (its slab), or the memory's (a point "
    'remembered where nothing stands now).'
)


def _terrain_sources(result: EvaluationResult) -> list[str]:
    """The report's lines on where the false obstacles on slopes come from (none without
    a fusing method's scans on slopes)."""
    from scanfuse.evaluate.attribution import SOURCES  # noqa: PLC0415

    rows = terrain_source_rows(result)
    if not rows:
        return []
    return [
        SOURCES_NOTE,
        '',
        _markdown_table(['method', *SOURCES], rows),
        '',
    ]


def terrain_table(result: EvaluationResult) -> Table | None:
    """The terrain rows as a rich table for the terminal (None: no terrain trial was run)."""
    if not result.terrain:
        return None
    view = Table(title='scanfuse evaluation: terrain (ramps, ledge, sills, braking, mounting)')
    for header in TERRAIN_HEADERS:
        view.add_column(header, justify='left' if header == 'method' else 'right')
    for row in terrain_rows(result):
        view.add_row(*row, style='bold' if row[0] == 'obstacle' else None)
    return view


def amr_table(result: EvaluationResult) -> Table | None:
    """The AMR's rows as a rich table for the terminal (None: no AMR trial was run)."""
    if not result.robots:
        return None
    view = Table(title='scanfuse evaluation: two-LiDAR AMR, reversing')
    for header in AMR_HEADERS:
        view.add_column(header, justify='left' if header == 'method' else 'right')
    for row in amr_rows(result):
        view.add_row(*row, style='bold' if row[0] == 'obstacle' else None)
    return view


def markdown(result: EvaluationResult) -> str:
    """report.md: what was run, the headline table, per-kind recall, maps, trials, figures."""
    from scanfuse.evaluate.closed_loop import TURNING_TRIALS  # noqa: PLC0415

    settings = result.settings
    turning = [
        TURNING_TRIALS[name] for name in settings.get('turning', ()) if name in TURNING_TRIALS
    ]
    turns = ', '.join(f'`{t.label}` ({t.description})' for t in turning)
    parts = [
        '# scanfuse evaluation',
        '',
        (
            f'Worlds: {", ".join(settings["worlds"])}; {settings["trials"]} seeded clutter worlds; '
            f'turning trials: {turns or "none"}; '
            f'depth {settings["resolution"][0]}x{settings["resolution"][1]}; '
            f'noise {"on" if settings["noise"] else "off"}. Tolerance {TOLERANCE_ABSOLUTE} m + '
            f'{100 * TOLERANCE_RELATIVE:.0f} % of the range. Scan metrics are measured on the '
            'scans of the `obstacle` closed-loop runs and of the turning trials (scripted: no '
            'method steers them), every method on the same scans.'
        ),
        '',
        timing_note(settings),
        '',
        *(
            [
                (
                    f'{result.retried} trial(s) ran again on another worker after theirs died '
                    '(Ray cluster); every trial is counted once.'
                ),
                '',
            ]
            if result.retried
            else []
        ),
        '## Headline',
        '',
        _markdown_table(HEADERS, headline_rows(result)),
        '',
        'Methods (every name in this report):',
        '',
        *(
            f'- `{line.split(": ", 1)[0]}`: {line.split(": ", 1)[1]}'
            for line in method_definitions(result)
        ),
        '',
        (
            'The `obstacle-nearest` variants keep the nearest point of each slot; `obstacle` keeps '
            'the farthest of the nearest points that agree (`obstacle_min_points`), so a lone '
            'noisy pixel is outvoted: a nearest-point method can find more low-obstacle slots '
            'in view and pays in false obstacles (compare their columns).'
        ),
        '',
        (
            f'Targets for `obstacle`: recall >= {HEADLINE_TARGETS["recall"]}, false obstacles '
            f'<= {100 * HEADLINE_TARGETS["false_obstacle_rate"]} % of slots, no collisions, '
            'no falls. A fall is a trial in which the base sank more than '
            f'{FALL_DEPTH * 100:.0f} cm below where it settled on the floor (it left the floor '
            'plane at a ledge, a stair or a hole); the run ends 1 s later.'
        ),
        '',
        '## Scan metrics per method',
        '',
    ]
    kinds = sorted({k for m in result.methods.values() for k in m.scan.recall_by_kind})
    rows = []
    for name, method in result.methods.items():
        scan = method.scan
        rows.append(
            [
                name,
                str(scan.low_slots),
                _fmt(scan.recall),
                _fmt(scan.recall_all),
                _percent(scan.false_obstacle_rate),
                _fmt(scan.median_error),
                _fmt(scan.p95_error),
                *(_fmt(scan.recall_by_kind.get(k, float('nan')), 2) for k in kinds),
            ]
        )
    headers = [
        'method',
        'low slots in view',
        'recall in view',
        'recall all',
        'false obstacles',
        'median error (m)',
        'p95 error (m)',
        *(f'recall {k}' for k in kinds),
    ]
    parts += [_markdown_table(headers, rows), '']
    parts += [
        '## Motion compensation per method',
        '',
        (
            "What each method's streams did with the scored scans: fused with a depth frame, "
            "of those moved to the scan's stamp through odometry, LiDAR sweeps de-skewed, and "
            'scans passed through without the camera.'
        ),
        '',
    ]
    rows = [
        [
            name,
            *(str(m.stream.get(key, 0)) for key in STREAM_KEYS),
        ]
        for name, m in result.methods.items()
        if m.stream
    ]
    parts += [_markdown_table(['method', *STREAM_KEYS], rows), '']
    parts += [
        '## False drop slots per method',
        '',
        DROPS_NOTE,
        '',
        _markdown_table(
            ['method', 'slots (worlds without drops)', 'false drop slots', 'share'],
            [
                [
                    name,
                    str(m.drop_free_slots) if m.drop_free_slots else '-',
                    str(m.false_drop_slots) if m.drop_free_slots else '-',
                    _percent(m.false_drop_rate),
                ]
                for name, m in result.methods.items()
            ],
        ),
        '',
    ]
    parts += ['## Scan metrics per world and turning trial', '']
    worlds = sorted({w for m in result.methods.values() for w in m.scan_by_world})
    rows = [
        [
            name,
            world,
            _fmt(m.scan_by_world[world].recall),
            _percent(m.scan_by_world[world].false_obstacle_rate),
            _fmt(m.scan_by_world[world].median_error),
            _fmt(m.scan_by_world[world].p95_error),
        ]
        for world in worlds
        for name, m in result.methods.items()
        if world in m.scan_by_world
    ]
    parts += [
        _markdown_table(
            ['method', 'world', 'recall', 'false obstacles', 'median error (m)', 'p95 error (m)'],
            rows,
        ),
        '',
    ]
    parts += [
        '## Maps (true poses) against the true footprints',
        '',
        MAPS_NOTE,
        '',
    ]
    rows = [
        [name, label, _fmt(a.precision), _fmt(a.recall), _fmt(a.iou)]
        for name, m in result.methods.items()
        for label, a in m.maps.items()
    ]
    parts += [_markdown_table(['method', 'trial', 'precision', 'recall', 'IoU'], rows), '']
    parts += memory_section(result)
    parts += amr_section(result)
    parts += terrain_section(result)
    parts += ['## Closed-loop trials', '']
    rows = [
        [
            o.trial,
            o.method,
            'yes' if o.collided else 'no',
            o.first_contact_kind or '-',
            'yes' if o.fell else 'no',
            'yes' if o.reached else 'no',
            _fmt(o.path_length, 2),
            _fmt(o.duration, 1),
        ]
        for o in result.trials
    ]
    parts += [
        _markdown_table(
            ['trial', 'method', 'collided', 'hit', 'fell', 'reached', 'driven (m)', 'time (s)'],
            rows,
        ),
        '',
    ]
    parts += ['## Files', '']
    parts += [f'- `{name}`' for name in result.files]
    parts += ['']
    return '\n'.join(parts)


# ---------------------------------------------------------------- figures


def write_figures(evaluation: Evaluation, out: Path) -> list[str]:
    files = []
    for label, snapshot in evaluation.snapshots.items():
        files.append(_scan_figure(evaluation, label, out).name)
        del snapshot
    for label, map_set in evaluation.maps.items():
        files.append(_maps_figure(label, map_set, out).name)
    for label, map_set in evaluation.crash_maps.items():
        files.append(
            _maps_figure(
                label,
                map_set,
                out,
                suffix='_lidar_run',
                title=f"{label}: the LiDAR-only robot's drive, mapped with its scans and fused",
            ).name
        )
    files.append(_bars_figure(evaluation, out).name)
    if evaluation.terrain_specs:
        files.append(_terrain_figure(evaluation, out).name)
        if evaluation.terrain.pitch:
            path = out / 'terrain_pitch.png'
            files.append(figures.pitch_figure(evaluation.terrain.pitch, path).name)
    for label, costmaps in evaluation.costmaps.items():
        files.append(_costmap_figure(label, costmaps, out).name)
    for label, entry in evaluation.collision_logs.items():
        if entry[2].collided:
            files.append(_collision_figure(label, entry, out).name)
            break
    return files


def _costmap_figure(label: str, entry: CostmapSet, out: Path) -> Path:
    from scanfuse.evaluate.costmap_figure import costmaps_figure  # noqa: PLC0415

    names = {
        'obstacle': 'obstacle (memory on)',
        'obstacle-no-memory': 'obstacle-no-memory',
        'lidar': 'lidar',
    }
    panels = [(names.get(name, name), costmap) for name, costmap in entry.costmaps.items()]
    return costmaps_figure(
        panels,
        entry.world.obstacles,
        (*entry.robot, 0.18),
        f'{label}: Nav2-like costmap (true poses) after the turn, per scan the robot was given',
        out / f'costmap_{label}.png',
    )


def _view(
    world: World, title: str, *, x: float, y: float, yaw: float, radius: float
) -> figures.WorldView:
    return figures.WorldView(
        title=title,
        footprints=[
            *((o.kind, o.footprint) for o in world.obstacles),
            *((d.kind, d.footprint) for d in world.drops),
        ],
        bounds=world.bounds,
        robot_xy=(x, y),
        robot_yaw=yaw,
        robot_radius=radius,
    )


def _scan_figure(evaluation: Evaluation, label: str, out: Path) -> Path:
    from scanfuse.evaluate.closed_loop import evaluation_world  # noqa: PLC0415

    snapshot = evaluation.snapshots[label]
    frame = snapshot.frame
    world_name, seed = label.rsplit('-', 1)
    world = evaluation_world(world_name, int(seed))
    origin = frame.origin[:2]
    view = _view(
        world,
        f'{world_name}: LiDAR scan (red) and fused obstacle scan (blue), robot '
        f'{FIGURE_GAP_DROP if world.drops else FIGURE_GAP}',
        x=frame.pose.x,
        y=frame.pose.y,
        yaw=frame.pose.yaw,
        radius=0.18,
    )
    layers = [
        figures.ScanLayer(
            'fused (obstacle)',
            snapshot.scans['obstacle'],
            figures.FUSED_COLOR,
            origin,
            frame.lidar_yaw,
            14.0,
        )
        if 'obstacle' in snapshot.scans
        else None,
        figures.ScanLayer(
            'LiDAR /scan', frame.scan, figures.LIDAR_COLOR, origin, frame.lidar_yaw, 4.0
        ),
    ]
    path = out / f'scans_{world_name}.png'
    return figures.world_scans_figure(view, [layer for layer in layers if layer], path)


FIGURE_GAP = '1 m before the obstacle'
FIGURE_GAP_DROP = '1 m before the edge'


def _extent(spec: GridSpec) -> tuple[float, float, float, float]:
    x0, y0 = spec.origin
    return (x0, x0 + spec.width * spec.resolution, y0, y0 + spec.height * spec.resolution)


def _maps_figure(
    label: str,
    map_set: MapSet,
    out: Path,
    *,
    suffix: str = '',
    title: str = '',
) -> Path:
    panels = [
        (f'{name}: {label}', map_set.grids[name].probability())
        for name in ('lidar', 'obstacle')
        if name in map_set.grids
    ]
    return figures.maps_figure(
        panels,
        map_set.truth,
        _extent(map_set.spec),
        out / f'maps_{label}{suffix}.png',
        title=title or f'{label}: LiDAR-only map and fused map, the obstacle run, true poses',
        thresholds=(OCCUPIED_THRESH, FREE_THRESH),
    )


def _bars_figure(evaluation: Evaluation, out: Path) -> Path:
    return metrics_figure(evaluation.result([]), out)


def metrics_figure(result: EvaluationResult, out: Path) -> Path:
    """`out/metrics.png`: each method's recall, false obstacles, goals and collisions (also
    from a saved `results.json`)."""
    names = list(result.methods)
    metrics = {
        'recall of low obstacles in view': [result.methods[n].scan.recall for n in names],
        'false obstacles (% of slots)': [
            100 * result.methods[n].scan.false_obstacle_rate for n in names
        ],
        'goals reached (share of trials)': [
            (loop.reached / loop.trials)
            if (loop := result.methods[n].closed_loop)
            else float('nan')
            for n in names
        ],
        'collisions (share of trials)': [
            (loop.collisions / loop.trials)
            if (loop := result.methods[n].closed_loop)
            else float('nan')
            for n in names
        ],
    }
    return figures.bars_figure(
        names, metrics, out / 'metrics.png', title='scanfuse: methods compared'
    )


def _terrain_figure(evaluation: Evaluation, out: Path) -> Path:
    """Per method on the terrain trials: false obstacles and drops and recall on slopes, and
    the share of its trials that reached their goal."""
    result = evaluation.result([])
    names = list(result.terrain)
    terrain = [result.terrain[n] for n in names]
    metrics = {
        'false obstacles on slopes (% of slots)': [
            100 * t.scan_slopes.false_obstacle_rate for t in terrain
        ],
        'false drops on slopes (% of slots)': [100 * t.slope_false_drop_rate for t in terrain],
        'recall of low obstacles on slopes': [t.scan_slopes.recall for t in terrain],
        'goals reached (share of terrain trials)': [
            (loop.reached / loop.trials) if (loop := t.closed_loop) else float('nan')
            for t in terrain
        ],
    }
    return figures.bars_figure(
        names, metrics, out / 'terrain.png', title='scanfuse: terrain trials (sprung robot)'
    )


def _collision_figure(label: str, entry: tuple[World, object, object, float], out: Path) -> Path:
    from scanfuse.evaluate.closed_loop import DriveLog, TrialOutcome  # noqa: PLC0415
    from scanfuse.evaluate.runner import odometry_world_poses  # noqa: PLC0415

    world, log, outcome, _ = entry
    assert isinstance(log, DriveLog)
    assert isinstance(outcome, TrialOutcome)
    spec = GridSpec.covering(world.bounds, 0.05, margin=0.3)
    true_map, odom_map = OccupancyGrid(spec), OccupancyGrid(spec)
    believed = odometry_world_poses(world, log)
    for record, (x, y, yaw) in zip(log.frames, believed, strict=True):
        frame = record.lidar
        true_map.integrate(frame.scan, frame.origin[0], frame.origin[1], frame.lidar_yaw)
        odom_map.integrate(frame.scan, x, y, yaw)
    from scanfuse.evaluate.mapping import rasterize_footprints  # noqa: PLC0415

    truth = rasterize_footprints(
        spec, [o.footprint for o in world.obstacles if o.overlaps_slab(0.03, 0.5)]
    )
    contact = log.contacts[0].position[:2] if log.contacts else None
    end_true = log.frames[-1].lidar.pose
    end_odom = believed[-1]
    drift = math.hypot(end_true.x - end_odom[0], end_true.y - end_odom[1])
    marks = [('first contact', (float(contact[0]), float(contact[1])))] if contact else []
    return figures.maps_figure(
        [
            ('LiDAR only, true poses', true_map.probability()),
            (
                f'LiDAR only, wheel odometry (drift {drift:.2f} m at the end)',
                odom_map.probability(),
            ),
        ],
        truth,
        _extent(spec),
        out / f'map_after_collision_{label}.png',
        title=f'{label}: map after the LiDAR-only robot hits the {outcome.first_contact_kind}',
        thresholds=(OCCUPIED_THRESH, FREE_THRESH),
        marks=marks,
    )
