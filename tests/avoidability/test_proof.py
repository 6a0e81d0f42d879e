"""The SUMO proof of escapes: one pass for every escape of a converted scene gives the verdicts of
one pass per escape (coster_sumo.avoidability.proof)."""

from __future__ import annotations

import functools
import json
from pathlib import Path

import pytest

from coster_sumo.avoidability import proof
from coster_sumo.cli.command_line import main
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
