"""Run a behaviour over the vehicle link, safely (SPEC C1, C4 "abort at any time"; SPEC §4).

The runner is the only place where a behaviour meets I/O. Per telemetry snapshot it checks the
abort sources, feeds the snapshot to the behaviour and executes the returned commands. On any abort
— a signal or an abort request (``abort_requested``), a ground-station abort command, link loss,
the vehicle leaving its attitude/depth envelope, a refused parameter, or an exception — it asks
the behaviour to release what it holds and then puts the autopilot back as it was found: overrides
released, the original mode, the original gains (:class:`RestorePoint`).

Every timer here is vehicle time. The only wall-clock quantity is the link's silence watchdog
(inside ``VehicleLink.next_telemetry``), because a dead link stops the vehicle clock.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Callable, Protocol, Sequence

from companion.interface import Behavior, Command, SetParameters, Telemetry

log = logging.getLogger(__name__)


class AbortProcedure(Exception):
    """Raised inside the run loop to stop the behaviour and restore the vehicle."""


@dataclass(frozen=True)
class SafetyLimits:
    """The envelope a procedure must keep; leaving it aborts (defaults suit a small AUV)."""

    max_roll: float = math.radians(35.0)
    max_pitch: float = math.radians(35.0)
    max_depth: float = 50.0  # m
    min_depth: float = -1.0  # m (a surfaced vehicle may read slightly negative)
    max_nan_samples: int = 40  # consecutive snapshots without attitude before aborting

    def violation(self, telemetry: Telemetry) -> str | None:
        if math.isfinite(telemetry.roll) and abs(telemetry.roll) > self.max_roll:
            return f"roll {math.degrees(telemetry.roll):.1f} deg beyond {math.degrees(self.max_roll):.0f} deg"
        if math.isfinite(telemetry.pitch) and abs(telemetry.pitch) > self.max_pitch:
            return f"pitch {math.degrees(telemetry.pitch):.1f} deg beyond {math.degrees(self.max_pitch):.0f} deg"
        if math.isfinite(telemetry.depth) and not self.min_depth <= telemetry.depth <= self.max_depth:
            return f"depth {telemetry.depth:.2f} m outside [{self.min_depth}, {self.max_depth}] m"
        return None


class Link(Protocol):
    """What the runner needs from ``companion.link.vehicle.VehicleLink``."""

    def next_telemetry(self, timeout_s: float = ...) -> Telemetry: ...

    def execute(self, commands: Sequence[Command]) -> None: ...

    def get_params(self, neutral_names) -> dict: ...

    def set_params(self, neutral_values: dict) -> dict: ...

    def set_mode(self, neutral: str) -> None: ...

    def release(self, actuator: str | None = None) -> None: ...

    def status_text(self, text: str, severity: int = 6) -> None: ...


#: gains and trims a procedure may change; captured before it starts and restored on abort
RESTORED_PARAMETERS = ("heading_p", "heading_i", "rudder_trim")


@dataclass
class RestorePoint:
    """How the autopilot was found: mode and the parameters a procedure may touch."""

    mode: str | None
    parameters: dict[str, float] = field(default_factory=dict)

    @classmethod
    def capture(cls, link, parameter_names: Sequence[str] = RESTORED_PARAMETERS) -> "RestorePoint":
        mode = getattr(link, "mode", None) or None
        names = [n for n in parameter_names if n in getattr(getattr(link, "profile", None), "params", {n: n})]
        parameters = link.get_params(names) if names else {}
        return cls(mode=mode, parameters=dict(parameters))

    def restore(self, link) -> list[str]:
        """Release overrides, write the original parameters back, restore the mode.

        Each step is attempted even if an earlier one fails; the failures are returned (and logged)
        so the caller can report them — a restore must never stop half-way on the first error.
        """
        problems: list[str] = []
        for what, action in (
            ("release overrides", lambda: link.release(None)),
            ("restore parameters", lambda: self.parameters and link.set_params(self.parameters)),
            ("restore mode", lambda: self.mode and link.set_mode(self.mode)),
        ):
            try:
                action()
            except Exception as exc:  # noqa: BLE001 - every restore step must be tried
                log.error("%s failed: %s", what, exc)
                problems.append(f"{what}: {exc}")
        return problems


@dataclass
class RunOutcome:
    """What happened: ``completed`` or ``aborted`` (with the reason), plus the behaviour's result."""

    status: str
    reason: str | None
    result: dict
    restore_problems: list[str] = field(default_factory=list)
    samples: int = 0
    vehicle_time_s: float = 0.0


