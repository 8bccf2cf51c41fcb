"""One identification campaign through the UDP relay under given link conditions, scored against
the simulator's truth and checked by the vehicle's state afterwards (``bench/bench_link_conditions.py``).

The simulator runs paced (``--speedup``, no lockstep: a lossy link cannot carry lockstep's
acknowledgements) and listens on UDP. The run:

1. a direct client (no relay) puts the vehicle in hold, armed, and notes its state
   (``harness.fault_cases.vehicle_state``: parameters, mode, armed, thrust, heading held);
2. the companion connects through a :class:`harness.udp_relay.UdpRelay` with the conditions (and any
   triggered faults) and runs the campaign through the application path
   (``companion.procedures.app.run_campaign``), while an optional ``during(relay, sim, report, stop)`` callback
   runs in a thread of its own (a second client changing a parameter...);
3. the relay is drained and closed; a direct client reads the vehicle's state again and compares it
   with what was found (or with the gains the campaign kept on purpose);
4. every accepted yaw model is scored against ``python -m sim linearize`` at the speed of its
   training record (``companion.rehearsal.rehearsal.simulator_truth``).

What the relay did is counted per direction (its ``stats``: ATTITUDE samples lost, delivered out of
vehicle-time order — which the companion drops); what the companion itself reports about the link is
read where it may appear (:func:`companion_link_quality`, guarded: today only
``link.telemetry.snapshots_dropped`` exists).
"""
from __future__ import annotations

import logging
import math
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterable

from harness.fault_cases import native_names, state_differences, vehicle_state
from harness.fault_schedule import Fault
from harness.link_conditions import LinkConditions
from harness.relay_process import RelayProcess
from harness.udp_relay import UdpRelay

log = logging.getLogger(__name__)

__all__ = ["CampaignRun", "companion_link_quality", "run_campaign_through_relay"]

PRESET = "starfish"
DO_CHANGE_SPEED = 178  # MAV_CMD_DO_CHANGE_SPEED: the thrust set-point (throttle % in param 3)
#: read one telemetry snapshot between connecting and the campaign, as ``rehearse`` does (``identify`` does not)
READ_TELEMETRY_FIRST = True
#: settle and window of the heading-held check after the run (vehicle seconds)
AFTER_SETTLE_S, AFTER_WINDOW_S = 8.0, 2.0
#: attribute names under which the companion may count what it lost or dropped (read if present)
QUALITY_NAMES = ("snapshots_dropped", "samples_reordered", "samples_out_of_order", "reordered", "out_of_order",
                 "samples_lost", "lost", "gaps", "max_gap_s", "duplicates", "records_rejected")


@dataclass
class CampaignRun:
    """What one campaign through the relay did."""

    condition: str
    seed: int
    speedup: float
    status: str | None = None
    reason: str | None = None
    crash: str | None = None
    restore_problems: list[str] = field(default_factory=list)
    attempts: list[dict] = field(default_factory=list)  # every attempt: axis, thrust, accepted, r2
    models: list[dict] = field(default_factory=list)  # accepted yaw models with their truth and errors (%)
    final_gains: dict[str, float] = field(default_factory=dict)  # native names
    state_problems: list[str] = field(default_factory=list)
    before: dict = field(default_factory=dict)
    after: dict = field(default_factory=dict)
    relay: dict = field(default_factory=dict)  # UdpRelay.stats()
    kernel_drops: dict = field(default_factory=dict)  # UdpRelay.socket_drops(): full receive buffers on the way
    companion: dict = field(default_factory=dict)  # what the companion reports about the link
    thrust_sent: list[tuple[float, float]] = field(default_factory=list)  # DO_CHANGE_SPEED the companion sent: (wall, %)
    thrust_delivered: list[tuple[float, float]] = field(default_factory=list)  # ... as the vehicle received them
    during: dict = field(default_factory=dict)  # what the ``during`` callback reported
    wall_s: float = 0.0

    @property
    def restored_by_state(self) -> bool:
        return self.crash is None and not self.state_problems

    @property
    def restore_claimed(self) -> bool:
        return self.crash is None and self.status is not None and not self.restore_problems


def companion_link_quality(link, outcome=None, campaign=None) -> dict:
    """What the companion exposes about link quality, wherever it may (come to) be: counters on
    ``link.telemetry`` or the link, a ``link_quality`` attribute or method on them, on the outcome or
    on the campaign. Empty when it exposes nothing."""
    found: dict = {}
    for owner_name, owner in (("telemetry", getattr(link, "telemetry", None)), ("link", link),
                              ("outcome", outcome), ("campaign", campaign)):
        if owner is None:
            continue
        for name in QUALITY_NAMES:
            value = getattr(owner, name, None)
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                found[f"{owner_name}.{name}"] = value
        quality = getattr(owner, "link_quality", None)
        if callable(quality):
            try:
                quality = quality()
            except Exception as exc:  # noqa: BLE001 - a bench reads what it can
                quality = f"unreadable: {exc}"
        if quality is not None:
            found[f"{owner_name}.link_quality"] = quality
    return found


