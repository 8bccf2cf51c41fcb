"""Accuracy of the steady-state LS (SPEC C8) over seeds, currents 1–20 mm/s in varied directions.

Two sources: (1) the synthetic kinematic vehicle of ``harness/datasets.py`` (position noise
0.2 m, DVL-like velocity noise 5 mm/s, transients in every turn) and (2) the simulator's ``hugin``
preset in-process, driven by the behaviours (sim sensor noise: position 0.07 m, velocity 0.01 m/s).
Prints the errors; no pass/fail.

    /tmp/venv/bin/python bench/bench_steady_state.py [--seeds N] [--sim-seeds M]
"""
from __future__ import annotations

import argparse
import math
import time

import numpy as np

from behaviors.steady_state import SquareConfig, SquarePattern, SteadyTurns, TurnConfig
from companion.numerics.steady_state import (
    fit_steady_turn,
    fit_straight_legs,
    steady_straight_mask,
    steady_turn_mask,
)
from harness.datasets import angle_error_deg, current_vector, synth_square, synth_turn
from harness.inprocess import HuginLoop


def summary(name: str, values) -> str:
    v = np.asarray(values, float)
    return f"{name}: mean {v.mean():.4g}, rms {math.sqrt(np.mean(v ** 2)):.4g}, max {np.abs(v).max():.4g}"


def synthetic(seeds: int) -> None:
    rng = np.random.default_rng(2024)
    cur_err, dir_err, surge_err, cond = [], [], [], []
    t_err, r_err, rate_err, resid = [], [], [], []
    start = time.perf_counter()
    for seed in range(seeds):
        speed, direction = rng.uniform(0.001, 0.020), rng.uniform(0, 360)
        cur = current_vector(speed, direction)
        d = synth_square(cur, seed)
        mask = steady_straight_mask(d["t"], d["yaw"], d["vel_body"])
        fit = fit_straight_legs(d["roll"][mask], d["pitch"][mask], d["yaw"][mask], d["vel_body"][mask])
        cur_err.append(1000 * np.hypot(*(fit.current - cur)))
        dir_err.append(angle_error_deg(fit.current_dir_deg, direction))
        surge_err.append(1000 * (fit.surge - 1.8))
        cond.append(fit.condition_number)
        rate = rng.choice([-1, 1]) * rng.uniform(4.5, 5.5)
        d = synth_turn(cur, 1000 + seed, rate_deg_s=rate, dt=1.0, pos_noise=0.1)
        mask = steady_turn_mask(d["t"], d["yaw"])
        tf = fit_steady_turn(d["t"][mask], d["north"][mask], d["east"][mask], d["yaw"][mask])
        t_err.append(1000 * np.hypot(*(tf.current - cur)))
        r_err.append(100 * (tf.radius / d["radius"] - 1))
        rate_err.append(100 * (math.degrees(tf.rate) / rate - 1))
        resid.append(tf.residual_std)
    elapsed = time.perf_counter() - start
    print(f"== synthetic ({seeds} seeds, currents 1–20 mm/s, random directions; {elapsed:.1f} s)")
    print("squares (velocity noise 5 mm/s, 150 s legs):")
    print("  " + summary("current vector error [mm/s]", cur_err))
    print("  " + summary("current direction error [deg]", dir_err))
    print("  " + summary("surge error [mm/s]", surge_err))
    print("  " + summary("condition number of H", cond))
    print("turns (position noise σ 0.10 m at 1 Hz, 240 s incl. spin-up):")
    print("  " + summary("current vector error [mm/s]", t_err))
    print("  " + summary("radius error [%]", r_err))
    print("  " + summary("turn-rate error [%]", rate_err))
    print("  " + summary("residual σ [m] (noise 0.10)", resid))


def simulator(seeds: int) -> None:
    rng = np.random.default_rng(7)
    rows = []
    start = time.perf_counter()
    for seed in range(seeds):
        speed, direction = rng.uniform(0.001, 0.020), rng.uniform(0, 360)
        cur = current_vector(speed, direction)
        loop = HuginLoop(cur, seed)
        square = SquarePattern(SquareConfig(thrust_ratio=0.7, leg_s=150.0))
        surge_truth = []
        # run the square while sampling the true water-relative surge on steady legs
        dt = 0.05
        steps = 0
        while not square.done and loop.vehicle.time_s < 700:
            loop.run(square, loop.vehicle.time_s + 1.0, dt)
            s = loop.vehicle.state
            if abs(s.yaw_rate) < math.radians(0.1):
                surge_truth.append(s.surge)
            steps += 1
        legs = square.result().fit
        assert legs is not None, square.result().error
        loop2 = HuginLoop(cur, 100 + seed)
        turns = SteadyTurns(TurnConfig(thrust_ratio=0.54, rudder_angles=(0.218,), turn_s=150.0, recover_s=5.0))
        radius_truth = []
        while not turns.done and loop2.vehicle.time_s < 300:
            loop2.run(turns, loop2.vehicle.time_s + 1.0, dt)
            s = loop2.vehicle.state
            if 100 < s.time_s < 150:
                radius_truth.append(math.hypot(s.surge * math.cos(s.pitch) + s.heave * math.sin(s.pitch), s.sway) / abs(s.yaw_rate))
        turn = turns.result().turns[0]
        assert turn.fit is not None, turn.error
        rows.append({
            "speed": speed, "dir": direction,
            "sq_cur": 1000 * math.hypot(legs.current[0] - cur[0], legs.current[1] - cur[1]),
            "sq_dir": angle_error_deg(legs.current_dir_deg, direction),
            "surge": 1000 * (legs.surge - np.median(surge_truth)),
            "cond": legs.condition_number,
            "tu_cur": 1000 * math.hypot(turn.fit.current[0] - cur[0], turn.fit.current[1] - cur[1]),
            "radius": 100 * (turn.fit.radius / np.median(radius_truth) - 1),
            "radius_m": turn.fit.radius,
            "rate": math.degrees(turn.fit.rate),
            "resid": turn.fit.residual_std,
        })
    elapsed = time.perf_counter() - start
    print(f"== simulator 'hugin' preset in-process ({seeds} seeds; {elapsed:.1f} s)")
    print("  speed[mm/s] dir[deg] | square: cur err[mm/s] dir err[deg] surge err[mm/s] cond | "
          "turn: cur err[mm/s] R[m] R err[%] rate[deg/s] resid σ[m]")
    for r in rows:
        print(f"  {1000 * r['speed']:6.1f} {r['dir']:6.1f} | {r['sq_cur']:6.2f} {r['sq_dir']:6.1f} {r['surge']:7.2f} "
              f"{r['cond']:5.2f} | {r['tu_cur']:6.2f} {r['radius_m']:6.2f} {r['radius']:6.2f} {r['rate']:6.2f} {r['resid']:6.3f}")
    for key, name in (("sq_cur", "square current error [mm/s]"), ("surge", "square surge error [mm/s]"),
                      ("tu_cur", "turn current error [mm/s]"), ("radius", "radius error vs truth [%]")):
        print("  " + summary(name, [r[key] for r in rows]))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=30)
    parser.add_argument("--sim-seeds", type=int, default=5)
    args = parser.parse_args()
    synthetic(args.seeds)
    if args.sim_seeds:
        simulator(args.sim_seeds)


if __name__ == "__main__":
    main()
