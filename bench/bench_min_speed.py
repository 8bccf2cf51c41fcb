"""Minimum-speed seeking figures (SPEC C7; thesis Fig. 5.22, 5.25, 5.26, Table 5.2) on the in-process
simulator (physics + autopilot, no MAVLink). Prints final TR/speed vs the analytic TR*/Vmin, settle
time, depth errors and thrust reversals (limit-cycle indicator) for: the seeking period Ts study,
a fin-budget δFB sweep, and δmax 0.26 / 0.35 / 0.40 (ELEV_MAX and the seeker's δmax together).
No asserts.

    /tmp/venv/bin/python bench/bench_min_speed.py
"""
from __future__ import annotations

import os
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from behaviors.min_speed import MinSpeedConfig, MinSpeedSeeking  # noqa: E402
from companion.numerics.fuzzy_seeker import SeekerConfig  # noqa: E402
from companion.numerics.minspeed import DivePlaneVehicle, minimum_speed  # noqa: E402
from tests.closed_loop import ClosedLoop  # noqa: E402

SEEDS = (1, 2, 3)


def seek(seed: int, seconds: float = 200.0, elev_max: float = 0.26, noise_scale: float = 1.0, **seeker) -> dict:
    loop = ClosedLoop(seed=seed, depth=2.0, params={"ELEV_MAX": elev_max})
    # bench-only: scale the simulated sensor noise (the seed's Simulink run was noise-free, §5.4)
    loop.vehicle._noise_sigma = loop.vehicle._noise_sigma * noise_scale
    loop.advance(100.0)
    config = MinSpeedConfig(seeker=SeekerConfig(delta_max=elev_max, **seeker), depth_setpoint=2.0,
                            depth_p=loop.param("DPT_P"), depth_i=loop.param("DPT_I"), pitch_max=loop.param("PIT_MAX"))
    behaviour = MinSpeedSeeking(config)
    loop.run(behaviour, seconds)
    result = behaviour.result()
    tail = [tr for t, tr in zip(result["series"]["time"], result["series"]["thrust_setpoint"]) if t >= seconds - 60.0]
    result["tail_range"] = (min(tail), max(tail))
    return result


def line(label: str, results: list[dict], analytic) -> str:
    cells = []
    for r in results:
        settle = "—" if r["settle_time_s"] is None else f"{r['settle_time_s']:.0f}s"
        settled_err = "—" if r["max_depth_error_settled_m"] is None else f"{r['max_depth_error_settled_m']:.2f}"
        cells.append(f"TR {r['thrust_ratio_final']:.2f} [{r['tail_range'][0]:.2f}–{r['tail_range'][1]:.2f}] "
                     f"V {r['speed_final']:.3f} settle {settle} dz {r['max_depth_error_m']:.2f}/{settled_err} rev {r['reversals_last_30s']}")
    return f"{label:<18} (TR* {analytic.thrust_ratio_star:.3f}, Vmin {analytic.v_min:.3f}): " + " | ".join(cells)


def main() -> None:
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
