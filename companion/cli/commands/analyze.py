"""``companion analyze squares|turns|eta|inertia --input FILE [--json] [--plot FILE.png]`` (SPEC C8, C9, C10).

Offline analysis of a recorded log (CSV or MAVLink tlog, see :mod:`companion.records.logs`).

JSON keys (SI units unless the key says otherwise):

* ``squares`` — ``surge_water``, ``sway_water``, ``heave_water`` (m/s, water-relative, body axes),
  ``sideslip_deg``, ``current_north``, ``current_east``, ``current_speed`` (m/s),
  ``current_dir_deg`` (direction the current flows **towards**, 0–360° from north, clockwise: 90 =
  towards east; paper eq. 11), ``condition_number`` (of H, ≈ 1 for a square), ``residual_std``,
  ``sigma`` (per estimate), ``samples``/``samples_used``.
* ``turns`` — ``radius_m``, ``turn_rate_deg_s`` (> 0 clockwise from above), ``water_speed``,
  ``current_north``, ``current_east``, ``current_speed``, ``current_dir_deg`` (towards, as above),
  ``residual_std_m``, ``sigma``, ``samples_used``.
* ``eta`` — ``models``: per η-model (LNB, LB, LQNB, LQB) ``estimates`` (k, kq, b, eta),
  ``sigma``, ``relative_sigma_pct``, ``j_ls``, ``dof``, ``j_per_dof``; ``best`` (J_LS/ν with the
  F-test parsimony guard of :func:`companion.numerics.lumped.select_model`), ``min_j_per_dof``,
  ``regime_points``.
* ``inertia`` — ``mass`` (kg or kg·m²) and its ``sigma``, ``offset``, ``bias``, ``j_ls``, ``dof``,
  ``j_per_dof``, ``omega_opt_rad_s`` (D-optimal frequency for the estimated mass).

Input formats for ``eta``: either a table of regime points (columns ``velocity``, ``force``,
``mapping``: 0 = reference mapping, 1 = the mapping whose efficiency η is identified), or a raw
record (columns ``t``, the position column named by ``--axis``, ``force``, ``mapping``) cut into
constant-force runs whose regime velocities are fitted by LS (x = u·t + x0) after ``--settle``.
For ``inertia``: columns ``t``, the ``--axis`` position column, ``force`` and optionally
``velocity``. Exit code 1 with a message on bad input.
"""
from __future__ import annotations

import argparse
import json
import logging
import math
import sys

import numpy as np

from companion.link.profiles import PROFILES
from companion.records.logs import LogError, NavLog, read_log, read_table_csv
from companion.numerics import lumped
from companion.numerics.steady_state import (
    fit_steady_turn,
    fit_straight_legs,
    steady_straight_mask,
    steady_turn_mask,
)

log = logging.getLogger(__name__)

KINDS = ("squares", "turns", "eta", "inertia")


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "analyze",
        help="analyse a recorded log: steady-state squares/turns, η-models, inertia",
        description=__doc__.split("\n\n", 1)[1] if __doc__ else None,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    parser.add_argument("kind", choices=KINDS, help="which analysis")
    parser.add_argument("--input", "-i", required=True, help="recorded log: .csv or MAVLink .tlog")
    parser.add_argument("--profile", choices=sorted(PROFILES), default="sim",
                        help="squares/turns from a tlog: the vehicle's autopilot profile, which decodes the "
                             "servo PWM into rudder/thrust (default: %(default)s)")
    parser.add_argument("--json", action="store_true", help="machine-readable JSON on stdout")
    parser.add_argument("--plot", metavar="FILE.png", help="write a figure (matplotlib, Agg)")
    parser.add_argument("--t-start", type=float, default=None, help="ignore samples before this time (s)")
    parser.add_argument("--t-end", type=float, default=None, help="ignore samples after this time (s)")
    parser.add_argument("--no-cut", action="store_true", help="squares/turns: do not cut transients")
    parser.add_argument("--rate-tol-deg", type=float, default=None,
                        help="transient cutting: heading-rate tolerance, deg/s (squares 0.5, turns 0.3)")
    parser.add_argument("--speed-tol", type=float, default=0.02, help="squares: velocity settling tolerance, m/s")
    parser.add_argument("--axis", default=None, help="eta/inertia: position column (default: position, else north)")
    parser.add_argument("--settle", type=float, default=0.3,
                        help="eta (raw record): fraction of each constant-force run discarded as transient")
    parser.add_argument("--k", type=float, default=None, help="inertia: linear drag k (known)")
    parser.add_argument("--kq", type=float, default=0.0, help="inertia: quadratic drag k_q (known)")
    parser.add_argument("--efficiency", type=float, default=1.0, help="inertia: thruster efficiency η of the mapping")
    parser.add_argument("--savgol-window", type=int, default=21, help="inertia: Savitzky–Golay window (samples)")
    parser.set_defaults(func=run)
    return parser