def run_behavior(
    link: Link,
    behavior: Behavior,
    *,
    limits: SafetyLimits = SafetyLimits(),
    abort_requested: Callable[[], str | None] = lambda: None,
    on_step: Callable[[Telemetry, Behavior], None] | None = None,
    restore: RestorePoint | None = None,
    restore_on_success: bool = False,
    telemetry_timeout_s: float = 5.0,
) -> RunOutcome:
    """Step ``behavior`` on every telemetry snapshot until it is done or an abort occurs.

    ``abort_requested`` is polled once per snapshot and returns a reason to abort (or None): the
    command line wires SIGINT/SIGTERM to it, the ground-station handler an abort command.
    ``on_step`` is called after each step (progress reports, store writes).
    """
    samples = 0
    first_time = last_time = math.nan
    nan_run = 0
    reason: str | None = None
    skip_to_now = getattr(link, "skip_to_now", None)
    if skip_to_now is not None:
        # snapshots queued during earlier blocking calls (a restore, a mode change) predate this
        # procedure: it must start from the vehicle as it is now (within a run, none is skipped)
        skip_to_now()
    try:
        while not behavior.done:
            telemetry = link.next_telemetry(timeout_s=telemetry_timeout_s)
            samples += 1
            if math.isnan(first_time):
                first_time = telemetry.time_s
            last_time = telemetry.time_s
            requested = abort_requested()
            if requested:
                raise AbortProcedure(requested)
            nan_run = 0 if telemetry.finite("roll", "pitch", "yaw") else nan_run + 1
            if nan_run > limits.max_nan_samples:
                raise AbortProcedure(f"no valid attitude for {nan_run} samples")
            violation = limits.violation(telemetry)
            if violation:
                raise AbortProcedure(f"safety limit: {violation}")
            link.execute(behavior.step(telemetry))
            if on_step is not None:
                on_step(telemetry, behavior)
    except AbortProcedure as exc:
        reason = str(exc)
    except KeyboardInterrupt:
        reason = "interrupted"
    except Exception as exc:  # noqa: BLE001 - link loss, refused parameter, bug: abort safely, then report
        log.exception("procedure failed")
        reason = f"{type(exc).__name__}: {exc}"
    problems: list[str] = []
    if reason is not None:
        log.warning("aborting: %s", reason)
        try:
            link.execute([c for c in behavior.abort(reason) if not isinstance(c, SetParameters)])
        except Exception as exc:  # noqa: BLE001 - the restore below still runs
            problems.append(f"behaviour abort: {exc}")
        if restore is not None:
            problems += restore.restore(link)
        _tell(link, f"aborted: {reason}", 4)
    elif restore is not None and restore_on_success:
        problems += restore.restore(link)
    return RunOutcome(
        status="aborted" if reason is not None else "completed",
        reason=reason,
        result=behavior.result(),
        restore_problems=problems,
        samples=samples,
        vehicle_time_s=0.0 if math.isnan(first_time) else last_time - first_time,
    )


def _tell(link, text: str, severity: int) -> None:
    try:
        link.status_text(text, severity)
    except Exception:  # noqa: BLE001 - a dead link cannot be told anything
        log.debug("could not send status text %r", text)
