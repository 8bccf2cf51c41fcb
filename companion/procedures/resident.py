"""Running beside a vehicle: the companion's resident loop (SPEC C1, C5; ``companion run``).

Between procedures it keeps the heading gains matched to speed with the schedule fitted from the
store's latest accepted yaw models (rate-limited, with hysteresis), and watches the vehicle's health:
passive identification from its ordinary manoeuvres against the stored models at the same speed,
with a STATUSTEXT warning, NAMED_VALUE_FLOATs and a store event when a parameter drifts
(``companion.procedures.health``). A ground station starts and
stops procedures with COMMAND_LONG aimed at component 191:

| command | procedure |
|---|---|
| MAV_CMD_USER_1 | identification campaign (then scheduling follows the schedule it wrote) |
| MAV_CMD_USER_2 | roll stabilisation (param1: closed-loop seconds, 0 = default) |
| MAV_CMD_USER_3 | minimum-speed seeking (param1: seconds, 0 = default) |
| MAV_CMD_USER_4 | abort the running procedure (the autopilot is restored); with none running and learning on: param1 = 1 accepts the learned gains, 0 reverts them |
| MAV_CMD_USER_5 | steady-state squares and turns (SPEC C8) |

A start is answered COMMAND_ACK IN_PROGRESS (with progress for the campaign) and finally ACCEPTED or
FAILED; a retransmitted start of the procedure already running is answered IN_PROGRESS again; a
start while another procedure runs, a start on a disarmed vehicle, or an abort with nothing running
is answered TEMPORARILY_REJECTED; a start of a procedure the configuration does not allow
(``ServeConfig.procedures``) is answered DENIED. Everything runs on vehicle time; SIGINT/SIGTERM
abort what runs and end. With ``learn`` (``companion run --learn``) the heading gains are tuned from
the mission's own course changes (``companion.procedures.learning``); the stored designs are then not
scheduled (the learner owns the heading gains), and the learner pauses while a procedure runs. An
optional observer (``Companion(observer=...)``, e.g. the status page of
``companion.service``) is told when a procedure starts and ends; it only watches.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any, Callable, Protocol

from pymavlink.dialects.v20.common import MAV_RESULT_DENIED

from behaviors.gain_scheduling import GainDesign, GainScheduler, ScheduleKind, SchedulingConfig
from behaviors.mission_learning import LearningConfig
from behaviors.base import Footprint
from companion.errors import UserError
from companion.link.errors import LinkError
from companion.numerics.drift import DriftConfig
from companion.numerics.gains import GainBounds
from companion.numerics.schedule import YawSchedule
from companion.procedures.app import (
    MAV_RESULT_ACCEPTED,
    MAV_RESULT_FAILED,
    MAV_RESULT_IN_PROGRESS,
    MAV_RESULT_TEMPORARILY_REJECTED,
    AbortFlag,
    GcsProgress,
    run_campaign,
    run_named_procedure,
)
from companion.procedures.campaign import CampaignConfig
from companion.procedures.health import HealthSession
from companion.procedures.learning import LearningSession
from companion.procedures.min_speed import MinSpeedProcedureConfig
from behaviors.schedules import kind_of, schedule_kind
from companion.procedures.registry import ABORT_COMMAND, COMMANDS, IDENTIFICATION_COMMAND, ProcedureContext
from companion.procedures.roll import RollProcedureConfig
from companion.procedures.runner import RestorePoint
from companion.records.store import Store

log = logging.getLogger(__name__)

#: the longest run a ground station may ask for with param1 (seconds of vehicle time)
MAX_PROCEDURE_S = 3600.0


class CompanionObserver(Protocol):
    """What the resident loop tells a watcher (the status page); called in the loop's thread."""

    def procedure_started(self, name: str, command: int) -> None: ...

    def procedure_finished(self, entry: dict) -> None: ...


def schedule_from_store(store: Store) -> YawSchedule | None:
    """The heading schedule exactly as the latest completed campaign designed and wrote it (read
    back through the one serialiser, never re-fitted)."""
    found = store.latest_design("heading")
    return found[1].schedule if found is not None else None


def latest_designs(store: Store, names) -> list[tuple[int, GainDesign]]:
    """(campaign id, design): the latest stored design of each named schedule kind (those never
    designed are skipped)."""
    return [found for name in names if (found := store.latest_design(name)) is not None]


