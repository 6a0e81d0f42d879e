"""The batch executor (process isolation, timeouts, crashes, resume), Wilson intervals, scene sources."""

from __future__ import annotations

import dataclasses
import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pyarrow.dataset as ds
import pytest

from coster_sumo.batch.executor import ExecutorSettings, Outcome, Task, execute, probe_task
from coster_sumo.batch.regress import run_key
from coster_sumo.batch.sources import parse_sources, scene_key
from coster_sumo.batch.store import RESULT_FIELDS, ResultRow, ResultStore, result_row
from coster_sumo.core.spec import ScenarioSpec as SceneSpec
from coster_sumo.errors import InputError
from coster_sumo.metrics import rate_with_ci, wilson_interval

REPO = Path(__file__).resolve().parents[2]
INTERSECTION = REPO / "networks" / "intersection" / "intersection.sumocfg"


def _probe(name: str, mode: str = "ok", sleep: float = 0.0) -> Task:
    return Task(name, probe_task, {"name": name, "mode": mode, "sleep": sleep})


def _outcomes(finished: list[tuple[Task, Outcome]]) -> dict[str, Outcome]:
    return {t.key: o for t, o in finished}


def test_segfault_and_hang_become_failed_outcomes_and_the_rest_finish(tmp_path):
    tasks = [_probe("a"), _probe("crash", "segfault"), _probe("b"), _probe("stuck", "hang"),
             _probe("oops", "error"), _probe("quit", "exit"), _probe("c")]
    out = _outcomes(execute(tasks, ExecutorSettings(workers=3, timeout=2.0, log_dir=tmp_path / "logs")))
    assert set(out) == {t.key for t in tasks}
    for k in ("a", "b", "c"):
        assert out[k].ok and out[k].value["name"] == k
    assert not out["crash"].ok and "SIGSEGV" in out["crash"].reason
    assert not out["stuck"].ok and "timed out after 2 s" in out["stuck"].reason
    # where it hung, from the task's own stack: the sleep in probe_task
    assert "in coster_sumo/batch/executor.py:" in out["stuck"].reason and "(probe_task)" in out["stuck"].reason
    assert "time.sleep" not in out["stuck"].reason and "Current thread" in out["stuck"].detail
    assert not out["oops"].ok and "ValueError: probe oops failed on purpose" in out["oops"].reason
    assert "Traceback" in out["oops"].detail
    assert not out["quit"].ok and "code 3" in out["quit"].reason
    # the batch adds the traceback to the task's log, where a user of --debug looks for it
    out["oops"].append_to_log(tmp_path / "logs" / "oops.log")
    out["a"].append_to_log(tmp_path / "logs" / "a.log")
    assert "ValueError: probe oops failed on purpose" in (tmp_path / "logs" / "oops.log").read_text()
    assert "task failed" not in (tmp_path / "logs" / "a.log").read_text()


def test_a_task_s_temporary_files_go_however_the_task_ends(tmp_path):
    modes = ("ok", "error", "segfault", "hang", "exit")
    tasks = [Task(m, probe_task, {"name": m, "mode": m, "note": str(tmp_path / f"{m}.txt")}) for m in modes]
    out = _outcomes(execute(tasks, ExecutorSettings(workers=2, timeout=2.0)))
    assert out["ok"].ok and not any(out[m].ok for m in modes[1:])
    for m in modes:
        made = Path((tmp_path / f"{m}.txt").read_text())
        assert made.name.startswith("probe-") and made.parent.name.startswith("coster-task-"), made
        assert not made.parent.exists(), f"{m}: {made.parent} left behind"


def test_task_folders_of_a_killed_batch_are_removed_by_the_next(tmp_path, monkeypatch):
    import tempfile

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    gone = subprocess.Popen([sys.executable, "-c", "pass"])
    gone.wait()  # a pid no process holds now
    orphan = tmp_path / f"coster-task-{gone.pid}-abc"
    alive = tmp_path / f"coster-task-{os.getppid()}-abc"  # a batch still running
    for d in (orphan, alive):
        (d / "sub").mkdir(parents=True)
    assert execute([_probe("a")])[0][1].ok
    assert not orphan.exists() and alive.exists()


