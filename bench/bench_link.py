"""Vehicle-interface throughput and latency against the simulator over loopback (SPEC C1).

For each speed-up: connect time, snapshots per wall second, achieved speed-up of the vehicle clock
as the companion sees it, the backlog left in pymavlink's parse buffer, and the wall-clock round
trip of a verified parameter write and of a verified mode change.

    python bench/bench_link.py --speedups 1,10,50,100 --seconds 3 [--transport udp|tcp]
"""
from __future__ import annotations

import argparse
import statistics
import sys
import time

from harness.simulator import start_sim


def measure(speedup: float, seconds: float, transport: str) -> dict:
    from companion.link.vehicle import VehicleLink

    sim = start_sim(transport=transport, speedup=speedup)
    try:
        wall = time.monotonic()
        link = VehicleLink.connect(sim.endpoint)
        connect_s = time.monotonic() - wall
        link.skip_to_now()
        first = link.next_telemetry()
        wall = time.monotonic()
        count = 0
        last = first
        while time.monotonic() - wall < seconds:
            last = link.next_telemetry()
            count += 1
        elapsed = time.monotonic() - wall
        backlog = link.transport.unparsed_bytes
        param_ms = []
        for value in (0.8, 0.9, 0.8, 0.9, 0.8):
            start = time.monotonic()
            link.set_param("HDG_P", value)
            param_ms.append(1000 * (time.monotonic() - start))
        mode_ms = []
        for mode in ("guided", "manual", "guided", "manual"):
            start = time.monotonic()
            link.set_mode(mode)
            mode_ms.append(1000 * (time.monotonic() - start))
        link.close()
        return {"speedup": speedup, "connect_s": connect_s, "snapshots_per_wall_s": count / elapsed,
                "achieved_speedup": (last.time_s - first.time_s) / elapsed, "backlog_bytes": backlog,
                "param_write_ms": statistics.median(param_ms), "mode_change_ms": statistics.median(mode_ms)}
    finally:
        sim.stop()
        sim.log_path.unlink(missing_ok=True)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--speedups", default="1,10,50,100")
    parser.add_argument("--seconds", type=float, default=3.0)
    parser.add_argument("--transport", choices=("udp", "tcp"), default="udp")
    args = parser.parse_args()
    print(f"{'speedup':>8} {'connect s':>10} {'snap/s':>8} {'achieved':>9} {'backlog B':>10} "
          f"{'param ms':>9} {'mode ms':>8}")
    for speedup in (float(s) for s in args.speedups.split(",")):
        r = measure(speedup, args.seconds, args.transport)
        print(f"{r['speedup']:>8g} {r['connect_s']:>10.3f} {r['snapshots_per_wall_s']:>8.0f} "
              f"{r['achieved_speedup']:>9.1f} {r['backlog_bytes']:>10d} {r['param_write_ms']:>9.1f} "
              f"{r['mode_change_ms']:>8.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
