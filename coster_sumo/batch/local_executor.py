"""The local half of the executor (:mod:`coster_sumo.batch.executor`): tasks, their outcomes,
and running them one fresh process each on this machine, with timeouts, scratch folders and logs."""

from __future__ import annotations

import contextlib
import multiprocessing as mp
import os
import shutil
import signal
import sys
import tempfile
import time
import traceback
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from multiprocessing.connection import Connection
from multiprocessing.connection import wait as mp_wait
from pathlib import Path
from typing import Any

from coster_sumo.errors import InputError
from coster_sumo.infra.procs import die_with_parent, imports_only, one_openmp_thread_after_fork, signal_name

# modules every SUMO task needs; never torch (forking after torch has started its thread pools is unsafe)
SUMO_TASK_MODULES = ("libsumo", "coster_sumo.pipeline.scenario",
                     "coster_sumo.method.generation", "coster_sumo.sim.inject",
                     "coster_sumo.pipeline.outputs",
                     "coster_sumo.geometry.drivable", "pyarrow.parquet")
# the preload of tasks that generate scenarios: SUMO, torch and the models' code, imported by a fork
# server (coster_sumo/batch/task_imports.py) so that no task imports them again and this process
# stays free of torch
GENERATION_TASK_MODULES = ("coster_sumo.batch.task_imports",)

DEFAULT_TIMEOUT_S = 900.0  # [s] wall clock per task


@dataclass(frozen=True)
class ExecutorSettings:
    """How a batch's tasks run (:func:`coster_sumo.batch.executor.execute`), checked when made.

    Attributes:
        workers: tasks at a time.
        executor: "local" (one ``multiprocessing`` process per task) or "ray".
        timeout: [s] wall clock per task; None = unlimited.
        start_method: "fork" (default where available) or "spawn" (local executor).
        log_dir: the local executor sends each task's stdout/stderr to ``log_dir/<key>.log``.
        ray_address: Ray cluster address (default: start a local Ray instance).
        preload: modules imported here first, so that forked task processes inherit them instead of
            importing them again (about 1 s per task for the SUMO side of the package);
            :data:`GENERATION_TASK_MODULES` (torch) are imported by a fork server instead, which
            every task forks from. On Ray, each Ray worker does the same for the tasks it forks.
        threads: compute threads per task (None: the cores shared among the workers).
    """

    workers: int = 1
    executor: str = "local"
    timeout: float | None = DEFAULT_TIMEOUT_S
    start_method: str | None = None
    log_dir: Path | None = None
    ray_address: str | None = None
    preload: Sequence[str] = ()
    threads: int | None = None

    def __post_init__(self) -> None:
        if self.workers < 1:
            raise InputError(f"--workers must be >= 1, not {self.workers}")
        if self.executor not in ("local", "ray"):
            raise InputError(f"--executor must be local or ray, not {self.executor!r}")



@dataclass
class Task:
    """One unit of work: ``fn(payload)`` in its own process.

    Attributes:
        key: unique name (file names, logs, progress).
        fn: a module-level function (picklable by reference for ``spawn`` and Ray).
        payload: its single argument (plain, picklable data).
        kind: free label the caller uses to dispatch results ("plan", "run", ...).
    """

    key: str
    fn: Callable[[dict[str, Any]], Any]
    payload: dict[str, Any]
    kind: str = "task"
    folders: dict[str, tuple[str, ...]] = field(default_factory=dict)
    """Payload keys that name folders on the driver the task reads and writes, each with the names
    of the files in it the task reads. Locally the task uses the folders themselves; on Ray the
    files travel with the task and what it writes into the folders comes back (module docstring)."""


@dataclass
class Outcome:
    """What became of a task: ``ok`` with ``value``, or not with a one-line ``reason``."""

    ok: bool
    value: Any = None
    reason: str = ""
    wall_time_s: float = 0.0
    detail: str = ""  # traceback or log tail, for the log file

    def append_to_log(self, path: Path) -> None:
        """Add a failed task's traceback (or log tail) to its log file, where ``--debug`` users look."""
        if self.ok or not self.detail:
            return
        with contextlib.suppress(OSError):
            path.parent.mkdir(parents=True, exist_ok=True)
            with path.open("a") as fh:
                fh.write("\n--- batch: task failed ---\n" + self.detail)


