"""Figures of the campaign on the real ArduPilot firmware: identification error against
the simulator's linearised truth, validation R², and ±20° heading-step overshoot and step error
(IAE) for the vehicle's default gains, Rover QuickTune's FF rule and the designed schedule.

ArduPilot SITL (built by you from ArduPilot's sources; its bin folder in ``ARDUPILOT_SITL_BIN`` or
``--ardupilot-bin``) flies our physics through the JSON backend, on loopback. Run it inside a private
network namespace if you can (``unshare -n``, then ``ip link set lo up``).

    python bench/bench_ardupilot.py --autopilot ardurover --repeats 3
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from dataclasses import replace

from companion.rehearsal.rehearsal import RehearsalConfig, preset_defaults, rehearse
from companion.link.profiles import get_profile
from companion.procedures.campaign import CampaignConfig

PRESETS = {"ardurover": "boat", "ardusub": "starfish"}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--autopilot", choices=sorted(PRESETS), default="ardurover")
    parser.add_argument("--ardupilot-bin", default=os.environ.get("ARDUPILOT_SITL_BIN"))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--speedup", type=float, default=20.0)
    parser.add_argument("--thrusts", default=None, help="comma-separated (default: the autopilot's three)")
    parser.add_argument("--procedure", choices=("quick", "thesis"), default="quick",
                        help="the campaign procedure (default: quick, what identify --connect flies)")
    args = parser.parse_args()
    if not args.ardupilot_bin:
        print("no ArduPilot SITL: pass --ardupilot-bin DIR or set ARDUPILOT_SITL_BIN", file=sys.stderr)
        return 2
    preset = PRESETS[args.autopilot]
    # the campaign ``identify --connect`` flies on this autopilot: its profile's thrusts, axes, doublets
    campaign = CampaignConfig().with_profile_defaults(get_profile(args.autopilot)).for_procedure(args.procedure)
    if args.thrusts:
        campaign = replace(campaign, thrusts=tuple(float(t) for t in args.thrusts.split(",")))
    thrusts = campaign.thrusts
    errors_a22, errors_b2, r2s, overshoot, iae, walls, vehicle_s, outcomes = [], [], [], {}, {}, [], [], []
    print(f"{args.autopilot} SITL + preset {preset}, thrusts {thrusts}, {args.repeats} repeats at {args.speedup:g}x, "
          f"{args.procedure} procedure")
    print("errors against the simulator's linearised truth at the physics' own speed (its truth log); 'est.' is the")
    print("autopilot's speed estimate, which the schedule uses")
    print(f"{'run':>3} {'thrust':>6} {'speed':>6} {'est.':>6} {'a22 err%':>9} {'b2 err%':>8} {'R2':>6}")
    for repeat in range(args.repeats):
        with tempfile.TemporaryDirectory() as out:
            config = RehearsalConfig(preset=preset, speedup=args.speedup, seed=repeat + 1, out_dir=out,
                                     campaign=campaign, behaviors=(), progress=False,
                                     current=preset_defaults(preset)["current"], autopilot=args.autopilot,
                                     ardupilot_bin=args.ardupilot_bin)
            started = time.monotonic()
            summary = rehearse(config)
            walls.append(time.monotonic() - started)
        outcomes.append(summary.get("status"))
        vehicle_s.append(summary.get("vehicle_time_s") or 0.0)
        for run in summary.get("runs", []):
            ea = 100.0 * (run["a22"] / run["true_a22"] - 1.0)
            eb = 100.0 * (run["b2"] / run["true_b2"] - 1.0)
            errors_a22.append(abs(ea))
            errors_b2.append(abs(eb))
            r2s.append(run["r2"])
            true = run.get("true_speed") or float("nan")
            print(f"{repeat + 1:>3} {run['thrust']:>6.2f} {true:>6.3f} {run['speed']:>6.3f} {ea:>9.1f} {eb:>8.1f} "
                  f"{run['r2']:>6.3f}")
        for step in summary.get("heading_steps", []):
            overshoot.setdefault(step["label"], []).append(step["max_overshoot_pct"])
            iae.setdefault(step["label"], []).append(step["iae_s"])
        if summary.get("status") != "completed":
            print(f"    run {repeat + 1}: {summary.get('status')} ({summary.get('reason')})")

    def med(values):
        return statistics.median(values) if values else float("nan")

    print()
    print(f"outcomes: {outcomes}")
    print(f"|a22 error| median {med(errors_a22):.1f} %, max {max(errors_a22, default=float('nan')):.1f} %  (goal ≤ 5 %)")
    print(f"|b2 error|  median {med(errors_b2):.1f} %, max {max(errors_b2, default=float('nan')):.1f} %  (goal ≤ 5 %)")
    print(f"validation R² min {min(r2s, default=float('nan')):.3f}, median {med(r2s):.3f}  (goal ≥ 0.9)")
    for label, values in sorted(overshoot.items()):
        print(f"heading steps, {label:>9}: overshoot median {med(values):5.1f} %, max {max(values):5.1f} %; "
              f"step error (IAE) median {med(iae[label]):5.1f} s" + ("  (goal ≤ 10 %)" if label == "scheduled" else ""))
    print(f"vehicle time per campaign {med(vehicle_s):.0f} s; wall time {med(walls):.0f} s at {args.speedup:g}x")
    return 0


if __name__ == "__main__":
    sys.exit(main())
