"""Steady-state manoeuvring characteristics under unknown current, as a procedure (SPEC C8).

A square pattern at fixed thrust (straight legs: eq. 7–8) and steady turns with the rudder held at
±12.5° (eq. 9–10), run over the link with restore points like every procedure; the recorded paths
(decimated to 1 Hz) are kept with the fitted figures so the report can draw the measured path, the
fitted path, the circle without current and the current vector.

Current direction convention: the direction the current flows **towards**, 0–360° from north,
clockwise (Hegrenæs et al., eq. 11).
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

import numpy as np

from behaviors.base import Status
from behaviors.json_form import json_form
from behaviors.sequence import SequenceBehavior
from behaviors.steady_state import SquareConfig, SquarePattern, SquaresResult, SteadyTurns, TurnConfig, TurnsResult
from companion.checks import require_positive
from companion.numerics.steady_state import current_direction_deg
from companion.procedures.results import ProcedureResult, finite_or_none
from companion.procedures.runner import SafetyLimits, run_for_result

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SteadyStateConfig:
    # HUGIN-like preset: TR 0.6 ≈ 1.56 m/s on the legs; turns at TR 0.5 (≈ 1.3 m/s, ≈ 5°/s at 12.5°)
    squares: SquareConfig = field(default_factory=lambda: SquareConfig(thrust_ratio=0.6, leg_s=120.0))
    turns: TurnConfig = field(default_factory=lambda: TurnConfig(thrust_ratio=0.5, rudder_angles=(0.218, -0.218),
                                                                  turn_s=150.0, recover_s=30.0))
    path_rate_hz: float = 1.0

    def __post_init__(self) -> None:
        require_positive(self, "path_rate_hz")


@dataclass(frozen=True)
class DecimatedPath:
    """A recorded path at about ``path_rate_hz``: vehicle time (s), north and east (m), one value of
    each per sample. The JSON: ``t``, ``north``, ``east``."""

    t: tuple[float, ...]
    north: tuple[float, ...]
    east: tuple[float, ...]

    def __post_init__(self) -> None:
        if not len(self.t) == len(self.north) == len(self.east):
            raise ValueError(f"DecimatedPath holds one north and one east per time, not {len(self.t)} times, "
                             f"{len(self.north)} north, {len(self.east)} east")

    @classmethod
    def of(cls, data: dict[str, np.ndarray], rate_hz: float) -> "DecimatedPath":
        """The first sample of each 1/rate_hz interval of a recorded path."""
        t = data["t"]
        if t.size == 0:
            return cls((), (), ())
        keep = np.concatenate([[True], np.diff(np.floor(t * rate_hz)) > 0])
        return cls(*(tuple(float(v) for v in data[name][keep]) for name in ("t", "north", "east")))

    def to_dict(self) -> dict:
        return json_form({"t": self.t, "north": self.north, "east": self.east})


@dataclass(frozen=True)
class SteadyStateFigures:
    """What the steady-state procedure measured: the squares (:class:`SquaresResult`) with their
    decimated path, and the turns (:class:`TurnsResult`) with one decimated path per turn recorded;
    each None (no path) until it started. The JSON: ``behavior`` (``steady_state``), then once
    started ``squares`` (the squares' keys and ``path``) and ``turns`` (the turns' keys and ``paths``)."""

    squares: SquaresResult | None = None
    square_path: DecimatedPath | None = None
    turns: TurnsResult | None = None
    turn_paths: tuple[DecimatedPath, ...] = ()

    def __post_init__(self) -> None:
        if (self.squares is None) != (self.square_path is None):
            raise ValueError("SteadyStateFigures holds the squares with their path, or neither")
        if self.turns is None and self.turn_paths:
            raise ValueError(f"SteadyStateFigures holds {len(self.turn_paths)} turn paths without the turns")

    def to_dict(self) -> dict:
        out: dict = {"behavior": "steady_state"}
        if self.squares is not None and self.square_path is not None:
            out["squares"] = {**self.squares.to_dict(), "path": self.square_path.to_dict()}
        if self.turns is not None:
            out["turns"] = {**self.turns.to_dict(), "paths": [path.to_dict() for path in self.turn_paths]}
        return out


class SteadyStateProcedure(SequenceBehavior):
    """Squares, then turns, under one restore point; ``result()`` holds both fits and the paths."""

    def __init__(self, config: SteadyStateConfig = SteadyStateConfig()) -> None:
        self.config = config
        self.squares = SquarePattern(config.squares)
        self.turns = SteadyTurns(config.turns)
        super().__init__([self.squares, self.turns], name="steady_state")

    def update(self, telemetry):
        """Both parts always run (a failed fit of one still leaves the other's figures); the
        procedure succeeds only when both did."""
        commands = super().update(telemetry)
        if self.status is Status.SUCCESS:
            failed = [part for part in (self.squares, self.turns) if part.status is not Status.SUCCESS]
            if failed:
                self.finish(Status.FAILURE, "; ".join(f"{part.name}: {part.reason or part.status.value}"
                                                      for part in failed))
        return commands

    def result(self) -> ProcedureResult[SteadyStateFigures]:
        rate = self.config.path_rate_hz
        squares = self.squares.status is not Status.INVALID
        turns = self.turns.status is not Status.INVALID
        figures = SteadyStateFigures(
            self.squares.result() if squares else None,
            DecimatedPath.of(self.squares.data(), rate) if squares else None,
            self.turns.result() if turns else None,
            tuple(DecimatedPath.of(data, rate) for data in self.turns.data()) if turns else ())
        return ProcedureResult.of("steady_state", self.status, self.reason, figures)


def steady_state_procedure(link, abort, config: SteadyStateConfig = SteadyStateConfig(), *,
                           limits: SafetyLimits | None = None) -> ProcedureResult[SteadyStateFigures]:
    """Squares, then turns, under one restore point."""
    return run_for_result(link, SteadyStateProcedure(config), abort_requested=abort, limits=limits)


def steady_summary(result: dict, true_current: tuple[float, float] | None = None) -> dict:
    """The JSON figures of the squares and turns of a stored result (and the errors against a known
    current, on the simulator)."""
    squares, turns = result.get("squares") or {}, result.get("turns") or {}
    summary: dict = {"status": result.get("status")}
    if "current_speed" in squares:
        summary["squares"] = {key: finite_or_none(squares.get(key)) for key in
                              ("surge_water", "sway_water", "heave_water", "current_speed", "current_dir_deg",
                               "condition_number")}
    summary["turns"] = [{key: finite_or_none(turn.get(key)) for key in
                         ("rudder_deg", "radius_m", "turn_rate_deg_s", "current_speed", "current_dir_deg",
                          "residual_std_m")} for turn in turns.get("turns", []) if "radius_m" in turn]
    if true_current is not None:
        north, east = true_current
        summary["true_current_speed"] = math.hypot(north, east)
        summary["true_current_dir_deg"] = current_direction_deg(north, east)
        if "current_north" in squares:
            summary["squares"]["current_error_mm_s"] = 1000 * math.hypot(squares["current_north"] - north,
                                                                        squares["current_east"] - east)
        for turn_summary, turn in zip(summary["turns"], (t for t in turns.get("turns", []) if "radius_m" in t)):
            turn_summary["current_error_mm_s"] = 1000 * math.hypot(turn["current_north"] - north,
                                                                   turn["current_east"] - east)
    return summary


#: the columns a parameter sweep's row holds of a steady-state result (:func:`steady_columns`)
STEADY_COLUMNS = ("steady_state_status", "squares_current_error_mm_s", "turns_current_error_max_mm_s")


def steady_columns(summary: dict) -> dict:
    """A sweep row's current-estimate errors from the rehearsal summary's steady_state section."""
    turns = [e for e in (finite_or_none(t.get("current_error_mm_s")) for t in summary.get("turns", [])) if e is not None]
    return {"steady_state_status": summary.get("status"),
            "squares_current_error_mm_s": finite_or_none((summary.get("squares") or {}).get("current_error_mm_s")),
            "turns_current_error_max_mm_s": max(turns) if turns else None}
