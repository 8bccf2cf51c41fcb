"""The identification campaign over a lossy, jittery UDP link: models, gains and restores per link
condition (``harness/udp_relay.py`` between the companion and a paced simulator).

Each run: the simulator (STARFISH, UDP, ``--speedup`` 5 or 20, no lockstep: a lossy link cannot
carry lockstep's acknowledgements), the companion through the relay running the campaign through
the application path (``run_campaign``, the quick procedure by default: what ``companion identify``
flies), then a direct client reading what the vehicle holds (``harness/link_campaign.py``). The same
seed drives the simulator and the relay's draws. Conditions, on both directions:

    clean    no loss, no delay
    loss2    2 % of datagrams lost
    jitter   50 ± 20 ms (uniform) of delay: datagrams closer than the jitter arrive out of order
    both     2 % loss and 50 ± 20 ms
    loss10   10 % lost

Prints per condition and speed-up: campaigns completed, yaw models accepted of those tried, the
signed a22 and b2 errors of the accepted ones against ``python -m sim linearize`` at their training
speed (median, range), their validation R² (min), gains written (runs, HDG_P range), what the relay
delivered out of vehicle-time order and lost (ATTITUDE samples to the companion, which drops an
older sample; datagrams to the vehicle), what the companion itself reports about the link (read
where it may appear; today only ``snapshots_dropped``), and the restores: confirmed by the vehicle's
state and claimed by the companion.

``--reproduce`` runs two reproductions instead (at ``--speedups``' first value, the short campaign of
the fault cases: yaw at 0.7 and 1.0 with one step check), and prints what the vehicle held after
beside what the companion reported:

- *a late set-point overtaking the restore's*: a clean run first counts the DO_CHANGE_SPEED frames
  the companion sends before its restore's; then the last of them (the last heading step's 100 %) is
  made late through the relay. Deterministically on a lockstep simulator (the fault cases' run, where
  the companion's traffic is a function of the seed): held until the restore's 70 % has passed. The
  way it was first found, on the paced simulator: 80 ms late (overtaken only when the restore's follows within
  80 ms, and only if the count of the clean run holds: both depend on the machine's load). Passes
  when the vehicle runs at the thrust it was found with, or the companion says it could not confirm
  it.
- *a ground station's change*: a second client (system 255, straight to the simulator's UDP port;
  the simulator serves several UDP clients) sets HDG_P 0.9 at the campaign's first RC override
  (its first doublet). Passes when the vehicle still holds 0.9 afterwards, or the companion reports
  the change (its reason or restore problems name HDG_P or someone else).

Both are expected to fail until the companion confirms restores by state and respects other
clients' changes: they measure the defects.

Delays are wall-clock figures of the relay, while the vehicle runs ``--speedup`` times faster: at 5×,
50 ± 20 ms of the relay are 250 ± 100 ms of the vehicle's time (at 20×, 1 ± 0.4 s: a sample then
arrives more than a second after a newer one, which the companion takes for a reboot). With
``--vehicle-time`` the delays are divided by the speed-up, so that the vehicle meets the link of a
1× vehicle (loss is the same either way).

    python bench/bench_link_conditions.py [--conditions clean,loss2,jitter,both,loss10] [--seeds 3]
        [--speedups 5,20] [--vehicle-time] [--axes yaw] [--thrusts 0.6,0.8,1.0] [--no-steps] [--jobs 1]
        [--json FILE]
    python bench/bench_link_conditions.py --reproduce [--speedups 5] [--seeds 1]
"""
from __future__ import annotations

import argparse
import json
import logging
import statistics
import sys
import tempfile
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict
from pathlib import Path

from harness.fault_schedule import Trigger, overtaken, timed_delay
from harness.link_campaign import DO_CHANGE_SPEED, CampaignRun, run_campaign_through_relay
from harness.link_conditions import LinkConditions
from harness.simulator import SimulatorError, start_sim

