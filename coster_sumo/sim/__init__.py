"""Talking to SUMO: the session that owns the connection, and recording nominal runs into scenes.

Nothing here imports SUMO at import time; :class:`~coster_sumo.sim.session.SumoSession` imports
libsumo / traci when it starts.
"""

from coster_sumo.sim.record import record, record_config
from coster_sumo.sim.session import SumoSession, VehicleStates

__all__ = ["SumoSession", "VehicleStates", "record", "record_config"]
