"""Run a behaviour over the vehicle link, safely (SPEC C1, C4 "abort at any time"; SPEC §4).

The runner is the only place where a behaviour meets I/O. Per telemetry snapshot it checks the
abort sources, feeds the snapshot to the behaviour and executes the returned commands. On any abort
— a signal or an abort request (``abort_requested``), a ground-station abort command, link loss,
the vehicle leaving its attitude/depth envelope, a refused parameter, or an exception — it asks
the behaviour to release what it holds and then puts the autopilot back as it was found: overrides
released, the original mode, the original gains (:class:`RestorePoint`).

Every timer here is vehicle time. The only wall-clock quantity is the link's silence watchdog
(inside ``VehicleLink.next_telemetry``), because a dead link stops the vehicle clock.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Callable, Iterable, Protocol, Sequence

from behaviors.base import Footprint, Status, footprint_of
from companion.checks import require_finite, require_positive, require_range
from companion.interface import Behavior, Command, SetHeading, SetMode, SetParameters, SetRollingMass, SetThrust, Telemetry
from companion.procedures.results import ProcedureResult

log = logging.getLogger(__name__)


class AbortProcedure(Exception):
    """Raised inside the run loop to stop the behaviour and restore the vehicle.

    ``pilot_has_it``: someone else changed the mode or disarmed; the restore then leaves the mode
    alone (overrides and gains still go back) so the companion never switches away from the pilot."""

    def __init__(self, reason: str, pilot_has_it: bool = False) -> None:
        super().__init__(reason)
        self.pilot_has_it = pilot_has_it


@dataclass(frozen=True)
class SafetyLimits:
    """The envelope a procedure must keep; leaving it aborts (defaults suit a small AUV)."""

    max_roll: float = math.radians(35.0)
    max_pitch: float = math.radians(35.0)
    max_depth: float = 50.0  # m
    min_depth: float = -1.0  # m (a surfaced vehicle may read slightly negative)
    max_nan_samples: int = 40  # consecutive snapshots without attitude before aborting
    require_armed: bool = True  # a disarmed vehicle (or one disarmed during the procedure) aborts it
    mode_grace_s: float = 3.0  # vehicle seconds in a mode the procedure did not ask for before aborting

    def __post_init__(self) -> None:
        require_range(self, "max_roll", 1e-3, math.pi)
        require_range(self, "max_pitch", 1e-3, math.pi / 2)
        require_finite(self, "max_depth", "min_depth")
        if self.min_depth > self.max_depth:
            raise ValueError(f"SafetyLimits: min_depth {self.min_depth} above max_depth {self.max_depth}")
        require_positive(self, "mode_grace_s")
        if not (isinstance(self.max_nan_samples, int) and self.max_nan_samples >= 1):
            raise ValueError(f"SafetyLimits.max_nan_samples must be an integer ≥ 1, not {self.max_nan_samples!r}")

    def violation(self, telemetry: Telemetry) -> str | None:
        if math.isfinite(telemetry.roll) and abs(telemetry.roll) > self.max_roll:
            return f"roll {math.degrees(telemetry.roll):.1f} deg beyond {math.degrees(self.max_roll):.0f} deg"
        if math.isfinite(telemetry.pitch) and abs(telemetry.pitch) > self.max_pitch:
            return f"pitch {math.degrees(telemetry.pitch):.1f} deg beyond {math.degrees(self.max_pitch):.0f} deg"
        if math.isfinite(telemetry.depth) and not self.min_depth <= telemetry.depth <= self.max_depth:
            return f"depth {telemetry.depth:.2f} m outside [{self.min_depth}, {self.max_depth}] m"
        return None


class Link(Protocol):
    """What the runner needs from ``companion.link.vehicle.VehicleLink``."""

    def next_telemetry(self, timeout_s: float = ...) -> Telemetry: ...

    def execute(self, commands: Sequence[Command]) -> None: ...

    def get_params(self, neutral_names) -> dict: ...

    def set_params(self, neutral_values: dict) -> dict: ...

    def set_mode(self, neutral: str) -> None: ...

    def release(self, actuator: str | None = None) -> None: ...

    def status_text(self, text: str, severity: int = 6) -> None: ...


#: set-points a restore point puts back, only when the vehicle was found in a mode that uses them
_SETPOINT_MODES = ("hold", "guided")


class RestoreGuard:
    """What a signal handler may do now (a second Ctrl-C 0.01 s apart once cut a parameter
    write of the restore and left HDG_I at 0.00584).

    ``interruptible`` is true only inside a procedure's step loop, where a second Ctrl-C may break a
    blocking call (the runner then aborts and restores); while ``active`` (a procedure runs) and
    outside that loop — its abort, its restore — nothing is interrupted; ``pending`` names what a restore under way
    still has to put back (empty when none is), so a forced exit can say it. Shared by the abort
    flag (``AbortFlag.guard``), the runner and the restore; no global state."""

    def __init__(self) -> None:
        self.interruptible = False  # inside a procedure's step loop
        self.active = 0  # procedures running (nested); 0: nothing to protect, a Ctrl-C may break anything
        self.restoring = False
        self.pending: list[str] = []


#: tries per restore item; a lost link is not retried (each try would wait out its timeout)
RESTORE_TRIES = 3


@dataclass
class RestorePoint:
    """How the autopilot was found, for everything a procedure declares it may change.

    Derived from the procedure's :class:`~behaviors.base.Footprint` (no list of names lives here):
    ``parameters`` holds the declared neutral parameters the profile knows (the "original gains" of
    reports and step checks); ``native`` holds the autopilot's own parameters behind them, which are
    what is restored (on a cascaded autopilot one neutral heading gain maps onto several rate-loop
    parameters, see ``AutopilotProfile.natives_touched``); ``setpoints`` the declared set-points
    read from the latest telemetry (thrust, rolling-mass angle).
    """

    mode: str | None
    parameters: dict[str, float] = field(default_factory=dict)
    native: dict[str, float] = field(default_factory=dict)
    setpoints: dict[str, float] = field(default_factory=dict)
    natives_of: dict[str, tuple[str, ...]] = field(default_factory=dict)  # neutral -> its native names

    @classmethod
    def capture(cls, link, footprint: Footprint = Footprint()) -> "RestorePoint":
        profile = getattr(link, "profile", None)
        known = profile.params if profile is not None else {}
        neutral = sorted(name for name in footprint.parameters if name in known)
        unknown = sorted(set(footprint.parameters) - set(neutral))
        if unknown:
            log.info("restore point: this profile has no parameter for %s (not touched)", unknown)
        natives_of = {name: profile.natives_touched([name]) for name in neutral} if profile is not None else {}
        native: dict[str, float] = {}
        unread: list[str] = []
        for name in dict.fromkeys(n for names in natives_of.values() for n in names):
            try:
                native[name] = link.get_param(name)
            except Exception:  # noqa: BLE001 - read again below
                unread.append(name)
        latest = getattr(link, "latest_telemetry", None)  # VehicleLink: a property (was never called: no
        telemetry = latest() if callable(latest) else latest  # set-point was ever captured over MAVLink)
        kept_by_autopilot = _persistent_setpoints(link)
        setpoints: dict[str, float] = {}
        if telemetry is not None:
            for setpoint, value in (("thrust", telemetry.thrust_ratio), ("heading", telemetry.yaw),
                                    ("rolling_mass", telemetry.mass_angle)):
                if setpoint in footprint.setpoints and setpoint in kept_by_autopilot and math.isfinite(value):
                    setpoints[setpoint] = float(value)
        parameters = dict(link.get_params(neutral)) if neutral else {}
        for name in unread:  # a second chance: answers lost on the link are not a missing parameter
            try:  # (fault injection: three lost PARAM_VALUEs left HDG_I out, and an abort left it changed)
                native[name] = link.get_param(name)
            except Exception as exc:  # noqa: BLE001 - a parameter this firmware lacks is not touched either
                log.info("restore point: %s not readable (%s)", name, exc)
        return cls(mode=getattr(link, "mode", None) or None, parameters=parameters, native=native,
                   setpoints=setpoints, natives_of=natives_of)

    def restore(self, link, *, parameters: bool = True, mode: bool = True,
                keep: Iterable[str] = (), guard: RestoreGuard | None = None) -> list[str]:
        """Release overrides, write back every parameter that changed (except the natives of the
        neutral names in ``keep``: verified results a procedure leaves on purpose), put the found
        set-points back, restore the mode.

        Each item is tried up to :data:`RESTORE_TRIES` times and every item is tried even if another
        fails: a restore never stops half-way. With a ``guard`` the signal handler knows a restore is
        under way (it then never interrupts it) and what is still pending. The failures are
        returned and logged."""
        strategy = getattr(link, "autopilot", None)
        if not callable(getattr(strategy, "release", None)):
            strategy = None  # a link without an autopilot strategy (the in-process harness)
        items: list[tuple[str, Callable[[], None]]] = [
            # through the autopilot's strategy: ArduSub keeps a released override's last value unless
            # the stick is centred first, and ArduRover's excitation ends by leaving MANUAL
            ("release overrides", lambda: strategy.release(None) if strategy is not None else link.release(None))]
        if parameters:
            kept = {n for name in keep for n in self.natives_of.get(name, ())}
            items += [(f"restore {name}", lambda name=name, value=value: _write_if_changed(link, name, value))
                      for name, value in self.native.items() if name not in kept]
        if self.mode in _SETPOINT_MODES and "thrust" in self.setpoints:
            items.append(("restore thrust", lambda: _set_and_confirm(link, SetThrust(self.setpoints["thrust"]))))
        if self.mode in _SETPOINT_MODES and "heading" in self.setpoints:
            items.append(("restore heading", lambda: _set_and_confirm(link, SetHeading(self.setpoints["heading"]))))
        if "rolling_mass" in self.setpoints:
            items.append(("restore rolling mass",
                          lambda: _set_and_confirm(link, SetRollingMass(self.setpoints["rolling_mass"]))))
        if mode and self.mode:
            items.append(("restore mode", lambda: link.set_mode(self.mode)))
        guard = guard or RestoreGuard()
        was_interruptible, guard.interruptible = guard.interruptible, False
        guard.restoring, guard.pending = True, [what for what, _ in items]
        problems: list[str] = []
        reconnect = _Reconnector(link)
        try:
            for what, action in items:
                failure = _try_restore_item(what, action, reconnect)
                if failure is not None:
                    problems.append(failure)
                guard.pending.remove(what)
        finally:
            guard.restoring, guard.interruptible = False, was_interruptible
        return problems


def _persistent_setpoints(link) -> tuple[str, ...]:
    """The set-points the link's autopilot keeps after the companion is done (its strategy's
    ``persistent_setpoints``): only those are captured and put back. Elsewhere a set-point is not
    autopilot state (ArduSub's thrust is an RC override the restore releases; ArduRover's speed is a
    fraction of WP_SPEED that telemetry does not report), so there is nothing to restore."""
    return tuple(getattr(getattr(link, "autopilot", None), "persistent_setpoints", ()) or ())


def _set_and_confirm(link, command: Command) -> None:
    """Send one set-point and wait until the vehicle acknowledged it (a restore is verified, like a
    parameter write: a lost command or acknowledgement fails the try, which is retried)."""
    link.execute([command])
    confirm = getattr(link, "await_setpoints", None)
    if callable(confirm):
        confirm()


def _last_words(link, within_s: float = 10.0) -> str:
    """The vehicle's latest warnings (STATUSTEXT severity ≤ 4, within ``within_s`` of vehicle time)
    as a suffix for an abort reason: why ArduSub disarmed, for instance; empty when it said nothing."""
    texts = getattr(link, "statustexts", None) or ()
    now = getattr(link, "vehicle_time_s", math.nan)
    recent = [text for when, severity, text in texts
              if severity <= 4 and not (math.isfinite(now) and math.isfinite(when) and now - when > within_s)]
    return f" (the vehicle said: {'; '.join(recent[-3:])})" if recent else ""


def _other_companion(link) -> str | None:
    """The link's report of another companion flying the same vehicle (None where it cannot tell)."""
    check = getattr(link, "other_companion", None)
    return check() if callable(check) else None


