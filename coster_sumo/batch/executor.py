"""The one executor for everything parallel: regressions, evaluations, dataset simulation.

:func:`execute` runs :class:`Task` s (a top-level function and a JSON-able payload) with at most
``workers`` at a time, **one fresh process per task** (libsumo holds one simulation per process,
docs/sumo.md §6), each under a wall-clock timeout. A task that raises, hangs past its timeout, or
kills its process (a SUMO segfault) becomes one failed :class:`Outcome` with the reason; the batch
goes on. Each local task gets its own temporary folder (``tempfile`` and ``TMPDIR`` point into
it), removed when the task ends however it ends: a task killed by a timeout or a crash leaves no
scratch files behind; folders of a batch that was itself killed are removed by the next batch.
A finished task may schedule more tasks (its ``on_done`` result), so a scene's planner
runs start as soon as its variants exist. ``executor="ray"`` runs the same functions on a Ray
cluster (``ray.init()`` locally when neither an address nor ``RAY_ADDRESS`` is given), each task
in a process of its own forked by a Ray worker as the local executor forks from the driver: the
worker imports the task modules once (or starts the fork server) and serves task after task,
and the timeout runs from the task's start on the worker (a task may wait in Ray's queue for a
free CPU; the clock does not run meanwhile). A task whose Ray worker or node dies
fails with a transient reason (a rerun tries it again). On Ray, workers need no disk shared with
the driver: a task names the folders of its payload it reads and writes (:attr:`Task.folders`); the
files it reads travel through Ray's object store (each file put there once), the task runs on a
private copy of those folders on the worker, and what it writes there comes back with its result
and is written into OUT by the driver.
"""

from __future__ import annotations

import dataclasses
import os
import signal
import tempfile
import time
from collections import deque
from collections.abc import Iterable
from pathlib import Path
from typing import Any

from coster_sumo.batch.local_executor import (  # noqa: F401 - re-exported: the executor's names
    DEFAULT_TIMEOUT_S,
    GENERATION_TASK_MODULES,
    LOST_ON_CLUSTER,
    SUMO_TASK_MODULES,
    ExecutorSettings,
    OnDone,
    Outcome,
    Task,
    _default_start_method,
    _execute_local,
    _import_quietly,
    _limit_threads,
    _NoProgress,
    _task_start_method,
    is_transient,
)
from coster_sumo.batch.ray_executor import _execute_ray


def execute(tasks: Iterable[Task], settings: ExecutorSettings | None = None, *,
            on_done: OnDone | None = None, quiet: bool = True, desc: str = "tasks",
            expected_total: int | None = None) -> list[tuple[Task, Outcome]]:
    """Run ``tasks`` (and whatever ``on_done`` schedules) as ``settings`` say (None: one local worker)
    and return every (task, outcome) in finish order.

    Args:
        on_done: called in this process as each task finishes; returns further tasks.
        quiet: no progress bar; ``desc``: the bar's label.
        expected_total: the progress bar's first total estimate (it grows when needed).
    """
    settings = settings or ExecutorSettings()
    pending = deque(tasks)
    finished: list[tuple[Task, Outcome]] = []
    method = _task_start_method(settings.start_method, settings.preload)
    if settings.executor == "local" and method == "fork":
        _import_quietly(settings.preload)
    progress: Any
    if quiet:
        progress = _NoProgress()
    else:
        from tqdm import tqdm

        tqdm.monitor_interval = 0  # no monitor thread in a process that forks
        progress = tqdm(total=max(expected_total or 0, len(pending)), desc=desc, unit="task", dynamic_ncols=True)

    def done(task: Task, outcome: Outcome) -> list[Task]:
        finished.append((task, outcome))
        more = list(on_done(task, outcome)) if on_done is not None else []
        # the bar's total: finished + queued (running ones are not counted: a lower bound)
        need = len(finished) + len(pending) + len(more)
        if need > progress.total:
            progress.total = need
            progress.refresh()
        return more

    try:
        if settings.log_dir is not None:
            settings.log_dir.mkdir(parents=True, exist_ok=True)
        if settings.executor == "local":
            _execute_local(pending, dataclasses.replace(settings, start_method=method), on_done=done,
                           progress=progress)
        else:
            _execute_ray(pending, workers=settings.workers, timeout=settings.timeout, on_done=done,
                         progress=progress, ray_address=settings.ray_address, preload=settings.preload)
        progress.total = len(finished)  # done: the estimate may have been high (fewer variants than asked)
        progress.refresh()
    finally:
        progress.close()  # interrupted: the bar keeps its total ("3/12 task", not "0task")
    return finished


def probe_task(payload: dict[str, Any]) -> dict[str, Any]:
    """A task for testing executors: ``mode`` = ok | error | segfault | hang | exit; ``sleep`` [s] first.
    With ``note`` (a file path) it first makes a temporary folder and writes that folder's path there.

    Returns its name, pid and the wall-clock interval [start, end] (epoch seconds) of its sleep.
    """
    if payload.get("note"):
        Path(payload["note"]).write_text(tempfile.mkdtemp(prefix="probe-"))
    start = time.time()
    time.sleep(float(payload.get("sleep", 0.0)))
    end = time.time()
    mode = payload.get("mode", "ok")
    if mode == "segfault":
        os.kill(os.getpid(), signal.SIGSEGV)
    if mode == "hang":
        time.sleep(3600)
    if mode == "error":
        raise ValueError(f"probe {payload.get('name')} failed on purpose")
    if mode == "exit":
        os._exit(3)
    return {"name": payload.get("name"), "pid": os.getpid(), "start": start, "end": end}
