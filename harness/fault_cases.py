"""Fault-injection cases: a procedure run through :class:`harness.fault_proxy.FaultProxy` with a
schedule of faults, then checked against the vehicle as it was found (the
fault-injection suite). Shared by ``tests/test_fault_injection.py`` (grouped schedules that cover every fault kind
at every phase) and ``bench/bench_faults.py`` (the matrix kind × phase × seed, one fault per case).

A case, on a ``--lockstep`` simulator served over TCP:

1. connects the companion through a fresh proxy, puts the vehicle in hold, armed, and notes every
   parameter of the autopilot profile, its mode and its thrust;
2. arms the proxy with the case's faults and runs the procedure through the application path
   (``run_campaign`` / ``run_named_behavior``) into a store file; with ``abort_after`` an operator
   abort is requested once the companion has sent that many frames of a kind, so the restore
   itself can be hit;
3. reconnects directly (no proxy) and compares: every parameter, the mode (unless the outcome says
   the pilot took the vehicle), the thrust the vehicle runs at, the last heading set-point the
   vehicle received, no RC override left held, and the store (``PRAGMA integrity_check``, the
   campaign row closed with a status and a reason, every row the application committed present).

What did not hold is returned as ``problems`` (empty: the case survived); an exception escaping the
procedure is a ``crash``. Phases are recognised from the companion's own traffic (the first thrust
set-point is the settle, the first RC override the excitation, the first PARAM_SET the step
checks' trial gains ...), counted from the clean runs on this simulator (see :data:`PHASES`).
"""
from __future__ import annotations

import logging
import math
import sqlite3
import time
import traceback
from dataclasses import dataclass, field, replace
from pathlib import Path

from harness.fault_proxy import BOTH, FAULT_KINDS, Fault, FaultProxy, Trigger

log = logging.getLogger(__name__)

__all__ = ["CASE_PROCEDURES", "FRAME_KINDS", "PHASES", "Case", "CaseResult", "Phase", "closed_cut_case",
           "mixed_case", "restore_case", "run_case", "single_case", "silent_cut_case"]

MAV_CMD_CONDITION_YAW = 115
MAV_CMD_DO_CHANGE_SPEED = 178

CASE_PROCEDURES = ("campaign", "roll", "min_speed")
FRAME_KINDS = tuple(kind for kind in FAULT_KINDS if kind != "cut")  # faults on single frames
#: RC channel value tolerance and set-point tolerances of the checks
THRUST_TOLERANCE = 0.011  # thrust ratio (the simulator reports whole percent)
HEADING_TOLERANCE_DEG = 0.01
#: the companion's link in the cases: a lockstep stall (a lost acknowledgement or sample) is broken
#: after 0.1 s of wall clock instead of 1 s (only the wall time of a case depends on it)
CASE_STALL_S = 0.1


@dataclass(frozen=True)
class Phase:
    """A phase of a procedure, recognised from the companion's traffic by ``trigger``. A restore
    phase starts at the companion's "aborted" STATUSTEXT, after an abort requested once the
    companion sent ``abort_after`` = (message, count) frames."""

    procedure: str
    name: str
    trigger: Trigger
    abort_after: tuple[str, int] | None = None

    @property
    def label(self) -> str:
        return f"{self.procedure}/{self.name}"

    @property
    def restore(self) -> bool:
        return self.abort_after is not None


