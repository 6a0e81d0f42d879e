"""`regress --executor ray` on a real multi-node Ray cluster whose workers share no folder with the driver.

The test starts the cluster as a user would (tests/ray_nodes.py): a head that runs no task and two
worker nodes, each a separate ``ray start`` in a working folder of its own. The driver's folder (the
configuration it reads and OUT) is hidden from the worker nodes: an empty tmpfs over it in their
mount namespace where this machine allows one, else a Python audit hook that refuses to open
anything below it. Every file a task reads travels with it and what it writes comes back through
Ray (coster_sumo.batch.executor). The rows must equal those of the local executor's run, run by
run, and a rerun of the same command must resume: finished runs are not redone, no row is counted
twice and a file the user put into OUT stays; runs lost with a worker node that died under them are
failed rows that the rerun runs again.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from coster_sumo.batch.store import ResultStore

REPO = Path(__file__).resolve().parents[2]
NETWORK = REPO / "networks" / "intersection"
pytestmark = [pytest.mark.slow, pytest.mark.sumo]

# what a run's outcome is; wall times and the finishing clock differ between any two batches
OUTCOME = ("run_key", "status", "collision", "adversary_contact", "target_other_collision", "target_off_road",
           "adversary_off_road", "route_completed", "target_arrived", "min_ttc", "contact_time",
           "relative_speed", "impact_angle", "t_col")
SENTINEL_TEXT = "only the driver can read this"


@pytest.fixture(scope="module")
def driver(tmp_path_factory):
    """The driver's folder: the configuration and every OUT; no worker node sees it."""
    pytest.importorskip("ray")
    sys.path.insert(0, str(REPO / "tests"))
    folder = tmp_path_factory.mktemp("ray") / "driver"
    shutil.copytree(NETWORK, folder / "net")
    (folder / "sentinel.txt").write_text(SENTINEL_TEXT)
    return folder


def _cluster(driver: Path, name: str):
    from ray_nodes import ray_cluster

    # COSTER_TEST_RAY_ISOLATION="audit hook" tries the fallback on a machine that has namespaces
    return ray_cluster(driver.parent / name, worker_cpus=(1, 1), hidden=[driver],
                       isolation=os.environ.get("COSTER_TEST_RAY_ISOLATION") or None)


@pytest.fixture(scope="module")
def cluster(driver):
    with _cluster(driver, "cluster") as c:
        yield c, driver


@pytest.fixture(scope="module")
def local_outcomes(driver, cluster):
    """The local executor's rows of the batch every test here runs on Ray."""
    c, _ = cluster
    local = _regress(driver / "net" / "intersection.sumocfg", driver / "local", driver, c.env)
    assert local.returncode == 0, local.stderr
    expected = _outcomes(driver / "local")
    assert len(expected) == 4
    return expected


def _regress(cfg: Path, out: Path, cwd: Path, env: dict[str, str], *extra: str) -> subprocess.CompletedProcess:
    args = [sys.executable, "-m", "coster_sumo", "-q", "regress", str(cfg), "--end", "40", "--init", "random",
            "--rollout", "cvae", "--samples", "100", "--variants", "2", "--planner", "replay", "--planner", "sumo",
            "--workers", "2", "--no-report", "-o", str(out), *extra]
    return subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=900)


def _outcomes(out: Path) -> dict[str, dict]:
    return {r.run_key: {k: getattr(r, k) for k in OUTCOME} for r in ResultStore(out / "results").read()}


def test_the_worker_nodes_cannot_read_the_driver_folder(cluster):
    from ray_nodes import node_cpus, unseen_by_workers

    c, driver = cluster
    assert sorted(node_cpus(c)) == [0, 1, 1]  # the head runs no task: every task runs on a worker node
    seen = unseen_by_workers(c, driver / "sentinel.txt")
    assert len({s["node"] for s in seen}) == 2
    for s in seen:  # the file is there for the driver, not for the nodes
        assert "read" not in s and s["error"] in ("FileNotFoundError", "PermissionError"), (c.isolation, s)
        assert not Path(s["cwd"]).is_relative_to(driver)


