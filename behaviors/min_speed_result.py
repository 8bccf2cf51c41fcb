"""What minimum-speed seeking found (:class:`behaviors.min_speed.MinSpeedSeeking`; thesis Fig. 5.22–5.24).

The figures the settling rule of ``behaviors.min_speed`` defines and the time series the report
plots, as one frozen record; ``to_dict`` is its JSON (docs/store.md).
"""
from __future__ import annotations

from dataclasses import dataclass

from behaviors.json_form import finite_floats, json_form
from companion.checks import require_count, require_measured


@dataclass(frozen=True)
class MinSpeedResult:
    """The seeker's run: whether it was aborted and why (empty: it was not), the final thrust set-point
    and the mean water speed over its last 10 s (None: no finite speed), when it settled (None: not
    settled), the largest depth error after the start-up transient and after settling (m; NaN or None
    where not known), the depth it held, the set-point's reversals in its last 30 s, the decisions
    taken, the θe crossover used, when a predicted start was reached, whether the governed move
    stalled, the levelled move's largest depth offset and when it faded, its length (s), and the
    recorded series (``time`` from the start, thrust, speed, pitch, elevator, depth, decision)."""

    aborted: bool
    abort_reason: str
    thrust_ratio_final: float
    speed_final: float | None
    settle_time_s: float | None
    max_depth_error_m: float
    max_depth_error_settled_m: float | None
    depth_setpoint_m: float | None
    reversals_last_30s: int
    decisions: int
    theta_e_crossover: float
    start_reached_s: float | None
    governed_stalled: bool
    depth_offset_max_m: float
    depth_offset_faded_s: float | None
    duration_s: float
    series: dict[str, list[float]]

    def __post_init__(self) -> None:
        require_count(self, "reversals_last_30s", "decisions")
        require_measured(self, "settle_time_s", "max_depth_error_m", "max_depth_error_settled_m", "start_reached_s",
                         "depth_offset_max_m", "depth_offset_faded_s", "duration_s")
        if not 0.0 <= self.thrust_ratio_final <= 1.0:
            raise ValueError(f"MinSpeedResult.thrust_ratio_final must be a thrust level in [0, 1], "
                             f"not {self.thrust_ratio_final!r}")

    def to_dict(self) -> dict:
        return json_form({
            "behavior": "min_speed", "aborted": self.aborted, "abort_reason": self.abort_reason,
            "thrust_ratio_final": self.thrust_ratio_final, "speed_final": self.speed_final,
            "settle_time_s": self.settle_time_s, "max_depth_error_m": self.max_depth_error_m,
            "max_depth_error_settled_m": self.max_depth_error_settled_m, "depth_setpoint_m": self.depth_setpoint_m,
            "reversals_last_30s": self.reversals_last_30s, "decisions": self.decisions,
            "theta_e_crossover": self.theta_e_crossover, "start_reached_s": self.start_reached_s,
            "governed_stalled": self.governed_stalled, "depth_offset_max_m": self.depth_offset_max_m,
            "depth_offset_faded_s": self.depth_offset_faded_s, "duration_s": self.duration_s,
            "series": {name: finite_floats(values) for name, values in self.series.items()}})