def test_each_task_runs_in_its_own_process_and_on_done_can_schedule_more():
    seen: list[str] = []

    def on_done(task: Task, outcome: Outcome) -> list[Task]:
        seen.append(task.key)
        return [_probe(f"{task.key}.child")] if "." not in task.key else []

    finished = execute([_probe("p0"), _probe("p1")], ExecutorSettings(workers=2), on_done=on_done)
    pids = {o.value["pid"] for _, o in finished}
    assert len(finished) == 4 and len(pids) == 4 and os.getpid() not in pids
    assert sorted(seen) == ["p0", "p0.child", "p1", "p1.child"]


def test_spawn_start_method_works_too():
    out = _outcomes(execute([_probe("s"), _probe("boom", "segfault")],
                                    ExecutorSettings(workers=2, start_method="spawn", timeout=30)))
    assert out["s"].ok and not out["boom"].ok


def test_workers_run_in_parallel():
    out = _outcomes(execute([_probe(f"t{i}", sleep=1.0) for i in range(4)], ExecutorSettings(workers=4)))
    starts = [o.value["start"] for o in out.values()]
    ends = [o.value["end"] for o in out.values()]
    assert len(out) == 4 and max(starts) < min(ends)  # all four were sleeping at the same moment


def _thread_limits(payload: dict) -> dict:
    import torch

    return {"torch": torch.get_num_threads(), "omp": os.environ.get("OMP_NUM_THREADS")}


