"""The figures of the behaviours' stored results in a campaign's report (``companion.records.report``):
each behaviour's registry entry (``companion.procedures.registry``) names its plot here."""
from __future__ import annotations

import math
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from companion.records.report import _figure  # noqa: E402

def plot_min_speed(result: dict, path: Path) -> str | None:
    series = result.get("series") or {}
    if not series.get("time"):
        return None

    def draw():
        t = np.asarray(series["time"]) - series["time"][0]
        panels = [("thrust_ratio", "thrust ratio", result.get("thrust_ratio_star")), ("speed", "speed (m/s)", result.get("v_min")),
                  ("pitch", "pitch (deg)", None), ("elevator", "elevator (deg)", None), ("depth", "depth (m)", None)]
        panels = [p for p in panels if series.get(p[0])]
        for i, (key, label, mark) in enumerate(panels):
            ax = plt.subplot(len(panels), 1, i + 1)
            values = np.asarray(series[key], dtype=float)
            if key in ("pitch", "elevator"):
                values = np.degrees(values)
            ax.plot(t, values)
            if mark:
                ax.axhline(mark, color="r", ls="--", lw=0.8, label="analytic")
                ax.legend(fontsize=7)
            ax.set_ylabel(label)
            ax.grid(True, alpha=0.3)
        ax.set_xlabel("time (s)")
        plt.suptitle("Minimum-speed seeking (Fig. 5.22); red: analytic TR* and Vmin")

    return _figure(path, draw, (9, 9))


def plot_roll(result: dict, path: Path) -> str | None:
    open_loop, closed_loop = result.get("open_series"), result.get("closed_series") or result.get("series")
    if not (closed_loop and closed_loop.get("time")):
        return None

    def draw():
        for i, (name, series) in enumerate((("open loop", open_loop), ("closed loop", closed_loop))):
            if not series or not series.get("time"):
                continue
            t = np.asarray(series["time"]) - series["time"][0]
            plt.subplot(2, 1, 1)
            plt.plot(t, np.degrees(series["roll"]), label=name)
            if series.get("mass_angle"):
                plt.subplot(2, 1, 2)
                plt.plot(t, np.degrees(series["mass_angle"]), label=name)
        plt.subplot(2, 1, 1)
        plt.ylabel("roll (deg)")
        plt.title(f"Roll, open vs closed loop (Fig. 4.8): σ {result.get('std_open_deg', math.nan):.2f}° → "
                  f"{result.get('std_closed_deg', math.nan):.2f}°")
        plt.legend()
        plt.grid(True, alpha=0.3)
        plt.subplot(2, 1, 2)
        plt.ylabel("mass angle (deg)")
        plt.xlabel("time (s)")
        plt.grid(True, alpha=0.3)

    return _figure(path, draw, (9, 6))


def plot_steady_state(result: dict, path: Path) -> str | None:
    """Squares: measured path and the fitted current; turns: measured path, fitted path (eq. 9) and
    the water-relative circle without current (Hegrenæs et al., Fig. 6–7)."""
    squares, turns = result.get("squares") or {}, result.get("turns") or {}
    paths = turns.get("paths") or []
    if not (squares.get("path", {}).get("t") or paths):
        return None

    def draw():
        ax = plt.subplot(1, 2, 1)
        sq = squares.get("path") or {}
        if sq.get("t"):
            ax.plot(sq["east"], sq["north"], ".", ms=2, label="measured (1 Hz)")
            if "current_north" in squares:
                e0, n0 = np.mean(sq["east"]), np.mean(sq["north"])
                scale = 0.25 * (max(sq["north"]) - min(sq["north"]) + 1.0) / max(squares["current_speed"], 1e-6)
                ax.annotate("", xy=(e0 + scale * squares["current_east"], n0 + scale * squares["current_north"]),
                            xytext=(e0, n0), arrowprops={"arrowstyle": "->", "color": "r", "lw": 2})
                ax.plot([], [], "r-", label=f"current {1000 * squares['current_speed']:.1f} mm/s "
                                            f"towards {squares['current_dir_deg']:.0f}°")
            ax.set_title(f"Square pattern: surge {squares.get('surge_water', math.nan):.3f} m/s, "
                         f"cond(H) {squares.get('condition_number', math.nan):.2f}", fontsize=9)
        ax.set_xlabel("east (m)")
        ax.set_ylabel("north (m)")
        ax.axis("equal")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)
        ax = plt.subplot(1, 2, 2)
        for turn, measured in zip(turns.get("turns", []), paths):
            if not measured.get("t"):
                continue
            line, = ax.plot(measured["east"], measured["north"], ".", ms=2,
                            label=f"rudder {turn.get('rudder_deg', math.nan):+.1f}° measured")
            if "radius_m" not in turn:
                continue
            t = np.asarray(measured["t"]) - turn["t0"]
            angle = math.radians(turn["turn_rate_deg_s"]) * t - turn["phase_rad"]
            circle = turn["radius_m"] * np.column_stack([np.cos(angle), np.sin(angle)])
            drift = np.outer(t, [turn["current_north"], turn["current_east"]])
            center = np.array([turn["center_north"], turn["center_east"]])
            fitted = center + drift + circle
            still = center + circle
            ax.plot(fitted[:, 1], fitted[:, 0], "-", color=line.get_color(), lw=0.8,
                    label=f"fit R {turn['radius_m']:.2f} m, σ {turn['residual_std_m']:.2f} m")
            ax.plot(still[:, 1], still[:, 0], ":", color=line.get_color(), lw=0.8)
        ax.set_title("Steady turns: measured, fitted (—), circle without current (···)", fontsize=9)
        ax.set_xlabel("east (m)")
        ax.axis("equal")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize=7)

    return _figure(path, draw, (12, 5.5))
