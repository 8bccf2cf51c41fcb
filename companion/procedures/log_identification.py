"""Identification from a recorded mission (``companion identify --log FILE``).

The same estimator a live campaign runs (SPEC C3: the SVF + RLS of
:class:`companion.numerics.identification.YawIdentifier`, with the campaign's P0 and holds for the
profile, ``CampaignConfig.resolved_for``) is run over every usable segment of the log
(:func:`companion.numerics.segments.find_segments`: steady speed, actuator activity, no
saturation, no gap). Each segment's model is then validated, as the campaign validates on a fresh
doublet, on a **different** used segment at a similar speed (within ``validation_speed_tolerance``):
the model is simulated on that segment's recorded rudder (eq. 3.35–3.37) and accepted at R² ≥ the
campaign's threshold if the estimate is a model (a22 < 0, b2 > 0, eq. 3.5–3.9). The accepted models are stored exactly as a live campaign stores its runs
(:meth:`Store.add_run`, one ``IdentificationAttempt`` each) under a campaign of kind ``"log"``,
and every requested gain schedule is designed from them (:meth:`Store.add_design`).

No gain is written anywhere: a live campaign writes its gains only after heading steps on the
vehicle confirmed them (``GainCheck``), which a log cannot do; the designed gains are stored with
the design, and ``companion identify --connect`` (or ``companion design``) puts them on a vehicle.
"""
from __future__ import annotations

import logging
import math
import os
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from behaviors.gain_scheduling import GainDesign
from behaviors.identification import IdentificationAttempt, ManoeuvreConfig, Rejection, no_model_reason
from companion.numerics.identification import ConvergenceRule, YawEstimate, YawIdentifier
from companion.numerics.segments import Segment, SegmentRules, find_segments
from companion.numerics.svf import DEFAULT_BANDWIDTH
from companion.numerics.validation import simulate_yaw, validate_yaw
from companion.procedures.campaign import CampaignConfig
from companion.records.flight_logs import SteeringRecord

log = logging.getLogger(__name__)

#: how many consecutive quiet samples eq. 3.39 needs, as in the campaign (reported, never a stop here)
_RULE = ConvergenceRule()


@dataclass(frozen=True)
class LogIdentificationConfig:
    """Segment rules, the campaign configuration whose estimator and schedules are used, and the
    validation pairing (see the module docstring)."""

    rules: SegmentRules = SegmentRules()
    campaign: CampaignConfig = CampaignConfig(axes=("yaw",))
    validation_speed_tolerance: float = 0.10  # relative
    # seconds of the log before each segment that only run the identifier's filters (no RLS): a
    # segment cut mid-turn then starts with filters that already follow the vehicle (8/λ: 0.3 %)
    warm_up_s: float = 8.0

    def to_dict(self) -> dict:
        return {"rules": asdict(self.rules), "validation_speed_tolerance": self.validation_speed_tolerance,
                "warm_up_s": self.warm_up_s,
                "estimator": {k: v for k, v in asdict(self.campaign.yaw).items()
                              if k in ("p0", "input_hold", "output_hold", "svf_bandwidth", "r2_threshold")},
                "schedules": list(self.campaign.schedules)}


@dataclass
class SegmentResult:
    """One segment's verdict and, when used, its model and validation."""

    segment: Segment
    number: int | None = None  # 1-based among the used segments
    attempt: IdentificationAttempt | None = None
    validated_on: int | None = None  # number of the segment it was validated on

    def summary(self) -> dict:
        out = self.segment.summary()
        out["number"] = self.number
        out["validated_on"] = self.validated_on
        if self.attempt is not None:
            out.update({"model": {k: v for k, v in vars(self.attempt.model).items() if k != "covariance"},
                        "r2": self.attempt.r2, "accepted": self.attempt.accepted,
                        "converged_s": self.attempt.converged_s})
        return out