class _Reconnector:
    """A restore's bounded attempts to get a closed link back (``link.reconnect``, at most
    :data:`RESTORE_RECONNECTS` per restore, each bounded by the link's own wall-clock limit);
    once one fails, the link is taken as gone for the rest of the restore."""

    def __init__(self, link) -> None:
        self._reconnect = getattr(link, "reconnect", None)
        self.left = RESTORE_RECONNECTS if callable(self._reconnect) else 0
        self.gone: str | None = None  # why the rest of the restore is not tried (the link did not come back)

    def __call__(self) -> bool:
        if self.left <= 0:
            return False
        self.left -= 1
        try:
            back = bool(self._reconnect())
        except Exception as exc:  # noqa: BLE001 - a failed reconnect is a lost link, reported below
            log.error("reconnect failed: %s", exc)
            back = False
        if not back:
            self.left = 0
            self.gone = "the link was lost and did not come back"
        return back


#: reconnections one restore may make (a link that keeps dropping is not chased for ever)
RESTORE_RECONNECTS = 2


def _try_restore_item(what: str, action: Callable[[], None],
                      reconnect: Callable[[], bool] = lambda: False) -> str | None:
    """``action`` tried up to :data:`RESTORE_TRIES` times; None on success, else the last failure.
    A lost link is reconnected if it can be (a TCP link that dropped and came back) and the item
    tried again; otherwise it ends the tries at once (bounded: each attempt already waited out its
    timeout)."""
    from companion.link.errors import LinkLost

    gone = getattr(reconnect, "gone", None)
    if gone:  # each try would fail on the closed connection, with a less useful message
        return f"{what}: not tried: {gone}"
    failure = "not tried"
    for attempt in range(1, RESTORE_TRIES + 1):
        try:
            action()
            return None
        except Exception as exc:  # noqa: BLE001 - every item is tried whatever went wrong
            failure = f"{type(exc).__name__}: {exc}" if not str(exc) else str(exc)
            log.error("%s failed (try %d of %d): %s", what, attempt, RESTORE_TRIES, failure)
            if isinstance(exc, LinkLost) and not reconnect():
                break
    return f"{what}: {failure}"


