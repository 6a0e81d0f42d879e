"""Output folders a user can trust: never destroyed unless we wrote them, replaced atomically, locked.

Every command that writes a folder goes through this module (docs/outputs.md has the contract and
the table of what each command does with an existing output):

- :func:`check_output` refuses, before any work, an output that would cost a user a file: a path
  that is a file, the working directory or a folder above it, a folder holding one of the inputs,
  or a non-empty folder that coster-sumo did not write (no :data:`MARKER`, or files the marker does
  not list). An earlier output of the same kind is replaced only when the caller allows it
  (``--overwrite``).
- :class:`OutputLock` holds an exclusive ``flock`` on a hidden lock file beside (or inside) the
  output for the whole command, so two commands never write one folder at once; the second one
  stops with one line.
- :func:`new_staging` makes the hidden folder a command writes into; :func:`publish` moves the old
  output aside, renames the staging folder in, and removes the old one last, so a kill at any
  moment leaves either the old output or the new one whole (plus hidden leftovers).
- :func:`staged_output` does the whole round for a command that replaces its output whole: check,
  lock, clean leftovers, check again under the lock, a staging folder to write into, published
  when the command's block ends and removed when it raises.
- :func:`clean_leftovers` (called with the lock held) removes what killed commands left beside
  the output, and puts an old output back where a kill came between the two renames.

Folders are made with :func:`os.mkdir`, so they get the user's umask (``tempfile.mkdtemp`` would
make them 0700).
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import json
import os
import secrets
import shutil
import time
from collections.abc import Iterable, Iterator, Sequence
from pathlib import Path
from typing import Any

from coster_sumo.errors import InputError

MARKER = ".coster-sumo.json"  # written last into every output folder a command publishes
LOCK_NAME = ".lock"  # the lock file inside an output that grows (a batch's)
STAGING_TAG = "staging"
OLD_TAG = "old"


def _resolved(path: Path) -> Path:
    return Path(os.path.abspath(path)).resolve()


def _inside(path: Path, folder: Path) -> bool:
    return path == folder or folder in path.parents


def read_marker(folder: Path) -> dict[str, Any] | None:
    """The marker of a folder coster-sumo wrote, or None (no marker, or not one of ours)."""
    try:
        doc = json.loads((folder / MARKER).read_text())
    except (OSError, ValueError):
        return None
    return doc if isinstance(doc, dict) and doc.get("tool") == "coster-sumo" else None


def _files_below(folder: Path) -> set[str]:
    return {p.relative_to(folder).as_posix() for p in folder.rglob("*") if not p.is_dir()} - {MARKER, LOCK_NAME}


def version() -> str:
    """The installed distribution's version (``unknown`` from a source tree that was never installed)."""
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as dist_version

    try:
        return dist_version("coster-sumo")
    except PackageNotFoundError:
        return "unknown"


def write_marker(folder: Path, kind: str) -> None:
    """Write :data:`MARKER` into ``folder``: who wrote it and every file it holds now."""
    doc = {"tool": "coster-sumo", "kind": kind, "version": version(),
           "written_at": time.strftime("%Y-%m-%dT%H:%M:%S"), "files": sorted(_files_below(folder))}
    (folder / MARKER).write_text(json.dumps(doc, indent=1))


def refresh_marker(folder: Path) -> None:
    """After a command added files to an output coster-sumo wrote (``export`` into a run folder):
    list them in its marker too. A folder without a marker is left as it is."""
    marker = read_marker(folder)
    if marker is not None:
        write_marker(folder, str(marker.get("kind")))


