"""Shared fixtures: synthetic scenes built in code, and the real WOMD samples when present."""

from __future__ import annotations

from pathlib import Path

import pytest

from coster_sumo.data import synthetic

REPO = Path(__file__).resolve().parents[1]
WOMD_DIR = REPO.parent / "shared" / "data" / "womd"
WOMD_PROTO = sorted((WOMD_DIR / "scenario_proto").glob("*.tfrecord"))
WOMD_PKL = sorted((WOMD_DIR / "scenarionet_pkl").glob("*.pkl"))
NO_WOMD_REASON = f"real WOMD samples not found under {WOMD_DIR} (they live in ../shared, never in the repo)"


def requires_womd() -> pytest.MarkDecorator:
    return pytest.mark.skipif(not WOMD_PROTO and not WOMD_PKL, reason=NO_WOMD_REASON)


@pytest.fixture(params=sorted(synthetic.ALL))
def synthetic_scene(request):
    return synthetic.ALL[request.param]()


def visible_lines(stream: str) -> list[str]:
    """What a terminal shows of ``stream``: progress bars redraw their line with carriage returns
    and clear it when they close, so each line shows only what follows its last carriage return."""
    return [shown for line in stream.split("\n") if (shown := line.split("\r")[-1].strip())]