def run_campaign_through_relay(sim, condition: str, conditions: LinkConditions | dict, seed: int, config,
                               workdir: Path, *, faults: Iterable[Fault] = (),
                               during: Callable[[UdpRelay, object, dict, threading.Event], None] | None = None,
                               connect_timeout_s: float = 30.0, relay_process: bool = True) -> CampaignRun:
    """One campaign (``config``: a ``CampaignConfig``) on the running UDP simulator ``sim`` through a
    relay with ``conditions`` and ``faults`` (module docstring); the relay runs in a process of its
    own unless ``relay_process`` is False (``harness.relay_process``)."""
    from companion.link.vehicle import VehicleLink

    run = CampaignRun(condition, seed, sim.speedup)
    started = time.monotonic()
    names = native_names()
    with VehicleLink.connect(sim.endpoint, heartbeat_timeout_s=connect_timeout_s) as direct:
        direct.next_telemetry(timeout_s=connect_timeout_s)
        direct.set_mode("hold")
        direct.arm(True)
        before = vehicle_state(direct, names, settle_s=2.0, window_s=1.0)
    relay = (RelayProcess(sim.port, seed=seed, conditions=conditions) if relay_process
             else UdpRelay(sim.port, seed=seed, conditions=conditions).start())
    try:
        campaign, outcome = _fly(run, relay, sim, config, faults, during, workdir, connect_timeout_s)
        relay.drain(1.0)
        run.thrust_sent = [(d.wall_s, d.params[2]) for d in relay.history(DO_CHANGE_SPEED, sent=True)]
        run.thrust_delivered = [(d.wall_s, d.params[2]) for d in relay.history(DO_CHANGE_SPEED)]
    finally:
        relay.close()
    run.relay = relay.stats()
    if outcome is not None:
        run.status, run.reason, run.restore_problems = outcome.status, outcome.reason, list(outcome.restore_problems)
    kept = dict(campaign.final_gains or {}) if campaign is not None and run.status == "completed" else {}
    with VehicleLink.connect(sim.endpoint, heartbeat_timeout_s=connect_timeout_s) as direct:
        after = vehicle_state(direct, names, settle_s=AFTER_SETTLE_S, window_s=AFTER_WINDOW_S)
    run.state_problems = state_differences(before, after, names, run.reason, kept)
    run.before = {k: v for k, v in before.items() if k != "params"}
    run.after = {k: v for k, v in after.items() if k != "params"}
    run.before["params"] = {n: before["params"][n] for n in ("HDG_P", "HDG_I", "HDG_TRIM") if n in before["params"]}
    run.after["params"] = {n: after["params"][n] for n in ("HDG_P", "HDG_I", "HDG_TRIM") if n in after["params"]}
    run.final_gains = _native(kept)
    if campaign is not None:
        run.models = score_models(campaign)
    run.wall_s = time.monotonic() - started
    return run


def _fly(run: CampaignRun, relay, sim, config, faults: Iterable[Fault], during, workdir: Path,
         connect_timeout_s: float) -> tuple[object, object]:
    """The companion through the relay: connect, the campaign, what it reports; (campaign, outcome),
    None for what never happened (an error before or during the campaign is ``run.crash``)."""
    from companion.link.vehicle import VehicleLink
    from companion.procedures.app import AbortFlag, run_campaign
    from companion.records.store import Store

    campaign = outcome = None
    try:
        link = VehicleLink.connect(relay.endpoint, heartbeat_timeout_s=connect_timeout_s)
    except Exception as exc:  # noqa: BLE001 - the link never came up over these conditions: a finding
        run.crash = f"connecting: {type(exc).__name__}: {exc}"
        return None, None
    helper: threading.Thread | None = None
    stop = threading.Event()
    phase = "before the campaign"
    try:
        if READ_TELEMETRY_FIRST:
            link.next_telemetry(timeout_s=connect_timeout_s)  # the vehicle clock runs before the campaign (as rehearse)
        relay.arm(list(faults))
        if during is not None:
            helper = threading.Thread(target=during, args=(relay, sim, run.during, stop), daemon=True,
                                      name="campaign-during")
            helper.start()
        with Store(workdir / f"store-{run.condition.replace(' ', '_')}-{run.seed}-{sim.speedup:g}.sqlite") as store:
            phase = "in the campaign"
            campaign, outcome, campaign_id = run_campaign(link, store, config, abort=AbortFlag(),
                                                          vehicle_id=store.add_vehicle("link-bench", "sim"))
            run.attempts = [{"axis": r["axis"], "thrust": r.get("thrust"), "accepted": bool(r["accepted"]),
                             "r2": r.get("r2")} for r in store.runs(campaign_id)]
    except Exception as exc:  # noqa: BLE001 - an escaping exception is a finding
        run.crash = f"{phase}: {type(exc).__name__}: {exc}"
    finally:
        stop.set()
        run.companion = companion_link_quality(link, outcome, campaign)
        run.kernel_drops = relay.socket_drops()  # before the companion's socket closes
        link.close()
        if helper is not None:
            helper.join(timeout=10.0)
    return campaign, outcome


def score_models(campaign, preset: str = PRESET) -> list[dict]:
    """Each accepted yaw model against the simulator's linearisation at its training speed: signed
    errors in percent."""
    from companion.rehearsal.rehearsal import simulator_truth

    rows = []
    for attempt in campaign.accepted:
        if attempt.axis != "yaw":
            continue
        truth = simulator_truth(preset, attempt.speed) or {}
        model = attempt.model
        row = {"thrust": attempt.thrust, "speed": attempt.speed, "a22": model.a22, "b2": model.b2, "r2": attempt.r2,
               "true_a22": truth.get("a22"), "true_b2": truth.get("b2")}
        for key in ("a22", "b2"):
            true = row[f"true_{key}"]
            row[f"{key}_error_pct"] = (100.0 * (row[key] / true - 1.0)
                                       if isinstance(true, (int, float)) and true and math.isfinite(row[key]) else None)
        rows.append(row)
    return rows


def _native(gains: dict[str, float]) -> dict[str, float]:
    from companion.link.autopilots.sim import PROFILE

    return {PROFILE.native_param(name): PROFILE.to_native_value(name, value) for name, value in gains.items()}