CONDITIONS = {
    "clean": LinkConditions(),
    "loss2": LinkConditions(loss=0.02),
    "jitter": LinkConditions(delay_s=0.05, jitter_s=0.02),
    "both": LinkConditions(loss=0.02, delay_s=0.05, jitter_s=0.02),
    "loss10": LinkConditions(loss=0.10),
}
LATE_SETPOINT_S = 0.08  # the reproduction's delay of the last thrust set-point before the restore
LOCKSTEP_SPEEDUP = 50.0  # the deterministic reproduction's lockstep simulator
GCS_HDG_P = 0.9  # what the ground station writes mid-campaign
GCS_SYSTEM = 255
WAIT_GCS_S = 900.0  # wall seconds the ground station waits for the first doublet (bounded)


# ====================================================================== one run
def campaign_config(axes: str | None, thrusts: str | None, no_steps: bool):
    """The quick procedure (``companion identify``'s default), narrowed as asked."""
    from companion.procedures.campaign import CampaignConfig

    fields: dict = {"schedules": ("heading",)}
    if axes:
        fields["axes"] = tuple(a for a in axes.split(",") if a)
    if thrusts:
        fields["thrusts"] = tuple(float(t) for t in thrusts.split(",") if t)
    if no_steps:
        fields["step_labels"] = ()
    return CampaignConfig(**fields).for_procedure("quick")


def in_vehicle_time(conditions: LinkConditions, speedup: float) -> LinkConditions:
    """``conditions`` as a vehicle running ``speedup`` times faster than the wall clock meets them:
    delays divided by the speed-up, a rate cap multiplied by it."""
    from dataclasses import replace

    rate = conditions.rate_bytes_s * speedup if conditions.rate_bytes_s is not None else None
    return replace(conditions, delay_s=conditions.delay_s / speedup, jitter_s=conditions.jitter_s / speedup,
                   reorder_max_s=conditions.reorder_max_s / speedup, rate_bytes_s=rate)


def one_run(condition: str, seed: int, speedup: float, axes: str | None, thrusts: str | None,
            no_steps: bool, vehicle_time: bool = False) -> dict:
    """A campaign under ``condition`` on a fresh simulator (a process of its own when ``--jobs`` > 1)."""
    config = campaign_config(axes, thrusts, no_steps)
    conditions = in_vehicle_time(CONDITIONS[condition], speedup) if vehicle_time else CONDITIONS[condition]
    with tempfile.TemporaryDirectory(prefix="bench-link-") as workdir:
        sim = start_sim(transport="udp", speedup=speedup, seed=seed, lockstep=False)
        try:
            run = run_campaign_through_relay(sim, condition, conditions, seed, config, Path(workdir))
        except Exception as exc:  # noqa: BLE001 - the harness failed: reported, the bench goes on
            run = CampaignRun(condition, seed, speedup, crash=f"harness: {type(exc).__name__}: {exc}",
                              state_problems=["not checked"])
        finally:
            sim.stop()
    out = asdict(run)
    out["restored_by_state"], out["restore_claimed"] = run.restored_by_state, run.restore_claimed
    return out


# ====================================================================== the table
def _range(values: list[float], fmt: str = "+.1f") -> str:
    if not values:
        return "-"
    return (f"{statistics.median(values):{fmt}} ({min(values):{fmt}}…{max(values):{fmt}})" if len(values) > 1
            else f"{values[0]:{fmt}}")


def _percent(part: float, whole: float) -> str:
    return f"{100.0 * part / whole:.1f} %" if whole else "-"


