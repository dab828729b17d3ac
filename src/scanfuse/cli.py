"""`scanfuse` command line: thin typer commands over the API functions.

Known errors (ScanfuseError) become one clean red line and exit code 1; anything
else keeps its traceback. The commands that write a bag take SIGTERM as they take
Ctrl-C (an exception, so staging folders are removed on the way out) and exit 143.
"""

from __future__ import annotations

import importlib.util
import logging
import re
import signal
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer
from rich.console import Console
from rich.markup import escape

from scanfuse.errors import ScanfuseError

if TYPE_CHECKING:
    from collections.abc import Iterator
    from types import FrameType

    from scanfuse.ros.batch import BagOptions

app = typer.Typer(
    name='scanfuse',
    help='Depth camera + 2D LiDAR fusion for ROS 2.',
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
console = Console(stderr=True)
SIM_MODULES = frozenset({'mujoco', 'matplotlib', 'tifffile'})
# Top-level names of ROS 2's Python packages (rclpy, its own dependencies, the messages).
ROS_MODULE = re.compile(r'(rclpy|rcl_\w+|rpyutils|rosidl_\w+|\w+_msgs|\w+_interfaces)')
ROS_WAYS = (
    "pip install 'scanfuse[ros]' (ROS 2 Jazzy wheels; 'scanfuse[ros-kilted]' for Kilted), "
    'or source a ROS 2 install (source /opt/ros/DISTRO/setup.bash) and run scanfuse with its Python'
)


class Terminated(BaseException):
    """SIGTERM, raised as Ctrl-C raises KeyboardInterrupt, so every `finally` and cleanup runs.

    Not a KeyboardInterrupt: typer turns those into exit code 130 before `main` sees them.
    """

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = signum


def _raise_terminated(signum: int, _frame: FrameType | None) -> None:
    raise Terminated(signum)


@contextmanager
def terminate_as_interrupt() -> Iterator[None]:
    """SIGTERM (the default of `kill`, systemd, docker stop) as an exception while inside."""
    previous = signal.signal(signal.SIGTERM, _raise_terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


INPUT_TOPICS = ('scan_topic', 'depth_topic', 'camera_info_topic')


def topics_named_in(params: Path | None) -> dict[str, str]:
    """The input topics a parameter file names: binding for a bag as for the node (one file,
    one meaning), unlike the defaults, which only break ties among a bag's topics. An empty
    topic names none: no such sensor (a LiDARs-only or camera-only robot), as the
    configuration the file gives already says."""
    if params is None:
        return {}
    from scanfuse.config import read_ros_params  # noqa: PLC0415

    values = read_ros_params(params)
    return {
        name: topic for name in INPUT_TOPICS if isinstance(topic := values.get(name), str) and topic
    }


@contextmanager
def topics_from_file(params: Path | None, named: dict[str, str]) -> Iterator[None]:
    """A bag error about a topic the parameter file named says where the name came from."""
    try:
        yield
    except ScanfuseError as err:
        culprits = [name for name, topic in named.items() if f'topic {topic} ' in str(err)]
        if not culprits:
            raise
        flags = {'scan_topic': '--scan', 'depth_topic': '--depth'}
        flags['camera_info_topic'] = '--camera-info'
        where = ', '.join(f'{name} in {params} ({flags[name]} overrides it)' for name in culprits)
        raise type(err)(f'{err} [{where}]') from err


@app.command()
def demo(
    out: Annotated[Path, typer.Option(help='folder for the report, figures and bag')] = Path(
        'results/demo'
    ),
) -> None:
    """Run scanfuse on the embedded default and write a report with figures."""
    from scanfuse.app.demo import run_demo  # noqa: PLC0415

    run_demo(out, console=Console())


@app.command()
def bag(
    input_bag: Annotated[
        Path, typer.Argument(metavar='INPUT', help='ROS 2 bag (folder, .db3, .mcap) or ROS 1 .bag')
    ],
    output: Annotated[Path, typer.Argument(help='new ROS 2 bag folder to write')],
    params: Annotated[
        Path | None,
        typer.Option('--params', help='ROS 2 parameter file (scanfuse: ros__parameters)'),
    ] = None,
    scan: Annotated[str | None, typer.Option('--scan', help='LaserScan topic')] = None,
    depth: Annotated[str | None, typer.Option('--depth', help='depth Image topic')] = None,
    camera_info: Annotated[
        str | None, typer.Option('--camera-info', help='CameraInfo topic of the depth image')
    ] = None,
    storage: Annotated[str, typer.Option(help='output storage: mcap | sqlite3')] = 'mcap',
    overwrite: Annotated[
        bool, typer.Option('--overwrite', help='replace OUTPUT if it exists')
    ] = False,
    no_depth_scan: Annotated[
        bool, typer.Option('--no-depth-scan', help='do not write the depth scan topic')
    ] = False,
    require_tf: Annotated[
        bool, typer.Option('--require-tf', help='fail unless /tf_static gives the extrinsics')
    ] = False,
    jobs: Annotated[
        int, typer.Option('--jobs', help='many bags: bags fused in parallel processes')
    ] = 1,
    cluster: Annotated[
        str | None,
        typer.Option(
            '--cluster',
            help='many bags: one task per bag on a Ray cluster, HOST:PORT of its head, auto, or '
            "local (pip install 'scanfuse[cluster]')",
        ),
    ] = None,
    max_retries: Annotated[
        int | None,
        typer.Option('--max-retries', help='with --cluster: runs again of a bag whose worker died'),
    ] = None,
    intrinsics: Annotated[
        tuple[float, float, float, float] | None,
        typer.Option(
            metavar='FX FY CX CY',
            help="the depth camera's focal lengths and principal point, pixels (CameraInfo's "
            "K), for a bag without CameraInfo; they replace the bag's",
        ),
    ] = None,
) -> None:
    """Fuse a recorded bag: copy every message and add /scan_fused and /scan_depth.

    INPUT may name many bags: a folder of bags or a quoted glob ('runs/*.mcap'); OUTPUT is
    then a folder that gets one fused bag per input, and a table lists every bag (a failed
    one with its error; the others go on).
    """
    from scanfuse.config import FusionConfig  # noqa: PLC0415
    from scanfuse.progress import RichProgress  # noqa: PLC0415
    from scanfuse.ros.bag import Intrinsics, fuse_bag  # noqa: PLC0415
    from scanfuse.ros.batch import BagOptions, is_batch  # noqa: PLC0415

    config = FusionConfig.from_ros_params(params) if params else FusionConfig()
    named = topics_named_in(params)
    camera = Intrinsics(*intrinsics) if intrinsics is not None else None
    if is_batch(input_bag):
        options = BagOptions(
            config,
            scan or named.get('scan_topic'),
            depth or named.get('depth_topic'),
            camera_info or named.get('camera_info_topic'),
            storage,
            overwrite,
            not no_depth_scan,
            require_tf,
            camera,
        )
        _fuse_many(input_bag, output, options, jobs, cluster, max_retries)
        return
    with terminate_as_interrupt(), topics_from_file(params, named):
        report = fuse_bag(
            input_bag,
            output,
            config=config,
            scan_topic=scan or named.get('scan_topic'),
            depth_topic=depth or named.get('depth_topic'),
            camera_info_topic=camera_info or named.get('camera_info_topic'),
            storage=storage,
            overwrite=overwrite,
            write_depth_scan=not no_depth_scan,
            require_tf=require_tf,
            progress=RichProgress(unit='messages'),
            intrinsics=camera,
        )
    Console().print(report.table())


def _fuse_many(
    source: Path,
    out: Path,
    options: BagOptions,
    jobs: int,
    cluster: str | None,
    max_retries: int | None,
) -> None:
    from scanfuse.cluster import backend_of  # noqa: PLC0415
    from scanfuse.errors import BagError  # noqa: PLC0415
    from scanfuse.progress import RichProgress  # noqa: PLC0415
    from scanfuse.ros.batch import fuse_bags  # noqa: PLC0415

    backend = backend_of(jobs, cluster, max_retries)
    with terminate_as_interrupt():
        report = fuse_bags(source, out, options, backend, RichProgress(unit='bags'))
    Console().print(report.table())
    if report.retried:
        Console().print(f'{report.retried} bag run(s) repeated after a worker died')
    if report.failed:
        names = ', '.join(str(outcome.input) for outcome in report.failed)
        msg = f'{len(report.failed)} of {len(report.outcomes)} bags failed: {names} (see the table)'
        raise BagError(msg)


LISTEN_DEFAULT = '/scan_fused'


@app.command()
def play(
    input_bag: Annotated[
        Path,
        typer.Argument(metavar='BAG', help='ROS 2 bag (folder, .db3, .mcap) or ROS 1 .bag'),
    ],
    rate: Annotated[float, typer.Option(help='speed: 2 plays twice as fast')] = 1.0,
    loop: Annotated[bool, typer.Option('--loop', help='play again and again until Ctrl-C')] = False,
    topic: Annotated[
        list[str] | None, typer.Option('--topic', help='play only this topic (repeatable)')
    ] = None,
    start: Annotated[float, typer.Option(help='start this many seconds into the bag')] = 0.0,
    listen: Annotated[
        bool,
        typer.Option(
            '--listen',
            help=f'wait for the node, then count what it publishes on {LISTEN_DEFAULT} '
            '(rate, latency) and print it at the end',
        ),
    ] = False,
    listen_to: Annotated[
        list[str] | None,
        typer.Option('--listen-to', help='listen to this topic instead (repeatable)'),
    ] = None,
    wait: Annotated[float, typer.Option(help='seconds to wait for the node with --listen')] = 30.0,
) -> None:
    """Publish a recording on ROS 2 topics at its recorded pace, each with its recorded QoS."""
    with ros_needed('play'):
        from scanfuse.ros.play import PlayOptions, play_bag  # noqa: PLC0415
    listened = list(listen_to or ([LISTEN_DEFAULT] if listen else []))
    options = PlayOptions(
        rate=rate, loop=loop, topics=tuple(topic or ()), start=start, listen=listened, wait=wait
    )
    with terminate_as_interrupt():
        report = play_bag(input_bag, options, say=lambda line: console.print(escape(line)))
    for line in report.lines():
        typer.echo(line)


@app.command()
def calibrate(
    input_bag: Annotated[
        Path,
        typer.Argument(metavar='BAG', help='ROS 2 bag (folder, .db3, .mcap) or ROS 1 .bag'),
    ],
    params: Annotated[
        Path | None,
        typer.Option(
            '--params',
            help='parameter file: the LiDAR mounting and the camera mounting to start from',
        ),
    ] = None,
    out: Annotated[
        Path, typer.Option('--out', help='folder for calibration.yaml, .json and .png')
    ] = Path('results/calibrate'),
    scan: Annotated[str | None, typer.Option('--scan', help='LaserScan topic')] = None,
    depth: Annotated[str | None, typer.Option('--depth', help='depth Image topic')] = None,
    camera_info: Annotated[
        str | None, typer.Option('--camera-info', help='CameraInfo topic of the depth image')
    ] = None,
) -> None:
    """Estimate the depth camera's mounting (floor: height, pitch, roll; LiDAR: yaw, x, y)."""
    from scanfuse.config import FusionConfig  # noqa: PLC0415
    from scanfuse.ros.calibration import calibrate_bag, save_calibration  # noqa: PLC0415

    config = FusionConfig.from_ros_params(params) if params else FusionConfig()
    named = topics_named_in(params)
    with topics_from_file(params, named):
        found = calibrate_bag(
            input_bag,
            config=config,
            scan_topic=scan or named.get('scan_topic'),
            depth_topic=depth or named.get('depth_topic'),
            camera_info_topic=camera_info or named.get('camera_info_topic'),
        )
    output = Console()
    for table in found.tables():
        output.print(table)
    typer.echo(found.parameters_yaml(), nl=False)
    for line in found.commands():
        typer.echo(line)
    written = save_calibration(found, out)
    output.print(f'written: {", ".join(str(path) for path in written)}')


@app.command()
def params(
    output: Annotated[
        Path | None, typer.Option('--output', help='write the table here instead of printing it')
    ] = None,
) -> None:
    """The parameter table (docs/parameters.md): every parameter, default, range, unit."""
    from scanfuse.ros.params import parameters_markdown  # noqa: PLC0415

    text = parameters_markdown()
    if output is None:
        typer.echo(text, nl=False)
    else:
        output.write_text(text, encoding='utf-8')


@app.command()
def simulate(
    out: Annotated[Path, typer.Option('--out', help='bag to write: NAME.mcap file or folder')],
    world: Annotated[
        str,
        typer.Option(
            help='room | bookshelf | barricade | clutter | ledge | stairs | hole | ramp-12 | '
            'ramp-8 | ramp-ledge | sills'
        ),
    ] = 'bookshelf',
    path: Annotated[
        str, typer.Option(help='scripted drive: straight | rotate | rotate-fast | arc | lap')
    ] = 'straight',
    duration: Annotated[float, typer.Option(help='simulated seconds')] = 20.0,
    seed: Annotated[int, typer.Option(help='world layout and sensor noise seed')] = 0,
    lidar: Annotated[
        str | None,
        typer.Option(help="rplidar-a2 | hokuyo-ust10lx (default: the robot's)"),
    ] = None,
    camera: Annotated[str, typer.Option(help='depth camera profile')] = 'd435',
    resolution: Annotated[str, typer.Option(help='depth image WIDTHxHEIGHT')] = '640x480',
    robot: Annotated[
        str,
        typer.Option(
            help='default (one 360-degree LiDAR, a front camera) | amr (two 270-degree LiDARs '
            'at opposite corners, a front and a rear camera; topics as '
            'examples/scanfuse_multi.yaml names them) | sprung (default on a suspension: its body '
            'pitches braking and on ramps; worlds ramp-12, ramp-8, ramp-ledge, sills)'
        ),
    ] = 'default',
    depth_rate: Annotated[
        float | None, typer.Option(help='depth images per second (default: the camera rate)')
    ] = None,
    depth_latency: Annotated[
        float, typer.Option(help='seconds from a depth exposure to its delivery (log time)')
    ] = 0.040,
    no_noise: Annotated[bool, typer.Option('--no-noise', help='perfect sensors')] = False,
    depth_backend: Annotated[
        str,
        typer.Option(help='auto (renderer where headless GL works) | multiray (no GL) | renderer'),
    ] = 'auto',
    snapshot: Annotated[
        Path | None, typer.Option(help='PNG of the world from above with the first scans')
    ] = None,
    params: Annotated[
        Path | None,
        typer.Option(help='scanfuse parameter file: the sensors are mounted as it says'),
    ] = None,
    lidar_height: Annotated[
        float | None, typer.Option(help='LiDAR height above the floor, m')
    ] = None,
    camera_height: Annotated[
        float | None, typer.Option(help='camera height above the floor, m')
    ] = None,
    camera_pitch: Annotated[
        float | None, typer.Option(help='camera pitch, radians, positive looks down')
    ] = None,
) -> None:
    """Simulate a robot in an indoor world and record its sensors and ground truth as a bag.

    The mounting and the topics come from --params (the same file the node and `scanfuse
    bag` read), then the flags; radians throughout.
    """
    from scanfuse.sim.headless_gl import choose_headless_gl  # noqa: PLC0415

    if depth_backend != 'multiray':
        choose_headless_gl()
    from scanfuse.sim.cli import (  # noqa: PLC0415
        mounting_from_params,
        run_simulate,
        topics_from_params,
    )

    mounting = mounting_from_params(params) if params is not None else {}
    topics = topics_from_params(params) if params is not None else {}
    flags = {'lidar_height': lidar_height, 'camera_height': camera_height}
    flags['camera_pitch'] = camera_pitch
    mounting.update({name: value for name, value in flags.items() if value is not None})
    with terminate_as_interrupt():
        run_simulate(
            out=out,
            world=world,
            path=path,
            duration=duration,
            seed=seed,
            lidar=lidar,
            camera=camera,
            resolution=resolution,
            depth_rate=depth_rate,
            depth_latency=depth_latency,
            noise=not no_noise,
            depth_backend=depth_backend,
            snapshot=snapshot,
            mounting=mounting,
            console=Console(),
            robot=robot,
            topics=topics,
        )


@app.command()
def evaluate(
    out: Annotated[Path, typer.Option('--out', help='folder for report.md, results.json, figures')],
    quick: Annotated[
        bool, typer.Option('--quick', help='small run: 2 clutter worlds, low resolution')
    ] = False,
    worlds: Annotated[
        str | None,
        typer.Option(
            help='comma-separated: bookshelf,barricade,clutter,room,ledge,stairs,hole,memory,'
            'terrain (ramps, a ledge beside a ramp, sills, braking, a mounting off)'
        ),
    ] = None,
    trials: Annotated[int | None, typer.Option(help='seeded clutter worlds (closed loop)')] = None,
    terrain_trials: Annotated[
        int | None,
        typer.Option(
            '--terrain-trials',
            help='seeded variants of each terrain family (default 5; 1 with --quick): more '
            'narrow the spread of the terrain numbers',
        ),
    ] = None,
    jobs: Annotated[
        int, typer.Option('--jobs', help='trials run in parallel processes (results as serial)')
    ] = 1,
    params: Annotated[
        Path | None,
        typer.Option(
            help='scanfuse parameter file: the robot mounted and every method based on it'
        ),
    ] = None,
    cluster: Annotated[
        str | None,
        typer.Option(
            '--cluster',
            help='run every trial as a task on a Ray cluster: HOST:PORT of its head, auto, or '
            "local (pip install 'scanfuse[cluster]'); replaces --jobs",
        ),
    ] = None,
    max_retries: Annotated[
        int | None,
        typer.Option(
            '--max-retries', help='with --cluster: runs again of a trial whose worker died'
        ),
    ] = None,
    sweep: Annotated[
        list[str] | None,
        typer.Option(
            '--sweep',
            help='NAME=V1,V2: evaluate every combination of these fusion parameter values on '
            'the same trials (repeat for more parameters); writes sweep.md, .json, .png',
        ),
    ] = None,
    score: Annotated[
        list[str] | None,
        typer.Option(
            '--score',
            help='also score this method on the same scans, without driving: a method, or a '
            "fusing one with parameters changed, e.g. 'obstacle[memory_scan_matching=false]' "
            '(repeat for more)',
        ),
    ] = None,
) -> None:
    """Measure every method: scan metrics, maps, closed-loop collisions; write a report.

    With --params the simulated robot is mounted as the file says (radians throughout), its
    slab is the file's, and every method changes only what defines it (e.g. `row` sets the
    method) on top of the file's values; `scanfuse.yaml` in --out records what was used.
    With --sweep every combination of the values runs on the same trials instead, and
    --out holds the comparison (sweep.md, sweep.json, sweep.png). A method given to --score
    is scored on the scans of the drives the others make: a change measured on the same
    drives, without the closed loop's chance.
    """
    from scanfuse.evaluate.cli import run_evaluate  # noqa: PLC0415

    run_evaluate(
        out,
        quick=quick,
        worlds=worlds,
        trials=trials,
        terrain_trials=terrain_trials,
        console=Console(),
        jobs=jobs,
        params=params,
        cluster=cluster,
        max_retries=max_retries,
        sweeps=sweep or (),
        scored=score or (),
    )


# The node parses these itself (scanfuse.ros.node); listed here so --help shows them.
NODE_OPTIONS_HELP = (
    '--foxglove [PORT]: serve a Foxglove live view on PORT (default 8765; 0: any free port). '
    '--foxglove-host HOST: the address it listens on (default 127.0.0.1: this machine only).'
)


@app.command(
    context_settings={'allow_extra_args': True, 'ignore_unknown_options': True},
    epilog=NODE_OPTIONS_HELP,
)
def node(
    ctx: typer.Context,
    params_file: Annotated[
        Path | None,
        typer.Option('--params-file', help='ROS 2 parameter file (scanfuse: ros__parameters)'),
    ] = None,
) -> None:
    """Run the live ROS 2 node; ROS arguments follow --ros-args (-r remaps, -p name:=value)."""
    with ros_needed('the live node'):
        from scanfuse.ros.node import main as node_main  # noqa: PLC0415
    if importlib.util.find_spec('tf2_msgs') is None:
        # The node still runs: the mounting then comes from the parameters, not from TF.
        warning = (
            'tf2_msgs is not installed, so the camera and LiDAR mounting comes from the '
            'camera_*/lidar_* parameters, not /tf_static and /tf; get it from a sourced ROS 2 '
            "install, or build it into this environment: pip install -e '.[rosbuild]' "
            '&& python tools/build_tf2_msgs.py'
        )
        console.print(f'[bold yellow]warning:[/] {escape(warning)}', soft_wrap=True)
    args = ['--params-file', str(params_file)] if params_file else []
    code = node_main([*args, *ctx.args])
    if code:
        raise typer.Exit(code)


def node_entry() -> int:
    """`ros2 run scanfuse scanfuse_node ARGS`, the colcon package's executable: `scanfuse node`."""
    sys.argv[0] = 'scanfuse'  # the usage line names the command it runs: `scanfuse node`
    return main(['node', *sys.argv[1:]])


@contextmanager
def ros_needed(what: str) -> Iterator[None]:
    """Imports inside need ROS 2 for Python: a missing ROS module is one clean line and exit
    1 saying how to get it; any other missing module is the bug it is."""
    try:
        yield
    except ModuleNotFoundError as err:
        missing = (err.name or '').partition('.')[0]
        if not ROS_MODULE.fullmatch(missing):
            raise
        report_error(f'{missing} is not installed; {what} needs ROS 2 for Python: {ROS_WAYS}')
        raise typer.Exit(1) from None


def report_error(message: str) -> None:
    """One red line, unwrapped, with the message's own brackets shown as they are."""
    console.print(f'[bold red]error:[/] {escape(message)}', soft_wrap=True)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `scanfuse` command; returns the exit code."""
    logging.basicConfig(level=logging.INFO, format='%(levelname)s %(name)s: %(message)s')
    try:
        # Standalone mode: typer prints usage errors itself and ends with SystemExit.
        app(args=argv)
    except SystemExit as done:
        return done.code if isinstance(done.code, int) else (0 if done.code is None else 1)
    except ScanfuseError as err:
        report_error(str(err))
        return 1
    except ModuleNotFoundError as err:
        if err.name not in SIM_MODULES:
            raise
        report_error(
            f'{err.name} is not installed; the simulator, evaluation and demo need the '
            "'sim' extra: pip install 'scanfuse[sim]'"
        )
        return 1
    except Terminated as stop:
        console.print('[red]terminated[/]')
        return 128 + stop.signum
    except KeyboardInterrupt:
        console.print('[red]aborted[/]')
        return 130
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
