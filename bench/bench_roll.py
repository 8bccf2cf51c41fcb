"""Roll stabilisation figures (SPEC C6; thesis Table 4.3, Fig. 4.7–4.8) on the in-process simulator.

Prints: roll mean/std open loop vs closed loop at 1.4 m/s (cruise thrust, propeller torque on,
random roll moment SIM_ROLL_DIST), for the default rate-feedback law and the seed's law; and the
settling time (|φ| < 2.5°) after a 25° kick at rest. No asserts.

    /tmp/venv/bin/python bench/bench_roll.py
"""
from __future__ import annotations

import argparse
import math
import time

import numpy as np

from behaviors.roll_stabilisation import RollStabilisation, RollStabilisationConfig
from companion.numerics.roll import RollVehicle, linearise, rate_feedback_gains, seed_gains, settle_time
from harness.inprocess import ClosedLoop

LAWS = {"open": None, "rate (default)": rate_feedback_gains(linearise(RollVehicle())),
        "seed": seed_gains(linearise(RollVehicle()))}


def cruise(gains, seed: int, disturbance: float) -> tuple[float, float, float]:
    loop = ClosedLoop(seed=seed, depth=2.0, params={"SIM_ROLL_DIST": disturbance})
    loop.advance(20.0)
    behaviour = RollStabilisation(RollStabilisationConfig(gains=gains)) if gains else None
    loop.run(behaviour, 120.0)  # the slow integral (zero at 0.01) removes the propeller-torque mean
    rolls: list[float] = []
    masses: list[float] = []
    loop.run(behaviour, 120.0, on_sample=lambda _s: (rolls.append(loop.vehicle.roll), masses.append(loop.vehicle.mass_angle)))
    return float(np.degrees(np.mean(rolls))), float(np.degrees(np.std(rolls))), float(np.degrees(np.mean(masses)))


def kick(gains, seed: int = 4) -> float:
    loop = ClosedLoop(seed=seed, depth=2.0, speed=0.0, thrust=0.0)
    loop.advance(5.0)
    loop.vehicle.kick_roll(math.radians(25.0))
    times: list[float] = []
    rolls: list[float] = []
    behaviour = RollStabilisation(RollStabilisationConfig(gains=gains)) if gains else None
    loop.run(behaviour, 30.0, on_sample=lambda _s: (times.append(loop.time_s), rolls.append(math.degrees(loop.vehicle.roll))))
    return settle_time(np.asarray(times) - times[0], rolls, band=2.5)


def main() -> None:
    argparse.ArgumentParser(description=__doc__.splitlines()[0]).parse_args()  # no options; --help
    start = time.time()
    for disturbance in (0.02, 0.05, 0.1):
        for seed in (3, 7):
            cells = []
            for name, gains in LAWS.items():
                mean, std, mass = cruise(gains, seed, disturbance)
                cells.append(f"{name}: mean {mean:+.2f}° std {std:.3f}° (mass mean {mass:+.1f}°)")
            print(f"1.4 m/s, SIM_ROLL_DIST {disturbance} N·m, seed {seed}: " + " | ".join(cells))
    print("25° kick at rest, settle to |φ| < 2.5°: "
          + ", ".join(f"{name} {kick(gains):.2f} s" for name, gains in LAWS.items()))
    print(f"wall time {time.time() - start:.1f} s")


if __name__ == "__main__":
    main()
