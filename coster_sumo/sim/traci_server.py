"""Starting SUMO as a TraCI server (or attaching to one) quickly and with a clear error."""

from __future__ import annotations

import contextlib
import subprocess
import tempfile
import time
from typing import IO, Any

from coster_sumo.errors import InputError
from coster_sumo.infra import sumo_install
from coster_sumo.sim.sumo_options import TRACI_CONNECT_TIMEOUT_S


def start_traci_server(traci: Any, command: list[str], label: str, name: str) -> tuple[Any, IO[bytes]]:
    """Popen SUMO with a free --remote-port and connect, polling every 20 ms.

    ``traci.start`` would sleep a whole second before its first retry and print about it. SUMO's
    stderr goes to a temporary file (returned; the caller closes it) so that a failed start can say why.
    """
    sumolib = sumo_install.import_sumolib()
    port = sumolib.miscutils.getFreeSocketPort()
    stderr = tempfile.TemporaryFile()
    proc = subprocess.Popen(command + ["--remote-port", str(port)], stdout=subprocess.DEVNULL,
                            stderr=stderr, env=sumo_install.subprocess_env())
    deadline = time.monotonic() + TRACI_CONNECT_TIMEOUT_S
    while True:
        try:
            return traci.connect(port=port, numRetries=0, proc=proc, label=label), stderr
        except Exception as exc:
            if proc.poll() is not None or time.monotonic() > deadline:
                if proc.poll() is None:
                    proc.kill()
                proc.wait()
                reason = server_error(stderr) or " ".join(str(exc).split())
                stderr.close()
                raise InputError(f"{name}: SUMO could not load it: {reason}") from None
            time.sleep(0.02)


def attach_traci(traci: Any, port: int | None, host: str, label: str) -> Any:
    """Connect to a server someone else started, polling quietly until it listens."""
    deadline = time.monotonic() + TRACI_CONNECT_TIMEOUT_S
    while True:
        try:
            return traci.connect(port=port, host=host, numRetries=0, label=label)
        except Exception:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.05)


def server_error(stderr: IO[bytes] | None) -> str:
    """The first error lines SUMO wrote (or its last lines)."""
    if stderr is None:
        return ""
    stderr.seek(0)
    lines = stderr.read().decode(errors="replace").splitlines()
    errors = [ln.strip() for ln in lines if ln.startswith("Error")]
    return " ".join(errors[:2]) or " ".join(ln.strip() for ln in lines[-2:])


def subscribe_simulation(api: Any, tc: Any) -> None:
    """Have every step bring back the time and the departed and arrived ids (one round trip)."""
    api.simulation.subscribe((tc.VAR_TIME, tc.VAR_DEPARTED_VEHICLES_IDS, tc.VAR_ARRIVED_VEHICLES_IDS))


def subscribe_vehicle(api: Any, tc: Any, veh_id: str) -> None:
    """Have every step bring back what :meth:`SumoSession.vehicle_states` reads of ``veh_id``."""
    with contextlib.suppress(Exception):  # a vehicle added but not yet inserted cannot be subscribed
        api.vehicle.subscribe(veh_id, (tc.VAR_POSITION, tc.VAR_ANGLE, tc.VAR_SPEED, tc.VAR_LENGTH, tc.VAR_WIDTH,
                                       tc.VAR_VEHICLECLASS, tc.VAR_TYPE))
