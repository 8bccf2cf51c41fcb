"""Closed-loop roll through MAVLink with and without lockstep at 10x and 100x (SPEC C2: results must
not depend on the speed-up). Prints roll std open/closed and wall time.

    python bench/bench_lockstep.py
"""
import sys, time
from pathlib import Path
sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from companion.cli.rehearsal import SimulatorProcess
from companion.link.vehicle import VehicleLink
from companion.procedures.behaviour_procedures import roll_procedure, RollProcedureConfig
from companion.procedures.app import AbortFlag
cfg = RollProcedureConfig(settle_s=5, open_s=30, closed_s=40, kick_deg=0)
for lockstep in (False, True):
    for speedup in (10, 100):
        with SimulatorProcess(speedup=speedup, seed=3, lockstep=lockstep) as sim:
            link = VehicleLink.connect(sim.endpoint, lockstep=lockstep); link.arm(True)
            t = time.monotonic(); r = roll_procedure(link, AbortFlag(), cfg, simulator=True); link.close()
        print("lockstep", lockstep, "x", speedup, "open %.3f closed %.3f" % (r["std_open_deg"], r["std_closed_deg"]), "wall %.1f" % (time.monotonic()-t))
