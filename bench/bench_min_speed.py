"""Minimum-speed seeking figures (SPEC C7; thesis Fig. 5.22, 5.25, 5.26, Table 5.2) on the in-process
simulator (physics + autopilot, no MAVLink). Prints final TR/speed vs the analytic TR*/Vmin, settle
time, depth errors and thrust reversals (limit-cycle indicator) for: the seeking period Ts study,
a fin-budget δFB sweep, and δmax 0.26 / 0.35 / 0.40 (ELEV_MAX and the seeker's δmax together);
these rows are the thesis law (``hold_after_change_s = 0``, θe crossover 0.01).

``--hold``: the thesis law against the hold after every change (SeekerConfig.hold_after_change_s,
the default), both at the thesis' θe crossover 0.01, and the product's rules (the hold and the
crossover raised for the autopilot's pitch loop, eq. M.1: "hold 4 s, M.1") at Ts = 1 s and 0.5 s,
seeds 1-6, on two harnesses: the closed loop of
harness.inprocess.ClosedLoop and the product procedure (companion.procedures.min_speed.min_speed_procedure
over harness.inprocess.InProcessLink, 100 s settling at 0.70 first). Per seed: final TR after 200 s,
settle time, max |depth error| after 5 s, reversals in the last 30 s; and in a separate 300 s run
whose thrust set-point is kicked to 0.60 at 150 s, the re-convergence time (from the kick to the
last change before 15 s without one) and the TR at 300 s. No asserts.

``--predicted``: in one run, per seed 1-6 and as a summary beside the goal, the procedure from
TR 0.70 (the thesis' start), the 0.005/s ramp to the analytic TR* + 0.04, the governed move to
TR* + 0.008 (MinSpeedProcedureConfig.governed()) and the levelled move there
(MinSpeedProcedureConfig.levelled(), the default: the level-flight pitch fed forward through the depth
set-point), all with the product's seeker (the hold and the θe crossover for the pitch loop, eq. M.1):
settle time, final TR and its % over TR*, max |depth error|, reversals in the last 30 s,
re-convergence after a kick to 0.60, and the levelled move's largest depth set-point offset.

``--cause``: what bounds the settle time once the depth integrator no longer does (the levelled
move), at the thesis' θe crossover 0.01 unless said, per seed 1-6: (1) the thrust held at TR* + 0.008 after the levelled move with no seeking
move (a hold longer than the run), and the first time from which the seeker's own decisions on the
recorded inputs would have kept for 15 s, at 0.01 and at the crossover for the pitch loop (eq. M.1);
(2) diagnostics that change what the product may not: the
simulated autopilot's pitch integral PIT_I 5x (the levelled and the governed move) and the seeker's
θe crossover at 0.02 (SPEC C7's value at sea; the levelled move and the start from 0.70), each
also kicked to 0.60 at 150 s (re-convergence and the TR at 300 s).

    python bench/bench_min_speed.py
    python bench/bench_min_speed.py --hold
    python bench/bench_min_speed.py --predicted
    python bench/bench_min_speed.py --cause
"""
from __future__ import annotations

import argparse
import time
from dataclasses import replace
from unittest import mock

from behaviors.min_speed import MinSpeedConfig, MinSpeedSeeking
from behaviors.min_speed_result import MinSpeedResult
from companion.procedures import min_speed as procedure
from companion.interface import SetThrust
from companion.numerics.fuzzy_seeker import KEEP, SeekerConfig, decide
from companion.numerics.minspeed import DivePlaneVehicle, minimum_speed
from harness.inprocess import ClosedLoop, InProcessLink

SEEDS = (1, 2, 3)


def seek(seed: int, seconds: float = 200.0, elev_max: float = 0.26, noise_scale: float = 1.0,
         **seeker) -> tuple[MinSpeedResult, tuple[float, float]]:
    """The seeker's result, and the range of its thrust set-point over the last 60 s."""
    seeker.setdefault("hold_after_change_s", 0.0)  # the thesis law unless asked
    loop = ClosedLoop(seed=seed, depth=2.0, params={"ELEV_MAX": elev_max})
    # bench-only: scale the simulated sensor noise (the seed's Simulink run was noise-free, §5.4)
    loop.vehicle._noise_sigma = loop.vehicle._noise_sigma * noise_scale
    loop.advance(100.0)
    config = MinSpeedConfig(seeker=SeekerConfig(delta_max=elev_max, **seeker), depth_setpoint=2.0,
                            depth_p=loop.param("DPT_P"), depth_i=loop.param("DPT_I"), pitch_max=loop.param("PIT_MAX"),
                            pitch_p=None)  # the thesis' θe crossover as configured (0.01)
    behaviour = MinSpeedSeeking(config)
    loop.run(behaviour, seconds)
    result = behaviour.result()
    tail = [tr for t, tr in zip(result.series["time"], result.series["thrust_setpoint"]) if t >= seconds - 60.0]
    return result, (min(tail), max(tail))


