"""Batches: many scenes, many variants, many planners, each run isolated in its own process.

- :mod:`~coster_sumo.batch.executor`: the one executor (one process per task, timeouts, Ray), its local
  half in :mod:`~coster_sumo.batch.local_executor` and its Ray half in :mod:`~coster_sumo.batch.ray_executor`;
- :mod:`~coster_sumo.batch.sources`: scene sources -> scenario specs, and their cached nominal scenes;
- :mod:`~coster_sumo.batch.store`: the Parquet result store (the rates with their Wilson intervals are
  in :mod:`~coster_sumo.metrics`);
- :mod:`~coster_sumo.batch.regress`: ``coster-sumo regress``;
- :mod:`~coster_sumo.batch.evaluate`: ``coster-sumo eval scenarios``;
- :mod:`~coster_sumo.batch.simulate`: ``coster-sumo simulate`` (nominal traffic recorded as clips);
- :mod:`~coster_sumo.batch.corpus`: ``coster-sumo corpus build`` (the nominal-traffic corpus), with
  :mod:`~coster_sumo.batch.nets` (the networks it authors) and :mod:`~coster_sumo.batch.card`
  (``coster-sumo corpus card``).
"""
