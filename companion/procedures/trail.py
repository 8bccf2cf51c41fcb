"""The trail a procedure leaves, and following it after a crash (SPEC C1: "every procedure can be
aborted at any moment and then leaves the autopilot as it found it" — including by ``kill -9``).

Before a procedure's first change the application stores its restore point (how the vehicle was
found) with this process's identity; every change is recorded *before* it is sent
(:class:`TrailRecorder`); when the restore has run, the trail is closed. A trail still open whose
process is gone was **interrupted**. The next start (``companion recover``, or ``identify`` and
``run`` before they do anything) finds it, says what differs on the vehicle now, and — when the
operator agrees (``--yes`` for scripts) — puts the vehicle back: overrides the procedure held are
released, parameters written back, set-points and mode restored unless the vehicle rebooted since
(a fresh boot keeps its own). The campaign row then ends ``interrupted``, never ``running``.
"""
from __future__ import annotations

import dataclasses
import logging
import math
import os
import socket
from dataclasses import dataclass, field
from typing import Callable, Sequence

from companion.interface import Command, OverrideActuator
from companion.procedures.restore import RestorePoint

log = logging.getLogger(__name__)

#: ArduPilot's boot counter: a restore point taken on another boot keeps its parameters, not its mode
BOOT_COUNT_PARAM = "STAT_BOOTCNT"


def vehicle_identity(link) -> dict:
    """Which vehicle a trail belongs to, and where its clock was (a later clock that is earlier
    means it rebooted since)."""
    transport = getattr(link, "transport", None)
    identity = {"system_id": getattr(transport, "system_id", getattr(link, "system_id", None)),
                "profile": getattr(getattr(link, "profile", None), "name", None),
                "endpoint": getattr(transport, "endpoint", None),
                "vehicle_time_s": _finite(getattr(link, "vehicle_time_s", math.nan))}
    boots = _boot_count(link)
    if boots is not None:
        identity["boot_count"] = boots
    return identity


def _boot_count(link) -> float | None:
    profile = getattr(link, "profile", None)
    if profile is None or getattr(profile, "name", "").startswith("sim"):
        return None
    try:
        return float(link.get_param(BOOT_COUNT_PARAM, retries=1))
    except Exception:  # noqa: BLE001 - an autopilot without a boot counter
        return None


def _finite(value) -> float | None:
    return float(value) if isinstance(value, (int, float)) and math.isfinite(value) else None


class TrailRecorder:
    """``recorder(commands)``: each state change stored before it is sent (the runner's ``on_change``)."""

    def __init__(self, store, campaign_id: int, link) -> None:
        self.store, self.campaign_id, self.link = store, campaign_id, link

    def __call__(self, commands: Sequence[Command]) -> None:
        now = _finite(getattr(self.link, "vehicle_time_s", math.nan))
        for command in commands:
            detail = dataclasses.asdict(command) if dataclasses.is_dataclass(command) else {"repr": repr(command)}
            self.store.add_change(self.campaign_id, now, type(command).__name__, detail)


# ====================================================================== finding and following
@dataclass
class Trail:
    """An interrupted procedure: its campaign, restore point, vehicle, and the changes it made."""

    campaign_id: int
    kind: str
    started_utc: str
    restore: RestorePoint | None
    vehicle: dict
    changes: list[dict] = field(default_factory=list)
    owner: str = ""

    @property
    def overrides_held(self) -> list[str]:
        """The actuators the procedure overrode (released by a recovery, whatever their state)."""
        return sorted({c["detail"].get("actuator") for c in self.changes if c["kind"] == OverrideActuator.__name__}
                      - {None})

    @property
    def last_change_s(self) -> float | None:
        times = [c["vehicle_time_s"] for c in self.changes if c["vehicle_time_s"] is not None]
        return max(times) if times else None


def _owner_alive(pid, host) -> bool:
    if pid is None or host != socket.gethostname():
        return False
    if pid == os.getpid():
        return True
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's live process
        return True
    return True


def interrupted(store) -> list[Trail]:
    """The store's open trails whose process is gone (a live owner is still running its procedure)."""
    found = []
    for row in store.open_trails():
        if _owner_alive(row["owner_pid"], row["owner_host"]):
            continue
        restore = RestorePoint.from_json(row["restore"]) if row["restore"] else None
        found.append(Trail(row["campaign_id"], row["kind"], row["started_utc"], restore, row["vehicle"],
                           row["changes"], f"pid {row['owner_pid']} on {row['owner_host']}"))
    return found


