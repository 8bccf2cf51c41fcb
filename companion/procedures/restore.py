"""How the autopilot was found, and putting it back (SPEC C1, C4 "abort at any time"; SPEC §4).

A :class:`RestorePoint` is taken before a procedure's first change, from what the procedure
declares it may touch (its :class:`~behaviors.base.Footprint`), and is what every ending puts back:
overrides released, parameters written back (only those that changed, each verified by its echo),
the set-points the autopilot keeps confirmed by its state (``restore_items``), the mode. Three
things it never does silently:

* **someone else's change** to one of those parameters during the procedure (the vehicle announced
  a value no write of ours asked for) is kept, not overwritten, and said;
* **after a reboot** (the vehicle's clock went back) the new boot's mode and set-points are its own:
  only the parameters, which the autopilot keeps in its flash across boots, are put back;
* **what it could not do** is returned, item by item (``problems``), and what it decided is said
  (``notes``).

A restore point has a JSON form (:meth:`RestorePoint.as_json`) so it can be stored before the
first change and followed by the next start if this process dies (``companion.procedures.trail``).
"""
from __future__ import annotations

import functools
import logging
import math
from dataclasses import dataclass, field, replace
from typing import Callable, Iterable

from behaviors.base import Footprint
from companion.interface import Command, SetHeading, SetRollingMass, SetThrust
from companion.link.parameters import ForeignChange
from companion.link.port import VehiclePort
from companion.procedures.late_setpoints import LateSetpointWatch, WatchedSetpoint
from companion.procedures.restore_items import Reconnector, StateCheck, set_and_confirm, try_restore_item, \
    in_flight_possible, wait_in_flight, write_if_changed

log = logging.getLogger(__name__)

#: set-points a restore point puts back, only when the vehicle was found in a mode that uses them
SETPOINT_MODES = ("hold", "guided")
THRUST_TOLERANCE = 0.011  # the read-back is whole PWM steps (0.002) and our simulator's whole percent
HEADING_TOLERANCE = math.radians(0.6)  # NAV_CONTROLLER_OUTPUT reports whole degrees
MASS_TOLERANCE = 0.01  # rad: the rolling mass settles on its servo's lag


class RestoreGuard:
    """What a signal handler may do now (a second Ctrl-C 0.01 s apart once cut a parameter
    write of the restore and left HDG_I at 0.00584).

    ``interruptible`` is true only inside a procedure's step loop, where a second Ctrl-C may break a
    blocking call (the runner then aborts and restores); while ``active`` (a procedure runs) and
    outside that loop — its abort, its restore — nothing is interrupted; ``pending`` names what a
    restore under way still has to put back (empty when none is), so a forced exit can say it.
    Shared by the abort flag (``AbortFlag.guard``), the runner and the restore; no global state."""

    def __init__(self) -> None:
        self.interruptible = False  # inside a procedure's step loop
        self.active = 0  # procedures running (nested); 0: nothing to protect, a Ctrl-C may break anything
        self.restoring = False
        self.pending: list[str] = []


def reboots_seen(link: VehiclePort) -> int:
    """How many reboots of the vehicle the link has seen (a new boot time, or a sequence reset)."""
    return int(link.clock.reboots)


