"""What fills the status board from ``companion run``, in the resident loop's own thread.

:class:`StatusFeed` watches without commanding anything and without MAVLink traffic of its own
(one read of the heading gains at start excepted):

* every telemetry snapshot (the link's ``telemetry.after_snapshot``, so also while a procedure
  runs): vehicle time, mode, armed, speed, heading, depth, actuators; every ``refresh_s`` of
  vehicle time, and at once after an event, what comes from the store and the loop: the runs and
  accepted models of the latest identification campaign, the designed schedules, the scheduler's
  last write, the gains on the vehicle (the last PARAM_VALUE the vehicle sent for each, from the
  link's parameter cache), the health monitor's windows and alarm;
* every report the companion sends the ground station (``ground.on_report``): NAMED_VALUE_FLOATs
  become the live estimates (a22, b2, ...), STATUSTEXTs the messages (warnings also the alarms),
  COMMAND_ACK progress the running procedure's progress;
* the resident loop's observer calls (``procedure_started`` / ``procedure_finished``); after an
  identification campaign it writes the campaign's HTML report into ``report_dir`` (unless the
  companion is stopping: a stop must not wait for plots).
"""
from __future__ import annotations

import logging
import math
from pathlib import Path
from typing import Any

from behaviors.schedules import schedule_kind
from companion.link.port import VehiclePort
from companion.service.status import StatusBoard

log = logging.getLogger(__name__)

#: design kinds the page shows (the heading PI, ArduPilot's native cascade, the pitch PI)
DESIGN_KINDS = ("heading", "cascade", "pitch")
MAV_RESULT_IN_PROGRESS = 5
MAV_SEVERITY_WARNING = 4


