"""Ordinary missions flown on the simulator, for the log identification and health monitoring
tests and bench: course changes by the autopilot's own heading hold at a few thrusts,
never a doublet.

* :class:`SurveyPlan` — a survey pattern as a pure function of vehicle time: at each thrust a
  straight settle, then legs of ``leg_s`` seconds, each starting with a course change taken in turn
  from ``course_changes_deg`` (a zig-zag around the base course).
* :func:`record_survey_tlog` — starts the simulator (``python -m sim run`` through the companion's
  launcher, lockstep), flies the plan over MAVLink with :class:`companion.link.vehicle.VehicleLink`
  in the holding mode and saves everything the vehicle sent as a tlog (pymavlink's ``logfile``:
  each message after its 8-byte time stamp), exactly what a ground station records.
"""
from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from pathlib import Path

from companion.interface import SetDepth, SetHeading, SetThrust

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class SurveyPlan:
    """Thrust and course set-points over vehicle time (see the module docstring)."""

    thrusts: tuple[float, ...] = (0.6, 0.8, 1.0)
    seconds_per_thrust: float = 240.0
    settle_s: float = 30.0  # straight after each thrust change (the speed settles)
    leg_s: float = 30.0
    course_changes_deg: tuple[float, ...] = (30.0, -45.0, 20.0, -30.0, 40.0, -15.0)
    depth: float | None = 2.0  # None: no depth set-point (a boat)
    base_course_deg: float = 0.0
    # None: each course change is a step; else the course set-point turns at this rate (a vehicle
    # whose thrusters also steer loses forward thrust when a step saturates its yaw torque)
    turn_rate_deg_s: float | None = None

    @property
    def duration_s(self) -> float:
        return self.seconds_per_thrust * len(self.thrusts)

    def setpoints(self, t: float) -> tuple[float, float]:
        """(thrust ratio, course in rad) at ``t`` seconds since the start of the plan."""
        index = min(int(t // self.seconds_per_thrust), len(self.thrusts) - 1)
        local = t - index * self.seconds_per_thrust
        legs = 0 if local < self.settle_s else 1 + int((local - self.settle_s) // self.leg_s)
        # the course carries on from the previous thrust's last leg (no jump at a thrust change)
        per_thrust = 1 + int(max(0.0, self.seconds_per_thrust - self.settle_s - 1e-9) // self.leg_s)
        done = index * per_thrust + legs
        cycle = self.course_changes_deg
        course = self.base_course_deg + sum(cycle[i % len(cycle)] for i in range(done))
        if self.turn_rate_deg_s is not None and done > 0:  # the latest change, taken at the turn rate
            changed_at = index * self.seconds_per_thrust + (self.settle_s + (legs - 1) * self.leg_s if legs else 0.0)
            change = cycle[(done - 1) % len(cycle)]
            remaining = abs(change) - self.turn_rate_deg_s * (t - changed_at)
            if legs and remaining > 0.0:
                course -= math.copysign(remaining, change)
        return self.thrusts[index], math.radians(course)


def fly_plan(link, plan: SurveyPlan, start_s: float | None = None, until_s: float | None = None,
             on_telemetry=None) -> float:
    """Fly ``plan`` over ``link`` in the holding mode until its end (or ``until_s`` seconds of it);
    ``on_telemetry(telemetry)`` sees every snapshot. Returns the vehicle time of the start."""
    telemetry = link.next_telemetry()
    start = telemetry.time_s if start_s is None else start_s
    end = plan.duration_s if until_s is None else until_s
    last: tuple[float, float] | None = None
    while True:
        t = telemetry.time_s - start
        if t >= end:
            return start
        setpoint = plan.setpoints(t)
        if setpoint != last:
            commands = [SetThrust(setpoint[0]), SetHeading(setpoint[1])]
            if last is None and plan.depth is not None:
                commands.insert(0, SetDepth(plan.depth))
            link.execute(commands)
            last = setpoint
        if on_telemetry is not None:
            on_telemetry(telemetry)
        telemetry = link.next_telemetry()


def record_survey_tlog(path: str | Path, plan: SurveyPlan = SurveyPlan(), *, preset: str = "starfish", seed: int = 1,
                       speedup: float = 0.0, extra_args: tuple[str, ...] = ()) -> Path:
    """Fly ``plan`` on the simulator (lockstep, ``speedup`` 0 = as fast as it goes) and save the tlog."""
    from companion.rehearsal.launcher import SimulatorProcess
    from companion.link.vehicle import VehicleLink

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with SimulatorProcess(preset=preset, speedup=speedup, seed=seed, lockstep=True,
                          extra_args=list(extra_args)) as sim:
        link = VehicleLink.connect(sim.endpoint, lockstep=True)
        logfile = link.transport.record_to(str(path))
        try:
            link.arm(True)
            link.set_mode("hold")
            fly_plan(link, plan)
        finally:
            link.close()
            if logfile is not None and not logfile.closed:
                logfile.close()
    log.info("recorded %s (%.0f s of vehicle time)", path, plan.duration_s)
    return path
