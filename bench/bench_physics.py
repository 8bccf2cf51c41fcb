"""Steps per second of ``sim.vehicle.Vehicle.step`` (the server needs ≥ 5,000/s for 100 Hz × 50).

Run: /tmp/venv/bin/python bench/bench_physics.py [--preset starfish] [--steps 50000]
"""
from __future__ import annotations

import argparse
import time

from sim.controllers import DepthPitchCascade, HeadingPI
from sim.preset import load_preset
from sim.vehicle import ActuatorDemand, Vehicle


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--preset", default="starfish")
    parser.add_argument("--steps", type=int, default=50_000)
    args = parser.parse_args()
    preset = load_preset(args.preset)
    vehicle = Vehicle(preset, seed=1)
    vehicle.roll_disturbance_amplitude = 0.05
    demand = ActuatorDemand(thrust_ratio=0.7)
    start = time.perf_counter()
    for _ in range(args.steps):
        vehicle.step(0.01, demand)
    bare = args.steps / (time.perf_counter() - start)

    heading = HeadingPI(kp=preset.autopilot.heading_p, ki=preset.autopilot.heading_i, imax=0.15)
    depth = DepthPitchCascade()
    start = time.perf_counter()
    for k in range(args.steps):
        demand.rudder = heading.update(0.01, 1.0, vehicle.yaw)
        demand.elevator = depth.update(0.01, 6.0, vehicle.depth, vehicle.pitch)
        vehicle.step(0.01, demand)
        if k % 5 == 0:  # 20 Hz sensors as the server reads them
            vehicle.measure()
    closed = args.steps / (time.perf_counter() - start)
    print(f"preset {args.preset}: Vehicle.step {bare:,.0f} steps/s; "
          f"with heading+depth controllers and 20 Hz measure() {closed:,.0f} steps/s "
          f"(needed: 5,000 for 100 Hz at 50x)")


if __name__ == "__main__":
    main()
