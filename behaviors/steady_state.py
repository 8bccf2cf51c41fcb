"""Steady-state manoeuvres under an unknown current (SPEC C8; Hegrenæs et al., §III-B).

Two behaviours, pure step functions of vehicle time and telemetry (SPEC §5):

* :class:`SquarePattern` — straight legs at a fixed thrust in the heading-and-depth holding mode,
  the heading set-point turned by 90° after each leg (``leg_s`` seconds of vehicle time); the
  transients after each turn are cut automatically and eq. 7–8 gives the water-relative velocity
  and the current.
* :class:`SteadyTurns` — for each rudder angle δ the rudder is held open loop (RC override, depth
  stays held) at a fixed thrust for ``turn_s`` seconds, then released and the vehicle brought back to
  its initial heading for ``recover_s`` seconds; the steady part of each turn is fitted with
  eq. 9–10 (radius, rate, current, residual σ).

``abort`` releases the rudder and restores the heading, thrust and mode the behaviour found;
``result`` gives the fits (:class:`SquaresResult`, :class:`TurnsResult`; ``to_dict`` their JSON).
"""
from __future__ import annotations

import logging
import math
from dataclasses import asdict, dataclass
from typing import Any, Sequence

import numpy as np

from companion.checks import require_choice, require_count, require_positive, require_range
from behaviors.base import Behaviour, Footprint, Status
from behaviors.json_form import json_form
from companion.interface import (
    Command,
    ReleaseActuator,
    OverrideActuator,
    SetDepth,
    SetHeading,
    SetMode,
    SetThrust,
    StatusText,
    Telemetry,
)
from companion.numerics.angles import wrap_pi
from companion.numerics.steady_state import (
    StraightLegFit,
    TurnFit,
    fit_steady_turn,
    fit_straight_legs,
    ned_to_body,
    steady_straight_mask,
    steady_turn_mask,
    water_relative_velocity,
)

log = logging.getLogger(__name__)

_NAV_FIELDS = ("north", "east", "down", "roll", "pitch", "yaw", "vel_north", "vel_east", "vel_down")


@dataclass
class _Recorder:
    """Navigation samples recorded from telemetry (only complete, new-time samples)."""

    rows: list

    def add(self, tel: Telemetry) -> None:
        if not tel.finite(*_NAV_FIELDS):
            return
        if self.rows and tel.time_s <= self.rows[-1][0]:
            return
        self.rows.append((tel.time_s, *(getattr(tel, name) for name in _NAV_FIELDS)))

    def arrays(self) -> dict[str, np.ndarray]:
        data = np.array(self.rows, float).reshape(-1, 1 + len(_NAV_FIELDS))
        out = {"t": data[:, 0]}
        out.update({name: data[:, i + 1] for i, name in enumerate(_NAV_FIELDS)})
        return out


@dataclass
class _StartState:
    time_s: float
    heading: float
    thrust_ratio: float
    mode: str

    @classmethod
    def begin(cls, telemetry: Telemetry, thrust_ratio: float, depth: float | None) -> tuple["_StartState", list[Command]]:
        """Record how the manoeuvre found the vehicle; commands: holding mode (if not in it), the
        manoeuvre's thrust and optional depth."""
        start = cls(telemetry.time_s, telemetry.yaw, telemetry.thrust_ratio, telemetry.mode)
        commands: list[Command] = [] if telemetry.mode == "hold" else [SetMode("hold")]
        commands.append(SetThrust(thrust_ratio))
        if depth is not None:
            commands.append(SetDepth(depth))
        return start, commands