@dataclass
class RestorePoint:
    """How the autopilot was found (module docstring).

    ``parameters`` holds the declared neutral parameters the profile knows (the "original gains" of
    reports and step checks); ``native`` the autopilot's own parameters behind them, which are what
    is restored (one neutral heading gain may map onto several rate-loop parameters,
    ``AutopilotProfile.natives_touched``); ``setpoints`` the declared set-points the autopilot keeps,
    read from the latest telemetry; ``boot`` the vehicle's reboots seen by the link when it was taken."""

    mode: str | None
    parameters: dict[str, float] = field(default_factory=dict)
    native: dict[str, float] = field(default_factory=dict)
    setpoints: dict[str, float] = field(default_factory=dict)
    natives_of: dict[str, tuple[str, ...]] = field(default_factory=dict)  # neutral -> its native names
    boot: int = 0
    notes: list[str] = field(default_factory=list)  # what the last restore decided (kept changes, reboots)

    @classmethod
    def capture(cls, link: VehiclePort, footprint: Footprint = Footprint()) -> "RestorePoint":
        profile = link.profile
        known = profile.params
        neutral = sorted(name for name in footprint.parameters if name in known)
        unknown = sorted(set(footprint.parameters) - set(neutral))
        if unknown:
            log.info("restore point: this profile has no parameter for %s (not touched)", unknown)
        natives_of = {name: profile.natives_touched([name]) for name in neutral}
        native: dict[str, float] = {}
        unread: list[str] = []
        for name in dict.fromkeys(n for names in natives_of.values() for n in names):
            try:
                native[name] = link.get_param(name)
            except Exception:  # noqa: BLE001 - read again below
                unread.append(name)
        telemetry = link.latest_telemetry
        kept_by_autopilot = _persistent_setpoints(link)
        setpoints: dict[str, float] = {}
        if telemetry is not None:
            # the heading the autopilot holds where it reports it, else the heading it is on
            heading = telemetry.heading_target if math.isfinite(telemetry.heading_target) else telemetry.yaw
            for setpoint, value in (("thrust", telemetry.thrust_ratio), ("heading", heading),
                                    ("rolling_mass", telemetry.mass_angle)):
                if setpoint in footprint.setpoints and setpoint in kept_by_autopilot and math.isfinite(value):
                    setpoints[setpoint] = float(value)
        parameters = dict(link.get_params(neutral)) if neutral else {}
        for name in unread:  # a second chance: answers lost on the link are not a missing parameter
            try:  # (fault injection: three lost PARAM_VALUEs left HDG_I out, and an abort left it changed)
                native[name] = link.get_param(name)
            except Exception as exc:  # noqa: BLE001 - a parameter this firmware lacks is not touched either
                log.info("restore point: %s not readable (%s)", name, exc)
        link.parameters.watch(native)  # from now on a change by anyone else is seen
        link.commands.forget_abandoned()  # a late set-point of an earlier procedure is this one's to override now
        return cls(mode=link.mode or None, parameters=parameters, native=native,
                   setpoints=setpoints, natives_of=natives_of, boot=reboots_seen(link))

    # ------------------------------------------------------------------ the trail's form
    def as_json(self) -> dict:
        return {"mode": self.mode, "parameters": self.parameters, "native": self.native,
                "setpoints": self.setpoints, "natives_of": {k: list(v) for k, v in self.natives_of.items()},
                "boot": self.boot}

    @classmethod
    def from_json(cls, data: dict) -> "RestorePoint":
        return cls(mode=data.get("mode"), parameters=dict(data.get("parameters") or {}),
                   native=dict(data.get("native") or {}), setpoints=dict(data.get("setpoints") or {}),
                   natives_of={k: tuple(v) for k, v in (data.get("natives_of") or {}).items()},
                   boot=int(data.get("boot") or 0))

    # ------------------------------------------------------------------ putting it back
    def restore(self, link: VehiclePort, *, parameters: bool = True, mode: bool = True,
                keep: Iterable[str] = (), guard: RestoreGuard | None = None) -> list[str]:
        """Release overrides, write back every parameter that changed (except the natives of the
        neutral names in ``keep``: verified results a procedure leaves on purpose, and what someone
        else changed meanwhile), put the found set-points back (confirmed by the vehicle's state),
        restore the mode; after a reboot, parameters only (module docstring).

        Each item is tried up to ``RESTORE_TRIES`` times and every item is tried even if another
        fails: a restore never stops half-way. With a ``guard`` the signal handler knows a restore is
        under way (it then never interrupts it) and what is still pending. The failures are returned
        and logged; what was decided is in :attr:`notes`."""
        self.notes = []
        _abandon_procedure_setpoints(link)
        rebooted = reboots_seen(link) > self.boot
        # no mode switch ends an excitation when the mode is not the companion's to change
        items: list[tuple[str, Callable[[], None]]] = [
            ("release overrides", lambda: _release_all(link, switch_mode=mode and not rebooted))]
        if parameters:
            items += self._parameter_items(link, keep)
            items.append(("check the parameters again", lambda: self._recheck_parameters(link, keep)))
        watched: list[WatchedSetpoint] = []
        items += [(what, functools.partial(self._unless_rebooted, link, what, action))
                  for what, action in self._setpoint_items(link, mode, watched)]
        if _late_setpoints_possible(link):
            items.append(("put back the procedure's late set-points",
                          lambda: LateSetpointWatch(link, watched, self.notes).settle()))
        items.append(("stop refreshing the procedure's targets", lambda: _forget_targets(link)))
        guard = guard or RestoreGuard()
        was_interruptible, guard.interruptible = guard.interruptible, False
        guard.restoring, guard.pending = True, [what for what, _ in items]
        problems: list[str] = []
        reconnect = Reconnector(link)
        try:
            for what, action in items:
                failure = try_restore_item(what, action, reconnect)
                if failure is not None:
                    problems.append(failure)
                guard.pending.remove(what)
        finally:
            guard.restoring, guard.interruptible = False, was_interruptible
            _stop_watching(link)
        for note in self.notes:
            log.warning("restore: %s", note)
        return problems

    def _parameter_items(self, link: VehiclePort, keep: Iterable[str]) -> list[tuple[str, Callable[[], None]]]:
        kept = {n for name in keep for n in self.natives_of.get(name, ())}
        foreign = dict(link.parameters.foreign)
        items: list[tuple[str, Callable[[], None]]] = []
        for name, value in self.native.items():
            if name in kept:
                continue
            change = foreign.get(name)
            if change is not None:
                items.append((f"restore {name}", functools.partial(self._keep_or_restore, link, name, value, change)))
                continue
            items.append((f"restore {name}", functools.partial(write_if_changed, link, name, value)))
        return items

    def _recheck_parameters(self, link: VehiclePort, keep: Iterable[str]) -> None:
        """Read the restored parameters again once what was in flight has landed: a write of the
        procedure delayed on the link can arrive after the restore's (as a set-point can,
        ``restore_items``). One found changed again is written back once more and said. Nothing can
        be in flight in lockstep or in process: then there is nothing to check."""
        if not self.native or not in_flight_possible(link):
            return
        wait_in_flight(link)
        kept = {n for name in keep for n in self.natives_of.get(name, ())}
        foreign = link.parameters.foreign
        for name, found in self.native.items():
            if name in kept or name in foreign:
                continue
            current = link.get_param(name)
            if not (math.isfinite(current) and abs(current - found) <= 1e-6 * max(1.0, abs(found))):
                self.notes.append(f"{name} read {current:g} after it was restored (a late write of the "
                                  f"procedure): written back to {found:g} again")
                link.set_param(name, found)

    def _keep_or_restore(self, link: VehiclePort, name: str, found: float, change: ForeignChange) -> None:
        """A parameter someone else changed during the procedure: read it again, keep it if it still
        holds their value (and that is no value a write of ours asked for), else put back ``found``
        (their change was overwritten since, or the announcement was a late echo of ours)."""
        current = link.get_param(name)
        theirs = math.isfinite(current) and abs(current - change.value) <= 1e-6 * max(1.0, abs(change.value))
        if theirs and not link.parameters.ours(name, current):
            self.notes.append(f"{name}: kept {change.value:g}, set by someone else during the procedure "
                              f"(found {found:g})")
            return
        write_if_changed(link, name, found)

    def _setpoint_items(self, link: VehiclePort, mode: bool,
                        watched: list[WatchedSetpoint]) -> list[tuple[str, Callable[[], None]]]:
        """The found set-points' items (and the mode's); each set-point put back and confirmed is
        added to ``watched`` with the MAVLink command that carried it (``late_setpoints``)."""
        items: list[tuple[str, Callable[[], None]]] = []
        found_in_setpoint_mode = self.mode in SETPOINT_MODES
        checks = (("thrust", SetThrust, StateCheck("thrust", lambda t: t.thrust_ratio, 0.0, THRUST_TOLERANCE)),
                  ("heading", SetHeading, _reported(link, StateCheck("heading target", lambda t: t.heading_target,
                                                                    0.0, HEADING_TOLERANCE, angular=True))),
                  ("rolling_mass", SetRollingMass, StateCheck("rolling mass", lambda t: t.mass_angle, 0.0,
                                                              MASS_TOLERANCE)))
        for name, command, check in checks:
            if name not in self.setpoints or (name != "rolling_mass" and not found_in_setpoint_mode):
                continue
            target = self.setpoints[name]
            check = replace(check, target=target) if check is not None else None
            label = name.replace('_', ' ')
            items.append((f"restore {label}", functools.partial(_put_back, link, label, command(target), check,
                                                                 watched)))
        if mode and self.mode:
            items.append(("restore mode", functools.partial(link.set_mode, self.mode)))
        return items

    def _unless_rebooted(self, link: VehiclePort, what: str, action: Callable[[], None]) -> None:
        """A set-point or the mode, unless the vehicle rebooted since the restore point was taken:
        a freshly booted vehicle's mode and set-points are its own (never a mode for a vehicle that
        may be disarmed on its cradle)."""
        if reboots_seen(link) > self.boot:
            note = "the vehicle rebooted during the procedure: its new boot keeps its own mode and set-points"
            if note not in self.notes:
                self.notes.append(note)
            log.info("%s: not done (%s)", what, note)
            return
        action()


