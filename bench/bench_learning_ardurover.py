"""Tuning during an ordinary survey on the real ArduRover firmware: ``companion run --learn`` beside
ArduPilot SITL flying a lawnmower in AUTO, against the same survey flown on the frame's gains alone.

ArduPilot SITL (built by you; its bin folder in ``ARDUPILOT_SITL_BIN`` or ``--ardupilot-bin``) flies
our physics through the JSON backend, on loopback: run it inside a private network namespace
(``unshare -n``, then ``ip link set lo up``). Per hull and repeat, two runs:

* **learning**: ``companion run --learn`` on SITL's serial0, while a ground station of its own
  (:class:`harness.rover_mission.MissionGroundStation`, SITL's serial1) uploads the survey with the
  MAVLink mission protocol (8 lanes of 120 m, 20 m apart, WP_SPEED 2), arms and switches to AUTO;
* **baseline**: the same, with ``companion run`` only watching.

Figures: vehicle time from the mission's start (AUTO) to the design's write and to the verdict,
the verdict and its figures, reverts, whether the mission ever left AUTO, the mission's time, and
for each lane (its middle half) flown after the write: cross-track RMS and turn-rate error RMS
(PID_TUNING, the ground station asks for it with GCS_PID_MASK) against the same lane in the
baseline. Never pass/fail.

    python bench/bench_learning_ardurover.py --hulls boat,boat-3dof --repeats 3

``--hulls motorboat`` (or ``motorboat-skid``): SITL's own boat as it ships (``rover.parm`` +
``motorboat.parm``; :class:`harness.own_sitl.OwnSitl`), physics this project did not write, the same
survey at WP_SPEED 2. The seed only numbers the repeat.

    python bench/bench_learning_ardurover.py --hulls motorboat --repeats 3
    python bench/bench_learning_ardurover.py --hulls motorboat --repeats 3 --set ATC_STR_RAT_FF=0.3 --set ATC_STR_RAT_I=0.02

``--autopilot ardusub``: ArduSub SITL flying its own vectored ROV as it ships (``sub.parm``;
:class:`harness.own_sitl.OwnSitl`: our AUV physics cannot fly ArduSub's AUTO), the same survey
5 m deep at ArduSub's WPNAV_SPEED (1 m/s), the yaw rate loop's PID_TUNING (GCS_PID_MASK 4) and the
cross-track measured from the positions against each lane's line (ArduSub sends none). The seed
only numbers the repeat (SITL's own vehicle has no seed).

    python bench/bench_learning_ardurover.py --autopilot ardusub --repeats 3
"""
from __future__ import annotations

import argparse
import json
import math
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from companion.rehearsal.launcher import SimulatorProcess  # noqa: E402
from companion.records.store import Store  # noqa: E402
from harness.rover_mission import (ROVER, SPEED_MASK_BIT, SUB, MissionGroundStation, fly_survey_beside,  # noqa: E402
                                   lawnmower)
from harness.own_sitl import OWN_VEHICLES, OwnSitl  # noqa: E402

SITL_SERIAL1_OFFSET = 2  # SITL's serial1 (tcp:2) is its serial0 port + 2, MAVLink 2