def summarise(runs: list[dict]) -> list[str]:
    """The figures of one condition at one speed-up."""
    models = [m for r in runs for m in r["models"]]
    yaw = [a for r in runs for a in r["attempts"] if a["axis"] == "yaw"]
    written = [r for r in runs if r["final_gains"]]
    hdg_p = [r["final_gains"].get("HDG_P") for r in written if r["final_gains"].get("HDG_P") is not None]
    down = [r["relay"].get("to_companion", {}) for r in runs]
    up = [r["relay"].get("to_vehicle", {}) for r in runs]
    att_delivered = sum(d.get("attitude_delivered", 0) for d in down)
    att_late = sum(d.get("attitude_out_of_order", 0) for d in down)
    att_lost = sum(d.get("attitude_lost", 0) for d in down)
    per_run_late = [_percent(d.get("attitude_out_of_order", 0), d.get("attitude_delivered", 0)) for d in down]
    exposed: dict = {}
    for r in runs:
        for key, value in r["companion"].items():
            if isinstance(value, (int, float)):
                exposed[key] = exposed.get(key, 0) + value
            else:
                exposed[key] = value
    lines = [
        f"  completed {sum(r['status'] == 'completed' for r in runs)}/{len(runs)}; yaw models accepted "
        f"{sum(a['accepted'] for a in yaw)}/{len(yaw)} tried",
        f"  a22 error {_range([m['a22_error_pct'] for m in models if m['a22_error_pct'] is not None])} %, "
        f"b2 error {_range([m['b2_error_pct'] for m in models if m['b2_error_pct'] is not None])} %, "
        f"validation R² min {min((m['r2'] for m in models), default=float('nan')):.3f}",
        f"  gains written {len(written)}/{len(runs)}" + (f", HDG_P {min(hdg_p):.3f}…{max(hdg_p):.3f}" if hdg_p else ""),
        f"  ATTITUDE to the companion: {att_late} of {att_delivered} delivered out of vehicle-time order "
        f"({_percent(att_late, att_delivered)}; per run {', '.join(per_run_late)}), {att_lost} lost "
        f"({_percent(att_lost, att_delivered + att_lost)}); to the vehicle: "
        f"{sum(u.get('lost', 0) for u in up)} datagrams lost, {sum(u.get('out_of_order', 0) for u in up)} out of order",
        f"  the companion reports: {json.dumps(exposed) if exposed else 'nothing'}",
        f"  restores confirmed by state {sum(r['restored_by_state'] for r in runs)}/{len(runs)}, claimed by the "
        f"companion {sum(r['restore_claimed'] for r in runs)}/{len(runs)}",
    ]
    for r in runs:
        if r["status"] != "completed" or r["crash"] or r["state_problems"]:
            lines.append(f"    seed {r['seed']}: {r['status']} ({r['reason'] or r['crash'] or ''})"
                         + (f"; state: {'; '.join(r['state_problems'])}" if r["state_problems"] else ""))
    return lines


def matrix(args) -> int:
    conditions = [c for c in args.conditions.split(",") if c]
    unknown = set(conditions) - set(CONDITIONS)
    if unknown:
        raise SystemExit(f"--conditions: unknown {sorted(unknown)} (known: {', '.join(CONDITIONS)})")
    speedups = [float(s) for s in args.speedups.split(",") if s]
    jobs = [(c, seed, s) for s in speedups for c in conditions for seed in range(1, args.seeds + 1)]
    started = time.monotonic()
    results: list[dict] = []
    with ProcessPoolExecutor(max_workers=max(1, args.jobs)) as pool:
        futures = [pool.submit(one_run, c, seed, s, args.axes, args.thrusts, args.no_steps, args.vehicle_time)
                   for c, seed, s in jobs]
        for (condition, seed, speedup), future in zip(jobs, futures):
            result = future.result()
            results.append(result)
            models = ", ".join(f"{m['a22_error_pct']:+.1f}" for m in result["models"] if m["a22_error_pct"] is not None)
            print(f"[{len(results)}/{len(jobs)}] {condition} x{speedup:g} seed {seed}: {result['status']} "
                  f"({result['reason'] or result['crash'] or ''}) a22 % [{models}] {result['wall_s']:.0f} s",
                  file=sys.stderr, flush=True)
    print(f"identification campaign over UDP through the relay, STARFISH, seeds 1-{args.seeds}; delays in "
          f"{'vehicle time (divided by the speed-up)' if args.vehicle_time else 'wall time'}; "
          f"{time.monotonic() - started:.0f} s wall")
    for speedup in speedups:
        for condition in conditions:
            runs = [r for r in results if r["condition"] == condition and r["speedup"] == speedup]
            print(f"\n{condition} ({CONDITIONS[condition].describe()}), x{speedup:g}")
            print("\n".join(summarise(runs)))
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1, default=str))
    return 0


# ====================================================================== reproductions
def _last_thrust_before_restore(run: CampaignRun) -> int:
    """How many DO_CHANGE_SPEED frames the companion sent before its restore's (the last one sent)."""
    return max(0, len(run.thrust_sent) - 1)