# --------------------------------------------------------------------------- analyses
def _window(nav: NavLog, t_start: float | None, t_end: float | None) -> NavLog:
    mask = np.ones(len(nav), bool)
    if t_start is not None:
        mask &= nav.t >= t_start
    if t_end is not None:
        mask &= nav.t <= t_end
    if not mask.any():
        raise ValueError("no samples inside the --t-start/--t-end window")
    return nav.select(mask)


def analyze_squares(nav: NavLog, cut: bool = True, rate_tol: float = math.radians(0.5),
                    speed_tol: float = 0.02) -> tuple[dict, np.ndarray]:
    """Straight-leg LS (eq. 7–8) on a log; returns (result dict, mask of the samples used)."""
    if len(nav) < 10:
        raise ValueError(f"too few samples ({len(nav)})")
    if cut:
        mask = steady_straight_mask(nav.t, nav.yaw, nav.vel_body, rate_tol, speed_tol)
        if mask.sum() < 10:
            raise ValueError("no steady straight leg found (try --no-cut or a larger --rate-tol-deg)")
    else:
        mask = np.ones(len(nav), bool)
    fit = fit_straight_legs(nav.roll[mask], nav.pitch[mask], nav.yaw[mask], nav.vel_body[mask])
    result = {**fit.as_dict(), "samples_used": int(mask.sum()), "samples_total": len(nav)}
    return result, mask


def analyze_turns(nav: NavLog, cut: bool = True, rate_tol: float = math.radians(0.3)):
    """Steady-turn LS (eq. 9–10) on a log; returns (result dict, mask, TurnFit)."""
    if len(nav) < 20:
        raise ValueError(f"too few samples ({len(nav)})")
    mask = steady_turn_mask(nav.t, nav.yaw, rate_tol) if cut else np.ones(len(nav), bool)
    if mask.sum() < 20:
        raise ValueError("the turn never settles to a steady rate (try --no-cut or a larger --rate-tol-deg)")
    fit = fit_steady_turn(nav.t[mask], nav.north[mask], nav.east[mask], nav.yaw[mask])
    return {**fit.as_dict(), "samples_used": int(mask.sum()), "samples_total": len(nav)}, mask, fit


def _position_column(table: dict[str, np.ndarray], axis: str | None, path: str) -> np.ndarray:
    name = axis or ("position" if "position" in table else "north")
    if name not in table:
        raise LogError(f"{path}: missing position column {name!r} (choose one with --axis)")
    values = table[name]
    return np.unwrap(values) if name == "yaw" else values


def regime_points_from_record(table: dict[str, np.ndarray], axis: str | None, settle: float, path: str) -> list[dict]:
    """Cut a raw record into runs of constant (force, mapping) and fit x = u·t + x0 to each run's
    settled part (the last ``1 − settle`` of it)."""
    for name in ("t", "force", "mapping"):
        if name not in table:
            raise LogError(f"{path}: missing column {name!r}")
    position = _position_column(table, axis, path)
    key = np.column_stack([table["force"], table["mapping"]])
    change = np.flatnonzero(np.any(np.diff(key, axis=0) != 0, axis=1)) + 1
    bounds = np.concatenate([[0], change, [key.shape[0]]])
    points = []
    for start, stop in zip(bounds[:-1], bounds[1:]):
        first = start + int(math.ceil(settle * (stop - start)))
        if stop - first < 3:
            continue
        u, sigma_u, _ = lumped.regime_velocity(table["t"][first:stop], position[first:stop])
        points.append({"force": float(key[start, 0]), "mapping": int(key[start, 1]), "velocity": u, "sigma": sigma_u,
                       "samples": int(stop - first)})
    return points


