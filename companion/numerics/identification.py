"""Online SVF-RLS identification of the yaw and pitch models (SPEC C3; thesis 002 §3.2, App. B).

Yaw (eq. 3.5–3.8, 3.14–3.15): ψ̇ = r, ṙ = a22·r + b2·(δr − δ0), i.e.
``ψ̈f = [ψ̇f, δf, −1]·[a22, b2, C0]ᵀ`` with C0 = b2·δ0, where ψf, δf are the heading and rudder
passed through the same state-variable filter λ²/(s+λ)² (:mod:`companion.numerics.svf`).

Pitch (App. B, eq. B.10/B.12): q̇ = −c22·q − c23·θ + d2·δs + Cb, i.e.
``θ̈f = [−θ̇f, −θf, δsf, 1]·[c22, c23, d2, Cb]ᵀ``.

Discretisation of the two SVFs (both exact, at the actual interval of every sample): the actuator
is commanded and held between samples, so its filter uses the thesis' zero-order hold (eq. 3.29–3.31,
``input_hold="zoh"``). The measured output (heading, pitch) is a smooth continuous signal, for which
a ZOH amounts to a half-sample lag against the actuator; at 20 Hz that lag biases b2 by ≈ 2 % on
noise-free data (measured: tests/test_numerics_identification.py). The output filter therefore
uses a first-order hold by default (``output_hold="foh"``, bias < 0.05 %); ``output_hold="zoh"``
reproduces the thesis' discretisation exactly.

Note on P0: the thesis' P0 = 100·I acts as a ridge prior pulling Θ towards 0 with weight 1/P0;
on a single 16.5 s doublet at 20 Hz (noise-free) it leaves a22 ≈ 8 % and b2 ≈ 4–6 % low. P0 is the
thesis' value by default (SPEC C3) and exposed; P0 ≥ 1e4 removes the effect.

Both filters are started at rest at the first sample (the campaign settles the vehicle on a
straight course first, so the first sample is a steady state); the RLS is fed from that sample on.
Convergence follows eq. 3.39, ‖Θk − Θk−1‖₂ < tolerance, required on ``consecutive`` successive
samples (thesis §3.4: "the criterion should be met consecutively for a certain number of times
before the training is stopped") and not before ``min_time_s`` of data (see :class:`ConvergenceRule`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .angles import wrap_pi
from .rls import RecursiveLeastSquares
from .svf import DEFAULT_BANDWIDTH, StateVariableFilter


@dataclass(frozen=True)
class ConvergenceRule:
    """Stopping rule of eq. 3.39.

    ``consecutive`` = 20 samples (1 s at the thesis' 20 Hz): long enough that the quiet samples
    while the rudder is held between the doublet's switches do not end training, short enough to
    stop near the thesis' "converged after about 12 s" of a 16.5 s window. ``min_time_s`` = 6 s is
    the thesis procedure's end of excitation (2 s lead + 4 s doublet): before it the estimate
    has not yet seen the whole excitation and a quiet stretch (e.g. before the doublet, where Θ
    does not move at all) must not count as convergence.
    """

    tolerance: float = 1e-3
    consecutive: int = 20
    min_time_s: float = 6.0
    # the drift rule, a noise-aware alternative: converged once Θ has moved by less than this fraction of
    # ‖Θ‖ over the last ``drift_window_s`` (measurement noise keeps the per-sample ‖ΔΘ‖ of eq. 3.39
    # near 10⁻³ long after the estimates settled); None: eq. 3.39 as above
    relative_drift: float | None = None
    drift_window_s: float = 1.5
    # the noise-band rule, taken by the quick procedure: converged once, over the last
    # ``noise_window_s``, every parameter stayed within ``noise_band``·σ_i of its current value, σ_i
    # the standard error the RLS covariance predicts (σ̂²·P, P of the RLS recursion): Θ then moves by less than
    # its own noise floor, and more samples of a decayed response cannot move it further. None: eq. 3.39
    noise_band: float | None = None
    noise_window_s: float = 1.0


def not_a_model(a22: float, b2: float, delta0: float) -> str | None:
    """Why (a22, b2, δ0) is no yaw model (eq. 3.5–3.9: a22 < 0, b2 > 0, all finite), in one
    sentence naming each number at fault; None when it is one."""
    problems = [f"{name} = {value:g}: not a finite number"
                for name, value in (("a22", a22), ("b2", b2), ("delta0", delta0)) if not math.isfinite(value)]
    if math.isfinite(a22) and not a22 < 0.0:
        problems.append(f"a22 = {a22:g} ≥ 0: not a stable model")
    if math.isfinite(b2) and not b2 > 0.0:
        problems.append(f"b2 = {b2:g} ≤ 0: the rudder turns the vehicle the wrong way")
    return "; ".join(problems) or None


@dataclass(frozen=True)
class YawEstimate:
    """What an estimator gives for ṙ = a22·r + b2·(δr − δ0) (eq. 3.6): any numbers, NaN included.

    The online identifier (eq. 3.32–3.34), the Kalman tracker (eq. L.1), the offline fit (eq. 3.38) and
    the bounded-pole fit (eq. 3.38p) can all come out unstable (a22 ≥ 0) or inverted (b2 ≤ 0) on real
    data; :meth:`model` is the one way from an estimate to a :class:`YawModel`, what designs, schedules
    and predictions take. ``covariance`` is the 3×3 covariance of [a22, b2, C0].

    Stored (``companion.records.serialise``) under the tag ``"YawEstimate"``; a :class:`YawModel` keeps
    its tag ``"YawModel"``, so the JSON of every model stored before is unchanged. A record tagged
    ``"YawModel"`` whose numbers are no model (stored before models validated: a rejected attempt's
    inverted estimate) is read back as a ``YawEstimate``.
    """

    a22: float
    b2: float
    delta0: float
    covariance: list | np.ndarray | None = None

    @property
    def c0(self) -> float:
        """C0 = b2·δ0 (eq. 3.7)."""
        return self.b2 * self.delta0

    @property
    def why_not_model(self) -> str | None:
        """Why this estimate is no :class:`YawModel` (e.g. "a22 = 0.6 ≥ 0: not a stable model"), None
        when it is one."""
        return not_a_model(self.a22, self.b2, self.delta0)

    @property
    def is_model(self) -> bool:
        """a22 < 0, b2 > 0 and a22, b2, δ0 finite (eq. 3.5–3.9)."""
        return self.why_not_model is None

    def model(self) -> YawModel:
        """This estimate as a :class:`YawModel` (itself when it is one); ValueError naming what is wrong
        when it is no model."""
        if isinstance(self, YawModel):
            return self
        problem = self.why_not_model
        if problem is not None:
            raise ValueError(problem)
        return YawModel(a22=self.a22, b2=self.b2, delta0=self.delta0, covariance=self.covariance)


@dataclass(frozen=True)
class YawModel(YawEstimate):
    """ṙ = a22·r + b2·(δr − δ0) (eq. 3.6) as designs, schedules and predictions take it: validated at
    construction, a22 < 0 (a stable yaw, 1/|a22| its time constant), b2 > 0 (the rudder turns the
    vehicle the way it is put) and a22, b2, δ0 finite (eq. 3.5–3.9). ValueError otherwise, naming
    what is wrong. ``covariance`` is the 3×3 covariance of [a22, b2, C0]."""

    def __post_init__(self) -> None:
        problem = self.why_not_model
        if problem is not None:
            raise ValueError(problem)


@dataclass
class PitchModel:
    """q̇ = −c22·q − c23·θ + d2·δs + Cb (eq. B.10). ``covariance`` is that of [c22, c23, d2, Cb]."""

    c22: float
    c23: float
    d2: float
    cb: float
    covariance: list | np.ndarray | None = None

    @property
    def delta_s0(self) -> float:
        """Steady-state elevator term δs0 = Cb/d2 (eq. B.13); NaN while d2 = 0."""
        return self.cb / self.d2 if self.d2 != 0.0 else math.nan


@dataclass
class IdentificationHistory:
    """Per accepted sample: time since the first sample, the parameter vector and its step norm."""

    time_s: list[float] = field(default_factory=list)
    theta: list[list[float]] = field(default_factory=list)
    step_norm: list[float] = field(default_factory=list)


class _SvfRlsIdentifier:
    """Shared machinery: two SVFs (output, input), an RLS, the convergence test, the history."""

    n_parameters = 0
    wraps_output = False

    def __init__(
        self,
        bandwidth: float = DEFAULT_BANDWIDTH,
        p0: float = 100.0,
        rule: ConvergenceRule = ConvergenceRule(),
        forgetting: float = 1.0,
        output_hold: str = "foh",
        input_hold: str = "zoh",
        warm_up_s: float = 0.0,
    ) -> None:
        self.bandwidth = bandwidth
        # samples within warm_up_s of the first only run the filters (no RLS update): a record that
        # does not start at rest (a log cut mid-turn) lets their start-up transient die out first;
        # it decays as e^(−λt)(1 + λt): 0.3 % of the initial error after 8/λ
        self.warm_up_s = float(warm_up_s)
        self.rule = rule
        self._output_filter = StateVariableFilter(bandwidth, hold=output_hold)
        self._input_filter = StateVariableFilter(bandwidth, hold=input_hold)
        self.rls = RecursiveLeastSquares(self.n_parameters, p0=p0, forgetting=forgetting)
        self.history = IdentificationHistory()
        self.samples = 0
        self.skipped = 0
        self.warming = 0  # samples that only advanced the filters (warm_up_s)
        self.converged = False
        self.converged_at_s: float | None = None  # when training may stop (the rule held long enough)
        self.criterion_met_from_s: float | None = None  # when eq. 3.39 started to hold for good
        self._quiet_start = 0.0
        self._first_time: float | None = None
        self._rls_start: float | None = None  # time of the first RLS update (after the warm-up)
        self._last_time: float | None = None
        self._last_raw_output: float | None = None
        self._output_unwrapped = 0.0
        self._quiet_count = 0

    def _regression(self, out_f: tuple[float, float, float], in_f: tuple[float, float, float]):
        raise NotImplementedError

    def _step(self, time_s: float, output: float, actuator: float) -> None:
        if not (math.isfinite(time_s) and math.isfinite(output) and math.isfinite(actuator)):
            self.skipped += 1
            return
        if self._last_time is not None and not (time_s > self._last_time):
            self.skipped += 1  # duplicate or out-of-order time stamp
            return
        if self.wraps_output and self._last_raw_output is not None:
            self._output_unwrapped += wrap_pi(output - self._last_raw_output)
        else:
            self._output_unwrapped = output
        self._last_raw_output = output

        if self._first_time is None or self._last_time is None:  # set together: the first sample
            self._first_time = time_s
            self._output_filter.reset(self._output_unwrapped)
            self._input_filter.reset(actuator)
            out_f = self._output_filter.outputs(self._output_unwrapped)
            in_f = self._input_filter.outputs(actuator)
        else:
            dt = time_s - self._last_time
            out_f = self._output_filter.update(self._output_unwrapped, dt)
            in_f = self._input_filter.update(actuator, dt)
        self._last_time = time_s
        if time_s - self._first_time < self.warm_up_s:
            self.warming += 1
            return
        if self._rls_start is None:
            self._rls_start = time_s

        previous = self.rls.theta.copy()
        regressor, target = self._regression(out_f, in_f)
        theta = self.rls.update(regressor, target)
        self.samples += 1
        elapsed = time_s - self._rls_start  # the first sample's time unless there is a warm-up
        step_norm = float(np.linalg.norm(theta - previous))
        self.history.time_s.append(elapsed)
        self.history.theta.append(theta.tolist())
        self.history.step_norm.append(step_norm)

        # eq. 3.39, met on `consecutive` successive samples after min_time_s
        if elapsed >= self.rule.min_time_s and step_norm < self.rule.tolerance:
            if self._quiet_count == 0:
                self._quiet_start = elapsed
            self._quiet_count += 1
        else:
            self._quiet_count = 0
        if not self.converged and self.rule.noise_band is not None and self._within_noise(elapsed, theta):
            self.converged = True
            self.converged_at_s = elapsed
            self.criterion_met_from_s = elapsed - self.rule.noise_window_s
        if not self.converged and self.rule.relative_drift is not None and self._drift_settled(elapsed, theta):
            self.converged = True
            self.converged_at_s = elapsed
            self.criterion_met_from_s = elapsed - self.rule.drift_window_s
        if not self.converged and self._quiet_count >= self.rule.consecutive:
            self.converged = True
            self.converged_at_s = elapsed
            # the thesis' figure (Fig. 3.11: "met from 12 s onward") is when the quiet run began
            self.criterion_met_from_s = self._quiet_start

    def _drift_settled(self, elapsed: float, theta: np.ndarray) -> bool:
        """The drift rule: over the last ``drift_window_s`` (all of it after ``min_time_s``) no
        estimate was farther than ``relative_drift``·‖Θ‖ from the current one."""
        rule = self.rule
        if rule.relative_drift is None or elapsed - rule.drift_window_s < rule.min_time_s:
            return False
        scale = float(np.linalg.norm(theta))
        if not scale > 0.0:
            return False
        return all(float(np.linalg.norm(past - theta)) <= rule.relative_drift * scale
                   for past in self._recent_thetas(elapsed - rule.drift_window_s))

    def _recent_thetas(self, since_s: float):
        """The recorded Θ (newest first) of the samples at or after ``since_s``."""
        times, thetas = self.history.time_s, self.history.theta
        index = len(times) - 1
        while index >= 0 and times[index] >= since_s:
            yield np.asarray(thetas[index])
            index -= 1

    def _within_noise(self, elapsed: float, theta: np.ndarray) -> bool:
        """The noise-aware rule (``ConvergenceRule.noise_band``): over the last ``noise_window_s``
        (all of it after ``min_time_s``) |Θ_i(t') − Θ_i(t)| < band·σ_i(t) for every parameter i."""
        rule = self.rule
        if elapsed - rule.noise_window_s < rule.min_time_s or self.rls.samples <= self.n_parameters:
            return False
        variances = np.diag(self.rls.parameter_covariance())
        if not np.all(np.isfinite(variances)) or np.any(variances <= 0.0):
            return False
        limits = rule.noise_band * np.sqrt(variances)
        return all(np.all(np.abs(past - theta) < limits) for past in self._recent_thetas(elapsed - rule.noise_window_s))

    @property
    def theta(self) -> np.ndarray:
        return self.rls.theta.copy()


class YawIdentifier(_SvfRlsIdentifier):
    """Online yaw identification, thesis §3.2 (SVF eq. 3.26–3.31, regression eq. 3.14–3.15, RLS, eq. 3.39).

    ``update(time_s, heading, rudder)``: heading in rad (wrapped or not; unwrapped internally),
    rudder deflection in rad, time in vehicle seconds. Samples with a NaN/inf value or a
    non-increasing time stamp are skipped (counted in ``skipped``).
    """

    n_parameters = 3
    wraps_output = True

    def _regression(self, out_f, in_f):
        heading_f, heading_rate_f, heading_acc_f = out_f
        rudder_f = in_f[0]
        return (heading_rate_f, rudder_f, -1.0), heading_acc_f

    def update(self, time_s: float, heading: float, rudder: float) -> YawEstimate:
        self._step(time_s, heading, rudder)
        return self.model()

    def model(self) -> YawEstimate:
        """Current estimate, a model or not (:meth:`YawEstimate.model` makes it one); δ0 = C0/b2
        (reported as 0 while b2 is still exactly 0)."""
        a22, b2, c0 = (float(v) for v in self.rls.theta)
        delta0 = c0 / b2 if b2 != 0.0 else 0.0
        covariance = self.rls.parameter_covariance() if self.rls.samples > self.n_parameters else None
        return YawEstimate(a22=a22, b2=b2, delta0=delta0, covariance=covariance)

    @property
    def history_table(self) -> dict[str, list[float]]:
        """For the convergence plot (Fig. 3.7): time_s, a22, b2, delta0, step_norm per sample."""
        thetas = np.asarray(self.history.theta) if self.history.theta else np.zeros((0, 3))
        b2 = thetas[:, 1]
        with np.errstate(divide="ignore", invalid="ignore"):
            delta0 = np.where(b2 != 0.0, thetas[:, 2] / np.where(b2 != 0.0, b2, 1.0), 0.0)
        return {
            "time_s": list(self.history.time_s),
            "a22": thetas[:, 0].tolist(),
            "b2": b2.tolist(),
            "delta0": delta0.tolist(),
            "step_norm": list(self.history.step_norm),
        }


class PitchIdentifier(_SvfRlsIdentifier):
    """Online pitch identification, thesis App. B (eq. B.10, B.12) with the chapter-3 machinery.

    ``update(time_s, pitch, elevator)``; same skipping rules as :class:`YawIdentifier`; pitch is
    not wrapped.
    """

    n_parameters = 4
    wraps_output = False

    def _regression(self, out_f, in_f):
        pitch_f, pitch_rate_f, pitch_acc_f = out_f
        elevator_f = in_f[0]
        return (-pitch_rate_f, -pitch_f, elevator_f, 1.0), pitch_acc_f

    def update(self, time_s: float, pitch: float, elevator: float) -> PitchModel:
        self._step(time_s, pitch, elevator)
        return self.model()

    def model(self) -> PitchModel:
        c22, c23, d2, cb = (float(v) for v in self.rls.theta)
        covariance = self.rls.parameter_covariance() if self.rls.samples > self.n_parameters else None
        return PitchModel(c22=c22, c23=c23, d2=d2, cb=cb, covariance=covariance)

    @property
    def history_table(self) -> dict[str, list[float]]:
        thetas = np.asarray(self.history.theta) if self.history.theta else np.zeros((0, 4))
        return {
            "time_s": list(self.history.time_s),
            "c22": thetas[:, 0].tolist(),
            "c23": thetas[:, 1].tolist(),
            "d2": thetas[:, 2].tolist(),
            "cb": thetas[:, 3].tolist(),
            "step_norm": list(self.history.step_norm),
        }
