"""Usable segments of a recorded mission for yaw identification: steady speed with
actuator activity. Pure functions of arrays (no I/O).

The record is cut into candidate segments and each one gets a verdict, in this order:

1. **gap in the data** — an interval between samples longer than ``max_gap_s`` (or a sample with a
   missing value) splits the record; the gap itself is reported;
2. **speed not steady** — within each continuous piece, windows of ``window_s`` seconds (the last
   one takes the remainder when that is at least ``min_s``); a window is steady when its smoothed
   speed stays within ±``speed_tolerance`` (relative) of its median and the thrust (when logged)
   within ±``thrust_tolerance``. A window that is not is trimmed from its start (a speed settling
   after a thrust change) to its longest steady tail, if that is at least ``min_s`` long;
3. **actuator saturated** — more than ``saturation_fraction`` of the samples at the actuator's
   limit (``|δ| ≥ saturation_margin·limit``): the recorded output is then not what the fin did;
4. **too little excitation** — rudder standard deviation below ``min_rudder_std`` or heading span
   below ``min_heading_span_deg``: a straight leg identifies nothing (ordinary course changes are
   enough; no doublet is needed).

Each segment starts at the quietest sample (smallest heading rate) of its first ``quiet_search_s``
seconds: the identifier's filters start at rest (SPEC C3), which a vehicle in mid-turn is not.
The limit, when the log does not state it, is the largest |δ| of the record if the actuator sat
there for at least ``plateau_s`` (a clipped output shows as a plateau), else unknown.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np


@dataclass(frozen=True)
class SegmentRules:
    """Thresholds of the segment verdicts (see the module docstring)."""

    window_s: float = 60.0
    min_s: float = 30.0
    max_gap_s: float = 0.5
    speed_smoothing_s: float = 5.0
    speed_tolerance: float = 0.04
    thrust_tolerance: float = 0.02
    min_rudder_std: float = 0.01  # rad
    min_heading_span_deg: float = 5.0
    saturation_margin: float = 0.98
    saturation_fraction: float = 0.02
    plateau_s: float = 0.5
    quiet_search_s: float = 10.0


@dataclass
class Segment:
    """One candidate segment and its verdict; ``start``/``stop`` index the record (stop exclusive)."""

    start: int
    stop: int
    t_start: float
    t_end: float
    used: bool = False
    reason: str = ""
    speed: float = math.nan  # mean, m/s
    speed_spread: float = math.nan  # (max − min)/median of the smoothed speed
    thrust: float | None = None
    rudder_std: float = math.nan
    heading_span_deg: float = math.nan
    saturated_fraction: float = math.nan

    @property
    def duration_s(self) -> float:
        return self.t_end - self.t_start

    def summary(self) -> dict:
        out = asdict(self)
        out["duration_s"] = self.duration_s
        return out


def _smooth(t: np.ndarray, values: np.ndarray, seconds: float) -> np.ndarray:
    """Centred moving average over ``seconds`` (by sample count at the median interval)."""
    if values.size < 3:
        return values.copy()
    dt = float(np.median(np.diff(t)))
    n = max(1, int(round(seconds / dt)))
    if n <= 1 or n >= values.size:
        return values.copy()
    kernel = np.ones(n) / n
    padded = np.pad(values, (n // 2, n - 1 - n // 2), mode="edge")
    return np.convolve(padded, kernel, mode="valid")


def rudder_limit_from_plateau(t: np.ndarray, rudder: np.ndarray, plateau_s: float = 0.5) -> float | None:
    """The largest |δ| of the record when the actuator sat there for ≥ ``plateau_s`` (a clipped
    output), else None."""
    magnitude = np.abs(rudder)
    finite = np.isfinite(magnitude)
    if finite.sum() < 3:
        return None
    top = float(np.max(magnitude[finite]))
    if top <= 0.0:
        return None
    at_top = finite & (magnitude >= 0.995 * top)
    dt = float(np.median(np.diff(t)))
    longest = run = 0
    for flag in at_top:
        run = run + 1 if flag else 0
        longest = max(longest, run)
    return top if longest * dt >= plateau_s else None


def _pieces(t: np.ndarray, ok: np.ndarray, max_gap_s: float) -> tuple[list[tuple[int, int]], list[Segment]]:
    """Continuous pieces (start, stop) between gaps, and the gaps as rejected segments."""
    breaks = np.flatnonzero((np.diff(t) > max_gap_s) | ~ok[1:] | ~ok[:-1])
    pieces: list[tuple[int, int]] = []
    gaps: list[Segment] = []
    start = 0
    for b in breaks.tolist():
        if b + 1 - start > 1:
            pieces.append((start, b + 1))
        gap_end = b + 1
        while gap_end < t.size and not ok[gap_end]:
            gap_end += 1
        if gap_end < t.size and (t[gap_end] - t[b] > max_gap_s or not ok[b + 1]):
            if not gaps or gaps[-1].stop <= b:
                gaps.append(Segment(b, gap_end + 1, float(t[b]), float(t[gap_end]), reason=(
                    f"gap in the data: {t[gap_end] - t[b]:.1f} s without a complete sample")))
        start = max(b + 1, gap_end)
    if t.size - start > 1:
        pieces.append((start, t.size))
    return pieces, gaps


def find_segments(t, heading, rudder, speed, thrust=None, *, rudder_limit: float | None = None,
                  rules: SegmentRules = SegmentRules()) -> list[Segment]:
    """Candidate segments of a record, in time order, each with its verdict (module docstring).

    ``heading`` in rad (wrapped or not), ``rudder`` in rad, ``speed`` in m/s, ``thrust`` a ratio or
    None; NaN values count as missing data."""
    t = np.asarray(t, dtype=float)
    raw_heading = np.asarray(heading, dtype=float)
    heading = np.unwrap(np.nan_to_num(raw_heading))
    rudder = np.asarray(rudder, dtype=float)
    speed = np.asarray(speed, dtype=float)
    thrust = None if thrust is None else np.asarray(thrust, dtype=float)
    ok = np.isfinite(t) & np.isfinite(raw_heading) & np.isfinite(rudder) & np.isfinite(speed)
    if rudder_limit is None:
        rudder_limit = rudder_limit_from_plateau(t, rudder, rules.plateau_s)
    pieces, segments = _pieces(t, ok, rules.max_gap_s)
    for start, stop in pieces:
        smooth = _smooth(t[start:stop], speed[start:stop], rules.speed_smoothing_s)
        heading_rate = np.abs(np.gradient(_smooth(t[start:stop], heading[start:stop], 1.0), t[start:stop]))
        for a, b in _windows(t[start:stop], rules):
            segments.append(_judge(start + a, start + b, t, heading, rudder, speed, thrust, smooth[a:b],
                                   heading_rate, start, rudder_limit, rules))
    segments.sort(key=lambda s: s.t_start)
    return segments


def _windows(t: np.ndarray, rules: SegmentRules) -> list[tuple[int, int]]:
    """Consecutive windows of ``window_s`` over a piece; a remainder shorter than ``min_s`` joins the last."""
    bounds = [0]
    edge = t[0] + rules.window_s
    while True:
        index = int(np.searchsorted(t, edge))
        if index >= t.size or t[-1] - t[index] < rules.min_s:
            break
        bounds.append(index)
        edge = t[index] + rules.window_s
    bounds.append(t.size)
    return list(zip(bounds[:-1], bounds[1:]))


def _steady_tail(t: np.ndarray, smooth: np.ndarray, thrust: np.ndarray | None, tolerance: float,
                 thrust_tolerance: float) -> int:
    """Index of the earliest sample from which the window's tail is steady (speed within ±tolerance of
    the tail's median, thrust within ±thrust_tolerance); the last index when none."""
    reference = float(np.median(smooth[len(smooth) // 2:]))
    bad = np.abs(smooth - reference) > tolerance * max(abs(reference), 1e-6)
    if thrust is not None:
        bad |= np.abs(thrust - np.median(thrust[len(thrust) // 2:])) > thrust_tolerance
    where = np.flatnonzero(bad)
    return int(where[-1] + 1) if where.size else 0


def _judge(a: int, b: int, t, heading, rudder, speed, thrust, smooth, heading_rate, piece_start: int,
           limit: float | None, rules: SegmentRules) -> Segment:
    thrust_w = None if thrust is None else thrust[a:b]
    median = float(np.median(smooth))
    spread = float((np.max(smooth) - np.min(smooth)) / max(abs(median), 1e-6))
    thrust_range = 0.0 if thrust_w is None else float(np.nanmax(thrust_w) - np.nanmin(thrust_w))
    reason = ""
    if spread > 2 * rules.speed_tolerance or thrust_range > 2 * rules.thrust_tolerance:
        tail = _steady_tail(t[a:b], smooth, thrust_w, rules.speed_tolerance, rules.thrust_tolerance)
        if t[b - 1] - t[a + min(tail, b - a - 1)] >= rules.min_s:
            a += tail
            smooth = smooth[tail:]
            median = float(np.median(smooth))
            spread = float((np.max(smooth) - np.min(smooth)) / max(abs(median), 1e-6))
        else:
            reason = (f"speed not steady: {np.min(smooth):.2f}–{np.max(smooth):.2f} m/s "
                      f"({100 * spread:.0f} % > {200 * rules.speed_tolerance:.0f} %)"
                      + (f", thrust {np.nanmin(thrust_w):.2f}–{np.nanmax(thrust_w):.2f}"
                         if thrust_w is not None and thrust_range else ""))
    if not reason:  # start where the vehicle is quietest (the filters start at rest)
        search = np.flatnonzero(t[a:b] - t[a] <= rules.quiet_search_s)
        rates = heading_rate[a - piece_start: a - piece_start + search.size]
        a += int(np.argmin(rates)) if rates.size else 0
    segment = Segment(a, b, float(t[a]), float(t[b - 1]))
    segment.speed = float(np.mean(speed[a:b]))
    segment.speed_spread = spread
    if thrust is not None and np.isfinite(thrust[a:b]).any():
        segment.thrust = round(float(np.nanmedian(thrust[a:b])), 3)
    segment.rudder_std = float(np.std(rudder[a:b]))
    segment.heading_span_deg = float(np.degrees(np.max(heading[a:b]) - np.min(heading[a:b])))
    segment.saturated_fraction = (float(np.mean(np.abs(rudder[a:b]) >= rules.saturation_margin * limit))
                                  if limit else 0.0)
    if not reason and segment.duration_s < rules.min_s:
        reason = f"too short: {segment.duration_s:.0f} s < {rules.min_s:.0f} s"
    if not reason and segment.saturated_fraction > rules.saturation_fraction:
        reason = (f"actuator saturated: {100 * segment.saturated_fraction:.1f} % of the samples at the "
                  f"±{limit:.3f} rad limit (> {100 * rules.saturation_fraction:.0f} %)")
    if not reason and (segment.rudder_std < rules.min_rudder_std
                       or segment.heading_span_deg < rules.min_heading_span_deg):
        reason = (f"too little excitation: rudder σ {segment.rudder_std:.4f} rad (min {rules.min_rudder_std:g}), "
                  f"heading span {segment.heading_span_deg:.1f}° (min {rules.min_heading_span_deg:g}°)")
    segment.used = not reason
    segment.reason = reason or (f"used: steady {segment.speed:.2f} m/s (±{50 * spread:.1f} %), rudder σ "
                                f"{segment.rudder_std:.3f} rad, heading span {segment.heading_span_deg:.0f}°")
    return segment