_ABORTED = Trigger("STATUSTEXT", 1, text="aborted")
#: the phases, in the order they happen (traffic of the clean runs of :func:`run_case`'s configs); a
#: PARAM_SET or set-point is counted only when it is a new request (``distinct``: not a retry)
PHASES: dict[str, Phase] = {phase.label: phase for phase in (
    Phase("campaign", "capture", Trigger("PARAM_REQUEST_READ", 1)),  # the restore point reads the gains
    Phase("campaign", "settle", Trigger("COMMAND_LONG", 1, command=MAV_CMD_DO_CHANGE_SPEED)),
    Phase("campaign", "excitation", Trigger("RC_CHANNELS_OVERRIDE", 1)),  # the training doublet
    Phase("campaign", "validation", Trigger("STATUSTEXT", 1, text="validating")),  # resettle, fresh doublet
    Phase("campaign", "second-thrust", Trigger("COMMAND_LONG", 2, command=MAV_CMD_DO_CHANGE_SPEED, distinct=True)),
    Phase("campaign", "step-checks", Trigger("PARAM_SET", 1)),  # the scheduled gains on trial
    Phase("campaign", "gains", Trigger("PARAM_SET", 7, distinct=True)),  # the final scheduled gains written
    Phase("campaign", "restore", _ABORTED, abort_after=("PARAM_SET", 3)),  # aborted in the step checks
    Phase("roll", "disturbance", Trigger("PARAM_SET", 1, param="SIM_ROLL_DIST")),
    Phase("roll", "settle", Trigger("COMMAND_LONG", 1, command=MAV_CMD_DO_CHANGE_SPEED)),
    Phase("roll", "closed-loop", Trigger("STATUSTEXT", 1, text="roll stabilisation on")),
    Phase("roll", "kick", Trigger("PARAM_SET", 1, param="SIM_ROLL_KICK")),
    Phase("roll", "restore", _ABORTED, abort_after=("COMMAND_LONG", 40)),  # aborted in the closed loop
    Phase("min_speed", "capture", Trigger("PARAM_REQUEST_READ", 1)),
    Phase("min_speed", "settle", Trigger("COMMAND_LONG", 1, command=MAV_CMD_DO_CHANGE_SPEED)),
    Phase("min_speed", "seeking", Trigger("STATUSTEXT", 1, text="seeking started")),
    Phase("min_speed", "restore", _ABORTED, abort_after=("COMMAND_LONG", 4)),  # aborted while seeking
)}


def phases_of(procedure: str, *, restore: bool | None = None) -> list[Phase]:
    """The phases of ``procedure`` (only restore phases, only the others, or all)."""
    return [p for p in PHASES.values() if p.procedure == procedure and (restore is None or p.restore == restore)]


# ====================================================================== cases
@dataclass(frozen=True)
class Case:
    """One run: ``procedure`` under ``faults``; ``covers`` the (kind, phase label) pairs it exercises."""

    label: str
    procedure: str
    faults: tuple[Fault, ...]
    covers: tuple[tuple[str, str], ...]
    abort_after: tuple[str, int] | None = None
    seed: int = 0


def frame_fault(kind: str, trigger: Trigger, *, frames: int = 3) -> Fault:
    """A bounded fault on single frames of either direction (any message) from ``trigger`` on."""
    return Fault(kind, trigger, direction=BOTH, frames=frames, window_s=2.0, hold_frames=6, max_hold_s=0.2)


def silent_cut(trigger: Trigger, cut_s: float = 0.3) -> Fault:
    """The link drops everything for ``cut_s`` wall seconds, sockets open (a radio dropout)."""
    return Fault("cut", trigger, cut_s=cut_s, reconnect=False)


def closing_cut(trigger: Trigger, cut_s: float = 0.5) -> Fault:
    """The connections close; the companion is accepted again ``cut_s`` wall seconds later."""
    return Fault("cut", trigger, cut_s=cut_s, reconnect=True)


def single_case(phase: Phase, kind: str, seed: int = 0, *, reconnect: bool = False) -> Case:
    """One fault ``kind`` at ``phase`` (the bench's cell); the seed shifts where in the phase it
    starts (0–4 frames after the trigger) and which byte a corruption flips."""
    trigger = replace(phase.trigger, after=seed % 5)
    if kind == "cut":
        fault = closing_cut(trigger) if reconnect else silent_cut(trigger)
    else:
        fault = frame_fault(kind, trigger)
    name = "cut-closed" if kind == "cut" and reconnect else kind
    return Case(f"{phase.label}:{name}:seed{seed}", phase.procedure, (fault,), ((kind, phase.label),),
                phase.abort_after, seed)


