"""Several collision snapshots for one target from one nominal pass (``run --snapshots K``)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from coster_sumo.cli.command_line import main

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.sumo
@pytest.mark.parametrize("network", ["intersection", "arterial"])
def test_three_snapshots_have_different_collision_times(tmp_path, network):
    out = tmp_path / "out"
    code = main(["--quiet", "run", str(REPO / "networks" / network / f"{network}.sumocfg"), "--snapshots", "3",
                 "--init", "random", "--rollout", "cv", "--variants", "1", "--planner", "replay", "--no-render",
                 "-o", str(out)])
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    t_cols = [s["t_col"] for s in summary["snapshots"]]
    assert len(t_cols) == 3 and min(abs(a - b) for i, a in enumerate(t_cols) for b in t_cols[i + 1:]) >= 2.0 - 1e-6
    assert {v["snapshot"] for v in summary["variants"]} == {0, 1, 2}
    assert (out / "snapshot_2.json").is_file()
    ids = [v["adversary_id"] for v in summary["variants"]]
    assert len(set(ids)) == len(ids)