def line(label: str, results: list[tuple[MinSpeedResult, tuple[float, float]]], analytic) -> str:
    cells = []
    for r, (low, high) in results:
        settle = "—" if r.settle_time_s is None else f"{r.settle_time_s:.0f}s"
        settled_err = "—" if r.max_depth_error_settled_m is None else f"{r.max_depth_error_settled_m:.2f}"
        cells.append(f"TR {r.thrust_ratio_final:.2f} [{low:.2f}–{high:.2f}] "
                     f"V {r.speed_final:.3f} settle {settle} dz {r.max_depth_error_m:.2f}/{settled_err} rev {r.reversals_last_30s}")
    return f"{label:<18} (TR* {analytic.thrust_ratio_star:.3f}, Vmin {analytic.v_min:.3f}): " + " | ".join(cells)


# ------------------------------------------------------------------ --hold: thesis law vs hold after change
HOLD_SEEDS = (1, 2, 3, 4, 5, 6)
KICK_AT_S, KICK_TO, KICK_RUN_S = 150.0, 0.60, 300.0


class KickedSeeker(MinSpeedSeeking):
    """Bench-only: the seeker whose set-point is kicked to ``KICK_TO`` at ``kick_at_s`` (a disturbance)."""

    kick_at_s: float | None = None

    def update(self, telemetry):  # the hook every caller reaches (the procedure ticks, not steps)
        commands = list(super().update(telemetry))
        if (self.kick_at_s is not None and self._start is not None and not getattr(self, "kicked_at", None)
                and telemetry.time_s - self._start >= self.kick_at_s):
            self.kicked_at = telemetry.time_s - self._start
            self.thrust_ratio = KICK_TO
            commands.append(SetThrust(KICK_TO))
        return commands


def reconvergence(behaviour: KickedSeeker, end_s: float, window_s: float = 15.0) -> float | None:
    """From the kick to the last set-point change before the first ``window_s`` without one."""
    changes = [behaviour.kicked_at]
    previous = KICK_TO
    for time_s, _decision, thrust in behaviour.decisions:
        if time_s >= behaviour.kicked_at and thrust != previous:
            changes.append(time_s)
            previous = thrust
    for i, change in enumerate(changes):
        following = changes[i + 1] if i + 1 < len(changes) else end_s
        if following - change >= window_s - 1e-9:
            return change - behaviour.kicked_at
    return None


def hold_run(harness: str, seed: int, period: float, hold: float, seconds: float, kick: bool,
             thesis_crossover: bool = True) -> KickedSeeker:
    seeker = SeekerConfig(period_s=period, hold_after_change_s=hold)

    def make(config: MinSpeedConfig) -> KickedSeeker:
        behaviour = KickedSeeker(config)
        behaviour.kick_at_s = KICK_AT_S if kick else None
        made.append(behaviour)
        return behaviour

    made: list[KickedSeeker] = []
    if harness == "loop":
        loop = ClosedLoop(seed=seed, depth=2.0)
        loop.advance(100.0)
        loop.run(make(MinSpeedConfig(seeker=seeker, depth_setpoint=2.0, depth_p=loop.param("DPT_P"),
                                     depth_i=loop.param("DPT_I"), pitch_max=loop.param("PIT_MAX"),
                                     pitch_p=None if thesis_crossover else loop.param("PIT_P"))), seconds)
    else:  # the product procedure; only the seeker's configuration and the kick are the bench's
        def product(config: MinSpeedConfig) -> KickedSeeker:
            seeker_config = replace(config.seeker, hold_after_change_s=hold)
            return make(replace(config, seeker=seeker_config, pitch_p=None if thesis_crossover else config.pitch_p))

        with mock.patch.object(procedure, "MinSpeedSeeking", product):
            result = procedure.min_speed_procedure(
                InProcessLink(seed=seed), lambda: None,
                procedure.MinSpeedProcedureConfig(duration_s=seconds, period_s=period)).to_json()
        assert result["status"] == "completed", result.get("abort_reason")
    return made[0]


