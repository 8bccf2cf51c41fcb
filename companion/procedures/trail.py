"""The trail a procedure leaves, and following it after a crash (SPEC C1: "every procedure can be
aborted at any moment and then leaves the autopilot as it found it" — including by ``kill -9``).

A campaign's row names its process from the start (``Store.start_campaign``: host, boot, PID and
the PID's start time, ``companion.records.owner``). Before a procedure's first change its restore
point (how the vehicle was found) is stored in a trail of its own, and every change is recorded
*before* it is sent (:class:`TrailRecorder`): the behaviour's commands, every parameter write and
mode request the link makes, and every RC channel it starts holding, whoever asked (a behaviour or
the autopilot's strategy). When the restore has run, the trail is closed. A trail still open
whose process is gone was **interrupted**. The next start (``companion recover``, or ``identify``
and ``run`` before they do anything) finds it, says what differs on the vehicle now, and — when
the operator agrees (``--yes`` for scripts) — puts the vehicle back:

* overrides the trail held are released (on ArduSub the stick is centred first);
* a parameter is written back if it holds a value the procedure wrote; one holding a value the
  procedure never wrote was set by someone else after the crash and is kept (said);
* set-points and the mode go back only if the vehicle is still in its found mode or in one the
  procedure asked for, and not after a reboot (a fresh boot keeps its own; on ArduPilot the boot
  counter tells, and a counter that cannot be read counts as a reboot: parameters only).

A recovery that could not put everything back leaves the trail open (and the command exits
non-zero), so the next start tries again; once the vehicle is as found it closes at once.
"""
from __future__ import annotations

import dataclasses
import logging
import math
from dataclasses import dataclass, field
from typing import Callable, Sequence

from companion.interface import Command, OverrideActuator, ReleaseActuator, SetMode
from companion.link.port import VehiclePort
from companion.procedures.restore import RestoreGuard, RestorePoint
from companion.procedures.restore_items import pump_vehicle_time
from companion.records.owner import ProcessOwner

log = logging.getLogger(__name__)

#: ArduPilot's boot counter: a restore point taken on another boot keeps its parameters, not its mode
BOOT_COUNT_PARAM = "STAT_BOOTCNT"
#: vehicle seconds a recovery keeps reading telemetry after releasing what a dead companion held
#: (ArduSub releases a centred stick 0.25 s after centring it; each release is sent three times)
RELEASE_PUMP_S = 1.0
#: change kinds recorded from the link itself (not behaviour commands)
PARAM_WRITE, MODE_REQUEST, CHANNEL_HELD = "ParamWrite", "ModeRequest", "ChannelHeld"


def vehicle_identity(link: VehiclePort) -> dict:
    """Which vehicle a trail belongs to (system id, profile, the board's own id where the autopilot
    sends one), and where its clock and boot counter were (a later clock that is earlier, or a
    counter that moved, means it rebooted since)."""
    identity = {"system_id": link.transport.system_id, "profile": link.profile.name,
                "endpoint": link.transport.endpoint, "vehicle_time_s": _finite(link.vehicle_time_s)}
    uid = link.announcements.hardware_uid
    if uid:
        identity["hardware_uid"] = uid
    boots = _boot_count(link)
    if boots is not None:
        identity["boot_count"] = boots
    return identity


def _boot_count(link: VehiclePort) -> float | None:
    if link.profile.name.startswith("sim"):
        return None
    try:
        return float(link.get_param(BOOT_COUNT_PARAM))
    except Exception:  # noqa: BLE001 - an autopilot without a boot counter, or a link that lost the answers
        return None


def _finite(value) -> float | None:
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None


