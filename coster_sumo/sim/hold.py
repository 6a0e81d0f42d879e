"""Held copies of a running libsumo simulation: variants continue from one instead of from ``begin``.

During the nominal pass, every so often (while the target runs), the process that holds the
libsumo simulation forks. The child, a *holder*, keeps that moment of the simulation and waits.
After generation, each variant runs in a grandchild forked from the latest holder that is not
later than the variant's start: the copy continues exactly as a run from ``begin`` with the same
seed would (docs/sumo.md §10: a forked libsumo process continues bit-exactly; SUMO's state files
do not), without simulating the prefix again.

Before the target departs, holders roll: one every ``lead_s`` with only the two newest kept, so
that an adversary that appears up to ``lead_s`` before the target does (a collision right after
the target's departure: the adversary drives its whole horizon before it) still has a holder
before it. Without them such variants simulate from ``begin``: on the wheel's A10KW motorway the
target departs at 400 s and t_col came 4 s later, and every variant simulated 400 s of traffic.
Where the demand says when the target is planned to depart (:meth:`HeldStates.expect_departure`;
SUMO inserts a vehicle then or later, never earlier), they start rolling ``2 lead_s`` before that:
rolling from ``begin``, one every 5 s over the 704 s before a target of the wheel's fokr_bs_demo
departs (about 140 forks), cost 3.6 s of its 8.9 s nominal pass.

Holders are thinned as the pass goes on (every other one is dropped and the spacing doubles when
there are too many), so their number and memory stay bounded. Once a collision time is known,
:meth:`HeldStates.advance` has the latest holder before it fork a new holder that simulates up to
shortly before the adversary appears, in the background (on another core) while the adversaries
are generated: the variants then start from there and do not each simulate the gap again.

Only libsumo sessions are held: a TraCI connection cannot be shared by forked processes, so TraCI
runs start every variant from ``begin``. What runs in a held copy is SUMO and numpy only: a forked
process does not carry torch's thread pools over (holders are made during the nominal pass, before
any model is loaded).
"""

from __future__ import annotations

import contextlib
import functools
import os
import pickle
import signal
import socket
import sys
import tempfile
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection, Pipe
from pathlib import Path
from typing import Any

from coster_sumo.errors import SumoError
from coster_sumo.infra.procs import die_with_parent, fork_and_wait
from coster_sumo.sim.session import SumoSession
from coster_sumo.sim.sumo_outputs import detach_outputs

MAX_HOLDERS = 8
FIRST_SPACING_S = 10.0  # [s] simulation time between holders before any thinning
LEAD_S = 5.0  # [s] how long before the target's departure an adversary may appear (the rollout horizon)
LEAD_HOLDERS = 2  # rolling holders kept before the target departs
MIN_ADVANCE_S = 2.0  # [s] a gap shorter than this is simulated by each variant itself
CONNECT_TIMEOUT_S = 60.0  # [s] for an advanced holder to call back (it does so right after its fork)

Job = Callable[[SumoSession, Any], Any]


