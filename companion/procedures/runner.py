"""Run a behaviour over the vehicle link, safely (SPEC C1, C4 "abort at any time"; SPEC §4).

The runner is the only place where a behaviour meets I/O. Per telemetry snapshot it checks the
abort sources, feeds the snapshot to the behaviour and executes the returned commands. On any abort
— a signal or an abort request (``abort_requested``), a ground-station abort command, link loss,
the vehicle leaving its attitude/depth envelope, a refused parameter, or an exception — it asks
the behaviour to release what it holds and then puts the autopilot back as it was found: overrides
released, the original mode, the original gains (``companion.procedures.restore.RestorePoint``).
A change to one of the procedure's parameters by someone else aborts it too (the restore keeps it).

Every timer here is vehicle time. The only wall-clock quantity is the link's silence watchdog
(inside ``VehicleLink.next_telemetry``), because a dead link stops the vehicle clock.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Protocol, Sequence

from behaviors.base import Behaviour, Status, footprint_of
from companion.interface import (Behavior, Command, NamedValue, OverrideActuator, ReleaseActuator, SetDepth,
                                 SetHeading, SetMode, SetParameters, SetRollingMass, SetThrust, StatusText, Telemetry)
from companion.errors import UserError as _UserError
from companion.link.errors import LinkError, VehicleRebooted
from companion.link.port import VehiclePort
from companion.procedures.limits import SafetyLimits
from companion.procedures.restore import RestoreGuard, RestorePoint, reboots_seen
from companion.procedures.results import Outcome, ProcedureResult

__all__ = ["AbortProcedure", "Link", "RestoreGuard", "RestorePoint", "RunOutcome", "SafetyLimits", "not_started",
           "run_behavior", "run_for_result", "run_procedure"]

log = logging.getLogger(__name__)


class AbortProcedure(Exception):
    """Raised inside the run loop to stop the behaviour and restore the vehicle.

    ``pilot_has_it``: someone else changed the mode or disarmed; the restore then leaves the mode
    alone (overrides and gains still go back) so the companion never switches away from the pilot."""

    def __init__(self, reason: str, pilot_has_it: bool = False) -> None:
        super().__init__(reason)
        self.pilot_has_it = pilot_has_it


#: what the runner needs of the vehicle: the one typed port (``companion.link.port``)
Link = VehiclePort


def _last_words(link: VehiclePort, within_s: float = 10.0) -> str:
    """The vehicle's latest warnings (STATUSTEXT severity ≤ 4, within ``within_s`` of vehicle time)
    as a suffix for an abort reason: why ArduSub disarmed, for instance; empty when it said nothing."""
    texts = link.statustexts
    now = link.vehicle_time_s
    recent = [text for when, severity, text in texts
              if severity <= 4 and not (math.isfinite(now) and math.isfinite(when) and now - when > within_s)]
    return f" (the vehicle said: {'; '.join(recent[-3:])})" if recent else ""


def _foreign_change(link: VehiclePort) -> str | None:
    """Someone else changed one of the procedure's parameters (the link watches them from the
    restore point on): the procedure's assumptions no longer hold."""
    foreign = link.parameters.foreign
    if not foreign:
        return None
    change = next(iter(foreign.values()))
    return f"{change.name} was changed to {change.value:g} by someone else during the procedure"


#: the commands that change the vehicle's state, recorded as they are made (a crash leaves a trail;
#: a release is recorded so the trail knows which overrides were still held)
STATE_CHANGES = (SetParameters, SetMode, SetThrust, SetHeading, SetDepth, SetRollingMass, OverrideActuator,
                 ReleaseActuator)
#: what a behaviour's abort may still send to a vehicle that rebooted: its new boot's mode and
#: set-points are its own, so only releases and words
AFTER_REBOOT = (ReleaseActuator, StatusText, NamedValue)


def _other_companion(link: VehiclePort) -> str | None:
    """The link's report of another companion flying the same vehicle (None where it cannot tell)."""
    return link.other_companion()


