"""Cost per step of reading a target's surroundings in libsumo: a standing context subscription
against a one-off query every 5th step (what the nominal pass does), against plain stepping.

    python bench/bench_context_query.py [--at 600] [--target veh400] [--radius 200]

Runs the wheel's A10KW configuration (``tools/game``) at 0.1 s steps up to ``--at`` in one call,
then alternates blocks of 25 steps of each mode (20 rounds, so that the growing traffic weighs on
all three alike) and prints the mean wall time per step of each mode and how many vehicles the
query found.
"""

from __future__ import annotations

import argparse
import time

from coster_sumo.infra import sumo_install


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--at", type=float, default=600.0, help="[s] where the measurement starts")
    ap.add_argument("--target", default="veh400")
    ap.add_argument("--radius", type=float, default=200.0)
    args = ap.parse_args()
    ls = sumo_install.import_libsumo()
    tc = ls.constants
    cfg = sumo_install.sumo_home() / "tools" / "game" / "A10KW.sumocfg"
    ls.start([sumo_install.binary("sumo"), "-c", str(cfg), "--step-length", "0.1", "--no-step-log", "true",
              "--no-warnings", "true"])
    ls.simulationStep(args.at)
    dom, var = tc.CMD_GET_VEHICLE_VARIABLE, [tc.VAR_POSITION, tc.VAR_ANGLE, tc.VAR_SPEED]
    acc = {"plain": 0.0, "once every 5th step": 0.0, "standing subscription": 0.0}
    steps, found = 0, 0
    for _ in range(20):
        for mode in acc:
            if mode == "standing subscription":
                ls.vehicle.subscribeContext(args.target, dom, args.radius, var)
            t0 = time.perf_counter()
            for i in range(25):
                ls.simulationStep()
                if mode == "once every 5th step" and i % 5 == 0:
                    ls.vehicle.subscribeContext(args.target, dom, args.radius, var)
                    found = len(ls.vehicle.getContextSubscriptionResults(args.target))
                    ls.vehicle.unsubscribeContext(args.target, dom, args.radius)
                elif mode == "standing subscription":
                    found = len(ls.vehicle.getContextSubscriptionResults(args.target))
            acc[mode] += time.perf_counter() - t0
            if mode == "standing subscription":
                ls.vehicle.unsubscribeContext(args.target, dom, args.radius)
        steps += 25
    t_end = ls.simulation.getTime()
    ls.close()
    print(f"A10KW from {args.at:g} s to {t_end:g} s, target {args.target}, radius {args.radius:g} m, "
          f"{found} vehicles found at the end")
    for mode, total in acc.items():
        print(f"  {mode:22s} {total / steps * 1e3:.2f} ms/step")


if __name__ == "__main__":
    main()
