"""The speed loop's surge dynamics learned from a mission's own speed changes, and the speed-change
segments that verify learned speed gains (eq. L.4). Pure.

**The record** (:class:`MissionSpeedRecorder`). While the vehicle is in a mode the autopilot steers
and turns slower than ``max_yaw_rate_deg_s``, the throttle its speed loop outputs
(``Telemetry.thrust_ratio``: ArduRover's SERVO3 read back, or a skid pair's un-mixed throttle, eq.
S.1) and the speed are kept at ``sample_s``. A faster turn, a gap or a mode the autopilot does not
steer closes the *stretch*, and so does ``max_stretch_s``. The limit is not the campaign's straight
running (``SurgeRecorder``'s 3°/s): ArduRover's AUTO makes its speed changes inside the corners
(measured on SITL's boat at WP_SPEED 2: the demand falls from 2.0 to 1.6 m/s as the turn starts, at
14–21°/s, and is back at 2.0 while the boat still turns at 14–17°/s; the straights held one speed
change in a whole survey, the start of AUTO), so the corners are in. Eq. S.4 has no turning term: a
hull that loses speed to its own turning (sway–yaw coupling) is fitted with that loss in the record,
which the held-out validation and the verification of the flown speed changes judge. A stretch
*holds a speed change* when its speed spans at least ``min_change_m_s``: the acceleration from rest
to WP_SPEED at the start of AUTO, and each corner's slow-down and re-acceleration.

**The fit and its validation** (:meth:`MissionSpeedRecorder.fit`). Once ``min_changes`` stretches
hold a speed change, the surge model (eq. S.4) is fitted by :func:`companion.numerics.surge.fit_surge_model`
(the campaign's output-error fit, not a second one) on every closed stretch but the newest one that
holds a speed change, and validated on that one, which it has not seen: the speed simulated from its
recorded throttle (from its first measured speed), scored by R² (eq. 3.35's form, ``min_r2``) and its
RMS. A model that fails waits for the next speed change (fitted on one more stretch, validated on the
new one); the steady starts of (k, p) are the steadiest 2 s of each stretch (speed and throttle
within 2 %).

**Closed-loop bias.** On a mission the throttle is not an input the companion chose: it is the speed
loop's answer to the speed error, so whatever moves the speed apart from the throttle (a gust or a
wave on the hull, a current change, the speed estimate's own noise and drift) is answered by the
throttle, and the throttle is correlated with the equation error. A regression of the measured
acceleration on the throttle (equation error) is then biased — most on a lane held at WP_SPEED, where
the throttle only answers such disturbances — and it differentiates a noisy speed. The output-error
fit does neither: the model's speed is simulated from the measured throttle alone (the measured speed
enters only as each stretch's initial condition and as the target), so the speed noise never enters a
regressor, and a disturbance the throttle answered is a misfit of the simulated speed rather than a
bias in a regression. What is left (a disturbance that lasts for a whole stretch) is bounded by
fitting where the set-point drives the throttle — stretches that hold the mission's own speed changes,
whose demand (WP_SPEED at the start of AUTO and after each corner) is external to the disturbance —
and judged where it would show: the output error on a stretch the fit has not seen.

**Speed-change segments** (:class:`SpeedSegmentRecorder`, verification of eq. L.4). The speed loop's
asked-for and measured speed (PID_TUNING: ArduRover sends, for GCS_PID_MASK bit value 2, the speed
demand after its acceleration limit and the measured speed), in windows of the record's running
(the same yaw-rate limit) of at most ``window_s``; a window of at least ``min_s`` whose asked-for speed spans ``min_change_m_s`` or
more is a segment (a corner's slow-down and re-acceleration, the start of AUTO), its figure the RMS of
asked-for minus measured speed (m/s).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.checks import require_count, require_positive
from .surge import SurgeModel, fit_surge_model

#: a steady level: the speed and the throttle within this fraction of their mean over STEADY_S
STEADY_SPREAD = 0.02
STEADY_S = 2.0


@dataclass(frozen=True)
class SpeedRecordConfig:
    """When a sample is kept and when the record is fitted (module docstring)."""

    #: samples turning faster are left out. ArduRover's AUTO makes its speed changes inside the corners
    #: (measured on SITL's boat at WP_SPEED 2: the demand falls from 2.0 to 1.6 m/s as the turn starts
    #: and is back at 2.0 while it still turns at 14–17°/s), so they are in; 3.0 keeps the campaign's
    #: straight running only (``SurgeRecorder``), which on that survey held one speed change, the start
    max_yaw_rate_deg_s: float = 30.0
    sample_s: float = 0.1  # samples kept this far apart (the fit integrates at ≤ 50 ms anyway)
    max_gap_s: float = 0.5  # a longer gap closes the stretch
    min_stretch_s: float = 5.0  # a shorter stretch is dropped
    max_stretch_s: float = 60.0  # a longer one is closed there (and the next one begins)
    min_change_m_s: float = 0.3  # a stretch whose speed spans this holds a speed change
    min_changes: int = 2  # stretches holding a speed change before a fit (one of them held out)
    min_r2: float = 0.9  # the held-out stretch's R² (eq. 3.35's form)
    max_stretches: int = 6  # the newest stretches kept (memory, and the fit's time in the resident loop)

    def __post_init__(self) -> None:
        require_positive(self, "max_yaw_rate_deg_s", "sample_s", "max_gap_s", "min_stretch_s", "max_stretch_s",
                         "min_change_m_s", "min_r2")
        require_count(self, "min_changes", "max_stretches")
        if self.min_changes < 2:
            raise ValueError("SpeedRecordConfig.min_changes: at least 2 (one is held out for the validation)")
        if self.max_stretches < self.min_changes:
            raise ValueError("SpeedRecordConfig.max_stretches must hold min_changes stretches")


@dataclass(frozen=True)
class SpeedStretch:
    """One closed stretch of the record: times (vehicle s), throttle (0..1) and speed (m/s)."""

    times: np.ndarray
    throttle: np.ndarray
    speed: np.ndarray

    @property
    def t_start(self) -> float:
        return float(self.times[0])

    @property
    def change_m_s(self) -> float:
        """The speed's span over the stretch (m/s)."""
        return float(np.ptp(self.speed))

    def steady_level(self) -> tuple[float, float] | None:
        """(throttle, speed) of the steadiest ``STEADY_S`` of the stretch, when both stayed within
        ``STEADY_SPREAD`` of their mean there (None: never steady)."""
        best: tuple[float, float, float] | None = None
        start = 0
        for stop in range(len(self.times)):
            while self.times[stop] - self.times[start] > STEADY_S:
                start += 1
            if self.times[stop] - self.times[start] < 0.9 * STEADY_S:
                continue
            u, t = self.speed[start:stop + 1], self.throttle[start:stop + 1]
            mean_u, mean_t = float(np.mean(u)), float(np.mean(t))
            if not (mean_u > 0.0 and mean_t > 0.0):
                continue
            spread = max(float(np.ptp(u)) / mean_u, float(np.ptp(t)) / mean_t)
            if spread <= STEADY_SPREAD and (best is None or spread < best[0]):
                best = (spread, mean_t, mean_u)
        return None if best is None else (best[1], best[2])


