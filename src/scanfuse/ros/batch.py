"""`scanfuse bag` over many bags: a folder of bags or a glob, one fused bag per input in an
output folder, one bag per task on a local pool or a Ray cluster (`scanfuse.cluster`).

Every bag is fused by `fuse_bag`, exactly as a single run fuses it. A bag that fails is
listed with its error and the others go on; every input's files are hashed before and after
its run, and a changed input is reported as a failure (it never should be).
"""

from __future__ import annotations

import glob
import hashlib
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from scanfuse.cluster import LocalPool, run_tasks
from scanfuse.errors import BagError, ScanfuseError

if TYPE_CHECKING:
    from rich.table import Table

    from scanfuse.cluster import Backend
    from scanfuse.config import FusionConfig
    from scanfuse.progress import Progress
    from scanfuse.ros.bag import Intrinsics

BAG_SUFFIXES = ('.mcap', '.db3', '.bag')
GLOB_CHARACTERS = frozenset('*?[')


def is_batch(source: str | Path) -> bool:
    """A glob, or a folder that is not itself a ROS 2 bag (no metadata.yaml): many bags."""
    text = str(source)
    if GLOB_CHARACTERS & set(text):
        return True
    path = Path(text)
    return path.is_dir() and not (path / 'metadata.yaml').exists()


def _is_bag(path: Path) -> bool:
    if path.is_dir():
        return (path / 'metadata.yaml').exists()
    return path.suffix in BAG_SUFFIXES


def find_bags(source: str | Path) -> list[Path]:
    """The bags a glob matches, or the bags in a folder (ROS 2 bag folders, .mcap, .db3 and
    ROS 1 .bag files; not its subfolders' contents), sorted by name."""
    text = str(source)
    if GLOB_CHARACTERS & set(text):
        found = [Path(name) for name in sorted(glob.glob(text))]  # noqa: PTH207 - a user's glob
        where = f'the pattern {text!r}'
    else:
        folder = Path(text)
        if not folder.is_dir():
            msg = f'{folder} is not a folder of bags; give a folder, a glob or one bag'
            raise BagError(msg)
        found = sorted(folder.iterdir())
        where = f'the folder {folder}'
    bags = [path for path in found if _is_bag(path)]
    if not bags:
        msg = (
            f'no bags in {where} (ROS 2 bag folders, .mcap, .db3, ROS 1 .bag); '
            'check the path, and quote a glob so the shell leaves it to scanfuse'
        )
        raise BagError(msg)
    return bags


def output_name(bag: Path) -> str:
    """The fused bag's folder name: the input's, without its file suffix."""
    return bag.name if bag.is_dir() else bag.stem


def input_digest(bag: Path) -> str:
    """SHA-256 over the bag's files (a bag folder: every file, by relative path)."""
    digest = hashlib.sha256()
    files = sorted(p for p in bag.rglob('*') if p.is_file()) if bag.is_dir() else [bag]
    for path in files:
        digest.update(str(path.relative_to(bag) if bag.is_dir() else path.name).encode())
        with path.open('rb') as stream:
            for block in iter(lambda: stream.read(1 << 20), b''):
                digest.update(block)
    return digest.hexdigest()


@dataclass(frozen=True)
class BagOptions:
    """What `fuse_bag` takes besides the paths: the same for every bag of a batch."""

    config: FusionConfig
    scan_topic: str | None = None
    depth_topic: str | None = None
    camera_info_topic: str | None = None
    storage: str = 'mcap'
    overwrite: bool = False
    write_depth_scan: bool = True
    require_tf: bool = False
    intrinsics: Intrinsics | None = None  # the depth camera's, for bags without CameraInfo


@dataclass(frozen=True)
class BagOutcome:
    """One bag of a batch: where its fused bag is, or why there is none."""

    input: Path
    output: Path
    error: str | None
    digest: str  # the input's SHA-256 before its run
    messages_written: int = 0
    scans_fused: int = 0
    wall_time_s: float = 0.0

    @property
    def ok(self) -> bool:
        return self.error is None


