"""The designed gains of a stored campaign as parameter files a ground station loads.

``companion results --campaign N --export FILE``: the campaign's gain designs (every schedule kind
it designed: the heading PI, ArduPilot's native steering/yaw cascade, the pitch PI), in the
autopilot's own parameter names and units (its profile), either

* **per speed** (no ``--speed``): one file per identified speed, ``FILE-<speed>ms.<suffix>``,
  holding the gains the schedule gives at that speed (the design's stored points, exactly), or
* **at a chosen speed** (``--speed U``): one file with the schedule's gains at U, from the stored
  schedule under the design rules the design carries (``GainDesign.rules``). A design stored before
  designs carried their rules is exported per identified speed only.

Only a completed campaign is exported. Each file starts with comments saying what it holds, from
which campaign, at which speed, and whether the gains were checked on the vehicle (a live campaign
keeps gains only after heading steps; gains designed from a log were never flown).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from behaviors.gain_scheduling import GainDesign, ScheduleKind
from behaviors.schedules import kind_of, schedule_kind
from companion.errors import UserError
from companion.link.profiles import get_profile
from companion.records.param_files import FORMATS, ParamFile, write
from companion.records.store import Store

#: file suffix → format (anything else: ``parm`` unless ``--format`` says otherwise)
SUFFIX_FORMATS = {".parm": "parm", ".param": "parm", ".params": "qgc"}


class ExportError(UserError):
    """A campaign whose gains cannot be exported as asked (one sentence, exit code 1)."""


@dataclass(frozen=True)
class GainSet:
    """The gains of every designed kind at one speed: neutral names and the autopilot's."""

    speed: float
    thrust: float | None
    neutral: dict[str, float]
    native: dict[str, float]
    notes: tuple[str, ...] = ()


def format_for(path: str | Path, given: str | None = None) -> str:
    """``given`` if any, else from the suffix (``.params`` → qgc), else ``parm``."""
    if given is not None:
        if given not in FORMATS:
            raise ExportError(f"format {given!r}: use {' or '.join(FORMATS)}")
        return given
    return SUFFIX_FORMATS.get(Path(path).suffix.lower(), "parm")


def stored_kind(design: GainDesign) -> ScheduleKind | None:
    """The kind a stored design was made with (``behaviors.schedules.kind_of``: the rules it carries);
    None for a design stored before designs carried their rules, which is then exported per identified
    speed only (its stored gains), never recomputed."""
    return kind_of(design)


def gain_sets(store: Store, campaign_id: int, speed: float | None = None) -> tuple[dict, Any, list[GainSet]]:
    """(campaign, profile, gain sets) of a completed campaign (module docstring); ExportError otherwise."""
    try:
        campaign = store.campaign(campaign_id)
    except KeyError as exc:
        raise ExportError(exc.args[0]) from None
    if campaign["status"] != "completed":
        reason = f" ({campaign['reason']})" if campaign.get("reason") else ""
        raise ExportError(f"campaign {campaign_id} is {campaign['status']}{reason}: only a completed campaign's "
                          "gains are exported")
    designs = store.designs(campaign_id)
    if not designs:
        raise ExportError(f"campaign {campaign_id} ({campaign['kind']}) designed no gains")
    profile = get_profile(campaign.get("profile") or "sim")
    if speed is not None:
        if not (math.isfinite(speed) and speed > 0):
            raise ExportError(f"--speed {speed!r}: give a speed in m/s > 0")
        neutral: dict[str, float] = {}
        notes = []
        for design in designs:
            kind = stored_kind(design)
            if kind is None:
                raise ExportError(f"the {design.kind} design of campaign {campaign_id} was stored without its design "
                                  "rules (an older store): export per identified speed instead (leave out --speed)")
            neutral.update(kind.gains(design.schedule, speed))
            low, high = design.schedule.speed_range
            if not low <= speed <= high:
                notes.append(f"{speed:g} m/s is outside the identified speeds of the {design.kind} schedule "
                             f"({low:.2f}-{high:.2f} m/s): its laws are extrapolated (clamped) as the companion "
                             "itself would")
        return campaign, profile, [_gain_set(profile, speed, None, neutral, notes)]
    lead = next((d for d in designs if schedule_kind(d.kind).axis == "yaw"), designs[0])
    sets = []
    for point in lead.points:
        neutral, notes = dict(point.scheduled), []
        for other in designs:
            if other is lead:
                continue
            kind = stored_kind(other)
            low, high = other.schedule.speed_range
            if kind is None or not low <= point.speed <= high:
                notes.append(f"the {other.kind} gains are left out: {point.speed:.2f} m/s is not within their "
                             "identified speeds" if kind is not None else
                             f"the {other.kind} gains are left out: their design was stored without its rules")
                continue
            neutral.update(kind.gains(other.schedule, point.speed))
        sets.append(_gain_set(profile, point.speed, point.thrust, neutral, notes))
    return campaign, profile, sets