@dataclass(frozen=True)
class SpeedFit:
    """A fit of eq. S.4 on the mission's stretches and its validation on a held-out one (eq. L.4):
    the model (its own R² is over the stretches it was fitted on), the held-out R² and RMS (m/s), the
    stretches used, and whether it is validated."""

    model: SurgeModel
    validation_r2: float
    validation_rms_m_s: float
    fitted_on: int
    held_out_start_s: float
    validated: bool
    speed_range: tuple[float, float]  # the steady speeds (or the record's, without a steady level)

    def to_dict(self) -> dict:
        def finite(value: float) -> float | None:
            return value if math.isfinite(value) else None
        return {"surge": self.model.describe(), "gain": self.model.gain, "exponent": self.model.exponent,
                "gamma": self.model.gamma, "lag_s": self.model.lag, "fit_r2": finite(self.model.r2),
                "validation_r2": finite(self.validation_r2), "validation_rms_m_s": finite(self.validation_rms_m_s),
                "fitted_on": self.fitted_on, "held_out_start_s": self.held_out_start_s, "validated": self.validated,
                "speed_range": list(self.speed_range)}


def validate_surge(model: SurgeModel, stretch: SpeedStretch) -> tuple[float, float]:
    """(R², RMS m/s) of the speed simulated by ``model`` from ``stretch``'s throttle against its
    measured speed (output error on a record the model was not fitted on)."""
    simulated = model.simulate(stretch.times, stretch.throttle, float(stretch.speed[0]))
    error = stretch.speed - simulated
    spread = float(np.sum((stretch.speed - stretch.speed.mean()) ** 2))
    r2 = 1.0 - float(error @ error) / spread if spread > 0.0 else math.nan
    return r2, float(np.sqrt(np.mean(error ** 2)))