def fuse_one(source: Path, target: Path, options: BagOptions) -> BagOutcome:
    """Fuse one bag of a batch (in a worker); its failure is returned, not raised."""
    from scanfuse.ros.bag import fuse_bag  # noqa: PLC0415

    started = time.perf_counter()
    before = input_digest(source)
    try:
        report = fuse_bag(
            source,
            target,
            config=options.config,
            scan_topic=options.scan_topic,
            depth_topic=options.depth_topic,
            camera_info_topic=options.camera_info_topic,
            storage=options.storage,
            overwrite=options.overwrite,
            write_depth_scan=options.write_depth_scan,
            require_tf=options.require_tf,
            intrinsics=options.intrinsics,
        )
    # One bag's failure of any kind is listed and the batch goes on (a bag from the field
    # may break a reader in ways no error of ours names).
    except Exception as err:  # noqa: BLE001
        kind = '' if isinstance(err, ScanfuseError) else f'{type(err).__name__}: '
        outcome = BagOutcome(source, target, f'{kind}{err}', before)
    else:
        outcome = BagOutcome(
            source,
            target,
            None,
            before,
            report.messages_written,
            report.scans_paired,
            time.perf_counter() - started,
        )
    if input_digest(source) != before:
        changed = f'the input changed during its run (SHA-256 {before[:12]}...); report this'
        return BagOutcome(source, target, changed, before)
    return outcome


@dataclass(frozen=True)
class BatchReport:
    """Every bag of a batch, in the order found, and how many runs a lost worker repeated."""

    outcomes: list[BagOutcome]
    retried: int = 0

    @property
    def failed(self) -> list[BagOutcome]:
        return [outcome for outcome in self.outcomes if not outcome.ok]

    def table(self) -> Table:
        from rich.markup import escape  # noqa: PLC0415
        from rich.table import Table  # noqa: PLC0415

        folders = {str(o.input.parent) for o in self.outcomes}
        outs = {str(o.output.parent) for o in self.outcomes}
        title = f'bags: {", ".join(sorted(folders))} -> {", ".join(sorted(outs))}'
        table = Table('input', 'output', 'messages', 'fused scans', 'seconds', title=title)
        for outcome in self.outcomes:
            if outcome.ok:
                table.add_row(
                    outcome.input.name,
                    outcome.output.name,
                    str(outcome.messages_written),
                    str(outcome.scans_fused),
                    f'{outcome.wall_time_s:.1f}',
                )
            else:
                error = escape(f'failed: {outcome.error}')
                table.add_row(outcome.input.name, f'[red]{error}[/red]', '', '', '')
        return table


def fuse_bags(
    source: str | Path,
    out: Path,
    options: BagOptions,
    backend: Backend | None = None,
    progress: Progress | None = None,
) -> BatchReport:
    """Fuse every bag `source` names (a folder or a glob) into `out`/<its name>."""
    bags = find_bags(source)
    names: dict[str, Path] = {}
    for bag in bags:
        other = names.setdefault(output_name(bag), bag)
        if other != bag:
            msg = f'{other} and {bag} would both be written to {out / output_name(bag)}; rename one'
            raise BagError(msg)
    if out.exists() and not out.is_dir():
        msg = f'output {out} exists and is not a folder; give a folder for the fused bags'
        raise BagError(msg)
    out.mkdir(parents=True, exist_ok=True)
    arguments = [(bag, out / output_name(bag), options) for bag in bags]
    if progress is not None:
        progress.start(f'{len(bags)} bags', len(bags))
    done = run_tasks(fuse_one, arguments, backend or LocalPool(), progress)
    if progress is not None:
        progress.finish()
    return BatchReport(done.results, done.retried)


__all__ = [
    'BagOptions',
    'BagOutcome',
    'BatchReport',
    'find_bags',
    'fuse_bags',
    'fuse_one',
    'input_digest',
    'is_batch',
]
