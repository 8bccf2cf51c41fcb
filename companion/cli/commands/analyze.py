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
import logging
import math
import sys

import numpy as np

from companion.cli.commands._common import finite_float, positive_float, print_json
from companion.link.profiles import PROFILES
from companion.records.logs import MAX_SPEED, LogError, NavLog, check_navigation_units, read_log, read_table_csv
from companion.records.serialise import null_reasons
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
    parser.add_argument("--t-start", type=finite_float, default=None, help="ignore samples before this time (s)")
    parser.add_argument("--t-end", type=finite_float, default=None, help="ignore samples after this time (s)")
    parser.add_argument("--no-cut", action="store_true", help="squares/turns: do not cut transients")
    parser.add_argument("--rate-tol-deg", type=positive_float, default=None,
                        help="transient cutting: heading-rate tolerance, deg/s (squares 0.5, turns 0.3)")
    parser.add_argument("--speed-tol", type=positive_float, default=0.02, help="squares: velocity settling tolerance, m/s")
    parser.add_argument("--axis", default=None, help="eta/inertia: position column (default: position, else north)")
    parser.add_argument("--settle", type=_fraction, default=0.3,
                        help="eta (raw record): fraction of each constant-force run discarded as transient")
    parser.add_argument("--k", type=_non_negative, default=None, help="inertia: linear drag k (known)")
    parser.add_argument("--kq", type=_non_negative, default=0.0, help="inertia: quadratic drag k_q (known)")
    parser.add_argument("--efficiency", type=positive_float, default=1.0, help="inertia: thruster efficiency η of the mapping")
    parser.add_argument("--savgol-window", type=_savgol_window, default=21, help="inertia: Savitzky–Golay window (samples)")
    parser.set_defaults(func=run)
    return parser


def _fraction(text: str) -> float:
    """A number in [0, 1) (argparse type)."""
    value = finite_float(text)
    if not 0.0 <= value < 1.0:
        raise argparse.ArgumentTypeError(f"expected a fraction in [0, 1), not {text!r}")
    return value


def _non_negative(text: str) -> float:
    """A finite number ≥ 0 (argparse type): a drag coefficient."""
    value = finite_float(text)
    if value < 0.0:
        raise argparse.ArgumentTypeError(f"expected a number >= 0, not {text!r}")
    return value