def _write_if_changed(link, name: str, value: float) -> None:
    """Write ``name`` back unless it already holds ``value`` (every write costs a flash write)."""
    current = link.get_param(name)
    if not (math.isfinite(current) and abs(current - value) <= 1e-6 * max(1.0, abs(value))):
        link.set_param(name, value)


@dataclass
class RunOutcome:
    """What happened: ``completed`` (the goal was reached), ``failed`` (the procedure ended without
    reaching it) or ``aborted``, with the reason, plus the behaviour's result."""

    status: str
    reason: str | None
    result: dict
    restore_problems: list[str] = field(default_factory=list)
    samples: int = 0
    vehicle_time_s: float = 0.0
    pilot_has_it: bool = False  # aborted because someone else took the vehicle (leave its mode alone)
    restore: "RestorePoint | None" = None  # the restore point run_procedure took


def run_behavior(
    link: Link,
    behavior: Behavior,
    *,
    limits: SafetyLimits = SafetyLimits(),
    abort_requested: Callable[[], str | None] = lambda: None,
    on_step: Callable[[Telemetry, Behavior], None] | None = None,
    restore: RestorePoint | None = None,
    restore_on_success: bool = False,
    telemetry_timeout_s: float = 5.0,
    skip_backlog: bool = True,
) -> RunOutcome:
    """Step ``behavior`` on every telemetry snapshot until it is done or an abort occurs.

    ``abort_requested`` is polled once per snapshot and returns a reason to abort (or None): the
    command line wires SIGINT/SIGTERM to it, the ground-station handler an abort command.
    ``on_step`` is called after each step (progress reports, store writes).
    """
    watchdog = _TakeoverWatchdog(limits, link)
    if hasattr(link, "commanded_mode"):
        link.commanded_mode = None  # only modes switched to during this run are the procedure's own
    skip_to_now = getattr(link, "skip_to_now", None)
    if skip_to_now is not None and skip_backlog:
        # snapshots queued during earlier blocking calls (a restore, a mode change) predate this
        # procedure: it must start from the vehicle as it is now (within a run, none is skipped)
        skip_to_now()
    guard = getattr(abort_requested, "guard", None)
    if guard is not None:
        guard.active += 1
    try:
        return _run_guarded(behavior, link, limits, abort_requested, on_step, restore, restore_on_success,
                            telemetry_timeout_s, watchdog, guard)
    finally:
        if guard is not None:
            guard.active -= 1


