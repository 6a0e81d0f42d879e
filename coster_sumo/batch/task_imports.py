"""Imported once by the fork server of tasks that generate scenarios (``eval scenarios``, ``regress``).

A task process forked from it starts with SUMO, torch and the models' code in memory. Imported in
the task itself they cost about 1.5-2.5 s per task (torch alone about 1 s on the 2-core machine
of bench/RESULTS.md), more than generating its five variants takes once they are there
(``bench/bench_generation.py``). Importing torch starts no thread pool, so a task forked from here
may use all its cores. libsumo prints a warning about pyarrow's version on import; it is kept off
the console here as the executor keeps it off for the other task modules.
"""

from __future__ import annotations

import contextlib
import io

with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()):
    import libsumo  # noqa: F401

import pyarrow.parquet  # noqa: F401, E402
import sklearn.cluster  # noqa: F401, E402 - the K-means of the selection (0.08 s a task imported again)
import torch  # noqa: F401, E402

import coster_sumo.geometry.drivable  # noqa: F401, E402
import coster_sumo.method.generation  # noqa: F401, E402
import coster_sumo.method.snapshot  # noqa: F401, E402
import coster_sumo.pipeline.outputs  # noqa: F401, E402
import coster_sumo.pipeline.scenario  # noqa: F401, E402
import coster_sumo.prior.infer  # noqa: F401, E402
import coster_sumo.rollout.checkpoint  # noqa: F401, E402
import coster_sumo.rollout.sample  # noqa: F401, E402
import coster_sumo.sim.inject  # noqa: F401, E402
