"""The SUMO proof of escapes: one pass for every escape of a converted scene gives the verdicts of
one pass per escape: in log traffic every escape, in reactive traffic those no logged agent reacts
to, the others leaving it for a pass of their own (coster_sumo.avoidability.proof)."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import numpy as np
import pytest

from coster_sumo.avoidability import proof
from coster_sumo.cli.command_line import main
from coster_sumo.core.plan import AdversaryPlan
from coster_sumo.core.spec import GenerationConfig, ScenarioSpec
from coster_sumo.infra.progress import bars
from coster_sumo.pipeline.run import RunOptions, run
from tests.conftest import WOMD_PKL, requires_womd

pytestmark = [pytest.mark.sumo, pytest.mark.slow, pytest.mark.realdata, requires_womd()]


def _verdicts(cfg: Path, seed: int, out: Path) -> list[list[dict | None]]:
    s = run(RunOptions(spec=ScenarioSpec(cfg, seed=seed), out=out, generation=GenerationConfig(), planner="replay",
                       render=False), bars(quiet=True)).to_json()
    return [[e and e.get("proof") for e in v["avoidability"]["escapes"].values()] for v in s["variants"]]


def test_every_escape_in_one_pass_gives_the_verdicts_of_a_pass_per_escape(tmp_path, monkeypatch):
    assert main(["-q", "convert", "-o", str(tmp_path / "conv"), str(WOMD_PKL[0])]) == 0
    (cfg,) = (tmp_path / "conv").glob("*/*.sumocfg")
    checked = 0
    prove_escapes = proof.prove_escapes
    for seed in (0, 1):
        got = {}
        for together in (False, True):
            monkeypatch.setattr(proof, "prove_escapes", functools.partial(prove_escapes, together=together))
            got[together] = _verdicts(cfg, seed, tmp_path / f"run{seed}{together}")
        # the same replays in SUMO: equal to the last digit the verdicts keep
        assert json.dumps(got[True], sort_keys=True) == json.dumps(got[False], sort_keys=True)
        checked += sum(1 for v in got[True] for e in v if e)
    assert checked >= 4  # escapes were found and proven (28 when this was written)


@pytest.mark.parametrize("source", ["synthetic", "womd", "follower"])
def test_reactive_traffic_gives_a_pass_of_its_own_only_to_an_escape_an_agent_reacts_to(source, tmp_path, monkeypatch):
    # every escape joins the joint pass, those reaches_no_one cannot clear in advance watched; an
    # escape leaves it exactly when a logged agent reacts in its own reactive pass, and the verdicts
    # are those of a reactive pass per escape. On the synthetic junction (seed 2) two escapes are
    # watched and nobody reacts to them; behind a stopped car the target's follower reacts
    from coster_sumo.converters.to_sumo import convert_scene

    from coster_sumo.avoidability.search import assess
    from coster_sumo.data import synthetic
    from coster_sumo.formats.targets import choose_target
    from coster_sumo.geometry.drivable import DrivableArea
    from coster_sumo.method.generation import generate_variants
    from coster_sumo.pipeline.scenario import nominal_scene
    from coster_sumo.sim import reactive

    if source == "synthetic":
        (cfg,) = convert_scene(synthetic.four_way_junction(), tmp_path).folder.glob("*.sumocfg")
    elif source == "follower":  # a target braking for a stopped car, its follower close behind
        from tests.avoidability.test_reacting_follower import _one_lane_road

        road, _ = nominal_scene(ScenarioSpec(_one_lane_road(tmp_path), seed=1, end=30.0))
        (cfg,) = convert_scene(road, tmp_path / "conv").folder.glob("*.sumocfg")
    else:
        assert main(["-q", "convert", "-o", str(tmp_path / "conv"), str(WOMD_PKL[0])]) == 0
        (cfg,) = (tmp_path / "conv").glob("*/*.sumocfg")
    spec = ScenarioSpec(cfg, seed=2)
    scene, _ = nominal_scene(spec)
    target = choose_target(scene, None, spec.config)
    drivable = DrivableArea.from_road_map(scene.road_map)
    if source == "follower":  # the stopped car where the target would be at 12 s, there from 7 s
        target = scene.tracks.index_of("ego")
        k = int(np.argmin(np.abs(scene.timestamps - 12.0)))
        times = np.arange(7.0, 12.01, 0.5)
        plans = [AdversaryPlan(times=times, x=np.full(len(times), float(scene.tracks.x[target, k]) + 5.0),
                               y=np.full(len(times), float(scene.tracks.y[target, k])), yaw=np.zeros(len(times)),
                               final_speed=0.0, length=5.0, width=1.8)]
    else:
        plans = [v.plan for v in generate_variants(scene, target, 2, GenerationConfig(), drivable)[0]]
    jobs = [proof.EscapeJob(p, e) for p in plans
            for e in proof._all_to_prove(assess(scene, target, p, drivable, reactive_others=True))]
    joints: list[proof._JointProof] = []
    real_run = proof._JointProof.run
    monkeypatch.setattr(proof._JointProof, "run", lambda self: joints.append(self) or real_run(self))
    own: list[int] = []  # per pass of its own: how many logged agents reacted there
    real_replayer = reactive.reactive_replayer

    def counted(*a, **k):
        r = real_replayer(*a, **k)
        own.append(r)
        return r

    monkeypatch.setattr(reactive, "reactive_replayer", counted)
    settings = proof.ProofSettings(drivable, traffic="reactive")
    together = proof.prove_escapes(spec, scene, target, jobs, settings)
    (joint,) = joints
    assert len(joint.jobs) == len(jobs) and joint.watched
    left = sorted(joint.would_react)
    assert len(own) == len(left) and all(len(r.handover) > 1 for r in own)  # each had an agent react
    # each own pass resumed 1 s before its job left, on the log's grid, not from the scene's begin
    origin = spec.begin if spec.begin is not None else float(scene.timestamps[0])
    assert sorted(joint.resumed) == left
    assert all(b > origin if joint.left_at[k] - proof.RESUME_LEAD_S > origin + 0.05 else b == origin
               for k, (b, _) in joint.resumed.items())
    assert any(b > origin for b, _ in joint.resumed.values()) if source == "follower" else True
    own.clear()
    apart = proof.prove_escapes(spec, scene, target, jobs, settings, together=False)
    assert len(own) == len(jobs)
    reacted = [i for i, r in enumerate(own) if len(r.handover) > 1]
    assert reacted == left  # the watch saw exactly the escapes an agent reacts to
    # both ways seen: on the junction the two watched escapes stay in the joint pass (3 jobs, 2 watched
    # when written); behind the stopped car the follower reacts to every one (6 of 6)
    assert (left == []) if source == "synthetic" else True
    assert left if source == "follower" else True
    assert json.dumps([v.to_json() for v in together]) == json.dumps([v.to_json() for v in apart])