OnDone = Callable[[Task, Outcome], Iterable[Task]]

# failures that say nothing about the input, so a plain rerun tries again: the clock, the machine's
# memory (the kernel's OOM killer sends SIGKILL) or its disk (ENOSPC, EDQUOT), a lost Ray node
LOST_ON_CLUSTER = "lost on the Ray cluster"  # a task whose worker process or node died under it
_TRANSIENT_MARKS = (LOST_ON_CLUSTER, "timed out", "(SIGKILL)", "No space left on device", "Disk quota exceeded",
                    "MemoryError", "Cannot allocate memory", "[Errno 28]", "[Errno 122]", "[Errno 12]")


def is_transient(reason: str) -> bool:
    """Whether a failed task's reason is transient (the machine, not the input): a rerun retries it."""
    return any(mark in reason for mark in _TRANSIENT_MARKS)


def _limit_threads(n: int) -> None:
    """At most ``n`` compute threads in this process (torch and OpenMP/BLAS pools started later).

    Several task processes each running torch with one thread per core oversubscribe the machine:
    their threads spin-wait on each other and every task gets slower.
    """
    for var in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
        os.environ[var] = str(n)
    torch = sys.modules.get("torch")  # already imported by the parent before the fork
    if torch is not None:
        with contextlib.suppress(Exception):
            torch.set_num_threads(n)


