"""The sweep report: one HTML page with PNG figures beside it (matplotlib, Agg), from the sweep's rows.

* ``sweep_overview.png`` — the distributions over the cases: identification error (a22, b2; the
  worst thrust of each case against the simulator's linearised truth), validation R² (the lowest
  of each case), heading-step overshoot with the scheduled gains against one constant gain,
  minimum-speed seeking (settling time against the final thrust ratio, beside the analytic TR*),
  the roll-σ reduction (open loop over closed loop), and the failure rate by reason (the
  rehearsal's own reason, numbers and names taken out so like failures group; behaviours that
  failed after a completed campaign are counted under their own name);
* a table per varied input (preset, seed, current, noise, perturbations, thrusts): how many cases,
  how many failed, and the median figures;
* the worst cases of each figure and every failed case (up to a limit), each with the ``companion
  rehearse`` command that reproduces it alone.
"""
from __future__ import annotations

import html
import json
import logging
import math
import statistics
from collections import Counter, defaultdict
from collections.abc import Sequence
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from companion.procedures.registry import PROCEDURES  # noqa: E402

log = logging.getLogger(__name__)

#: (column, title, larger is worse) of the worst-case tables
WORST = (
    ("a22_error_max_pct", "a22 identification error (%)", True),
    ("b2_error_max_pct", "b2 identification error (%)", True),
    ("r2_min", "validation R² (lowest)", False),
    ("overshoot_scheduled_max_pct", "overshoot, scheduled gains (%)", True),
    ("min_speed_tr_error_pct", "minimum speed: final TR off TR* (%)", True),
    ("min_speed_settle_s", "minimum speed: settling time (s)", True),
    ("roll_sigma_reduction", "roll σ reduction (open/closed)", False),
)
#: the inputs a breakdown table may group by (those with more than one value in the sweep)
GROUP_BY = ("preset", "seed", "current", "noise", "perturb", "thrusts", "axes", "behaviors")


def _values(rows: Sequence[dict], column: str) -> list[float]:
    return [float(r[column]) for r in rows if isinstance(r.get(column), (int, float))
            and not isinstance(r.get(column), bool) and math.isfinite(r[column])]


def failure_counts(rows: Sequence[dict]) -> Counter:
    """Failures by reason: cases that did not complete (by their failure kind), and behaviours that
    failed or aborted after a completed campaign (by behaviour)."""
    counts: Counter = Counter()
    for row in rows:
        if row.get("status") != "completed":
            counts[f"{row.get('status')}: {row.get('failure') or 'no reason given'}"] += 1
            continue
        for spec in PROCEDURES.values():  # each procedure's row holds its outcome as <name>_status
            column = f"{spec.name}_status"
            if row.get(column) not in (None, "completed"):
                counts[f"{spec.cli_name} {row[column]} (campaign completed)"] += 1
    return counts


def _no_data(ax, title: str) -> None:
    ax.set_title(title, fontsize=10)
    ax.text(0.5, 0.5, "no data in this sweep", ha="center", va="center", transform=ax.transAxes, color="0.5")
    ax.set_xticks([])
    ax.set_yticks([])


def _hist(ax, series: dict[str, list[float]], title: str, xlabel: str) -> None:
    present = {label: values for label, values in series.items() if values}
    if not present:
        _no_data(ax, title)
        return
    allv = [v for values in present.values() for v in values]
    lo, hi = min(allv), max(allv)
    bins = 20 if hi > lo else 1
    for label, values in present.items():
        median = statistics.median(values)
        ax.hist(values, bins=bins, range=(lo, hi) if hi > lo else None, alpha=0.6,
                label=f"{label} (n {len(values)}, median {median:.3g})")
    ax.set_title(title, fontsize=10)
    ax.set_xlabel(xlabel)
    ax.set_ylabel("cases")
    ax.legend(fontsize=7)
    ax.grid(True, alpha=0.3)