class MissionSpeedRecorder:
    """Streams (time, throttle, speed, yaw rate, allowed); closes stretches; :meth:`fit` when the
    record holds enough speed change (module docstring)."""

    def __init__(self, config: SpeedRecordConfig = SpeedRecordConfig()) -> None:
        self.config = config
        self.stretches: list[SpeedStretch] = []
        self._rows: list[tuple[float, float, float]] = []
        self._fitted_changes = 0  # stretches with a speed change when the last fit was tried
        self.attempts: list[SpeedFit] = []

    @property
    def changes(self) -> int:
        """Closed stretches holding a speed change."""
        return sum(1 for s in self.stretches if s.change_m_s >= self.config.min_change_m_s)

    def add(self, t: float, throttle: float, speed: float, yaw_rate: float, allowed: bool) -> None:
        c = self.config
        straight = math.isfinite(yaw_rate) and abs(yaw_rate) < math.radians(c.max_yaw_rate_deg_s)
        if not (allowed and straight and all(math.isfinite(v) for v in (t, throttle, speed))):
            self._close()
            return
        if self._rows and t - self._rows[-1][0] > c.max_gap_s:
            self._close()
        if self._rows and t - self._rows[-1][0] < c.sample_s - 1e-9:
            return
        self._rows.append((t, throttle, speed))
        if t - self._rows[0][0] >= c.max_stretch_s:
            self._close()

    def _close(self) -> None:
        rows, self._rows = self._rows, []
        if len(rows) < 2 or rows[-1][0] - rows[0][0] < self.config.min_stretch_s:
            return
        data = np.asarray(rows)
        self.stretches.append(SpeedStretch(data[:, 0], data[:, 1], data[:, 2]))
        del self.stretches[:-self.config.max_stretches]

    def fit(self) -> SpeedFit | None:
        """A new fit when a stretch with a speed change closed since the last one and there are
        ``min_changes`` of them (module docstring); None otherwise, or when nothing can be fitted."""
        c = self.config
        changing = [k for k, s in enumerate(self.stretches) if s.change_m_s >= c.min_change_m_s]
        if len(changing) < c.min_changes or self.changes <= self._fitted_changes:
            return None
        self._fitted_changes = self.changes
        held = changing[-1]
        train = [s for k, s in enumerate(self.stretches) if k != held]
        times = np.concatenate([s.times for s in train])
        throttle = np.concatenate([s.throttle for s in train])
        speed = np.concatenate([s.speed for s in train])
        bounds, start = [], 0
        for s in train:
            bounds.append((start, start + len(s.times)))
            start += len(s.times)
        levels = [level for s in train if (level := s.steady_level()) is not None]
        if not levels:  # the law's start from the end of each stretch (the fit decides)
            levels = [(float(s.throttle[-1]), float(s.speed[-1])) for s in train
                      if s.throttle[-1] > 0.0 and s.speed[-1] > 0.0]
        try:
            model = fit_surge_model(times, throttle, speed, levels, bounds)
        except ValueError:
            return None
        r2, rms = validate_surge(model, self.stretches[held])
        steady = [u for _, u in levels] if any(s.steady_level() for s in train) else \
            [float(np.percentile(speed, 10)), float(np.percentile(speed, 90))]
        fit = SpeedFit(model=model, validation_r2=r2, validation_rms_m_s=rms, fitted_on=len(train),
                       held_out_start_s=self.stretches[held].t_start,
                       validated=bool(math.isfinite(r2) and r2 >= c.min_r2 and model.gamma > 0.0),
                       speed_range=(min(steady), max(steady)))
        self.attempts.append(fit)
        return fit


