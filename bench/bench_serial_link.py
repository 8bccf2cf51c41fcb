"""The identification campaign over a serial telemetry radio at 57600 baud that loses bytes: what the
radio dropped, what the companion reported, the campaign's wall time (``harness/serial_campaign.py``).

Each case: a ``--lockstep`` simulator (STARFISH, TCP), ``companion identify --connect /dev/pts/N,57600
--lockstep --thrusts 0.7 --axes yaw --json`` through a pseudo-terminal pair bridged to it by a radio
model each way (``harness/serial_bridge.py``: 5760 B/s, a 2048-byte buffer that drops what does not
fit, ``--loss`` of the bytes lost on the air in runs of ``--burst`` bytes on average, seeded), then a
direct client comparing the vehicle's state with what was found. One line per case, then a summary.

    python bench/bench_serial_link.py [--loss 0.02] [--burst 32] [--seeds 1,2,3]
"""
from __future__ import annotations

import argparse
import logging
import statistics
import sys
import tempfile
from pathlib import Path

from harness.fault_schedule import TO_COMPANION
from harness.serial_bridge import add_radio_arguments, radio_from
from harness.serial_campaign import run_serial_campaign
from harness.simulator import start_sim

log = logging.getLogger("bench_serial_link")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_radio_arguments(parser)
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING, format="%(message)s", stream=sys.stdout)
    log.setLevel(logging.INFO)  # the bench's own lines; the rest only when something is wrong
    conditions, seeds = radio_from(args)
    log.info("radio each way: %s", conditions.describe())
    runs = []
    with tempfile.TemporaryDirectory() as folder:
        for seed in seeds:
            sim = start_sim(transport="tcp", speedup=0, seed=1, lockstep=True)
            try:
                run = run_serial_campaign(sim, Path(folder) / f"store-{seed}.sqlite", conditions, seed)
            finally:
                sim.stop()
            runs.append(run)
            log.info("seed %d: %s; vehicle %s", seed, run.summary(),
                     "as found" if not run.state_problems else "; ".join(run.state_problems))
    completed = [r for r in runs if r.status == "completed"]
    ratios = [r.quality["frames_lost"] / r.radio[TO_COMPANION]["frames_hit"]
              for r in runs if r.quality.get("frames") and r.radio[TO_COMPANION]["frames_hit"]]
    log.info("%d of %d completed; vehicle as found in %d; wall time of the completed %s; frames the companion "
             "reported lost per frame the radio hit: %s", len(completed), len(runs),
             sum(not r.state_problems for r in runs),
             f"{min(r.wall_s for r in completed):.1f}–{max(r.wall_s for r in completed):.1f} s" if completed else "-",
             f"{min(ratios):.2f}–{max(ratios):.2f} (median {statistics.median(ratios):.2f})" if ratios else "-")
    return 0 if all(not r.state_problems for r in runs) else 1


if __name__ == "__main__":
    sys.exit(main())
