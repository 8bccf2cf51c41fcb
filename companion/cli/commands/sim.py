"""``companion sim``: start the simulator as a child process (SPEC C2, C10).

Runs ``python -m sim run ...`` with this interpreter (``sys.executable``) — a subprocess, never an
import, so the companion stays independent of ``sim/``. The child's output goes straight to this
terminal; SIGINT/SIGTERM are forwarded to it, and its exit code is returned.
"""
from __future__ import annotations

import argparse
import signal
import subprocess
import sys


def add_parser(subparsers) -> None:
    parser = subparsers.add_parser("sim", help="start the SITL vehicle simulator",
                                   description=__doc__.splitlines()[0])
    parser.add_argument("--preset", default=None, help="vehicle preset (python -m sim presets)")
    parser.add_argument("--speedup", type=float, default=None, help="vehicle time / wall time")
    parser.add_argument("--listen", default=None, metavar="ENDPOINT", help="e.g. udpin:127.0.0.1:14550")
    parser.add_argument("--seed", type=int, default=None, help="noise / disturbance seed")
    parser.add_argument("--current", default=None, metavar="VN,VE", help="water current north,east (m/s)")
    parser.add_argument("--duration", type=float, default=None, help="stop after this many vehicle seconds")
    parser.set_defaults(func=run)


def sim_command(args: argparse.Namespace) -> list[str]:
    """The child's argv: only the options given are passed (the simulator owns the defaults)."""
    argv = [sys.executable, "-m", "sim", "run"]
    for option in ("preset", "speedup", "listen", "seed", "current", "duration"):
        value = getattr(args, option, None)
        if value is not None:
            argv += [f"--{option}", str(value)]
    return argv


def run(args: argparse.Namespace) -> int:
    child = subprocess.Popen(sim_command(args))

    def forward(signum, _frame) -> None:
        if child.poll() is None:
            child.send_signal(signum)

    previous = {sig: signal.signal(sig, forward) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:
        while True:
            try:
                return child.wait()
            except KeyboardInterrupt:  # the handler already forwarded it; wait for the child to end
                continue
    finally:
        for sig, handler in previous.items():
            signal.signal(sig, handler)