@dataclass
class _Holder:
    time: float  # [s] the simulation time it holds (for an advancing one: the time it advances to)
    pid: int
    conn: Connection
    ready: bool = True  # False while an advanced holder is still simulating up to ``time``
    lead: bool = False  # made before the target departed (one of the rolling ones)


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

    def __init__(self, target_id: str, max_holders: int = MAX_HOLDERS, spacing_s: float = FIRST_SPACING_S,
                 lead_s: float = LEAD_S, more_targets: Sequence[str] = ()) -> None:
        self.target_id = target_id
        # several targets (one run for each): holders roll until the first of them departs
        self.targets = tuple(dict.fromkeys((target_id, *more_targets)))
        self.max_holders = max_holders
        self.spacing_s = spacing_s
        self.lead_s = lead_s
        self.holders: list[_Holder] = []
        self._next_s: float | None = None
        self._next_lead_s: float | None = None
        self._departed = False
        self._quiet_until_s: float | None = None  # no rolling holder (nor the check for it) before

    def expect_departure(self, planned_s: float | None) -> None:
        """The targets' earliest planned departure [s] (None: unknown): rolling holders start
        ``2 lead_s`` before it instead of at the pass's begin."""
        self._quiet_until_s = None if planned_s is None else planned_s - 2 * self.lead_s

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
        if self._quiet_until_s is not None and t < self._quiet_until_s - 1e-9:
            return False  # the targets cannot depart before their planned time
        if not can_hold(session):
            return False
        if not self._departed:
            ids = session.vehicle_ids()
            if not any(v in ids for v in self.targets):
                self._hold_lead(session)
                return False
            self._departed = True
        self._hold(session)
        self._next_s = t + self.spacing_s
        lead = [h for h in self.holders if h.lead]
        rest = [h for h in self.holders if not h.lead]
        if len(rest) > self.max_holders:
            # keep the first (the target's departure: any t_col is after it) and every other one
            # of the rest, counted back from the newest
            keep = [rest[0], *rest[1:][::-1][::2][::-1]]
            for h in rest:
                if h not in keep:
                    self._stop(h)
            self.holders = lead + keep
            self.spacing_s *= 2
        return False

    def _hold_lead(self, session: SumoSession) -> None:
        """Before the target departs: a rolling holder every ``lead_s``, the two newest kept."""
        if self.lead_s <= 0 or (self._next_lead_s is not None and session.time < self._next_lead_s - 1e-9):
            return
        self._hold(session)
        self.holders[-1].lead = True
        self._next_lead_s = session.time + self.lead_s
        while len(self.holders) > LEAD_HOLDERS:
            self._stop(self.holders.pop(0))

    def _hold(self, session: SumoSession) -> None:
        parent_end, child_end = Pipe()
        sys.stdout.flush()
        sys.stderr.flush()
        pid = os.fork()
        if pid == 0:  # the holder
            die_with_parent()
            for folder in (session.sumo_outputs, *session.own_outputs):  # the pass's outputs are the parent's alone
                if folder is not None:
                    detach_outputs(folder)
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

    def advance(self, t: float) -> _Holder | None:
        """Start a new holder at the first step at or after ``t`` [s], made from the latest one before.

        Returns at once: the new holder simulates from the old one's moment up to ``t`` in its own
        process; :meth:`run` waits for it. The old holder stays (other variants may start earlier).
        Returns None (and does nothing) when the latest holder is already within
        :data:`MIN_ADVANCE_S` of ``t``, or there is none.
        """
        h = self.holder_before(t)
        if h is None or t - h.time < MIN_ADVANCE_S:
            return None
        with tempfile.TemporaryDirectory(prefix="coster-hold-") as tmp:
            address = str(Path(tmp) / "holder.sock")
            server = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            try:
                server.bind(address)
                server.listen(1)
                server.settimeout(CONNECT_TIMEOUT_S)
                self._wait_ready(h)
                h.conn.send(("advance", t, address))
                try:
                    sock, _ = server.accept()
                except OSError as exc:
                    raise SumoError(f"a held simulation did not start its advanced copy: {exc}") from None
            finally:
                server.close()
        sock.settimeout(None)
        new = _Holder(t, -1, Connection(sock.detach()), ready=False)
        self.holders.append(new)
        self.holders.sort(key=lambda x: x.time)
        return new

    @staticmethod
    def _wait_ready(h: _Holder) -> None:
        """Block until an advanced holder has reached its moment (its real time replaces the asked one)."""
        if h.ready:
            return
        try:
            msg = h.conn.recv()
        except (EOFError, OSError):
            msg = ("failed", "it exited")
        if msg[0] != "ready":
            raise SumoError(f"a held simulation failed to advance to {h.time:.1f} s: {msg[1]}")
        h.time, h.pid, h.ready = float(msg[1]), int(msg[2]), True

    def run(self, holder: _Holder, jobs: Sequence[tuple[Job, Any]], workers: int = 1) -> list[Any]:
        """Run ``job(session, payload)`` for each job in a copy of ``holder``'s simulation.

        Returns each job's result, in order; a job that failed raises its error here.
        """
        results = []
        for ok, value in self.run_each(holder, jobs, workers):
            if not ok:
                raise SumoError(f"a held simulation failed to continue: {value}")
            results.append(value)
        return results

    def run_each(self, holder: _Holder, jobs: Sequence[tuple[Job, Any]], workers: int = 1,
                 timeout: float | None = None) -> list[tuple[bool, Any]]:
        """Like :meth:`run`, but each job's outcome on its own: ``(True, result)``, or ``(False,
        reason)`` for a job that raised, crashed its copy (a SUMO segfault) or ran past ``timeout`` [s]
        (then it is stopped); the other jobs are not affected."""
        self._wait_ready(holder)
        with tempfile.TemporaryDirectory(prefix="coster-hold-") as tmp:
            paths = [str(Path(tmp) / f"{i}.pickle") for i in range(len(jobs))]
            try:
                holder.conn.send(("run", [(fn, payload, path) for (fn, payload), path
                                          in zip(jobs, paths, strict=True)], max(1, workers), timeout))
                statuses = holder.conn.recv()
            except (EOFError, OSError) as exc:
                reason = f"the held simulation died ({type(exc).__name__})"
                return [(False, reason)] * len(jobs)
            outcomes: list[tuple[bool, Any]] = []
            for path, (ok, detail) in zip(paths, statuses, strict=True):
                if not ok:
                    outcomes.append((False, detail))
                    continue
                with open(path, "rb") as fh:  # our own file, written by our own forked process
                    outcomes.append((True, pickle.load(fh)))
            return outcomes

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
        if h.pid > 0:  # an advanced holder is its maker's child, not ours: the maker or init reaps it
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
            if msg[0] == "advance":
                _advance_copy(session, conn, float(msg[1]), str(msg[2]))
                continue
            if msg[0] != "run":
                break
            _, jobs, workers, timeout = msg
            calls = [(functools.partial(fn, session, payload), path) for fn, payload, path in jobs]
            statuses = fork_and_wait(calls, workers, timeout)
            conn.send(statuses)
    except BaseException:  # noqa: BLE001 - a holder never raises into the main program's stack
        code = 1
    os._exit(code)


def _advance_copy(session: SumoSession, conn: Connection, t: float, address: str) -> None:
    """In a holder: fork a copy that calls back at ``address``, simulates up to ``t`` [s] and holds."""
    sys.stdout.flush()
    sys.stderr.flush()
    if os.fork() != 0:
        return  # the holder goes on waiting for jobs
    die_with_parent()
    conn.close()  # the maker's connection belongs to the maker
    code = 0
    try:
        sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        sock.connect(address)
        mine = Connection(sock.detach())
    except BaseException:  # noqa: BLE001 - nobody to tell: the main process times out waiting
        os._exit(1)
    try:
        eps = 1e-6 * session.step_length
        while session.time < t - eps:
            session.step()
        mine.send(("ready", session.time, os.getpid()))
    except BaseException as exc:  # noqa: BLE001 - reported to the main process, which raises it
        with contextlib.suppress(OSError):
            mine.send(("failed", " ".join(str(exc).split()) or type(exc).__name__))
        code = 1
    if code:
        os._exit(code)
    _holder_loop(session, mine)  # never returns