def hold_table() -> None:
    tr_star = minimum_speed(DivePlaneVehicle()).thrust_ratio_star
    print(f"TR* {tr_star:.3f} analytic (≈ 0.437 in the simulator); per seed {HOLD_SEEDS}: final TR at 200 s | "
          f"settle s | max |dz| m | reversals last 30 s || kick to {KICK_TO} at {KICK_AT_S:.0f} s: "
          f"re-convergence s | TR at {KICK_RUN_S:.0f} s")
    for period in (1.0, 0.5):
        for harness in ("loop", "procedure"):
            for hold, thesis_crossover in ((0.0, True), (4.0, True), (4.0, False)):
                plain = [hold_run(harness, s, period, hold, 200.0, False, thesis_crossover) for s in HOLD_SEEDS]
                kicked = [hold_run(harness, s, period, hold, KICK_RUN_S, True, thesis_crossover) for s in HOLD_SEEDS]
                results = [b.result() for b in plain]
                label = ("thesis law" if hold == 0.0 else f"hold {hold:.0f} s"
                         if thesis_crossover else f"hold {hold:.0f} s, M.1")
                finals = " ".join(f"{r.thrust_ratio_final:.2f}" for r in results)
                settles = " ".join(_seconds(r.settle_time_s) for r in results)
                depths = " ".join(f"{r.max_depth_error_m:.2f}" for r in results)
                reversals = " ".join(str(r.reversals_last_30s) for r in results)
                reconverged = " ".join(_seconds(reconvergence(b, KICK_RUN_S)) for b in kicked)
                after_kick = " ".join(f"{b.thrust_ratio:.2f}" for b in kicked)
                print(f"Ts {period} {harness:<9} {label:<10}: TR {finals} | settle {settles} | dz {depths} | "
                      f"rev {reversals} || reconv {reconverged} | TR {after_kick}")


FROM_070 = ("from TR 0.70 (thesis)", procedure.MinSpeedProcedureConfig())
RAMP = ("ramp to TR*+0.04", procedure.MinSpeedProcedureConfig(start_margin=0.04))
GOVERNED = ("governed TR*+0.008", procedure.MinSpeedProcedureConfig.governed())
LEVELLED = ("levelled TR*+0.008", procedure.MinSpeedProcedureConfig.levelled())


def predicted_run(seed: int, config: procedure.MinSpeedProcedureConfig, seconds: float, kick: bool, *,
                  params: dict[str, float] | None = None, seeker: dict | None = None,
                  thesis_crossover: bool = False) -> KickedSeeker:
    """The product procedure (100 s at 0.70 first, then ``seconds`` of seeking) with ``config``;
    ``params`` (native names) are set on the simulated autopilot first and ``seeker`` replaces fields
    of the seeker's configuration (diagnostics only, ``--cause``)."""
    made: list[KickedSeeker] = []

    def product(seeker_config: MinSpeedConfig) -> KickedSeeker:
        if seeker:
            seeker_config = replace(seeker_config, seeker=replace(seeker_config.seeker, **seeker))
        if thesis_crossover:  # θe_TS as configured (0.01), not raised for the pitch loop (eq. M.1)
            seeker_config = replace(seeker_config, pitch_p=None)
        behaviour = KickedSeeker(seeker_config)
        behaviour.kick_at_s = KICK_AT_S if kick else None
        made.append(behaviour)
        return behaviour

    link = InProcessLink(seed=seed)
    for name, value in (params or {}).items():
        link.set_param(name, value)
    with mock.patch.object(procedure, "MinSpeedSeeking", product):
        result = procedure.min_speed_procedure(
            link, lambda: None, replace(config, duration_s=seconds),
            analytic=procedure.analytic_minimum_speed("starfish")).to_json()
    assert result["status"] == "completed", result.get("abort_reason")
    return made[0]


