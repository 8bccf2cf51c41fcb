"""Closed-loop roll through MAVLink with and without lockstep at 10x and 100x (SPEC C2: results must
not depend on the speed-up). Prints roll std open/closed and wall time.

    python bench/bench_lockstep.py [--speedups 10,100] [--open-s 30] [--closed-s 40]
"""
import argparse
import time

from companion.rehearsal.launcher import SimulatorProcess
from companion.link.vehicle import VehicleLink
from companion.procedures.app import AbortFlag
from companion.procedures.roll import RollProcedureConfig, roll_procedure


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--speedups", default="10,100")
    parser.add_argument("--open-s", type=float, default=30.0, help="open-loop seconds (vehicle time)")
    parser.add_argument("--closed-s", type=float, default=40.0, help="closed-loop seconds (vehicle time)")
    args = parser.parse_args()
    cfg = RollProcedureConfig(settle_s=5, open_s=args.open_s, closed_s=args.closed_s, kick_deg=0)
    for lockstep in (False, True):
        for speedup in (float(s) for s in args.speedups.split(",")):
            with SimulatorProcess(speedup=speedup, seed=3, lockstep=lockstep) as sim:
                link = VehicleLink.connect(sim.endpoint, lockstep=lockstep)
                link.arm(True)
                t = time.monotonic()
                r = roll_procedure(link, AbortFlag(), cfg, simulator=True).to_json()
                link.close()
            print("lockstep", lockstep, "x", f"{speedup:g}", "open %.3f closed %.3f" % (r["std_open_deg"], r["std_closed_deg"]),
                  "wall %.1f" % (time.monotonic() - t))


if __name__ == "__main__":
    main()
