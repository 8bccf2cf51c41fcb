"""Figures of the campaign on the real PX4 firmware: identification error against the simulator's
linearised truth at each speed, validation R², and ±20° heading-step overshoot, time to 5 % and step
error (IAE) for PX4's gains as found and for the designed schedule; with ``--aborts``, the four abort
scenarios and what each left not as found.

PX4 SITL (built by you from PX4's sources; its build folder in ``PX4_SITL_BIN`` or ``--px4-bin``)
flies our boat (``px4-rover``: the Ackermann rover module) or our AUV (``px4-uuv``: the HippoCampus
airframe, the AUV trimmed neutral) through its MAVLink HIL interface. Run it inside a private
network namespace:

    unshare -n bash -c 'ip link set lo up; python bench/bench_px4.py --autopilot px4-rover --repeats 3'
"""
from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

from companion.link.profiles import get_profile
from companion.procedures.campaign import CampaignConfig
from companion.rehearsal.rehearsal import RehearsalConfig, rehearse

PRESETS = {"px4-rover": "boat", "px4-uuv": "starfish"}


def _largest_gaps(summary: dict) -> dict[float, float]:
    """Thrust -> the largest interval (ms) between two samples of its accepted yaw records: a
    companion that lags PX4's stream loses UDP datagrams, and a record with holes identifies worse."""
    from companion.records.store import Store

    gaps: dict[float, float] = {}
    if not summary.get("store") or summary.get("campaign_id") is None:
        return gaps
    with Store(summary["store"], read_only=True) as store:
        for run in store.runs(summary["campaign_id"], with_series=True):
            if run["axis"] != "yaw" or not run["accepted"]:
                continue
            steps = []
            for part in ("training", "validation"):  # each record on its own (they are seconds apart)
                times = (run["series"].get(part) or {}).get("time", [])
                steps += [b - a for a, b in zip(times, times[1:]) if b > a]
            gaps[run["thrust"]] = 1000.0 * max(steps, default=float("nan"))
    return gaps


def _identification(args, campaign) -> None:
    errors_a22, errors_b2, r2s, steps, vehicle_s, walls, outcomes = [], [], [], {}, [], [], []
    phases: list[dict] = []
    versus: list[tuple[float, float, float, float, float]] = []  # thrust, flown/predicted overshoot and IAE
    originals: dict[float, list[dict]] = {}  # PX4's gains as found, predicted at each identified speed
    print(f"{args.autopilot} SITL + preset {PRESETS[args.autopilot]}, thrusts {campaign.thrusts}, {args.repeats} "
          f"repeats at {args.speedup:g}x")
    print("errors against the simulator's linearised truth at the physics' own speed (its truth log); 'est.' is PX4's")
    print(f"{'run':>3} {'thrust':>6} {'speed':>6} {'est.':>6} {'a22':>8} {'true':>8} {'err%':>6} {'b2':>7} {'true':>7} "
          f"{'err%':>6} {'R2':>6} {'gap ms':>7}")
    for repeat in range(args.repeats):
        with tempfile.TemporaryDirectory() as out:
            config = RehearsalConfig(preset=PRESETS[args.autopilot], speedup=args.speedup, seed=repeat + 1,
                                     out_dir=out, campaign=campaign, behaviors=(), progress=False,
                                     autopilot=args.autopilot, px4_bin=args.px4_bin, report=False)
            started = time.monotonic()
            summary = rehearse(config)
            walls.append(time.monotonic() - started)
            gaps = _largest_gaps(summary)
        outcomes.append(str(summary.get("status")))
        verified = summary.get("verified") or {}
        for step in verified.get("flown", []):
            if step.get("predicted"):
                versus.append((step["thrust"], step["max_overshoot_pct"], step["predicted"]["overshoot_pct"],
                               step["iae_s"], step["predicted"]["iae_s"]))
        for row in verified.get("predicted", []):
            if row["label"] == "original":
                originals.setdefault(row["thrust"], []).append(row)
        vehicle_s.append(summary.get("vehicle_time_s") or 0.0)
        phases.append(summary.get("vehicle_time_by_phase") or {})
        for run in summary.get("runs", []):
            ea = 100.0 * (run["a22"] / run["true_a22"] - 1.0)
            eb = 100.0 * (run["b2"] / run["true_b2"] - 1.0)
            errors_a22.append(abs(ea))
            errors_b2.append(abs(eb))
            r2s.append(run["r2"])
            print(f"{repeat + 1:>3} {run['thrust']:>6.2f} {run.get('true_speed') or float('nan'):>6.3f} "
                  f"{run['speed']:>6.3f} {run['a22']:>8.4f} {run['true_a22']:>8.4f} {ea:>6.1f} {run['b2']:>7.4f} "
                  f"{run['true_b2']:>7.4f} {eb:>6.1f} {run['r2']:>6.3f} {gaps.get(run['thrust'], float('nan')):>7.0f}")
        for step in summary.get("heading_steps", []):
            steps.setdefault((step["label"], step["thrust"]), []).append(step)
        if summary.get("status") != "completed" or summary.get("verification") != "passed":
            print(f"    run {repeat + 1}: {summary.get('status')} ({summary.get('reason')}); "
                  f"verification {summary.get('verification')}")
        else:
            print(f"    run {repeat + 1}: gains kept {summary.get('final_gains')}")

    def med(values):
        values = [v for v in values if v is not None]
        return statistics.median(values) if values else float("nan")

    def top(values):
        values = [v for v in values if v is not None]
        return max(values) if values else float("nan")

    print()
    print(f"outcomes: {outcomes}")
    print(f"|a22 error| median {med(errors_a22):.1f} %, max {top(errors_a22):.1f} %  (goal ≤ 5 %)")
    print(f"|b2 error|  median {med(errors_b2):.1f} %, max {top(errors_b2):.1f} %  (goal ≤ 5 %)")
    print(f"validation R² min {min(r2s, default=float('nan')):.3f}, median {med(r2s):.3f}  (goal ≥ 0.9)")
    print("heading steps ±20° (PX4's gains as found = 'original'; goal for 'scheduled': ≤ 10 %, faster):")
    print(f"{'gains':>10} {'thrust':>6} {'overshoot % med/max':>20} {'time to 5 % s med/max':>22} {'IAE s med':>10}")
    for (label, thrust), rows in sorted(steps.items(), key=lambda item: (item[0][1], item[0][0])):
        over = [r["max_overshoot_pct"] for r in rows]
        settle = [r.get("settling_time_s") for r in rows]
        print(f"{label:>10} {thrust:>6.2f} {med(over):>9.1f} / {top(over):<8.1f} {med(settle):>10.1f} / "
              f"{top(settle):<9.1f} {med([r['iae_s'] for r in rows]):>10.2f}")
    print("PX4's gains as found, predicted on each run's model (not flown: eq. A.3):")
    for thrust, rows in sorted(originals.items()):
        print(f"{'original':>10} {thrust:>6.2f} {med([r['overshoot_pct'] for r in rows]):>9.1f} / "
              f"{top([r['overshoot_pct'] for r in rows]):<8.1f} {med([r.get('settling_time_s') for r in rows]):>10.1f} / "
              f"{top([r.get('settling_time_s') for r in rows]):<9.1f} {med([r['iae_s'] for r in rows]):>10.2f}")
    if versus:
        print("flown minus predicted, the design's verification steps (eq. A.3's margin):")
        print(f"  overshoot points: {', '.join(f'{f - p:+.1f}' for _t, f, p, _fi, _pi in versus)}")
        print(f"  IAE %:            {', '.join(f'{100.0 * (fi / pi - 1.0):+.1f}' for *_x, fi, pi in versus)}")
    names = sorted({name for by_phase in phases for name in by_phase})
    by_phase = ", ".join(f"{name} {med([p.get(name, 0.0) for p in phases]):.0f} s" for name in names)
    print(f"vehicle time per campaign median {med(vehicle_s):.0f} s ({min(vehicle_s):.0f}–{max(vehicle_s):.0f} s; "
          f"median by phase: {by_phase}); wall time {med(walls):.0f} s at {args.speedup:g}x")


