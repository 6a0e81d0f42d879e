"""Counts nominal passes for tests/batch/test_shared_pass.py: every process started with this folder on
PYTHONPATH and COSTER_TEST_PASS_COUNT set appends one line to that file per nominal pass it records
(batch tasks run in processes of their own, fork-server children included, so a patch in the test's
process would not see them)."""

import os

if os.environ.get("COSTER_TEST_PASS_COUNT"):
    import coster_sumo.pipeline.scenario as _scenario

    _nominal_scene = _scenario.nominal_scene

    def _counted(*args, **kwargs):  # type: ignore[no-untyped-def]
        with open(os.environ["COSTER_TEST_PASS_COUNT"], "a") as fh:
            fh.write(f"{os.getpid()}\n")
        return _nominal_scene(*args, **kwargs)

    _scenario.nominal_scene = _counted