# --------------------------------------------------------------------------- squares
@dataclass(frozen=True)
class SquareConfig:
    """A square pattern (paper §III-B: one square at a fixed propeller setting)."""

    thrust_ratio: float = 0.8
    leg_s: float = 150.0  # vehicle time per leg, including the transient after the turn
    legs: int = 4
    first_heading: float | None = None  # rad; None = the heading found at the start
    clockwise: bool = True  # +90° per leg (starboard turns) or −90°
    depth: float | None = None  # m; None = keep the held depth
    rate_tol: float = math.radians(0.5)  # transient cutting: |heading rate| below this on a leg
    speed_tol: float = 0.02  # m/s: body velocity over ground settled within this
    min_leg_s: float = 20.0

    def __post_init__(self) -> None:
        require_range(self, "thrust_ratio", 1e-3, 1.0)
        require_positive(self, "leg_s", "rate_tol", "speed_tol", "min_leg_s")
        if not (isinstance(self.legs, int) and 1 <= self.legs <= 16):
            raise ValueError(f"SquareConfig.legs must be an integer in 1..16, not {self.legs!r}")


#: where a square pattern is: not started, flying, fitted, not fitted, stopped from outside
SQUARE_STATUSES = ("pending", "running", "completed", "failed", "aborted")


@dataclass(frozen=True)
class SquaresResult:
    """The square pattern (eq. 7–8): where it is (:data:`SQUARE_STATUSES`), its configuration, the
    navigation samples recorded, the fit of the steady straight legs and the samples it used once
    completed, and why it has none once failed or aborted. The JSON holds the fit's figures
    (``StraightLegFit.as_dict``: its ``samples`` is the fit's)."""

    status: str
    config: SquareConfig
    samples: int
    fit: StraightLegFit | None = None
    samples_used: int | None = None
    error: str | None = None

    def __post_init__(self) -> None:
        require_choice(self, "status", SQUARE_STATUSES)
        require_count(self, "samples")
        if (self.fit is not None) != (self.status == "completed") or (self.fit is None) != (self.samples_used is None):
            raise ValueError(f"SquaresResult: a fit and the samples it used exactly when completed, not {self.status!r}")
        if (self.error is not None) != (self.status in ("failed", "aborted")):
            raise ValueError(f"SquaresResult: an error exactly when failed or aborted, not {self.status!r}")

    def to_dict(self) -> dict:
        out = {"behavior": "squares", "status": self.status, "config": asdict(self.config), "samples": self.samples}
        if self.fit is not None:
            out.update(self.fit.as_dict(), samples_used=self.samples_used)
        if self.error is not None:
            out["error"] = self.error
        return json_form(out)