def _put_back(link: VehiclePort, label: str, setpoint: Command, check: StateCheck | None,
              watched: list[WatchedSetpoint]) -> None:
    """One found set-point sent and confirmed by state; what carried it is noted for the late watch."""
    sends = link.commands.sends_of
    before = dict(sends)
    set_and_confirm(link, setpoint, check)
    if check is None:
        return
    for command in [c for c in sends if sends[c] > before.get(c, 0)]:
        watched.append(WatchedSetpoint(label, command, setpoint, check))


def _late_setpoints_possible(link: VehiclePort) -> bool:
    """A set-point the restore abandoned may still be answered (a MAVLink link; the in-process harness
    applies every command at once)."""
    return link.commands.answers_late


def _reported(link: VehiclePort, check: StateCheck) -> StateCheck | None:
    """``check``, where the vehicle reports that state (its profile says so), else None."""
    if check.what == "heading target" and not link.profile.reports_heading_target:
        return None
    return check


def _release_all(link: VehiclePort, *, switch_mode: bool = True) -> None:
    """Release every override through the autopilot's strategy (ArduSub keeps a released override's
    last value unless the stick is centred first; ArduRover's excitation ends by leaving MANUAL,
    unless ``switch_mode`` is False: the pilot has the vehicle, or it rebooted)."""
    if not switch_mode:
        link.autopilot.forget_excitation()
    link.autopilot.release(None)


def _forget_targets(link: VehiclePort) -> None:
    """The strategy stops refreshing the procedure's targets (``AutopilotStrategy.forget_targets``)."""
    link.autopilot.forget_targets()


def _abandon_procedure_setpoints(link: VehiclePort) -> None:
    """Nothing of the procedure is sent once its restore begins: set-points it left unanswered are
    no longer re-sent (one arriving late is caught by the state confirmation)."""
    abandoned = link.commands.abandon()
    if abandoned:
        log.info("restore: the procedure's unanswered set-points %s are not sent again", abandoned)


def _stop_watching(link: VehiclePort) -> None:
    link.parameters.watch(())


def _persistent_setpoints(link: VehiclePort) -> tuple[str, ...]:
    """The set-points the link's autopilot keeps after the companion is done (its strategy's
    ``persistent_setpoints``): only those are captured and put back. Elsewhere a set-point is not
    autopilot state (ArduSub's thrust is an RC override the restore releases; ArduRover's speed is a
    fraction of WP_SPEED that telemetry does not report), so there is nothing to restore."""
    return tuple(link.autopilot.persistent_setpoints)
