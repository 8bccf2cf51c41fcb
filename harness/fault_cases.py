"""Fault-injection cases: a procedure run through :class:`harness.fault_proxy.FaultProxy` (TCP) or
:class:`harness.udp_relay.UdpRelay` (UDP) with a schedule of faults, then checked against the
vehicle as it was found (the fault-injection suite). Shared by ``tests/test_fault_injection.py``
(grouped schedules that cover every fault kind at every phase) and ``bench/bench_faults.py`` (the
matrix kind × phase × seed, one fault per case, over either transport).

A case, on a ``--lockstep`` simulator served over TCP or UDP (the transport of the case is the
simulator's: a TCP simulator is reached through the proxy, a UDP one through the relay):

1. connects the companion through a fresh proxy or relay, puts the vehicle in hold, armed, and notes
   every parameter of the autopilot profile, its mode, its thrust and its heading;
2. arms the proxy with the case's faults and runs the procedure through the application path
   (``run_campaign`` / ``run_named_behavior``) into a store file; with ``abort_after`` an operator
   abort is requested once the companion has sent that many frames of a kind, so the restore
   itself can be hit;
3. reconnects directly (no proxy) and compares **by state**, what the vehicle holds afterwards:
   every parameter, the mode (unless the outcome says the pilot took the vehicle), armed, the thrust
   it runs at and the heading it steers to (the mean yaw over 2 s after 8 s of vehicle time, against
   the heading it was found holding); then what it was last told (the last heading set-point
   delivered, no RC override left held) and the store (``PRAGMA integrity_check``, the campaign row
   closed with a status and a reason, every row the application committed present).

What did not hold is returned as ``problems`` (empty: the case survived), the part of them about the
vehicle's state as ``state_problems`` (empty: the restore is confirmed by state, whatever the
companion claimed in its ``restore_problems``); an exception escaping the procedure is a ``crash``. Phases are recognised from the companion's own traffic (the first thrust
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

from harness.fault_proxy import BOTH, FAULT_KINDS, Fault, FaultProxy, LinkConditions, Trigger
from harness.udp_relay import UdpRelay

log = logging.getLogger(__name__)

__all__ = ["CASE_PROCEDURES", "FRAME_KINDS", "PHASES", "TRANSPORTS", "Case", "CaseResult", "Phase", "closed_cut_case",
           "fault_link", "mixed_case", "native_names", "restore_case", "run_case", "single_case", "silent_cut_case",
           "state_differences", "vehicle_state"]

MAV_CMD_CONDITION_YAW = 115
MAV_CMD_DO_CHANGE_SPEED = 178

CASE_PROCEDURES = ("campaign", "roll", "min_speed")
TRANSPORTS = ("tcp", "udp")
FRAME_KINDS = tuple(kind for kind in FAULT_KINDS if kind != "cut")  # faults on single frames
#: RC channel value tolerance and set-point tolerances of the checks
THRUST_TOLERANCE = 0.011  # thrust ratio (the simulator reports whole percent)
HEADING_TOLERANCE_DEG = 0.01
#: the heading held, by state: the mean yaw over HEADING_WINDOW_S after HEADING_SETTLE_S of vehicle
#: time on the direct reconnection, within HEADING_HELD_DEG of the heading found (the yaw wanders
#: ±0.8° in hold at 70 %; a set-point left at a step's +20° shows at once); only with steerage
HEADING_SETTLE_S, HEADING_WINDOW_S, HEADING_HELD_DEG, STEERAGE_THRUST = 8.0, 2.0, 3.0, 0.3
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
    state_problems: list[str] = field(default_factory=list)  # the vehicle's state afterwards (in problems too)
    restore_problems: list[str] = field(default_factory=list)  # what the companion itself reported
    faults: list[dict] = field(default_factory=list)  # FaultProxy.summary()
    wall_s: float = 0.0
    wall_decisions: int = 0  # the companion's waits ended on wall clock and lockstep stalls it broke
    transport: str = "tcp"
    before: dict = field(default_factory=dict)  # the vehicle as found (no parameters)
    after: dict = field(default_factory=dict)  # the vehicle afterwards, by state (no parameters)
    link: dict = field(default_factory=dict)  # the proxy's or relay's counts per direction
    thrust_sent: list[float] = field(default_factory=list)  # DO_CHANGE_SPEED throttle (%) as the companion sent them
    thrust_delivered: list[float] = field(default_factory=list)  # ... as the vehicle received them

    @property
    def survived(self) -> bool:
        return self.crash is None and not self.problems

    @property
    def restored_by_state(self) -> bool:
        """The vehicle held afterwards what it was found with (or was left with on purpose)."""
        return not self.state_problems

    @property
    def restore_claimed(self) -> bool:
        """The companion ended the procedure and said its restore had no problem."""
        return self.crash is None and self.status is not None and not self.restore_problems

    @property
    def untriggered(self) -> list[str]:
        """Scheduled faults that never started or hit nothing (the run ended before their phase)."""
        return [f["fault"] for f in self.faults if not f["triggered"] or not f["affected"]]


#: ``abort_after`` = (FAULT_FIRED, k): the abort is asked once k of the case's faults have started
FAULT_FIRED = "a fault fired"


class _AbortAfter:
    """An abort source (polled once per snapshot) that asks for an abort once the companion has sent
    ``count`` frames of ``message`` through the proxy (or ``count`` faults fired,
    :data:`FAULT_FIRED`); carries the flag's restore guard."""

    def __init__(self, proxy: FaultProxy | UdpRelay, message: str, count: int) -> None:
        from companion.procedures.app import AbortFlag

        self.proxy, self.message, self.count = proxy, message, count
        self._flag = AbortFlag()
        self.guard = self._flag.guard

    def __call__(self) -> str | None:
        seen = len(self.proxy.triggered) if self.message == FAULT_FIRED else self.proxy.count(self.message)
        if self._flag.reason is None and seen >= self.count:
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