@dataclass(frozen=True)
class FlownSpeedSegment:
    """A speed-change segment (module docstring): times (vehicle s), asked-for and measured speed
    (m/s), and the throttle the speed loop output when it began (0..1; NaN when unknown): the state
    a replay starts from."""

    t_start: float
    times: np.ndarray
    desired: np.ndarray
    achieved: np.ndarray
    throttle0: float

    @property
    def change_m_s(self) -> float:
        return float(np.ptp(self.desired))

    @property
    def speed(self) -> float:
        return float(np.mean(self.achieved))

    def error_m_s(self, achieved: np.ndarray | None = None) -> float:
        """RMS of asked-for minus measured speed (or ``achieved``, a replay), m/s."""
        got = self.achieved if achieved is None else achieved
        return float(np.sqrt(np.mean((self.desired - got) ** 2)))


class SpeedSegmentRecorder:
    """Streams (time, asked-for speed, measured speed, throttle, recorded: within the record's yaw-rate
    limit in a mode the autopilot steers); :meth:`add` returns a
    :class:`FlownSpeedSegment` when a window with a speed change closes (module docstring)."""

    def __init__(self, window_s: float = 20.0, min_s: float = 5.0, min_change_m_s: float = 0.3,
                 max_gap_s: float = 1.0) -> None:
        if not (window_s > 0 and 0 < min_s <= window_s and min_change_m_s > 0 and max_gap_s > 0):
            raise ValueError("SpeedSegmentRecorder needs positive lengths (min_s ≤ window_s), change and gap")
        self.window_s, self.min_s, self.min_change, self.max_gap_s = window_s, min_s, min_change_m_s, max_gap_s
        self._rows: list[tuple[float, float, float]] = []
        self._throttle0 = math.nan
        self.interrupted = 0
        #: windows without a speed change (the speed held): (start, RMS speed error m/s)
        self.holds: list[tuple[float, float]] = []

    def discard(self) -> None:
        """Drop the window being recorded (the gains changed during it)."""
        if self._rows:
            self.interrupted += 1
        self._rows = []

    def add(self, t: float, desired: float, achieved: float, throttle: float, recorded: bool) -> FlownSpeedSegment | None:
        usable = recorded and all(math.isfinite(v) for v in (t, desired, achieved))
        closed = None
        if self._rows and (not usable or t - self._rows[-1][0] > self.max_gap_s):
            closed = self._close()
        if not usable:
            return closed
        if not self._rows:
            self._throttle0 = throttle
        self._rows.append((t, desired, achieved))
        if t - self._rows[0][0] >= self.window_s:
            return self._close()
        return closed

    def _close(self) -> FlownSpeedSegment | None:
        rows, self._rows = self._rows, []
        if len(rows) < 2 or rows[-1][0] - rows[0][0] < self.min_s:
            return None
        data = np.asarray(rows)
        segment = FlownSpeedSegment(float(data[0, 0]), data[:, 0], data[:, 1], data[:, 2], float(self._throttle0))
        if segment.change_m_s >= self.min_change:
            return segment
        self.holds.append((segment.t_start, segment.error_m_s()))
        return None