def mixed_case(procedure: str, seed: int = 0) -> Case:
    """Every frame fault kind at every (non-restore) phase of ``procedure``, one after the other
    within the phase (8 frames apart); which kind meets the phase's own trigger frame rotates from
    phase to phase, so each kind hits a phase's key message somewhere."""
    faults, covers = [], []
    for number, phase in enumerate(phases_of(procedure, restore=False)):
        for slot in range(len(FRAME_KINDS)):
            kind = FRAME_KINDS[(slot + number + seed) % len(FRAME_KINDS)]
            faults.append(frame_fault(kind, replace(phase.trigger, after=8 * slot)))
            covers.append((kind, phase.label))
    return Case(f"{procedure}:mixed:seed{seed}", procedure, tuple(faults), tuple(covers), seed=seed)


def silent_cut_case(procedure: str) -> Case:
    """A short silent cut at every (non-restore) phase of ``procedure``."""
    phases = phases_of(procedure, restore=False)
    return Case(f"{procedure}:cuts", procedure, tuple(silent_cut(p.trigger) for p in phases),
                tuple(("cut", p.label) for p in phases))


def restore_case(procedure: str, kinds: tuple[str, ...] = FRAME_KINDS) -> Case:
    """An abort during ``procedure``, then ``kinds`` one after the other in its restore (a cut, if
    among them, last: it takes every frame while it lasts)."""
    phase = phases_of(procedure, restore=True)[0]
    faults = []
    for slot, kind in enumerate(kinds):
        trigger = replace(phase.trigger, after=6 * slot)
        faults.append(silent_cut(trigger) if kind == "cut" else frame_fault(kind, trigger))
    return Case(f"{phase.label}:{'+'.join(kinds)}", procedure, tuple(faults),
                tuple((kind, phase.label) for kind in kinds), phase.abort_after)


def closed_cut_case(phase: Phase) -> Case:
    """The connection closes at ``phase``: the procedure loses its link; the restore must reconnect."""
    return Case(f"{phase.label}:cut-closed", phase.procedure, (closing_cut(phase.trigger),),
                (("cut", phase.label),), phase.abort_after)


# ====================================================================== running one
@dataclass
class CaseResult:
    """What a case did and what did not hold (``problems`` empty: survived)."""

    case: Case
    status: str | None = None
    reason: str | None = None
    crash: str | None = None
    problems: list[str] = field(default_factory=list)
    restore_problems: list[str] = field(default_factory=list)
    faults: list[dict] = field(default_factory=list)  # FaultProxy.summary()
    wall_s: float = 0.0
    wall_decisions: int = 0  # the companion's waits ended on wall clock and lockstep stalls it broke

    @property
    def survived(self) -> bool:
        return self.crash is None and not self.problems

    @property
    def untriggered(self) -> list[str]:
        """Scheduled faults that never started or hit nothing (the run ended before their phase)."""
        return [f["fault"] for f in self.faults if not f["triggered"] or not f["affected"]]


class _AbortAfter:
    """An abort source (polled once per snapshot) that asks for an abort once the companion has sent
    ``count`` frames of ``message`` through the proxy; carries the flag's restore guard."""

    def __init__(self, proxy: FaultProxy, message: str, count: int) -> None:
        from companion.procedures.app import AbortFlag

        self.proxy, self.message, self.count = proxy, message, count
        self._flag = AbortFlag()
        self.guard = self._flag.guard

    def __call__(self) -> str | None:
        if self._flag.reason is None and self.proxy.count(self.message) >= self.count:
            self._flag.request(f"operator abort (after {self.count} {self.message})")
        return self._flag()


class _CountingStore:
    """Counts the rows the application committed, per table (wraps Store._insert)."""

    def __init__(self, store) -> None:
        self.committed: dict[str, int] = {}
        insert = store._insert

        def counted(sql: str, args: tuple) -> int:
            row = insert(sql, args)  # raises if the transaction did not commit: then not counted
            table = sql.split("INTO", 1)[1].split("(", 1)[0].strip().split()[0]
            self.committed[table] = self.committed.get(table, 0) + 1
            return row

        store._insert = counted


