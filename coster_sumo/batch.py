"""Batches: many scenes, many variants, many planners, each run isolated in its own process.

Three layers, usable on their own:

1. **Executor** (:func:`execute`): runs :class:`Task` s (a top-level function and a JSON-able
   payload) with at most ``workers`` at a time, **one fresh process per task** (libsumo holds one
   simulation per process, SUMO_FACTS §6), each under a wall-clock timeout. A task that raises, hangs
   past its timeout, or kills its process (a SUMO segfault) becomes one failed :class:`Outcome` with
   the reason; the batch goes on. A finished task may schedule more tasks (its ``on_done`` result),
   so a scene's planner runs start as soon as its variants exist. ``executor="ray"`` runs the same
   functions on a Ray cluster (``ray.init()`` locally when no address is given; one worker process
   per task through ``max_calls=1``; files in OUT must be on a file system the workers share).
2. **Scene sources** (:func:`parse_sources`): ``.sumocfg`` files (``CFG@seed=3,begin=20,end=50,target=veh``
   overrides; ``seeds`` makes several scenes from one configuration), folders (every ``.sumocfg``
   below, e.g. converted WOMD scenes with their ``scene.npz``), and text files listing sources.
3. **Regression** (:func:`regress`): for each scene the variants are generated **once** (a task
   writing ``OUT/plans/<scene_key>.json`` and the nominal scene ``OUT/plans/<scene_key>.npz``),
   then every planner runs on the same variants. One row per (scene, variant, planner) goes into a
   Parquet dataset ``OUT/results/`` as one small part file per run, written atomically (temporary
   name, then rename), so a rerun skips what is done and never duplicates a row.

The generator evaluation (``coster-sumo eval scenarios``, :func:`evaluate_generators`) uses the
same executor and the same scene sources.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import json
import math
import multiprocessing as mp
import os
import re
import signal
import sys
import tempfile
import time
import traceback
from collections import deque
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from multiprocessing.connection import Connection
from multiprocessing.connection import wait as mp_wait
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from coster_sumo.errors import InputError

if TYPE_CHECKING:
    from coster_sumo.drivable import DrivableArea
    from coster_sumo.pipeline import PlannedScenario, RunOptions
    from coster_sumo.scene import Scene

DEFAULT_TIMEOUT_S = 900.0  # [s] wall clock per task
WILSON_Z = 1.959963984540054  # two-sided 95 %

# ============================================================================ executor


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


@dataclass
class Outcome:
    """What became of a task: ``ok`` with ``value``, or not with a one-line ``reason``."""

    ok: bool
    value: Any = None
    reason: str = ""
    wall_time_s: float = 0.0
    detail: str = ""  # traceback or log tail, for the log file


OnDone = Callable[[Task, Outcome], Iterable[Task]]


def _signal_name(code: int) -> str:
    with contextlib.suppress(ValueError):
        return signal.Signals(code).name
    return f"signal {code}"


def _die_with_parent() -> None:
    """Linux: have the kernel SIGKILL this process when its parent dies (a killed batch leaves no orphans)."""
    if not sys.platform.startswith("linux"):
        return
    with contextlib.suppress(Exception):
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL)  # 1 = PR_SET_PDEATHSIG


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
                log_path: str | None, threads: int | None = None) -> None:
    """Body of a task process: run, send ("ok", value) or ("error", reason, traceback), exit hard."""
    _die_with_parent()
    if threads is not None:
        _limit_threads(threads)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    import faulthandler

    faulthandler.disable()  # a crash is reported as one line by the parent, not a dump on its terminal
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


def _default_start_method() -> str:
    return "fork" if "fork" in mp.get_all_start_methods() else "spawn"


def _execute_local(pending: deque[Task], *, workers: int, timeout: float | None, on_done: OnDone,
                   progress: Any, start_method: str | None, log_dir: Path | None) -> None:
    ctx: Any = mp.get_context(start_method or _default_start_method())
    running: list[_Running] = []
    threads = max(1, (os.cpu_count() or 1) // max(1, workers))  # the cores shared among the workers

    def finish(r: _Running, outcome: Outcome) -> None:
        running.remove(r)
        with contextlib.suppress(Exception):
            r.reader.close()
        pending.extend(on_done(r.task, outcome))
        progress.update(1)

    try:
        while pending or running:
            while pending and len(running) < workers:
                task = pending.popleft()
                reader, writer = ctx.Pipe(duplex=False)
                log = (log_dir / f"{task.key}.log") if log_dir is not None else None
                proc = ctx.Process(target=_child_main, args=(task.fn, task.payload, writer,
                                                             str(log) if log else None, threads),
                                   name=f"coster-{task.key}", daemon=True)
                proc.start()
                writer.close()  # the child holds the only writer: EOF when it dies
                running.append(_Running(task, proc, reader, time.monotonic(), log))
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
                        why = (f"crashed ({_signal_name(-code)})" if code is not None and code < 0
                               else f"exited with code {code} without a result")
                        tail = _log_tail(r.log)
                        finish(r, Outcome(False, reason=why + (f"; log: {tail}" if tail else ""), wall_time_s=wall))
                    elif msg[0] == "ok":
                        finish(r, Outcome(True, value=msg[1], wall_time_s=wall))
                    else:
                        finish(r, Outcome(False, reason=msg[1], wall_time_s=wall, detail=msg[2]))
                elif timeout is not None and wall > timeout:
                    r.proc.kill()
                    r.proc.join()
                    finish(r, Outcome(False, reason=f"timed out after {timeout:g} s (killed)", wall_time_s=wall))
    finally:
        for r in running:
            with contextlib.suppress(Exception):
                r.proc.kill()
                r.proc.join()


def _ray_entry(fn: Callable[[dict[str, Any]], Any], payload: dict[str, Any]) -> Any:
    return fn(payload)


def _execute_ray(pending: deque[Task], *, workers: int, timeout: float | None, on_done: OnDone,
                 progress: Any, ray_address: str | None) -> None:
    try:
        import ray
    except ImportError:
        raise InputError("--executor ray needs Ray: pip install 'coster-sumo[ray]' (or pip install ray)") from None
    started_here = False
    if not ray.is_initialized():
        kwargs: dict[str, Any] = {"include_dashboard": False, "log_to_driver": False}
        if ray_address:
            kwargs["address"] = ray_address
        else:
            kwargs["num_cpus"] = workers
        ray.init(**kwargs)
        started_here = True
    remote = ray.remote(num_cpus=1, max_calls=1, max_retries=0)(_ray_entry)
    running: dict[Any, tuple[Task, float]] = {}
    try:
        while pending or running:
            while pending and len(running) < workers:
                task = pending.popleft()
                running[remote.remote(task.fn, task.payload)] = (task, time.monotonic())
            now = time.monotonic()
            wait_s = 1.0
            if timeout is not None:
                wait_s = max(0.01, min([wait_s] + [s + timeout - now for _, s in running.values()]))
            ready, _ = ray.wait(list(running), num_returns=1, timeout=wait_s)
            now = time.monotonic()
            for ref in list(running):
                task, start = running[ref]
                outcome: Outcome | None = None
                if ref in ready:
                    try:
                        outcome = Outcome(True, value=ray.get(ref), wall_time_s=now - start)
                    except ray.exceptions.RayTaskError as exc:
                        cause = exc.as_instanceof_cause() if hasattr(exc, "as_instanceof_cause") else exc
                        outcome = Outcome(False, reason=_one_line(getattr(cause, "cause", None) or cause),
                                          wall_time_s=now - start, detail=str(exc))
                    except Exception as exc:  # noqa: BLE001 - WorkerCrashedError, ...
                        outcome = Outcome(False, reason=f"crashed ({_one_line(exc)[:200]})", wall_time_s=now - start)
                elif timeout is not None and now - start > timeout:
                    with contextlib.suppress(Exception):
                        ray.cancel(ref, force=True)
                    outcome = Outcome(False, reason=f"timed out after {timeout:g} s (killed)", wall_time_s=now - start)
                if outcome is not None:
                    del running[ref]
                    pending.extend(on_done(task, outcome))
                    progress.update(1)
    finally:
        for ref in running:
            with contextlib.suppress(Exception):
                ray.cancel(ref, force=True)
        if started_here:
            ray.shutdown()


class _NoProgress:
    total = 0

    def update(self, n: int = 1) -> None:
        pass

    def refresh(self) -> None:
        pass

    def close(self) -> None:
        pass


def execute(tasks: Iterable[Task], *, on_done: OnDone | None = None, workers: int = 1,
            executor: str = "local", timeout: float | None = DEFAULT_TIMEOUT_S, quiet: bool = True,
            desc: str = "tasks", expected_total: int | None = None, start_method: str | None = None,
            log_dir: Path | None = None, ray_address: str | None = None,
            preload: Sequence[str] = ()) -> list[tuple[Task, Outcome]]:
    """Run ``tasks`` (and whatever ``on_done`` schedules) and return every (task, outcome) in finish order.

    Args:
        on_done: called in this process as each task finishes; returns further tasks.
        workers: tasks at a time.
        executor: "local" (one ``multiprocessing`` process per task) or "ray".
        timeout: [s] wall clock per task; None = unlimited.
        quiet: no progress bar.
        expected_total: the progress bar's first total estimate (it grows when needed).
        start_method: "fork" (default where available) or "spawn" (local executor).
        log_dir: the local executor sends each task's stdout/stderr to ``log_dir/<key>.log``.
        ray_address: Ray cluster address (default: start a local Ray instance).
        preload: modules imported here first, so that forked task processes inherit them instead of
            importing them again (about 1 s per task for the SUMO side of the package).
    """
    if workers < 1:
        raise InputError(f"--workers must be >= 1, not {workers}")
    if executor not in ("local", "ray"):
        raise InputError(f"--executor must be local or ray, not {executor!r}")
    pending = deque(tasks)
    finished: list[tuple[Task, Outcome]] = []
    if executor == "local" and (start_method or _default_start_method()) == "fork":
        import importlib
        import io

        for name in preload:  # quietly: libsumo prints a version warning about pyarrow on import
            with contextlib.suppress(Exception), contextlib.redirect_stdout(io.StringIO()), \
                    contextlib.redirect_stderr(io.StringIO()):
                importlib.import_module(name)
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
        if log_dir is not None:
            log_dir.mkdir(parents=True, exist_ok=True)
        if executor == "local":
            _execute_local(pending, workers=workers, timeout=timeout, on_done=done, progress=progress,
                           start_method=start_method, log_dir=log_dir)
        else:
            _execute_ray(pending, workers=workers, timeout=timeout, on_done=done, progress=progress,
                         ray_address=ray_address)
    finally:
        progress.total = len(finished)  # the estimate may have been high (fewer variants than asked)
        progress.refresh()
        progress.close()
    return finished


def probe_task(payload: dict[str, Any]) -> dict[str, Any]:
    """A task for testing executors: ``mode`` = ok | error | segfault | hang | exit; ``sleep`` [s] first.

    Returns its name, pid and the wall-clock interval [start, end] (epoch seconds) of its sleep.
    """
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


# modules every SUMO task needs; never torch (forking after torch has started its thread pools is unsafe)
SUMO_TASK_MODULES = ("libsumo", "coster_sumo.pipeline", "coster_sumo.sim.inject", "coster_sumo.outputs",
                     "coster_sumo.drivable", "pyarrow.parquet")


# ============================================================================ statistics


def wilson_interval(successes: int, n: int, z: float = WILSON_Z) -> tuple[float, float]:
    """Wilson score interval of a binomial proportion (95 % by default); (nan, nan) when n = 0."""
    if n <= 0:
        return float("nan"), float("nan")
    p = successes / n
    z2 = z * z
    centre = (p + z2 / (2 * n)) / (1 + z2 / n)
    half = z / (1 + z2 / n) * math.sqrt(p * (1 - p) / n + z2 / (4 * n * n))
    return max(0.0, centre - half), min(1.0, centre + half)


def rate_with_ci(flags: Sequence[bool]) -> dict[str, Any]:
    """{"rate", "ci_low", "ci_high", "k", "n"} of boolean outcomes (Wilson 95 %)."""
    n = len(flags)
    k = int(sum(bool(f) for f in flags))
    lo, hi = wilson_interval(k, n)
    return {"rate": k / n if n else None, "ci_low": lo if n else None, "ci_high": hi if n else None, "k": k, "n": n}


# ============================================================================ scene sources


@dataclass(frozen=True)
class SceneSpec:
    """One scene of a batch: a configuration, its seed and time window, and the target."""

    config: Path
    seed: int = 0
    begin: float | None = None
    end: float | None = None
    target: str | None = None

    def label(self) -> str:
        parts = [f"{self.config}", f"seed={self.seed}"]
        if self.begin is not None:
            parts.append(f"begin={self.begin:g}")
        if self.end is not None:
            parts.append(f"end={self.end:g}")
        if self.target is not None:
            parts.append(f"target={self.target}")
        return f"{parts[0]}@{','.join(parts[1:])}"


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "-", text).strip("-") or "x"


def _short_hash(obj: Any) -> str:
    return hashlib.sha1(json.dumps(obj, sort_keys=True, default=str).encode()).hexdigest()[:8]


def scene_key(spec: SceneSpec, generation: dict[str, Any] | None = None) -> str:
    """A readable, stable, file-safe key: ``<config stem>_s<seed>[_b<begin>][_e<end>]_<hash>``."""
    name = f"{_slug(spec.config.stem)}_s{spec.seed}"
    if spec.begin is not None:
        name += f"_b{spec.begin:g}"
    if spec.end is not None:
        name += f"_e{spec.end:g}"
    ident = {"config": str(spec.config.resolve()), "seed": spec.seed, "begin": spec.begin, "end": spec.end,
             "target": spec.target, "generation": generation or {}}
    return f"{name}_{_short_hash(ident)}"


def _parse_overrides(text: str, where: str) -> dict[str, str]:
    out: dict[str, str] = {}
    for item in filter(None, (s.strip() for s in text.split(","))):
        k, eq, v = item.partition("=")
        if not eq or k not in ("seed", "seeds", "begin", "end", "target"):
            raise InputError(f"{where}: bad override {item!r}; use seed=N, seeds=N, begin=S, end=S or target=ID")
        out[k] = v
    return out


def parse_sources(sources: Sequence[str | Path], *, seed: int = 0, seeds: int = 1, begin: float | None = None,
                  end: float | None = None, target: str | None = None) -> list[SceneSpec]:
    """Expand scene sources into scenes (module docstring); duplicates are dropped, order kept.

    ``CFG@seed=3`` fixes the seed; ``seeds=N`` (per source or the keyword) makes N scenes with seeds
    seed, seed+1, ...; ``begin``/``end`` [s] bound the window; ``target`` names the target vehicle.
    """
    specs: list[SceneSpec] = []

    def add(path: Path, ov: dict[str, str], where: str, depth: int) -> None:
        if depth > 8:
            raise InputError(f"{where}: source lists nest too deeply")
        if path.is_dir():
            cfgs = sorted(p for p in path.rglob("*.sumocfg") if "export" not in p.relative_to(path).parts)
            if not cfgs:
                raise InputError(f"{path}: no .sumocfg below this folder")
            for c in cfgs:
                add(c, ov, where, depth + 1)
            return
        if not path.exists():
            raise InputError(f"{path}: no such scene source (a .sumocfg, a folder of scenes or a list file)")
        if path.suffix == ".sumocfg":
            try:
                s0 = int(ov["seed"]) if "seed" in ov else seed
                n = int(ov.get("seeds", seeds)) if "seed" not in ov else 1
                b = float(ov["begin"]) if "begin" in ov else begin
                e = float(ov["end"]) if "end" in ov else end
            except ValueError as exc:
                raise InputError(f"{where}: bad override value ({exc})") from None
            if n < 1:
                raise InputError(f"{where}: seeds must be >= 1")
            for i in range(n):
                specs.append(SceneSpec(path, s0 + i, b, e, ov.get("target", target)))
            return
        for ln_no, line in enumerate(path.read_text().splitlines(), 1):
            line = line.split("#", 1)[0].strip()
            if line:
                p_text, _, o_text = line.partition("@")
                sub = Path(p_text)
                sub = sub if sub.is_absolute() else path.parent / sub
                add(sub, {**ov, **_parse_overrides(o_text, f"{path}:{ln_no}")}, f"{path}:{ln_no}", depth + 1)

    for src in sources:
        text = str(src)
        p_text, _, o_text = text.partition("@")
        add(Path(p_text), _parse_overrides(o_text, text), text, 0)
    seen: set[SceneSpec] = set()
    unique = []
    for s in specs:
        if s not in seen:
            seen.add(s)
            unique.append(s)
    return unique


# ============================================================================ generation

GENERATION_KEYS = ("init", "rollout", "collision_time", "variants", "samples")


def _atomic_json(path: Path, obj: Any) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(obj, indent=1, default=_json_default))
    os.replace(tmp, path)


def _json_default(o: Any) -> Any:
    if isinstance(o, np.generic):
        return o.item()
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    return str(o)


def _plan_once(scene: Scene, target: int, opts: RunOptions, drivable: DrivableArea) -> PlannedScenario:
    """One draw of snapshot + plans (pipeline.plan_scenario)."""
    from coster_sumo import pipeline

    return pipeline.plan_scenario(scene, target, opts, drivable)


def derived_seed(seed: int, j: int) -> int:
    """The seed of extra draw ``j`` (j >= 1) of a scene: deterministic, far from seed + small ints."""
    return int.from_bytes(hashlib.sha1(f"{seed}/{j}".encode()).digest()[:4], "little")


def generate_variants(scene: Scene, target: int, opts: RunOptions, drivable: DrivableArea,
                      max_draws: int | None = None) -> tuple[list[dict[str, Any]], dict[str, Any]]:
    """Up to ``opts.variants`` variants: [{"plan": AdversaryPlan dict, "snapshot": dict, "draw": j}], info.

    The CVAE gives K representatives per snapshot in one draw. A single-trajectory rollout (the
    constant-velocity baseline) gives one, so further draws with derived seeds (a new snapshot each,
    through the random init or the prior's sampling) fill up to K. Draw 0 uses ``opts.seed`` itself,
    so variant 0 equals ``coster-sumo run`` with the same options.
    """
    from coster_sumo.snapshot import NoSnapshot

    variants: list[dict[str, Any]] = []
    infos: list[dict[str, Any]] = []
    reasons: list[str] = []
    max_draws = max_draws if max_draws is not None else 3 * opts.variants
    for j in range(max_draws):
        if len(variants) >= opts.variants:
            break
        o = opts if j == 0 else dataclasses.replace(opts, seed=derived_seed(opts.seed, j))
        try:
            planned = _plan_once(scene, target, o, drivable)
        except NoSnapshot as exc:
            reasons.append(f"draw {j}: {exc}")
            if opts.rollout != "cv":
                break  # the CVAE already tried its K; another seed rarely changes a scene without snapshot
            continue
        infos.append({k: v for k, v in planned.info.items() if k != "dropped"} | {"draw": j, "seed": o.seed})
        for plan in planned.plans:
            if len(variants) >= opts.variants:
                break
            plan = dataclasses.replace(plan, vehicle_id=f"adversary{len(variants)}")
            variants.append({"plan": plan.to_dict(), "snapshot": planned.snapshot.to_dict(), "draw": j})
        if opts.rollout != "cv" and len(variants) >= len(planned.plans):
            break  # the CVAE's K representatives are the variants
    if not variants:
        raise NoSnapshot("; ".join(reasons[:3]) or "no variant")
    return variants, {"draws": infos, "rejected_draws": reasons}


def nominal_for(spec: SceneSpec, cache_dir: Path) -> tuple[Scene, bool, Path]:
    """The nominal 10 Hz scene of ``spec`` (recorded once, cached as ``cache_dir/<key>.npz``)."""
    from coster_sumo.pipeline import RunOptions, converted_scene_file, nominal_scene
    from coster_sumo.scene import load_scene, save_scene

    key = scene_key(spec)
    path = cache_dir / f"{key}.npz"
    converted = converted_scene_file(spec.config) is not None
    if path.exists():
        return load_scene(path), converted, path
    scene, converted = nominal_scene(RunOptions(config=spec.config, out=cache_dir, begin=spec.begin, end=spec.end,
                                                seed=spec.seed))
    cache_dir.mkdir(parents=True, exist_ok=True)
    tmp = cache_dir / f".{key}.{os.getpid()}.tmp.npz"
    save_scene(scene, tmp)
    os.replace(tmp, path)
    return scene, converted, path


def _spec_from(payload: dict[str, Any]) -> SceneSpec:
    s = payload["spec"]
    return SceneSpec(Path(s["config"]), int(s["seed"]), s.get("begin"), s.get("end"), s.get("target"))


def _spec_dict(spec: SceneSpec) -> dict[str, Any]:
    return {"config": str(spec.config), "seed": spec.seed, "begin": spec.begin, "end": spec.end,
            "target": spec.target}


def _run_options(spec: SceneSpec, gen: dict[str, Any], out: Path) -> RunOptions:
    from coster_sumo.pipeline import RunOptions

    return RunOptions(config=spec.config, out=out, target=spec.target, begin=spec.begin, end=spec.end,
                      seed=spec.seed, samples=int(gen.get("samples", 1000)), variants=int(gen.get("variants", 5)),
                      collision_time=str(gen.get("collision_time", "entropy")), init=str(gen.get("init", "snapshot")),
                      rollout=str(gen.get("rollout", "cvae")), render=False, quiet=True,
                      models_dir=Path(gen["models_dir"]) if gen.get("models_dir") else None)


def generation_task(payload: dict[str, Any]) -> dict[str, Any]:
    """Task: nominal pass + variants of one scene -> ``plans/<scene_key>.json`` (+ the scene's .npz)."""
    from coster_sumo.drivable import DrivableArea
    from coster_sumo.pipeline import choose_target

    t0 = time.perf_counter()
    spec = _spec_from(payload)
    plans_dir = Path(payload["plans_dir"])
    gen = payload["generation"]
    scene, converted, scene_file = nominal_for(spec, plans_dir)
    target = choose_target(scene, spec.target, spec.config)
    if scene.tracks.valid[target].sum() < 2:
        raise InputError(f"{spec.config}: target {str(scene.tracks.ids[target])!r} never departs in the window")
    drivable = DrivableArea.from_road_map(scene.road_map)
    t1 = time.perf_counter()
    variants, info = generate_variants(scene, target, _run_options(spec, gen, plans_dir), drivable)
    doc = {"scene_key": payload["scene_key"], "status": "ok", "spec": _spec_dict(spec), "converted": converted,
           "scene_file": scene_file.name, "target_id": str(scene.tracks.ids[target]),
           "end": float(scene.timestamps[-1]), "generation": gen, "variants": variants, "info": info,
           "timings_s": {"nominal": round(t1 - t0, 3), "generation": round(time.perf_counter() - t1, 3)}}
    _atomic_json(plans_dir / f"{payload['scene_key']}.json", doc)
    return {"scene_key": payload["scene_key"], "variants": len(variants)}


# ============================================================================ planner runs


def _target_path(res: Any, target_id: str, every: int = 5) -> list[list[float]]:
    t = res.scene.tracks
    if target_id not in set(t.ids.tolist()):
        return []
    a = t.index_of(target_id)
    steps = np.flatnonzero(t.valid[a])[::every]
    return [[round(float(t.x[a, s]), 2), round(float(t.y[a, s]), 2)] for s in steps]


def run_task(payload: dict[str, Any]) -> dict[str, Any]:
    """Task: one planner on one variant of one scene -> a result row (:data:`RESULT_FIELDS`)."""
    from coster_sumo.drivable import DrivableArea
    from coster_sumo.outputs import variant_record
    from coster_sumo.pipeline import log_actors, replay_planner_for
    from coster_sumo.planners import make_planner
    from coster_sumo.scene import load_scene
    from coster_sumo.sim.inject import run_injection
    from coster_sumo.sim.plan import AdversaryPlan

    plans_dir = Path(payload["plans_dir"])
    doc = json.loads((plans_dir / f"{payload['scene_key']}.json").read_text())
    scene = load_scene(plans_dir / doc["scene_file"])
    spec = _spec_from(doc)
    i = int(payload["variant"])
    v = doc["variants"][i]
    plan = AdversaryPlan.from_dict(v["plan"])
    target_id = doc["target_id"]
    target = scene.tracks.index_of(target_id)
    drivable = DrivableArea.from_road_map(scene.road_map)
    planner = make_planner(payload["planner"], replay_planner_for(scene, target))
    actors = log_actors(spec.config, scene, exclude={target_id}) if doc["converted"] else ()
    t_col = float(v["snapshot"]["time"])
    with tempfile.TemporaryDirectory(prefix="coster-run-") as wd:
        res = run_injection(spec.config, target_id, plan, planner, seed=spec.seed, end=float(doc["end"]) + 1e-9,
                            begin=spec.begin, drivable=drivable, actors=actors, workdir=Path(wd))
    rec = variant_record(i, plan, res, target_id, t_col)
    target_any = any(e.kind == "collision" and target_id in e.vehicles for e in res.events)
    return _row(payload, status="ok", reason="", collision=bool(rec["collision"]) or target_any,
                adversary_contact=bool(rec["collision"]),
                target_other_collision=any(e.kind == "collision" and target_id in e.vehicles
                                           and plan.vehicle_id not in e.vehicles for e in res.events),
                target_off_road=bool(res.target_off_road), adversary_off_road=bool(res.adversary_off_road),
                route_completed=bool(res.route_completed), target_arrived=bool(res.target_arrived),
                min_ttc=rec["min_ttc"], contact_time=rec["collision_time"], contact_offset_s=rec["contact_offset_s"],
                relative_speed=rec["relative_speed"], impact_angle=rec["impact_angle"],
                sumo_reported_contact=bool(rec["sumo_reported_contact"]), t_col=t_col,
                sim_wall_time_s=float(res.wall_time_s), target_path=json.dumps(_target_path(res, target_id)))


RESULT_FIELDS: dict[str, str] = {
    # name: pyarrow type name; see the README "regress" section for meanings and units
    "run_key": "string", "scene_key": "string", "config": "string", "seed": "int64", "variant": "int64",
    "planner": "string", "status": "string", "reason": "string",
    "collision": "bool", "adversary_contact": "bool", "target_other_collision": "bool",
    "target_off_road": "bool", "adversary_off_road": "bool", "route_completed": "bool", "target_arrived": "bool",
    "min_ttc": "float64", "contact_time": "float64", "contact_offset_s": "float64", "relative_speed": "float64",
    "impact_angle": "float64", "sumo_reported_contact": "bool", "t_col": "float64",
    "sim_wall_time_s": "float64", "wall_time_s": "float64", "target_path": "string", "finished_at": "string",
}


def _row(payload: dict[str, Any], **values: Any) -> dict[str, Any]:
    row: dict[str, Any] = dict.fromkeys(RESULT_FIELDS)
    row.update({"run_key": payload["run_key"], "scene_key": payload["scene_key"], "config": payload.get("config"),
                "seed": payload.get("seed"), "variant": int(payload["variant"]), "planner": payload["planner"]})
    row.update(values)
    return row


def result_schema() -> Any:
    import pyarrow as pa

    types = {"string": pa.string(), "int64": pa.int64(), "float64": pa.float64(), "bool": pa.bool_()}
    return pa.schema([(k, types[t]) for k, t in RESULT_FIELDS.items()])


class ResultStore:
    """``OUT/results/``: one Parquet part file per run, ``<run_key>.parquet``, written atomically.

    Temporary files start with "." so that readers (``pyarrow.dataset``) ignore them.
    """

    def __init__(self, folder: Path) -> None:
        self.folder = Path(folder)
        self.folder.mkdir(parents=True, exist_ok=True)

    def path(self, run_key: str) -> Path:
        return self.folder / f"{run_key}.parquet"

    def write(self, row: dict[str, Any]) -> Path:
        import pyarrow as pa
        import pyarrow.parquet as pq

        row = {**dict.fromkeys(RESULT_FIELDS), **row,
               "finished_at": row.get("finished_at") or time.strftime("%Y-%m-%dT%H:%M:%S")}
        for k in ("min_ttc", "contact_time", "contact_offset_s", "relative_speed", "impact_angle"):
            if isinstance(row[k], float) and not math.isfinite(row[k]):
                row[k] = None
        table = pa.Table.from_pylist([row], schema=result_schema())
        final = self.path(row["run_key"])
        tmp = self.folder / f".{row['run_key']}.{os.getpid()}.tmp"
        pq.write_table(table, tmp)
        os.replace(tmp, final)
        return final

    def keys(self) -> set[str]:
        return {p.stem for p in self.folder.glob("*.parquet") if not p.name.startswith(".")}

    def read(self) -> list[dict[str, Any]]:
        import pyarrow.dataset as ds

        if not self.keys():
            return []
        return ds.dataset(self.folder, format="parquet", schema=result_schema()).to_table().to_pylist()


# ============================================================================ regression


@dataclass
class RegressOptions:
    """Everything ``coster-sumo regress`` takes (see its --help)."""

    sources: list[str]
    planners: list[str]
    out: Path
    variants: int = 3
    workers: int = 1
    executor: str = "local"
    timeout: float | None = DEFAULT_TIMEOUT_S
    seed: int = 0
    seeds: int = 1
    begin: float | None = None
    end: float | None = None
    target: str | None = None
    init: str = "snapshot"
    rollout: str = "cvae"
    collision_time: str = "entropy"
    samples: int = 1000
    models_dir: Path | None = None
    retry_failed: bool = False
    report: bool = True
    quiet: bool = False
    ray_address: str | None = None
    start_method: str | None = None


def run_key(scene: str, variant: int, planner: str) -> str:
    return f"{scene}__v{variant}__{_slug(planner)}"


def check_generation_inputs(init: str, rollout: str, collision_time: str, models_dir: Path | None) -> None:
    """Option values, and weights that the chosen methods need (exit 2 before any work)."""
    for name, value, allowed in (("--collision-time", collision_time, ("entropy", "last", "random")),
                                 ("--init", init, ("snapshot", "random")), ("--rollout", rollout, ("cvae", "cv"))):
        if value not in allowed:
            raise InputError(f"{name} must be one of {', '.join(allowed)}, not {value!r}")
    reason = missing_weights(init, rollout, models_dir)
    if reason:
        raise InputError(f"{reason}; the weight-free baselines are --init random --rollout cv")


def missing_weights(init: str, rollout: str, models_dir: Path | None) -> str | None:
    """Why the method (init, rollout) cannot run here, or None."""
    import importlib.util

    from coster_sumo.models import model_path

    if init == "snapshot":
        try:
            model_path("prior.pt", models_dir)
        except InputError as exc:
            return str(exc)
    if rollout == "cvae":
        try:
            found = importlib.util.find_spec("coster_sumo.rollout.sample") is not None
        except ModuleNotFoundError:
            found = False
        if not found:
            return "the CVAE rollout (coster_sumo.rollout) is not installed in this version"
    return None


def _check_planners(planners: Sequence[str]) -> None:
    from coster_sumo.planners import ReplayPlanner, make_planner

    if not planners:
        raise InputError("give at least one --planner")
    if len(set(planners)) != len(planners) or len({_slug(p) for p in planners}) != len(planners):
        raise InputError(f"--planner values must be distinct: {', '.join(planners)}")
    dummy = ReplayPlanner(np.zeros(1), np.zeros(1), np.zeros(1), np.zeros(1), np.zeros(1), np.ones(1, bool), 4.5)
    for p in planners:
        make_planner(p, dummy)


def regress(opts: RegressOptions) -> dict[str, Any]:
    """Run the regression (module docstring); returns the summary (also OUT/summary.json)."""
    t_start = time.perf_counter()
    _check_planners(opts.planners)
    if opts.variants < 1:
        raise InputError("--variants must be >= 1")
    check_generation_inputs(opts.init, opts.rollout, opts.collision_time, opts.models_dir)
    specs = parse_sources(opts.sources, seed=opts.seed, seeds=opts.seeds, begin=opts.begin, end=opts.end,
                          target=opts.target)
    out = Path(opts.out)
    plans_dir, logs_dir = out / "plans", out / "logs"
    plans_dir.mkdir(parents=True, exist_ok=True)
    store = ResultStore(out / "results")
    gen = {"init": opts.init, "rollout": opts.rollout, "collision_time": opts.collision_time,
           "variants": opts.variants, "samples": opts.samples,
           "models_dir": str(opts.models_dir) if opts.models_dir else None}
    keys = {scene_key(s, gen): s for s in specs}
    _atomic_json(out / "regress.json", {"options": {k: (str(v) if isinstance(v, Path) else v)
                                                    for k, v in dataclasses.asdict(opts).items()},
                                        "scenes": {k: s.label() for k, s in keys.items()}})
    existing = store.read() if opts.retry_failed else []
    failed_runs = {r["run_key"] for r in existing if r["status"] != "ok"}
    done = store.keys() - failed_runs
    n_runs_expected = len(keys) * opts.variants * len(opts.planners)

    def run_tasks_for(key: str, doc: dict[str, Any]) -> list[Task]:
        spec = keys[key]
        tasks = []
        for i in range(len(doc["variants"])):
            for p in opts.planners:
                rk = run_key(key, i, p)
                if rk not in done:
                    tasks.append(Task(rk, run_task, {"run_key": rk, "scene_key": key, "variant": i, "planner": p,
                                                     "plans_dir": str(plans_dir), "config": str(spec.config),
                                                     "seed": spec.seed}, kind="run"))
        return tasks

    initial: list[Task] = []
    for key, spec in keys.items():
        pf = plans_dir / f"{key}.json"
        doc = _read_json(pf)
        if doc is not None and (doc.get("status") == "ok" or not opts.retry_failed):
            if doc.get("status") == "ok":
                initial.extend(run_tasks_for(key, doc))
            continue
        initial.append(Task(f"plan__{key}", generation_task, {"scene_key": key, "spec": _spec_dict(spec),
                                                             "plans_dir": str(plans_dir), "generation": gen},
                            kind="plan"))

    def on_done(task: Task, outcome: Outcome) -> list[Task]:
        key = task.payload["scene_key"]
        if task.kind == "plan":
            if outcome.ok:
                doc = _read_json(plans_dir / f"{key}.json")
                return run_tasks_for(key, doc) if doc else []
            _atomic_json(plans_dir / f"{key}.json", {"scene_key": key, "status": "failed", "reason": outcome.reason,
                                                     "spec": task.payload["spec"], "generation": gen})
            _append_log(logs_dir / f"{task.key}.log", outcome)
            return []
        if outcome.ok:
            row = {**outcome.value, "wall_time_s": round(outcome.wall_time_s, 3)}
        else:
            _append_log(logs_dir / f"{task.key}.log", outcome)
            row = _row(task.payload, status="failed", reason=outcome.reason, wall_time_s=round(outcome.wall_time_s, 3))
        store.write(row)
        return []

    execute(initial, on_done=on_done, workers=opts.workers, executor=opts.executor, timeout=opts.timeout,
            quiet=opts.quiet, desc="regress", expected_total=len(initial) + n_runs_expected - len(done),
            start_method=opts.start_method, log_dir=logs_dir if opts.executor == "local" else None,
            ray_address=opts.ray_address, preload=SUMO_TASK_MODULES)
    summary = summarize_regression(out, keys, opts.planners)
    summary["wall_time_s"] = round(time.perf_counter() - t_start, 3)
    summary["options"] = {"variants": opts.variants, "workers": opts.workers, "executor": opts.executor,
                          "timeout_s": opts.timeout, **{k: gen[k] for k in GENERATION_KEYS}, "seed": opts.seed}
    _atomic_json(out / "summary.json", summary)  # before the report: a plotting failure loses no result
    if opts.report:
        from coster_sumo.report import write_regression_report

        summary["report"] = write_regression_report(out, summary, store.read())
        _atomic_json(out / "summary.json", summary)
    return summary


def _append_log(path: Path, outcome: Outcome) -> None:
    if not outcome.detail:
        return
    with contextlib.suppress(OSError):
        path.parent.mkdir(parents=True, exist_ok=True)
        with path.open("a") as fh:
            fh.write("\n--- batch: task failed ---\n" + outcome.detail)


def _read_json(path: Path) -> dict[str, Any] | None:
    if not path.exists():
        return None
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def summarize_regression(out: Path, keys: dict[str, SceneSpec], planners: Sequence[str]) -> dict[str, Any]:
    """summary.json content of a regression over ``keys`` x ``planners`` (rows already in OUT/results)."""
    plans_dir = out / "plans"
    rows = [r for r in ResultStore(out / "results").read() if r["scene_key"] in keys and r["planner"] in planners]
    scenes_failed, n_variants = [], 0
    for key, spec in keys.items():
        doc = _read_json(plans_dir / f"{key}.json") or {"status": "failed", "reason": "not generated"}
        if doc.get("status") == "ok":
            n_variants += len(doc["variants"])
        else:
            scenes_failed.append({"scene_key": key, "scene": spec.label(), "reason": doc.get("reason")})
    per_planner: dict[str, Any] = {}
    for p in planners:
        mine = [r for r in rows if r["planner"] == p]
        ok = [r for r in mine if r["status"] == "ok"]
        ttc = [r["min_ttc"] for r in ok if r["min_ttc"] is not None and not r["adversary_contact"]]
        rel = [r["relative_speed"] for r in ok if r["relative_speed"] is not None]
        per_planner[p] = {
            "runs": len(mine), "failed": len(mine) - len(ok),
            "RCR": rate_with_ci([r["route_completed"] for r in ok]),
            "CR": rate_with_ci([r["collision"] for r in ok]),
            "ORR": rate_with_ci([r["target_off_road"] for r in ok]),
            "adversary_contact_rate": rate_with_ci([r["adversary_contact"] for r in ok]),
            "median_min_ttc_s": float(np.median(ttc)) if ttc else None,
            "mean_relative_speed_mps": float(np.mean(rel)) if rel else None,
        }
    failures = [{"run_key": r["run_key"], "reason": r["reason"]} for r in rows if r["status"] != "ok"]
    return {
        "command": "regress",
        "scenes": {"total": len(keys), "generated": len(keys) - len(scenes_failed), "failed": scenes_failed},
        "variants": n_variants,
        "runs": {"expected": n_variants * len(planners), "recorded": len(rows), "ok": len(rows) - len(failures),
                 "failed": len(failures), "failures": failures},
        "planners": per_planner,
        "results": "results/ (Parquet dataset, one part per run)",
        "units": {"rates": "fraction of runs, Wilson 95% interval", "min_ttc": "s", "relative_speed": "m/s",
                  "impact_angle": "deg"},
    }


def regression_exit_code(summary: dict[str, Any]) -> int:
    """0 when every scene generated and every run finished; 1 otherwise (DESIGN contracts)."""
    return 1 if summary["scenes"]["failed"] or summary["runs"]["failed"] else 0


# ============================================================================ generator evaluation


@dataclass(frozen=True)
class GeneratorMethod:
    """One scenario generator of the evaluation table."""

    name: str
    init: str
    rollout: str
    collision_time: str = "entropy"
    group: str = "main"  # "main" | "ablation" (collision time) | "baseline"


GENERATOR_METHODS: tuple[GeneratorMethod, ...] = (
    GeneratorMethod("COSTER", "snapshot", "cvae", "entropy"),
    GeneratorMethod("Random+CVAE", "random", "cvae", "entropy"),
    GeneratorMethod("Snapshot+CV", "snapshot", "cv", "entropy"),
    GeneratorMethod("Random+CV", "random", "cv", "last", group="baseline"),
    GeneratorMethod("COSTER t_col=last", "snapshot", "cvae", "last", group="ablation"),
    GeneratorMethod("COSTER t_col=random", "snapshot", "cvae", "random", group="ablation"),
)


@dataclass
class EvalOptions:
    """Everything ``coster-sumo eval scenarios`` takes."""

    sources: list[str]
    out: Path
    methods: list[str] | None = None  # names of GENERATOR_METHODS (default: all)
    planner: str = "replay"
    variants: int = 5
    samples: int = 1000
    workers: int = 1
    executor: str = "local"
    timeout: float | None = DEFAULT_TIMEOUT_S
    seed: int = 0
    seeds: int = 1
    begin: float | None = None
    end: float | None = None
    target: str | None = None
    models_dir: Path | None = None
    quiet: bool = False
    ray_address: str | None = None


def _hist(values: np.ndarray, bins: np.ndarray, lo: float, hi: float) -> list[int]:
    return np.histogram(np.clip(values, lo, hi), bins=bins)[0].astype(int).tolist()


def scene_task(payload: dict[str, Any]) -> dict[str, Any]:
    """Eval task: nominal pass of one scene (cached .npz) and its speed/acceleration histograms."""
    from coster_sumo.metrics import ACCEL_BINS, SPEED_BINS, speeds_and_accels
    from coster_sumo.pipeline import choose_target

    spec = _spec_from(payload)
    scene, _, path = nominal_for(spec, Path(payload["scenes_dir"]))
    choose_target(scene, spec.target, spec.config)
    t = scene.tracks
    v, a = speeds_and_accels(t.xy, t.valid, scene.dt)
    return {"scene_file": path.name, "speed_hist": _hist(v, SPEED_BINS, 0, 50),
            "accel_hist": _hist(a, ACCEL_BINS, -10, 10)}


def method_task(payload: dict[str, Any]) -> dict[str, Any]:
    """Eval task: one generator on one scene; every variant injected; per-variant records + histograms."""
    from coster_sumo.drivable import DrivableArea
    from coster_sumo.metrics import ACCEL_BINS, SPEED_BINS, speeds_and_accels
    from coster_sumo.pipeline import choose_target, log_actors, replay_planner_for
    from coster_sumo.planners import make_planner
    from coster_sumo.scene import load_scene
    from coster_sumo.sim.inject import run_injection
    from coster_sumo.sim.plan import AdversaryPlan
    from coster_sumo.snapshot import NoSnapshot

    spec = _spec_from(payload)
    scenes_dir = Path(payload["scenes_dir"])
    scene = load_scene(scenes_dir / payload["scene_file"])
    converted = (spec.config.parent / "scene.npz").exists()
    target = choose_target(scene, spec.target, spec.config)
    target_id = str(scene.tracks.ids[target])
    drivable = DrivableArea.from_road_map(scene.road_map)
    m = payload["method"]
    gen = {"init": m["init"], "rollout": m["rollout"], "collision_time": m["collision_time"],
           "variants": payload["variants"], "samples": payload["samples"], "models_dir": payload.get("models_dir")}
    reason = missing_weights(m["init"], m["rollout"], Path(gen["models_dir"]) if gen["models_dir"] else None)
    if reason:
        return {"status": "skipped", "reason": reason}
    t0 = time.perf_counter()
    try:
        variants, _ = generate_variants(scene, target, _run_options(spec, gen, scenes_dir), drivable)
    except NoSnapshot as exc:
        return {"status": "no_scenario", "reason": str(exc), "generation_s": time.perf_counter() - t0,
                "records": []}
    except InputError as exc:
        if "model weights not found" in str(exc):
            return {"status": "skipped", "reason": str(exc)}
        raise
    gen_s = time.perf_counter() - t0
    records = []
    speeds, accels = [], []
    end = float(scene.timestamps[-1]) + 1e-9
    for i, v in enumerate(variants):
        plan = AdversaryPlan.from_dict(v["plan"])
        planner = make_planner(payload["planner"], replay_planner_for(scene, target))
        actors = log_actors(spec.config, scene, exclude={target_id}) if converted else ()
        with tempfile.TemporaryDirectory(prefix="coster-eval-") as wd:
            res = run_injection(spec.config, target_id, plan, planner, seed=spec.seed, end=end, begin=spec.begin,
                                drivable=drivable, actors=actors, workdir=Path(wd))
        c = res.contact
        records.append({"variant": i, "collision": c is not None, "adversary_off_road": res.adversary_off_road,
                        "relative_speed": c.relative_speed if c else None,
                        "impact_angle": c.impact_angle if c else None, "t_col": v["snapshot"]["time"]})
        tr = res.scene.tracks
        if plan.vehicle_id in set(tr.ids.tolist()):
            a = tr.index_of(plan.vehicle_id)
            stop = min(c.time if c else plan.t_col, plan.t_col)
            window = (res.scene.timestamps >= plan.t_start - 1e-6) & (res.scene.timestamps <= stop + 1e-6)
            sv, sa = speeds_and_accels(tr.xy[a:a + 1], (tr.valid[a] & window)[None], res.scene.dt)
            speeds.append(sv)
            accels.append(sa)
    sv = np.concatenate(speeds) if speeds else np.zeros(0)
    sa = np.concatenate(accels) if accels else np.zeros(0)
    return {"status": "ok", "records": records, "generation_s": gen_s,
            "speed_hist": _hist(sv, SPEED_BINS, 0, 50), "accel_hist": _hist(sa, ACCEL_BINS, -10, 10)}


def evaluate_generators(opts: EvalOptions) -> dict[str, Any]:
    """``coster-sumo eval scenarios``: every generator on every scene; metrics table (JSON, Markdown, PNG)."""
    t_start = time.perf_counter()
    names = opts.methods or [m.name for m in GENERATOR_METHODS]
    by_name = {m.name: m for m in GENERATOR_METHODS}
    unknown = [n for n in names if n not in by_name]
    if unknown:
        raise InputError(f"unknown method(s) {', '.join(unknown)}; choose from {', '.join(by_name)}")
    methods = [by_name[n] for n in names]
    _check_planners([opts.planner])
    specs = parse_sources(opts.sources, seed=opts.seed, seeds=opts.seeds, begin=opts.begin, end=opts.end,
                          target=opts.target)
    out = Path(opts.out)
    scenes_dir, parts_dir = out / "scenes", out / "parts"
    parts_dir.mkdir(parents=True, exist_ok=True)
    scenes_dir.mkdir(parents=True, exist_ok=True)
    skipped: dict[str, str] = {}
    for m in methods:
        reason = missing_weights(m.init, m.rollout, opts.models_dir)
        if reason:
            skipped[m.name] = reason
    active = [m for m in methods if m.name not in skipped]
    keys = {scene_key(s): s for s in specs}

    def method_tasks(key: str, scene_file: str) -> list[Task]:
        tasks = []
        for m in active:
            pk = f"{key}__{_slug(m.name)}__k{opts.variants}"
            if (parts_dir / f"{pk}.json").exists():
                continue
            tasks.append(Task(pk, method_task, {
                "part_key": pk, "scene_key": key, "spec": _spec_dict(keys[key]), "scene_file": scene_file,
                "scenes_dir": str(scenes_dir), "method": dataclasses.asdict(m), "variants": opts.variants,
                "samples": opts.samples, "planner": opts.planner,
                "models_dir": str(opts.models_dir) if opts.models_dir else None}, kind="method"))
        return tasks

    initial = []
    for key, spec in keys.items():
        sp = _read_json(parts_dir / f"{key}__scene.json")
        if sp is not None and sp.get("status") == "ok":
            initial.extend(method_tasks(key, sp["scene_file"]))
        elif sp is None:
            initial.append(Task(f"{key}__scene", scene_task, {"spec": _spec_dict(spec), "scenes_dir": str(scenes_dir),
                                                              "scene_key": key}, kind="scene"))

    def on_done(task: Task, outcome: Outcome) -> list[Task]:
        key = task.payload["scene_key"]
        if task.kind == "scene":
            doc = {"status": "ok", **outcome.value} if outcome.ok else {"status": "failed", "reason": outcome.reason}
            _atomic_json(parts_dir / f"{key}__scene.json", doc)
            return method_tasks(key, doc["scene_file"]) if outcome.ok else []
        doc = outcome.value if outcome.ok else {"status": "failed", "reason": outcome.reason}
        _atomic_json(parts_dir / f"{task.payload['part_key']}.json",
                     {**doc, "method": task.payload["method"]["name"], "scene_key": key})
        return []

    execute(initial, on_done=on_done, workers=opts.workers, executor=opts.executor, timeout=opts.timeout,
            quiet=opts.quiet, desc="eval scenarios", expected_total=len(keys) * (1 + len(active)),
            log_dir=out / "logs" if opts.executor == "local" else None, ray_address=opts.ray_address,
            preload=SUMO_TASK_MODULES)
    table = aggregate_generator_metrics(parts_dir, keys, methods, skipped, opts.variants)
    summary = {"command": "eval scenarios", "scenes": {k: s.label() for k, s in keys.items()},
               "planner": opts.planner, "variants": opts.variants, "samples": opts.samples,
               "methods": table, "wall_time_s": round(time.perf_counter() - t_start, 3),
               "units": {"SUR/CR/ORR": "fraction", "VDD/ADD": "Jensen-Shannon divergence, nats (max ln 2)",
                         "CSD": "m/s", "CPD/CPD_circular": "deg", "generation_s_per_variant": "s"}}
    _atomic_json(out / "summary.json", summary)
    from coster_sumo.report import write_generator_report

    summary["report"] = write_generator_report(out, summary)
    _atomic_json(out / "summary.json", summary)
    return summary


def aggregate_generator_metrics(parts_dir: Path, keys: dict[str, SceneSpec], methods: Sequence[GeneratorMethod],
                                skipped: dict[str, str], variants: int) -> dict[str, Any]:
    """Per method: SUR, CR, ORR (with Wilson intervals), VDD, ADD, CSD, CPD, circular CPD."""
    from coster_sumo.metrics import (
        circular_std_deg,
        collision_position_diversity,
        collision_speed_diversity,
        js_divergence,
    )

    raw_v = raw_a = None
    good_scenes = []
    failed_scenes = []
    for key in keys:
        sp = _read_json(parts_dir / f"{key}__scene.json")
        if sp is None or sp.get("status") != "ok":
            failed_scenes.append({"scene_key": key, "reason": (sp or {}).get("reason", "not run")})
            continue
        good_scenes.append(key)
        raw_v = np.add(raw_v, sp["speed_hist"]) if raw_v is not None else np.asarray(sp["speed_hist"])
        raw_a = np.add(raw_a, sp["accel_hist"]) if raw_a is not None else np.asarray(sp["accel_hist"])
    table: dict[str, Any] = {}
    for m in methods:
        entry: dict[str, Any] = {"group": m.group, "init": m.init, "rollout": m.rollout,
                                 "collision_time": m.collision_time}
        if m.name in skipped:
            table[m.name] = {**entry, "status": "skipped", "reason": skipped[m.name]}
            continue
        loaded = [_read_json(parts_dir / f"{k}__{_slug(m.name)}__k{variants}.json") for k in good_scenes]
        parts: list[dict[str, Any]] = [p for p in loaded if p is not None]
        skip = [p for p in parts if p.get("status") == "skipped"]
        if parts and len(skip) == len(parts):
            table[m.name] = {**entry, "status": "skipped", "reason": skip[0]["reason"]}
            continue
        records = [r for p in parts if p.get("status") == "ok" for r in p["records"]]
        n_scenes = len(good_scenes)
        successes = sum(True for p in parts if p.get("status") == "ok" and any(r["collision"] for r in p["records"]))
        gen_v = np.sum([p["speed_hist"] for p in parts if p.get("status") == "ok"], axis=0) if records else None
        gen_a = np.sum([p["accel_hist"] for p in parts if p.get("status") == "ok"], axis=0) if records else None
        rel = [r["relative_speed"] for r in records if r["collision"]]
        ang = [r["impact_angle"] for r in records if r["collision"]]
        gen_time = [p["generation_s"] / max(1, len(p["records"])) for p in parts
                    if p.get("status") == "ok" and p["records"]]
        cr = rate_with_ci([r["collision"] for r in records])
        orr = rate_with_ci([r["adversary_off_road"] for r in records])
        sur = rate_with_ci([True] * successes + [False] * (n_scenes - successes))

        def f(x: float | None) -> float | None:
            return None if x is None or not math.isfinite(x) else float(x)

        table[m.name] = {
            **entry, "status": "ok", "scenes": n_scenes, "variants": len(records),
            "failed_tasks": [{"scene_key": p["scene_key"], "reason": p.get("reason")} for p in parts
                             if p.get("status") == "failed"],
            "SUR": sur["rate"], "CR": cr["rate"], "ORR": orr["rate"],
            "SUR_ci": [sur["ci_low"], sur["ci_high"]], "CR_ci": [cr["ci_low"], cr["ci_high"]],
            "ORR_ci": [orr["ci_low"], orr["ci_high"]],
            "VDD": f(js_divergence(raw_v, gen_v)) if gen_v is not None and raw_v is not None else None,
            "ADD": f(js_divergence(raw_a, gen_a)) if gen_a is not None and raw_a is not None else None,
            "CSD": f(collision_speed_diversity(rel)) if rel else None,
            "CPD": f(collision_position_diversity(ang)) if ang else None,
            "CPD_circular": f(circular_std_deg(ang)) if ang else None,
            "generation_s_per_variant": float(np.mean(gen_time)) if gen_time else None,
            "relative_speeds": rel, "impact_angles": ang,
        }
    return {"table": table, "failed_scenes": failed_scenes}


def eval_exit_code(summary: dict[str, Any]) -> int:
    t = summary["methods"]
    bad = bool(t["failed_scenes"]) or any(m.get("failed_tasks") for m in t["table"].values())
    return 1 if bad else 0