def fly(hull: str, seed: int, learn: bool, speedup: float, bin_dir: str, folder: Path,
        settings: dict[str, float] | None = None) -> dict:
    tag = f"{hull}-{seed}-{'learn' if learn else 'base'}"
    own = OWN_VEHICLES.get(hull)
    sub = own is not None and own.binary == "ardusub"
    if own is not None:  # SITL's own vehicle (harness.own_sitl): its serial1 is the ground station's
        sim = OwnSitl(bin_dir, own, speedup, params=dict(settings or {}), workdir=folder / f"sitl-{tag}").start()
        sim.wait_listening()
        endpoint, station_endpoint = sim.endpoint, sim.station_endpoint
        vehicle = SUB if sub else ROVER
        # ArduRover: the steering loop's PID_TUNING and the speed loop's (eq. L.4), as learning asks for them
        params = ({"GCS_PID_MASK": float(vehicle.pid_mask)} if sub else
                  {"GCS_PID_MASK": float(vehicle.pid_mask | SPEED_MASK_BIT), "WP_SPEED": 2.0})
    else:
        sim = SimulatorProcess(preset=hull, speedup=speedup, seed=seed, lockstep=False, autopilot="ardurover",
                               ardupilot_bin=bin_dir, log_path=folder / f"sim-{tag}.log")
        sim.start()
        endpoint, station_endpoint = sim.endpoint, f"tcp:127.0.0.1:{sim.port + SITL_SERIAL1_OFFSET}"
        # the steering loop's PID_TUNING and the speed loop's (eq. L.4), as the learning session asks for them
        vehicle, params = ROVER, {"WP_SPEED": 2.0, "GCS_PID_MASK": float(ROVER.pid_mask | SPEED_MASK_BIT)}
    store = folder / f"store-{tag}.sqlite"
    command = [sys.executable, "-m", "companion", "-v", "run", "--connect", endpoint, "--no-health",
               "--store", str(store), "--max-vehicle-time", "3000" if sub else "1500"] + (
                   ["--learn"] if learn else ["--no-scheduling"])
    points = lawnmower()
    station = MissionGroundStation(station_endpoint, points, params, vehicle=vehicle)
    with open(folder / f"companion-{tag}.log", "w") as output:
        try:
            run = fly_survey_beside(command, station, 3000.0 / speedup, output=output)
        finally:
            sim.stop()
    track = station.track
    auto = vehicle.auto_mode
    auto_at = next((t for t, mode in track.modes if mode == auto), math.nan)
    out = {"hull": hull, "seed": seed, "learn": learn, "mission_s": station.done_at_s - auto_at, "auto_at_s": auto_at,
           "left_auto": any(mode != auto for t, mode in track.modes if t > auto_at),
           "legs": track.legs(points=points if sub else None), "corners": track.corners(),
           "companion_exit": run.returncode}
    with Store(store) as records:
        campaign = next((c for c in records.campaigns() if c["kind"] == "learning"), None)
        results = records.behavior_results(campaign["id"], "learning") if campaign else []
    if results:
        result = results[0]["result"]
        writes = result["writes"]
        design = next((w["time_s"] for w in writes if w["why"] == "design"), math.nan)
        verdict_at = result.get("verdict_at_s")
        out.update(phase=result["phase"], reason=result["reason"], design_s=design - auto_at,
                   verified_s=verdict_at - auto_at if verdict_at is not None else math.nan,
                   reverts=sum(1 for w in writes if w["why"] == "revert"), verdict=result["verdict"],
                   written=writes[0]["gains"] if writes else None, write_at=design,
                   original=campaign["config"].get("original") if campaign.get("config") else None)
        out.update(speed=_speed_figures(result.get("speed"), auto_at, campaign.get("config") or {}))
    return out


def _speed_figures(speed: dict | None, auto_at: float, config: dict) -> dict | None:
    """The speed loop's learning (eq. L.4) from the session's record: phase and reason, the write
    (vehicle s after AUTO), the gains written against the original, the fits and the verdict."""
    if not speed:
        return None
    design = next((w for w in speed["writes"] if w["why"] == "design"), None)
    verdict_at = speed.get("verdict_at_s")
    return {"phase": speed["phase"], "reason": speed["reason"], "fits": speed["fits"],
            "write_at": design["time_s"] if design else math.nan,
            "design_s": design["time_s"] - auto_at if design else math.nan,
            "verified_s": verdict_at - auto_at if verdict_at is not None else math.nan,
            "written": design["gains"] if design else None, "original": config.get("speed_original"),
            "reverts": sum(1 for w in speed["writes"] if w["why"] == "revert"), "verdict": speed["verdict"],
            "segments": speed["segments"]}