@dataclass
class ServeConfig:
    campaign: CampaignConfig = CampaignConfig()
    roll: RollProcedureConfig = RollProcedureConfig()
    min_speed: MinSpeedProcedureConfig = MinSpeedProcedureConfig()
    scheduling: SchedulingConfig = SchedulingConfig()
    bounds: GainBounds = GainBounds()
    schedule_gains: bool = True
    schedules: tuple[str, ...] = ("heading", "pitch")  # kinds kept matched to speed, when designed
    preset: str | None = None  # simulator preset (analytic minimum speed, simulator hooks)
    max_vehicle_s: float | None = None  # stop after this much vehicle time (tests); None: until signalled
    # health monitoring: passive identification against the stored models between procedures
    health: bool = True
    drift: DriftConfig = DriftConfig()
    # tuning during ordinary missions (the operator's opt-in, ``--learn``)
    learn: bool = False
    learning: LearningConfig = LearningConfig()
    # the procedures a ground station may start (names of registry.COMMANDS); an abort is always obeyed
    procedures: tuple[str, ...] = tuple(COMMANDS.values())

    def __post_init__(self) -> None:
        unknown = [name for name in self.procedures if name not in COMMANDS.values()]
        if unknown:
            raise ValueError(f"ServeConfig.procedures: unknown procedure(s) {', '.join(map(repr, unknown))} "
                             f"(known: {', '.join(COMMANDS.values())})")