def check_output(out: Path, *, kind: str, inputs: Iterable[Path] = (), overwrite: bool = False,
                 reusable: bool = False, signature: str | None = None) -> None:
    """Raise :class:`InputError` (one line, exit code 2) where writing ``out`` could lose a user's file.

    ``kind`` names what the command writes ("run", "convert", "regress", ...). ``reusable``: the
    command adds to an earlier output of its kind (a batch that resumes, ``convert`` adding scenes)
    instead of replacing it, so such a folder is accepted without ``overwrite``. ``signature``: for
    such a command, a file that marks its outputs written before markers existed (a dataset's
    ``manifest.json``), so that they still resume.
    """
    real = _resolved(out)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: exists and is not a folder; give a folder for -o")
    cwd = _resolved(Path.cwd())
    if _inside(cwd, real):
        raise InputError(f"{out}: is the working directory or a folder above it; give a new folder for -o")
    home = _resolved(Path.home())
    if real == home or real == Path(real.anchor):
        raise InputError(f"{out}: is the home or root folder; give a new folder for -o")
    for inp in inputs:
        r = _resolved(Path(inp))
        if _inside(r, real) or (r.is_file() and r.parent == real):
            raise InputError(f"{out}: holds the input {inp}; give another folder for -o")
    if not out.is_dir() or not any(p.name != LOCK_NAME for p in out.iterdir()):
        return
    marker = read_marker(out)
    if marker is None and reusable and signature is not None and (out / signature).is_file():
        return
    if marker is None:
        raise InputError(f"{out}: exists and holds files coster-sumo did not write; give a new or empty "
                         "folder for -o")
    if marker.get("kind") != kind:
        raise InputError(f"{out}: holds the output of coster-sumo {marker.get('kind')}, not of {kind}; give "
                         "another folder for -o")
    if reusable:
        return
    foreign = sorted(_files_below(out) - set(marker.get("files", [])))
    if foreign:
        raise InputError(f"{out}: holds {foreign[0]}"
                         + (f" and {len(foreign) - 1} more file(s)" if len(foreign) > 1 else "")
                         + " that coster-sumo did not write; move them away or give another folder for -o")
    if not overwrite:
        raise InputError(f"{out}: holds an earlier coster-sumo {kind} output; give --overwrite to replace it, "
                         "or another folder for -o")


class OutputLock:
    """An exclusive lock on an output folder for the life of a command (``with OutputLock(out):``).

    The lock file is ``.<name>.lock`` beside ``out`` (``inside=False``, for outputs that are
    replaced whole) or ``out/.lock`` (``inside=True``, for outputs that grow, such as a batch's).
    A second command on the same output raises :class:`InputError` naming the holder's pid.
    """

    def __init__(self, out: Path, *, inside: bool = False, wait_s: float = 0.0) -> None:
        self.out = out
        self.path = out / LOCK_NAME if inside else out.parent / f".{out.name}.lock"
        self.wait_s = wait_s  # [s] how long to wait for another holder before giving up
        self._fd: int | None = None

    def __enter__(self) -> OutputLock:
        self.path.parent.mkdir(parents=True, exist_ok=True)
        give_up = time.monotonic() + self.wait_s
        while True:
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o666)
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as exc:
                if exc.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                    os.close(fd)
                    raise
                holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
                os.close(fd)
                if time.monotonic() < give_up:
                    time.sleep(0.05)
                    continue
                raise InputError(f"{self.out}: another coster-sumo command is writing it (pid {holder}); wait "
                                 "for it to finish or give another folder for -o") from None
            # the file may have been unlinked by the holder that just released it: lock the one on disk
            try:
                same = os.stat(self.path).st_ino == os.fstat(fd).st_ino
            except FileNotFoundError:
                same = False
            if same:
                break
            os.close(fd)
        os.ftruncate(fd, 0)
        os.pwrite(fd, str(os.getpid()).encode(), 0)
        self._fd = fd
        return self

    def __exit__(self, *exc: object) -> None:
        if self._fd is None:
            return
        with contextlib.suppress(OSError):
            os.unlink(self.path)  # while still locked: a waiting command re-checks the inode
        os.close(self._fd)
        self._fd = None


def new_staging(out: Path) -> Path:
    """A new hidden folder beside ``out`` to write into (``.<name>.staging.<pid>.<random>``)."""
    out.parent.mkdir(parents=True, exist_ok=True)
    path = out.parent / f".{out.name}.{STAGING_TAG}.{os.getpid()}.{secrets.token_hex(4)}"
    os.mkdir(path)  # the user's umask, unlike tempfile.mkdtemp
    return path


