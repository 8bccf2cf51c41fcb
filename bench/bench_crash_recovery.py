"""Crash recovery at random points of a campaign: ``companion identify`` killed with SIGKILL after a
random number of recorded changes (seeded, between one and all but the last of the changes a whole
campaign records, counted first on a campaign run to its end), then ``companion recover --yes``; a case is restored
when the heading gains, the mode and the thrust are as found and the rudder is back with the heading
loop (no override left), and the campaign row says ``interrupted`` (harness/crash_cases.py).

    python bench/bench_crash_recovery.py [--cases 20] [--seed 1]
"""
from __future__ import annotations

import argparse
import random
import sys
import tempfile
from collections import Counter
from pathlib import Path

from harness.crash_cases import campaign_command, prepare_vehicle, run_crash_case, store_changes
from harness.simulator import start_sim


def whole_campaign_changes(store: Path) -> int:
    """The changes one campaign of the cases' kind records when it runs to its end."""
    import subprocess

    sim = start_sim(transport="tcp", speedup=0, seed=99, lockstep=True)
    try:
        prepare_vehicle(sim.endpoint)
        subprocess.run(campaign_command(sim.endpoint, store), capture_output=True, timeout=600)
    finally:
        sim.stop()
    return len(store_changes(store))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--cases", type=int, default=20)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    rng = random.Random(args.seed)
    rows, restored = [], 0
    with tempfile.TemporaryDirectory() as folder:
        total = whole_campaign_changes(Path(folder) / "whole.sqlite")
        print(f"a whole campaign records {total} changes", flush=True)
        for case in range(args.cases):
            after = rng.randint(1, max(total - 1, 1))  # kill after this many recorded changes
            sim = start_sim(transport="tcp", speedup=0, seed=case + 1, lockstep=True)
            try:
                store = Path(folder) / f"case{case}.sqlite"
                result = run_crash_case(sim, store, f"after {after} changes",
                                        lambda changes, found, after=after: len(changes) >= after)
            finally:
                sim.stop()
            kinds = Counter(kind for kind, _ in store_changes(store)[:result.changes_at_kill])
            last = store_changes(store)[result.changes_at_kill - 1][0] if result.changes_at_kill else "-"
            restored += result.restored
            rows.append((case, after, result.changes_at_kill, last, result.damaged.get("rudder", float("nan")),
                         result.restored, "; ".join(result.problems)))
            print(f"case {case:2d}: killed after {result.changes_at_kill:2d} changes (last {last:16s}) "
                  f"rudder held {result.damaged.get('rudder', float('nan')):.2f} rad -> "
                  f"{'restored' if result.restored else 'NOT restored: ' + '; '.join(result.problems)}"
                  f"  [{dict(kinds)}]", flush=True)
    print(f"\n{restored} of {args.cases} kills at random points of a campaign: vehicle restored on the next start")
    return 0 if restored == args.cases else 1


if __name__ == "__main__":
    sys.exit(main())