def analyze_eta(path: str, axis: str | None = None, settle: float = 0.3) -> dict:
    table = read_table_csv(path)
    if {"velocity", "force", "mapping"} <= set(table):
        points = [{"force": float(f), "mapping": int(m), "velocity": float(v)}
                  for v, f, m in zip(table["velocity"], table["force"], table["mapping"])]
    else:
        points = regime_points_from_record(table, axis, settle, path)
    if not points:
        raise ValueError("no regime points found")
    velocity = np.array([p["velocity"] for p in points])
    force = np.array([p["force"] for p in points])
    second = np.array([p["mapping"] != 0 for p in points])
    fits = lumped.fit_eta_models(velocity, force, second)
    choice = lumped.select_model(fits)
    return {
        "models": {name: fit.as_dict() for name, fit in fits.items()},
        "best": choice["best"],
        "min_j_per_dof": choice["min_j_per_dof"],
        "f_test_p": choice["f_test_p"],
        "regime_points": points,
    }


def analyze_inertia(path: str, k_lin: float, k_quad: float, efficiency: float = 1.0,
                    axis: str | None = None, savgol_window: int = 21) -> tuple[dict, lumped.InertiaFit, dict]:
    table = read_table_csv(path, ("t", "force"))
    position = _position_column(table, axis, path)
    fit = lumped.fit_inertia(table["t"], position, table["force"], k_lin, k_quad, efficiency,
                             velocity=table.get("velocity"), savgol_window=savgol_window)
    mean_speed = float(np.mean(np.gradient(position, table["t"])))
    out = fit.as_dict()
    if fit.mass > 0:
        out["omega_opt_rad_s"] = lumped.d_optimal_frequency(fit.mass, k_lin, k_quad, mean_speed)
    return out, fit, table


# --------------------------------------------------------------------------- output
def _print_human(kind: str, result: dict) -> None:
    if kind == "squares":
        s = result["sigma"]
        print(f"water-relative velocity: surge {result['surge_water']:.4f} ± {s['surge']:.4f} m/s, "
              f"sway {result['sway_water']:.4f} ± {s['sway']:.4f} m/s, heave {result['heave_water']:.4f} m/s")
        print(f"sideslip {result['sideslip_deg']:.2f} deg")
        print(f"current {result['current_speed'] * 1000:.1f} mm/s towards {result['current_dir_deg']:.1f} deg "
              f"(from north, clockwise)")
        print(f"condition number of H {result['condition_number']:.3f}; residual σ {result['residual_std']:.4f} m/s; "
              f"{result['samples_used']}/{result['samples_total']} samples used")
    elif kind == "turns":
        print(f"turning radius {result['radius_m']:.2f} ± {result['sigma']['radius_m']:.2f} m, "
              f"rate {result['turn_rate_deg_s']:.3f} deg/s, water speed {result['water_speed']:.3f} m/s")
        print(f"current {result['current_speed'] * 1000:.1f} mm/s towards {result['current_dir_deg']:.1f} deg "
              f"(from north, clockwise)")
        print(f"residual σ {result['residual_std_m']:.3f} m; {result['samples_used']}/{result['samples_total']} samples used")
    elif kind == "eta":
        for name, model in result["models"].items():
            parts = ", ".join(f"{k} {v:.4g} (σ {model['relative_sigma_pct'][k]:.1f} %)"
                              for k, v in model["estimates"].items())
            print(f"η{name:5s}: {parts}; J_LS {model['j_ls']:.4g}, ν {model['dof']}, J/ν {model['j_per_dof']:.4g}")
        print(f"best model: η{result['best']} (smallest J_LS/ν: η{result['min_j_per_dof']})")
    else:
        print(f"inertia {result['mass']:.4g} ± {result['sigma']:.2g}; bias {result['bias']:.3g}; "
              f"J_LS/ν {result['j_per_dof']:.3g} (ν {result['dof']})")
        if "omega_opt_rad_s" in result:
            print(f"D-optimal excitation for this inertia: ω_opt {result['omega_opt_rad_s']:.4f} rad/s")