class TrailRecorder:
    """``recorder(commands)``: each state change stored before it is sent (the runner's
    ``on_change``), plus the link's own parameter writes, mode requests and newly held RC channels
    (subscribed here; :meth:`close` unsubscribes). An override is recorded once per actuator while
    it is held (a doublet changes its value every step; a recovery needs only which were held)."""

    def __init__(self, store, trail_id: int, link: VehiclePort) -> None:
        self.store, self.trail_id, self.link = store, trail_id, link
        self._overridden: set[str] = set()
        self._unsubscribe: list[Callable[[], None]] = [link.parameters.on_write(self._param_write),
                                                        link.modes.on_request(self._mode_request),
                                                        link.overrides.on_hold(self._channel_held)]

    def _now(self) -> float | None:
        return _finite(self.link.vehicle_time_s)

    def __call__(self, commands: Sequence[Command]) -> None:
        for command in commands:
            if isinstance(command, OverrideActuator):
                if command.actuator in self._overridden:
                    continue
                self._overridden.add(command.actuator)
            elif isinstance(command, ReleaseActuator):
                released = self._overridden if command.actuator is None else {command.actuator}
                if not released & self._overridden:
                    continue
                self._overridden -= released
            detail = dataclasses.asdict(command) if dataclasses.is_dataclass(command) else {"repr": repr(command)}
            self.store.add_change(self.trail_id, self._now(), type(command).__name__, detail)

    def _param_write(self, name: str, value: float) -> None:
        self.store.add_change(self.trail_id, self._now(), PARAM_WRITE, {"name": name, "value": value})

    def _mode_request(self, neutral: str) -> None:
        self.store.add_change(self.trail_id, self._now(), MODE_REQUEST, {"mode": neutral})

    def _channel_held(self, channel: int) -> None:
        self.store.add_change(self.trail_id, self._now(), CHANNEL_HELD, {"channel": channel})

    def close(self) -> None:
        for unsubscribe in self._unsubscribe:
            unsubscribe()
        self._unsubscribe.clear()


# ====================================================================== finding and following
@dataclass
class Trail:
    """An interrupted procedure: its trail, campaign, restore point, vehicle, the changes it made
    and the process that owned it."""

    trail_id: int | None
    campaign_id: int
    kind: str
    started_utc: str
    restore: RestorePoint | None
    vehicle: dict
    changes: list[dict] = field(default_factory=list)
    owner: ProcessOwner = field(default_factory=lambda: ProcessOwner(None, ""))

    def _of(self, kind: str) -> list[dict]:
        return [c["detail"] for c in self.changes if c["kind"] == kind]

    def overrides_held(self, channel_names: dict[int, str] | None = None) -> list[str]:
        """The actuators the procedure may have left overridden: overridden by a behaviour and not
        released after, and every channel the link started holding (named through ``channel_names``,
        channel → actuator, where given), whatever its state."""
        held: set[str] = set()
        for change in self.changes:
            detail = change["detail"]
            if change["kind"] == OverrideActuator.__name__ and detail.get("actuator"):
                held.add(detail["actuator"])
            elif change["kind"] == ReleaseActuator.__name__:
                held = set() if detail.get("actuator") is None else held - {detail["actuator"]}
        for detail in self._of(CHANNEL_HELD):
            channel = detail.get("channel")
            name = (channel_names or {}).get(channel) if isinstance(channel, int) else None
            held.add(name if name else f"channel {detail.get('channel')}")
        return sorted(held)

    def wrote(self, name: str, value: float) -> bool:
        """The procedure wrote ``value`` to parameter ``name`` (its autopilot name)."""
        return any(d.get("name") == name and isinstance(d.get("value"), (int, float))
                   and abs(d["value"] - value) <= 1e-6 * max(1.0, abs(value)) for d in self._of(PARAM_WRITE))

    @property
    def modes_asked(self) -> set[str]:
        """The modes the procedure asked for (its behaviour's, and its strategy's own switches)."""
        return {d["mode"] for d in self._of(MODE_REQUEST) + self._of(SetMode.__name__) if isinstance(d.get("mode"), str)}

    @property
    def last_change_s(self) -> float | None:
        times = [c["vehicle_time_s"] for c in self.changes if c["vehicle_time_s"] is not None]
        return max(times) if times else None


def interrupted(store) -> list[Trail]:
    """The store's open trails whose process is gone (a live owner is still running its procedure)."""
    found = []
    for row in store.open_trails():
        owner: ProcessOwner = row["owner"]
        if owner.alive():
            continue
        restore = RestorePoint.from_json(row["restore"]) if row["restore"] else None
        found.append(Trail(row["trail_id"], row["campaign_id"], row["kind"], row["started_utc"], restore,
                           row["vehicle"], row["changes"], owner))
    return found


