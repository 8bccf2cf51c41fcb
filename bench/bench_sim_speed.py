"""Simulator throughput: achieved speed-up and attitude rate (vehicle time) with a client reading
all traffic. Targets (SPEC C2, task brief): ≥ 45× real time at --speedup 50, ≥ 20 Hz ATTITUDE.

    /tmp/venv/bin/python bench/bench_sim_speed.py [--speedup 50] [--seconds 10] [--transport udp]

Prints numbers; it is not a pass/fail test.
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

from harness.mavlink_clients import connect_client  # sets MAVLINK20 before pymavlink is imported
from harness.simulator import start_sim


def _process_cpu_s(pid: int) -> float:
    """user + system CPU seconds of a process (Linux /proc; NaN elsewhere)."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return float("nan")


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--speedup", type=float, default=50.0)
    parser.add_argument("--seconds", type=float, default=10.0, help="wall seconds to measure")
    parser.add_argument("--transport", choices=("udp", "tcp"), default="udp")
    parser.add_argument("--armed-hold", action="store_true", default=True,
                        help="arm and hold heading/depth (controllers running) — default on")
    args = parser.parse_args()

    sim = start_sim(transport=args.transport, speedup=args.speedup)
    try:
        conn = connect_client(sim.endpoint)
        mav = conn.mav
        if args.armed_hold:
            mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)
            mav.command_long_send(1, 1, 176, 0, 1, 2, 0, 0, 0, 0, 0)
        counts: dict[str, int] = {}
        first_att = last_att = None
        gaps = 0
        prev = None
        t0 = time.monotonic()
        cpu0 = time.process_time()
        sim_cpu0 = _process_cpu_s(sim.process.pid)
        while time.monotonic() - t0 < args.seconds:
            msg = conn.recv_match(blocking=True, timeout=0.5)
            if msg is None:
                continue
            kind = msg.get_type()
            counts[kind] = counts.get(kind, 0) + 1
            if kind == "ATTITUDE":
                if first_att is None:
                    first_att = (time.monotonic(), msg.time_boot_ms)
                last_att = (time.monotonic(), msg.time_boot_ms)
                if prev is not None and msg.time_boot_ms - prev > 50:
                    gaps += 1
                prev = msg.time_boot_ms
        client_cpu = time.process_time() - cpu0
        sim_cpu = _process_cpu_s(sim.process.pid) - sim_cpu0
        wall = last_att[0] - first_att[0]
        vehicle = (last_att[1] - first_att[1]) / 1000.0
        ratio = vehicle / wall
        att_rate = (counts["ATTITUDE"] - 1) / vehicle
        total = sum(counts.values())
        print(f"transport            : {args.transport}")
        print(f"requested speed-up   : {args.speedup:g}x")
        print(f"achieved speed-up    : {ratio:.1f}x   (target >= 45x at 50: "
              f"{'OK' if ratio >= 45 or args.speedup < 50 else 'MISSED'})")
        print(f"attitude rate        : {att_rate:.2f} Hz vehicle time   (target >= 20 Hz: "
              f"{'OK' if att_rate >= 19.95 else 'MISSED'})")
        print(f"attitude gaps > 50 ms: {gaps} (lost or late samples seen by the client)")
        print(f"messages received    : {total} in {wall:.1f} s wall = {total / wall:.0f} msg/s")
        print(f"client CPU           : {client_cpu:.1f} s")
        print(f"simulator CPU        : {sim_cpu:.1f} s = {100 * sim_cpu / args.seconds:.0f} % of one core")
        print("per type             : " + ", ".join(f"{k} {v}" for k, v in sorted(counts.items())))
        conn.close()
    finally:
        sim.stop()
        log_text = sim.log_text()
        sim.log_path.unlink(missing_ok=True)
        tail = [line for line in log_text.splitlines() if "vehicle in" in line]
        if tail:
            print("simulator log        : " + tail[-1].split("sim.server: ", 1)[-1])
    return 0


if __name__ == "__main__":
    sys.exit(main())