class Companion:
    """The resident loop; ``run()`` returns when signalled (or after ``max_vehicle_s``)."""

    def __init__(self, link, store: Store, vehicle_id: int, config: ServeConfig, stop: AbortFlag,
                 observer: CompanionObserver | None = None) -> None:
        self.link, self.store, self.vehicle_id, self.config, self.stop = link, store, vehicle_id, config, stop
        self.observer = observer
        self.pending: list[tuple[int, tuple[float, ...]]] = []
        self.procedure_abort: AbortFlag | None = None
        self.running: int | None = None
        self.scheduler: GainScheduler | None = None
        self.unscheduled: RestorePoint | None = None
        self.history: list[dict] = []
        self.health = HealthSession(link, store, vehicle_id, config.drift) if config.health else None
        self.learning = LearningSession(link, store, vehicle_id, config.learning, config.campaign) if config.learn else None
        link.ground.on_user_command(self._on_user_command)

    # ------------------------------------------------------------------ ground station
    def _on_user_command(self, command: int, params: tuple[float, ...]) -> None:
        if command == ABORT_COMMAND:
            if self.procedure_abort is not None:
                self.procedure_abort.request("ground station abort (MAV_CMD_USER_4)")
                self.link.ground.send_command_ack(command, MAV_RESULT_ACCEPTED)
            elif self.pending:  # a start that has not begun yet is cancelled
                cancelled, _ = self.pending.pop(0)
                self.link.ground.send_command_ack(cancelled, MAV_RESULT_FAILED)
                self.link.ground.send_command_ack(command, MAV_RESULT_ACCEPTED)
            elif self.learning is not None and self._learning_decision(params):
                self.link.ground.send_command_ack(command, MAV_RESULT_ACCEPTED)
            else:
                self.link.ground.send_command_ack(command, MAV_RESULT_TEMPORARILY_REJECTED)
            return
        if command not in COMMANDS:
            self.link.ground.send_command_ack(command, MAV_RESULT_FAILED)
            return
        if COMMANDS[command] not in self.config.procedures:
            self.link.status_text(f"{COMMANDS[command]} is not allowed by the configuration"[:50], 4)
            self.link.ground.send_command_ack(command, MAV_RESULT_DENIED)
            return
        if command in (self.running, *(c for c, _ in self.pending)):
            # a retransmission (the GCS did not see our first ACK): the same answer again
            self.link.ground.send_command_ack(command, MAV_RESULT_IN_PROGRESS, 0)
            return
        if self.procedure_abort is not None or self.pending:
            self.link.ground.send_command_ack(command, MAV_RESULT_TEMPORARILY_REJECTED)
            return
        if not self.link.armed:
            self.link.status_text("procedure refused: the vehicle is not armed", 4)
            self.link.ground.send_command_ack(command, MAV_RESULT_TEMPORARILY_REJECTED)
            return
        self.pending.append((command, params))
        self.link.ground.send_command_ack(command, MAV_RESULT_IN_PROGRESS, 0)

    def _learning_decision(self, params: tuple[float, ...]) -> bool:
        """USER_4 with nothing running: param1 = 1 accepts the learned gains, else they are reverted;
        False when learning has nothing on the vehicle to decide on."""
        learning = self.learning
        if learning is None:
            return False
        if params and params[0] == 1:
            return learning.accept()
        return learning.revert()

    def _abort_requested(self) -> Callable[[], str | None]:
        return lambda: self.stop() or (self.procedure_abort() if self.procedure_abort else None)

    # ------------------------------------------------------------------ loop
    def _rebuild_scheduler(self) -> None:
        """One scheduler over every stored design of the configured kinds, reading the schedules
        exactly as written (``schedule_from_store``), writing their scheduled gains in one set."""
        if not self.config.schedule_gains:
            return
        profile = self.link.profile
        found = latest_designs(self.store, self.config.schedules)
        kinds = [self._kind_of(design, campaign_id) for campaign_id, design in found]
        designs = {design.kind: design for _, design in found}
        kinds = [k for k in kinds if all(name in profile.params for name in k.scheduled)]
        if not kinds:
            self.scheduler = None
            return

        def gains_at(speed: float) -> dict[str, float]:
            gains: dict[str, float] = {}
            for kind in kinds:
                gains.update(kind.scheduled_gains(designs[kind.name].schedule, speed))
            return gains

        parameters = tuple(name for kind in kinds for name in kind.scheduled)
        # the gains in place before scheduling starts are what stopping the loop gives back
        self.unscheduled = RestorePoint.capture(self.link, Footprint.of(parameters=parameters))
        self.scheduler = GainScheduler(gains_at, self.config.scheduling, parameters=parameters,
                                       live_value=kinds[0].live_value)
        log.info("gain scheduling on: %s", "; ".join(f"{k.name}: {designs[k.name].schedule.describe()}" for k in kinds))

    def _kind_of(self, design: GainDesign, campaign_id: int) -> ScheduleKind:
        """The kind the stored design was made with (the rules it carries: e.g. the cascade's full scale
        and output scaling on ArduRover), else — a design stored before designs carried their rules —
        this service's default, said."""
        kind = kind_of(design)
        if kind is not None:
            return kind
        log.warning("the %s schedule of campaign %d is scheduled with the default design rules (it was stored "
                    "without its own)", design.kind, campaign_id)
        return schedule_kind(design.kind, self.config.bounds if design.kind == "heading" else None)

    def run(self) -> list[dict]:
        """Serve until stopped; then the gains in place before scheduling started are written back
        (learned gains: kept if verified, else the original ones, ``LearningSession.finish``)."""
        if self.learning is not None:
            refused = self.learning.start()
            if refused is not None:
                log.warning("learning off: %s", refused)
                self.link.status_text(f"LEARN: off, {refused}"[:50], 4)
                self.learning = None
        if self.learning is None:
            self._rebuild_scheduler()
        if self.health is not None:
            self.health.start()
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
                if self.health is not None:
                    self.health.step(telemetry)
                if self.learning is not None:
                    self.learning.step(telemetry)
        finally:
            if self.learning is not None:
                self.learning.finish()
            if self.health is not None:
                self.health.finish()
            if self.scheduler is not None and self.scheduler.writes and self.unscheduled is not None:
                self.unscheduled.restore(self.link, mode=False)
        return self.history

    def _release_foreign(self, scheduler: GainScheduler, unscheduled: RestorePoint) -> None:
        """A scheduled gain someone else set (a ground station's PARAM_SET) is theirs: no longer
        scheduled, kept on exit (the restore keeps a change it did not make), and said."""
        foreign = self.link.parameters.foreign
        changed = [neutral for neutral in scheduler.footprint.parameters - scheduler.released
                   if any(native in foreign for native in unscheduled.natives_of.get(neutral, ()))]
        if not changed:
            return
        scheduler.release(changed)
        natives = ", ".join(f"{c.name} {c.value:g}" for c in foreign.values())
        log.warning("gain scheduling: %s set by someone else (%s): no longer scheduled, their value kept",
                    ", ".join(sorted(changed)), natives)
        self.link.status_text(f"scheduling stopped for {natives}: theirs kept"[:50], 4)

    def _schedule(self, telemetry) -> None:
        """One scheduler step; a refused or lost write leaves the last good gains (rolled back if
        the failure came half-way through a set), and the loop goes on."""
        scheduler, unscheduled = self.scheduler, self.unscheduled
        if scheduler is None or unscheduled is None:  # _rebuild_scheduler sets both: no scheduler, nothing to do
            return
        self._release_foreign(scheduler, unscheduled)
        commands = scheduler.step(telemetry)
        if not commands:
            return
        try:
            self.link.execute(commands)
            scheduler.confirm()
        except Exception as exc:  # noqa: BLE001 - the resident loop must outlive a refused write
            log.warning("scheduled gain write failed: %s", exc)
            scheduler.reject()
            good = scheduler.written or unscheduled.parameters
            for name, value in good.items():  # each one on its own: one refusal must not stop the others
                if name not in scheduler.footprint.parameters or name in scheduler.released:
                    continue
                try:
                    self.link.set_params({name: value})
                except Exception as rollback_exc:  # noqa: BLE001
                    log.error("could not roll %s back: %s", name, rollback_exc)
            self.link.status_text(f"gain scheduling: write failed ({exc})"[:50], 4)

    def _run_procedure(self, command: int, params: tuple[float, ...]) -> None:
        """Start what the command names (``companion.procedures.registry.COMMANDS``), one runner for all.
        A learning session ends first (its unverified gains put back, its verified ones kept) and a
        new one starts after, from the gains the procedure left: its restore must never undo what the
        procedure verified and wrote."""
        if self.learning is not None:
            self.learning.finish()
            if self.learning.restore_problems:  # the vehicle is not as found: nothing may build on it
                problems = "; ".join(self.learning.restore_problems)
                log.error("%s not started: learning could not put the vehicle back (%s)", COMMANDS[command], problems)
                self.link.status_text("procedure refused: learning's gains not put back", 4)
                self.link.ground.send_command_ack(command, MAV_RESULT_FAILED)
                self.learning = None  # the trail stays open: `companion recover` puts the vehicle back
                return
        try:
            self._run_one(command, params)
        finally:
            if self.learning is not None:
                self._restart_learning()

    def _restart_learning(self) -> None:
        self.learning = LearningSession(self.link, self.store, self.vehicle_id, self.config.learning, self.config.campaign)
        refused = self.learning.start()
        if refused is not None:
            log.warning("learning off after the procedure: %s", refused)
            self.learning = None

    def _run_one(self, command: int, params: tuple[float, ...]) -> None:
        self.procedure_abort = AbortFlag()
        self.running = command
        name = COMMANDS[command]
        abort = self._abort_requested()
        self._notify("procedure_started", name, command)
        try:
            if command == IDENTIFICATION_COMMAND:
                gcs = GcsProgress(self.link, command)
                _campaign, outcome, campaign_id = run_campaign(self.link, self.store, self.config.campaign,
                                                               vehicle_id=self.vehicle_id, abort=abort, gcs=gcs)
                entry: dict[str, Any] = {"procedure": name, "status": outcome.status, "reason": outcome.reason,
                                         "campaign_id": campaign_id}
                if self.learning is None:  # with learning on, the learner owns the heading gains
                    self._rebuild_scheduler()
                if self.health is not None:  # a new campaign is the new healthy reference
                    self.health.start()
            else:
                seconds = params[0] if params and math.isfinite(params[0]) and params[0] > 0 else None
                if seconds is not None and seconds > MAX_PROCEDURE_S:
                    raise ValueError(f"param1 {seconds:g} s is beyond the {MAX_PROCEDURE_S:g} s a procedure may last")
                context = ProcedureContext(configs={"roll": self.config.roll, "min_speed": self.config.min_speed},
                                           preset=self.config.preset, simulator=False, seconds=seconds)
                ran = run_named_procedure(name, self.link, self.store, vehicle_id=self.vehicle_id, campaign_id=None,
                                          abort=abort, context=context)
                status = ran.result.status
                self.link.ground.send_command_ack(command, MAV_RESULT_ACCEPTED if status == "completed" else MAV_RESULT_FAILED,
                                           100 if status == "completed" else 0)
                entry = {"procedure": name, "status": status, "summary": ran.summary}
        except (LinkError, UserError) as exc:  # expected conditions: a sentence
            log.warning("procedure %d failed: %s", command, exc)
            log.debug("procedure %d failed", command, exc_info=True)
            self.link.ground.send_command_ack(command, MAV_RESULT_FAILED)
            entry = {"procedure": name, "status": "failed", "reason": str(exc)}
        except Exception as exc:  # noqa: BLE001 - the resident loop must survive a failed procedure
            log.exception("procedure %d failed", command)
            self.link.ground.send_command_ack(command, MAV_RESULT_FAILED)
            entry = {"procedure": name, "status": "failed", "reason": str(exc)}
        finally:
            self.procedure_abort = None
            self.running = None
        self.history.append(entry)
        log.info("procedure finished: %s", entry)
        self._notify("procedure_finished", entry)

    def _notify(self, event: str, *args) -> None:
        """Tell the observer, if any; a watcher that fails never disturbs the loop."""
        if self.observer is None:
            return
        try:
            getattr(self.observer, event)(*args)
        except Exception as exc:  # noqa: BLE001 - the observer only watches
            log.warning("status observer failed on %s: %s", event, exc)
