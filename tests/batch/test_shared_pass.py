"""``coster-sumo regress`` with several targets of one configuration: one nominal pass for all."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from coster_sumo.batch.regress import with_targets
from coster_sumo.batch.shared_pass import pass_key, shared_passes
from coster_sumo.batch.sources import scene_key
from coster_sumo.batch.store import ResultStore
from coster_sumo.core.spec import ScenarioSpec
from coster_sumo.errors import InputError

REPO = Path(__file__).resolve().parents[2]
INTERSECTION = REPO / "networks" / "intersection" / "intersection.sumocfg"
ARTERIAL = REPO / "networks" / "arterial" / "arterial.sumocfg"
SMALL = ["--end", "40", "--init", "random", "--rollout", "cv", "--variants", "2"]


def test_targets_of_one_configuration_window_and_seed_share_a_pass():
    a, b = ScenarioSpec(INTERSECTION, 0, None, 40.0, "ego"), ScenarioSpec(INTERSECTION, 0, None, 40.0, "pre_W.1")
    other_seed = ScenarioSpec(INTERSECTION, 1, None, 40.0, "ego")
    other_window = ScenarioSpec(INTERSECTION, 0, None, 30.0, "pre_W.1")
    unnamed = ScenarioSpec(INTERSECTION, 0, None, 40.0, None)
    keys = {scene_key(s): s for s in (a, b, other_seed, other_window, unnamed)}
    passes = shared_passes(keys)
    assert list(passes.values()) == [[scene_key(a), scene_key(b)]]  # the lone ones keep a pass of their own
    assert list(passes) == [pass_key([a, b])] and pass_key([a, b]) != pass_key([b, a])
    assert pass_key([a, b]).startswith("pass_intersection_s0_e40_2t_")


def test_regress_targets_expand_as_run_chooses_them():
    from coster_sumo.formats.targets import choose_targets

    plain = [ScenarioSpec(ARTERIAL, 0, None, 60.0, None)]
    picked = [c.vehicle_id for c in choose_targets(ARTERIAL, 3, None, 60.0)]
    assert [s.target for s in with_targets(plain, None, (), 3)] == picked
    named = [ScenarioSpec(INTERSECTION, 0, None, 40.0, "ego")]
    assert [s.target for s in with_targets(named, "ego", ("pre_W.1", "ego"), None)] == ["ego", "pre_W.1"]
    with pytest.raises(InputError, match="--targets must be >= 1"):
        with_targets(plain, None, (), 0)


@pytest.mark.sumo
@pytest.mark.slow
def test_two_targets_record_one_pass_and_a_rerun_after_a_kill_keeps_it(tmp_path):
    """The pass runs once for both targets (counted in every process of the batch); a batch killed
    after recording it, started again, records none and finishes every run."""
    out, counter = tmp_path / "reg", tmp_path / "passes.txt"
    env = {**os.environ, "PYTHONPATH": f"{REPO / 'tests' / 'pass_counter'}{os.pathsep}{REPO}",
           "COSTER_TEST_PASS_COUNT": str(counter)}
    cmd = [sys.executable, "-m", "coster_sumo", "-q", "regress", str(INTERSECTION), *SMALL, "--seed", "2",
           "--target", "ego", "--target", "pre_W.1", "--planner", "replay", "--workers", "2", "-o", str(out)]
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline and not list((out / "plans").glob("pass_*.npz")):
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)  # the pass is recorded; the scenes' generation is not finished
    proc.wait()
    assert counter.read_text().count("\n") == 1
    done = subprocess.run(cmd, cwd=REPO, env=env, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert counter.read_text().count("\n") == 1, "the rerun recorded the pass again"
    [shared] = list((out / "plans").glob("pass_*.npz"))
    assert not [p for p in (out / "plans").glob("*.npz") if p != shared]  # no pass of a target's own
    docs = [json.loads(p.read_text()) for p in (out / "plans").glob("intersection_*.json")]
    assert sorted(d["target_id"] for d in docs) == ["ego", "pre_W.1"]
    assert {d["scene_file"] for d in docs} == {shared.name} and all(d["status"] == "ok" for d in docs)
    rows = ResultStore(out / "results").read()
    assert len(rows) == sum(len(d["variants"]) for d in docs) >= 2 and all(r.ok for r in rows)


@pytest.mark.sumo
@pytest.mark.slow
def test_eval_scenarios_targets_of_one_configuration_share_a_pass(tmp_path):
    from coster_sumo.cli.command_line import main

    sources = tmp_path / "scenes.txt"
    sources.write_text(f"{INTERSECTION}@target=ego,end=40,seed=2\n{INTERSECTION}@target=pre_W.1,end=40,seed=2\n")
    out = tmp_path / "ev"
    assert main(["-q", "eval", "scenarios", str(sources), "--variants", "1", "--method", "Random+CV",
                 "-o", str(out)]) == 0
    [shared] = list((out / "scenes").glob("*.npz"))
    assert shared.name.startswith("pass_intersection_s2_e40_2t_")
    parts = [json.loads(p.read_text()) for p in (out / "parts").glob("*__scene.json")]
    assert len(parts) == 2 and {p["scene_file"] for p in parts} == {shared.name}
    assert json.loads((out / "metrics.json").read_text())["methods"]["Random+CV"]["scenes"] == 2
