"""Held copies of a running libsumo simulation: variants continue from one instead of from ``begin``.

During the nominal pass, every so often (while the target runs), the process that holds the
libsumo simulation forks. The child, a *holder*, keeps that moment of the simulation and waits.
After generation, each variant runs in a grandchild forked from the latest holder that is not
later than the variant's start: the copy continues exactly as a run from ``begin`` with the same
seed would (docs/sumo.md §10: a forked libsumo process continues bit-exactly; SUMO's state files
do not), without simulating the prefix again.

Holders are thinned as the pass goes on (every other one is dropped and the spacing doubles when
there are too many), so their number and memory stay bounded. Only libsumo sessions are held: a
TraCI connection cannot be shared by forked processes, so TraCI runs start every variant from
``begin``. What runs in a held copy is SUMO and numpy only: a forked process does not carry torch's
thread pools over (holders are made during the nominal pass, before any model is loaded).
"""

from __future__ import annotations

import contextlib
import os
import pickle
import signal
import sys
import tempfile
import traceback
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection, Pipe
from pathlib import Path
from typing import Any

from coster_sumo.atomic import atomic_path
from coster_sumo.errors import SumoError
from coster_sumo.sim.session import SumoSession

MAX_HOLDERS = 8
FIRST_SPACING_S = 10.0  # [s] simulation time between holders before any thinning

Job = Callable[[SumoSession, Any], Any]


@dataclass
class _Holder:
    time: float  # [s] the simulation time it holds
    pid: int
    conn: Connection


def can_hold(session: SumoSession) -> bool:
    """Whether this session can be held: in-process libsumo on a system with fork.

    Jobs run in forked processes must not use torch (a fork does not carry its thread pools over).
    """
    return not session.uses_traci and hasattr(os, "fork") and session.port is None


class HeldStates:
    """Forked copies of a simulation at moments of its nominal pass; see the module docstring.

    Use :meth:`after_step` as (part of) the nominal pass's ``after_step`` hook, then :meth:`run`
    jobs from the holder before a given time, and :meth:`close` (or use it as a context manager).
    """

    def __init__(self, target_id: str, max_holders: int = MAX_HOLDERS, spacing_s: float = FIRST_SPACING_S) -> None:
        self.target_id = target_id
        self.max_holders = max_holders
        self.spacing_s = spacing_s
        self.holders: list[_Holder] = []
        self._next_s: float | None = None

    def __enter__(self) -> HeldStates:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # ------------------------------------------------------------------ during the nominal pass

    def after_step(self, session: SumoSession, states: Any = None) -> bool:
        """Hold the simulation now if it is time (the target runs); never asks to stop."""
        t = session.time
        if self._next_s is not None and t < self._next_s - 1e-9:
            return False
        if self.target_id not in session.vehicle_ids() or not can_hold(session):
            return False
        self._hold(session)
        self._next_s = t + self.spacing_s
        if len(self.holders) > self.max_holders:  # keep every other one (the newest stays)
            keep = self.holders[len(self.holders) % 2::2]
            for h in self.holders:
                if h not in keep:
                    self._stop(h)
            self.holders = keep
            self.spacing_s *= 2
        return False

    def _hold(self, session: SumoSession) -> None:
        parent_end, child_end = Pipe()
        sys.stdout.flush()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:  # the holder
            parent_end.close()
            for h in self.holders:  # the other holders' pipes belong to the parent
                with contextlib.suppress(OSError):
                    h.conn.close()
            _holder_loop(session, child_end)  # never returns
        child_end.close()
        self.holders.append(_Holder(session.time, pid, parent_end))

    # ------------------------------------------------------------------ afterwards

    def holder_before(self, t: float) -> _Holder | None:
        """The latest holder at or before simulation time ``t`` [s]."""
        before = [h for h in self.holders if h.time <= t + 1e-9]
        return before[-1] if before else None

    def run(self, holder: _Holder, jobs: Sequence[tuple[Job, Any]], workers: int = 1) -> list[Any]:
        """Run ``job(session, payload)`` for each job in a copy of ``holder``'s simulation.

        Returns each job's result, in order; a job that failed raises its error here.
        """
        with tempfile.TemporaryDirectory(prefix="coster-hold-") as tmp:
            paths = [str(Path(tmp) / f"{i}.pickle") for i in range(len(jobs))]
            holder.conn.send(("run", [(fn, payload, path) for (fn, payload), path in zip(jobs, paths, strict=True)],
                              max(1, workers)))
            statuses = holder.conn.recv()
            results = []
            for path, (ok, detail) in zip(paths, statuses, strict=True):
                if not ok:
                    raise SumoError(f"a held simulation failed to continue: {detail}")
                with open(path, "rb") as fh:  # our own file, written by our own forked process
                    results.append(pickle.load(fh))
            return results

    def close(self) -> None:
        for h in self.holders:
            self._stop(h)
        self.holders = []

    @staticmethod
    def _stop(h: _Holder) -> None:
        with contextlib.suppress(OSError, EOFError, BrokenPipeError):
            h.conn.send(("quit",))
        with contextlib.suppress(OSError):
            h.conn.close()
        with contextlib.suppress(ChildProcessError, OSError):
            os.waitpid(h.pid, 0)


def _holder_loop(session: SumoSession, conn: Connection) -> None:
    """Body of a holder: wait for jobs, run each in a forked copy, report; exit on "quit" or EOF."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the main process's to handle
    code = 0
    try:
        while True:
            try:
                msg = conn.recv()
            except (EOFError, OSError):
                break
            if msg[0] != "run":
                break
            _, jobs, workers = msg
            statuses: list[tuple[bool, str]] = [(False, "not run")] * len(jobs)
            running: dict[int, int] = {}
            pending = list(enumerate(jobs))
            while pending or running:
                while pending and len(running) < workers:
                    i, (fn, payload, path) = pending.pop(0)
                    sys.stdout.flush()
                    sys.stderr.flush()
                    pid = os.fork()
                    if pid == 0:
                        _worker(session, fn, payload, path)  # never returns
                    running[pid] = i
                pid, status = os.wait()
                i = running.pop(pid, -1)
                if i >= 0:
                    ok = os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0
                    detail = "" if ok else _failure(jobs[i][2], status)
                    statuses[i] = (ok, detail)
            conn.send(statuses)
    except BaseException:  # noqa: BLE001 - a holder never raises into the main program's stack
        code = 1
    os._exit(code)


def _worker(session: SumoSession, fn: Job, payload: Any, path: str) -> None:
    code = 0
    try:
        result = fn(session, payload)
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            pickle.dump(result, fh)
    except BaseException:  # noqa: BLE001 - reported to the holder through the exit code and a file
        with contextlib.suppress(OSError), open(path + ".err", "w") as fh:
            fh.write(traceback.format_exc())
        code = 1
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


def _failure(path: str, status: int) -> str:
    if os.WIFSIGNALED(status):
        return f"crashed ({signal.Signals(os.WTERMSIG(status)).name})"
    with contextlib.suppress(OSError):
        lines = Path(path + ".err").read_text().strip().splitlines()
        if lines:
            return lines[-1]
    return f"exited with code {os.WEXITSTATUS(status)}"
