"""Campaign report: one HTML page with PNG plots (matplotlib, Agg), built from the store (SPEC C10).

Plots (each skipped when its data is absent): parameter convergence (thesis Fig. 3.7), validation
overlays with R² (Fig. 3.9), b2 against u² with the fitted law (Fig. 3.8), turning radius / rate /
U-turn time against speed (Fig. 3.13), heading steps with the original, one constant and the
scheduled gains (Fig. 3.16), thrust and speed during minimum-speed seeking (Fig. 5.22), roll
open against closed loop (Fig. 4.8) and, for a ``companion run`` session, the drift of the passive
estimates with their CUSUM. Regenerate any time with ``companion results --report``.
"""
from __future__ import annotations

import html
import json
import logging
import math
import textwrap
from pathlib import Path
from typing import Callable, Mapping

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from companion.numerics.turning import turning_performance  # noqa: E402
from companion.records.report_section import ReportSection
from companion.records.serialise import RECORD_TYPES, from_json, to_json
from companion.records.store import Store  # noqa: E402

log = logging.getLogger(__name__)


def _figure(path: Path, draw: Callable[[], None], size=(9, 5)) -> str | None:
    """Draw with ``draw`` into a new figure and save it; a plot that fails is logged, not fatal."""
    fig = plt.figure(figsize=size)
    try:
        draw()
        fig.tight_layout()
        fig.savefig(path, dpi=90)
        return path.name
    except Exception as exc:  # noqa: BLE001 - a report with one missing plot beats no report
        log.warning("plot %s failed: %s", path.name, exc)
        return None
    finally:
        plt.close(fig)


def _run_label(run: dict) -> str:
    """"T 60%" for a campaign run; a run from a log without thrust is named by its speed."""
    thrust = run.get("thrust")
    if isinstance(thrust, (int, float)):
        return f"T {thrust * 100:.0f}%"
    speed = run.get("speed")
    return f"#{run.get('attempt')} u {speed:.2f} m/s" if isinstance(speed, (int, float)) else f"#{run.get('attempt')}"


def _by_thrust(runs: list[dict], axis: str) -> list[dict]:
    return sorted((r for r in runs if r["axis"] == axis), key=lambda r: (r["thrust"] or 0, r["attempt"]))


def plot_convergence(runs: list[dict], path: Path) -> str | None:
    accepted = [r for r in _by_thrust(runs, "yaw") if r["accepted"] and r.get("series", {}).get("training")]
    if not accepted:
        return None

    def draw():
        # the RLS estimates Θ = [a22, b2, C0] (thesis Fig. 3.5/3.7); δ0 = C0/b2 is meaningless
        # while b2 is still ≈ 0 before the doublet, so C0 is what is plotted
        names = ("a22", "b2", "C0")
        for row, name in enumerate(names):
            ax = plt.subplot(len(names), 1, row + 1)
            for run in accepted:
                history = run["series"]["training"].get("history") or {}
                if not history.get("a22"):
                    continue
                values = (np.asarray(history["delta0"]) * np.asarray(history["b2"]) if name == "C0"
                          else history[name])
                ax.plot(history["time_s"], values, label=_run_label(run))
                if run.get("converged_s"):
                    ax.axvline(run["converged_s"], color="0.8", lw=0.8)
            ax.set_ylabel(name)
            ax.grid(True, alpha=0.3)
            if row == 0:
                ax.set_title("Online estimates during training (Fig. 3.7); grey: convergence")
                ax.legend(fontsize=7, ncol=5)
        ax.set_xlabel("time since training start (s)")

    return _figure(path, draw, (9, 7))


def plot_validation(runs: list[dict], path: Path) -> str | None:
    accepted = [r for r in _by_thrust(runs, "yaw") if r["accepted"] and r.get("series", {}).get("validation")]
    if not accepted:
        return None

    def draw():
        n = len(accepted)
        for i, run in enumerate(accepted):
            ax = plt.subplot(n, 1, i + 1)
            val = run["series"]["validation"]
            t = np.asarray(val["time"]) - val["time"][0]
            measured = np.degrees(np.unwrap(np.asarray(val["signal"], dtype=float)))
            ax.plot(t, measured, label="measured")
            if val.get("simulated"):
                ax.plot(t, np.degrees(val["simulated"]), "--", label="model")
            ax.set_ylabel("heading (deg)")
            ax.set_title(f"{_run_label(run)}  u {run['speed']:.2f} m/s  R² {run['r2']:.3f}", fontsize=9)
            ax.grid(True, alpha=0.3)
            if i == 0:
                ax.legend(fontsize=7)
        ax.set_xlabel("time (s)")

    return _figure(path, draw, (9, 2.2 * len(accepted) + 1))