def native_names() -> list[str]:
    """Every parameter of the simulator profile (what any procedure could change)."""
    from companion.link.autopilots.sim import PROFILE

    return sorted(set(PROFILE.params.values()))


def vehicle_state(link, names: list[str], *, settle_s: float = 0.0, window_s: float = 1.0) -> dict:
    """Parameters (native), mode, armed, thrust of the vehicle as ``link`` sees it now, and the
    heading it holds: the circular mean yaw over ``window_s`` of vehicle time after ``settle_s``."""
    params = {name: link.get_param(name) for name in names}
    link.skip_to_now()  # snapshots queued during the blocking calls predate them
    for _ in range(3):  # a few samples: the thrust output follows its set-point within one step
        telemetry = link.next_telemetry(timeout_s=10.0)
    thrust, start = telemetry.thrust_ratio, telemetry.time_s
    sines, cosines = [], []
    for _ in range(int((settle_s + window_s) * 100)):  # bounded: 100 samples per second at most
        if telemetry.time_s - start >= settle_s + window_s:
            break
        if telemetry.time_s - start >= settle_s and math.isfinite(telemetry.yaw):
            sines.append(math.sin(telemetry.yaw))
            cosines.append(math.cos(telemetry.yaw))
        telemetry = link.next_telemetry(timeout_s=10.0)
    heading = math.atan2(sum(sines), sum(cosines)) if sines else float("nan")
    return {"params": params, "mode": link.mode, "thrust": thrust, "yaw": telemetry.yaw, "heading": heading,
            "armed": link.armed, "thrust_late": telemetry.thrust_ratio}


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
                             preset="starfish", simulator=True,
                             config={"roll": roll_config(), "min_speed": min_speed_config()}.get(case.procedure))
    return (out.result.status, out.result.reason, list(out.result.restore_problems),
            getattr(out.outcome, "restore", None), {})


#: the last vehicle time (ms) a companion saw on each UDP lockstep simulator, by port (see
#: :func:`_resume_udp_lockstep`)
_UDP_LOCKSTEP_MS: dict[int, int] = {}


