"""Planners that break the process they run in, for the batch isolation tests (``module:Class``)."""

from __future__ import annotations

import os
import time
from pathlib import Path

from coster_sumo.sim.session import SumoSession


class _Base:
    name = "misbehaving"

    def additional_files(self, workdir: Path) -> list[Path]:
        return []

    def setup(self, session: SumoSession, target_id: str) -> None:
        pass


class Abort(_Base):
    """Kills its process with SIGABRT a few seconds into the pass, the way a libsumo crash does."""

    def before_step(self, session: SumoSession, target_id: str, t_next: float, present: bool) -> None:
        if t_next > 5.0:
            os.abort()


class Hang(_Base):
    """Stops answering a few seconds into the pass (a SUMO that hangs)."""

    def before_step(self, session: SumoSession, target_id: str, t_next: float, present: bool) -> None:
        if t_next > 5.0:
            time.sleep(3600)