def _savgol_window(text: str) -> int:
    """An odd whole number of samples ≥ 5 (argparse type): the Savitzky–Golay window of order 4."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number, not {text!r}") from None
    if value < 5 or value % 2 == 0:
        raise argparse.ArgumentTypeError(f"the window must be odd and at least 5 samples, not {text!r}")
    return value


# --------------------------------------------------------------------------- analyses
#: the heading a turn fit needs: the current separates from the circle only over a full turn (with
#: less, bench figures: 240° of steady turn leaves a 6 mm/s current error, 420° 3.5 mm/s)
MIN_TURN_SWEEP = 2 * math.pi
#: above this condition number of H the straight legs do not separate the current from the velocity
MAX_SQUARES_CONDITION = 1e3
#: above this scaled condition number the inertia regressors (velocity, 1, t) are collinear
MAX_INERTIA_CONDITION = 1e6


def _window(nav: NavLog, t_start: float | None, t_end: float | None) -> NavLog:
    if t_start is None and t_end is None:
        return nav  # the whole log: no copy
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
    check_navigation_units(nav)
    if cut:
        mask = steady_straight_mask(nav.t, nav.yaw, nav.vel_body, rate_tol, speed_tol)
        if mask.sum() < 10:
            raise ValueError("no steady straight leg found (try --no-cut or a larger --rate-tol-deg)")
    else:
        mask = np.ones(len(nav), bool)
    fit = fit_straight_legs(nav.roll, nav.pitch, nav.yaw, nav.vel_body, mask=mask)  # selects block by block
    if not fit.condition_number <= MAX_SQUARES_CONDITION:
        raise ValueError(f"the legs' headings do not separate the current from the vehicle's velocity (cond(H) "
                         f"{fit.condition_number:.3g} > {MAX_SQUARES_CONDITION:g}): fly legs on at least two headings, "
                         "ideally a square")
    result = {**fit.as_dict(), "samples_used": int(mask.sum()), "samples_total": len(nav)}
    return result, mask


def analyze_turns(nav: NavLog, cut: bool = True, rate_tol: float = math.radians(0.3)):
    """Steady-turn LS (eq. 9–10) on a log; returns (result dict, mask, TurnFit)."""
    if len(nav) < 20:
        raise ValueError(f"too few samples ({len(nav)})")
    check_navigation_units(nav)
    mask = steady_turn_mask(nav.t, nav.yaw, rate_tol) if cut else np.ones(len(nav), bool)
    if mask.sum() < 20:
        raise ValueError("the turn never settles to a steady rate (try --no-cut or a larger --rate-tol-deg)")
    _require_turning(nav.yaw[mask])
    _require_track_follows_heading(nav.t[mask], nav.north[mask], nav.east[mask], nav.yaw[mask])
    fit = fit_steady_turn(nav.t[mask], nav.north[mask], nav.east[mask], nav.yaw[mask])
    if not abs(fit.rate) * fit.radius <= MAX_SPEED:
        raise ValueError(f"the fitted turn (R {fit.radius:.4g} m at {math.degrees(fit.rate):.3g}°/s) moves at "
                         f"{abs(fit.rate) * fit.radius:.3g} m/s, beyond {MAX_SPEED:g} m/s: not a turn of this vehicle")
    result = {**fit.as_dict(), "samples_used": int(mask.sum()), "samples_total": len(nav)}
    return result, mask, fit


def _require_turning(yaw: np.ndarray) -> None:
    """ValueError unless the steady part of the log turns through :data:`MIN_TURN_SWEEP` (a near-straight
    run would otherwise be fitted as a turn kilometres wide)."""
    heading = np.unwrap(yaw)
    sweep = float(abs(heading[-1] - heading[0]))
    if sweep < MIN_TURN_SWEEP:
        raise ValueError(f"the steady part of the log turns through {math.degrees(sweep):.0f}°, less than the "
                         f"{math.degrees(MIN_TURN_SWEEP):.0f}° a turn fit needs to separate the current from the "
                         "circle: record at least one full steady turn")


def _require_track_follows_heading(t: np.ndarray, north: np.ndarray, east: np.ndarray, yaw: np.ndarray,
                                   chord_s: float = 2.0) -> None:
    """ValueError unless the track (course over ground from position chords ``chord_s`` apart) turns
    through the same angle as the heading, within a factor 2 and in the same direction: a yaw in
    degrees turns 57× too far, a yaw counted anticlockwise (ENU) turns the other way."""
    picks = np.unique(np.append(np.searchsorted(t, np.arange(t[0], t[-1], chord_s)), t.size - 1))
    if picks.size < 3:
        return
    course = np.unwrap(np.arctan2(np.diff(east[picks]), np.diff(north[picks])))
    heading = np.unwrap(yaw)[picks]
    track_sweep, heading_sweep = float(course[-1] - course[0]), float(heading[-1] - heading[0])
    ratio = heading_sweep / track_sweep if track_sweep else math.inf
    if not 0.5 <= ratio <= 2.0:
        why = ("yaw must increase clockwise from north (NED)" if ratio < 0
               else "is yaw in degrees (convert to radians)?")
        raise ValueError(f"the heading turns through {math.degrees(heading_sweep):.0f}° while the track turns through "
                         f"{math.degrees(track_sweep):.0f}°: {why}")


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


def _check_mapping(table: dict[str, np.ndarray], path: str) -> None:
    """The ``mapping`` column names a mapping: 0 (reference) or 1 (the one whose η is identified), nothing else."""
    mapping = table["mapping"]
    bad = np.flatnonzero((mapping != 0) & (mapping != 1))
    if bad.size:
        raise LogError(f"{path}: mapping {mapping[bad[0]]:g} in data row {bad[0] + 1}: the mapping column must be "
                       "0 (reference) or 1 (the mapping whose efficiency η is identified)")


def analyze_eta(path: str, axis: str | None = None, settle: float = 0.3) -> dict:
    table = read_table_csv(path)
    if "mapping" in table:
        _check_mapping(table, path)
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
    condition = fit.extra.get("scaled_condition_number", 0.0)
    if not condition <= MAX_INERTIA_CONDITION:
        raise ValueError(f"the velocity hardly varies, so the inertia cannot be told from the drag and bias "
                         f"(scaled cond(H) {condition:.3g}): excite with a varying force, e.g. a sine (eq. 4.40)")
    if not fit.mass > 0:
        raise ValueError(f"the estimated inertia is not positive ({fit.mass:.4g} ± {fit.mass_sigma:.2g}): the data do "
                         "not determine it (check --k, --kq, the force sign and the position column)")
    mean_speed = float(np.mean(np.gradient(position, table["t"])))
    out = fit.as_dict()
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


#: why a number of each analysis can be non-finite (it is then null in JSON, with this reason)
NULL_REASONS = {
    "squares": "not determined by the data (singular covariance)",
    "turns": "not determined by the data (singular covariance of the turn fit)",
    "eta": "not determined by the data (an estimate of zero, or a singular covariance)",
    "inertia": "not determined by the data (singular covariance or no degrees of freedom)",
}


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
    reasons = null_reasons(result, NULL_REASONS[kind])
    if reasons:  # an estimate the data leave undetermined is null in JSON, with the reason beside it
        result["null_reasons"] = reasons
    if args.json:
        print_json(result)
    else:
        _print_human(kind, result)
        if args.plot:
            print(f"figure written to {args.plot}")
    return 0