@dataclass
class RunOutcome:
    """What happened: ``completed`` (the goal was reached), ``failed`` (the procedure ended without
    reaching it) or ``aborted``, with the reason, plus the behaviour's result."""

    status: Outcome
    reason: str | None
    result: Any
    restore_problems: list[str] = field(default_factory=list)
    samples: int = 0
    vehicle_time_s: float = 0.0
    pilot_has_it: bool = False  # aborted because someone else took the vehicle (leave its mode alone)
    restore: "RestorePoint | None" = None  # the restore point run_procedure took
    restore_notes: list[str] = field(default_factory=list)  # what the restore decided (kept changes, a reboot)
    store_problems: list[str] = field(default_factory=list)  # what could not be stored (a full disk)

    def __post_init__(self) -> None:
        self.status = Outcome.of(self.status)


def run_behavior(
    link: Link,
    behavior: Behavior,
    *,
    limits: SafetyLimits | None = None,
    abort_requested: Callable[[], str | None] = lambda: None,
    on_step: Callable[[Telemetry, Behavior], None] | None = None,
    restore: RestorePoint | None = None,
    restore_on_success: bool = False,
    telemetry_timeout_s: float = 5.0,
    skip_backlog: bool = True,
    on_change: Callable[[Sequence[Command]], None] | None = None,
) -> RunOutcome:
    """Step ``behavior`` on every telemetry snapshot until it is done or an abort occurs.

    ``abort_requested`` is polled once per snapshot and returns a reason to abort (or None): the
    command line wires SIGINT/SIGTERM to it, the ground-station handler an abort command.
    ``on_step`` is called after each step (progress reports, store writes); ``on_change`` with the
    commands that change the vehicle's state (:data:`STATE_CHANGES`) *before* they are sent (the
    trail a crash leaves for the next start).
    """
    limits = limits if limits is not None else SafetyLimits.for_profile(link.profile)
    watchdog = _TakeoverWatchdog(limits, link)
    envelope = limits.watch()
    link.commanded_mode = None  # only modes switched to during this run are the procedure's own
    if skip_backlog:
        # snapshots queued during earlier blocking calls (a restore, a mode change) predate this
        # procedure: it must start from the vehicle as it is now (within a run, none is skipped)
        link.skip_to_now()
    guard = getattr(abort_requested, "guard", None)
    if guard is not None:
        guard.active += 1
    try:
        return _run_guarded(behavior, link, limits, abort_requested, on_step, restore, restore_on_success,
                            telemetry_timeout_s, watchdog, guard, on_change, envelope)
    finally:
        if guard is not None:
            guard.active -= 1


