"""Application services: run procedures over a link with the store, progress and abort sources.

Used by the command line (``identify``, ``run-behavior``, ``run``, ``rehearse``). Everything that
touches the store or the ground station lives here, so behaviours stay pure.

Ground-station protocol (SPEC C1): COMMAND_LONG aimed at component 191 —
``MAV_CMD_USER_1`` starts the identification campaign, ``MAV_CMD_USER_2`` roll stabilisation,
``MAV_CMD_USER_3`` minimum-speed seeking, ``MAV_CMD_USER_4`` aborts whatever runs. A start is
answered with COMMAND_ACK IN_PROGRESS carrying the progress (percent) as the procedure advances, and
a final ACCEPTED (completed) or FAILED (aborted, with the reason in a STATUSTEXT).
"""
from __future__ import annotations

import logging
import os
import signal
import sys
from dataclasses import dataclass, replace
from typing import Any, Callable

from pymavlink.dialects.v20.common import (MAV_RESULT_ACCEPTED, MAV_RESULT_FAILED, MAV_RESULT_IN_PROGRESS,
                                           MAV_RESULT_TEMPORARILY_REJECTED)

from companion.link.port import VehiclePort
from companion.interface import Behavior, Telemetry
from companion.procedures.campaign import (AttemptRecorded, CampaignConfig, DesignMade, GainsWritten,
                                           IdentificationCampaign, SpeedTuned, StepsChecked)
from behaviors.base import footprint_of
from companion.procedures.readiness import await_ready
from companion.procedures.registry import PROCEDURES, ProcedureContext
from companion.procedures.results import Outcome, ProcedureResult
from companion.procedures.runner import (RestoreGuard, RestorePoint, RunOutcome, SafetyLimits, not_started,
                                         run_procedure)
from companion.procedures.trail import TrailRecorder, vehicle_identity
from companion.link.errors import LinkError
from companion.link.modes import HAND_FLOWN_MODES
from companion.records.store import Store, StoreError

__all__ = ["MAV_RESULT_ACCEPTED", "MAV_RESULT_FAILED", "MAV_RESULT_IN_PROGRESS", "MAV_RESULT_TEMPORARILY_REJECTED",
           "AbortFlag", "ConsoleProgress", "GcsProgress", "NamedRun", "drain_campaign_events", "install_signal_handlers",
           "run_campaign", "run_named_behavior", "run_named_procedure", "vehicle_record"]

log = logging.getLogger(__name__)


class AbortFlag:
    """The first abort reason wins; polled by the runner once per telemetry snapshot."""

    def __init__(self) -> None:
        self.reason: str | None = None
        self.guard = RestoreGuard()  # what a signal may interrupt now, and what a restore has left

    def request(self, reason: str) -> None:
        if self.reason is None:
            self.reason = reason

    def clear(self) -> None:
        self.reason = None

    def __call__(self) -> str | None:
        return self.reason


#: the signal that force-exits (1: the abort request, 2: break a blocking call or "restoring...")
FORCE_EXIT_SIGNAL = 3


def install_signal_handlers(flag: AbortFlag, stream=None) -> Callable[[], None]:
    """SIGINT/SIGTERM request an abort (the runner then restores the vehicle) instead of killing us
    mid-procedure. A second SIGINT inside a procedure's step loop raises KeyboardInterrupt (for a
    procedure stuck in a blocking call); the runner still aborts and restores. A restore is never
    interrupted: a signal during it only says so, and the third signal exits at once (code 130)
    after printing what is still unrestored. Messages go to ``stream`` (stderr). Returns an undo
    function."""
    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    received = [0]

    def say(text: str) -> None:
        out = stream or sys.stderr
        out.write(text + "\n")
        out.flush()

    def handler(signum, _frame):
        received[0] += 1
        guard = flag.guard
        breakable = guard.interruptible or (guard.active == 0 and not guard.restoring)
        if received[0] >= FORCE_EXIT_SIGNAL and not breakable:
            if guard.restoring:
                left = ", ".join(guard.pending) or "nothing left"
            else:
                left = "a procedure is ending; its restore had not started" if guard.active else "nothing to restore"
            say(f"forced exit: NOT restored: {left}")
            os._exit(130)
        flag.request(f"signal {signal.Signals(signum).name}")
        if received[0] >= 2 and signum == signal.SIGINT and breakable:
            raise KeyboardInterrupt
        if received[0] >= 2 and breakable:  # nothing to protect: no countdown (none would be kept)
            say("stopping: nothing to restore")
        elif received[0] >= 2:
            doing = f"restoring the vehicle ({', '.join(guard.pending) or 'finishing'})" if guard.restoring \
                else "ending the procedure and restoring the vehicle"
            say(f"{doing}; signal {FORCE_EXIT_SIGNAL - received[0]} more time(s) to exit without restoring")

    return handle_stop_signals(handler, previous)


