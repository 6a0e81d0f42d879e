"""Forked child processes that die with their parent, stop at a timeout, and report crashes as one line.

libsumo holds one simulation per process and can take its process down (a segmentation fault), and
a variant's planner may hang; so every variant of ``run`` is simulated in a forked child. This
module holds that mechanism once: the batch executor, the held copies of a nominal pass
(:mod:`coster_sumo.sim.hold`) and ``run``'s variants all use it.

- :func:`die_with_parent`: on Linux the kernel SIGKILLs the child when its parent dies, so a
  killed command (Ctrl-C, SIGTERM, SIGKILL) leaves no process behind, however deep the tree.
- :func:`fork_and_wait`: each ``(fn, path)`` runs in its own forked child, at most ``workers`` at
  a time; the child pickles ``fn()``'s value to ``path`` (written atomically) and the parent
  gets ``(ok, reason)`` per call: ``crashed (SIGSEGV)``, ``timed out after 30 s``, or the last
  line of the child's traceback.
- :func:`run_forked`: one call in a child, its value returned or :class:`ChildFailed` raised.
"""

from __future__ import annotations

import contextlib
import faulthandler
import functools
import os
import pickle
import select
import signal
import sys
import tempfile
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any

from coster_sumo.errors import SumoError
from coster_sumo.infra.atomic import atomic_path

POLL_S = 0.01  # [s] how often a waiting parent looks at its children and their clocks


class ChildFailed(SumoError):
    """A forked child crashed, timed out or raised; the message is its one-line reason."""


_IMPORTS_ONLY = False  # True in a process coster-sumo serve forked for a command, until that command runs torch


def mark_imports_only() -> None:
    """Say that this process (a fork of ``coster-sumo serve``, :mod:`coster_sumo.cli.server`) has torch
    and scikit-learn imported but never ran their thread pools."""
    global _IMPORTS_ONLY
    _IMPORTS_ONLY = True


def imports_only() -> bool:
    """Whether torch and scikit-learn, if imported, never ran here (see :func:`mark_imports_only`):
    this process may then fork children that run them, as the command line does before it loads
    them. Callers that would otherwise keep torch in this process check it."""
    return _IMPORTS_ONLY


def die_with_parent() -> None:
    """Linux: have the kernel SIGKILL this process when its parent dies (a killed command leaves no orphans)."""
    if not sys.platform.startswith("linux"):
        return
    parent = os.getppid()
    with contextlib.suppress(Exception):
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # 1 = PR_SET_PDEATHSIG
    if os.getppid() != parent:  # the parent died before the request took effect
        os._exit(1)


def signal_name(code: int) -> str:
    """``SIGSEGV`` for 11; ``signal N`` for a number Python does not know."""
    with contextlib.suppress(ValueError):
        return signal.Signals(code).name
    return f"signal {code}"


def one_openmp_thread_after_fork() -> bool:
    """In a forked child of a process that may have run OpenMP code (torch, scikit-learn's KMeans):
    one thread. The parent's OpenMP pool does not survive the fork, and a child that starts a
    parallel region on more than one thread hangs (measured: a torch matrix product and a KMeans fit
    after fork never returned); on one thread both work. A parent that loaded neither (the CLI
    forks before any model is loaded) leaves its children all threads. Returns whether it limited."""
    torch = sys.modules.get("torch")
    if torch is None and "sklearn" not in sys.modules:
        return False
    with contextlib.suppress(Exception):
        from threadpoolctl import threadpool_limits

        threadpool_limits(1, user_api="openmp")
    if torch is not None:
        torch.set_num_threads(1)
    return True


def passive_openmp_waits() -> None:
    """OpenMP threads (torch's pool, scikit-learn's K-means) that wait at a barrier sleep instead of
    spinning: set before torch loads (OpenMP reads it then); a value the user set is kept.

    On the 2-core machine shared with other jobs (load average 10), the freeway's generation
    (bench/bench_freeway.py's scene, two torch threads, the weights loaded) took 5.6-13.1 s with
    spinning waits and 1.6-2.4 s with passive ones, the plans bit for bit the same: a spinning
    thread burns the core its descheduled sibling, or the run's own SUMO processes, would use.
    """
    if "torch" not in sys.modules:
        os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")


def usable_cores() -> int:
    """The cores this process may run on (its CPU affinity where the system has one)."""
    with contextlib.suppress(AttributeError, OSError):
        return max(1, len(os.sched_getaffinity(0)))
    return max(1, os.cpu_count() or 1)


@contextlib.contextmanager
def torch_threads(n: int | None) -> Iterator[None]:
    """torch computes on ``n`` threads inside the block, on as many as before after it (None: no change).

    For work that shares the machine with processes of its own: the models' thread pool spin-waits
    for every thread at every operation, so a pool as wide as the machine beside one busy process
    makes every operation wait for a core (measured on the 2-core machine at a load average of 5:
    the demo's generation, torch and the weights already loaded, 0.59-0.71 s on one thread against
    1.6-8.9 s on two, three runs each; the variants are bit for bit the same on one and two).
    """
    if n is None:
        yield
        return
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(max(1, n))
    try:
        yield
    finally:
        torch.set_num_threads(before)


def _child_body(fn: Callable[[], Any], path: str) -> None:
    """In a forked child: run ``fn``, pickle its value to ``path`` (or its traceback to ``path.err``), exit."""
    die_with_parent()
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    faulthandler.disable()  # a crash is reported by the parent as one line, not a dump on the terminal
    one_openmp_thread_after_fork()
    code = 0
    try:
        value = fn()
        with atomic_path(path) as tmp, open(tmp, "wb") as fh:
            pickle.dump(value, fh)
    except BaseException:  # noqa: BLE001 - reported to the parent through the exit code and a file
        with contextlib.suppress(OSError), open(path + ".err", "w") as fh:
            fh.write(traceback.format_exc())
        code = 1
    sys.stdout.flush()
    sys.stderr.flush()
    outputs = sys.modules.get("coster_sumo.infra.staging")
    if outputs is not None:  # a temporary folder this child made itself (none where its parent had one)
        outputs.cleanup()
    os._exit(code)  # no atexit handlers inherited from the parent (libsumo, tqdm)