def _aborts(args) -> None:
    from harness.px4 import SCENARIOS, UdpRelay, connect_armed, run_scenario, simulator

    print(f"\naborts on {args.autopilot}: each from as found, then checked after 12 s of vehicle time")
    with tempfile.TemporaryDirectory() as out, simulator(args.autopilot, Path(out), args.speedup) as sim:
        relay = UdpRelay(sim.port)
        link = connect_armed(sim, relay)
        try:
            for name in SCENARIOS:
                row = run_scenario(name, link, relay, Path(out))
                verdict = "as found" if not row["not_as_found"] and not row["restore_problems"] else \
                    f"NOT as found: {row['not_as_found'] + row['restore_problems']}"
                print(f"  {name:>17}: {row['status']} ({row['reason']}): {verdict}")
        finally:
            link.close()
            relay.close()


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--autopilot", choices=sorted(PRESETS), default="px4-rover")
    parser.add_argument("--px4-bin", default=os.environ.get("PX4_SITL_BIN"))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--speedup", type=float, default=5.0)
    parser.add_argument("--thrusts", default=None, help="comma-separated (default: the profile's three)")
    parser.add_argument("--aborts", action="store_true", help="also run the four abort scenarios")
    parser.add_argument("--no-campaigns", action="store_true", help="only the abort scenarios")
    args = parser.parse_args()
    if not args.px4_bin:
        print("no PX4 SITL: pass --px4-bin DIR or set PX4_SITL_BIN", file=sys.stderr)
        return 2
    os.environ["PX4_SITL_BIN"] = args.px4_bin
    # the campaign ``identify --connect`` flies on this autopilot: its profile's thrusts, axes, doublets
    campaign = CampaignConfig().with_profile_defaults(get_profile(args.autopilot)).quick()
    if args.thrusts:
        campaign = CampaignConfig(thrusts=tuple(float(t) for t in args.thrusts.split(",")),
                                  user_set=("thrusts",)).with_profile_defaults(get_profile(args.autopilot)).quick()
    if not args.no_campaigns:
        _identification(args, campaign)
    if args.aborts or args.no_campaigns:
        _aborts(args)
    return 0


if __name__ == "__main__":
    sys.exit(main())