def _run_guarded(behavior, link, limits, abort_requested, on_step, restore, restore_on_success,
                 telemetry_timeout_s, watchdog, guard) -> RunOutcome:
    """:func:`run_behavior`'s loop, abort and restore (``guard``: see :class:`RestoreGuard`)."""
    samples = 0
    first_time = last_time = math.nan
    nan_run = 0
    reason: str | None = None
    pilot_has_it = False
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
                requested = abort_requested() or _other_companion(link)
                if requested:
                    raise AbortProcedure(requested)
                nan_run = 0 if telemetry.finite("roll", "pitch", "yaw") else nan_run + 1
                if nan_run > limits.max_nan_samples:
                    raise AbortProcedure(f"no valid attitude for {nan_run} samples")
                violation = limits.violation(telemetry)
                if violation:
                    raise AbortProcedure(f"safety limit: {violation}")
                takeover = watchdog.check(telemetry)
                if takeover:
                    raise AbortProcedure(takeover, pilot_has_it=True)
                commands = behavior.step(telemetry)
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
    except Exception as exc:  # noqa: BLE001 - link loss, refused parameter, bug: abort safely, then report
        log.exception("procedure failed")
        reason = f"{type(exc).__name__}: {exc}"
    problems: list[str] = []
    if reason is not None:
        log.warning("aborting: %s", reason)
        unwanted = (SetParameters, SetMode) if pilot_has_it else (SetParameters,)
        try:
            link.execute([c for c in behavior.abort(reason) if not isinstance(c, unwanted)])
        except Exception as exc:  # noqa: BLE001 - the restore below still runs
            problems.append(f"behaviour abort: {exc}")
        if restore is not None:
            problems += restore.restore(link, mode=not pilot_has_it, guard=guard)
        _tell(link, f"aborted: {reason}", 4)
    elif restore is not None and restore_on_success:
        problems += restore.restore(link, guard=guard)
    status = "aborted" if reason is not None else "completed"
    if reason is None and getattr(behavior, "status", None) is Status.FAILURE:
        status, reason = "failed", getattr(behavior, "reason", None) or "the procedure did not reach its goal"
    return RunOutcome(
        status=status,
        reason=reason,
        result=behavior.result(),
        restore_problems=problems,
        samples=samples,
        vehicle_time_s=0.0 if math.isnan(first_time) else last_time - first_time,
        pilot_has_it=pilot_has_it,
    )