def test_regress_on_a_multi_node_ray_cluster_equals_the_local_run_and_resumes(cluster, local_outcomes):
    c, driver = cluster
    cfg = driver / "net" / "intersection.sumocfg"
    ray_out = driver / "ray_out"
    remote = _regress(cfg, ray_out, driver, c.env, "--executor", "ray", "--address", c.address)
    assert remote.returncode == 0, remote.stderr
    expected = local_outcomes
    assert _outcomes(ray_out) == expected
    # the plans and the nominal scene came back through Ray and were written by the driver
    plans = json.loads(next((ray_out / "plans").glob("*.json")).read_text())
    assert plans["status"] == "ok" and (ray_out / "plans" / plans["scene_file"]).is_file()

    # the same command again resumes: a lost run is redone, the others are not, nothing is counted twice
    parts = sorted((ray_out / "results").glob("*.parquet"))
    assert len(parts) == 4
    stamps = {p.name: p.stat().st_mtime_ns for p in parts}
    parts[0].unlink()
    (ray_out / "my_notes.txt").write_text("mine")
    again = _regress(cfg, ray_out, driver, c.env, "--executor", "ray", "--address", c.address)
    assert again.returncode == 0, again.stderr
    assert _outcomes(ray_out) == expected
    after = {p.name: p.stat().st_mtime_ns for p in (ray_out / "results").glob("*.parquet")}
    assert set(after) == set(stamps)
    assert {n: t for n, t in after.items() if n != parts[0].name} == \
        {n: t for n, t in stamps.items() if n != parts[0].name}
    summary = json.loads((ray_out / "summary.json").read_text())
    assert summary["runs"]["recorded"] == 4 and summary["runs"]["ok"] == 4
    assert (ray_out / "my_notes.txt").read_text() == "mine"


def test_a_task_waiting_for_a_free_cpu_is_not_timed_out_and_a_hang_is(cluster):
    from coster_sumo.batch.executor import ExecutorSettings, Task, execute, probe_task

    c, _ = cluster
    # five tasks at once on the two CPUs: three wait in Ray's queue; the clock runs from each start
    tasks = [Task(f"t{i}", probe_task, {"name": f"t{i}", "sleep": 4.0}) for i in range(4)]
    tasks.append(Task("stuck", probe_task, {"name": "stuck", "mode": "hang"}))
    how = ExecutorSettings(workers=5, executor="ray", timeout=7.0, ray_address=c.address)
    out = {t.key: o for t, o in execute(tasks, how)}
    assert all(out[f"t{i}"].ok for i in range(4)), {k: o.reason for k, o in out.items()}
    assert not out["stuck"].ok and out["stuck"].reason.startswith("timed out after 7 s (killed) in ")


def _node_runs_a_task(node: Path) -> bool:
    """Whether a task runs on the worker node started in ``node``: a task's scratch folder names the
    Ray worker that forked it (coster_sumo.batch.executor), and that worker runs in the node's folder."""
    for scratch in Path(tempfile.gettempdir()).glob("coster-task-*-*"):
        pid = scratch.name.split("-")[2]
        try:
            if os.readlink(f"/proc/{pid}/cwd") == str(node):
                return True
        except OSError:
            continue
    return False


def _kill_node(node: Path) -> int:
    """Kill every process of the worker node started in ``node`` (its raylet, workers and tasks)."""
    killed = 0
    for proc in Path("/proc").iterdir():
        try:
            if proc.name.isdigit() and os.readlink(proc / "cwd") == str(node):
                os.kill(int(proc.name), signal.SIGKILL)
                killed += 1
        except OSError:
            continue
    return killed


def test_runs_lost_with_a_worker_node_are_run_again_by_the_rerun(driver, local_outcomes):
    cfg = driver / "net" / "intersection.sumocfg"
    out = driver / "node_lost"
    with _cluster(driver, "cluster_b") as c:
        node = driver.parent / "cluster_b" / "node2"
        args = [sys.executable, "-m", "coster_sumo", "-q", "regress", str(cfg), "--end", "40", "--init", "random",
                "--rollout", "cvae", "--samples", "100", "--variants", "2", "--planner", "replay", "--planner",
                "sumo", "--workers", "2", "--no-report", "-o", str(out), "--executor", "ray", "--address", c.address]
        batch = subprocess.Popen(args, cwd=driver, env=c.env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                                 text=True)
        deadline = time.monotonic() + 300
        # the scene's variants exist, and one of its runs is on the node: the node dies under it
        while batch.poll() is None and time.monotonic() < deadline and not (
                any((out / "plans").glob("*.json")) and _node_runs_a_task(node)):
            time.sleep(0.05)
        assert batch.poll() is None, "the batch ended before a run started on the second node"
        assert _kill_node(node) > 0
        _, err = batch.communicate(timeout=600)
        assert batch.returncode == 1, err  # a run failed: the batch says so
        rows = ResultStore(out / "results").read()
        lost = [r for r in rows if not r.ok]
        assert lost and all(str(r.reason).startswith("lost on the Ray cluster") for r in lost)
        again = _regress(cfg, out, driver, c.env, "--executor", "ray", "--address", c.address)
        assert again.returncode == 0, again.stderr
    assert _outcomes(out) == local_outcomes
    assert len(ResultStore(out / "results").read()) == 4
