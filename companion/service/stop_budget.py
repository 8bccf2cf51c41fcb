"""How long a stop may take: the worst case of aborting a procedure and restoring the vehicle.

systemd stops the service with one SIGTERM and kills it ``TimeoutStopSec`` later; a kill in the
middle of a restore leaves the vehicle half restored, so ``deploy/marine-companion.service`` must
give more than this. The restore (``companion.procedures.restore.RestorePoint.restore``) tries each
item up to ``RESTORE_TRIES`` times and never stops half-way; the worst case here is a live link at
1× (telemetry flows, so every wait lasts its full vehicle time) on which every answer to the
restore's requests is lost or overtaken, each item failing all its tries:

* noticing the stop: the runner reads the abort flag once per snapshot (at most the telemetry
  timeout without one), and a parameter write under way finishes first;
* releasing the overrides (through the autopilot's strategy: on ArduRover a mode change);
* each parameter: a read and a write (``_write_if_changed``), each of ``PARAM_RETRIES`` tries;
* the parameters read again once what was in flight has landed (``CONFIRM_VEHICLE_S`` and three
  command tries of wall clock), each written back once more if a late write changed it;
* each set-point put back: acknowledged (three command periods), then confirmed by the vehicle's
  state (up to ``CONFIRM_TIMEOUT_S``), sent again when overtaken (``CONFIRM_RESENDS`` times);
* the mode (its tries of one command period each);
* after the procedure, the resident loop writes back the gains that were in place before it
  started scheduling (each one a read and a write, as above).

On a silent link each try ends at the wall-clock guard instead (``LinkTimeouts.wall_guard_s``),
but nothing can be restored there: waiting longer only delays the stop, and the autopilot takes
its RC channels back by itself after ``RC_OVERRIDE_TIME``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from companion.link.clock import LinkTimeouts
from companion.procedures.restore_items import CONFIRM_RESENDS, CONFIRM_TIMEOUT_S, CONFIRM_VEHICLE_S, RESTORE_TRIES

#: tries of one parameter read or write (``ParameterChannel.get_param/set_param``'s default)
PARAM_RETRIES = 3
#: command periods a set-point is awaited (``CommandChannel.await_setpoints``)
SETPOINT_PERIODS = 3
#: the runner's telemetry timeout (``run_procedure``'s default), seconds without a snapshot
TELEMETRY_TIMEOUT_S = 5.0


@dataclass(frozen=True)
class StopBudget:
    """Seconds per part of a stop (module docstring) and their sum."""

    parts: dict[str, float]

    @property
    def total_s(self) -> float:
        return sum(self.parts.values())


def stop_budget(parameters: int, scheduled: int, setpoints: int = 2, timeouts: LinkTimeouts = LinkTimeouts(),
                tries: int = RESTORE_TRIES) -> StopBudget:
    """The worst case of a stop (module docstring) for a procedure declaring ``parameters`` native
    parameters and ``setpoints`` set-points, with ``scheduled`` scheduled gains to give back."""
    param_try = max(timeouts.param_try_s, timeouts.min_try_wall_s)  # at 1×, vehicle time = wall time
    command_try = max(timeouts.command_s, timeouts.min_try_wall_s)
    mode_change = max(int(math.ceil(timeouts.mode_s / timeouts.command_s)), 1) * command_try
    write_back = 2 * PARAM_RETRIES * param_try
    setpoint = (1 + CONFIRM_RESENDS) * (SETPOINT_PERIODS * command_try + CONFIRM_TIMEOUT_S)
    return StopBudget({
        "notice the stop": TELEMETRY_TIMEOUT_S + write_back,
        "release the overrides": tries * mode_change,
        "parameters": parameters * tries * write_back,
        "parameters read again": tries * (CONFIRM_VEHICLE_S + 3 * command_try + parameters * write_back),
        "set-points": setpoints * tries * setpoint,
        "mode": tries * mode_change,
        "scheduled gains": scheduled * tries * write_back,
    })
