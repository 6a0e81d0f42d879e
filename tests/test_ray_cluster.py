"""`regress --executor ray` on a real multi-node Ray cluster whose workers share no folder with OUT.

The test starts the cluster as a user would: a head (no CPUs: it schedules, it runs no task) and
two worker nodes, each a separate ``ray start`` in a working directory of its own that does not
contain OUT. The batch then runs from a third folder; every file a task reads travels with it and
what it writes comes back through Ray (coster_sumo.batch.executor). Its rows must equal those of
the local executor's run, run by run.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import uuid
from pathlib import Path

import pytest

from coster_sumo.batch.store import ResultStore

REPO = Path(__file__).resolve().parents[1]
CFG = REPO / "networks" / "intersection" / "intersection.sumocfg"
pytestmark = [pytest.mark.slow, pytest.mark.sumo]

# what a run's outcome is; wall times and the finishing clock differ between any two batches
OUTCOME = ("run_key", "status", "collision", "adversary_contact", "target_other_collision", "target_off_road",
           "adversary_off_road", "route_completed", "target_arrived", "min_ttc", "contact_time",
           "relative_speed", "impact_angle", "t_col")


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


@pytest.fixture(scope="module")
def cluster(tmp_path_factory):
    pytest.importorskip("ray")
    ray_bin = Path(sys.executable).parent / "ray"
    base = tmp_path_factory.mktemp("cluster")
    temp_dir = Path(f"/tmp/ray-{uuid.uuid4().hex[:8]}")  # short: Ray's socket paths must fit 108 bytes
    env = {**os.environ, "RAY_USAGE_STATS_ENABLED": "0", "RAY_AUTH_MODE": "disabled", "PYTHONPATH": str(REPO)}
    port = _free_port()
    address = f"127.0.0.1:{port}"
    common = ["--node-ip-address=127.0.0.1", f"--temp-dir={temp_dir}", "--disable-usage-stats"]
    starts = [[str(ray_bin), "start", "--head", f"--port={port}", "--num-cpus=0", "--include-dashboard=false",
               *common]]
    starts += [[str(ray_bin), "start", f"--address={address}", "--num-cpus=1", *common] for _ in range(2)]
    try:
        for i, cmd in enumerate(starts):
            cwd = base / f"node{i}"
            cwd.mkdir()
            done = subprocess.run(cmd, cwd=cwd, env=env, capture_output=True, text=True, timeout=180)
            if done.returncode != 0:
                pytest.fail(f"ray start failed: {done.stderr[-2000:]}")
        yield address, env
    finally:
        # stop this cluster's processes only (`ray stop` would stop every Ray on the machine)
        for pid_dir in Path("/proc").iterdir():
            if not pid_dir.name.isdigit():
                continue
            try:
                cmdline = (pid_dir / "cmdline").read_bytes().decode(errors="replace")
            except OSError:
                continue
            if str(temp_dir) in cmdline or f"127.0.0.1:{port}" in cmdline:
                try:
                    os.kill(int(pid_dir.name), signal.SIGKILL)
                except OSError:
                    pass
        shutil.rmtree(temp_dir, ignore_errors=True)


def _regress(out: Path, cwd: Path, env: dict[str, str], *extra: str) -> subprocess.CompletedProcess:
    args = [sys.executable, "-m", "coster_sumo", "-q", "regress", str(CFG), "--end", "40", "--init", "random",
            "--rollout", "cvae", "--samples", "100", "--variants", "2", "--planner", "replay", "--planner", "sumo",
            "--workers", "2", "--no-report", "-o", str(out), *extra]
    return subprocess.run(args, cwd=cwd, env=env, capture_output=True, text=True, timeout=900)


def _outcomes(out: Path) -> dict[str, dict]:
    return {r["run_key"]: {k: r[k] for k in OUTCOME} for r in ResultStore(out / "results").read()}


def test_regress_on_a_multi_node_ray_cluster_equals_the_local_run(cluster, tmp_path):
    address, env = cluster
    driver = tmp_path / "driver"
    driver.mkdir()
    local = _regress(tmp_path / "local", driver, env)
    assert local.returncode == 0, local.stderr
    ray_out = tmp_path / "ray_out"
    remote = _regress(ray_out, driver, env, "--executor", "ray", "--address", address)
    assert remote.returncode == 0, remote.stderr
    expected, got = _outcomes(tmp_path / "local"), _outcomes(ray_out)
    assert len(expected) == 4 and got == expected
    # the plans came back through Ray and were written by the driver
    plans = json.loads(next((ray_out / "plans").glob("*.json")).read_text())
    assert plans["status"] == "ok" and (ray_out / "plans" / plans["scene_file"]).is_file()
    # a rerun resumes: nothing runs twice
    again = _regress(ray_out, driver, env, "--executor", "ray", "--address", address)
    assert again.returncode == 0 and _outcomes(ray_out) == expected
    assert len(list((ray_out / "results").glob("*.parquet"))) == 4
