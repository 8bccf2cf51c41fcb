"""Figures of the campaign on the real ArduPilot firmware: per speed, the identified a22 and b2
against the stated truth (median and worst over the runs), validation R², the chosen speed law,
heading steps (overshoot and time to stay within 5 %) with the vehicle's default gains, Rover
QuickTune's FF rule and the design, speed steps with the default and the designed speed loop, and
the campaign's vehicle time.

ArduPilot SITL (built by you from ArduPilot's sources; its bin folder in ``ARDUPILOT_SITL_BIN`` or
``--ardupilot-bin``) flies our physics through the JSON backend, on loopback. Run it inside a
private network namespace (``unshare -n``, then ``ip link set lo up``).

    python bench/bench_ardupilot.py --frame rudder --physics 3dof --repeats 3
    python bench/bench_ardupilot.py --frame skid --physics 3dof --repeats 3
    python bench/bench_ardupilot.py --frame rudder --physics nomoto          # the first-order boat
    python bench/bench_ardupilot.py --frame skid --physics ardupilot         # SITL's own motorboat-skid
    python bench/bench_ardupilot.py --autopilot ardusub                      # our AUV on ArduSub

The truth of a 3-DOF hull is its doublet-equivalent first-order model (eq. S.6, at each run's own
doublet, speed and record); Nomoto's classic K/T and the nonlinear hull's fit at the flown
amplitude are printed beside it. ``--physics ardupilot`` flies ArduPilot's own motorboat model
(``--model motorboat[-skid]`` with rover.parm, motorboat.parm and, skid, rover-skid.parm; waves and
wind off unless ``--waves``), which has no truth to score against: it runs
``companion identify --connect`` as a user would and prints what happened.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

from companion.cli.commands._campaign_text import verification_lines
from companion.link.profiles import get_profile
from companion.procedures.campaign import CampaignConfig
from companion.rehearsal.rehearsal import RehearsalConfig, preset_defaults, rehearse

PRESETS = {("ardurover", "rudder", "nomoto"): "boat", ("ardurover", "rudder", "3dof"): "boat-3dof",
           ("ardurover", "skid", "3dof"): "boat-skid", ("ardusub", "rudder", "nomoto"): "starfish"}


def med(values):
    values = [v for v in values if v is not None and math.isfinite(v)]
    return statistics.median(values) if values else float("nan")


def worst(values):
    values = [abs(v) for v in values if v is not None and math.isfinite(v)]
    return max(values) if values else float("nan")


def fmt(value, spec=".1f"):
    return format(value, spec) if isinstance(value, (int, float)) and math.isfinite(value) else "-"


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--autopilot", choices=("ardurover", "ardusub"), default="ardurover")
    parser.add_argument("--frame", choices=("rudder", "skid"), default="rudder",
                        help="rudder: steering servo and throttle; skid: twin thrusters (ArduRover)")
    parser.add_argument("--physics", choices=("nomoto", "3dof", "ardupilot"), default="3dof",
                        help="nomoto: our first-order boat; 3dof: our surge-sway-yaw hull; ardupilot: SITL's own "
                             "model (ArduRover's motorboat, ArduSub's vectored ROV; no truth)")
    parser.add_argument("--ardupilot-bin", default=os.environ.get("ARDUPILOT_SITL_BIN"))
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--speedup", type=float, default=10.0)
    parser.add_argument("--thrusts", default=None, help="comma-separated (default: the autopilot's)")
    parser.add_argument("--step-deg", type=float, default=40.0, help="heading-step size (default 40)")
    parser.add_argument("--waves", action="store_true", help="--physics ardupilot: waves and wind on (robustness)")
    parser.add_argument("--wp-speed", type=float, default=None,
                        help="--physics ardupilot: WP_SPEED set on the boat (m/s) before the campaign (default: "
                             "the frame's, 3 m/s)")
    parser.add_argument("--procedure", choices=("quick", "thesis"), default="quick",
                        help="the campaign procedure (default: quick, what identify --connect flies)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="--physics ardupilot: a parameter set on the vehicle before the campaign (repeatable), "
                             "as a user would change it")
    parser.add_argument("--keep", default=None, metavar="DIR",
                        help="keep each run's folder (its store, with the flown steps; SITL's own vehicles: "
                             "identify's JSON too) in DIR/run-N")
    parser.add_argument("--full-comparison", action="store_true",
                        help="fly the defaults, QuickTune's rule and the design at every speed (identify "
                             "--full-comparison) instead of verifying the design with two steps")
    args = parser.parse_args()
    if not args.ardupilot_bin:
        print("no ArduPilot SITL: pass --ardupilot-bin DIR or set ARDUPILOT_SITL_BIN", file=sys.stderr)
        return 2
    if args.physics == "ardupilot":
        return motorboat(args)
    preset = PRESETS.get((args.autopilot, args.frame if args.autopilot == "ardurover" else "rudder", args.physics))
    if preset is None:
        print(f"no preset for {args.autopilot} {args.frame} {args.physics} (skid boats exist as 3dof only)",
              file=sys.stderr)
        return 2
    return ours(args, preset)


def campaign_of(args) -> CampaignConfig:
    """The campaign ``identify --connect`` flies on this autopilot (its profile's thrusts, axes, doublets),
    with heading steps of ``--step-deg``."""
    campaign = CampaignConfig().with_profile_defaults(get_profile(args.autopilot)).for_procedure(args.procedure)
    step = math.radians(args.step_deg)
    campaign = replace(campaign, step_test=replace(campaign.step_test, step=step),
                       verification=replace(campaign.verification, step=step))
    if args.full_comparison:
        campaign = replace(campaign, checks="compare")
    if args.thrusts:
        campaign = replace(campaign, thrusts=tuple(float(t) for t in args.thrusts.split(",")),
                           user_set=("thrusts",))
    return campaign


def ours(args, preset: str) -> int:
    campaign = campaign_of(args)
    summaries, walls = [], []
    print(f"{args.autopilot} SITL + our {preset} physics, {args.repeats} runs at {args.speedup:g}x, {args.procedure} "
          f"procedure, ±{args.step_deg:g}° heading steps")
    for repeat in range(args.repeats):
        with _run_folder(args.keep, repeat) as out:
            config = RehearsalConfig(preset=preset, speedup=args.speedup, seed=repeat + 1, out_dir=out,
                                     campaign=campaign, behaviors=(), progress=False, report=False,
                                     current=preset_defaults(preset)["current"], autopilot=args.autopilot,
                                     ardupilot_bin=args.ardupilot_bin)
            started = time.monotonic()
            summaries.append(rehearse(config))
            walls.append(time.monotonic() - started)
        s = summaries[-1]
        print(f"run {repeat + 1}: {s.get('status')}" + (f" ({s.get('reason')})" if s.get("reason") else "")
              + f", vehicle time {fmt(s.get('vehicle_time_s'), '.0f')} s")
    identification_table(summaries)
    law_table(summaries)
    heading_table(summaries)
    for index, s in enumerate(summaries):
        lines = verification_lines(s.get("verified"))
        if lines:
            print(f"\nrun {index + 1}: " + "\n".join(lines))
    speed_table(summaries)
    times = [s.get("vehicle_time_s") for s in summaries]
    phases = {}
    for s in summaries:
        for phase, seconds in (s.get("vehicle_time_by_phase") or {}).items():
            phases.setdefault(phase, []).append(seconds)
    print(f"\nvehicle time per campaign: median {fmt(med(times), '.0f')} s ("
          + ", ".join(f"{k} {fmt(med(v), '.0f')} s" for k, v in sorted(phases.items()))
          + f"); wall time median {fmt(med(walls), '.0f')} s at {args.speedup:g}x")
    print(f"outcomes: {[str(s.get('status')) for s in summaries]}")
    return 0


@contextlib.contextmanager
def _run_folder(keep: str | None, repeat: int):
    """A run's rehearsal folder: DIR/run-N, kept, with ``--keep``; else a temporary one."""
    if keep is None:
        with tempfile.TemporaryDirectory() as out:
            yield out
        return
    folder = Path(keep) / f"run-{repeat + 1}"
    folder.mkdir(parents=True, exist_ok=True)
    yield str(folder)


def identification_table(summaries) -> None:
    rows = {}
    for s in summaries:
        for run in s.get("runs", []):
            rows.setdefault(run["thrust"], []).append(run)
    print("\nidentification against the stated truth (3-DOF: doublet-equivalent first order, eq. S.6; first order:"
          " the linearisation) at the physics' own speed; error % median / worst over the runs")
    print(f"{'thrust':>6} {'speed':>6} {'a22':>7} {'truth':>7} {'err%':>11} {'b2':>6} {'truth':>6} {'err%':>11} "
          f"{'R2 min':>6} | {'K/T a22':>7} {'b2':>6} | {'at amp. a22':>11} {'b2':>6}")
    for thrust, runs in sorted(rows.items()):
        ea = [100 * (r["a22"] / r["true_a22"] - 1) for r in runs if r.get("true_a22")]
        eb = [100 * (r["b2"] / r["true_b2"] - 1) for r in runs if r.get("true_b2")]
        print(f"{thrust:>6.2f} {fmt(med([r.get('true_speed') or r['speed'] for r in runs]), '.3f'):>6} "
              f"{fmt(med([r['a22'] for r in runs]), '.3f'):>7} {fmt(med([r.get('true_a22') for r in runs]), '.3f'):>7} "
              f"{fmt(med(ea), '+.1f'):>5}/{fmt(worst(ea), '.1f'):>5} "
              f"{fmt(med([r['b2'] for r in runs]), '.3f'):>6} {fmt(med([r.get('true_b2') for r in runs]), '.3f'):>6} "
              f"{fmt(med(eb), '+.1f'):>5}/{fmt(worst(eb), '.1f'):>5} {fmt(min(r['r2'] for r in runs), '.3f'):>6} | "
              f"{fmt(med([r.get('true_a22_nomoto') for r in runs]), '.3f'):>7} "
              f"{fmt(med([r.get('true_b2_nomoto') for r in runs]), '.3f'):>6} | "
              f"{fmt(med([r.get('true_a22_amplitude') for r in runs]), '.3f'):>11} "
              f"{fmt(med([r.get('true_b2_amplitude') for r in runs]), '.3f'):>6}")
    errors_a = [100 * (r["a22"] / r["true_a22"] - 1) for runs in rows.values() for r in runs if r.get("true_a22")]
    errors_b = [100 * (r["b2"] / r["true_b2"] - 1) for runs in rows.values() for r in runs if r.get("true_b2")]
    print(f"|a22 error| median {fmt(med([abs(e) for e in errors_a]))} %, worst {fmt(worst(errors_a))} %; "
          f"|b2 error| median {fmt(med([abs(e) for e in errors_b]))} %, worst {fmt(worst(errors_b))} %  (goal ≤ 5 %)")


def law_table(summaries) -> None:
    for index, s in enumerate(summaries):
        for name, design in (s.get("design") or {}).items():
            schedule = design.get("schedule") or {}
            print(f"run {index + 1} {name} schedule: b2 law {schedule.get('b2_law')}: {schedule.get('b2_law_reason')}")


def heading_table(summaries) -> None:
    rows = {}
    for s in summaries:
        for step in s.get("heading_steps", []):
            rows.setdefault((step["thrust"], step["label"]), []).append(step)
    if not rows:
        return
    print("\nheading steps: overshoot % and time to stay within 5 % (s), median / worst over the runs")
    print(f"{'thrust':>6} {'gains':>10} {'overshoot':>12} {'to 5 %':>12} {'IAE':>6}")
    for (thrust, label), steps in sorted(rows.items()):
        over = [s["max_overshoot_pct"] for s in steps]
        settle = [s["settling_time_s"] if s.get("settling_time_s") is not None else math.inf for s in steps]
        print(f"{thrust:>6.2f} {label:>10} {fmt(med(over)):>5} / {fmt(worst(over)):>5} "
              f"{fmt(med(settle)):>5} / {fmt(max(settle)):>5} {fmt(med([s['iae_s'] for s in steps]), '.2f'):>6}")
    design = [s for (_, label), steps in rows.items() if label == "scheduled" for s in steps]
    print(f"designed gains: worst overshoot {fmt(worst([s['max_overshoot_pct'] for s in design]))} % (goal ≤ 10 %)")


def speed_table(summaries) -> None:
    loops = [s.get("speed_loop") for s in summaries if s.get("speed_loop")]
    if not loops:
        return
    print("\nspeed loop (surge model eq. S.4; design eq. S.5; steps in GUIDED there and back)")
    for index, loop in enumerate(loops):
        surge, design = loop.get("surge"), loop.get("design")
        print(f"run {index + 1}: {loop['status']} ({loop.get('reason') or loop.get('verdict')})")
        if surge:
            print(f"  surge: {surge['describe']}, R² {fmt(surge.get('r2'), '.4f')}")
        keeps = bool((design or {}).get("keeps_original"))
        if design:
            gains = design["gains"]
            worst = design.get("worst_settling_s") or {}
            print(f"  worst summed settling over the feed-forward error ±{100 * (design.get('feed_forward_error') or 0):.1f} % "
                  f"(eq. S.5r): design {fmt(worst.get('design'))} s, original {fmt(worst.get('original'))} s")
            print(f"  {'best design (not written)' if keeps else 'design'}: CRUISE_SPEED {gains['cruise_speed']:.2f}, CRUISE_THROTTLE {100 * gains['cruise_thrust']:.1f},"
                  f" ATC_SPEED_P {gains['speed_p']:.3f}, ATC_SPEED_I {gains['speed_i']:.3f} (original "
                  + ", ".join(f"{k} {v:.3g}" for k, v in (loop.get("original") or {}).items()) + ")")
        predicted = (design or {}).get("predicted") or {}
        for label, steps in (loop.get("steps") or {}).items():
            detail = "; ".join(f"{x['start']:.2f}→{x['target']:.2f} m/s: {fmt(x['overshoot_pct'])} %, "
                               f"{fmt(x['settling_time_s'])} s" for x in steps["steps"])
            forecast = [predicted.get(label), predicted.get(f"{label}_back")]
            if all(forecast):
                detail += " (predicted " + "; ".join(f"{fmt(p['overshoot_pct'])} %, {fmt(p['settling_time_s'])} s"
                                                     for p in forecast) + ")"
            print(f"  {label:>8}: {detail}")
        if "original" not in (loop.get("steps") or {}) and predicted.get("original"):
            print("  original: predicted " + "; ".join(f"{fmt(predicted[k]['overshoot_pct'])} %, "
                                                      f"{fmt(predicted[k]['settling_time_s'])} s"
                                                      for k in ("original", "original_back"))
                  + (" (not flown: no design predicted better, the vehicle's own gains stay)" if keeps
                     else " (not flown: the design's flight agreed with its prediction)"))
        elif loop.get("original_flown_because"):
            print(f"  original flown: {loop['original_flown_because']}")


# ---------------------------------------------------------------------------- ArduPilot's own boat
def motorboat(args) -> int:
    """SITL's own motorboat (skid or rudder), or ArduSub's own vectored ROV, as a user finds them
    (their shipped defaults), and ``companion identify --connect`` against it. ArduSub's failsafes
    for a pilot's sticks and the ground station's heartbeat are off (FS_PILOT_INPUT 0, FS_GCS_ENABLE
    0) so the rig can arm it from one client."""
    from companion.link.vehicle import VehicleLink
    from companion.rehearsal.rehearsal import arm_when_ready
    from sim.ardupilot_sitl import free_instance

    source = Path(args.ardupilot_bin).resolve().parents[2] / "Tools" / "autotest" / "default_params"
    sub = args.autopilot == "ardusub"
    model = "vectored" if sub else "motorboat-skid" if args.frame == "skid" else "motorboat"
    files = (["sub.parm"] if sub else
             ["rover.parm", "motorboat.parm"] + (["rover-skid.parm"] if args.frame == "skid" else []))
    outcomes: list = []
    totals: list[float] = []
    for repeat in range(args.repeats):
        with _run_folder(args.keep, repeat) as work:
            extra = Path(work) / "bench.parm"
            found = ("FS_PILOT_INPUT 0\nFS_GCS_ENABLE 0\n" if sub else
                     ("SIM_WAVE_ENABLE 1\nSIM_WIND_SPD 3\n" if args.waves else "SIM_WAVE_ENABLE 0\nSIM_WIND_SPD 0\n")
                     + (f"WP_SPEED {args.wp_speed:g}\n" if args.wp_speed else ""))
            extra.write_text(found + "".join(f"{name.strip()} {value.strip()}\n"
                                             for name, _, value in (item.partition("=") for item in args.set)))
            defaults = ",".join([str(source / f) for f in files] + [str(extra)])
            instance = free_instance()
            port = 5760 + 10 * instance
            command = [str(Path(args.ardupilot_bin) / ("ardusub" if sub else "ardurover")), "--model", model, "--speedup", f"{args.speedup:g}",
                       "-I", str(instance), "--home", "-35.363262,149.165237,0,0", "--defaults", defaults]
            print(f"run {repeat + 1}: {' '.join(command)}")
            sitl = subprocess.Popen(command, cwd=work, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
            try:
                time.sleep(2.0)
                endpoint = f"tcp:127.0.0.1:{port}"
                link = VehicleLink.connect(endpoint, heartbeat_timeout_s=60.0)
                try:
                    arm_when_ready(link, patience_s=120.0)  # a user arms the boat; the campaign never does
                finally:
                    link.close()
                identify = [sys.executable, "-m", "companion", "identify", "--connect", endpoint, "--store",
                            str(Path(work) / "s.sqlite"), "--step-deg", f"{args.step_deg:g}", "--json"]
                if args.thrusts:
                    identify += ["--thrusts", args.thrusts]
                if args.full_comparison:
                    identify += ["--full-comparison"]
                print("  " + " ".join(identify[2:]))
                started = time.monotonic()
                done = subprocess.run(identify, capture_output=True, text=True, timeout=3600)
                wall = time.monotonic() - started
                if args.keep:
                    (Path(work) / "identify.json").write_text(done.stdout)
            finally:
                sitl.terminate()
                try:
                    sitl.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    sitl.kill()
        try:
            result = json.loads(done.stdout)
        except json.JSONDecodeError:
            print(f"  exit {done.returncode}: {done.stderr[-800:]}")
            outcomes.append(("error", done.stderr[-200:]))
            continue
        outcomes.append((result["status"], result.get("reason")))
        print(f"  exit {done.returncode}: {result['status']}" + (f" ({result['reason']})" if result.get("reason") else "")
              + f", {wall:.0f} s of wall time")
        for a in result.get("accepted") or []:
            model_ = a["model"]
            print(f"  thrust {a['thrust']:.2f} speed {a['speed']:.2f} m/s: a22 {model_['a22']:.3f} b2 {model_['b2']:.3f} "
                  f"R² {a['r2']:.3f}")
        for name, design in (result.get("design") or {}).items():
            schedule = design.get("schedule") or {}
            print(f"  {name} schedule: b2 law {schedule.get('b2_law')}: {schedule.get('b2_law_reason')}")
        for step in result.get("steps") or []:
            settle = [x.get("settling_time_s") for x in step.get("steps", [])]
            print(f"  heading steps thrust {step['thrust']:.2f} {step['label']:>10}: overshoot "
                  f"{fmt(step.get('max_overshoot_pct'))} %, to 5 % {', '.join(fmt(x) for x in settle)} s")
        loop = result.get("speed_loop")
        if loop:
            print(f"  speed loop: {loop.get('reason') or loop.get('verdict')}")
            for label, steps in (loop.get("steps") or {}).items():
                detail = "; ".join(f"{x['start']:.2f}→{x['target']:.2f} m/s: {fmt(x['overshoot_pct'])} %, "
                                   f"{fmt(x['settling_time_s'])} s" for x in steps["steps"])
                print(f"    {label:>8}: {detail}")
        print(f"  final gains: {result.get('final_gains')}")
        phases = result.get("vehicle_time_by_phase") or {}
        if phases:
            total = sum(phases.values())
            totals.append(total)
            print(f"  vehicle time {total:.0f} s (" + ", ".join(f"{k} {v:.0f} s" for k, v in sorted(phases.items())) + ")")
    print(f"outcomes: {outcomes}")
    if totals:
        print(f"vehicle time: median {statistics.median(totals):.0f} s, {min(totals):.0f}–{max(totals):.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