def plot_b2_law(runs: list[dict], schedule, truth: dict | None, path: Path) -> str | None:
    accepted = [r for r in _by_thrust(runs, "yaw") if r["accepted"]]
    if not accepted:
        return None

    def draw():  # against u: the chosen law (u² + c or u + c, eq. S.3) drawn as written
        u = np.array([r["speed"] for r in accepted])
        b2 = np.array([r["model"]["b2"] for r in accepted])
        plt.plot(u, b2, "o", label="identified")
        if schedule is not None:  # the law as written: clamped outside the identified range
            grid = np.linspace(0.05, max(u) * 1.15, 50)
            power = "u" if getattr(schedule, "b2_law", "u2") == "u" else "u²"
            plt.plot(grid, [schedule.b2_at(g) for g in grid], "-",
                     label=f"schedule b2 = {schedule.b2_slope:.3f}·{power} + {schedule.b2_intercept:.3f} (clamped)")
        if truth:
            pts = sorted(truth.values(), key=lambda t: t["speed"])
            plt.plot([t["speed"] for t in pts], [t["b2"] for t in pts], "x", label="simulator truth")
        plt.xlabel("u (m/s)")
        plt.ylabel("b2 (s⁻²)")
        reason = getattr(schedule, "b2_law_reason", "") if schedule is not None else ""
        wrapped = "\n".join(textwrap.wrap(reason, 100)[:3])
        plt.title("Steering authority against speed (Fig. 3.8)" + (f"\n{wrapped}" if reason else ""), fontsize=8)
        plt.grid(True, alpha=0.3)
        plt.legend()

    return _figure(path, draw, (7, 5))


def plot_turning(design, delta_max: float, path: Path) -> str | None:
    if design is None:
        return None
    speeds = [point.speed for point in design.points]
    grid = np.linspace(max(0.3, min(speeds) * 0.7), max(speeds) * 1.2, 40)

    def draw():  # the schedule's own model at each speed (a22 trend and clamping included)
        perf = [turning_performance(design.schedule.model_at(u), u, delta_max) for u in grid]
        for i, (attr, label) in enumerate((("turning_radius_m", "turning radius (m)"),
                                           ("yaw_rate_max_deg_s", "max yaw rate (deg/s)"),
                                           ("u_turn_time_s", "U-turn time (s)"))):
            ax = plt.subplot(1, 3, i + 1)
            ax.plot(grid, [getattr(p, attr) for p in perf])
            ax.set_xlabel("speed (m/s)")
            ax.set_ylabel(label)
            ax.grid(True, alpha=0.3)
        plt.suptitle(f"Turning performance from the fitted laws, δmax {delta_max:.2f} rad (Fig. 3.13)")

    return _figure(path, draw, (11, 4))


def plot_heading_steps(steps: list[dict], path: Path) -> str | None:
    if not steps:
        return None
    thrusts = sorted({s["thrust"] for s in steps})

    def draw():
        for i, thrust in enumerate(thrusts):
            ax = plt.subplot(len(thrusts), 1, i + 1)
            for s in (s for s in steps if s["thrust"] == thrust):
                series = s.get("series") or {}
                if not series.get("time"):
                    continue
                t = np.asarray(series["time"]) - series["time"][0]
                course = series["heading"][0]
                ax.plot(t, np.degrees(np.asarray(series["heading"]) - course),
                        label=f"{s['label']} (overshoot {s['max_overshoot_pct']:.1f}%)")
            ax.plot(t, np.degrees(np.asarray(series["target"]) - series["target"][0]), "k:", lw=0.8)
            ax.set_ylabel(f"T {thrust * 100:.0f}%\nΔψ (deg)")
            ax.legend(fontsize=7, loc="upper right")
            ax.grid(True, alpha=0.3)
        ax.set_xlabel("time (s)")
        size = next((x.get("step_deg") for s in steps for x in s.get("steps", []) if x.get("step_deg")), 20.0)
        plt.suptitle(f"±{abs(size):.0f}° heading steps: original, comparison and scheduled gains (Fig. 3.16)")

    return _figure(path, draw, (9, 2.2 * len(thrusts) + 1))