@contextlib.contextmanager
def staged_output(out: Path, *, kind: str, inputs: Iterable[Path] = (), overwrite: bool = False) -> Iterator[Path]:
    """``with staged_output(out, kind=...) as staging:`` the block writes into ``staging``, which
    becomes ``out`` when the block ends (:func:`publish`) and is removed when it raises.

    ``out`` is checked (:func:`check_output`) before the lock is taken and again under it (another
    command may have written it in between), and what killed commands left beside it is cleaned
    up; the lock is held until the output is in place.
    """
    check_output(out, kind=kind, inputs=inputs, overwrite=overwrite)
    with OutputLock(out):
        clean_leftovers(out)
        check_output(out, kind=kind, inputs=(), overwrite=overwrite)
        staging = new_staging(out)
        try:
            yield staging
            publish(staging, out, kind=kind)
        except BaseException:
            shutil.rmtree(staging, ignore_errors=True)
            raise


def _leftovers(out: Path, tag: str) -> list[Path]:
    prefix = f".{out.name}.{tag}."
    with contextlib.suppress(OSError):
        return sorted(p for p in out.parent.iterdir() if p.name.startswith(prefix))
    return []


def clean_leftovers(out: Path) -> list[str]:
    """With the output's lock held: remove staging folders of killed commands, and put back an old
    output that a kill left moved aside (or remove it where a new one is in place). Returns what
    was done, one line each."""
    done: list[str] = []
    for old in _leftovers(out, OLD_TAG):
        if not out.exists():
            os.replace(old, out)
            done.append(f"restored {out} (an earlier command was stopped while replacing it)")
        else:
            shutil.rmtree(old, ignore_errors=True)
    for staging in _leftovers(out, STAGING_TAG):
        shutil.rmtree(staging, ignore_errors=True)
        done.append(f"removed {staging.name} (left by a stopped command)")
    return done


def clean_leftovers_in(folder: Path) -> list[str]:
    """:func:`clean_leftovers` for every output inside ``folder`` (a command that stages entries
    inside its output, such as ``convert``'s scene folders); call it with the folder's lock held."""
    names = set()
    with contextlib.suppress(OSError):
        for p in folder.iterdir():
            for tag in (STAGING_TAG, OLD_TAG):
                head, sep, _ = p.name.rpartition(f".{tag}.")
                if sep and head.startswith(".") and len(head) > 1:
                    names.add(head[1:])
    return [line for name in sorted(names) for line in clean_leftovers(folder / name)]


def publish(staging: Path, out: Path, *, kind: str) -> None:
    """Make ``staging`` the output ``out``: marker in, old output aside, new one in, old one removed."""
    write_marker(staging, kind)
    old: Path | None = None
    if out.exists():
        old = out.parent / f".{out.name}.{OLD_TAG}.{os.getpid()}.{secrets.token_hex(4)}"
        os.replace(out, old)
    try:
        os.replace(staging, out)
    except OSError:
        if old is not None:
            os.replace(old, out)  # put the earlier output back
        raise
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


FULL_DISK_BYTES = 1 << 20  # [B] below this much free room, a truncated file is blamed on the disk


def raise_if_disk_full(path: Path) -> None:
    """Raise ``OSError(ENOSPC)`` naming ``path`` when its file system is (nearly) full.

    For files written by other programs: netconvert reports success after a truncated write on a
    full disk, and the half net then reads as malformed XML; this says what really happened.
    """
    try:
        st = os.statvfs(path if path.is_dir() else path.parent)
    except OSError:
        return
    if st.f_bavail * st.f_frsize < FULL_DISK_BYTES:
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))


def staged_names(folder: Path, names: Sequence[str]) -> list[Path]:
    """Hidden staging entries left inside ``folder`` by killed writes: names starting with "." that
    end in one of ``names`` (for example ``.tmp``); for commands that stage entries inside their output."""
    with contextlib.suppress(OSError):
        return [p for p in folder.iterdir() if p.name.startswith(".") and p.name.endswith(tuple(names))]
    return []