def plot_overview(rows: Sequence[dict], path: Path, title: str = "") -> str | None:
    """The main figure (module docstring); returns the file name, None when it could not be drawn."""
    fig, axes = plt.subplots(2, 3, figsize=(15, 8.5))
    try:
        _hist(axes[0, 0], {"a22": _values(rows, "a22_error_max_pct"), "b2": _values(rows, "b2_error_max_pct")},
              "Identification error (worst thrust per case)", "|error| vs linearised truth (%)")
        _hist(axes[0, 1], {"R² (lowest per case)": _values(rows, "r2_min")}, "Validation R²", "R²")
        _hist(axes[0, 2], {"scheduled gains": _values(rows, "overshoot_scheduled_max_pct"),
                           "one constant gain": _values(rows, "overshoot_constant_max_pct")},
              "±20° heading steps: max overshoot per case", "overshoot (%)")
        ax = axes[1, 0]
        pairs = [(r["min_speed_settle_s"], r["min_speed_tr_final"]) for r in rows
                 if isinstance(r.get("min_speed_settle_s"), (int, float))
                 and isinstance(r.get("min_speed_tr_final"), (int, float))]
        unsettled = [r["min_speed_tr_final"] for r in rows if isinstance(r.get("min_speed_tr_final"), (int, float))
                     and not isinstance(r.get("min_speed_settle_s"), (int, float))]
        if pairs or unsettled:
            if pairs:
                ax.scatter([p[0] for p in pairs], [p[1] for p in pairs], s=18, label=f"settled (n {len(pairs)})")
            if unsettled:
                ax.scatter([0.0] * len(unsettled), unsettled, marker="x", color="C3",
                           label=f"never settled (n {len(unsettled)}, at x = 0)")
            stars = _values(rows, "min_speed_tr_star")
            if stars:
                ax.axhline(statistics.median(stars), color="k", lw=1, ls="--", label="analytic TR* (median)")
            ax.set_title("Minimum-speed seeking", fontsize=10)
            ax.set_xlabel("settling time (s)")
            ax.set_ylabel("final thrust ratio")
            ax.legend(fontsize=7)
            ax.grid(True, alpha=0.3)
        else:
            _no_data(ax, "Minimum-speed seeking")
        _hist(axes[1, 1], {"σ open / σ closed": _values(rows, "roll_sigma_reduction")},
              "Roll stabilisation: σ reduction", "σ open loop / σ closed loop")
        ax = axes[1, 2]
        counts = failure_counts(rows)
        if rows and not counts:
            ax.set_title("Failure rate by reason", fontsize=10)
            ax.text(0.5, 0.5, f"no failure in {len(rows)} cases", ha="center", va="center", transform=ax.transAxes)
            ax.set_xticks([])
            ax.set_yticks([])
        elif rows:
            labels = [label for label, _ in counts.most_common(8)]
            rates = [100.0 * counts[label] / len(rows) for label in labels]
            ax.barh(range(len(labels)), rates, color="C3")
            ax.set_yticks(range(len(labels)), [label if len(label) < 48 else label[:45] + "…" for label in labels],
                        fontsize=7)
            ax.invert_yaxis()
            ax.set_xlabel(f"% of {len(rows)} cases")
            ax.set_title("Failure rate by reason", fontsize=10)
            ax.grid(True, axis="x", alpha=0.3)
        else:
            _no_data(ax, "Failure rate by reason")
        if title:
            fig.suptitle(title)
        fig.tight_layout()
        fig.savefig(path, dpi=90)
        return path.name
    except Exception as exc:  # noqa: BLE001 - a report without its figure beats no report
        log.warning("sweep figure %s failed: %s", path.name, exc)
        return None
    finally:
        plt.close(fig)


def _fmt(value) -> str:
    if value is None or value == "":
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, float):
        return f"{value:.4g}"
    return str(value)


def _group_value(row: dict, key: str) -> str:
    if key == "current":
        return f"{row.get('current_north', 0):g}, {row.get('current_east', 0):g} m/s"
    value = row.get(key)
    return "none" if value in ("", None) else str(value)


def _median_text(rows: Sequence[dict], column: str) -> str:
    values = _values(rows, column)
    return f"{statistics.median(values):.3g}" if values else "–"


def breakdown_tables(rows: Sequence[dict]) -> list[str]:
    """HTML tables: for each input with more than one value, cases, failures and median figures per value."""
    parts = []
    for key in GROUP_BY:
        groups: dict[str, list[dict]] = defaultdict(list)
        for row in rows:
            groups[_group_value(row, key)].append(row)
        if len(groups) < 2:
            continue
        head = ("<tr><th>" + html.escape(key) + "</th><th>cases</th><th>not completed</th><th>a22 error %</th>"
                "<th>b2 error %</th><th>R² min</th><th>overshoot sched. %</th><th>overshoot const. %</th>"
                "<th>TR final</th><th>roll σ ratio</th></tr>")
        body = []
        for value, members in groups.items():
            failed = sum(1 for r in members if r.get("status") != "completed")
            body.append("<tr>" + "".join(f"<td>{html.escape(cell)}</td>" for cell in (
                value, str(len(members)), f"{failed} ({100.0 * failed / len(members):.0f} %)",
                _median_text(members, "a22_error_max_pct"), _median_text(members, "b2_error_max_pct"),
                _median_text(members, "r2_min"), _median_text(members, "overshoot_scheduled_max_pct"),
                _median_text(members, "overshoot_constant_max_pct"), _median_text(members, "min_speed_tr_final"),
                _median_text(members, "roll_sigma_reduction"))) + "</tr>")
        parts.append(f"<h3>By {html.escape(key)} (medians)</h3><table>{head}{''.join(body)}</table>")
    return parts