def plot_speed_loop(result: dict, path: Path) -> str | None:
    """The surge model on the settles it was fitted to (eq. S.4), and the speed steps with the
    original and the designed speed-loop gains (eq. S.5)."""
    record, surge = result.get("record") or {}, result.get("surge")
    steps = result.get("steps") or {}
    if not (record.get("time") or steps):
        return None

    def draw():
        ax = plt.subplot(1, 2, 1)
        t, u, thr = (np.asarray(record.get(k) or [], dtype=float) for k in ("time", "speed", "throttle"))
        if t.size:
            ax.plot(t, u, ".", ms=2, label="measured")
            if surge is not None:
                breaks = [0] + [k for k in range(1, t.size) if t[k] - t[k - 1] > 2.0] + [t.size]
                for n, (a, b) in enumerate(zip(breaks[:-1], breaks[1:])):
                    if b - a > 2:
                        ax.plot(t[a:b], surge.simulate(t[a:b], thr[a:b], u[a]), "r-", lw=1,
                                label="surge model" if n == 0 else None)
            ax.set_xlabel("time (s)")
            ax.set_ylabel("speed (m/s)")
            ax.set_title(surge.describe() if surge is not None else "straight settles", fontsize=8)
            ax.legend(fontsize=7)
            ax.grid(True, alpha=0.3)
        ax = plt.subplot(1, 2, 2)
        for label, flown in steps.items():
            series = flown.get("series") or {}
            if series.get("time"):
                times = np.asarray(series["time"]) - series["time"][0]
                ax.plot(times, series["speed"], label=f"{label} (overshoot {flown['max_overshoot_pct']:.1f}%)")
                ax.plot(times, series["demand"], "k:", lw=0.8)
        ax.set_xlabel("time (s)")
        ax.set_ylabel("speed (m/s)")
        ax.set_title("speed steps in GUIDED: original and designed speed loop", fontsize=8)
        ax.legend(fontsize=7)
        ax.grid(True, alpha=0.3)

    return _figure(path, draw, (12, 4.5))


def plot_health(result: dict, path: Path) -> str | None:
    """The drift of the passive estimates: a22 and b2 over their reference at the same
    speed per window (±σ, with the tolerance band), and the CUSUM statistics against the threshold."""
    windows = [w for w in result.get("windows") or [] if w.get("used")]
    if not windows:
        return None
    config = result.get("config") or {}

    def draw():
        t = np.array([w["t_end"] for w in windows])
        tolerance = config.get("tolerance", 0.0)
        ax = plt.subplot(2, 1, 1)
        for name, colour in (("a22", "C0"), ("b2", "C1")):
            ratio = np.array([w["ratio"][name] for w in windows])
            sigma = np.array([w[f"sigma_{name}"] / abs(w["reference"][name]) for w in windows])
            ax.errorbar(t, ratio, yerr=sigma, fmt="o-", ms=3, lw=0.8, color=colour, label=f"{name} / reference")
        ax.axhspan(1 - tolerance, 1 + tolerance, color="0.9", label=f"±{100 * tolerance:.0f} % tolerance")
        ax.set_ylabel("estimate / stored model")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, loc="lower left")
        alarm = result.get("alarm")
        title = "Passive estimates against the stored model at the same speed"
        if alarm:
            title += f": alarm at {alarm['time_s']:.0f} s ({alarm['parameter']} {alarm['change_pct']:+.0f} %)"
        ax.set_title(title, fontsize=9)
        ax = plt.subplot(2, 1, 2, sharex=ax)
        for name, colour in (("a22", "C0"), ("b2", "C1")):
            ax.step(t, [w["cusum"][name] for w in windows], where="post", color=colour, label=f"CUSUM {name}")
        if config.get("threshold"):
            ax.axhline(config["threshold"], color="r", ls="--", lw=0.8, label="threshold h")
        if alarm:
            for axis in plt.gcf().axes:
                axis.axvline(alarm["time_s"], color="r", lw=0.8)
        ax.set_ylabel("CUSUM (σ units)")
        ax.set_xlabel("vehicle time (s)")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7, loc="upper left")

    return _figure(path, draw, (9, 6))


