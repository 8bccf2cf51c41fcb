"""The identification campaign from a ground station with the status page attacked (slowloris, a flood
of complete requests, malformed HTTP; ``harness.page_attack``) against the same campaign with the page
left alone: the campaign's wall time and outcome side by side, and what the attack was answered.

Our simulator in lockstep over TCP (the campaign's outcome is the vehicle's, whatever the load),
``companion run --lockstep --http 127.0.0.1:0``, the default campaign (five thrusts) unless
``--thrusts``; ``harness.page_campaign`` runs each. ``tests/test_status_page_under_attack.py`` is the
same campaign under the same attack, with assertions.

    python bench/bench_status_page_attack.py [--repeats 2] [--speedup 20] [--slowloris 300]
"""
from __future__ import annotations

import argparse
import logging
import statistics
import sys
import tempfile
from pathlib import Path

from harness.page_attack import AttackPlan
from harness.page_campaign import PageCampaign, campaign_beside_the_page
from harness.simulator import start_sim

log = logging.getLogger(__name__)


def one_campaign(workdir: Path, plan: AttackPlan | None, speedup: float, seed: int,
                 thrusts: str | None) -> PageCampaign:
    """One campaign on a fresh lockstep simulator (its log deleted afterwards)."""
    sim = start_sim(transport="tcp", speedup=speedup, seed=seed, lockstep=True)
    try:
        return campaign_beside_the_page(sim.endpoint, workdir, plan, thrusts=thrusts)
    finally:
        sim.stop()
        if sim.log_path is not None:
            sim.log_path.unlink(missing_ok=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--repeats", type=int, default=2, help="campaigns of each kind (alternating)")
    parser.add_argument("--speedup", type=float, default=20.0)
    parser.add_argument("--seed", type=int, default=2)
    parser.add_argument("--thrusts", default=None, help="e.g. 0.8 (default: the campaign's five)")
    parser.add_argument("--slowloris", type=int, default=300, help="half-open connections")
    parser.add_argument("--flooders", type=int, default=4, help="threads sending complete requests")
    args = parser.parse_args()
    logging.basicConfig(level=logging.WARNING, format="%(message)s")
    plan = AttackPlan(slowloris=args.slowloris, flooders=args.flooders)
    runs: dict[str, list[PageCampaign]] = {"page left alone": [], "page attacked": []}
    with tempfile.TemporaryDirectory(prefix="page-attack-") as tmp:
        for repeat in range(args.repeats):
            for kind, attack in (("page left alone", None), ("page attacked", plan)):
                run = one_campaign(Path(tmp) / f"{kind.split()[1]}-{repeat}", attack, args.speedup, args.seed,
                                   args.thrusts)
                runs[kind].append(run)
                outcome = "completed" if run.completed else f"NOT completed {run.acks[-3:]}"
                print(f"{kind:16s} #{repeat + 1}: {outcome}, {run.campaign_wall_s:5.1f} s of wall clock, "
                      f"companion exit {run.exit_code}, page after {run.page_after}", flush=True)
                if run.counts is not None:
                    c = run.counts
                    print(f"{'':20s}flood {dict(c.flood)}; slowloris {dict(c.slowloris)}; malformed "
                          f"{dict(c.malformed)}; longest without a 200 {c.flood_longest_without_200_s:.1f} s, "
                          f"slowest answer {c.flood_latency_max_s:.2f} s", flush=True)
                if "no telemetry snapshot" in run.stderr or "Traceback" in run.stderr:
                    print(run.stderr[-2000:], file=sys.stderr)
    print(f"\n{'campaign':16s} {'completed':>9s} {'wall s, median':>15s} {'min':>6s} {'max':>6s}")
    for kind, rows in runs.items():
        walls = [r.campaign_wall_s for r in rows]
        print(f"{kind:16s} {sum(r.completed for r in rows):>5d}/{len(rows):<3d} {statistics.median(walls):15.1f} "
              f"{min(walls):6.1f} {max(walls):6.1f}")
    attacked = [r.counts for r in runs["page attacked"] if r.counts is not None]
    if attacked:
        total = {code: sum(c.answered(code) for c in attacked) for code in ("200", "503")}
        fourxx = sum(n for c in attacked for kind in (c.flood, c.malformed, c.slowloris)
                     for code, n in kind.items() if code.startswith("4"))
        seconds = sum(c.duration_s for c in attacked)
        print(f"attack answers over {seconds:.0f} s: 200 {total['200']}, 503 {total['503']}, 4xx {fourxx}, "
              f"refused {sum(c.refused() for c in attacked)}; complete requests answered 200: "
              f"{sum(c.flood['200'] for c in attacked)} of {sum(sum(c.flood.values()) for c in attacked)}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
