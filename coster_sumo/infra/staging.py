"""This process's temporary folder for SUMO's outputs and staged configuration copies.

A command's SUMO processes write the outputs a configuration declares, and load the copies of it
the project stages, into one temporary folder per process (docs/sumo.md, the outputs sandbox). The
folder is removed when its process ends; a forked child uses its parent's, which outlives a crash of
the child. Each folder holds a lock file its process keeps locked, so the next process can tell a
dead one's folder (the lock can be taken) and remove it, however that process died.
"""

from __future__ import annotations

import atexit
import contextlib
import os
import shutil
import tempfile
from multiprocessing import util as mp_util
from pathlib import Path

_STAGING: list[Path] = []  # [this process's staging folder], made on first use
_OWNER = os.getpid()
STAGING_PREFIX = "coster-sumo-outputs-"
# Each staging folder holds this file, locked (flock) by the process that made it while it lives; the
# kernel drops the lock when that process dies, however it dies (a SIGSEGV in SUMO, SIGKILL), which
# atexit cannot see. A folder whose lock can be taken is a dead process's: the next one removes it.
# The file is locked under another name and then renamed, so it is never seen unlocked by its maker.
LOCK_NAME = ".owner.lock"
_LOCK_FD: list[int] = []


def _remove_own() -> None:
    """Remove the staging folder of this process (not one a forked parent made)."""
    if _STAGING and _OWNER == os.getpid():
        shutil.rmtree(_STAGING.pop(), ignore_errors=True)
        while _LOCK_FD:
            with contextlib.suppress(OSError):
                os.close(_LOCK_FD.pop())


def remove_dead_staging(root: Path | None = None) -> list[Path]:
    """Remove the staging folders under ``root`` (the temporary folder) that a dead process left
    (its lock file could be locked); returns them. A folder without a lock file (another version's,
    or one being made) is left alone."""
    import fcntl

    removed = []
    for folder in Path(root or tempfile.gettempdir()).glob(STAGING_PREFIX + "*"):
        lock = folder / LOCK_NAME
        try:
            if folder in _STAGING:
                continue
            fd = os.open(lock, os.O_RDWR)
        except OSError:
            continue
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:  # its process lives
            os.close(fd)
            continue
        shutil.rmtree(folder, ignore_errors=True)
        os.close(fd)
        removed.append(folder)
    return removed


def staging_folder() -> Path:
    """This process's temporary folder for outputs and staged copies (removed at its exit; a forked
    child uses its parent's, which outlives it). Making it removes those of dead processes first."""
    import fcntl

    global _OWNER
    if not _STAGING:
        remove_dead_staging()
        folder = Path(tempfile.mkdtemp(prefix=STAGING_PREFIX))
        fd = os.open(folder / f"{LOCK_NAME}.new", os.O_RDWR | os.O_CREAT, 0o600)
        fcntl.flock(fd, fcntl.LOCK_EX)  # held until this process (and its forks, which share it) ends
        os.rename(folder / f"{LOCK_NAME}.new", folder / LOCK_NAME)
        _LOCK_FD[:] = [fd]
        _STAGING[:] = [folder]
        _OWNER = os.getpid()
        atexit.register(_remove_own)
        mp_util.Finalize(None, _remove_own, exitpriority=0)  # multiprocessing children skip atexit
    return _STAGING[0]


def cleanup() -> None:
    """Remove this process's staging folder now (a forked child calls it before ``os._exit``)."""
    _remove_own()