def _table(rows: list[dict], columns: list[tuple[str, str, str]]) -> str:
    head = "".join(f"<th>{html.escape(title)}</th>" for _, title, _ in columns)
    body = []
    for row in rows:
        cells = []
        for key, _, fmt in columns:
            value = row.get(key)
            cells.append(f"<td>{format(value, fmt) if isinstance(value, (int, float)) and value is not None else html.escape(str(value if value is not None else '–'))}</td>")
        body.append("<tr>" + "".join(cells) + "</tr>")
    return f"<table><tr>{head}</tr>{''.join(body)}</table>"


def from_json_tree(value):
    """A stored result with its records typed again (``serialise.from_json`` on every tagged dict)."""
    if isinstance(value, dict):
        if value.get("type") in RECORD_TYPES:
            return from_json(value)
        return {k: from_json_tree(v) for k, v in value.items()}
    if isinstance(value, list):
        return [from_json_tree(v) for v in value]
    return value


def _speed_loop_html(result: dict) -> str:
    """The speed loop's surge model, design and steps beside the original gains, as text and a table."""
    surge, design = result.get("surge"), result.get("design")
    lines = [f"<p>{html.escape(str(result.get('reason') or result.get('verdict') or result.get('status')))}</p>"]
    if surge is not None:
        lines.append(f"<p>Surge model (eq. S.4): {html.escape(surge.describe())}, R² {surge.r2:.4f} over "
                     f"{surge.stretches} straight stretches.</p>")
    rows = []
    original = result.get("original") or {}
    designed = design.gains.params() if design is not None else {}
    for label, gains in (("original", original), ("design", designed)):
        flown = (result.get("steps") or {}).get(label) or {}
        predicted = design.predicted.get(label if label == "original" else "design", {}) if design is not None else {}
        rows.append({"gains": label, **gains, "predicted overshoot %": predicted.get("overshoot_pct"),
                     "flown overshoot %": flown.get("max_overshoot_pct"),
                     "flown settling s": flown.get("settling_time_s")})
    names = ["cruise_speed", "cruise_thrust", "speed_p", "speed_i"]
    lines.append(_table(rows, [("gains", "gains", "")] + [(n, n, ".3f") for n in names]
                        + [(k, k, ".1f") for k in ("predicted overshoot %", "flown overshoot %", "flown settling s")]))
    return "\n".join(lines)


