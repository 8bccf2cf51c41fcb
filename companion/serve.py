"""Running beside a vehicle: the companion's resident loop (SPEC C1, C5; ``companion run``).

Between procedures it keeps the heading gains matched to speed with the schedule fitted from the
store's latest accepted yaw models (rate-limited, with hysteresis). A ground station starts and
stops procedures with COMMAND_LONG aimed at component 191:

| command | procedure |
|---|---|
| MAV_CMD_USER_1 | identification campaign (then the schedule is refitted from its models) |
| MAV_CMD_USER_2 | roll stabilisation (param1: closed-loop seconds, 0 = default) |
| MAV_CMD_USER_3 | minimum-speed seeking (param1: seconds, 0 = default) |
| MAV_CMD_USER_4 | abort the running procedure (the autopilot is restored) |

A start is answered COMMAND_ACK IN_PROGRESS (with progress for the campaign) and finally ACCEPTED or
FAILED; a retransmitted start of the procedure already running is answered IN_PROGRESS again; a
start while another procedure runs, a start on a disarmed vehicle, or an abort with nothing running
is answered TEMPORARILY_REJECTED. Everything runs on vehicle time; SIGINT/SIGTERM abort what runs and end.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace
from typing import Callable

from behaviors.gain_scheduling import GainScheduler, SchedulingConfig
from companion.app import (
    MAV_CMD_USER_1,
    MAV_CMD_USER_2,
    MAV_CMD_USER_3,
    MAV_CMD_USER_4,
    MAV_RESULT_ACCEPTED,
    MAV_RESULT_FAILED,
    MAV_RESULT_IN_PROGRESS,
    AbortFlag,
    GcsProgress,
    run_campaign,
)
from companion.behavior_runs import MinSpeedProcedureConfig, RollProcedureConfig, run_named_behavior
from companion.campaign import CampaignConfig, gains_to_params
from companion.numerics.gains import GainBounds
from companion.numerics.identification import YawModel
from companion.numerics.schedule import YawSchedule, fit_yaw_schedule
from companion.store import Store

log = logging.getLogger(__name__)

MAV_RESULT_TEMPORARILY_REJECTED = 1


def schedule_from_store(store: Store) -> YawSchedule | None:
    """The schedule of the latest identification campaign with ≥ 2 accepted yaw models."""
    for campaign in reversed(store.campaigns()):
        if campaign["kind"] != "identification":
            continue
        models = [m for m in store.models(campaign["id"], axis="yaw") if m.speed is not None]
        if len(models) < 2:
            continue
        try:
            return fit_yaw_schedule([m.speed for m in models],
                                    [YawModel(m.params["a22"], m.params["b2"], m.params["delta0"]) for m in models])
        except ValueError as exc:
            log.warning("campaign %d: no schedule (%s)", campaign["id"], exc)
    return None


@dataclass
class ServeConfig:
    campaign: CampaignConfig = CampaignConfig()
    roll: RollProcedureConfig = RollProcedureConfig()
    min_speed: MinSpeedProcedureConfig = MinSpeedProcedureConfig()
    scheduling: SchedulingConfig = SchedulingConfig()
    bounds: GainBounds = GainBounds()
    schedule_gains: bool = True
    preset: str | None = None  # simulator preset (analytic minimum speed, simulator hooks)
    max_vehicle_s: float | None = None  # stop after this much vehicle time (tests); None: until signalled


class Companion:
    """The resident loop; ``run()`` returns when signalled (or after ``max_vehicle_s``)."""

    def __init__(self, link, store: Store, vehicle_id: int, config: ServeConfig, stop: AbortFlag) -> None:
        self.link, self.store, self.vehicle_id, self.config, self.stop = link, store, vehicle_id, config, stop
        self.pending: list[tuple[int, tuple[float, ...]]] = []
        self.procedure_abort: AbortFlag | None = None
        self.running: int | None = None
        self.scheduler: GainScheduler | None = None
        self.history: list[dict] = []
        link.on_user_command(self._on_user_command)

    # ------------------------------------------------------------------ ground station
    def _on_user_command(self, command: int, params: tuple[float, ...]) -> None:
        if command == MAV_CMD_USER_4:
            if self.procedure_abort is not None:
                self.procedure_abort.request("ground station abort (MAV_CMD_USER_4)")
                self.link.send_command_ack(command, MAV_RESULT_ACCEPTED)
            else:
                self.link.send_command_ack(command, MAV_RESULT_TEMPORARILY_REJECTED)
            return
        if command not in (MAV_CMD_USER_1, MAV_CMD_USER_2, MAV_CMD_USER_3):
            self.link.send_command_ack(command, MAV_RESULT_FAILED)
            return
        if command in (self.running, *(c for c, _ in self.pending)):
            # a retransmission (the GCS did not see our first ACK): the same answer again
            self.link.send_command_ack(command, MAV_RESULT_IN_PROGRESS, 0)
            return
        if self.procedure_abort is not None or self.pending:
            self.link.send_command_ack(command, MAV_RESULT_TEMPORARILY_REJECTED)
            return
        if not getattr(self.link, "armed", True):
            self.link.status_text("procedure refused: the vehicle is not armed", 4)
            self.link.send_command_ack(command, MAV_RESULT_TEMPORARILY_REJECTED)
            return
        self.pending.append((command, params))
        self.link.send_command_ack(command, MAV_RESULT_IN_PROGRESS, 0)

    def _abort_requested(self) -> Callable[[], str | None]:
        return lambda: self.stop() or (self.procedure_abort() if self.procedure_abort else None)

    # ------------------------------------------------------------------ loop
    def _rebuild_scheduler(self) -> None:
        if not self.config.schedule_gains:
            return
        schedule = schedule_from_store(self.store)
        if schedule is None:
            self.scheduler = None
            return
        bounds = self.config.bounds
        self.scheduler = GainScheduler(lambda u: gains_to_params(schedule.gains_at(u, bounds)), self.config.scheduling)
        log.info("gain scheduling on: a22 %.3f, b2 = %.3f u^2 + %.3f", schedule.a22, schedule.b2_slope, schedule.b2_intercept)

    def run(self) -> list[dict]:
        self._rebuild_scheduler()
        self.link.status_text("companion ready: USER_1 identify, USER_2 roll, USER_3 min-speed, USER_4 abort")
        start = math.nan
        while not self.stop():
            telemetry = self.link.next_telemetry()
            if math.isnan(start):
                start = telemetry.time_s
            if self.config.max_vehicle_s is not None and telemetry.time_s - start >= self.config.max_vehicle_s:
                break
            if self.pending:
                self._run_procedure(*self.pending.pop(0))
                continue
            if self.scheduler is not None:
                self.link.execute(self.scheduler.step(telemetry))
        return self.history

    def _run_procedure(self, command: int, params: tuple[float, ...]) -> None:
        self.procedure_abort = AbortFlag()
        self.running = command
        gcs = GcsProgress(self.link, command)
        abort = self._abort_requested()
        try:
            if command == MAV_CMD_USER_1:
                campaign, outcome, campaign_id = run_campaign(self.link, self.store, self.config.campaign,
                                                              vehicle_id=self.vehicle_id, abort=abort, gcs=gcs)
                entry = {"procedure": "identification", "status": outcome.status, "reason": outcome.reason,
                         "campaign_id": campaign_id}
                self._rebuild_scheduler()
            else:
                name = "roll" if command == MAV_CMD_USER_2 else "min_speed"
                seconds = params[0] if params and math.isfinite(params[0]) and params[0] > 0 else None
                roll = replace(self.config.roll, closed_s=seconds) if seconds and name == "roll" else self.config.roll
                seek = (replace(self.config.min_speed, duration_s=seconds) if seconds and name == "min_speed"
                        else self.config.min_speed)
                outcome = run_named_behavior(name, self.link, self.store, vehicle_id=self.vehicle_id, campaign_id=None,
                                             abort=abort, preset=self.config.preset, simulator=False,
                                             roll_config=roll, min_speed_config=seek)
                status = outcome["summary"]["status"]
                self.link.send_command_ack(command, MAV_RESULT_ACCEPTED if status == "completed" else MAV_RESULT_FAILED,
                                           100 if status == "completed" else 0)
                entry = {"procedure": name, "status": status, "summary": outcome["summary"]}
        except Exception as exc:  # noqa: BLE001 - the resident loop must survive a failed procedure
            log.exception("procedure %d failed", command)
            self.link.send_command_ack(command, MAV_RESULT_FAILED)
            entry = {"procedure": command, "status": "failed", "reason": str(exc)}
        finally:
            self.procedure_abort = None
            self.running = None
        self.history.append(entry)
        log.info("procedure finished: %s", entry)