def test_workers_share_the_cores_instead_of_oversubscribing_them():
    """As the command line runs a batch: a driver that has not loaded torch gives each task the
    cores divided among the workers."""
    code = textwrap.dedent("""
        import json, os, sys
        from coster_sumo.batch.executor import ExecutorSettings, Task, execute
        from tests.batch.test_batch import _thread_limits
        assert "torch" not in sys.modules
        got = {w: execute([Task("t", _thread_limits, {})], ExecutorSettings(workers=w, timeout=120))[0][1].value
               for w in (1, 2, 64)}
        print(json.dumps(got))
    """)
    done = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, timeout=300,
                          env={**os.environ, "PYTHONPATH": str(REPO)})
    assert done.returncode == 0, done.stderr
    cores = os.cpu_count() or 1
    for workers, value in json.loads(done.stdout.strip().splitlines()[-1]).items():
        expect = max(1, cores // int(workers))
        assert value == {"torch": expect, "omp": str(expect)}, (workers, value)


def _torch_on_all_threads(payload: dict) -> dict:
    import torch

    x = torch.ones(512, 512)
    for _ in range(20):  # big enough for torch to start its OpenMP pool on every thread it has
        x = (x @ x).clamp(max=1.0)
    return {"torch": torch.get_num_threads(), "omp": os.environ.get("OMP_NUM_THREADS")}


def test_a_driver_that_ran_torch_starts_its_tasks_from_a_clean_fork_server():
    """A task forked from a process that has run torch hangs when it runs torch on more than one
    thread (the parent's OpenMP pool does not survive the fork). Such a driver (a test, the Python
    API) starts its tasks from a fork server that never ran a thread pool: they run torch on their
    share of the cores and return."""
    import torch

    from coster_sumo.batch.executor import _default_start_method

    x = torch.ones(256, 256)
    _ = x @ x  # the driver's OpenMP pool is up
    assert _default_start_method() == "forkserver"
    out = _outcomes(execute([Task("t", _torch_on_all_threads, {})], ExecutorSettings(workers=1, timeout=120)))
    cores = os.cpu_count() or 1
    assert out["t"].ok and out["t"].value == {"torch": cores, "omp": str(cores)}, out["t"]


@pytest.mark.parametrize(("k", "n", "low", "high"), [
    (0, 10, 0.0, 0.2775),  # Wilson 95 % for 0/10: [0, 0.2775]
    (5, 10, 0.2366, 0.7634),
    (10, 10, 0.7225, 1.0),
    (1, 2, 0.0945, 0.9055),
    (81, 263, 0.2553, 0.3662),  # Newcombe (1998) example 81/263: 0.2553-0.3662
])
def test_wilson_interval_known_values(k, n, low, high):
    lo, hi = wilson_interval(k, n)
    assert lo == pytest.approx(low, abs=1e-4)
    assert hi == pytest.approx(high, abs=1e-4)


def test_wilson_interval_empty_and_rate_helper():
    lo, hi = wilson_interval(0, 0)
    assert lo != lo and hi != hi  # nan
    r = rate_with_ci([True, False, True, True])
    assert r["rate"] == 0.75 and r["k"] == 3 and r["n"] == 4 and r["ci_low"] < 0.75 < r["ci_high"]
    assert rate_with_ci([])["rate"] is None


def test_result_store_writes_atomically_and_reads_as_a_dataset(tmp_path):
    store = ResultStore(tmp_path / "results")
    for i in range(3):
        store.write(ResultRow(run_key=run_key("scene", i, "sumo:IDM"), scene_key="scene", variant=i,
                              planner="sumo:IDM", status="ok", reason="", collision=i == 1, min_ttc=float("inf")))
    (tmp_path / "results" / ".half-written.tmp").write_bytes(b"PAR1 garbage")  # a crash mid-write
    rows = store.read()
    assert len(rows) == 3 and store.keys() == {f"scene__v{i}__sumo-IDM" for i in range(3)}
    assert sorted(r.collision for r in rows) == [False, False, True]
    assert all(r.min_ttc is None and r.finished_at for r in rows)
    assert ds.dataset(tmp_path / "results", format="parquet").count_rows() == 3
    store.write(dataclasses.replace(rows[0], status="failed"))  # rewriting a key replaces its row
    assert len(store.read()) == 3


def test_a_result_row_has_the_stored_fields_in_their_order():
    from typing import get_type_hints

    assert list(get_type_hints(ResultRow)) == list(RESULT_FIELDS)
    row = result_row({"run_key": "k", "scene_key": "s", "variant": "2", "planner": "replay"}, status="ok")
    assert list(row.to_json()) == list(RESULT_FIELDS) and row.variant == 2 and row.collision is None
    assert ResultRow.from_json(row.to_json()) == row


RESUMABLE_BATCH = textwrap.dedent("""
    import sys
    from pathlib import Path
    from coster_sumo.batch.executor import ExecutorSettings, Task, execute, probe_task
    from coster_sumo.batch.store import RESULT_FIELDS, ResultRow, ResultStore, result_row
    store = ResultStore(Path(sys.argv[1]))
    done = store.keys()
    tasks = [Task(f"run{i:02d}", probe_task, {"name": i, "sleep": 1.0}) for i in range(12) if f"run{i:02d}" not in done]
    def on_done(task, outcome):
        store.write(result_row({"run_key": task.key, "scene_key": "s", "variant": 0, "planner": "p"},
                               status="ok" if outcome.ok else "failed", reason=outcome.reason))
        return []
    execute(tasks, ExecutorSettings(workers=2), on_done=on_done)
    print(len(tasks))
""")


def test_sigkill_halfway_then_rerun_gives_every_run_exactly_once(tmp_path):
    results = tmp_path / "results"
    proc = subprocess.Popen([sys.executable, "-c", RESUMABLE_BATCH, str(results)], cwd=REPO)
    deadline = time.monotonic() + 60
    # count as the store does: a part being written when the kill lands is a hidden temporary file
    while time.monotonic() < deadline and len(ResultStore(results).keys()) < 4:
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    done_before = len(ResultStore(results).keys())
    assert 4 <= done_before < 12
    out = subprocess.run([sys.executable, "-c", RESUMABLE_BATCH, str(results)], cwd=REPO, capture_output=True,
                         text=True, check=True)
    assert int(out.stdout.split()[-1]) == 12 - done_before  # only the missing runs ran again
    rows = ResultStore(results).read()
    assert sorted(r.run_key for r in rows) == [f"run{i:02d}" for i in range(12)]
    assert all(r.ok for r in rows)


def test_parse_sources_overrides_seeds_lists_and_folders(tmp_path):
    cfg = str(INTERSECTION)
    specs = parse_sources([f"{cfg}@seed=3,begin=20,end=50", cfg], seeds=2, seed=10)
    assert specs == [SceneSpec(INTERSECTION, 3, 20.0, 50.0), SceneSpec(INTERSECTION, 10), SceneSpec(INTERSECTION, 11)]
    listing = tmp_path / "scenes.txt"
    listing.write_text(f"# two scenes\n{cfg}@seed=1\n\n{cfg}@seed=1  # duplicate\n{REPO / 'networks' / 'merge'}\n")
    specs = parse_sources([listing])
    assert [s.config.stem for s in specs] == ["intersection", "merge"] and specs[0].seed == 1
    assert len(parse_sources([REPO / "networks"])) == 3
    with pytest.raises(InputError, match="no such scene source"):
        parse_sources([tmp_path / "nope.sumocfg"])
    with pytest.raises(InputError, match="bad override"):
        parse_sources([f"{cfg}@speed=3"])


def test_scene_keys_are_stable_and_distinct():
    a = SceneSpec(INTERSECTION, 0)
    assert scene_key(a) == scene_key(SceneSpec(INTERSECTION, 0))
    assert scene_key(a).startswith("intersection_s0_")
    assert len({scene_key(a), scene_key(SceneSpec(INTERSECTION, 1)), scene_key(a, {"init": "random"}),
                scene_key(SceneSpec(INTERSECTION, 0, end=40.0))}) == 4


@pytest.mark.slow
def test_ray_executor_isolates_crashes_and_hangs():
    pytest.importorskip("ray")
    tasks = [_probe("a"), _probe("crash", "segfault"), _probe("stuck", "hang"), _probe("oops", "error"), _probe("b")]
    # a task's clock runs from its start on its Ray worker (tests/batch/test_ray_cluster.py checks that a
    # task waiting for a free CPU is not timed out); the hang must still be killed
    out = _outcomes(execute(tasks, ExecutorSettings(workers=2, timeout=20.0, executor="ray")))
    assert out["a"].ok and out["b"].ok
    assert not out["crash"].ok and not out["stuck"].ok and "timed out" in out["stuck"].reason
    assert not out["oops"].ok and "probe oops failed on purpose" in out["oops"].reason


def test_a_part_file_of_another_shape_is_done_again(tmp_path):
    """eval scenarios resumes from its part files: one that is JSON but not a part (edited by hand,
    written by another version) counts as not done, instead of stopping the batch."""
    import json

    from coster_sumo.batch.generator_summary import read_method_part

    part = tmp_path / "p.json"
    part.write_text(json.dumps({"status": "ok", "records": [3]}))
    assert read_method_part(part) is None
    part.write_text(json.dumps({"status": "ok", "records": []}))
    assert read_method_part(part) is not None and read_method_part(tmp_path / "missing.json") is None


def test_eval_scenarios_keeps_reactive_parts_apart_and_refuses_an_unknown_traffic_mode(tmp_path):
    from coster_sumo.batch.evaluate import EvalOptions, evaluate_generators, part_key

    log = part_key("scene", "COSTER", 5, "abcdef0123")
    assert part_key("scene", "COSTER", 5, "abcdef0123", traffic="log") == log
    assert part_key("scene", "COSTER", 5, "abcdef0123", traffic="reactive") == log + "__reactive"
    assert part_key("scene", "COSTER", 5, "abcdef0123", "pedestrian", "reactive") == log + "__pedestrian__reactive"
    with pytest.raises(InputError, match="traffic must be log or reactive"):
        evaluate_generators(EvalOptions(sources=[str(INTERSECTION)], out=tmp_path / "o", traffic="ghost"))
    assert not (tmp_path / "o").exists()