@dataclass
class Recovery:
    """What following a trail found and did; ``complete`` when the vehicle is back as found (the
    trail is then closed), False when something could not be put back (the trail stays open)."""

    campaign_id: int
    differences: list[str]
    applied: bool
    problems: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    other_vehicle: bool = False  # the trail belongs to another vehicle: left for it

    @property
    def complete(self) -> bool:
        return self.applied and not self.problems

    def as_json(self) -> dict:
        return {**dataclasses.asdict(self), "complete": self.complete}


def _channel_names(link: VehiclePort) -> dict[int, str]:
    channels = link.profile.channels
    return {channel: name for name, channel in channels.items()}


def _other_vehicle(link: VehiclePort, trail: Trail) -> str | None:
    """Why the trail is not this vehicle's (None when it is, or when nothing tells)."""
    now = {"system_id": link.transport.system_id, "profile": link.profile.name,
           "hardware_uid": link.announcements.hardware_uid}
    for key, what in (("hardware_uid", "board"), ("system_id", "system"), ("profile", "autopilot")):
        then = trail.vehicle.get(key)
        if then is not None and now[key] is not None and then != now[key]:
            return f"{what} {then}, not this vehicle's {now[key]}"
    return None


def _rebooted_since(link: VehiclePort, trail: Trail) -> tuple[bool, str | None]:
    """(rebooted, note): the vehicle's clock is now earlier than the trail's last change, or its boot
    counter moved; a boot counter recorded then and unreadable now counts as a reboot (said)."""
    now = link.vehicle_time_s
    last = trail.last_change_s if trail.last_change_s is not None else trail.vehicle.get("vehicle_time_s")
    if math.isfinite(now) and last is not None and now < last:
        return True, None
    before = trail.vehicle.get("boot_count")
    if before is None:
        return False, None
    after = _boot_count(link)
    if after is None:
        return True, (f"{BOOT_COUNT_PARAM} could not be read: taken as rebooted (parameters put back, "
                      "the mode and set-points left as they are)")
    return after != before, None


def _parameters_now(link: VehiclePort, restore: RestorePoint) -> dict[str, float | None]:
    """Each restored parameter's value on the vehicle now (None: not readable)."""
    values: dict[str, float | None] = {}
    for name in restore.native:
        try:
            values[name] = link.get_param(name)
        except Exception:  # noqa: BLE001 - said by differences(), tried again by the restore
            values[name] = None
    return values


def _same(a: float | None, b: float) -> bool:
    return a is not None and math.isfinite(a) and abs(a - b) <= 1e-6 * max(1.0, abs(b))


def differences(link: VehiclePort, trail: Trail, values: dict[str, float | None] | None = None) -> list[str]:
    """What is not as the procedure found it, one line each."""
    restore = trail.restore
    out = [f"RC override of the {name} may still be held" for name in trail.overrides_held(_channel_names(link))]
    if restore is None:
        return out + ["no restore point was stored: the procedure ended before its first change"]
    values = _parameters_now(link, restore) if values is None else values
    for name, found in restore.native.items():
        now = values.get(name)
        if now is None:
            out.append(f"{name}: not readable now; found {found:g}")
        elif not _same(now, found):
            who = "" if trail.wrote(name, now) else " (a value the procedure never wrote)"
            out.append(f"{name} is {now:g}, found {found:g}{who}")
    mode = link.mode
    if restore.mode and mode and mode != restore.mode:
        out.append(f"mode is {mode}, found {restore.mode}")
    latest = link.latest_telemetry
    if latest is not None and "thrust" in restore.setpoints and math.isfinite(latest.thrust_ratio) \
            and abs(latest.thrust_ratio - restore.setpoints["thrust"]) > 0.011:
        out.append(f"thrust is {latest.thrust_ratio:.2f}, found {restore.setpoints['thrust']:.2f}")
    return out


