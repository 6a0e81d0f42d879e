"""Exports of generated variants into formats other tools play without coster-sumo.

- :mod:`coster_sumo.exports.sumo`: a standalone SUMO folder per variant; plain ``sumo -c`` plays it,
  adversary included, through SUMO's FCD replay device.
"""

from coster_sumo.exports.sumo import write_sumo_export

__all__ = ["write_sumo_export"]
