"""Health monitoring inside ``companion run``: the application side of
:class:`behaviors.health_monitor.HealthMonitor` — its reference from the store, its commands to
the link, its records in the store.

* **Reference**: the yaw models of the latest completed campaign that has accepted yaw models (a
  live ``identification`` campaign or an offline ``log`` one), as the speed laws
  :func:`companion.numerics.schedule.schedule_from_models` fits to them (a22(u), b2(u)); without
  one there is nothing to compare with and no monitor runs. A campaign stored before models
  validated whose accepted estimate is no model (a22 ≥ 0 or b2 ≤ 0, eq. 3.5–3.9) is no reference.
* **Records**: one campaign of kind ``health`` per session of ``companion run``; each alarm is a
  ``health_alarm`` result holding its evidence (the windows that led to it) the moment it is
  raised, and at the end of the session a ``health`` result holds every window (the drift plot of
  the report: ``companion results --campaign N --report DIR``).
"""
from __future__ import annotations

import logging
import math
from dataclasses import asdict

from behaviors.health_monitor import HealthMonitor
from companion.numerics.drift import DriftConfig
from companion.numerics.identification import YawEstimate
from companion.numerics.schedule import YawSchedule, schedule_from_models
from companion.records.store import Store

log = logging.getLogger(__name__)

#: campaign kinds whose accepted yaw models can serve as the healthy reference
REFERENCE_KINDS = ("identification", "log")


def reference_from_store(store: Store) -> tuple[int, YawSchedule] | None:
    """(campaign id, speed laws) of the latest completed campaign with accepted yaw models, or None."""
    for campaign in reversed(store.campaigns()):
        if campaign["kind"] not in REFERENCE_KINDS or campaign["status"] != "completed":
            continue
        stored = [m for m in store.models(campaign["id"], "yaw") if m.speed is not None]
        if not stored:
            continue
        try:
            models = [_estimate(m.params).model() for m in stored]
            return campaign["id"], schedule_from_models([m.speed for m in stored if m.speed is not None], models)
        except ValueError as exc:
            log.info("campaign %d cannot serve as the health reference: %s", campaign["id"], exc)
    return None


def _estimate(params: dict) -> YawEstimate:
    """A stored model's numbers (null: NaN) as an estimate."""
    a22, b2, delta0 = (math.nan if value is None else float(value)
                       for value in (params.get("a22"), params.get("b2"), params.get("delta0", 0.0)))
    return YawEstimate(a22, b2, delta0)


class HealthSession:
    """The monitor of one ``companion run`` session and its records (module docstring)."""

    def __init__(self, link, store: Store, vehicle_id: int, config: DriftConfig = DriftConfig()) -> None:
        self.link, self.store, self.vehicle_id, self.config = link, store, vehicle_id, config
        self.monitor: HealthMonitor | None = None
        self.campaign_id: int | None = None
        self.reference_id: int | None = None

    def start(self) -> bool:
        """(Re)build the monitor from the store's latest reference; False when there is none."""
        found = reference_from_store(self.store)
        if found is None:
            log.info("health monitoring off: no completed campaign with accepted yaw models in the store")
            return False
        reference_id, schedule = found
        if self.monitor is not None and reference_id == self.reference_id:
            return True
        self.finish()
        self.reference_id = reference_id
        self.monitor = HealthMonitor.from_schedule(schedule, self.config, label=f"campaign {reference_id}")
        self.campaign_id = self.store.start_campaign(self.vehicle_id, "health", {
            "reference_campaign": reference_id, "reference": schedule.describe(), "drift": asdict(self.config)})
        self.link.status_text(f"health monitor on (reference: campaign {reference_id})"[:50])
        log.info("health monitoring against campaign %d: %s", reference_id, schedule.describe())
        return True

    def step(self, telemetry) -> None:
        """One snapshot: the monitor's reports go to the link, its alarms to the store at once."""
        if self.monitor is None:
            return
        commands = self.monitor.step(telemetry)
        if commands:
            self.link.execute(commands)
        while self.monitor.events:
            event = self.monitor.events[0]
            self.store.add_behavior_result(self.campaign_id, "health_alarm", "alarm", event["evidence"])
            self.monitor.events.pop(0)

    def finish(self) -> None:
        """Store every window and close the session's campaign (idempotent)."""
        if self.monitor is None or self.campaign_id is None:
            return
        result = self.monitor.result()
        alarm = result.alarm
        self.store.add_behavior_result(self.campaign_id, "health", "alarm" if alarm else "completed", result.to_dict())
        reason = (f"{alarm.parameter} {alarm.change_pct:+.0f}% at t = {alarm.time_s:.0f} s"
                  if alarm else None)
        self.store.finish_campaign(self.campaign_id, "completed", reason)
        self.monitor, self.campaign_id = None, None
