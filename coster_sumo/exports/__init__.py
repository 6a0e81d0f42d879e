"""Exports of generated variants into formats other tools play without coster-sumo.

- :mod:`coster_sumo.exports.sumo`: a standalone SUMO folder per variant; plain ``sumo -c`` plays it,
  adversary included, through SUMO's FCD replay device.
- :mod:`coster_sumo.exports.openscenario`: OpenSCENARIO 1.2 + OpenDRIVE (optional extra
  ``coster-sumo[openscenario]``; imported only when used).
- :mod:`coster_sumo.exports.trajectories`: every vehicle's trajectory as CSV and JSON.
- :mod:`coster_sumo.exports.run_folder`: all of them for every variant of a run folder
  (``coster-sumo export``).
"""

from coster_sumo.exports.sumo import write_sumo_export

__all__ = ["write_sumo_export"]