def _run_guarded(behavior, link, limits, abort_requested, on_step, restore, restore_on_success,
                 telemetry_timeout_s, watchdog, guard, on_change, envelope) -> RunOutcome:
    """:func:`run_behavior`'s loop, abort and restore (``guard``: see :class:`RestoreGuard`)."""
    samples = 0
    first_time = last_time = math.nan
    nan_run = 0
    reason: str | None = None
    pilot_has_it = False
    rebooted = False
    try:
        try:
            if guard is not None:
                guard.interruptible = True  # a second Ctrl-C may break a blocking call, here only
            while not behavior.done:
                telemetry = link.next_telemetry(timeout_s=telemetry_timeout_s)
                samples += 1
                if math.isnan(first_time):
                    first_time = telemetry.time_s
                last_time = telemetry.time_s
                requested = abort_requested() or _other_companion(link) or _foreign_change(link)
                if requested:
                    raise AbortProcedure(requested)
                nan_run = 0 if telemetry.finite("roll", "pitch", "yaw") else nan_run + 1
                if nan_run > limits.max_nan_samples:
                    raise AbortProcedure(f"no valid attitude for {nan_run} samples")
                violation = envelope.check(telemetry)
                if violation:
                    raise AbortProcedure(f"safety limit: {violation}")
                takeover = watchdog.check(telemetry)
                if takeover:
                    raise AbortProcedure(takeover, pilot_has_it=True)
                commands = behavior.step(telemetry)
                changes = [c for c in commands if isinstance(c, STATE_CHANGES)]
                if changes and on_change is not None:
                    on_change(changes)
                link.execute(commands)
                watchdog.commanded(commands)
                if on_step is not None:
                    on_step(telemetry, behavior)
        finally:
            if guard is not None:
                guard.interruptible = False  # from here on (abort, restore) no signal interrupts
    except AbortProcedure as exc:
        reason = str(exc)
        pilot_has_it = exc.pilot_has_it
    except KeyboardInterrupt:
        reason = "interrupted"
    except (LinkError, _UserError) as exc:  # expected conditions: a sentence, the traceback only at debug level
        log.debug("procedure stopped", exc_info=True)
        reason = f"{type(exc).__name__}: {exc}"
        rebooted = isinstance(exc, VehicleRebooted)
    except Exception as exc:  # noqa: BLE001 - a bug: abort safely, then report (with its traceback)
        log.exception("procedure failed")
        reason = f"{type(exc).__name__}: {exc}"
    problems: list[str] = []
    if reason is not None:
        log.warning("aborting: %s", reason)
        unwanted = (SetParameters, SetMode) if pilot_has_it else (SetParameters,)
        try:
            commands = [c for c in behavior.abort(reason) if not isinstance(c, unwanted)]
            if rebooted:
                commands = [c for c in commands if isinstance(c, AFTER_REBOOT)]
            link.execute(commands)
        except Exception as exc:  # noqa: BLE001 - the restore below still runs
            problems.append(f"behaviour abort: {exc}")
        if restore is not None:
            problems += restore.restore(link, mode=not pilot_has_it, guard=guard)
        _tell(link, f"aborted: {reason}", 4)
    elif restore is not None and restore_on_success:
        problems += restore.restore(link, guard=guard)
    notes = list(restore.notes) if restore is not None else []
    if not rebooted and restore is not None:
        reason = named_reboot(reason, link, restore.boot)
    status = Outcome.ABORTED if reason is not None else Outcome.COMPLETED
    # a registered behaviour need only be a companion.interface.Behavior: one built on Behaviour says how it ended
    if reason is None and isinstance(behavior, Behaviour) and behavior.status is Status.FAILURE:
        status, reason = Outcome.FAILED, behavior.reason or "the procedure did not reach its goal"
    return RunOutcome(
        status=status,
        reason=reason,
        result=behavior.result(),
        restore_problems=problems,
        samples=samples,
        vehicle_time_s=0.0 if math.isnan(first_time) else last_time - first_time,
        pilot_has_it=pilot_has_it,
        restore_notes=notes,
    )


def run_procedure(
    link: Link,
    procedure: Behavior,
    *,
    limits: SafetyLimits | None = None,
    abort_requested: Callable[[], str | None] = lambda: None,
    on_step: Callable[[Telemetry, Behavior], None] | None = None,
    telemetry_timeout_s: float = 5.0,
    restore: RestorePoint | None = None,
    on_change: Callable[[Sequence[Command]], None] | None = None,
) -> RunOutcome:
    """Run one procedure (a behaviour, usually a sequence) under one restore point (``restore``
    when the caller already took it from the procedure's footprint).

    The restore point is derived from the procedure's declared footprint and taken before its first
    step. Afterwards the vehicle is put back as found: always after an abort or a failure (the mode
    too, unless the pilot took the vehicle), and after success or failure too except for the parameters
    the procedure keeps on purpose (``kept_parameters``, e.g. a campaign's verified final gains: what
    one loop verified stays when another loop's design was refused)."""
    guard = getattr(abort_requested, "guard", None)
    if guard is not None:
        guard.active += 1  # from here to the end of the restore only the step loop is interruptible
    try:
        if restore is None:
            try:
                restore = RestorePoint.capture(link, footprint_of(procedure))
            except Exception as exc:  # noqa: BLE001 - nothing was changed yet: refuse to start, never raise
                return not_started(exc)
        outcome = run_behavior(link, procedure, limits=limits, abort_requested=abort_requested, on_step=on_step,
                               restore=None, telemetry_timeout_s=telemetry_timeout_s, on_change=on_change)
        outcome.restore = restore
        # what a procedure verified stays even when another part of it failed (a campaign's speed loop
        # verified beside a refused heading design); an abort puts everything back
        keep: frozenset[str] = getattr(procedure, "kept_parameters", frozenset()) \
            if outcome.status in ("completed", "failed") else frozenset()
        outcome.restore_problems += restore.restore(link, mode=not outcome.pilot_has_it, keep=keep, guard=guard)
        outcome.restore_notes = list(restore.notes)
        if outcome.status == "aborted":
            outcome.reason = named_reboot(outcome.reason, link, restore.boot)
        return outcome
    finally:
        if guard is not None:
            guard.active -= 1