class SquarePattern(Behaviour):
    """Square pattern at fixed thrust in the holding mode; fits eq. 7–8 at the end (SPEC C8)."""

    footprint = Footprint.of(setpoints=("mode", "thrust", "heading", "depth"))

    def __init__(self, config: SquareConfig | None = None) -> None:
        super().__init__("squares")
        self.config = config or SquareConfig()
        self._start: _StartState | None = None
        self._leg = -1
        self._status = "pending"
        self._recorder = _Recorder([])
        self._fit: tuple[StraightLegFit, int] | None = None  # the fit and the samples it used
        self._error: str | None = None

    def leg_heading(self, leg: int) -> float:
        assert self._start is not None
        base = self.config.first_heading if self.config.first_heading is not None else self._start.heading
        step = math.pi / 2 if self.config.clockwise else -math.pi / 2
        return wrap_pi(base + leg * step)

    def update(self, telemetry: Telemetry) -> Sequence[Command]:
        commands: list[Command] = []
        cfg = self.config
        if self._start is None:
            if not telemetry.finite("yaw"):
                return []
            self._start, started = _StartState.begin(telemetry, cfg.thrust_ratio, cfg.depth)
            self._status = "running"
            commands += started
            commands.append(StatusText(f"squares: {cfg.legs} legs of {cfg.leg_s:.0f} s at thrust {cfg.thrust_ratio:.2f}"))
        elapsed = telemetry.time_s - self._start.time_s
        if elapsed >= cfg.legs * cfg.leg_s:
            self._recorder.add(telemetry)
            self._finish()
            commands.append(StatusText(f"squares: {self._status}"))
            return commands
        leg = int(elapsed // cfg.leg_s)
        if leg != self._leg:
            self._leg = leg
            heading = self.leg_heading(leg)
            commands.append(SetHeading(heading))
            commands.append(StatusText(f"squares: leg {leg + 1}/{cfg.legs} heading {math.degrees(heading) % 360:.0f} deg"))
        self._recorder.add(telemetry)
        return commands

    def _finish(self) -> None:
        try:
            self._fit = analyse_square(self._recorder.arrays(), self.config)
            self._status = "completed"
            self.finish(Status.SUCCESS)
        except ValueError as exc:
            self._status = "failed"
            self._error = str(exc)
            log.warning("square pattern fit failed: %s", exc)
            self.finish(Status.FAILURE, str(exc))

    def terminate(self, status: Status) -> Sequence[Command]:
        if status is not Status.ABORTED:
            return []
        was_running = self._status == "running"
        if self._status in ("pending", "running"):
            self._status = "aborted"
            self._error = f"aborted: {self.reason}"
        return [StatusText(f"squares aborted: {self.reason}", severity=4)] if was_running else []

    def data(self) -> dict[str, np.ndarray]:
        """The navigation samples recorded on the legs (arrays t, north, east, … as analysed)."""
        return self._recorder.arrays()

    def result(self) -> SquaresResult:
        fit, used = self._fit if self._fit is not None else (None, None)
        return SquaresResult(self._status, self.config, len(self._recorder.rows), fit, used, self._error)


def analyse_square(data: dict[str, np.ndarray], config: SquareConfig = SquareConfig()) -> tuple[StraightLegFit, int]:
    """Cut the transients of recorded square-pattern data and fit eq. 7–8: the fit and the samples
    it used. ``data`` holds arrays t, roll, pitch, yaw, vel_north/east/down."""
    vel_body = ned_to_body(data["roll"], data["pitch"], data["yaw"],
                           np.column_stack([data["vel_north"], data["vel_east"], data["vel_down"]]))
    if data["t"].size < 10:
        raise ValueError("too few samples recorded")
    mask = steady_straight_mask(data["t"], data["yaw"], vel_body, config.rate_tol, config.speed_tol, config.min_leg_s)
    if mask.sum() < 10:
        raise ValueError("no steady straight leg found after cutting the transients")
    fit = fit_straight_legs(data["roll"][mask], data["pitch"][mask], data["yaw"][mask], vel_body[mask])
    return fit, int(mask.sum())


# --------------------------------------------------------------------------- steady turns
@dataclass(frozen=True)
class TurnConfig:
    """Steady turns with the rudder locked (paper §III-B: fixed rudder and propeller set-points)."""

    thrust_ratio: float = 0.8
    rudder_angles: tuple[float, ...] = (0.22, -0.22)  # rad (≈ ±12.5°, the paper's turns)
    turn_s: float = 150.0  # vehicle time per rudder angle, including the transient
    recover_s: float = 30.0  # straight, heading control back, between turns
    depth: float | None = None
    rate_tol: float = math.radians(0.3)  # transient cutting: heading rate settled within this
    min_steady_s: float = 30.0

    def __post_init__(self) -> None:
        require_range(self, "thrust_ratio", 1e-3, 1.0)
        require_positive(self, "turn_s", "recover_s", "rate_tol", "min_steady_s")
        if not self.rudder_angles or any(not (isinstance(a, (int, float)) and 0 < abs(a) <= 1.0)
                                         for a in self.rudder_angles):
            raise ValueError(f"TurnConfig.rudder_angles must be non-zero angles within ±1 rad, not {self.rudder_angles!r}")


@dataclass(frozen=True)
class TurnOutcome:
    """One steady turn at ``rudder_rad``: the fit of its steady part (eq. 9–10) and the samples it
    used, the mean water-relative surge and sway over it (m/s) and the sideslip (deg) when the
    velocities were recorded; or why it could not be fitted."""

    rudder_rad: float
    fit: TurnFit | None = None
    samples_used: int | None = None
    surge_water: float | None = None
    sway_water: float | None = None
    sideslip_deg: float | None = None
    error: str | None = None

    def __post_init__(self) -> None:
        if (self.fit is None) == (self.error is None) or (self.fit is None) != (self.samples_used is None):
            raise ValueError("TurnOutcome: a fit with the samples it used, or the error why there is none")

    @property
    def rudder_deg(self) -> float:
        return math.degrees(self.rudder_rad)

    def to_dict(self) -> dict:
        out: dict[str, Any] = {"rudder_rad": self.rudder_rad, "rudder_deg": self.rudder_deg}
        if self.fit is not None:
            out.update(self.fit.as_dict(), samples_used=self.samples_used)
            if self.surge_water is not None:
                out.update(surge_water=self.surge_water, sway_water=self.sway_water, sideslip_deg=self.sideslip_deg)
        if self.error is not None:
            out["error"] = self.error
        return json_form(out)


#: where the turns are: not started, turning, every turn fitted, some, none, stopped from outside
TURN_STATUSES = ("pending", "running", "completed", "partial", "failed", "aborted")


@dataclass(frozen=True)
class TurnsResult:
    """The steady turns (eq. 9–10): where they are (:data:`TURN_STATUSES`), their configuration, and
    each turn flown (:class:`TurnOutcome`); the JSON adds the fitted turns' mean current
    (``current_north``, ``current_east``, m/s) when there is one."""

    status: str
    config: TurnConfig
    turns: tuple[TurnOutcome, ...] = ()

    def __post_init__(self) -> None:
        require_choice(self, "status", TURN_STATUSES)
        fitted = sum(1 for turn in self.turns if turn.fit is not None)
        expected = {"completed": len(self.turns) > 0 and fitted == len(self.turns),
                    "partial": 0 < fitted < len(self.turns), "failed": fitted == 0}
        if not expected.get(self.status, True):
            raise ValueError(f"TurnsResult: {fitted} of {len(self.turns)} turns fitted is not {self.status!r}")

    @property
    def current(self) -> tuple[float, float] | None:
        """The fitted turns' mean current (north, east), m/s; None without a fitted turn."""
        currents = [turn.fit.current for turn in self.turns if turn.fit is not None]
        if not currents:
            return None
        mean = np.mean(np.array([(float(c[0]), float(c[1])) for c in currents]), axis=0)
        return float(mean[0]), float(mean[1])

    def to_dict(self) -> dict:
        out: dict[str, Any] = {"behavior": "turns", "status": self.status, "config": asdict(self.config),
                               "turns": [turn.to_dict() for turn in self.turns]}
        current = self.current
        if current is not None:
            out["current_north"], out["current_east"] = current
        return json_form(out)


class SteadyTurns(Behaviour):
    """Rudder held at fixed angles (RC override, depth still held); fits eq. 9–10 per angle."""

    footprint = Footprint.of(setpoints=("mode", "thrust", "heading", "depth", "rudder"))

    def __init__(self, config: TurnConfig | None = None) -> None:
        super().__init__("turns")
        self.config = config or TurnConfig()
        self._start: _StartState | None = None
        self._status = "pending"
        self._index = -1
        self._phase = ""
        self._phase_start = 0.0
        self._recorders: list[_Recorder] = [_Recorder([]) for _ in self.config.rudder_angles]
        self._turns: list[TurnOutcome] = []

    def update(self, telemetry: Telemetry) -> Sequence[Command]:
        cfg = self.config
        commands: list[Command] = []
        if self._start is None:
            if not telemetry.finite("yaw"):
                return []
            self._start, started = _StartState.begin(telemetry, cfg.thrust_ratio, cfg.depth)
            self._status = "running"
            commands += started
            commands.extend(self._begin_turn(0, telemetry.time_s))
            return commands
        elapsed = telemetry.time_s - self._phase_start
        if self._phase == "turn":
            self._recorders[self._index].add(telemetry)
            if elapsed >= cfg.turn_s:
                self._phase, self._phase_start = "recover", telemetry.time_s
                commands += [ReleaseActuator("rudder"), SetHeading(self._start.heading),
                             StatusText(f"turns: rudder released after turn {self._index + 1}")]
        elif self._phase == "recover" and elapsed >= cfg.recover_s:
            if self._index + 1 < len(cfg.rudder_angles):
                commands.extend(self._begin_turn(self._index + 1, telemetry.time_s))
            else:
                self._finish()
                commands += [SetHeading(self._start.heading), StatusText(f"turns: {self._status}")]
        return commands

    def _begin_turn(self, index: int, time_s: float) -> list[Command]:
        self._index, self._phase, self._phase_start = index, "turn", time_s
        angle = self.config.rudder_angles[index]
        return [OverrideActuator("rudder", angle),
                StatusText(f"turns: {index + 1}/{len(self.config.rudder_angles)} rudder {math.degrees(angle):+.1f} deg")]

    def _finish(self) -> None:
        ok = 0
        for angle, recorder in zip(self.config.rudder_angles, self._recorders):
            try:
                self._turns.append(analyse_turn(recorder.arrays(), self.config, angle))
                ok += 1
            except ValueError as exc:
                self._turns.append(TurnOutcome(angle, error=str(exc)))
                log.warning("turn fit (rudder %.3f rad) failed: %s", angle, exc)
        self._status = "completed" if ok == len(self._recorders) else ("partial" if ok else "failed")
        if ok:
            self.finish(Status.SUCCESS)
        else:
            self.finish(Status.FAILURE, "no turn could be fitted")

    def terminate(self, status: Status) -> Sequence[Command]:
        if status is not Status.ABORTED:
            return []
        was_running = self._status == "running"
        if self._status in ("pending", "running"):
            self._status = "aborted"
        if not was_running:
            return []
        return [ReleaseActuator("rudder"), StatusText(f"turns aborted: {self.reason}", severity=4)]

    def data(self) -> list[dict[str, np.ndarray]]:
        """The navigation samples recorded in each turn, in the order of ``rudder_angles``."""
        return [recorder.arrays() for recorder in self._recorders]

    def result(self) -> TurnsResult:
        return TurnsResult(self._status, self.config, tuple(self._turns))


def analyse_turn(data: dict[str, np.ndarray], config: TurnConfig, rudder_rad: float) -> TurnOutcome:
    """Cut the transient of one recorded turn at ``rudder_rad`` and fit eq. 9–10; with the mean
    water-relative surge/sway over the steady part (eq. 5 with the fitted current) when velocities
    are present."""
    t = data["t"]
    if t.size < 20:
        raise ValueError("too few samples recorded in the turn")
    mask = steady_turn_mask(t, data["yaw"], config.rate_tol)
    if mask.sum() < 20 or t[mask][-1] - t[mask][0] < config.min_steady_s:
        raise ValueError("the turn did not reach a steady rate long enough")
    fit = fit_steady_turn(t[mask], data["north"][mask], data["east"][mask], data["yaw"][mask])
    if "vel_north" not in data:
        return TurnOutcome(rudder_rad, fit, int(mask.sum()))
    vel_body = ned_to_body(data["roll"][mask], data["pitch"][mask], data["yaw"][mask],
                           np.column_stack([data["vel_north"], data["vel_east"], data["vel_down"]])[mask])
    v_wb = water_relative_velocity(data["roll"][mask], data["pitch"][mask], data["yaw"][mask], vel_body, fit.current)
    mean = v_wb.mean(axis=0)
    return TurnOutcome(rudder_rad, fit, int(mask.sum()), float(mean[0]), float(mean[1]),
                       math.degrees(math.atan2(mean[1], mean[0])))