@dataclass
class LogIdentification:
    """What :func:`identify_log` found: per-segment results, accepted attempts and designs."""

    record: SteeringRecord
    segments: list[SegmentResult] = field(default_factory=list)
    designs: dict[str, GainDesign] = field(default_factory=dict)
    design_errors: dict[str, str] = field(default_factory=dict)

    @property
    def attempts(self) -> list[IdentificationAttempt]:
        return [s.attempt for s in self.segments if s.attempt is not None]

    @property
    def accepted(self) -> list[IdentificationAttempt]:
        return [a for a in self.attempts if a.accepted]

    @property
    def status(self) -> str:
        return "completed" if self.accepted and not self.design_errors else "failed"

    @property
    def reason(self) -> str | None:
        if not self.attempts:
            return "no usable segment (" + "; ".join(sorted({_short(s.segment.reason) for s in self.segments})) + ")"
        if not self.accepted:
            return "no model passed validation on another segment at a similar speed"
        if self.design_errors:
            return "; ".join(f"{k} design: {v}" for k, v in self.design_errors.items())
        return None


def _short(reason: str) -> str:
    return reason.split(":")[0]


def _estimator(config: LogIdentificationConfig) -> ManoeuvreConfig:
    return config.campaign.yaw


def lead_in(t: np.ndarray, ok: np.ndarray, start: int, seconds: float, max_gap_s: float) -> int:
    """The earliest index at most ``seconds`` before ``start`` reachable without a gap or a missing value."""
    k = start
    while k > 0 and t[start] - t[k - 1] <= seconds and ok[k - 1] and t[k] - t[k - 1] <= max_gap_s:
        k -= 1
    return k


def _identify_segment(record: SteeringRecord, segment: Segment, manoeuvre: ManoeuvreConfig,
                      config: LogIdentificationConfig) -> YawIdentifier:
    a, b = segment.start, segment.stop
    ok = np.isfinite(record.heading) & np.isfinite(record.rudder)
    first = lead_in(record.t, ok, a, config.warm_up_s, config.rules.max_gap_s)
    identifier = YawIdentifier(
        bandwidth=manoeuvre.svf_bandwidth if manoeuvre.svf_bandwidth is not None else DEFAULT_BANDWIDTH,
        p0=manoeuvre.p0, rule=replace(_RULE, min_time_s=0.0), input_hold=manoeuvre.input_hold,
        output_hold=manoeuvre.output_hold, warm_up_s=float(record.t[a] - record.t[first]) - 1e-9)
    for time_s, heading, rudder in zip(record.t[first:b], record.heading[first:b], record.rudder[first:b]):
        identifier.update(float(time_s), float(heading), float(rudder))
    return identifier


def _initial_rate(t: np.ndarray, heading: np.ndarray, span_s: float = 0.5) -> float:
    """Mean heading rate over the first ``span_s`` seconds (the simulation's initial yaw rate)."""
    n = int(np.searchsorted(t, t[0] + span_s))
    if n < 2:
        return 0.0
    unwrapped = np.unwrap(heading[:n + 1])
    return float((unwrapped[-1] - unwrapped[0]) / (t[min(n, t.size - 1)] - t[0]))


def _validation_partner(results: list[SegmentResult], me: SegmentResult, tolerance: float) -> SegmentResult | None:
    """The used segment, other than ``me``, nearest in speed within ``tolerance`` (then nearest in time)."""
    candidates = [r for r in results if r.number is not None and r is not me
                  and abs(r.segment.speed - me.segment.speed) <= tolerance * me.segment.speed]
    if not candidates:
        return None
    return min(candidates, key=lambda r: (round(abs(r.segment.speed - me.segment.speed), 3),
                                          abs(r.segment.t_start - me.segment.t_start)))


