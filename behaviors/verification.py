"""One heading step that decides whether designed gains may stay on the vehicle (eq. A.3; SPEC C5: "every
design is checked by heading steps through the autopilot before it is kept").

The gains go on the vehicle as a trial, the thrust is set, and the vehicle settles on its course
only until it is steady (the steadiness rule: speed and yaw rate; no fixed wait) — or, when the
step is chained right after a record at the same thrust (``steady_now``), only until the speed has
stopped changing (``chained_speed_change``: re-entering the holding mode to engage a new trim runs
the thrust at the autopilot's cruise value until the set-point follows, and a step flown while the
speed recovers is disturbed and flown twice). Then one step of
``step`` rad (its sign alternating, so a campaign stays near its course) and the record **ends
when it has decided**: once the heading has been within the settle band (5 % of the step) for
``band_hold_s`` after its peak, or after ``max_s`` without settling. A step that cannot decide is
repeated once — the speed wandered by more than ``max_speed_change`` during it (a disturbance, a
thrust change not settled), or the rudder sat at its limit for more than ``max_saturated_s`` (the
design assumes an unsaturated rudder) — and a second such step ends it undecided. The figures of
merit are :func:`companion.numerics.step_response.step_metrics`.

Chaining: the course the step ends on is the next check's course; nothing returns to the start.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Sequence

import numpy as np

from behaviors.base import Behaviour, Footprint, Status
from behaviors.heading_steps import reengage_hold
from behaviors.steadiness import SteadinessDetector, SteadinessRule
from companion.checks import require_positive, require_range
from companion.interface import Command, SetHeading, SetParameters, SetThrust, StatusText, Telemetry
from companion.numerics.angles import wrap_pi
from companion.numerics.step_response import SETTLE_BAND, smooth_heading, step_metrics


@dataclass(frozen=True)
class VerificationConfig:
    """How one verification step is flown and when it has decided (module docstring)."""

    step: float = math.radians(20.0)  # rad; the campaign may shrink it so the rudder stays linear
    settle_max_s: float = 20.0  # vehicle seconds to wait for a steady vehicle before the step
    band_hold_s: float = 1.5  # within the settle band this long after the peak: decided
    max_s: float = 25.0  # a step not settled by then has decided (against the gains)
    max_speed_change: float = 0.10  # relative change of the water speed during the step: disturbed
    max_saturated_s: float = 2.0  # rudder at its limit longer than this: the step cannot decide
    repeats: int = 1  # an undecided step is flown again this many times
    chained_speed_change: float = 0.015  # relative spread of three mean speeds below which a chained step starts
    chained_window_s: float = 1.0  # vehicle seconds in each of those means
    steadiness: SteadinessRule = field(default_factory=SteadinessRule)

    def __post_init__(self) -> None:
        require_range(self, "step", math.radians(2.0), math.radians(90.0))
        require_positive(self, "settle_max_s", "band_hold_s", "max_s", "max_speed_change", "max_saturated_s",
                         "chained_speed_change", "chained_window_s")
        if not (isinstance(self.repeats, int) and 0 <= self.repeats <= 3):
            raise ValueError(f"VerificationConfig.repeats must be an integer in 0..3, not {self.repeats!r}")


class VerificationStep(Behaviour):
    """Trial ``gains`` at ``thrust``, one decisive heading step (module docstring).

    ``result()`` has the flown step's metrics (``overshoot_pct``, ``iae_s``, ``settling_time_s``,
    ``oscillations``), ``decided`` (False: disturbed or saturated twice), ``why_undecided``, the
    step's size and sign, the speed, and the series for the report."""

    def __init__(self, thrust: float, gains: dict[str, float], config: VerificationConfig = VerificationConfig(),
                 *, sign: float = 1.0, rudder_max: float = math.inf, label: str = "scheduled",
                 steady_now: bool = False) -> None:
        super().__init__(f"verify {label} at {thrust:.2f}")
        self.footprint = Footprint.of(parameters=tuple(gains), setpoints=("mode", "thrust", "heading"))
        # chained right after a record that ended steady at this thrust (a validation record ends
        # 4 s after its doublet, on course): the step starts at once, without a settle of its own
        self.steady_now = steady_now
        self.thrust, self.gains, self.config, self.label = thrust, dict(gains), config, label
        self.sign = 1.0 if sign >= 0 else -1.0
        self.rudder_max = rudder_max
        self._phase = "settle"
        self._phase_start = math.nan
        self._course = math.nan
        self._target = math.nan
        self._unwrap = (math.nan, 0.0)  # (last yaw, offset)
        self._steady: SteadinessDetector | None = None
        self._speeds: list[float] = []
        self._saturated_s = 0.0
        self._last_time = math.nan
        self._band_since: float | None = None
        self._peaked = False
        self.flights = 0
        self.why_undecided: str | None = None
        self._recent_speeds: list[tuple[float, float]] = []  # (time, water speed) of a chained start
        self.metrics: dict = {}
        self.series: dict[str, list[float]] = {"time": [], "heading": [], "target": [], "rudder": [], "speed": []}
        self.stage_times: dict[str, float] = {}

    # ------------------------------------------------------------------ helpers
    def _unwrapped(self, yaw: float) -> float:
        last, offset = self._unwrap
        if math.isfinite(last):
            offset += -2 * math.pi if yaw - last > math.pi else (2 * math.pi if yaw - last < -math.pi else 0.0)
        self._unwrap = (yaw, offset)
        return yaw + offset

    def _enter(self, phase: str, now: float) -> None:
        if math.isfinite(self._phase_start):
            self.stage_times[self._phase] = self.stage_times.get(self._phase, 0.0) + now - self._phase_start
        self._phase, self._phase_start = phase, now

    # ------------------------------------------------------------------ lifecycle
    def initialise(self, telemetry: Telemetry) -> Sequence[Command]:
        self._phase_start = telemetry.time_s
        self._course = self._unwrapped(telemetry.yaw) if telemetry.finite("yaw") else 0.0
        self._steady = SteadinessDetector(self.config.steadiness, "yaw", wrap_pi(self._course))
        commands: list[Command] = [SetParameters(dict(self.gains))]
        if "rudder_trim" in self.gains:
            commands += reengage_hold(self.thrust, wrap_pi(self._course))
        return commands + [SetThrust(self.thrust), SetHeading(wrap_pi(self._course)),
                           StatusText(f"verifying {self.label} gains at thrust {self.thrust:.2f}"[:50])]

    def update(self, telemetry: Telemetry) -> Sequence[Command]:
        if not telemetry.finite("yaw"):
            return []
        now = telemetry.time_s
        heading = self._unwrapped(telemetry.yaw)
        if self._phase == "settle" and self.steady_now and self.flights == 0:
            if self._speed_steady(now, telemetry.speed_water) or now - self._phase_start >= self.config.settle_max_s:
                return self._begin_step(now, heading)
            return []
        if self._phase == "settle":
            self._steady.add(now, telemetry.speed_water, telemetry.yaw_rate, telemetry.pitch_rate, telemetry.yaw)
            if self._steady.steady(now) or now - self._phase_start >= self.config.settle_max_s:
                return self._begin_step(now, heading)
            return []
        self._record(telemetry, now, heading)
        verdict = self._decided(telemetry, now, heading)
        if verdict is None:
            return []
        return self._conclude(verdict, now, heading)

    def _speed_steady(self, now: float, speed: float) -> bool:
        """The chained start (module docstring): the means of the water speed over the last three
        ``chained_window_s`` windows differ by less than ``chained_speed_change`` of the speed. Three
        windows, not a slope: a slope or two means are flat on the crest of a transient."""
        if math.isfinite(speed):
            self._recent_speeds.append((now, speed))
        window = self.config.chained_window_s
        while self._recent_speeds and self._recent_speeds[0][0] < now - 3 * window:
            self._recent_speeds.pop(0)
        if not self._recent_speeds or self._recent_speeds[0][0] > now - 2.9 * window:
            return False
        times, speeds = np.array(self._recent_speeds).T
        means = [speeds[(times > now - (k + 1) * window) & (times <= now - k * window)] for k in range(3)]
        if any(len(part) < 3 for part in means):
            return False
        levels = [float(np.mean(part)) for part in means]
        return max(levels) - min(levels) < self.config.chained_speed_change * max(abs(levels[0]), 1e-6)

    def _begin_step(self, now: float, heading: float) -> list[Command]:
        self.flights += 1
        self._enter("step", now)
        self._course = heading
        self._target = heading + self.sign * self.config.step
        self._speeds, self._saturated_s, self._band_since, self._peaked = [], 0.0, None, False
        self._last_time = now
        self._first_index = len(self.series["time"])
        return [SetHeading(wrap_pi(self._target))]

    def _record(self, telemetry: Telemetry, now: float, heading: float) -> None:
        self.series["time"].append(now)
        self.series["heading"].append(heading)
        self.series["target"].append(self._target)
        self.series["rudder"].append(telemetry.rudder)
        self.series["speed"].append(telemetry.speed_water)
        if telemetry.finite("speed_water"):
            self._speeds.append(telemetry.speed_water)
        if math.isfinite(telemetry.rudder) and abs(telemetry.rudder) >= 0.98 * self.rudder_max:
            self._saturated_s += max(0.0, now - self._last_time)
        self._last_time = now

    def _decided(self, telemetry: Telemetry, now: float, heading: float) -> str | None:
        """``"settled"``, ``"timeout"``, ``"disturbed"``, ``"saturated"`` or None (keep flying)."""
        if self._saturated_s > self.config.max_saturated_s:
            return "saturated"
        if len(self._speeds) > 5:
            low, high = min(self._speeds), max(self._speeds)
            if high - low > self.config.max_speed_change * max(high, 1e-6):
                return "disturbed"
        size = self._target - self._course
        progress = (heading - self._course) / size
        if progress >= 1.0:
            self._peaked = True  # crossed the target: the peak is at or after here
        if self._peaked and abs(progress - 1.0) <= SETTLE_BAND:
            if self._band_since is None:
                self._band_since = now
            if now - self._band_since >= self.config.band_hold_s and self._past_peak():
                return "settled"
        else:
            self._band_since = None
        if now - self._phase_start >= self.config.max_s:
            return "timeout"
        return None

    def _past_peak(self) -> bool:
        """The smoothed heading has turned back from its extreme (the overshoot is in the record)."""
        first = self._first_index
        times = np.asarray(self.series["time"][first:])
        heading = np.asarray(self.series["heading"][first:])
        if len(times) < 7:
            return False
        smooth = smooth_heading(times, heading) * self.sign
        return int(np.argmax(smooth)) < len(smooth) - 3

    def _conclude(self, verdict: str, now: float, heading: float) -> list[Command]:
        first = self._first_index
        self.metrics = step_metrics(self.series["time"][first:], self.series["heading"][first:],
                                    self._course, self._target)
        speeds = self._speeds
        self.metrics.update(step_deg=math.degrees(self._target - self._course),
                            speed=float(np.mean(speeds)) if speeds else math.nan, ended=verdict,
                            duration_s=now - self._phase_start)
        if verdict in ("settled", "timeout"):
            self.why_undecided = None
            self._enter("done", now)
            self.finish(Status.SUCCESS)
            return []
        self.why_undecided = f"the step was {verdict}"
        if self.flights > self.config.repeats:
            self._enter("done", now)
            self.finish(Status.FAILURE, f"{self.label} gains at thrust {self.thrust:.2f}: "
                                        f"{self.why_undecided} twice, the step could not decide")
            return []
        self.sign = -self.sign  # fly it again, back the other way, once steady
        self._enter("settle", now)
        self._steady = SteadinessDetector(self.config.steadiness, "yaw", wrap_pi(heading))
        return [SetHeading(wrap_pi(self._target))]

    def terminate(self, status: Status) -> Sequence[Command]:
        if status is Status.ABORTED and math.isfinite(self._course):
            return [SetHeading(wrap_pi(self._course))]
        return []

    @property
    def decided(self) -> bool:
        return self.status is Status.SUCCESS

    def result(self) -> dict:
        return {"label": self.label, "thrust": self.thrust, "gains": self.gains, "decided": self.decided,
                "why_undecided": self.why_undecided, "flights": self.flights,
                "max_overshoot_pct": self.metrics.get("overshoot_pct", math.nan),
                "iae_s": self.metrics.get("iae_s", math.nan),
                "oscillations": self.metrics.get("oscillations", 0), "steps": [self.metrics] if self.metrics else [],
                "config": asdict(self.config), "series": self.series, "stage_times": self.stage_times,
                "aborted": self.status is Status.ABORTED}