class StatusFeed:
    """The resident loop's observer and the link's watcher (module docstring)."""

    def __init__(self, board: StatusBoard, link: VehiclePort, store, *, endpoint: str, report_dir: str | Path | None = None,
                 refresh_s: float = 2.0, vehicle_period_s: float = 0.1, max_messages: int = 20,
                 health_windows: int = 10) -> None:
        self.board, self.link, self.store, self.endpoint = board, link, store, endpoint
        self.report_dir = Path(report_dir) if report_dir else None
        self.refresh_s, self.vehicle_period_s = refresh_s, vehicle_period_s
        self.max_messages, self.health_windows = max_messages, health_windows
        self.companion = None
        self.messages: list[dict] = []
        self.estimates: dict[str, dict] = {}
        self.procedure: dict[str, Any] = {"state": "idle", "name": None}
        self.history: list[dict] = []
        self._last_vehicle_s = -math.inf
        self._last_refresh_s = -math.inf
        self._dirty = True

    # ------------------------------------------------------------------ wiring
    def watch(self, companion, version: str = "") -> None:
        """Start watching ``companion`` (a :class:`companion.procedures.resident.Companion` built
        with this feed as its observer) and its link."""
        self.companion = companion
        link = self.link
        profile, transport = link.profile, link.transport
        self.board.set("companion", {"version": version, "component": transport.component,
                                     "procedures_allowed": list(companion.config.procedures),
                                     "scheduling": companion.config.schedule_gains,
                                     "health": companion.config.health})
        self.board.set("connection", {"endpoint": self.endpoint,
                                      "system_id": transport.system_id,
                                      "autopilot_component": transport.autopilot_component,
                                      "profile": profile.name})
        self.board.set("procedure", self.procedure)
        self.board.set("report", self._latest_report())
        link.telemetry.after_snapshot(self._on_snapshot)
        link.ground.on_report(self.on_report)
        self._read_gains_once()

    def _read_gains_once(self) -> None:
        """The heading (and pitch) gains as found, so the page shows them before any write."""
        natives = self._gain_natives()
        cache = self._cache()
        for native in natives:
            if native in cache:
                continue
            try:
                self.link.get_param(native)
            except Exception as exc:  # noqa: BLE001 - a gain not read is shown as unknown
                log.debug("status page: %s not read: %s", native, exc)

    # ------------------------------------------------------------------ the resident loop's observer
    def procedure_started(self, name: str, command: int) -> None:
        self.procedure = {"state": "running", "name": name, "command": command, "progress_pct": None,
                          "started_s": _finite(self.link.vehicle_time_s),
                          "last": self.procedure.get("last")}
        self.board.set("procedure", self.procedure)
        self._dirty = True

    def procedure_finished(self, entry: dict) -> None:
        last = {**entry, "finished_s": _finite(self.link.vehicle_time_s)}
        self.procedure = {"state": "idle", "name": None, "last": last}
        self.history = (self.history + [last])[-10:]
        self.board.set("procedure", self.procedure)
        self.board.set("history", self.history)
        campaign_id = entry.get("campaign_id")
        if campaign_id is not None and self.report_dir is not None:
            self._write_report(int(campaign_id))
        self.refresh()

    def _write_report(self, campaign_id: int) -> None:
        if self.companion is not None and self.companion.stop():
            log.info("no report for campaign %d: the companion is stopping", campaign_id)
            return
        from companion.procedures.registry import report_sections
        from companion.records.report import write_report  # matplotlib: only when a report is due

        if self.report_dir is None:
            return

        try:
            path = write_report(self.store, campaign_id, self.report_dir / f"campaign-{campaign_id}",
                                sections=report_sections())
        except Exception as exc:  # noqa: BLE001 - a report that fails must not stop the companion
            log.warning("report of campaign %d not written: %s", campaign_id, exc)
            return
        log.info("report of campaign %d: %s", campaign_id, path)
        self.board.set("report", {"campaign_id": campaign_id, "path": str(path), "url": "/report/"})

    def _latest_report(self) -> dict | None:
        """The newest report already in ``report_dir`` (from an earlier session), if any."""
        found = latest_report(self.report_dir)
        if found is None:
            return None
        return {"campaign_id": int(found.parent.name.split("-")[1]), "path": str(found), "url": "/report/"}

    # ------------------------------------------------------------------ the link's events
    def on_report(self, report) -> None:
        """A report sent to the ground station (``companion.link.ground_station.Report``)."""
        if report.kind == "value":
            self.estimates = {**self.estimates, report.name: {"value": report.value, "time_s": _finite(report.time_s)}}
            self.board.set("estimates", self.estimates)
        elif report.kind == "text":
            self._message(report.time_s, report.severity, report.text, "companion")
        elif report.kind == "ack" and report.command == self.procedure.get("command") \
                and report.result == MAV_RESULT_IN_PROGRESS and self.procedure.get("state") == "running":
            self.procedure = {**self.procedure, "progress_pct": report.progress}
            self.board.set("procedure", self.procedure)
            self._dirty = True

    def _message(self, time_s: float, severity: int, text: str, source: str) -> None:
        self.messages = (self.messages + [{"time_s": _finite(time_s), "severity": severity, "text": text,
                                           "source": source}])[-self.max_messages:]
        self.board.set("messages", self.messages)
        if severity <= MAV_SEVERITY_WARNING:
            self._dirty = True

    def _on_snapshot(self) -> None:
        telemetry = self.link.latest_telemetry
        if telemetry is not None:
            self.on_telemetry(telemetry)

    def on_telemetry(self, telemetry) -> None:
        """One snapshot: the vehicle section (at most every ``vehicle_period_s`` of vehicle time)
        and, when due, the sections read from the store and the loop. Never raises."""
        try:
            now = telemetry.time_s
            if not (now - self._last_vehicle_s < self.vehicle_period_s):
                self._last_vehicle_s = now
                self.board.set("vehicle", vehicle_section(telemetry))
            if self._dirty or not (now - self._last_refresh_s < self.refresh_s):
                self._last_refresh_s = now
                self.refresh()
        except Exception as exc:  # noqa: BLE001 - the page only watches: it must never stop the loop
            log.debug("status feed failed: %s", exc, exc_info=True)

    # ------------------------------------------------------------------ from the store and the loop
    def refresh(self) -> None:
        self._dirty = False
        designs = self._designs()
        self.board.set("models", self._models())
        self.board.set("schedule", self._schedule(designs))
        self.board.set("gains", self._gains(designs))
        self.board.set("health", self._health())
        self.board.set("learning", self._learning())
        self.board.set("alarms", self._alarms())

    def _models(self) -> dict | None:
        campaign_id = self.store.latest_campaign_id("identification")
        if campaign_id is None:
            return None
        campaign = self.store.campaign(campaign_id)
        runs = [{"axis": r["axis"], "thrust": r["thrust"], "attempt": r["attempt"], "speed": r["speed"],
                 "r2": r["r2"], "accepted": bool(r["accepted"]),
                 "model": {k: v for k, v in r["model"].items() if isinstance(v, (int, float))}}
                for r in self.store.runs(campaign_id)]
        return {"campaign_id": campaign_id, "status": campaign["status"], "reason": campaign.get("reason"),
                "runs": runs, "accepted": sum(1 for r in runs if r["accepted"])}

    def _designs(self) -> list[tuple[int, Any]]:
        found = []
        for kind in DESIGN_KINDS:
            design = self.store.latest_design(kind)
            if design is not None:
                found.append(design)
        return found

    def _schedule(self, found: list[tuple[int, Any]]) -> dict:
        designs = [{"kind": design.kind, "campaign_id": campaign_id, "law": design.schedule.describe(),
                    "points": [{"speed": p.speed, "thrust": p.thrust, "gains": p.scheduled} for p in design.points]}
                   for campaign_id, design in found]
        scheduler = getattr(self.companion, "scheduler", None)
        writes = list(getattr(scheduler, "writes", []) or [])
        return {"active": scheduler is not None, "designs": designs, "last_write": writes[-1] if writes else None,
                "writes": len(writes)}

    def _gain_natives(self, designs: list[tuple[int, Any]] | None = None) -> dict[str, str]:
        """native name → neutral name of the gains the page shows: every designed kind's, else the
        profile's heading schedule's."""
        profile = self.link.profile
        designs = self._designs() if designs is None else designs
        kinds = [design.kind for _, design in designs] or [profile.heading_schedule]
        out: dict[str, str] = {}
        for name in kinds:
            try:
                parameters = schedule_kind(name).parameters
            except ValueError:
                continue
            for neutral in parameters:
                if neutral in profile.params:
                    out[profile.params[neutral]] = neutral
        return out

    def _cache(self) -> dict:
        return dict(self.link.parameters.cache)

    def _gains(self, designs: list[tuple[int, Any]]) -> dict:
        cache = self._cache()
        return {"on_vehicle": [{"name": native, "neutral": neutral, "value": cache.get(native)}
                               for native, neutral in self._gain_natives(designs).items()],
                "source": "the last PARAM_VALUE the vehicle sent for each"}

    def _health(self) -> dict | None:
        session = getattr(self.companion, "health", None)
        if session is None:
            return {"on": False, "reason": "health monitoring is off"}
        monitor = session.monitor
        if monitor is None:
            return {"on": False, "reason": "no completed campaign with accepted yaw models to compare with"}
        from behaviors.health_monitor import verdict_row

        rows = [verdict_row(v) for v in monitor.verdicts[-self.health_windows:]]
        windows = [{k: row[k] for k in ("t_start", "t_end", "speed", "used", "reason", "ratio", "cusum", "alarm")}
                   for row in rows]
        alarm = monitor.alarm
        return {"on": True, "reference_campaign": session.reference_id, "windows_seen": len(monitor.verdicts),
                "windows": windows,
                "alarm": None if alarm is None else {"parameter": alarm.alarm, "time_s": alarm.window.t_end,
                                                     "change_pct": 100.0 * (alarm.ratio[alarm.alarm] - 1.0)}}

    def _learning(self) -> dict:
        session = getattr(self.companion, "learning", None)
        if session is None:
            return {"on": False, "reason": "learning is off (companion run --learn)"}
        return session.status()

    def _alarms(self) -> list[dict]:
        alarms = [m for m in self.messages if m["severity"] <= MAV_SEVERITY_WARNING]
        for time_s, severity, text in list(self.link.statustexts)[-20:]:
            if severity <= MAV_SEVERITY_WARNING:
                alarms.append({"time_s": _finite(time_s), "severity": severity, "text": text, "source": "vehicle"})
        alarms.sort(key=lambda a: -math.inf if a["time_s"] is None else a["time_s"])
        return alarms[-10:]


def vehicle_section(telemetry) -> dict:
    """The vehicle's state in one snapshot (angles in degrees for the reader)."""
    return {"time_s": telemetry.time_s, "mode": telemetry.mode, "armed": bool(telemetry.armed),
            "speed_water": telemetry.speed_water, "speed_ground": telemetry.speed_ground,
            "heading_deg": math.degrees(telemetry.yaw) % 360.0 if math.isfinite(telemetry.yaw) else None,
            "depth": telemetry.depth, "rudder_deg": math.degrees(telemetry.rudder) if math.isfinite(telemetry.rudder) else None,
            "thrust": telemetry.thrust_ratio}


def latest_report(report_dir: Path | None) -> Path | None:
    """``report_dir/campaign-N/report.html`` of the highest N, None when there is none."""
    if report_dir is None or not report_dir.is_dir():
        return None
    found = []
    for child in report_dir.glob("campaign-*/report.html"):
        suffix = child.parent.name.split("-", 1)[1]
        if suffix.isdigit():
            found.append((int(suffix), child))
    return max(found)[1] if found else None


def _finite(value: float) -> float | None:
    return value if isinstance(value, (int, float)) and math.isfinite(value) else None
