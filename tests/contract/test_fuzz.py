"""The seeded fuzz harness (tests/fuzz.py) over the CLI: a few hundred damaged inputs, none may misbehave.

The long run (3,000+ inputs) is ``python tests/fuzz.py --count 3000 --seed 0`` (docs/womd.md).
"""

from __future__ import annotations

import pytest

from tests.conftest import requires_womd
from tests.fuzz import fuzz, report

pytestmark = [pytest.mark.slow, pytest.mark.sumo, pytest.mark.realdata, requires_womd()]


def test_fuzzed_inputs_are_refused_cleanly(tmp_path):
    outcomes = fuzz(300, seed=20261123, workdir=tmp_path / "fuzz", batch_size=50, solo_every=30)
    table = report(outcomes)
    assert sum(row["inputs"] for row in table.values()) == 300
    assert {"tfrecord", "pickle", "crafted", "hostile_id", "sumo_xml"} <= set(table)
    bad = [f"{o.input.kind}/{o.input.mutation} {o.input.path.name}: {'; '.join(o.problems)}"
           for o in outcomes if o.problems]
    assert not bad, "\n".join(bad[:20])