def _plan(link: VehiclePort, trail: Trail, values: dict[str, float | None], rebooted: bool) -> tuple[RestorePoint, bool, list[str]]:
    """The restore to run: parameters someone else set after the crash left out, the mode and
    set-points only where the vehicle is still in a mode of the procedure's (module docstring).
    Returns (restore point, whether the mode is put back, notes)."""
    restore = trail.restore
    if restore is None:
        raise ValueError("a trail without a restore point has nothing to plan")
    notes: list[str] = []
    native = {}
    for name, found in restore.native.items():
        now = values.get(name)
        if now is not None and not _same(now, found) and not trail.wrote(name, now):
            notes.append(f"{name}: kept {now:g}, set by someone else after the companion stopped (found {found:g})")
            continue
        native[name] = found
    plan = dataclasses.replace(restore, native=native)
    mode_now = link.mode
    ours = mode_now in trail.modes_asked or mode_now == restore.mode
    if rebooted:
        plan.setpoints = {}
        return plan, False, notes
    if not ours and mode_now:
        notes.append(f"mode {mode_now} was chosen by someone else after the companion stopped: left as it is, "
                     "with its set-points")
        plan.setpoints = {}
        return plan, False, notes
    return plan, True, notes


def recover(link: VehiclePort, store, trail: Trail, decide: Callable[[list[str]], bool | None],
            guard: RestoreGuard | None = None) -> Recovery:
    """Follow ``trail`` on the connected vehicle: say what differs, and if ``decide(differences)``
    agrees, put it back (module docstring); ``decide`` answers None when nobody could be asked (no
    terminal and no ``--yes``), which is said as such, never as the operator's refusal. When everything is back the trail is closed and the
    campaign ends ``interrupted``; otherwise the trail stays open for the next start. A trail of
    another vehicle is left as it is. ``guard`` keeps a second Ctrl-C from cutting a write."""
    other = _other_vehicle(link, trail)
    if other is not None:
        note = f"campaign {trail.campaign_id} was flown on {other}: left for that vehicle's next start"
        return Recovery(trail.campaign_id, [], False, notes=[note], other_vehicle=True)
    values = _parameters_now(link, trail.restore) if trail.restore is not None else {}
    found = differences(link, trail, values)
    answer = decide(found)
    if answer is None:
        return Recovery(trail.campaign_id, found, False,
                        notes=["nobody could be asked (no terminal, no --yes): the vehicle was not changed"])
    if not answer:
        return Recovery(trail.campaign_id, found, False, notes=["the operator declined: the vehicle was not changed"])
    rebooted, reboot_note = _rebooted_since(link, trail)
    notes = [reboot_note] if reboot_note else []
    problems = _release_held(link, trail)
    if trail.restore is not None:
        plan, mode, planned = _plan(link, trail, values, rebooted)
        notes += planned
        reboots_now = link.clock.reboots
        # the restore point's boot, counted on this link: one before now if the vehicle rebooted since
        # (the restore then keeps the new boot's mode and set-points), else now
        plan.boot = reboots_now - 1 if rebooted else reboots_now
        problems += plan.restore(link, mode=mode, guard=guard)
        notes += plan.notes
    result = Recovery(trail.campaign_id, found, True, problems, notes)
    if problems:
        log.error("campaign %d: not everything could be put back: %s", trail.campaign_id, "; ".join(problems))
        return result  # the trail stays open: the next start tries again
    reason = f"interrupted: the companion ({trail.owner.describe()}) stopped during the procedure; the next start " \
             "put the vehicle back"
    if trail.trail_id is not None:
        store.finish_restore(trail.trail_id, problems, notes)
    store.close_trail(trail.trail_id, trail.campaign_id, "interrupted", reason)
    log.warning("campaign %d: %s", trail.campaign_id, reason)
    return result


def _release_held(link: VehiclePort, trail: Trail) -> list[str]:
    """Release what the dead companion may have held, through the autopilot's strategy, and keep
    reading telemetry :data:`RELEASE_PUMP_S` so the releases (and ArduSub's centring) go out."""
    names = _channel_names(link)
    held = [name for name in trail.overrides_held(names) if not name.startswith("channel ")]
    if not held:
        return []
    try:
        link.autopilot.release_after_crash(held)
        pump_vehicle_time(link, RELEASE_PUMP_S)
    except Exception as exc:  # noqa: BLE001 - said; the restore still runs
        return [f"release the overrides {', '.join(held)}: {exc}"]
    return []


def close_without_vehicle(store, trail: Trail) -> None:
    """A trail with nothing to put back (no restore point, no change): closed ``interrupted``."""
    store.close_trail(trail.trail_id, trail.campaign_id, "interrupted",
                      f"interrupted: the companion ({trail.owner.describe()}) stopped before the procedure "
                      "changed anything")