def campaign_config():
    """The short campaign of the fault cases: two thrusts, yaw only, short settles, one step check
    whose verdict is lenient (the cases test the link, not the gains: a design is always written,
    so the final-gains phase is always reached)."""
    from behaviors.heading_steps import StepTestConfig
    from behaviors.identification import ManoeuvreConfig
    from companion.procedures.campaign import CampaignConfig, GainCheck

    return CampaignConfig(thrusts=(0.7, 1.0), axes=("yaw",), step_labels=("scheduled",),
                          yaw=ManoeuvreConfig(settle_s=8.0, resettle_s=6.0),
                          step_test=StepTestConfig(settle_s=12.0, hold_s=20.0),
                          verify=GainCheck(max_overshoot_pct=100.0, max_oscillations=10, better_than_original=False))


def roll_config():
    from companion.procedures.roll import RollProcedureConfig

    return RollProcedureConfig(settle_s=4.0, open_s=6.0, closed_s=6.0, kick_deg=15.0, kick_record_s=4.0)


def min_speed_config():
    from companion.procedures.min_speed import MinSpeedProcedureConfig

    return MinSpeedProcedureConfig(settle_s=4.0, duration_s=16.0)


def _native_names() -> list[str]:
    """Every parameter of the simulator profile (what any procedure could change)."""
    from companion.link.autopilots.sim import PROFILE

    return sorted(set(PROFILE.params.values()))


def _snapshot(link, names: list[str]) -> dict:
    """Parameters (native), mode and thrust of the vehicle as ``link`` sees it now."""
    params = {name: link.get_param(name) for name in names}
    link.skip_to_now()  # snapshots queued during the blocking calls predate them
    for _ in range(3):  # a few samples: the thrust output follows its set-point within one step
        telemetry = link.next_telemetry(timeout_s=10.0)
    return {"params": params, "mode": link.mode, "thrust": telemetry.thrust_ratio, "yaw": telemetry.yaw,
            "armed": link.armed}


def _run_procedure(case: Case, link, store, abort) -> tuple[str, str | None, list[str], object, dict]:
    """The procedure through the application path: (status, reason, restore problems, restore point,
    kept parameters)."""
    from companion.procedures.app import run_campaign, run_named_behavior

    vehicle_id = store.add_vehicle("fault-case", "sim")
    if case.procedure == "campaign":
        campaign, outcome, _ = run_campaign(link, store, campaign_config(), vehicle_id=vehicle_id, abort=abort)
        kept = dict(campaign.final_gains or {}) if outcome.status == "completed" else {}
        return outcome.status, outcome.reason, outcome.restore_problems, outcome.restore, kept
    out = run_named_behavior(case.procedure, link, store, vehicle_id=vehicle_id, campaign_id=None, abort=abort,
                             preset="starfish", simulator=True, roll_config=roll_config(),
                             min_speed_config=min_speed_config())
    return (out.result.status, out.result.reason, list(out.result.restore_problems),
            getattr(out.outcome, "restore", None), {})


def run_case(sim, case: Case, store_path: Path, *, connect_timeout_s: float = 20.0) -> CaseResult:
    """Run ``case`` against the running simulator ``sim`` (``--lockstep``, TCP) and check it."""
    from companion.link.vehicle import LinkTimeouts, VehicleLink
    from companion.procedures.app import AbortFlag
    from companion.records.store import Store

    result = CaseResult(case)
    names = _native_names()
    started = time.monotonic()
    with FaultProxy(sim.port, seed=case.seed) as proxy:
        link = VehicleLink.connect(proxy.endpoint, lockstep=True, heartbeat_timeout_s=connect_timeout_s,
                                   timeouts=LinkTimeouts(lockstep_stall_s=CASE_STALL_S))
        try:
            link.set_mode("hold")
            link.arm(True)
            before = _snapshot(link, names)
            abort = _AbortAfter(proxy, *case.abort_after) if case.abort_after else AbortFlag()
            proxy.arm(case.faults)
            with Store(store_path) as store:
                counter = _CountingStore(store)
                try:
                    status, reason, restore_problems, restore, kept = _run_procedure(case, link, store, abort)
                except Exception as exc:  # noqa: BLE001 - an escaping exception is the finding
                    result.crash = f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=6)}"
                    status, reason, restore_problems, restore, kept = None, None, [], None, {}
            proxy.disarm()
            result.wall_decisions = link.clock.wall_timeouts
            result.status, result.reason, result.restore_problems = status, reason, restore_problems
            result.faults = proxy.summary()
            if link.overrides.active:
                result.problems.append(f"the companion still holds RC overrides {link.overrides.active}")
            held = proxy.held_overrides()
            if held:
                result.problems.append(f"the vehicle was last told to hold RC channels {held}")
            result.problems += _check_setpoints(proxy, restore)
        finally:
            link.close()
    result.problems += _check_vehicle(sim, before, names, status, reason, kept, connect_timeout_s)
    result.problems += _check_store(store_path, counter.committed, case, status)
    result.wall_s = time.monotonic() - started
    return result