def _plot(kind: str, path: str, **data) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 6))
    if kind in ("squares", "turns"):
        nav, mask = data["nav"], data["mask"]
        result = data["result"]
        ax.plot(nav.east, nav.north, ".", ms=2, color="0.7", label="measured (all)")
        ax.plot(nav.east[mask], nav.north[mask], ".", ms=2, color="C0", label="measured (steady, fitted)")
        if kind == "turns":
            fit = data["fit"]
            tt = nav.t[mask]
            fitted = fit.position(tt)
            ax.plot(fitted[:, 1], fitted[:, 0], "--", color="C1", label="LS fitted path (eq. 9)")
            angle = np.linspace(0, 2 * np.pi, 200)
            ax.plot(fit.center[1] + fit.radius * np.sin(angle), fit.center[0] + fit.radius * np.cos(angle),
                    "-", color="C2", label=f"circle without current, R = {fit.radius:.2f} m")
            ax.plot(fit.center[1], fit.center[0], "x", color="C2")
            origin = fit.center
        else:
            origin = np.array([np.mean(nav.north), np.mean(nav.east)])
        scale = 0.25 * max(np.ptp(nav.north), np.ptp(nav.east), 1.0) / max(result["current_speed"], 1e-9)
        ax.annotate("", xy=(origin[1] + scale * result["current_east"], origin[0] + scale * result["current_north"]),
                    xytext=(origin[1], origin[0]), arrowprops={"arrowstyle": "->", "color": "C3", "lw": 2})
        ax.plot([], [], color="C3", label=f"current {result['current_speed'] * 1000:.1f} mm/s "
                                        f"towards {result['current_dir_deg']:.0f}° (arrow not to scale)")
        ax.set_xlabel("east (m)")
        ax.set_ylabel("north (m)")
        ax.set_aspect("equal", adjustable="datalim")
    elif kind == "eta":
        result = data["result"]
        pts = result["regime_points"]
        v = np.array([p["velocity"] for p in pts])
        f = np.array([p["force"] for p in pts])
        m = np.array([p["mapping"] for p in pts]) != 0
        ax.plot(v[~m], f[~m], "o", label="reference mapping")
        ax.plot(v[m], f[m], "s", label="second mapping (nominal force)")
        grid = np.linspace(v.min(), v.max(), 100)
        for name, model in result["models"].items():
            est = model["estimates"]
            drag = est["k"] * grid + est.get("kq", 0.0) * grid * np.abs(grid) + est.get("b", 0.0)
            ax.plot(grid, drag, "-", lw=2 if name == result["best"] else 0.8, label=f"η{name} drag")
        ax.set_xlabel("regime velocity")
        ax.set_ylabel("force / torque")
    else:
        fit, table = data["fit"], data["table"]
        ax.plot(table["t"], fit.fit.residuals, label="residual of y = Hθ (eq. 4.43–4.45)")
        ax.set_xlabel("t (s)")
        ax.set_ylabel("residual (force·time)")
    ax.legend(fontsize=8)
    ax.grid(True, alpha=0.3)
    ax.set_title(f"companion analyze {kind}")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run(args: argparse.Namespace) -> int:
    kind = args.kind
    try:
        plot_data: dict = {}
        if kind in ("squares", "turns"):
            nav = _window(read_log(args.input, args.profile), args.t_start, args.t_end)
            if kind == "squares":
                rate_tol = math.radians(args.rate_tol_deg if args.rate_tol_deg is not None else 0.5)
                result, mask = analyze_squares(nav, not args.no_cut, rate_tol, args.speed_tol)
                plot_data = {"nav": nav, "mask": mask, "result": result}
            else:
                rate_tol = math.radians(args.rate_tol_deg if args.rate_tol_deg is not None else 0.3)
                result, mask, fit = analyze_turns(nav, not args.no_cut, rate_tol)
                plot_data = {"nav": nav, "mask": mask, "result": result, "fit": fit}
        elif kind == "eta":
            result = analyze_eta(args.input, args.axis, args.settle)
            plot_data = {"result": result}
        else:
            if args.k is None:
                raise ValueError("inertia needs the known linear drag --k (and --kq, --efficiency)")
            result, fit, table = analyze_inertia(args.input, args.k, args.kq, args.efficiency, args.axis,
                                                 args.savgol_window)
            plot_data = {"fit": fit, "table": table}
        if args.plot:
            _plot(kind, args.plot, **plot_data)
    except (LogError, ValueError, np.linalg.LinAlgError) as exc:
        print(f"companion analyze {kind}: error: {exc}", file=sys.stderr)
        return 1
    result = {"kind": kind, "input": args.input, **result}
    if args.json:
        print(json.dumps(result, indent=2, default=float))
    else:
        _print_human(kind, result)
        if args.plot:
            print(f"figure written to {args.plot}")
    return 0