def run_for_result(link: Link, procedure: Behavior, *, abort_requested: Callable[[], str | None] = lambda: None,
                   limits: SafetyLimits | None = None) -> ProcedureResult:
    """:func:`run_procedure`, then the procedure's own :class:`ProcedureResult` as the runner saw it end."""
    outcome = run_procedure(link, procedure, limits=limits, abort_requested=abort_requested)
    result = procedure.result()
    if not isinstance(result, ProcedureResult):
        raise TypeError(f"{type(procedure).__name__}.result() gave {type(result).__name__}, not a ProcedureResult")
    return result.with_outcome(outcome)


def named_reboot(reason: str | None, link: VehiclePort, boot: int) -> str | None:
    """An abort whose cause was the autopilot restarting (a crash, a power cycle: first seen as
    silence, then, once it answers again, as its new boot) named as a reboot; otherwise unchanged."""
    if reason is None or "rebooted" in reason or reboots_seen(link) <= boot:
        return reason
    return f"the autopilot rebooted during the procedure (first seen as {reason})"


def not_started(exc: Exception) -> RunOutcome:
    """The outcome of a procedure whose restore point could not be taken (the link lost the
    answers): aborted before its first step, so nothing was changed and nothing needs restoring."""
    log.error("restore point not taken: %s", exc)
    return RunOutcome(Outcome.ABORTED, f"restore point not taken: {type(exc).__name__}: {exc}", {})


class _TakeoverWatchdog:
    """Someone else took the vehicle: it was disarmed, or its mode differs from the last one the
    procedure asked for (the mode it was found in until then) for longer than the grace period.
    A procedure must then stop at once, not fight the pilot (SPEC §4: record, switch, restore)."""

    def __init__(self, limits: SafetyLimits, link: VehiclePort) -> None:
        self.limits = limits
        self.link = link
        self._number = link.profile.mode_number
        self.expected_mode: str | None = None
        self.armed_seen = False
        self.foreign_since: float | None = None

    def commanded(self, commands) -> None:
        for command in commands:
            if isinstance(command, SetMode):
                self.expected_mode = command.mode
        # a mode the companion switched to itself (an autopilot strategy's excitation mode) is ours
        own = self.link.commanded_mode
        if own:
            self.expected_mode = own

    def _same(self, a: str, b: str) -> bool:
        """Two neutral names of one mode number (e.g. ArduRover's "hold" and "guided") are the same mode."""
        if a == b:
            return True
        try:
            return self._number(a) == self._number(b)
        except Exception:  # noqa: BLE001 - an unknown name is another mode
            return False

    def _before_own_change(self, telemetry: Telemetry) -> bool:
        """The snapshot predates the heartbeat that confirmed the companion's latest mode change: it
        may still show the mode before it, however late the link delivered it."""
        confirmed = self.link.modes.commanded_at_s
        return math.isfinite(confirmed) and telemetry.time_s <= confirmed

    def check(self, telemetry: Telemetry) -> str | None:
        if self.limits.require_armed:
            if telemetry.armed:
                self.armed_seen = True
            elif self.armed_seen:
                return "the vehicle was disarmed" + _last_words(self.link)
            else:
                return "the vehicle is not armed"
        if not telemetry.mode:
            return None
        if self.expected_mode is None:
            self.expected_mode = telemetry.mode
        if self._same(telemetry.mode, self.expected_mode) or self._before_own_change(telemetry):
            self.foreign_since = None
            return None
        if self.foreign_since is None:
            self.foreign_since = telemetry.time_s
        if telemetry.time_s - self.foreign_since > self.limits.mode_grace_s:
            return f"mode changed to {telemetry.mode} by someone else (the procedure had {self.expected_mode})"
        return None


def _tell(link, text: str, severity: int) -> None:
    try:
        link.status_text(text, severity)
    except Exception:  # noqa: BLE001 - a dead link cannot be told anything
        log.debug("could not send status text %r", text)