def predicted_table() -> None:
    """The starts side by side (module docstring), per seed and as a summary."""
    tr_star = procedure.analytic_minimum_speed("starfish")["thrust_ratio_star"]
    goal = "≤ 60 s | ≤ +2.0 % | ≤ 0.30 m | ≤ 1 | re-converges"
    print(f"analytic TR* {tr_star:.4f} (+2 % = {1.02 * tr_star:.4f}); product procedure over InProcessLink, 100 s at "
          f"0.70 first; 200 s runs, and 300 s runs kicked to {KICK_TO} at {KICK_AT_S:.0f} s")
    print("columns: settle s (last set-point change before 15 s without one, from the start of seeking, the move "
          "included) | final TR (% over TR*) | max |depth error| m after 5 s | reversals in the last 30 s | "
          "re-convergence s after the kick and the TR at the end of that run")
    summaries = []
    for label, config in (FROM_070, RAMP, GOVERNED, LEVELLED):
        results = [predicted_run(s, config, 200.0, False).result() for s in HOLD_SEEDS]
        kicked = [predicted_run(s, config, KICK_RUN_S, True) for s in HOLD_SEEDS]
        reconverged = [reconvergence(b, KICK_RUN_S) for b in kicked]
        for seed, r, reconv, k in zip(HOLD_SEEDS, results, reconverged, kicked):
            over = 100 * (r.thrust_ratio_final / tr_star - 1)
            offset = f" | depth offset ≤ {r.depth_offset_max_m:.2f} m" if r.depth_offset_max_m else ""
            print(f"{label:<24} seed {seed}: settle {_seconds(r.settle_time_s):>4} | TR {r.thrust_ratio_final:.4f} "
                  f"({over:+.1f} %) | dz {r.max_depth_error_m:.3f} | rev {r.reversals_last_30s} | "
                  f"reconv {_seconds(reconv)}, TR {k.thrust_ratio:.2f} at {KICK_RUN_S:.0f} s{offset}")
        summaries.append((label, results, reconverged))
    print(f"{'summary':<24} {'settle s':<14} {'final TR (% TR*)':<26} {'max dz m':<12} {'reversals':<10} "
          f"{'reconv s':<12} | goal: {goal}")
    for label, results, reconverged in summaries:
        settles = [r.settle_time_s for r in results]
        finals = [r.thrust_ratio_final for r in results]
        depths = [r.max_depth_error_m for r in results]
        met = sum(1 for r in results if r.settle_time_s is not None and r.settle_time_s <= 60.0
                  and r.thrust_ratio_final <= 1.02 * tr_star and r.max_depth_error_m <= 0.3
                  and r.reversals_last_30s <= 1)
        print(f"{label:<24} {_range(settles):<14} "
              f"{min(finals):.3f}-{max(finals):.3f} ({100 * (min(finals) / tr_star - 1):+.1f}..{100 * (max(finals) / tr_star - 1):+.1f} %)"
              f"{'':<3} {min(depths):.2f}-{max(depths):.2f}{'':<3} {max(r.reversals_last_30s for r in results):<10} "
              f"{_range(reconverged):<12} | all goals on {met}/{len(results)} seeds")


def first_quiet_keeps(behaviour: MinSpeedSeeking, window_s: float = 15.0) -> float | None:
    """The first time (s from the start) from which the seeker's decisions on its recorded, filtered
    inputs, taken every Ts without the hold, keep for ``window_s``: when the vehicle as it flew would
    have let the seeker settle."""
    series = behaviour.series
    config = behaviour.seeker_config
    decisions: list[tuple[float, int]] = []
    due = config.period_s
    for time_s, theta_e, delta in zip(series["time"], series["pitch_error_filtered"], series["elevator_filtered"]):
        if time_s >= due and theta_e == theta_e and delta == delta:
            due += config.period_s
            decisions.append((time_s, decide(theta_e, delta, config)))
    end = decisions[-1][0] if decisions else 0.0
    for start, _ in decisions:
        if start + window_s > end:
            return None
        if all(d == KEEP for t, d in decisions if start <= t < start + window_s):
            return start
    return None