def _resume_udp_lockstep(sim, link, seen_ms: int | None = None) -> None:
    """A lockstep simulator over UDP does not notice a companion leaving (UDP has no disconnect): its
    vehicle time waits at the last sample acknowledged, for an acknowledgement beyond it that a new
    companion cannot give before it has received a sample. Acknowledge once the last vehicle time a
    companion saw on this simulator, so the next sample comes (TCP needs none of this)."""
    if sim.transport != "udp" or not sim.lockstep:
        return
    known = max(_UDP_LOCKSTEP_MS.get(sim.port, 0), seen_ms or 0)
    if known > 0:
        link.clock.acknowledge(known)


def _note_udp_lockstep(sim, link) -> None:
    if sim.transport == "udp" and link.clock.last_sample_ms is not None:
        _UDP_LOCKSTEP_MS[sim.port] = max(_UDP_LOCKSTEP_MS.get(sim.port, 0), int(link.clock.last_sample_ms))


def fault_link(sim, seed: int = 0, conditions: LinkConditions | dict | None = None) -> FaultProxy | UdpRelay:
    """The fault tool in front of ``sim`` for its transport: the TCP proxy or the UDP relay (not started)."""
    if sim.transport == "tcp":
        return FaultProxy(sim.port, seed=seed, conditions=conditions)
    return UdpRelay(sim.port, seed=seed, conditions=conditions)


def run_case(sim, case: Case, store_path: Path, *, transport: str | None = None, connect_timeout_s: float = 20.0,
             conditions: LinkConditions | dict | None = None, stay_connected_s: float = 0.0) -> CaseResult:
    """Run ``case`` against the running simulator ``sim`` (``--lockstep``) over ``transport``
    ("tcp" through the proxy, "udp" through the relay; None: the simulator's) and check it.
    ``conditions``: link conditions of the proxy or relay besides the case's faults (none: clean);
    ``stay_connected_s``: wall seconds the companion keeps reading telemetry after the procedure
    (as ``companion run`` would) before the link is closed."""
    from companion.link.vehicle import LinkTimeouts, VehicleLink
    from companion.procedures.app import AbortFlag
    from companion.records.store import Store

    transport = transport or sim.transport
    if transport not in TRANSPORTS or transport != sim.transport:
        raise ValueError(f"a {transport!r} case needs a simulator listening on {transport} (it listens on "
                         f"{sim.transport}); transports: {', '.join(TRANSPORTS)}")
    result = CaseResult(case, transport=transport)
    names = native_names()
    started = time.monotonic()
    with fault_link(sim, case.seed, conditions) as proxy:
        link = VehicleLink.connect(proxy.endpoint, lockstep=sim.lockstep, heartbeat_timeout_s=connect_timeout_s,
                                   timeouts=LinkTimeouts(lockstep_stall_s=CASE_STALL_S))
        try:
            _resume_udp_lockstep(sim, link)
            link.set_mode("hold")
            link.arm(True)
            before = vehicle_state(link, names)
            abort = _AbortAfter(proxy, *case.abort_after) if case.abort_after else AbortFlag()
            proxy.arm(case.faults)
            with Store(store_path) as store:
                counter = _CountingStore(store)
                try:
                    status, reason, restore_problems, restore, kept = _run_procedure(case, link, store, abort)
                except Exception as exc:  # noqa: BLE001 - an escaping exception is the finding
                    result.crash = f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=6)}"
                    status, reason, restore_problems, restore, kept = None, None, [], None, {}
            stay_until = time.monotonic() + stay_connected_s
            while result.crash is None and time.monotonic() < stay_until:
                link.next_telemetry()
            proxy.disarm()
            proxy.drain()  # what is still held or in flight reaches the vehicle, as on a real link
            result.wall_decisions = link.clock.wall_timeouts
            result.status, result.reason, result.restore_problems = status, reason, list(restore_problems)
            result.faults = proxy.summary()
            result.link = proxy.stats()
            result.thrust_sent = [d.params[2] for d in proxy.history(MAV_CMD_DO_CHANGE_SPEED, sent=True)]
            result.thrust_delivered = [d.params[2] for d in proxy.history(MAV_CMD_DO_CHANGE_SPEED)]
            if link.overrides.active:
                result.problems.append(f"the companion still holds RC overrides {link.overrides.active}")
            held = proxy.held_overrides()
            if held:
                result.problems.append(f"the vehicle was last told to hold RC channels {held}")
            result.problems += _check_setpoints(proxy, restore)
        finally:
            _note_udp_lockstep(sim, link)
            link.close()
    after, result.state_problems = _check_vehicle(sim, before, names, status, reason, kept, connect_timeout_s,
                                                  seen_ms=proxy.vehicle_time_ms)
    result.before, result.after = _without_params(before), _without_params(after)
    result.problems += result.state_problems
    result.problems += _check_store(store_path, counter.committed, case, status)
    result.wall_s = time.monotonic() - started
    return result