def _gain_set(profile, speed: float, thrust: float | None, neutral: dict[str, float], notes: list[str]) -> GainSet:
    native: dict[str, float] = {}
    for name, value in neutral.items():
        if name not in profile.params:
            notes.append(f"{name} is left out: the {profile.name} profile has no parameter for it")
            continue
        native[profile.native_param(name)] = profile.to_native_value(name, value)
    if not native:
        raise ExportError(f"none of the designed gains ({', '.join(neutral)}) is a parameter of the "
                          f"{profile.name} autopilot")
    return GainSet(speed=speed, thrust=thrust, neutral=neutral, native=native, notes=tuple(notes))


def _comments(store: Store, campaign: dict, profile, gains: GainSet, designs: list[GainDesign],
              generator: str) -> tuple[str, ...]:
    if campaign["kind"] == "log":
        verified = "designed from a recorded log, never flown: check them with heading steps before relying on them"
    elif store.behavior_results(campaign["id"], "heading_steps"):
        verified = f"the campaign flew heading steps with them (companion results --campaign {campaign['id']})"
    else:
        verified = "not checked with heading steps on the vehicle"
    at = (f"identified at thrust {gains.thrust:.2f}: the schedule's gains at that speed" if gains.thrust is not None
          else "the schedule's gains at this chosen speed")
    lines = [f"{generator}: gains designed by campaign {campaign['id']} ({campaign['kind']}, {campaign['status']}, "
             f"started {campaign['started_utc']}) for {campaign['vehicle']} ({profile.name})",
             f"speed {gains.speed:.3f} m/s, {at}",
             *[f"{d.kind} schedule: {d.schedule.describe()}" for d in designs],
             f"verification: {verified}",
             *gains.notes,
             f"written {datetime.now(timezone.utc).strftime('%Y-%m-%dT%H:%M:%SZ')}"]
    return tuple(ascii_text(line) for line in lines)


#: the symbols of the schedules' descriptions, spelled for tools that read files as ASCII
_ASCII = {"·": "*", "−": "-", "–": "-", "⁻¹": "^-1", "⁻²": "^-2", "²": "^2", "⁻": "^-", "δ": "delta", "ζ": "zeta", "ω": "omega", "°": " deg",
          "\n": " "}


def ascii_text(text: str) -> str:
    for symbol, spelled in _ASCII.items():
        text = text.replace(symbol, spelled)
    return text.encode("ascii", "replace").decode("ascii")


def per_speed_path(path: Path, speed: float) -> Path:
    return path.with_name(f"{path.stem}-{speed:.2f}ms{path.suffix}")


def export_gains(store: Store, campaign_id: int, path: str | Path, *, speed: float | None = None,
                 fmt: str | None = None, generator: str = "marine-companion", system_id: int | None = None) -> list[Path]:
    """Write the file(s) (module docstring); returns their paths."""
    path = Path(path)
    kind = format_for(path, fmt)
    campaign, profile, sets = gain_sets(store, campaign_id, speed)
    designs = store.designs(campaign_id)
    types = dict(getattr(profile, "param_types", {}) or {})
    sysid = system_id if system_id is not None else _system_id(campaign.get("vehicle", ""))
    written = []
    for gains in sets:
        target = path if speed is not None else per_speed_path(path, gains.speed)
        text = write(ParamFile(values=gains.native, comments=_comments(store, campaign, profile, gains, designs, generator),
                               types=types, system_id=sysid, component_id=1), kind)
        target.parent.mkdir(parents=True, exist_ok=True)
        target.write_text(text, encoding="utf-8")
        written.append(target)
    return written


def _system_id(vehicle_name: str) -> int:
    """The system id in a vehicle record's name (``sysid-3``), else 1 (QGroundControl's default)."""
    if vehicle_name.startswith("sysid-") and vehicle_name[6:].isdigit() and 1 <= int(vehicle_name[6:]) <= 255:
        return int(vehicle_name[6:])
    return 1