def _child_main(fn: Callable[[dict[str, Any]], Any], payload: dict[str, Any], writer: Connection,
                log_path: str | None, threads: int | None = None, scratch: str | None = None,
                forked_from_driver: bool = True) -> None:
    """Body of a task process: run, send ("ok", value) or ("error", reason, traceback), exit hard.
    ``scratch``: the task's temporary folder (the parent removes it); on a timeout the parent asks
    for the task's Python stack (SIGUSR1), which goes to ``scratch/STACK_FILE``."""
    die_with_parent()
    if scratch is not None:
        os.environ["TMPDIR"] = scratch  # SUMO's and other child processes' temporary files too
        tempfile.tempdir = scratch
    # forked from a driver that ran torch or scikit-learn: one thread or a hang (a task from the
    # fork server, which ran neither, keeps its share of the cores)
    if forked_from_driver and one_openmp_thread_after_fork():
        threads = 1
    if threads is not None:
        _limit_threads(threads)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    import faulthandler

    faulthandler.disable()  # a crash is reported as one line by the parent, not a dump on its terminal
    if scratch is not None:  # kept open for the process's life: faulthandler writes to its descriptor
        stack = open(os.path.join(scratch, STACK_FILE), "w")  # noqa: SIM115
        faulthandler.register(signal.SIGUSR1, file=stack, all_threads=True)
    if log_path is not None:
        with contextlib.suppress(OSError):
            fd = os.open(log_path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
            sys.stdout.flush()
            sys.stderr.flush()
            os.dup2(fd, 1)
            os.dup2(fd, 2)
            os.close(fd)
            faulthandler.enable(file=2)  # the Python stack of a crash goes to the task's log
    try:
        msg: tuple[Any, ...] = ("ok", fn(payload))
    except BaseException as exc:  # noqa: BLE001 - every failure becomes a row
        msg = ("error", _one_line(exc), traceback.format_exc())
    try:
        writer.send(msg)
    except Exception as exc:  # noqa: BLE001 - e.g. an unpicklable value
        with contextlib.suppress(Exception):
            writer.send(("error", f"result could not be sent back: {_one_line(exc)}", ""))
    writer.close()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(0)  # skip atexit handlers inherited from the parent (libsumo, tqdm)


STACK_FILE = ".stack.txt"  # in a task's scratch folder: its Python stack, written on SIGUSR1


def _stack_of(r: _Running, wait_s: float = 2.0) -> tuple[str, str]:
    """A hung task's Python stack (faulthandler's dump on SIGUSR1) and, for the one-line reason,
    where its main thread was: `` in FILE:LINE (FUNCTION)``, innermost frame of the package."""
    path = Path(r.scratch) / STACK_FILE
    with contextlib.suppress(OSError):
        os.kill(r.proc.pid, signal.SIGUSR1)
    text = ""
    deadline = time.monotonic() + wait_s
    while not text and time.monotonic() < deadline:
        time.sleep(0.05)
        with contextlib.suppress(OSError):
            text = path.read_text(errors="replace")
    if text:  # faulthandler writes the dump in one go from its signal handler; let it finish
        time.sleep(0.1)
        with contextlib.suppress(OSError):
            text = path.read_text(errors="replace")
    return where_it_hung(text), text


def where_it_hung(stack: str) -> str:
    """From a faulthandler dump: the innermost frame of the thread that runs the task, in the
    package's own code where it has one (``File "…/coster_sumo/x.py", line 3 in f``)."""
    for block in stack.split("\n\n"):
        frames = [ln.strip() for ln in block.splitlines() if ln.strip().startswith("File ")]
        if not any(ln.endswith(" in _child_main") for ln in frames):
            continue
        ours = [ln for ln in frames if "/coster_sumo/" in ln and not ln.endswith(" in _child_main")]
        line = (ours or frames)[0]
        try:
            file = line.split('"')[1]
            lineno = line.split(", line ")[1].split()[0]
            func = line.rsplit(" in ", 1)[1]
        except IndexError:
            return ""
        if "/coster_sumo/" in file:
            file = "coster_sumo/" + file.rsplit("/coster_sumo/", 1)[1]
        return f" in {file}:{lineno} ({func})"
    return ""


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _log_tail(path: Path | None, lines: int = 3) -> str:
    if path is None or not path.exists():
        return ""
    with contextlib.suppress(OSError):
        noise = ("File ", "Extension modules", "Current thread", "Thread 0x", "Fatal Python error", "<no Python")
        tail = [ln.strip() for ln in path.read_text(errors="replace").splitlines()
                if ln.strip() and not ln.strip().startswith(noise)][-lines:]
        return " | ".join(tail)[-300:]
    return ""


@dataclass
class _Running:
    task: Task
    proc: Any  # multiprocessing.Process
    reader: Connection
    started: float
    log: Path | None
    scratch: str


_SCRATCH_PREFIX = "coster-task-"


def _remove_orphaned_scratch() -> None:
    """Remove the task folders of batches whose process is gone (a batch killed with SIGKILL has
    no chance to remove its own; its tasks die with it)."""
    for folder in Path(tempfile.gettempdir()).glob(f"{_SCRATCH_PREFIX}*-*"):
        owner = folder.name[len(_SCRATCH_PREFIX):].split("-", 1)[0]
        if not owner.isdigit() or int(owner) == os.getpid():
            continue
        try:
            os.kill(int(owner), 0)
        except ProcessLookupError:
            shutil.rmtree(folder, ignore_errors=True)
        except OSError:  # alive, another user's
            pass


def _driver_has_run_threads() -> bool:
    """Whether this process may have started thread pools that a forked child would inherit broken:
    torch's and scikit-learn's OpenMP pools (a child that runs them on more than one thread hangs)
    and the locks other threads may hold at the moment of the fork. The command line forks its tasks
    before it loads either; a test or a Python API user may have run both. A command that
    ``coster-sumo serve`` runs has them imported but never run (:func:`coster_sumo.infra.procs.imports_only`)."""
    return ("torch" in sys.modules or "sklearn" in sys.modules) and not imports_only()


def _default_start_method() -> str:
    """``fork`` from a driver that has run no thread pools (fast: the child inherits the imports);
    ``forkserver`` from one that has (tasks fork from a clean server process that only imported
    the task modules, so they run every library on all their threads); ``spawn`` where there is
    no fork."""
    methods = mp.get_all_start_methods()
    if "fork" not in methods:
        return "spawn"
    return "forkserver" if _driver_has_run_threads() and "forkserver" in methods else "fork"


def _task_start_method(start_method: str | None, preload: Sequence[str]) -> str:
    """How task processes start: ``start_method`` if given, else :func:`_default_start_method`, but
    from a fork server where ``preload`` holds torch (the server imports it; the process that starts
    the tasks stays free of it and forks cheaply)."""
    method = start_method or _default_start_method()
    if method == "fork" and set(preload) & set(GENERATION_TASK_MODULES) and "forkserver" in mp.get_all_start_methods():
        method = "forkserver"
    return method


def _import_quietly(modules: Sequence[str]) -> None:
    """Import ``modules`` here, so that forked tasks inherit them; quietly: libsumo prints a version
    warning about pyarrow on import."""
    import importlib
    import io

    for name in modules:
        with contextlib.suppress(Exception), contextlib.redirect_stdout(io.StringIO()), \
                contextlib.redirect_stderr(io.StringIO()):
            importlib.import_module(name)


def _execute_local(pending: deque[Task], settings: ExecutorSettings, *, on_done: OnDone, progress: Any) -> None:
    workers, timeout, log_dir, threads = settings.workers, settings.timeout, settings.log_dir, settings.threads
    preload = settings.preload
    method = settings.start_method or _default_start_method()
    ctx: Any = mp.get_context(method)
    if method == "forkserver":  # the server imports these once; every task forks from it
        ctx.set_forkserver_preload(sorted({*preload, *(t.fn.__module__ for t in pending)}))
    running: list[_Running] = []
    if threads is None:
        threads = max(1, (os.cpu_count() or 1) // max(1, workers))  # the cores shared among the workers
    _remove_orphaned_scratch()

    def finish(r: _Running, outcome: Outcome) -> None:
        running.remove(r)
        with contextlib.suppress(Exception):
            r.reader.close()
        shutil.rmtree(r.scratch, ignore_errors=True)
        pending.extend(on_done(r.task, outcome))
        progress.update(1)

    try:
        while pending or running:
            while pending and len(running) < workers:
                task = pending.popleft()
                reader, writer = ctx.Pipe(duplex=False)
                log = (log_dir / f"{task.key}.log") if log_dir is not None else None
                scratch = tempfile.mkdtemp(prefix=f"{_SCRATCH_PREFIX}{os.getpid()}-")
                proc = ctx.Process(target=_child_main, args=(task.fn, task.payload, writer,
                                                             str(log) if log else None, threads, scratch,
                                                             method == "fork"),
                                   name=f"coster-{task.key}", daemon=True)
                proc.start()
                writer.close()  # the child holds the only writer: EOF when it dies
                running.append(_Running(task, proc, reader, time.monotonic(), log, scratch))
            now = time.monotonic()
            wait_s = 1.0
            if timeout is not None:
                wait_s = max(0.01, min([wait_s] + [r.started + timeout - now for r in running]))
            mp_wait([r.reader for r in running], timeout=wait_s)
            now = time.monotonic()
            for r in list(running):
                wall = now - r.started
                if r.reader.poll():
                    try:
                        msg = r.reader.recv()
                    except (EOFError, OSError):
                        msg = None
                    r.proc.join(timeout=30)
                    if r.proc.is_alive():
                        r.proc.kill()
                        r.proc.join()
                    if msg is None:
                        code = r.proc.exitcode
                        why = (f"crashed ({signal_name(-code)})" if code is not None and code < 0
                               else f"exited with code {code} without a result")
                        tail = _log_tail(r.log)
                        finish(r, Outcome(False, reason=why + (f"; log: {tail}" if tail else ""), wall_time_s=wall))
                    elif msg[0] == "ok":
                        finish(r, Outcome(True, value=msg[1], wall_time_s=wall))
                    else:
                        finish(r, Outcome(False, reason=msg[1], wall_time_s=wall, detail=msg[2]))
                elif timeout is not None and wall > timeout:
                    where, stack = _stack_of(r)
                    r.proc.kill()
                    r.proc.join()
                    finish(r, Outcome(False, reason=f"timed out after {timeout:g} s (killed){where}",
                                      wall_time_s=wall, detail=stack))
    finally:
        for r in running:
            with contextlib.suppress(Exception):
                r.proc.kill()
                r.proc.join()
            shutil.rmtree(r.scratch, ignore_errors=True)


class _NoProgress:
    total = 0

    def update(self, n: int = 1) -> None:
        pass

    def refresh(self) -> None:
        pass

    def close(self) -> None:
        pass