def _without_params(snapshot: dict) -> dict:
    return {k: v for k, v in snapshot.items() if k != "params"}


def _check_setpoints(proxy: FaultProxy | UdpRelay, restore) -> list[str]:
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


def _check_outcome(status, reason) -> list[str]:
    """The procedure ended with one of the outcome words, and with a reason unless it completed."""
    problems = []
    if status not in (None, "completed", "aborted", "failed"):
        problems.append(f"outcome status {status!r}")
    if status in ("aborted", "failed") and not reason:
        problems.append(f"{status} without a reason")
    return problems


def _check_vehicle(sim, before: dict, names: list[str], status, reason, kept: dict, timeout_s: float,
                   seen_ms: int | None = None) -> tuple[dict, list[str]]:
    """Reconnect directly and compare the vehicle's state with what was found: (the state after, what
    differs)."""
    from companion.link.vehicle import VehicleLink

    problems = _check_outcome(status, reason)
    with VehicleLink.connect(sim.endpoint, lockstep=sim.lockstep, heartbeat_timeout_s=timeout_s) as check:
        _resume_udp_lockstep(sim, check, seen_ms)
        after = vehicle_state(check, names, settle_s=HEADING_SETTLE_S, window_s=HEADING_WINDOW_S)
        _note_udp_lockstep(sim, check)
    return after, problems + state_differences(before, after, names, reason, kept)


def state_differences(before: dict, after: dict, names: list[str], reason: str | None, kept: dict) -> list[str]:
    """What the vehicle holds ``after`` (:func:`vehicle_state`) that differs from ``before``: every
    parameter (or the value ``kept`` on purpose, by profile name), the mode and armed state (unless
    ``reason`` says the pilot took the vehicle), the thrust, and the heading it steers to (with
    steerage, in the mode it was found in)."""
    from companion.link.autopilots.sim import PROFILE

    problems = []
    kept_native = {PROFILE.native_param(name): PROFILE.to_native_value(name, value) for name, value in kept.items()}
    for name in names:
        found, now = before["params"][name], after["params"][name]
        want = kept_native.get(name, found)
        if not _same(now, want):
            problems.append(f"{name} = {now!r}, found {found!r}" + (f", kept {want!r}" if name in kept_native else ""))
    pilot = reason is not None and ("someone else" in reason or "disarmed" in reason)
    if after["mode"] != before["mode"] and not pilot:
        problems.append(f"mode {after['mode']!r}, found {before['mode']!r}")
    if after["armed"] != before["armed"] and not pilot:
        problems.append(f"{'armed' if after['armed'] else 'disarmed'}, found {'armed' if before['armed'] else 'disarmed'}")
    for key, when in (("thrust", ""), ("thrust_late", f" {HEADING_SETTLE_S + HEADING_WINDOW_S:g} s later")):
        if not math.isfinite(after[key]) or abs(after[key] - before["thrust"]) > THRUST_TOLERANCE:
            problems.append(f"thrust {after[key]:.3f}{when}, found {before['thrust']:.3f}")
            break
    if before["thrust"] >= STEERAGE_THRUST and after["mode"] == before["mode"]:
        off = math.degrees((after["heading"] - before["heading"] + math.pi) % (2 * math.pi) - math.pi)
        if not abs(off) <= HEADING_HELD_DEG:
            problems.append(f"heading held {math.degrees(after['heading']) % 360:.1f} deg, found "
                            f"{math.degrees(before['heading']) % 360:.1f} deg")
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