def reproduce_late_setpoint(speedup: float, seed: int, workdir: Path) -> list[str]:
    """The last thrust set-point before the restore's made late: held until the restore's has passed,
    on a lockstep simulator (the companion's traffic is then a function of the seed, so the set-point
    to hold is found by a clean run first), and 80 ms late on a paced one (as first found: overtaken
    only if the restore's follows within 80 ms, which depends on the machine's load)."""
    from harness.fault_cases import Case, campaign_config as short_campaign, run_case

    lines = [f"late set-point, seed {seed}:"]
    sim = start_sim(transport="udp", speedup=LOCKSTEP_SPEEDUP, seed=seed, lockstep=True)
    try:
        count = run_case(sim, Case("campaign/count", "campaign", (), (), seed=seed), workdir / f"count-{seed}.sqlite")
        nth = max(1, len(count.thrust_sent) - 1)
        trigger = Trigger("COMMAND_LONG", nth, command=DO_CHANGE_SPEED)
        fault = overtaken(trigger, Trigger("COMMAND_LONG", command=DO_CHANGE_SPEED), messages=("COMMAND_LONG",))
        late = run_case(sim, Case("campaign/late-setpoint", "campaign", (fault,), (), seed=seed),
                        workdir / f"late-{seed}.sqlite")
    finally:
        sim.stop()
    found, held = late.before.get("thrust"), late.after.get("thrust")
    thrust_problems = [p for p in late.state_problems if p.startswith("thrust")]
    said_so = any("thrust" in p for p in late.restore_problems)
    lines += [f"  lockstep x{LOCKSTEP_SPEEDUP:g}, DO_CHANGE_SPEED number {nth} held until the restore's has passed: "
              f"{'PASS' if not thrust_problems or said_so else 'FAIL'}",
              f"    the companion sent thrust {late.thrust_sent[-3:]} %, the vehicle received {late.thrust_delivered[-3:]} %"
              f" (the clean run: {count.status}, {len(count.thrust_sent)} sent)",
              f"    the vehicle holds thrust {held:.2f} (found {found:.2f}); the companion: {late.status} "
              f"({late.reason or ''}), restore_problems {late.restore_problems}; by state: "
              f"{'; '.join(late.state_problems) or 'as found'}"]
    clean = LinkConditions()
    sim = start_sim(transport="udp", speedup=speedup, seed=seed, lockstep=False)
    try:
        first = run_campaign_through_relay(sim, "count", clean, seed, short_campaign(), workdir)
    finally:
        sim.stop()
    nth = _last_thrust_before_restore(first)
    gap = (first.thrust_sent[-1][0] - first.thrust_sent[-2][0]) * 1000 if len(first.thrust_sent) > 1 else float("nan")
    fault = timed_delay(Trigger("COMMAND_LONG", nth, command=DO_CHANGE_SPEED), LATE_SETPOINT_S,
                        messages=("COMMAND_LONG",))
    sim = start_sim(transport="udp", speedup=speedup, seed=seed, lockstep=False)
    try:
        run = run_campaign_through_relay(sim, "late set-point", clean, seed, short_campaign(), workdir, faults=[fault])
    finally:
        sim.stop()
    found, held = run.before.get("thrust"), run.after.get("thrust")
    said_so = any("thrust" in p for p in run.restore_problems)
    ok = (held is not None and found is not None and abs(held - found) <= 0.011) or said_so
    lines += [f"  paced x{speedup:g}, DO_CHANGE_SPEED number {nth} (in a clean run the last before the restore's, "
              f"{gap:.1f} ms before it) {LATE_SETPOINT_S * 1000:g} ms late: {'PASS' if ok else 'FAIL'}",
              f"    the companion sent thrust {[p for _, p in run.thrust_sent[-3:]]} %, the vehicle received "
              f"{[p for _, p in run.thrust_delivered[-3:]]} %",
              f"    the vehicle holds thrust {held:.2f} (found {found:.2f}); the companion: {run.status} "
              f"({run.reason or ''}), restore_problems {run.restore_problems}; by state: "
              f"{'; '.join(run.state_problems) or 'as found'}"]
    return lines


