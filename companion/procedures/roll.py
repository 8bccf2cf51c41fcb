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
from behaviors.json_form import finite_floats
from behaviors.observe import Observe
from behaviors.roll_kick import RollKick
from behaviors.roll_stabilisation import RollStabilisation, RollStabilisationConfig
from behaviors.sequence import Instant, SequenceBehavior
from companion.checks import require_non_negative, require_positive
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

    def result(self) -> ProcedureResult:
        cfg = self.config
        figures: dict = {"behavior": "roll", "thrust": cfg.thrust, "simulator": self.simulator}
        if self.simulator:
            figures["disturbance_nm"] = cfg.disturbance_nm
        if self.closed_loop.done and self.closed_loop.status is Status.SUCCESS:
            closed = self.closed_loop.result()
            speeds = [v for v in self.open_loop.series["speed_water"] if math.isfinite(v)]
            figures.update(std_open_deg=self.open_loop.std_deg("roll"), std_closed_deg=closed.roll_std_deg,
                           speed=float(np.mean(speeds)) if speeds else None,
                           open_series={k: self.open_loop.series[k] for k in ("time", "roll", "mass_angle")},
                           closed_series={k: finite_floats(closed.series[k]) for k in ("time", "roll", "mass_angle")},
                           gains=asdict(closed.gains))
        if self.kicks:
            figures["kick_deg"] = cfg.kick_deg
            figures["kick_settle_open_s"] = self.kicks[0].settle_time_s()
            figures["kick_settle_closed_s"] = self.kicks[1].settle_time_s()
        return ProcedureResult.of("roll", self.status, self.reason, figures)


def _mean_roll(observe: Observe):
    return lambda: float(np.nanmean(np.asarray(observe.series["roll"], dtype=float))) if observe.series["roll"] else 0.0


def roll_summary(result: dict) -> dict:
    """The JSON figures of a stored roll result."""
    return figures_of(result, ("std_open_deg", "std_closed_deg", "speed", "kick_settle_open_s", "kick_settle_closed_s"))


def roll_procedure(link, abort, config: RollProcedureConfig = RollProcedureConfig(), *, simulator: bool = False,
                   limits: SafetyLimits | None = None) -> ProcedureResult:
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