def identify_log(record: SteeringRecord, config: LogIdentificationConfig = LogIdentificationConfig(),
                 profile=None) -> LogIdentification:
    """Segments, per-segment identification and cross-validation, and the gain designs (module docstring).

    ``profile`` resolves the campaign configuration (estimator holds, the heading schedule kind)."""
    if profile is not None and record.actuation is not None:
        profile = replace(profile, actuation=record.actuation)  # the log's own: its speed law (eq. S.3)
    campaign = config.campaign.resolved_for(profile) if profile is not None else config.campaign
    config = replace(config, campaign=campaign)
    manoeuvre = _estimator(config)
    segments = find_segments(record.t, record.heading, record.rudder, record.speed, record.thrust,
                             rudder_limit=record.rudder_limit, rules=config.rules)
    result = LogIdentification(record=record, segments=[SegmentResult(s) for s in segments])
    used = [r for r in result.segments if r.segment.used]
    models: dict[int, YawIdentifier] = {}
    for number, item in enumerate(used, start=1):
        item.number = number
        models[number] = _identify_segment(record, item.segment, manoeuvre, config)
    for number, item in enumerate(used, start=1):
        identifier = models[number]
        model = identifier.model()
        partner = _validation_partner(result.segments, item, config.validation_speed_tolerance)
        r2 = math.nan
        validation: dict = {}
        if partner is not None:
            item.validated_on = partner.number
            r2, validation = _validate(record, partner.segment, model)
        else:
            item.segment.reason += "; no other used segment within " \
                f"{100 * config.validation_speed_tolerance:.0f} % of its speed to validate on"
        passed = math.isfinite(r2) and r2 >= manoeuvre.r2_threshold
        not_model = no_model_reason(model) if passed else None  # as the campaign: no model, not accepted
        a, b = item.segment.start, item.segment.stop
        item.attempt = IdentificationAttempt(
            attempt=number, axis="yaw", thrust=item.segment.thrust, speed=item.segment.speed, model=model,
            r2=r2, accepted=passed and not_model is None, converged=bool(identifier.converged),
            converged_s=identifier.converged_at_s, criterion_met_from_s=identifier.criterion_met_from_s,
            training_s=item.segment.duration_s, samples=identifier.samples,
            training={"time": record.t[a:b].tolist(), "signal": record.heading[a:b].tolist(),
                      "actuator": record.rudder[a:b].tolist(),
                      "history": {k: [float(x) for x in v] for k, v in identifier.history_table.items()}},
            validation=validation, rejected_for=not_model, rejection=None if not_model is None else Rejection.NOT_A_MODEL)
    for kind in campaign.kinds():
        if kind.axis != "yaw":
            continue
        try:
            result.designs[kind.name] = kind.design(result.accepted)
        except ValueError as exc:
            result.design_errors[kind.name] = str(exc)
    log.info("log %s: %d segments, %d used, %d accepted", record.source, len(segments), len(used),
             len(result.accepted))
    return result


def _validate(record: SteeringRecord, segment: Segment, model: YawEstimate) -> tuple[float, dict]:
    a, b = segment.start, segment.stop
    t, heading, rudder = record.t[a:b], record.heading[a:b], record.rudder[a:b]
    rate0 = _initial_rate(t, heading)
    try:
        r2 = float(validate_yaw(model, t, heading, rudder, yaw_rate0=rate0))
        simulated = simulate_yaw(model, t, rudder, float(np.unwrap(heading)[0]), rate0).tolist()
    except (ValueError, FloatingPointError) as exc:
        log.warning("validation on segment at %.1f s failed: %s", segment.t_start, exc)
        return math.nan, {}
    return r2, {"time": t.tolist(), "signal": heading.tolist(), "actuator": rudder.tolist(), "simulated": simulated}


def store_log_identification(store, result: LogIdentification, config: LogIdentificationConfig,
                             profile_name: str) -> int:
    """Store as a live campaign does (runs, models, designs) under a campaign of kind ``"log"``,
    with the segment verdicts and the checks made on the log as a ``log_segments`` result."""
    record = result.record
    vehicle_id = store.add_vehicle(f"log:{os.path.basename(record.source)}", profile_name,
                                   {"log": record.source, "format": record.kind})
    campaign_id = store.start_campaign(vehicle_id, "log", {"log": record.source, "format": record.kind,
                                                           "profile": profile_name, **config.to_dict()})
    try:
        for attempt in result.attempts:
            store.add_run(campaign_id, attempt)
        for design in result.designs.values():
            store.add_design(campaign_id, design)
        store.add_behavior_result(campaign_id, "log_segments", "completed", {
            "log": log_summary(record), "segments": [s.summary() for s in result.segments]})
    except BaseException:
        store.finish_campaign(campaign_id, "failed", "interrupted while storing")
        raise
    store.finish_campaign(campaign_id, result.status, result.reason)
    return campaign_id


def log_summary(record: SteeringRecord) -> dict:
    return {"source": record.source, "format": record.kind, "samples": len(record), "duration_s": record.duration_s,
            "rudder_source": record.rudder_source, "speed_source": record.speed_source,
            "rudder_limit": record.rudder_limit, "checks": list(record.checks)}