@dataclass
class Recovery:
    """What following a trail found and did."""

    campaign_id: int
    differences: list[str]
    applied: bool
    problems: list[str] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)
    other_vehicle: bool = False  # the trail belongs to another vehicle: left for it

    def as_json(self) -> dict:
        return dataclasses.asdict(self)


def _rebooted_since(link, trail: Trail) -> bool:
    """The vehicle's clock is now earlier than the trail's last change, or its boot counter moved."""
    now = getattr(link, "vehicle_time_s", math.nan)
    last = trail.last_change_s if trail.last_change_s is not None else trail.vehicle.get("vehicle_time_s")
    if isinstance(now, float) and math.isfinite(now) and last is not None and now < last:
        return True
    before = trail.vehicle.get("boot_count")
    after = _boot_count(link) if before is not None else None
    return before is not None and after is not None and after != before


def differences(link, trail: Trail) -> list[str]:
    """What is not as the procedure found it, one line each."""
    restore = trail.restore
    out = [f"RC override of the {name} may still be held" for name in trail.overrides_held]
    if restore is None:
        return out + ["no restore point was stored: the procedure ended before its first change"]
    for name, found in restore.native.items():
        try:
            now = link.get_param(name)
        except Exception as exc:  # noqa: BLE001 - said, and tried again by the restore
            out.append(f"{name}: not readable now ({exc}); found {found:g}")
            continue
        if not (math.isfinite(now) and abs(now - found) <= 1e-6 * max(1.0, abs(found))):
            out.append(f"{name} is {now:g}, found {found:g}")
    mode = getattr(link, "mode", None)
    if restore.mode and mode and mode != restore.mode:
        out.append(f"mode is {mode}, found {restore.mode}")
    latest = getattr(link, "latest_telemetry", None)
    if latest is not None and "thrust" in restore.setpoints and math.isfinite(latest.thrust_ratio) \
            and abs(latest.thrust_ratio - restore.setpoints["thrust"]) > 0.011:
        out.append(f"thrust is {latest.thrust_ratio:.2f}, found {restore.setpoints['thrust']:.2f}")
    return out


def recover(link, store, trail: Trail, decide: Callable[[list[str]], bool]) -> Recovery:
    """Follow ``trail`` on the connected vehicle: say what differs, and if ``decide(differences)``
    agrees, put it back and close the campaign ``interrupted``. A trail of another vehicle is left
    as it is."""
    system_id = getattr(getattr(link, "transport", None), "system_id", None)
    profile = getattr(getattr(link, "profile", None), "name", None)
    if trail.vehicle.get("system_id") not in (None, system_id) or trail.vehicle.get("profile") not in (None, profile):
        note = (f"campaign {trail.campaign_id} was flown on system {trail.vehicle.get('system_id')} "
                f"({trail.vehicle.get('profile')}), not this vehicle: left for that vehicle's next start")
        return Recovery(trail.campaign_id, [], False, notes=[note], other_vehicle=True)
    found = differences(link, trail)
    if not decide(found):
        return Recovery(trail.campaign_id, found, False, notes=["the operator declined: the vehicle was not changed"])
    rebooted = _rebooted_since(link, trail)
    problems: list[str] = []
    overrides = getattr(link, "overrides", None)
    for actuator in trail.overrides_held:
        try:
            overrides.release(actuator)
        except Exception as exc:  # noqa: BLE001 - reported, the rest still runs
            problems.append(f"release the {actuator}: {exc}")
    notes: list[str] = []
    if trail.restore is not None:
        restore = trail.restore
        reboots_now = int(getattr(getattr(link, "clock", None), "reboots", 0) or 0)
        # the restore point's boot, counted on this link: one before now if the vehicle rebooted since
        # (the restore then keeps the new boot's mode and set-points), else now
        restore.boot = reboots_now - 1 if rebooted else reboots_now
        problems += restore.restore(link)
        notes += restore.notes
    reason = (f"interrupted: the companion ({trail.owner}) stopped during the procedure; the next start "
              f"put the vehicle back" + (f" ({len(problems)} item(s) could not be)" if problems else ""))
    store.finish_restore(trail.campaign_id, problems, notes)
    store.finish_campaign(trail.campaign_id, "interrupted", reason)
    log.warning("campaign %d: %s", trail.campaign_id, reason)
    return Recovery(trail.campaign_id, found, True, problems, notes)


def close_without_vehicle(store, trail: Trail) -> None:
    """A trail with nothing to put back (no restore point, no change): closed ``interrupted``."""
    store.finish_campaign(trail.campaign_id, "interrupted",
                          f"interrupted: the companion ({trail.owner}) stopped before the procedure changed anything")