def cause_table() -> None:
    """What bounds the levelled move's settle time (module docstring), per seed and as a range."""
    held = {"hold_after_change_s": 1e6}  # after the move, every seeking move is held: the thrust stays
    print("per seed 1-6, product procedure over InProcessLink, 100 s at 0.70 first, 200 s of seeking")
    for thesis, label in ((True, "θe_TS 0.01"), (False, "θe_TS for the pitch loop (eq. M.1)")):
        runs = [predicted_run(s, LEVELLED[1], 200.0, False, seeker=held, thesis_crossover=thesis) for s in HOLD_SEEDS]
        quiet = [first_quiet_keeps(b) for b in runs]
        print(f"levelled move, then TR held at TR*+0.008, {label}: the seeker's decisions would keep for 15 s "
              f"from {_join(quiet, _seconds)} s (range {_range(quiet)}); max dz "
              f"{_join([b.max_depth_error() for b in runs], '{:.2f}'.format)} m")
    diagnostics = (("PIT_I x5, levelled", LEVELLED[1], {"PIT_I": 5 * -0.1}, None),
                   ("PIT_I x5, governed", GOVERNED[1], {"PIT_I": 5 * -0.1}, None),
                   ("θe_TS 0.02, levelled", LEVELLED[1], None, {"theta_e_threshold": 0.02}),
                   ("θe_TS 0.02, from 0.70", FROM_070[1], None, {"theta_e_threshold": 0.02}))
    for label, config, params, seeker in diagnostics:
        results = [predicted_run(s, config, 200.0, False, params=params, seeker=seeker,
                                 thesis_crossover=True).result() for s in HOLD_SEEDS]
        kicked = [predicted_run(s, config, KICK_RUN_S, True, params=params, seeker=seeker, thesis_crossover=True)
                  for s in HOLD_SEEDS]
        print(f"{label:<22}: settle {_join([r.settle_time_s for r in results], _seconds)} s | final TR "
              f"{_join([r.thrust_ratio_final for r in results], '{:.2f}'.format)} | dz "
              f"{_join([r.max_depth_error_m for r in results], '{:.2f}'.format)} m | rev "
              f"{_join([r.reversals_last_30s for r in results], str)} || kicked: reconv "
              f"{_join([reconvergence(k, KICK_RUN_S) for k in kicked], _seconds)} s, TR at {KICK_RUN_S:.0f} s "
              f"{_join([k.thrust_ratio for k in kicked], '{:.2f}'.format)}")


def _join(values: list, form) -> str:
    return " ".join(form(v) for v in values)


def _range(values: list[float | None]) -> str:
    known = [v for v in values if v is not None]
    text = f"{min(known):.0f}-{max(known):.0f}" if known else "—"
    missing = len(values) - len(known)
    return text + (f" ({missing} never)" if missing else "")


def _seconds(value: float | None) -> str:
    return "—" if value is None else f"{value:.0f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hold", action="store_true", help="the thesis law against the hold after every change")
    parser.add_argument("--predicted", action="store_true",
                        help="the starts side by side: from TR 0.70, the ramp to TR* + 0.04, the governed and "
                             "the levelled move to TR* + 0.008, per seed and summary")
    parser.add_argument("--cause", action="store_true",
                        help="what bounds the levelled move's settle time: the thrust held after it, and "
                             "diagnostics with a faster pitch integral or the seeker's θe crossover at 0.02")
    args = parser.parse_args()
    if args.cause:
        start = time.time()
        cause_table()
        print(f"wall time {time.time() - start:.1f} s")
        return
    if args.predicted:
        start = time.time()
        predicted_table()
        print(f"wall time {time.time() - start:.1f} s")
        return
    if args.hold:
        start = time.time()
        hold_table()
        print(f"wall time {time.time() - start:.1f} s")
        return
    start = time.time()
    base = minimum_speed(DivePlaneVehicle())
    print("columns per seed: final TR [range over the last 60 s], mean speed of the last 10 s, settle time, "
          "max |depth error| after 5 s / after settling (m), thrust reversals in the last 30 s")
    for period in (0.5, 1.0, 2.0, 2.5, 3.0):
        print(line(f"Ts {period} s", [seek(s, period_s=period) for s in SEEDS], base))
    for period in (0.5, 1.0, 2.5):  # noise-free, as the seed's simulation: the seeds then coincide
        print(line(f"Ts {period} s no noise", [seek(1, period_s=period, noise_scale=0.0)], base))
    print(line("Ts 1 s noise x0.1", [seek(s, period_s=1.0, noise_scale=0.1) for s in SEEDS], base))
    for budget in (0.02, 0.05, 0.08):
        print(line(f"Ts 1 δFB {budget}", [seek(s, period_s=1.0, fin_budget=budget) for s in SEEDS], base))
    for delta_max in (0.26, 0.35, 0.40):
        analytic = minimum_speed(DivePlaneVehicle(), delta_max)
        print(line(f"Ts 1 δmax {delta_max}", [seek(s, period_s=1.0, elev_max=delta_max) for s in SEEDS], analytic))
    for budget in (0.02, 0.05, 0.08, 0.12):
        print(line(f"Ts 2.5 δFB {budget}", [seek(s, period_s=2.5, fin_budget=budget) for s in SEEDS], base))
    for delta_max in (0.26, 0.35, 0.40):
        analytic = minimum_speed(DivePlaneVehicle(), delta_max)
        print(line(f"Ts 2.5 δmax {delta_max}", [seek(s, period_s=2.5, elev_max=delta_max) for s in SEEDS], analytic))
    print(f"wall time {time.time() - start:.1f} s")


if __name__ == "__main__":
    main()