def _clean(value):
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _clean(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_clean(v) for v in value]
    return value


def compare(learned: dict, baseline: dict, what: str = "legs") -> list[dict]:
    """Lanes (``what="corners"``: lane-end corners) flown after the write, against the same ones (by
    waypoint) in the baseline."""
    base = {leg["waypoint"]: leg for leg in baseline.get(what, [])}
    return [{"waypoint": leg["waypoint"], "learned": leg, "baseline": base.get(leg["waypoint"])}
            for leg in learned.get(what, []) if leg["start_s"] >= learned.get("write_at", math.inf)]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--autopilot", choices=("ardurover", "ardusub"), default="ardurover",
                        help="ardusub: SITL's own vectored ROV (--hulls is then ignored)")
    parser.add_argument("--hulls", default=None,
                        help="ArduRover: our presets (default boat,boat-3dof) or SITL's own motorboat, motorboat-skid")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--speedup", type=float, default=10.0)
    parser.add_argument("--ardupilot-bin", default=os.environ.get("ARDUPILOT_SITL_BIN"))
    parser.add_argument("--json", metavar="FILE", default=None, help="also write every run to FILE")
    parser.add_argument("--keep", metavar="DIR", default=None,
                        help="keep each run's store and logs in DIR (default: a temporary folder, deleted)")
    parser.add_argument("--baseline", action=argparse.BooleanOptionalAction, default=True,
                        help="fly the baseline (the frame's gains alone) after each learning run (default: yes)")
    parser.add_argument("--set", action="append", default=[], metavar="NAME=VALUE",
                        help="SITL's own vehicles: a parameter among its defaults at boot (repeatable), e.g. a "
                             "boat tuned poorly: --set ATC_STR_RAT_FF=0.3")
    args = parser.parse_args()
    if not args.ardupilot_bin:
        parser.error("give --ardupilot-bin or set ARDUPILOT_SITL_BIN (ArduPilot's build/sitl/bin)")
    try:
        settings = {name.strip(): float(value) for name, _, value in (item.partition("=") for item in args.set)}
    except ValueError:
        parser.error(f"--set takes NAME=VALUE with a number, not {args.set}")
    if settings and args.autopilot == "ardurover" and not set((args.hulls or "").split(",")) <= set(OWN_VEHICLES):
        parser.error("--set applies to SITL's own vehicles only (--hulls motorboat,motorboat-skid)")
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench-learning-") as name:
        folder = Path(args.keep or name)
        folder.mkdir(parents=True, exist_ok=True)
        sub = args.autopilot == "ardusub"
        hulls = "sitl-rov" if sub else args.hulls or "boat,boat-3dof"
        for hull in hulls.split(","):
            for seed in range(1, args.repeats + 1):
                learned = fly(hull, seed, True, args.speedup, args.ardupilot_bin, folder, settings)
                baseline = (fly(hull, seed, False, args.speedup, args.ardupilot_bin, folder, settings) if args.baseline
                            else {**learned, "legs": [], "mission_s": math.nan, "left_auto": False})
                rows.append({"learned": learned, "baseline": baseline, "lanes": compare(learned, baseline),
                             "corners": compare(learned, baseline, "corners")})
                print(summary(rows[-1]), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(_clean(rows), indent=1, allow_nan=False))
    return 0