def _case_label(row: dict) -> str:
    bits = [f"{row.get('preset')}", f"seed {row.get('seed')}",
            f"current {row.get('current_north', 0):g},{row.get('current_east', 0):g}"]
    if row.get("noise") not in (None, 1, 1.0):
        bits.append(f"noise ×{row['noise']:g}")
    if row.get("perturb"):
        bits.append(str(row["perturb"]))
    return ", ".join(bits)


def worst_cases(rows: Sequence[dict], per_figure: int = 3, failures: int = 20) -> list[tuple[str, list[tuple]]]:
    """[(title, [(row, value text), …]), …]: every failed case (up to ``failures``) and the worst
    ``per_figure`` cases of each figure."""
    out = []
    failed = [r for r in rows if r.get("status") != "completed"]
    if failed:
        out.append(("Cases that did not complete", [(r, r.get("reason") or r.get("status")) for r in failed[:failures]]))
    for column, title, larger_worse in WORST:
        scored = [(float(r[column]), r) for r in rows if isinstance(r.get(column), (int, float))
                  and not isinstance(r.get(column), bool) and math.isfinite(r[column])]
        if not scored:
            continue
        scored.sort(key=lambda item: item[0], reverse=larger_worse)
        out.append((title, [(r, f"{value:.4g}") for value, r in scored[:per_figure]]))
    return out


def write_sweep_report(rows: Sequence[dict], out_dir: str | Path, *, name: str = "sweep", spec: dict | None = None,
                       outcome: dict | None = None, csv_name: str | None = None) -> Path:
    """Write ``report.html`` and ``sweep_overview.png`` into ``out_dir``; returns the HTML path."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    rows = list(rows)
    completed = sum(1 for r in rows if r.get("status") == "completed")
    title = f"Sweep {name}: {len(rows)} cases, {completed} completed"
    image = plot_overview(rows, out / "sweep_overview.png", title)
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>" + html.escape(title) + "</title>",
        ("<style>body{font-family:sans-serif;max-width:1250px;margin:2em auto}table{border-collapse:collapse;"
         "margin:.5em 0 1.5em}td,th{border:1px solid #ccc;padding:2px 6px;font-size:90%;text-align:left}"
         "code{font-size:85%;background:#f4f4f4;padding:1px 3px}</style></head><body>"),
        f"<h1>{html.escape(title)}</h1>",
    ]
    counts = failure_counts(rows)
    parts.append("<p>" + ", ".join(f"{html.escape(status)}: {n}" for status, n in
                                   sorted(Counter(r["status"] for r in rows).items())) + "."
                 + (f" Rows: <a href='{html.escape(csv_name)}'>{html.escape(csv_name)}</a>." if csv_name else "")
                 + " Figures: the simulator's linearised truth is the reference for identification errors;"
                   " every case is reproducible alone with the command shown.</p>")
    if image:
        parts.append(f"<img src='{image}' alt='sweep overview' style='max-width:100%'>")
    if counts:
        parts.append("<h2>Failures by reason</h2><table><tr><th>reason</th><th>cases</th><th>rate</th></tr>"
                     + "".join(f"<tr><td>{html.escape(label)}</td><td>{n}</td><td>{100.0 * n / len(rows):.1f} %</td></tr>"
                               for label, n in counts.most_common()) + "</table>")
    tables = breakdown_tables(rows)
    if tables:
        parts += ["<h2>By input</h2>", *tables]
    worst = worst_cases(rows)
    if worst:
        parts.append("<h2>Worst cases, each with the command that reproduces it alone</h2>")
        for heading, items in worst:
            parts.append(f"<h3>{html.escape(heading)}</h3><table><tr><th>value</th><th>case</th><th>command</th></tr>")
            for row, value in items:
                parts.append(f"<tr><td>{html.escape(str(value))}</td><td>{html.escape(_case_label(row))}</td>"
                             f"<td><code>{html.escape(str(row.get('command') or ''))}</code></td></tr>")
            parts.append("</table>")
    if spec:
        parts += ["<h2>Specification</h2>", "<pre>" + html.escape(json.dumps(spec, indent=1)) + "</pre>"]
    if outcome:
        parts += ["<h2>This run</h2>", "<pre>" + html.escape(json.dumps(outcome, indent=1)) + "</pre>"]
    parts.append("</body></html>")
    path = out / "report.html"
    path.write_text("\n".join(parts), encoding="utf-8")
    return path