def run_procedure(
    link: Link,
    procedure: Behavior,
    *,
    limits: SafetyLimits = SafetyLimits(),
    abort_requested: Callable[[], str | None] = lambda: None,
    on_step: Callable[[Telemetry, Behavior], None] | None = None,
    telemetry_timeout_s: float = 5.0,
    restore: RestorePoint | None = None,
) -> RunOutcome:
    """Run one procedure (a behaviour, usually a sequence) under one restore point (``restore``
    when the caller already took it from the procedure's footprint).

    The restore point is derived from the procedure's declared footprint and taken before its first
    step. Afterwards the vehicle is put back as found: always after an abort or a failure (the mode
    too, unless the pilot took the vehicle), and after success too except for the parameters the
    procedure keeps on purpose (``kept_parameters``, e.g. a campaign's verified final gains)."""
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
                               restore=None, telemetry_timeout_s=telemetry_timeout_s)
        outcome.restore = restore
        keep = getattr(procedure, "kept_parameters", frozenset()) if outcome.status == "completed" else frozenset()
        outcome.restore_problems += restore.restore(link, mode=not outcome.pilot_has_it, keep=keep, guard=guard)
        return outcome
    finally:
        if guard is not None:
            guard.active -= 1


def run_for_result(link: Link, procedure: Behavior, *, abort_requested: Callable[[], str | None] = lambda: None,
                   limits: SafetyLimits = SafetyLimits()) -> ProcedureResult:
    """:func:`run_procedure`, then the procedure's own :class:`ProcedureResult` as the runner saw it end."""
    outcome = run_procedure(link, procedure, limits=limits, abort_requested=abort_requested)
    return procedure.result().with_outcome(outcome)


def not_started(exc: Exception) -> RunOutcome:
    """The outcome of a procedure whose restore point could not be taken (the link lost the
    answers): aborted before its first step, so nothing was changed and nothing needs restoring."""
    log.error("restore point not taken: %s", exc)
    return RunOutcome("aborted", f"restore point not taken: {type(exc).__name__}: {exc}", {})


class _TakeoverWatchdog:
    """Someone else took the vehicle: it was disarmed, or its mode differs from the last one the
    procedure asked for (the mode it was found in until then) for longer than the grace period.
    A procedure must then stop at once, not fight the pilot (SPEC §4: record, switch, restore)."""

    def __init__(self, limits: SafetyLimits, link=None) -> None:
        self.limits = limits
        self.link = link
        profile = getattr(link, "profile", None)
        self._number = profile.mode_number if profile is not None else None
        self.expected_mode: str | None = None
        self.armed_seen = False
        self.foreign_since: float | None = None

    def commanded(self, commands) -> None:
        for command in commands:
            if isinstance(command, SetMode):
                self.expected_mode = command.mode
        # a mode the companion switched to itself (an autopilot strategy's excitation mode) is ours
        own = getattr(self.link, "commanded_mode", None)
        if isinstance(own, str) and own:
            self.expected_mode = own

    def _same(self, a: str, b: str) -> bool:
        """Two neutral names of one mode number (e.g. ArduRover's "hold" and "guided") are the same mode."""
        if a == b:
            return True
        try:
            return self._number is not None and self._number(a) == self._number(b)
        except Exception:  # noqa: BLE001 - an unknown name is another mode
            return False

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
        confirmed = getattr(getattr(self.link, "modes", None), "confirmed_s", None)
        if self._same(telemetry.mode, self.expected_mode) or (
                isinstance(confirmed, float) and telemetry.time_s <= confirmed):
            # a snapshot assembled before the heartbeat that confirmed our own change still shows the
            # old mode: measured on ArduRover SITL at 20x under load, 3.2 s of such queued snapshots
            # after a switch to MANUAL outlasted the grace and aborted the campaign
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
