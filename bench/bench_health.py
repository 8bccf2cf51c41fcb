"""Health monitoring over MAVLink: detection delay of a 30 % loss of fin effectiveness and
false alarms in fault-free missions, measured with ``companion run``'s resident loop.

1. The reference: a live identification campaign (yaw, thrusts 0.6/0.7/0.8, no step checks) on the
   simulator, seed 0, stored as ``companion identify`` stores it.
2. Per seed, on a copy of that store, the simulator (lockstep, as fast as it goes) flies a survey
   at cruise (thrust 0.7, ≈ 1.39 m/s): a course change every ``--leg`` s (30, −20, 25, −35°, in
   turn) by its own heading hold, while :class:`companion.procedures.resident.Companion` (what
   ``companion run`` runs) watches. The course changes are the vehicle's mission: the bench sends
   them on the companion's link, on vehicle time, as a mission planner would.
   * fault-free: ``--hours`` of vehicle time; any alarm is a false alarm;
   * fault: ``python -m sim run --fault b2=0.7@T`` with T = 600 s + (seed − 1)·leg/seeds (the fault
     lands at a different point of the course-change cycle on every seed); the delay is the
     alarm's vehicle time − T.

Prints one row per run and a summary (``--json``: one object). ``--plot FILE.png`` saves the drift
plot of the first fault run (README figure). Never pass/fail.

    python bench/bench_health.py --seeds 5 --hours 1 --jobs 2 --plot docs/health_drift.png
"""
from __future__ import annotations

import argparse
import json
import shutil
import sys
import tempfile
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from behaviors.identification import ManoeuvreConfig  # noqa: E402
from companion.rehearsal.launcher import SimulatorProcess  # noqa: E402
from companion.interface import SetHeading, SetThrust  # noqa: E402
from companion.procedures.campaign import CampaignConfig  # noqa: E402
from harness.missions import SurveyPlan  # noqa: E402

CRUISE = 0.7


def _connect(sim):
    from companion.link.vehicle import VehicleLink

    link = VehicleLink.connect(sim.endpoint, lockstep=True)
    link.arm(True)
    link.set_mode("hold")
    return link


def reference_store(path: Path) -> dict:
    """The live campaign on seed 0 (the healthy vehicle), stored at ``path``; its accepted models."""
    from companion.procedures.app import AbortFlag, run_campaign, vehicle_record
    from companion.records.store import Store

    config = CampaignConfig(thrusts=(0.6, 0.7, 0.8), axes=("yaw",), step_labels=(), write_gains=False,
                            yaw=ManoeuvreConfig())
    with SimulatorProcess(preset="starfish", speedup=0.0, seed=0, lockstep=True) as sim, Store(path) as store:
        link = _connect(sim)
        try:
            campaign, outcome, campaign_id = run_campaign(link, store, config, vehicle_id=vehicle_record(store, link),
                                                          abort=AbortFlag())
        finally:
            link.close()
    return {"campaign_id": campaign_id, "status": outcome.status,
            "models": [{"speed": a.speed, "a22": a.model.a22, "b2": a.model.b2} for a in campaign.accepted]}


