"""Roll stabilisation as a procedure (SPEC C6; thesis §4.4–4.5).

A sequence of behaviours under one restore point (``run_procedure``): settle in the holding mode
with the mass centred, record open loop, run the roll PI closed loop; on the simulator
(``simulator=True``) also its test hooks — a random roll moment (``roll_disturbance``) for the
open/closed comparison and a 25° roll impulse (``roll_kick``) open and closed loop — to reproduce
the seeds' experiments. Figures: roll standard deviation open vs closed loop (seed: 1.02° → 0.39°
at 1.4 m/s) and the settling time of the impulse (seed: 4 s closed loop, > 10 s open).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from behaviors.base import Status
from behaviors.json_form import finite_floats, json_form
from behaviors.observe import Observe, ObserveResult
from behaviors.roll_kick import RollKick, RollKickResult
from behaviors.roll_stabilisation import RollStabilisation, RollStabilisationConfig, RollStabilisationResult
from behaviors.sequence import Instant, SequenceBehavior
from companion.checks import require_non_negative, require_positive, require_range
from companion.interface import SetMode, SetParameters, SetRollingMass, SetThrust
from companion.procedures.results import ProcedureResult, figures_of, finite_or_none
from companion.procedures.runner import SafetyLimits, run_for_result


@dataclass(frozen=True)
class RollProcedureConfig:
    thrust: float = 0.70  # ≈ 1.4 m/s on STARFISH, the seed's condition
    settle_s: float = 20.0
    open_s: float = 60.0
    closed_s: float = 60.0
    disturbance_nm: float = 0.05  # roll_disturbance on the simulator
    kick_deg: float = 25.0  # roll_kick on the simulator; 0 skips the impulse tests
    kick_record_s: float = 15.0
    settle_band_deg: float = 2.5

    def __post_init__(self) -> None:
        require_positive(self, "thrust", "settle_s", "open_s", "closed_s", "kick_record_s", "settle_band_deg")
        require_non_negative(self, "disturbance_nm", "kick_deg")
        if self.thrust > 1.0:
            raise ValueError(f"RollProcedureConfig.thrust must be a thrust level in (0, 1], not {self.thrust!r}")


#: the series of the open and the closed loop the figures keep
ROLL_SERIES = ("time", "roll", "mass_angle")


@dataclass(frozen=True)
class RollFigures:
    """What the roll procedure measured: its thrust, whether it ran on the simulator (then with the
    random roll moment ``disturbance_nm``, N·m), the open loop recorded (:class:`ObserveResult`, with
    ``speed_water``) and the closed loop (:class:`RollStabilisationResult`), both or neither (the
    closed loop did not complete), and the impulse tests (``kick_deg``, the open then the closed
    loop's :class:`RollKickResult`), none without them. The JSON: ``behavior`` (``roll``), ``thrust``,
    ``simulator``, [``disturbance_nm``], [``std_open_deg``, ``std_closed_deg``, ``speed`` (the open
    loop's mean water speed), ``open_series``, ``closed_series``, ``gains``], [``kick_deg``,
    ``kick_settle_open_s``, ``kick_settle_closed_s``]."""

    thrust: float
    simulator: bool
    disturbance_nm: float | None = None
    open_loop: ObserveResult | None = None
    closed_loop: RollStabilisationResult | None = None
    kick_deg: float | None = None
    kicks: tuple[RollKickResult, ...] = ()

    def __post_init__(self) -> None:
        require_range(self, "thrust", 0.0, 1.0)
        if self.simulator != (self.disturbance_nm is not None):
            raise ValueError("RollFigures.disturbance_nm is the simulator's roll moment: given exactly when "
                             f"simulator is True, not {self.disturbance_nm!r} with simulator={self.simulator}")
        if self.simulator:
            require_non_negative(self, "disturbance_nm")
        if (self.open_loop is None) != (self.closed_loop is None):
            raise ValueError("RollFigures holds the open loop and the closed loop together, or neither")
        if self.open_loop is not None and not set(ROLL_SERIES + ("speed_water",)) <= set(self.open_loop.series):
            raise ValueError(f"RollFigures.open_loop must record {', '.join(ROLL_SERIES)} and speed_water, not "
                             f"{', '.join(self.open_loop.series)}")
        if (self.kick_deg is None) != (not self.kicks) or len(self.kicks) not in (0, 2):
            raise ValueError("RollFigures.kicks are the open then the closed loop's impulse tests of kick_deg, "
                             f"or none without kick_deg, not {len(self.kicks)} with kick_deg={self.kick_deg!r}")
        if self.kick_deg is not None:
            require_positive(self, "kick_deg")

    @property
    def std_open_deg(self) -> float | None:
        """The open loop's roll standard deviation (deg; NaN without a finite sample, None: not run)."""
        return self.open_loop.std_deg("roll") if self.open_loop is not None else None

    @property
    def std_closed_deg(self) -> float | None:
        return self.closed_loop.roll_std_deg if self.closed_loop is not None else None

    @property
    def speed(self) -> float | None:
        """The open loop's mean water speed (m/s; None without a finite sample)."""
        if self.open_loop is None:
            return None
        speeds = [v for v in self.open_loop.series["speed_water"] if math.isfinite(v)]
        return float(np.mean(speeds)) if speeds else None

    @property
    def kick_settle_open_s(self) -> float | None:
        return self.kicks[0].settle_s if self.kicks else None

    @property
    def kick_settle_closed_s(self) -> float | None:
        return self.kicks[1].settle_s if self.kicks else None

    def to_dict(self) -> dict:
        out: dict = {"behavior": "roll", "thrust": self.thrust, "simulator": self.simulator}
        if self.simulator:
            out["disturbance_nm"] = self.disturbance_nm
        if self.open_loop is not None and self.closed_loop is not None:
            out.update(std_open_deg=self.std_open_deg, std_closed_deg=self.std_closed_deg, speed=self.speed,
                       open_series={k: finite_floats(self.open_loop.series[k]) for k in ROLL_SERIES},
                       closed_series={k: finite_floats(self.closed_loop.series[k]) for k in ROLL_SERIES},
                       gains=asdict(self.closed_loop.gains))
        if self.kicks:
            out.update(kick_deg=self.kick_deg, kick_settle_open_s=self.kick_settle_open_s,
                       kick_settle_closed_s=self.kick_settle_closed_s)
        return json_form(out)


class RollProcedure(SequenceBehavior):
    """The roll procedure (module docstring); ``result()`` gives the figures."""

    def __init__(self, config: RollProcedureConfig = RollProcedureConfig(), *, simulator: bool = False) -> None:
        self.config = config
        self.simulator = simulator
        self.open_loop = Observe(config.open_s, ("roll", "mass_angle", "speed_water"), label="open loop")
        self.closed_loop = RollStabilisation(RollStabilisationConfig(duration_s=config.closed_s))
        items: list = []
        if simulator:
            items.append(Instant(SetParameters({"roll_disturbance": config.disturbance_nm}), name="disturbance on"))
        items += [Instant(SetMode("hold"), SetThrust(config.thrust), SetRollingMass(0.0), name="prepare"),
                  Observe(config.settle_s, label="settle"), self.open_loop, self.closed_loop]
        self.kicks: list[RollKick] = []
        if simulator and config.kick_deg:
            items.append(Instant(SetParameters({"roll_disturbance": 0.0}), name="disturbance off"))
            for closed in (False, True):
                before = Observe(5.0, ("roll",), commands=[SetRollingMass(0.0)], label="before kick")
                kick = RollKick(config.kick_deg, config.kick_record_s, _mean_roll(before), closed_loop=closed,
                                settle_band_deg=config.settle_band_deg)
                self.kicks.append(kick)
                items += [before, kick]
        items.append(Instant(SetRollingMass(0.0), name="centre the mass"))
        super().__init__(items, name="roll", stop_on_failure=True)

    def result(self) -> ProcedureResult[RollFigures]:
        cfg = self.config
        closed = self.closed_loop.done and self.closed_loop.status is Status.SUCCESS
        figures = RollFigures(cfg.thrust, self.simulator, cfg.disturbance_nm if self.simulator else None,
                              self.open_loop.result() if closed else None,
                              self.closed_loop.result() if closed else None,
                              cfg.kick_deg if self.kicks else None, tuple(kick.result() for kick in self.kicks))
        return ProcedureResult.of("roll", self.status, self.reason, figures)


def _mean_roll(observe: Observe):
    return lambda: float(np.nanmean(np.asarray(observe.series["roll"], dtype=float))) if observe.series["roll"] else 0.0


def roll_summary(result: dict) -> dict:
    """The JSON figures of a stored roll result."""
    return figures_of(result, ("std_open_deg", "std_closed_deg", "speed", "kick_settle_open_s", "kick_settle_closed_s"))


def roll_procedure(link, abort, config: RollProcedureConfig = RollProcedureConfig(), *, simulator: bool = False,
                   limits: SafetyLimits | None = None) -> ProcedureResult[RollFigures]:
    """Build and run the roll procedure under one restore point; its result as the runner saw it end."""
    return run_for_result(link, RollProcedure(config, simulator=simulator), abort_requested=abort,
                          limits=limits)


#: the columns a parameter sweep's row holds of a roll result (:func:`roll_columns`)
ROLL_COLUMNS = ("roll_status", "roll_std_open_deg", "roll_std_closed_deg", "roll_sigma_reduction")


def roll_columns(summary: dict) -> dict:
    """A sweep row's roll figures from the rehearsal summary's roll section (empty: not run)."""
    open_deg, closed_deg = finite_or_none(summary.get("std_open_deg")), finite_or_none(summary.get("std_closed_deg"))
    return {"roll_status": summary.get("status"), "roll_std_open_deg": open_deg, "roll_std_closed_deg": closed_deg,
            "roll_sigma_reduction": open_deg / closed_deg if open_deg is not None and closed_deg else None}