def handle_stop_signals(handler, previous: dict | None = None) -> Callable[[], None]:
    """Install ``handler`` for SIGINT and SIGTERM; returns the function that puts back the handlers
    found (``previous``, when the caller already read them)."""
    previous = previous or {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    for sig in previous:
        signal.signal(sig, handler)

    def undo() -> None:
        for sig, old in previous.items():
            signal.signal(sig, old)

    return undo


@dataclass
class GcsProgress:
    """COMMAND_ACK IN_PROGRESS with the progress percent, then the final result (SPEC C1)."""

    link: VehiclePort
    command: int
    target_system: int = 0
    target_component: int = 0
    _last: int = -1

    def update(self, fraction: float) -> None:
        percent = int(max(0.0, min(1.0, fraction)) * 100)
        if percent >= self._last + 5 or (percent == 100 and self._last != 100):
            self._last = percent
            self.link.ground.send_command_ack(self.command, MAV_RESULT_IN_PROGRESS, percent,
                                              self.target_system, self.target_component)

    def finish(self, outcome: RunOutcome) -> None:
        result = MAV_RESULT_ACCEPTED if outcome.status == "completed" else MAV_RESULT_FAILED
        self.link.ground.send_command_ack(self.command, result,
                                          100 if result == MAV_RESULT_ACCEPTED else max(self._last, 0),
                                          self.target_system, self.target_component)


class ConsoleProgress:
    """A one-line progress display on stderr for long procedures (no dependency is allowed for this,
    and a single rewritten line is all a terminal user needs)."""

    def __init__(self, label: str, enabled: bool = True) -> None:
        self.label = label
        self.enabled = enabled and sys.stderr.isatty()
        self._shown = -1

    def update(self, fraction: float, detail: str = "") -> None:
        percent = int(fraction * 100)
        if not self.enabled or percent == self._shown:
            return
        self._shown = percent
        bar = "#" * (percent // 5) + "." * (20 - percent // 5)
        sys.stderr.write(f"\r{self.label} [{bar}] {percent:3d}% {detail[:50]:<50}")
        sys.stderr.flush()

    def close(self) -> None:
        if self.enabled and self._shown >= 0:
            sys.stderr.write("\n")


def vehicle_record(store: Store, link: VehiclePort, name: str | None = None, config: dict | None = None) -> int:
    return store.add_vehicle(name or f"sysid-{link.transport.system_id}", link.profile.name, config or {})


def drain_campaign_events(store: Store, campaign_id: int, campaign: IdentificationCampaign) -> None:
    """Write what the campaign produced since the last call (one transaction per event); an event
    leaves the queue only once it is stored, so a failed write is retried at the next call.
    Records go in typed: the store serialises them (``companion.records.serialise``)."""
    while campaign.events:
        event = campaign.events[0]
        if isinstance(event, AttemptRecorded):
            store.add_run(campaign_id, event.attempt)
        elif isinstance(event, StepsChecked):
            store.add_behavior_result(campaign_id, "heading_steps", "completed", event.result.to_dict())
        elif isinstance(event, GainsWritten):
            store.add_gains(campaign_id, event.speed, event.before, event.after)
        elif isinstance(event, DesignMade):
            store.add_design(campaign_id, event.design)
        elif isinstance(event, SpeedTuned):
            store.add_behavior_result(campaign_id, "speed_loop", event.status, event.result.to_dict())
        else:
            raise TypeError(f"unknown campaign event {event!r}")
        campaign.events.pop(0)


def run_campaign(
    link: VehiclePort,
    store: Store,
    config: CampaignConfig,
    *,
    vehicle_id: int,
    abort: Callable[[], str | None],
    limits: SafetyLimits | None = None,
    gcs: GcsProgress | None = None,
    console: ConsoleProgress | None = None,
) -> tuple[IdentificationCampaign, RunOutcome, int]:
    """Run the identification campaign as one procedure (``run_procedure``: one restore point from
    its declared footprint), storing as it goes and leaving a trail (``companion.procedures.trail``).
    Afterwards the vehicle is as found, except for the final gains of a successful campaign (the
    step checks' trial gains are always undone). A store that cannot be written (a full disk) ends
    the procedure, restored; what could not be stored is in the outcome's ``store_problems``."""
    profile = link.profile
    config = config.resolved_for(profile)
    limits = limits if limits is not None else SafetyLimits.for_profile(profile)
    campaign_id = store.start_campaign(vehicle_id, "identification", config.to_dict())
    # a vehicle that does not wait for the companion keeps moving while the design computes: it then
    # runs beside the loop (behaviors/background.py); one that waits (lockstep, in-process) stays exact
    campaign = IdentificationCampaign(config, background_design=not link.waits_for_companion)
    try:
        objection = await_ready(link, tell=lambda text: _tell(link, text[:50], 4))
    except LinkError as exc:  # lost while waiting: nothing was changed
        objection = f"{type(exc).__name__}: {exc}"
    if objection is not None:  # nothing was changed: refuse, with the vehicle's reason
        outcome = RunOutcome(Outcome.ABORTED, f"not started: the vehicle is not ready: {objection}", {})
        _close_record(store, campaign_id, outcome)
        if gcs is not None:
            gcs.finish(outcome)
        return campaign, outcome, campaign_id
    try:
        original = RestorePoint.capture(link, campaign.footprint)  # the original gains, for the step checks
    except Exception as exc:  # noqa: BLE001 - the link lost the answers: close the record, never raise
        outcome = not_started(exc)
        _close_record(store, campaign_id, outcome)
        if gcs is not None:
            gcs.finish(outcome)
        return campaign, outcome, campaign_id
    if campaign.adopt_original(original.parameters):
        try:
            store.update_campaign_config(campaign_id, campaign.config.to_dict())
        except StoreError as exc:  # the design still uses it; only an export's rebuild would miss it
            log.warning("the resolved campaign configuration could not be stored: %s", exc)
    log.info("campaign %d started; original gains %s, mode %s", campaign_id, original.parameters, original.mode)
    if original.mode in HAND_FLOWN_MODES:  # a pilot may be driving it: taking it is said, never silent
        text = f"campaign takes the vehicle from {original.mode.upper()}"
        log.warning("%s: the pilot's sticks are overridden until the campaign ends (then %s again)",
                    text, original.mode.upper())
        _tell(link, text, 4)
    try:
        trail_id = store.save_restore_point(campaign_id, original.as_json(), vehicle_identity(link))
    except StoreError as exc:  # nothing was changed: a procedure without its trail is not started
        outcome = RunOutcome(Outcome.ABORTED, f"not started: the restore point could not be stored: {exc}", {})
        _close_record(store, campaign_id, outcome)
        if gcs is not None:
            gcs.finish(outcome)
        return campaign, outcome, campaign_id

    def on_step(telemetry: Telemetry, _behavior: Behavior) -> None:
        drain_campaign_events(store, campaign_id, campaign)
        fraction = campaign.progress()
        if gcs is not None:
            gcs.update(fraction)
        if console is not None and console.enabled:
            current = campaign.current_step
            console.update(fraction, f"t={telemetry.time_s:7.1f}s {current.name if current else ''}")

    # one capture: the original gains of the step checks are the restore point's own values
    recorder = TrailRecorder(store, trail_id, link)
    try:
        outcome = run_procedure(link, campaign, limits=limits, abort_requested=abort, on_step=on_step,
                                restore=original, on_change=recorder)
    finally:
        recorder.close()
    try:
        _store_safely(outcome, lambda: drain_campaign_events(store, campaign_id, campaign))
    finally:
        _close_record(store, campaign_id, outcome, trail_id)
        if gcs is not None:
            gcs.finish(outcome)
        if console is not None:
            console.close()
    return campaign, outcome, campaign_id


def _store_safely(outcome: RunOutcome, write: Callable[[], object]) -> None:
    """``write()`` after the vehicle is restored; a store that cannot be written is said in the
    outcome (the vehicle and what was stored before are fine), never raised."""
    try:
        write()
    except StoreError as exc:
        log.error("%s", exc)
        outcome.store_problems.append(str(exc))


def _close_record(store: Store, campaign_id: int, outcome: RunOutcome, trail_id: int | None = None) -> None:
    """The trail closed (the restore ran) and the campaign row finished, each as far as the store allows."""
    if trail_id is not None:
        _store_safely(outcome, lambda: store.finish_restore(trail_id, outcome.restore_problems,
                                                            outcome.restore_notes))
    _store_safely(outcome, lambda: store.finish_campaign(campaign_id, outcome.status, outcome.reason))


@dataclass(frozen=True)
class NamedRun:
    """A procedure run by name: its result (as the runner saw it end), the JSON figures of that
    result, and the runner's outcome (None when the procedure did not apply and never started)."""

    result: ProcedureResult
    summary: dict
    outcome: RunOutcome | None


def run_named_procedure(name: str, link: VehiclePort, store: Store, *, vehicle_id: int, campaign_id: int | None, abort,
                        context: ProcedureContext | None = None, limits: SafetyLimits | None = None) -> NamedRun:
    """Run a registered procedure (``companion.procedures.registry.PROCEDURES``) by name under one
    restore point and store its result."""
    spec = PROCEDURES.get(name)
    if spec is None:
        raise ValueError(f"unknown procedure {name!r} ({', '.join(PROCEDURES)})")
    own = campaign_id is None
    if campaign_id is None:
        campaign_id = store.start_campaign(vehicle_id, name, {"preset": getattr(context, "preset", None)})
    result: ProcedureResult = ProcedureResult(name, Outcome.NOT_STARTED, "not started")
    outcome = None
    profile = link.profile
    refusal = spec.applies(profile)
    if refusal is not None:  # never "completed": the procedure does not apply to this vehicle
        result = ProcedureResult(name, Outcome.REFUSED, refusal)
        store.add_behavior_result(campaign_id, name, "refused", result.to_json())
        if own:
            store.finish_campaign(campaign_id, "refused", refusal)
        _tell(link, f"{name} refused: {refusal}"[:50], 4)
        return NamedRun(result, spec.summary(result.to_json()), None)
    try:
        procedure = spec.build(link, context or ProcedureContext())
        try:
            restore = RestorePoint.capture(link, footprint_of(procedure))
        except Exception as exc:  # noqa: BLE001 - nothing was changed yet: refuse to start, never raise
            outcome = not_started(exc)
        else:
            try:
                trail_id = store.save_restore_point(campaign_id, restore.as_json(), vehicle_identity(link))
            except StoreError as exc:  # nothing was changed: a procedure without its trail is not started
                outcome = RunOutcome(Outcome.ABORTED, f"not started: the restore point could not be stored: {exc}", {})
                result = procedure.result().with_outcome(outcome)
                return NamedRun(result, spec.summary(result.to_json()), outcome)
            recorder = TrailRecorder(store, trail_id, link)
            try:
                outcome = run_procedure(link, procedure, limits=limits or SafetyLimits.for_profile(profile),
                                        abort_requested=abort, restore=restore, on_change=recorder)
            finally:
                recorder.close()
            _store_safely(outcome, lambda: store.finish_restore(trail_id, outcome.restore_problems,
                                                                outcome.restore_notes))
        result = procedure.result().with_outcome(outcome)
        _store_safely(outcome, lambda: store.add_behavior_result(campaign_id, name, result.status, result.to_json()))
    finally:
        if own and outcome is not None:
            _store_safely(outcome, lambda: store.finish_campaign(campaign_id, result.status, result.reason))
    return NamedRun(result, spec.summary(result.to_json()), outcome)


def _tell(link, text: str, severity: int) -> None:
    try:
        link.status_text(text, severity)
    except Exception:  # noqa: BLE001 - a dead link cannot be told anything
        log.debug("could not send status text %r", text)


def run_named_behavior(name: str, link: VehiclePort, store: Store, *, vehicle_id: int, campaign_id: int | None,
                       abort, preset: str | None = None, simulator: bool = True, config: Any = None) -> NamedRun:
    """:func:`run_named_procedure` for a registered procedure with its configuration (None: its
    registered default)."""
    context = ProcedureContext(configs={} if config is None else {name: config}, preset=preset, simulator=simulator)
    return run_named_procedure(name, link, store, vehicle_id=vehicle_id, campaign_id=campaign_id, abort=abort,
                               context=context)
