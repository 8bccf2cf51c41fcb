"""``companion minspeed``: the analytic minimum speed of a vehicle (SPEC C7, eq. 5.28–5.55).

    companion minspeed [--preset NAME | --vehicle FILE.json] [--delta-max D] [--json]

Where the vehicle comes from: ``--vehicle`` reads a JSON file (a simulator preset or a flat dict of
:class:`~companion.numerics.minspeed.DivePlaneVehicle` fields). ``--preset NAME`` reads the
simulator's preset file ``sim/presets/NAME.json`` **as data**: the companion must not import the
simulator, so the file is located with ``importlib.util.find_spec("sim")`` — which, for a
top-level package, finds its folder without executing it — and read from the filesystem. Without
either option the Table 5.1 vehicle (the dataclass defaults) is used.
"""
from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from companion.cli.commands._common import finite_float, print_json
from companion.numerics.minspeed import minimum_speed
from companion.records.vehicle_files import load_vehicle, preset_path  # noqa: F401 - part of this command's API


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "minspeed",
        help="analytic minimum speed, pitch, thrust and thrust ratio of a vehicle (eq. 5.28-5.55)",
        description=__doc__.split("\n\n")[0],
    )
    source = parser.add_mutually_exclusive_group()
    source.add_argument("--preset", help="simulator preset name (sim/presets/NAME.json, read as data)")
    source.add_argument("--vehicle", metavar="FILE.json", help="vehicle parameters as JSON")
    parser.add_argument("--delta-max", type=_elevator_limit, default=None,
                        help="elevator limit δmax in rad, in (0, π/2] (default: the vehicle's)")
    parser.add_argument("--json", action="store_true", help="machine-readable output")
    parser.set_defaults(func=run)


def _elevator_limit(text: str) -> float:
    """δmax in (0, π/2] rad (argparse type): nan, inf, zero, negative and degrees refused."""
    value = finite_float(text)
    if not 0.0 < value <= math.pi / 2:
        raise argparse.ArgumentTypeError(f"the elevator limit must be in (0, π/2] rad, not {text!r}")
    return value


def run(args: argparse.Namespace) -> int:
    try:
        vehicle, source = load_vehicle(args.preset, args.vehicle, args.delta_max)
        result = minimum_speed(vehicle)
    except (OSError, ValueError, np.linalg.LinAlgError) as exc:
        print(f"companion minspeed: error: {exc}", file=sys.stderr)
        return 2
    delta_max = vehicle.delta_max
    out = {**result.as_json(), "delta_max": delta_max, "source": source}
    if not result.exists:
        out["reason"] = "the required and achievable pitch curves never meet: no minimum speed for this δmax"
    if args.json:
        print_json(out)
    elif result.exists:
        print(
            f"{source}: δmax {delta_max:.3f} rad → Vmin {result.v_min:.3f} m/s, θ* {result.theta_star_deg:.2f}°, "
            f"Ft* {result.thrust_star:.2f} N, TR* {result.thrust_ratio_star:.3f}"
            + ("" if result.condition_548 else " (closed-form condition 5.48 not met)")
        )
    else:
        print(f"{source}: no minimum speed for δmax {delta_max:.3f} rad (condition 5.48: {result.condition_548})")
    return 0  # "exists" in the output says whether there is a minimum speed