def write_report(store: Store, campaign_id: int, out_dir: str | Path, *, truth: dict | None = None,
                 extra_results: dict | None = None, summary: dict | None = None, delta_max: float = 0.26,
                 sections: Mapping[str, ReportSection] | None = None) -> Path:
    """Write ``report.html`` and its PNGs into ``out_dir``; returns the HTML path.

    ``truth`` maps thrust (as a string) to the simulator's linearised {a22, b2, delta0, speed};
    ``extra_results`` maps a behaviour kind to its result dict; ``sections`` the behaviours' figures
    by kind (``companion.procedures.registry.report_sections``): a stored result of a kind there is
    drawn.
    """
    sections = dict(sections or {})
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    campaign = store.campaign(campaign_id)
    runs = store.runs(campaign_id, with_series=True)
    behaviour_rows = store.behavior_results(campaign_id)
    designs = {d.kind: d for d in store.designs(campaign_id)}  # typed, exactly as the campaign wrote them
    design = designs.get("heading") or designs.get("cascade")
    steps = [b["result"] for b in behaviour_rows if b["kind"] == "heading_steps"]
    extra = dict(extra_results or {})
    for row in behaviour_rows:
        if (row["kind"] in sections or row["kind"] == "health") and row["kind"] not in extra:
            extra[row["kind"]] = row["result"]
    speed_loop = next((from_json_tree(row["result"]) for row in behaviour_rows if row["kind"] == "speed_loop"), None)
    alarms = [row["result"] for row in behaviour_rows if row["kind"] == "health_alarm"]
    if "health" not in extra and alarms:  # a session that died after its alarm: the alarm's evidence
        extra["health"] = {**alarms[-1], "alarm": {k: alarms[-1].get(k) for k in ("parameter", "time_s", "change_pct")}}

    images = [
        ("Parameter convergence", plot_convergence(runs, out / "convergence.png")),
        ("Validation on fresh doublets", plot_validation(runs, out / "validation.png")),
        ("b2 against u²", plot_b2_law(runs, design.schedule if design else None, truth, out / "b2_law.png")),
        ("Turning performance", plot_turning(design, delta_max, out / "turning.png")),
        ("Heading steps", plot_heading_steps(steps, out / "heading_steps.png")),
        ("Speed loop: surge model and speed steps",
         plot_speed_loop(speed_loop, out / "speed_loop.png") if speed_loop else None),
        *[(section.title, section.plot(extra[kind], out / section.file)) for kind, section in sections.items()
          if kind in extra],
        ("Health: drift of the identified parameters",
         plot_health(extra["health"], out / "health.png") if "health" in extra else None),
    ]
    run_rows = [{"axis": r["axis"], "thrust": r["thrust"], "attempt": r["attempt"], "speed": r["speed"], "r2": r["r2"],
                 "accepted": "yes" if r["accepted"] else "no", "converged_s": r["converged_s"],
                 **{k: v for k, v in r["model"].items() if isinstance(v, (int, float))}} for r in runs]
    model_keys = sorted({k for row in run_rows for k in row} - {"axis", "thrust", "attempt", "speed", "r2", "accepted", "converged_s"})
    columns = [("axis", "axis", ""), ("thrust", "thrust", ".2f"), ("attempt", "try", "d"), ("speed", "speed m/s", ".3f"),
               ("r2", "R²", ".3f"), ("accepted", "accepted", ""), ("converged_s", "converged s", ".1f")] + \
              [(k, k, ".4f") for k in model_keys]
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>Identification campaign</title>",
        "<style>body{font-family:sans-serif;max-width:1100px;margin:2em auto}table{border-collapse:collapse;margin:1em 0}"
        "td,th{border:1px solid #ccc;padding:2px 8px;text-align:right}img{max-width:100%}pre{background:#f6f6f6;padding:1em}</style>",
        "</head><body>",
        f"<h1>Campaign {campaign_id}: {html.escape(campaign['vehicle'])} ({html.escape(str(campaign['profile']))})</h1>",
        f"<p>Status <b>{html.escape(campaign['status'])}</b>{(' — ' + html.escape(campaign['reason'])) if campaign.get('reason') else ''};"
        f" started {campaign['started_utc']}, finished {campaign.get('finished_utc') or '–'}.</p>",
        "<h2>Identification runs</h2>", _table(run_rows, columns),
    ]
    for kind, kind_design in designs.items():
        rows = [{"thrust": point.thrust, "speed": point.speed,
                 **{f"own {k}": v for k, v in point.own.items()}, **point.scheduled} for point in kind_design.points]
        gain_names = list(kind_design.points[0].scheduled) if kind_design.points else []
        own_names = [f"own {k}" for k in (kind_design.points[0].own if kind_design.points else {})]
        parts += [f"<h2>Gain design: {html.escape(kind)}</h2>",
                  f"<p class='schedule'>{html.escape(kind_design.schedule.describe())}.</p>",
                  _table(rows, [("thrust", "thrust", ".2f"), ("speed", "speed m/s", ".3f")]
                         + [(n, n, ".4f") for n in own_names] + [(n, f"scheduled {n}", ".4f") for n in gain_names]),
                  # the schedule shown, machine-readable: exactly the record the gains were computed from
                  f"<script type='application/json' id='schedule-{html.escape(kind)}'>"
                  f"{json.dumps(to_json(kind_design.schedule), allow_nan=False)}</script>"]
    if speed_loop:
        parts += ["<h2>Speed loop</h2>", _speed_loop_html(speed_loop)]
    gains = store.gains(campaign_id)
    if gains:
        parts += ["<h2>Gains written</h2>", "<pre>" + html.escape(json.dumps(gains, indent=1)) + "</pre>"]
    for title, image in images:
        if image:
            parts.append(f"<h2>{html.escape(title)}</h2><img src='{image}' alt='{html.escape(title)}'>")
    if summary:
        parts += ["<h2>Summary (JSON)</h2>", "<pre>" + html.escape(json.dumps(summary, indent=1)) + "</pre>"]
    parts.append("</body></html>")
    path = out / "report.html"
    path.write_text("\n".join(parts), encoding="utf-8")
    return path
