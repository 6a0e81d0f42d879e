"""Planners that break the process they run in, for the batch isolation tests (``module:Class``).

SUMO drives the target (as ``--planner sumo``) until 5 s into the pass, then the process fails.
"""

from __future__ import annotations

import os
import time

from coster_sumo.sim.planners import SumoPlanner
from coster_sumo.sim.session import SumoSession

FAIL_AFTER_S = 5.0  # [s] simulation time


class Abort(SumoPlanner):
    """Kills its process with SIGABRT, the way a libsumo crash does."""

    def before_step(self, session: SumoSession, target_id: str, t_next: float, present: bool) -> None:
        if t_next > FAIL_AFTER_S:
            os.abort()
        super().before_step(session, target_id, t_next, present)


class Hang(SumoPlanner):
    """Stops answering (a SUMO that hangs)."""

    def before_step(self, session: SumoSession, target_id: str, t_next: float, present: bool) -> None:
        if t_next > FAIL_AFTER_S:
            time.sleep(3600)
        super().before_step(session, target_id, t_next, present)


ONCE_ENV = "COSTER_TEST_ONCE"  # a file path: the first pass that creates it misbehaves, the others drive


def _first() -> bool:
    """True in the first pass to claim the file named by ``$COSTER_TEST_ONCE`` (atomic create)."""
    try:
        os.close(os.open(os.environ[ONCE_ENV], os.O_CREAT | os.O_EXCL | os.O_WRONLY))
    except (KeyError, FileExistsError):
        return False
    return True


class AbortOnce(SumoPlanner):
    """The first pass that runs it crashes (SIGABRT) once past 5 s; every other pass drives as ``sumo``."""

    def before_step(self, session: SumoSession, target_id: str, t_next: float, present: bool) -> None:
        if t_next > FAIL_AFTER_S and not getattr(self, "_spared", False):
            if _first():
                os.abort()
            self._spared = True
        super().before_step(session, target_id, t_next, present)


class HangOnce(SumoPlanner):
    """The first pass that runs it hangs once past 5 s; every other pass drives as ``sumo``."""

    def before_step(self, session: SumoSession, target_id: str, t_next: float, present: bool) -> None:
        if t_next > FAIL_AFTER_S and not getattr(self, "_spared", False):
            if _first():
                time.sleep(3600)
            self._spared = True
        super().before_step(session, target_id, t_next, present)
