"""The Ray half of the executor (:mod:`coster_sumo.batch.executor`): each task forked by a Ray worker
as the local executor forks it, its folders' files shipped through Ray's object store and what it
wrote brought back to the driver (no disk shared with the workers)."""

from __future__ import annotations

import contextlib
import os
import tempfile
import time
from collections import deque
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from coster_sumo.batch.local_executor import (
    LOST_ON_CLUSTER,
    ExecutorSettings,
    OnDone,
    Outcome,
    Task,
    _execute_local,
    _import_quietly,
    _NoProgress,
    _one_line,
    _task_start_method,
)
from coster_sumo.errors import InputError


def _ray_entry(fn: Callable[[dict[str, Any]], Any], payload: dict[str, Any], shipped: dict[str, dict[str, Any]],
               timeout: float | None, preload: Sequence[str] = ()) -> tuple[Outcome, dict[str, dict[str, bytes]]]:
    """On a Ray worker: the task on private copies of its folders, in a process of its own as on the
    local executor (a crash or a hang is a failed :class:`Outcome`); ``timeout`` runs from the task's
    start here, not from its submission (a task may wait in Ray's queue for a free CPU). The worker
    serves many tasks: ``preload`` is imported here once (or by a fork server) as :func:`execute`
    does for local tasks. Returns the outcome and, when it succeeded, every file the task wrote or
    changed in its folders (``{payload key: {name: bytes}}``), for the driver to write."""
    import ray

    cpus = ray.get_runtime_context().get_assigned_resources().get("CPU", 1.0)
    method = _task_start_method(None, preload)
    if method == "fork":
        _import_quietly(preload)

    def run(local: dict[str, Any]) -> Outcome:
        finished: list[Outcome] = []

        def keep(_task: Task, outcome: Outcome) -> list[Task]:
            finished.append(outcome)
            return []

        settings = ExecutorSettings(timeout=timeout, start_method=method, preload=preload, threads=max(1, int(cpus)))
        _execute_local(deque([Task("ray-task", fn, local)]), settings, on_done=keep, progress=_NoProgress())
        return finished[0]

    if not shipped:
        return run(payload), {}
    with tempfile.TemporaryDirectory(prefix="coster-ray-") as tmp:
        local = dict(payload)
        before: dict[str, dict[str, int]] = {}
        for key, files in shipped.items():
            folder = Path(tmp) / key
            folder.mkdir()
            for name, data in files.items():
                (folder / name).parent.mkdir(parents=True, exist_ok=True)
                (folder / name).write_bytes(ray.get(data) if isinstance(data, ray.ObjectRef) else data)
            local[key] = str(folder)
            before[key] = {p.relative_to(folder).as_posix(): p.stat().st_mtime_ns for p in folder.rglob("*")
                           if p.is_file()}
        outcome = run(local)
        back: dict[str, dict[str, bytes]] = {}
        for key in shipped if outcome.ok else ():
            folder = Path(local[key])
            back[key] = {p.relative_to(folder).as_posix(): p.read_bytes() for p in sorted(folder.rglob("*"))
                         if p.is_file() and not p.name.startswith(".")
                         and before[key].get(p.relative_to(folder).as_posix()) != p.stat().st_mtime_ns}
    return outcome, back


class _Shipper:
    """The driver's side of :attr:`Task.folders` on Ray: files put into the object store once each,
    and files that come back written into the driver's folders (atomically)."""

    def __init__(self, ray: Any) -> None:
        self.ray = ray
        self._refs: dict[tuple[str, int, int], Any] = {}

    def ship(self, task: Task) -> dict[str, dict[str, Any]]:
        shipped: dict[str, dict[str, Any]] = {}
        for key, names in task.folders.items():
            folder = Path(task.payload[key])
            shipped[key] = {}
            for name in names:
                path = folder / name
                if not path.is_file():
                    continue
                st = path.stat()
                ident = (str(path.resolve()), st.st_mtime_ns, st.st_size)
                if ident not in self._refs:
                    self._refs[ident] = self.ray.put(path.read_bytes())
                shipped[key][name] = self._refs[ident]
        return shipped

    @staticmethod
    def land(task: Task, back: dict[str, dict[str, bytes]]) -> None:
        from coster_sumo.infra.atomic import atomic_path

        for key, files in back.items():
            folder = Path(task.payload[key])
            for name, data in files.items():
                path = folder / name
                path.parent.mkdir(parents=True, exist_ok=True)
                with atomic_path(path) as tmp:
                    tmp.write_bytes(data)


def _execute_ray(pending: deque[Task], *, workers: int, timeout: float | None, on_done: OnDone,
                 progress: Any, ray_address: str | None, preload: Sequence[str] = ()) -> None:
    try:
        import ray
    except ImportError:
        raise InputError("--executor ray needs Ray: pip install 'coster-sumo[ray]' (or pip install ray)") from None
    started_here = False
    if not ray.is_initialized():
        kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False}
        if ray_address:
            kwargs["address"] = ray_address
        elif not os.environ.get("RAY_ADDRESS"):  # else ray.init connects to the cluster it names
            kwargs["num_cpus"] = workers
        ray.init(**kwargs)
        started_here = True
    # no max_calls=1: a worker that forks every task keeps no simulation of its own and is reused
    remote = ray.remote(num_cpus=1, max_retries=0)(_ray_entry)
    # the Ray worker itself died (the task runs in a child of it, whose crash is an Outcome): its node
    # was lost or its memory ran out, so a rerun tries again
    lost = (ray.exceptions.WorkerCrashedError, ray.exceptions.NodeDiedError, ray.exceptions.OutOfMemoryError,
            ray.exceptions.ObjectLostError, ray.exceptions.LocalRayletDiedError)
    shipper = _Shipper(ray)
    running: dict[Any, tuple[Task, float]] = {}
    try:
        while pending or running:
            while pending and len(running) < workers:
                task = pending.popleft()
                ref = remote.remote(task.fn, task.payload, shipper.ship(task), timeout, tuple(preload))
                running[ref] = (task, time.monotonic())
            ready, _ = ray.wait(list(running), num_returns=1, timeout=1.0)
            for ref in ready:
                task, submitted = running.pop(ref)
                waited = time.monotonic() - submitted  # queued + run, for a failure the worker did not time
                try:
                    outcome, back = ray.get(ref)
                    if outcome.ok:
                        shipper.land(task, back)
                except ray.exceptions.RayTaskError as exc:  # the entry's own failure (its files, ...)
                    cause = exc.as_instanceof_cause() if hasattr(exc, "as_instanceof_cause") else exc
                    outcome = Outcome(False, reason=_one_line(getattr(cause, "cause", None) or cause),
                                      wall_time_s=waited, detail=str(exc))
                except lost as exc:
                    outcome = Outcome(False, reason=f"{LOST_ON_CLUSTER} ({_one_line(exc)[:200]})", wall_time_s=waited)
                except Exception as exc:  # noqa: BLE001 - any other failure of Ray is one failed task
                    outcome = Outcome(False, reason=f"crashed ({_one_line(exc)[:200]})", wall_time_s=waited)
                pending.extend(on_done(task, outcome))
                progress.update(1)
    finally:
        for ref in running:
            with contextlib.suppress(Exception):
                ray.cancel(ref, force=True)
        if started_here:
            ray.shutdown()