def watch(store_path: str, seed: int, seconds: float, fault_at: float | None, factor: float, leg_s: float) -> dict:
    """One ``companion run`` session over MAVLink on a survey at cruise; returns its health record."""
    from companion.procedures.app import AbortFlag
    from companion.procedures.resident import Companion, ServeConfig
    from companion.records.store import Store

    extra = ["--fault", f"b2={factor}@{fault_at}"] if fault_at is not None else []
    plan = SurveyPlan(thrusts=(CRUISE,), seconds_per_thrust=1e9, settle_s=leg_s, leg_s=leg_s,
                      course_changes_deg=(30.0, -20.0, 25.0, -35.0), depth=2.0)
    wall = time.monotonic()
    with SimulatorProcess(preset="starfish", speedup=0.0, seed=seed, lockstep=True, extra_args=extra) as sim, \
            Store(store_path) as store:
        link = _connect(sim)
        read, last = link.next_telemetry, []
        start = []

        def mission(timeout_s: float = 5.0):
            telemetry = read(timeout_s)
            if not start:
                start.append(telemetry.time_s)
            setpoint = plan.setpoints(telemetry.time_s - start[0])
            if setpoint not in last:
                commands = [SetThrust(setpoint[0]), SetHeading(setpoint[1])]
                link.execute(commands)
                last[:] = [setpoint]
            return telemetry

        link.next_telemetry = mission
        try:
            Companion(link, store, store.add_vehicle(f"seed {seed}"), ServeConfig(max_vehicle_s=seconds,
                                                                                schedule_gains=False),
                      AbortFlag()).run()
        finally:
            link.close()
        health = [c for c in store.campaigns() if c["kind"] == "health"][-1]
        result = store.behavior_results(health["id"], "health")[-1]["result"]
    used = [w for w in result["windows"] if w["used"]]
    alarm = result["alarm"]
    row = {"seed": seed, "fault_at_s": fault_at, "vehicle_s": seconds, "wall_s": round(time.monotonic() - wall, 1),
           "windows": len(result["windows"]), "used": len(used), "alarm": alarm,
           "max_cusum_healthy": max([max(w["cusum"].values()) for w in used
                                     if fault_at is None or w["t_end"] < fault_at] or [0.0]),
           "b2_ratio_healthy": [round(w["ratio"]["b2"], 4) for w in used if fault_at is None or w["t_end"] < fault_at]}
    if fault_at is not None:
        row["delay_s"] = round(alarm["time_s"] - fault_at, 2) if alarm else None
        row["after_fault_b2_ratio"] = [round(w["ratio"]["b2"], 3) for w in used if w["t_start"] >= fault_at][:3]
    row["result"] = result
    return row


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--hours", type=float, default=1.0, help="fault-free vehicle time per seed")
    parser.add_argument("--fault-at", type=float, default=600.0)
    parser.add_argument("--factor", type=float, default=0.7)
    parser.add_argument("--after", type=float, default=180.0, help="vehicle seconds watched after the fault")
    parser.add_argument("--leg", type=float, default=30.0, help="seconds between course changes")
    parser.add_argument("--jobs", type=int, default=2)
    parser.add_argument("--plot", default=None, help="save the first fault run's drift plot here")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    work = Path(tempfile.mkdtemp(prefix="bench-health-"))
    try:
        reference = reference_store(work / "reference.sqlite")
        runs = []
        jobs = []
        with ProcessPoolExecutor(max_workers=args.jobs) as pool:
            for seed in range(1, args.seeds + 1):
                # the fault lands at a different point of the course-change cycle on every seed
                onset = args.fault_at + (seed - 1) * args.leg / args.seeds
                for fault_at, seconds in ((onset, onset + args.after), (None, 3600.0 * args.hours)):
                    store = work / f"seed{seed}-{'fault' if fault_at else 'clean'}.sqlite"
                    shutil.copy(work / "reference.sqlite", store)
                    jobs.append(pool.submit(watch, str(store), seed, seconds, fault_at, args.factor, args.leg))
            for job in jobs:
                row = job.result()
                runs.append(row)
                if not args.json:
                    kind = "fault" if row["fault_at_s"] is not None else "clean"
                    alarm = row["alarm"]
                    print(f"seed {row['seed']} {kind:5s} {row['vehicle_s']:6.0f} s vehicle, {row['wall_s']:5.0f} s wall: "
                          f"{row['used']}/{row['windows']} windows used, healthy max CUSUM {row['max_cusum_healthy']:.2f}; "
                          + (f"alarm {alarm['parameter']} {alarm['change_pct']:+.0f}% at {alarm['time_s']:.0f} s"
                             + (f" (delay {row['delay_s']:.1f} s)" if row.get("delay_s") is not None else "")
                             if alarm else "no alarm"), flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    faults = [r for r in runs if r["fault_at_s"] is not None]
    clean = [r for r in runs if r["fault_at_s"] is None]
    delays = [r["delay_s"] for r in faults if r.get("delay_s") is not None]
    summary = {"reference": reference, "cruise_thrust": CRUISE,
               "fault": f"b2 x{args.factor} at {args.fault_at:g} s + (seed - 1) x {args.leg / args.seeds:g} s",
               "detected": f"{len(delays)}/{len(faults)}", "delay_s": {"min": min(delays, default=None),
                                                                      "max": max(delays, default=None),
                                                                      "all": delays},
               "false_alarms": sum(1 for r in clean if r["alarm"]), "fault_free_vehicle_h": sum(r["vehicle_s"] for r in clean) / 3600,
               "fault_free_windows_used": sum(r["used"] for r in clean),
               "fault_free_max_cusum": max((r["max_cusum_healthy"] for r in runs), default=None),
               "pre_fault_false_alarms": sum(1 for r in faults if r["alarm"] and r["alarm"]["time_s"] < r["fault_at_s"])}
    if args.plot and faults:
        from companion.records.report import plot_health

        Path(args.plot).parent.mkdir(parents=True, exist_ok=True)
        plot_health(faults[0]["result"], Path(args.plot))
        summary["plot"] = args.plot
    if args.json:
        print(json.dumps({"summary": summary, "runs": [{k: v for k, v in r.items() if k != "result"} for r in runs]},
                         allow_nan=False))
    else:
        print(json.dumps(summary, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
