"""How lost telemetry samples move the identified yaw model: the evidence behind the record
sampling rule (``companion.numerics.sampling.SamplingRule``).

Flies full yaw training records in-process (the simulator's autopilot and physics, STARFISH, the
quick procedure's window, seeds × thrusts), then identifies each record again offline after taking
samples out of it, and prints how far a22 and b2 move from the full record's estimate:

* random loss of a fraction of the samples (what a lossy radio does);
* one gap of a given length placed where it hurts most: across the doublet's switch at its middle
  (what a reordering link does once samples arriving late are discarded).

    python bench/bench_sampling_gaps.py [--seeds 4]
"""
from __future__ import annotations

import argparse
import random
import statistics

from behaviors.identification import IdentificationManoeuvre, ManoeuvreConfig
from companion.interface import SetThrust
from companion.numerics.identification import ConvergenceRule, YawIdentifier
from companion.procedures.runner import run_behavior

THRUSTS = (0.6, 0.8, 1.0)
LOSSES = (0.02, 0.10, 0.20, 0.30, 0.50)
GAPS_S = (0.1, 0.15, 0.2, 0.25, 0.3, 0.5, 1.0)


def records(seeds: int) -> list[dict]:
    from harness.inprocess import InProcessLink

    config = ManoeuvreConfig(settle_s=15.0, resettle_s=10.0, stop_on_convergence=False, r2_threshold=-1.0,
                             max_attempts=1)
    out = []
    for seed in range(1, seeds + 1):
        for thrust in THRUSTS:
            link = InProcessLink(seed=seed)
            manoeuvre = IdentificationManoeuvre(config, thrust=thrust)
            link.execute([SetThrust(thrust)])
            run_behavior(link, manoeuvre)
            attempt = manoeuvre.attempts[0]
            out.append({"seed": seed, "thrust": thrust, "switch_s": config.pre_excitation_s + config.doublet_period_s / 2,
                        **{k: attempt.training[k] for k in ("time", "signal", "actuator")}})
    return out


def identify(times, heading, rudder) -> tuple[float, float]:
    identifier = YawIdentifier(rule=ConvergenceRule())
    for t, h, r in zip(times, heading, rudder):
        identifier.update(t, h, r)
    model = identifier.model()
    return model.a22, model.b2


def thinned(record: dict, keep) -> tuple[list, list, list]:
    rows = [(t, h, r) for i, (t, h, r) in enumerate(zip(record["time"], record["signal"], record["actuator"]))
            if keep(i, t)]
    return tuple(list(column) for column in zip(*rows))  # type: ignore[return-value]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--seeds", type=int, default=4)
    args = parser.parse_args()
    rng = random.Random(7)
    data = records(args.seeds)
    print(f"{len(data)} training records (STARFISH, thrusts {THRUSTS}, seeds 1..{args.seeds}), 20 Hz")
    print("change of a22 / b2 against the full record's estimate, median and max over records")
    print(f"{'samples out':28s} {'a22 med':>8s} {'a22 max':>8s} {'b2 med':>8s} {'b2 max':>8s}")

    def row(label: str, keep_for) -> None:
        da, db = [], []
        for record in data:
            a_full, b_full = identify(record["time"], record["signal"], record["actuator"])
            a, b = identify(*thinned(record, keep_for(record)))
            da.append(abs(a / a_full - 1) * 100)
            db.append(abs(b / b_full - 1) * 100)
        print(f"{label:28s} {statistics.median(da):7.2f}% {max(da):7.2f}% {statistics.median(db):7.2f}% {max(db):7.2f}%")

    for loss in LOSSES:
        row(f"random loss {loss:.0%}", lambda record, loss=loss: (lambda i, t: i == 0 or rng.random() >= loss))
    for gap in GAPS_S:
        def keep_for(record, gap=gap):
            start = record["time"][0] + record["switch_s"] - gap / 2
            return lambda i, t: not start < t < start + gap
        row(f"one gap of {gap:.2f} s at the switch", keep_for)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
