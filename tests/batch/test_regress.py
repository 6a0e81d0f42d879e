"""``coster-sumo regress`` and ``coster-sumo eval scenarios`` on a project network (SUMO)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from coster_sumo.batch.store import ResultStore
from coster_sumo.cli.command_line import main

REPO = Path(__file__).resolve().parents[2]
INTERSECTION = REPO / "networks" / "intersection" / "intersection.sumocfg"
# weight-free generation (random init, constant-velocity rollout) on a 40 s window
SMALL = ["--end", "40", "--init", "random", "--rollout", "cv", "--variants", "2"]


def test_regress_rejects_bad_input_before_any_work(tmp_path, capsys):
    o = str(tmp_path / "o")
    assert main(["regress", str(tmp_path / "missing.sumocfg"), *SMALL, "--planner", "replay", "-o", o]) == 2
    assert "missing.sumocfg: no such file or folder" in capsys.readouterr().err
    assert main(["regress", str(INTERSECTION), *SMALL, "--planner", "sumo:NoSuchModel", "-o", o]) == 2
    assert "unknown SUMO car-following model" in capsys.readouterr().err
    assert main(["regress", str(INTERSECTION), "--planner", "replay", "--models", str(tmp_path), "-o", o]) == 2
    assert "no such file (model weights" in capsys.readouterr().err
    assert not (tmp_path / "o" / "results").exists()


@pytest.mark.sumo
@pytest.mark.slow
def test_regress_two_planners_same_variants_then_rerun_skips(tmp_path):
    out = tmp_path / "reg"
    argv = ["-q", "regress", str(INTERSECTION), *SMALL, "--planner", "replay", "--planner", "sumo:IDM",
            "--workers", "2", "-o", str(out)]
    assert main(argv) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["runs"] == {"expected": 4, "recorded": 4, "ok": 4, "failed": 0, "failures": []}
    assert set(summary["planners"]) == {"replay", "sumo:IDM"}
    for p in summary["planners"].values():
        assert p["runs"] == 2 and p["RCR"]["n"] == 2 and 0 <= p["CR"]["ci_low"] <= p["CR"]["ci_high"] <= 1
    rows = ResultStore(out / "results").read()
    assert sorted((r.variant, r.planner) for r in rows) == [(0, "replay"), (0, "sumo:IDM"),
                                                                  (1, "replay"), (1, "sumo:IDM")]
    assert len({r.t_col for r in rows if r.variant == 0}) == 1  # both planners saw the same variant
    for f in ("report.md", "report.html", "plots/rates.png", "plots/impact_angles.png", "plots/relative_speeds.png"):
        assert (out / f).stat().st_size > 0
    before = {p.name: p.stat().st_mtime_ns for p in (out / "results").glob("*.parquet")}
    assert main(argv) == 0  # everything is done: nothing runs again (no part file rewritten)
    assert {p.name: p.stat().st_mtime_ns for p in (out / "results").glob("*.parquet")} == before


@pytest.mark.sumo
@pytest.mark.slow
def test_regress_sumo_crash_or_hang_is_one_failed_row_and_the_rest_finish(tmp_path):
    out = tmp_path / "reg"
    cmd = [sys.executable, "-m", "coster_sumo", "-q", "regress", str(INTERSECTION), *SMALL,
           "--planner", "sumo", "--planner", "tests.misbehaving_planners:Abort",
           "--planner", "tests.misbehaving_planners:Hang", "--timeout", "30", "--workers", "2", "-o", str(out)]
    done = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, env={**os.environ, "PYTHONPATH": str(REPO)})
    assert done.returncode == 1, done.stderr  # the work ran, some runs failed
    rows = {(r.variant, r.planner): r for r in ResultStore(out / "results").read()}
    assert len(rows) == 6
    for v in (0, 1):
        assert rows[(v, "sumo")].status == "ok"
        assert rows[(v, "tests.misbehaving_planners:Abort")].status == "failed"
        assert "SIGABRT" in str(rows[(v, "tests.misbehaving_planners:Abort")].reason)
        assert rows[(v, "tests.misbehaving_planners:Hang")].status == "failed"
        assert "timed out" in str(rows[(v, "tests.misbehaving_planners:Hang")].reason)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["runs"]["ok"] == 2 and summary["runs"]["failed"] == 4


@pytest.mark.sumo
@pytest.mark.slow
def test_regress_killed_halfway_resumes_without_duplicates(tmp_path):
    out = tmp_path / "reg"
    cmd = [sys.executable, "-m", "coster_sumo", "-q", "regress", str(INTERSECTION), *SMALL, "--variants", "3",
           "--planner", "replay", "--planner", "sumo", "--workers", "2", "-o", str(out)]
    proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and len(list((out / "results").glob("*.parquet"))) < 2:
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    first = len(list((out / "results").glob("*.parquet")))
    assert 2 <= first < 6
    assert subprocess.run(cmd, cwd=REPO, capture_output=True).returncode == 0
    rows = ResultStore(out / "results").read()
    keys = [r.run_key for r in rows]
    assert len(keys) == 6 and len(set(keys)) == 6 and all(r.ok for r in rows)


@pytest.mark.sumo
@pytest.mark.slow
def test_eval_scenarios_reports_missing_weights_as_skipped(tmp_path):
    out = tmp_path / "ev"
    code = main(["-q", "eval", "scenarios", str(INTERSECTION), "--end", "40", "--variants", "2",
                 "--models", str(tmp_path / "no_models"), "--method", "Random+CV", "--method", "Snapshot+CV",
                 "-o", str(out)])
    assert code == 0
    metrics = json.loads((out / "metrics.json").read_text())["methods"]
    skipped = metrics["Snapshot+CV"]
    assert skipped["status"] == "skipped" and "no such file (model weights" in skipped["reason"]
    rc = metrics["Random+CV"]
    assert rc["status"] == "ok" and rc["variants"] == 2 and rc["scenes"] == 1
    for k in ("SUR", "CR", "ORR", "VDD", "ADD", "VDD_tcol"):
        assert rc[k] is not None and 0 <= rc[k] <= 1
    assert rc["size_in_class"] == 1.0  # the baseline's 4.5 x 1.9 m sedan is a passenger car
    assert sum(rc["adversaries_by_lane_type"].values()) == 2 and set(rc["adversaries_by_lane_type"]) <= {
        "SURFACE_STREET", "FREEWAY", "BIKE_LANE", "UNDEFINED"}
    assert (out / "metrics.md").read_text().count("skipped") >= 1
    assert (out / "metrics.png").stat().st_size > 0


@pytest.mark.sumo
@pytest.mark.slow
def test_eval_scenarios_resumed_says_what_was_done_and_runs_nothing_again(tmp_path, capsys):
    out = tmp_path / "ev"
    args = ["eval", "scenarios", str(INTERSECTION), "--end", "40", "--variants", "1", "--method", "Random+CV",
            "-o", str(out)]
    assert main(args) == 0
    before = {p.name: p.stat().st_mtime_ns for p in (out / "parts").iterdir()}
    capsys.readouterr()
    assert main(args) == 0
    said = capsys.readouterr().out
    assert "resuming" in said and "2 of 2 tasks done before" in said, said  # the scene and the method
    assert {p.name: p.stat().st_mtime_ns for p in (out / "parts").iterdir()} == before
