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
from companion.procedures.app import (
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
from companion.procedures.behaviour_procedures import MinSpeedProcedureConfig, RollProcedureConfig, run_named_behavior
from companion.procedures.campaign import CampaignConfig, gains_to_params
from companion.numerics.gains import GainBounds
from companion.numerics.identification import YawModel
from companion.numerics.schedule import YawSchedule, fit_yaw_schedule
from companion.procedures.runner import RestorePoint
from companion.records.store import Store

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
        self.unscheduled: RestorePoint | None = None
        self.history: list[dict] = []
        link.on_user_command(self._on_user_command)

    # ------------------------------------------------------------------ ground station
    def _on_user_command(self, command: int, params: tuple[float, ...]) -> None:
        if command == MAV_CMD_USER_4:
            if self.procedure_abort is not None:
                self.procedure_abort.request("ground station abort (MAV_CMD_USER_4)")
                self.link.send_command_ack(command, MAV_RESULT_ACCEPTED)
            elif self.pending:  # a start that has not begun yet is cancelled
                cancelled, _ = self.pending.pop(0)
                self.link.send_command_ack(cancelled, MAV_RESULT_FAILED)
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

        def gains_at(speed: float) -> dict[str, float]:  # Kp and Ki only (see behaviors.gain_scheduling)
            gains = gains_to_params(schedule.gains_at(speed, bounds))
            return {"heading_p": gains["heading_p"], "heading_i": gains["heading_i"]}

        # the gains in place before scheduling starts are what stopping the loop gives back
        self.unscheduled = RestorePoint.capture(self.link)
        self.scheduler = GainScheduler(gains_at, self.config.scheduling)
        log.info("gain scheduling on: a22 %.3f, b2 = %.3f u^2 + %.3f", schedule.a22, schedule.b2_slope, schedule.b2_intercept)

    def run(self) -> list[dict]:
        """Serve until stopped; then the gains in place before scheduling started are written back."""
        self._rebuild_scheduler()
        self.link.status_text("companion ready: USER_1 identify, USER_2 roll, USER_3 min-speed, USER_4 abort")
        start = math.nan
        try:
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
                    self._schedule(telemetry)
        finally:
            if self.scheduler is not None and self.scheduler.writes and self.unscheduled is not None:
                self.unscheduled.restore(self.link, mode=False)
        return self.history

    def _schedule(self, telemetry) -> None:
        """One scheduler step; a refused or lost write leaves the last good gains (rolled back if
        the failure came half-way through a set), and the loop goes on."""
        commands = self.scheduler.step(telemetry)
        if not commands:
            return
        try:
            self.link.execute(commands)
            self.scheduler.confirm()
        except Exception as exc:  # noqa: BLE001 - the resident loop must outlive a refused write
            log.warning("scheduled gain write failed: %s", exc)
            self.scheduler.reject()
            good = self.scheduler.written or self.unscheduled.parameters
            try:
                self.link.set_params({k: v for k, v in good.items() if k in ("heading_p", "heading_i")})
            except Exception as rollback_exc:  # noqa: BLE001
                log.error("could not roll the heading gains back: %s", rollback_exc)
            self.link.status_text(f"gain scheduling: write failed ({exc})"[:50], 4)

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