def _gcs_changes_heading_gain(relay, sim, report: dict, stop: threading.Event) -> None:
    """At the campaign's first RC override, a ground station sets HDG_P straight on the simulator."""
    from harness.mavlink_clients import connect_client

    deadline = time.monotonic() + WAIT_GCS_S
    while relay.count("RC_CHANNELS_OVERRIDE") < 1:
        if stop.is_set() or time.monotonic() > deadline:
            report["sent"] = False
            return
        time.sleep(0.02)
    conn = connect_client(sim.endpoint, source_system=GCS_SYSTEM)
    try:
        mav = conn.mav
        report["vehicle_time_ms"] = relay.vehicle_time_ms
        for _ in range(3):  # bounded: three tries, 2 s each
            mav.param_set_send(1, 1, b"HDG_P", GCS_HDG_P, 9)  # MAV_PARAM_TYPE_REAL32
            answer = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=2.0)
            while answer is not None and answer.param_id != "HDG_P":
                answer = conn.recv_match(type="PARAM_VALUE", blocking=True, timeout=2.0)
            if answer is not None:
                report["confirmed"] = answer.param_value
                break
        report["sent"] = True
    finally:
        conn.close()


def reproduce_foreign_change(speedup: float, seed: int, workdir: Path) -> list[str]:
    from harness.fault_cases import campaign_config as short_campaign

    sim = start_sim(transport="udp", speedup=speedup, seed=seed, lockstep=False)
    try:
        run = run_campaign_through_relay(sim, "ground station", LinkConditions(), seed, short_campaign(), workdir,
                                         during=_gcs_changes_heading_gain)
    finally:
        sim.stop()
    held = run.after.get("params", {}).get("HDG_P")
    told = " ".join([run.reason or "", *run.restore_problems])
    reported = "HDG_P" in told or "someone else" in told or "heading_p" in told
    kept = held is not None and abs(held - GCS_HDG_P) < 1e-4
    return [f"ground station sets HDG_P {GCS_HDG_P} at the first doublet, x{speedup:g} seed {seed}: "
            f"{'PASS' if kept or reported else 'FAIL'}",
            f"  the ground station's write: {run.during}",
            f"  the vehicle holds HDG_P {held} after (found {run.before.get('params', {}).get('HDG_P')}; the campaign "
            f"wrote {run.final_gains.get('HDG_P')})",
            f"  the companion: {run.status} ({run.reason}), restore_problems {run.restore_problems}"]


def reproduce(args) -> int:
    speedup = float(args.speedups.split(",")[0])
    with tempfile.TemporaryDirectory(prefix="bench-link-repro-") as workdir:
        for seed in range(1, args.seeds + 1):
            print("\n".join(reproduce_late_setpoint(speedup, seed, Path(workdir))), flush=True)
            print("\n".join(reproduce_foreign_change(speedup, seed, Path(workdir))), flush=True)
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--conditions", default=",".join(CONDITIONS))
    parser.add_argument("--seeds", type=int, default=3)
    parser.add_argument("--speedups", default="5,20")
    parser.add_argument("--vehicle-time", action="store_true",
                        help="delays are the vehicle's: divided by the speed-up (module docstring)")
    parser.add_argument("--axes", help="e.g. yaw (default: the quick procedure's yaw,pitch)")
    parser.add_argument("--thrusts", help="e.g. 0.6,0.8,1.0 (default: the quick procedure's five)")
    parser.add_argument("--no-steps", action="store_true", help="no heading-step checks (then no gain is written)")
    parser.add_argument("--jobs", type=int, default=1, help="runs at once, each a process (default: %(default)s)")
    parser.add_argument("--json", metavar="FILE", help="also write every run's figures to FILE")
    parser.add_argument("--reproduce", action="store_true", help="the two reproductions instead of the matrix")
    parser.add_argument("-v", "--verbose", action="store_true")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO if args.verbose else logging.CRITICAL, stream=sys.stderr,
                        format="%(relativeCreated)8.0f %(name)s %(levelname)s %(message)s")
    try:
        return reproduce(args) if args.reproduce else matrix(args)
    except SimulatorError as exc:
        print(f"simulator did not start: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