def summary(row: dict) -> str:
    lrn, base = row["learned"], row["baseline"]
    lanes = row["lanes"]

    def mean(values):
        values = [v for v in values if v is not None and math.isfinite(v)]
        return sum(values) / len(values) if values else math.nan

    xt_l = mean([lane["learned"]["cross_track_rms_m"] for lane in lanes])
    xt_b = mean([lane["baseline"]["cross_track_rms_m"] for lane in lanes if lane["baseline"]])
    tr_l = mean([lane["learned"]["turn_rate_error_rms_deg_s"] for lane in lanes])
    tr_b = mean([lane["baseline"]["turn_rate_error_rms_deg_s"] for lane in lanes if lane["baseline"]])
    corners = row.get("corners", [])
    tc_l = mean([c["learned"]["turn_rate_error_rms_deg_s"] for c in corners])
    tc_b = mean([c["baseline"]["turn_rate_error_rms_deg_s"] for c in corners if c["baseline"]])
    verdict = lrn.get("verdict") or {}
    original, written = lrn.get("original") or {}, lrn.get("written") or {}
    changed = ", ".join(f"{name} {original.get(name, math.nan):.3g}→{value:.3g}" for name, value in written.items()
                        if not math.isclose(value, original.get(name, math.nan), rel_tol=1e-3)) or "none"
    return (_speed_summary(row) + f"gains changed: {changed}\n" + f"{lrn['hull']:10} seed {lrn['seed']}: {lrn.get('phase', '-'):9} write {lrn.get('design_s', math.nan):6.1f} s "
            f"verified {lrn.get('verified_s', math.nan):6.1f} s after AUTO, reverts {lrn.get('reverts', 0)}, "
            f"left AUTO {lrn['left_auto']}/{base['left_auto']}; lanes after ({len(lanes)}): cross-track "
            f"{xt_l:.3f}/{xt_b:.3f} m ({xt_l / xt_b:.2f}), turn-rate error {tr_l:.2f}/{tr_b:.2f} deg/s "
            f"({tr_l / tr_b:.2f}); corners after ({len(corners)}): turn-rate error {tc_l:.2f}/{tc_b:.2f} deg/s "
            f"({tc_l / tc_b:.2f}); mission {lrn['mission_s']:.1f}/{base['mission_s']:.1f} s "
            f"({100 * (lrn['mission_s'] / base['mission_s'] - 1):+.1f} %); verdict: {verdict.get('reason', lrn.get('reason'))}")


def _speed_summary(row: dict) -> str:
    """The speed loop's figures (eq. L.4): when written and verified, which gains, the verdict, and the
    speed-tracking RMS on the legs flown after the write against the same legs of the baseline."""
    speed = row["learned"].get("speed")
    if not speed:
        return "speed loop: not learned\n"
    base = {leg["waypoint"]: leg for leg in row["baseline"]["legs"]}
    after = [(leg["speed_error_rms_m_s"], base[leg["waypoint"]]["speed_error_rms_m_s"])
             for leg in row["learned"]["legs"] if leg["start_s"] >= speed["write_at"] and leg["waypoint"] in base]
    finite = [(a, b) for a, b in after if math.isfinite(a) and math.isfinite(b)]
    learned = sum(a for a, _ in finite) / len(finite) if finite else math.nan
    baseline = sum(b for _, b in finite) / len(finite) if finite else math.nan
    original, written = speed.get("original") or {}, speed.get("written") or {}
    changed = ", ".join(f"{name} {original.get(name, math.nan):.3g}→{value:.3g}" for name, value in written.items()) \
        or "none"
    fit = speed["fits"][-1] if speed["fits"] else None
    fitted = (f"fit R² {fit['validation_r2']:.3f} held out ({fit['surge']})" if fit and fit["validation_r2"] is not None
              else "no fit")
    verdict = speed.get("verdict") or {}
    return (f"speed loop: {speed['phase']}, write {speed['design_s']:.1f} s verified {speed['verified_s']:.1f} s after "
            f"AUTO, reverts {speed['reverts']}; {fitted}; gains {changed}; legs after the write ({len(finite)}): "
            f"speed error {learned:.3f}/{baseline:.3f} m/s ({learned / baseline if baseline else math.nan:.2f}); "
            f"verdict: {verdict.get('reason', speed['reason'])}\n")


if __name__ == "__main__":
    sys.exit(main())
