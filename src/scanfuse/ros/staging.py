"""Staging folders: an output is written beside its target in full, then renamed into place.

A run writes into `.NAME.XXXXXXXX.partial` (XXXXXXXX from `tempfile.mkdtemp`) in the folder
of its output NAME and holds an `flock` on the `.lock` file inside for as long as it runs.
The kernel drops that lock when the process ends however it ends (SIGKILL, power loss aside),
so a later run tells a folder left behind by a dead run from one a live run is still writing,
and removes only the former, and only when its contents are what a run writes: the lock file
and a `NAME/` bag folder of `metadata.yaml` and `NAME*.mcap` / `NAME*.db3` files. Anything
else, even under a matching name, is left alone.
"""

from __future__ import annotations

import errno
import fcntl
import logging
import os
import re
import shutil
import stat
import tempfile
import time
from pathlib import Path
from typing import TYPE_CHECKING, final

from scanfuse.errors import BagError

if TYPE_CHECKING:
    from types import TracebackType

logger = logging.getLogger(__name__)

SUFFIX = '.partial'
LOCK_NAME = '.lock'
# '.' + NAME + '.' + eight random characters + '.partial': room NAME leaves under NAME_MAX.
STAGING_OVERHEAD = 1 + 1 + 8 + len(SUFFIX)
# Characters of tempfile's random names (tempfile._RandomNameSequence).
_STAGING = re.compile(r'\.(?P<name>.+)\.[a-z0-9_]{8}' + re.escape(SUFFIX))
_BAG_FILE_SUFFIXES = ('.mcap', '.db3', '.db3-journal', '.db3-wal', '.db3-shm')
# A folder without a lock predates locking (or is a few microseconds old): stale only when
# nothing in it has changed for this long, so a run that is writing is never swept.
UNLOCKED_STALE_S = 300.0


@final
class Staging:
    """A locked staging folder beside `target`; stale ones of earlier runs are swept first."""

    def __init__(self, target: Path) -> None:
        self.target = target
        self.folder: Path | None = None
        self._lock_fd: int | None = None

    @property
    def output(self) -> Path:
        """Where the run writes: `<staging folder>/NAME`."""
        assert self.folder is not None
        return self.folder / self.target.name

    def __enter__(self) -> Staging:
        parent = self.target.parent
        sweep_stale(parent)
        try:
            folder = Path(
                tempfile.mkdtemp(prefix=f'.{self.target.name}.', suffix=SUFFIX, dir=parent)
            )
        except OSError as err:
            raise output_error(self.target, err) from err
        self.folder = folder
        try:
            fd = os.open(folder / LOCK_NAME, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o600)
        except OSError as err:
            shutil.rmtree(folder, ignore_errors=True)
            raise output_error(self.target, err) from err
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)  # a fresh file: nobody else holds it
        self._lock_fd = fd
        return self

    def __exit__(
        self,
        kind: type[BaseException] | None,
        error: BaseException | None,
        trace: TracebackType | None,
    ) -> None:
        # Removed while still locked, so no sweeper of another run races this removal.
        if self.folder is not None:
            shutil.rmtree(self.folder, ignore_errors=True)
        if self._lock_fd is not None:
            os.close(self._lock_fd)
            self._lock_fd = None


def output_error(target: Path, err: OSError) -> BagError:
    """One line that says why the output `target` cannot be written and what to do."""
    hints = {
        errno.ENOSPC: 'the disk is full; free space or write somewhere else',
        errno.EDQUOT: 'the disk quota is used up; free space or write somewhere else',
        errno.EFBIG: 'a file grew past the size this system allows (ulimit -f, or the '
        "filesystem's file size limit); write somewhere else",
        errno.EROFS: 'the filesystem is read-only; write somewhere else',
        errno.EACCES: 'permission denied; write to a folder you can write to',
        errno.EPERM: 'permission denied; write to a folder you can write to',
        errno.ENAMETOOLONG: 'the name is too long for this filesystem; choose a shorter name',
    }
    reason = hints.get(err.errno or 0, 'choose another output path')
    detail = err.strerror or str(err)
    msg = f'cannot write the output {target}: {detail}; {reason}'
    return BagError(msg)


def sweep_stale(parent: Path) -> list[Path]:
    """Remove the staging folders in `parent` left by runs that are no longer alive."""
    removed: list[Path] = []
    try:
        entries = list(os.scandir(parent))
    except OSError:
        return removed
    for entry in entries:
        match = _STAGING.fullmatch(entry.name)
        if match is None or not entry.is_dir(follow_symlinks=False):
            continue
        folder = Path(entry.path)
        if _remove_if_stale(folder, match['name']):
            removed.append(folder)
    return removed


def _remove_if_stale(folder: Path, name: str) -> bool:
    if not _holds_only_our_files(folder, name):
        logger.debug('leaving %s alone: it holds files scanfuse does not write', folder)
        return False
    lock = folder / LOCK_NAME
    try:
        fd = os.open(lock, os.O_RDWR | os.O_CLOEXEC | os.O_NOFOLLOW)
    except FileNotFoundError:
        if time.time() - _newest_change(folder) < UNLOCKED_STALE_S:
            return False
        fd = None
    except OSError:
        return False
    try:
        if fd is not None:
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                return False  # a live run holds it
        size = sum(p.stat().st_size for p in folder.rglob('*') if p.is_file())
        shutil.rmtree(folder, ignore_errors=True)
    finally:
        if fd is not None:
            os.close(fd)
    logger.info('removed %s (%.1f MB), left by an interrupted scanfuse run', folder, size / 1e6)
    return True


def _holds_only_our_files(folder: Path, name: str) -> bool:
    """Only `.lock` and a NAME/ folder of the files a rosbags Writer makes for NAME."""
    try:
        for entry in os.scandir(folder):
            if entry.name == LOCK_NAME and entry.is_file(follow_symlinks=False):
                continue
            if entry.name != name or not entry.is_dir(follow_symlinks=False):
                return False
            for inner in os.scandir(entry.path):
                if not stat.S_ISREG(inner.stat(follow_symlinks=False).st_mode):
                    return False
                if inner.name != 'metadata.yaml' and not (
                    inner.name.startswith(name) and inner.name.endswith(_BAG_FILE_SUFFIXES)
                ):
                    return False
    except OSError:
        return False
    return True


def _newest_change(folder: Path) -> float:
    times = [folder.stat().st_mtime]
    times += [p.stat().st_mtime for p in folder.rglob('*')]
    return max(times)