def _reason(path: str, status: int) -> str:
    if os.WIFSIGNALED(status):
        return f"crashed ({signal_name(os.WTERMSIG(status))})"
    with contextlib.suppress(OSError):
        lines = Path(path + ".err").read_text().strip().splitlines()
        if lines:
            return lines[-1]
    return f"exited with code {os.WEXITSTATUS(status)}"


def _poll(pid: int) -> tuple[int, int]:
    """``os.waitpid(pid, WNOHANG)``: (0, 0) while the child runs (only our own children are waited for)."""
    return os.waitpid(pid, os.WNOHANG)


def _pidfd(pid: int) -> int | None:
    """A descriptor that becomes readable when child ``pid`` exits (Linux 5.3 and later), or None."""
    try:
        return os.pidfd_open(pid)
    except (AttributeError, OSError):
        return None


def _nap(fds: list[int]) -> None:
    """Wait :data:`POLL_S`, or less: until one of the children behind ``fds`` exits (a child's pass
    takes tens of milliseconds; sleeping the whole poll interval after each cost up to a fifth)."""
    if fds:
        with contextlib.suppress(OSError, ValueError):
            select.select(fds, [], [], POLL_S)
            return
    time.sleep(POLL_S)


def fork_and_wait(calls: Sequence[tuple[Callable[[], Any], str]], workers: int = 1,
                  timeout: float | None = None) -> list[tuple[bool, str]]:
    """Run each ``fn`` of ``calls`` in a forked child that pickles its value to ``path``.

    Returns ``(ok, reason)`` per call, in order (``reason`` is "" where ok). A child that runs
    longer than ``timeout`` [s] is killed. Should this process be interrupted while waiting, the
    children still running are killed before the exception goes on.
    """
    statuses: list[tuple[bool, str]] = [(False, "not run")] * len(calls)
    running: dict[int, tuple[int, float]] = {}  # pid -> (call index, start time)
    fds: dict[int, int] = {}  # pid -> its pidfd, where the system has them
    pending = list(enumerate(calls))
    timed_out: set[int] = set()
    try:
        while pending or running:
            while pending and len(running) < max(1, workers):
                i, (fn, path) = pending.pop(0)
                sys.stdout.flush()
                sys.stderr.flush()
                pid = os.fork()
                if pid == 0:
                    _child_body(fn, path)  # never returns
                running[pid] = (i, time.monotonic())
                if (fd := _pidfd(pid)) is not None:
                    fds[pid] = fd
            finished = [(pid, status) for pid, status in map(_poll, running) if pid]
            if not finished:
                now = time.monotonic()
                for child, (_, started) in running.items():
                    if timeout is not None and now - started > timeout and child not in timed_out:
                        with contextlib.suppress(ProcessLookupError):
                            os.kill(child, signal.SIGKILL)
                        timed_out.add(child)
                _nap(list(fds.values()))
                continue
            for pid, status in finished:
                i, _ = running.pop(pid)
                if pid in fds:
                    os.close(fds.pop(pid))
                if pid in timed_out:
                    statuses[i] = (False, f"timed out after {timeout:g} s (stopped)")
                elif os.WIFEXITED(status) and os.WEXITSTATUS(status) == 0:
                    statuses[i] = (True, "")
                else:
                    statuses[i] = (False, _reason(calls[i][1], status))
    finally:
        for child in running:
            with contextlib.suppress(OSError):
                os.kill(child, signal.SIGKILL)
            with contextlib.suppress(OSError):
                os.waitpid(child, 0)
        for fd in fds.values():
            with contextlib.suppress(OSError):
                os.close(fd)
    return statuses


def run_forked(fn: Callable[[], Any], timeout: float | None = None) -> Any:
    """``fn()`` in a forked child: its value, or :class:`ChildFailed` with the one-line reason."""
    with tempfile.TemporaryDirectory(prefix="coster-child-") as tmp:
        path = str(Path(tmp) / "value.pickle")
        [(ok, reason)] = fork_and_wait([(fn, path)], timeout=timeout)
        if not ok:
            raise ChildFailed(reason)
        with open(path, "rb") as fh:  # our own file, written by our own child
            return pickle.load(fh)


def _capture(fn: Callable[[], Any]) -> tuple[bool, Any]:
    """In the child: ``(True, value)``, or ``(False, error)`` for one of our errors or an error of the
    operating system (a full disk, a folder it may not write): they cross back whole."""
    from coster_sumo.errors import CosterError

    try:
        return True, fn()
    except (CosterError, OSError) as exc:
        return False, exc


def run_supervised(fn: Callable[[], Any], what: str) -> Any:
    """A whole command's work in a forked child, so that a SUMO crash is one line, not a dead command.

    Errors of ours (:class:`~coster_sumo.errors.CosterError`) raised in the child are raised again
    here with their exit codes; a crash or any other failure of the child becomes
    :class:`ChildFailed` naming ``what`` (``"run of CFG"``). The child dies with this process.
    """
    from coster_sumo.infra.staging import staging_folder

    staging_folder()  # made here, the child's SUMO outputs folder outlives a crash of the child and goes with us
    try:
        ok, value = run_forked(functools.partial(_capture, fn))
    except ChildFailed as exc:
        raise ChildFailed(f"{what}: stopped, {exc}") from None
    if not ok:
        raise value
    return value