def _check_setpoints(proxy: FaultProxy, restore) -> list[str]:
    """The last heading and thrust set-points the vehicle received are the ones it was found with."""
    if restore is None:
        return []
    problems = []
    setpoints = getattr(restore, "setpoints", {}) or {}
    heading = setpoints.get("heading")
    sent = proxy.delivered_commands.get(MAV_CMD_CONDITION_YAW)
    if heading is not None and sent is not None:
        want = math.degrees(heading) % 360.0
        if abs((sent[0] - want + 180.0) % 360.0 - 180.0) > HEADING_TOLERANCE_DEG:
            problems.append(f"heading set-point left at {sent[0]:.2f} deg (found {want:.2f} deg)")
    return problems


def _check_vehicle(sim, before: dict, names: list[str], status, reason, kept: dict, timeout_s: float) -> list[str]:
    """Reconnect directly and compare with what was found."""
    from companion.link.autopilots.sim import PROFILE
    from companion.link.vehicle import VehicleLink

    problems = []
    if status not in (None, "completed", "aborted", "failed"):
        problems.append(f"outcome status {status!r}")
    if status in ("aborted", "failed") and not reason:
        problems.append(f"{status} without a reason")
    with VehicleLink.connect(sim.endpoint, lockstep=True, heartbeat_timeout_s=timeout_s) as check:
        after = _snapshot(check, names)
    kept_native = {PROFILE.native_param(name): PROFILE.to_native_value(name, value) for name, value in kept.items()}
    for name in names:
        found, now = before["params"][name], after["params"][name]
        want = kept_native.get(name, found)
        if not _same(now, want):
            problems.append(f"{name} = {now!r}, found {found!r}" + (f", kept {want!r}" if name in kept_native else ""))
    pilot = reason is not None and ("someone else" in reason or "disarmed" in reason)
    if after["mode"] != before["mode"] and not pilot:
        problems.append(f"mode {after['mode']!r}, found {before['mode']!r}")
    if not math.isfinite(after["thrust"]) or abs(after["thrust"] - before["thrust"]) > THRUST_TOLERANCE:
        problems.append(f"thrust {after['thrust']:.3f}, found {before['thrust']:.3f}")
    return problems


def _same(a: float, b: float) -> bool:
    return math.isfinite(a) and math.isfinite(b) and abs(a - b) <= 1e-6 * max(1.0, abs(b))


def _check_store(path: Path, committed: dict[str, int], case: Case, status) -> list[str]:
    """Integrity check, the campaign row closed, every committed row there (read from a fresh
    connection, as another process would)."""
    problems = []
    db = sqlite3.connect(f"file:{path}?mode=ro", uri=True)
    try:
        integrity = db.execute("PRAGMA integrity_check").fetchone()[0]
        if integrity != "ok":
            problems.append(f"store integrity check: {integrity}")
        for table, count in committed.items():
            present = db.execute(f"SELECT COUNT(*) FROM {table}").fetchone()[0]  # noqa: S608 - our table names
            if present < count:
                problems.append(f"store lost rows: {table} has {present} of {count} committed")
        campaigns = db.execute("SELECT status, reason FROM campaigns").fetchall()
    finally:
        db.close()
    if not campaigns:
        problems.append("no campaign row")
    elif status is not None and campaigns[-1][0] != status:
        problems.append(f"campaign row says {campaigns[-1][0]!r}, the outcome {status!r}")
    elif campaigns[-1][0] == "running":
        problems.append("campaign row left 'running'")
    return problems
