"""The simulator's autopilot logic and parameter table without sockets (sim/autopilot.py,
sim/params.py), plus the ``python -m sim`` command line's non-serving subcommands."""
from __future__ import annotations

import json
import math
import subprocess
import sys

import pytest

from companion.rehearsal.launcher import parse_ready
from sim.autopilot import (
    MODE_ALT_HOLD,
    MODE_GUIDED,
    MODE_MANUAL,
    Autopilot,
    Result,
    fin_from_pwm,
    pwm_from_fin,
)
from sim.params import ParamTable
from sim.preset import load_preset
from sim.vehicle import Vehicle

DT = 0.01


def make(seed: int = 0) -> Autopilot:
    preset = load_preset("starfish")
    return Autopilot(Vehicle(preset, seed=seed), ParamTable.for_preset(preset))


def run(ap: Autopilot, seconds: float) -> None:
    for _ in range(int(round(seconds / DT))):
        ap.step(DT)


def test_param_validation():
    table = ParamTable.for_preset(load_preset("starfish"))
    assert table["HDG_P"] == pytest.approx(0.64)
    assert table.set("HDG_P", 1.5).accepted and table["HDG_P"] == 1.5
    for bad in (float("nan"), float("inf"), -1.0, 1e9):
        result = table.set("HDG_P", bad)
        assert not result.accepted and result.value == 1.5 and table["HDG_P"] == 1.5
    unknown = table.set("NOPE", 1.0)
    assert not unknown.accepted and unknown.value is None
    assert table.set("SYSID_MYGCS", 254.6).value == 255.0  # integers are cast (rounded)
    assert table.name_at(table.index("RC_OVR_TIME")) == "RC_OVR_TIME"
    assert table.name_at(len(table)) is None


def test_disarmed_outputs_zero_thrust_and_centred_fins():
    ap = make()
    ap.set_mode(MODE_ALT_HOLD)
    run(ap, 1.0)
    assert ap.demand.thrust_ratio == 0.0 and ap.demand.rudder == 0.0 and ap.demand.elevator == 0.0


def test_entering_hold_captures_heading_depth_and_cruise_thrust():
    ap = make()
    ap.arm(True)
    ap.vehicle.yaw = 1.0
    assert ap.set_mode(MODE_ALT_HOLD) == Result.ACCEPTED
    assert ap.heading_setpoint == pytest.approx(1.0)
    assert ap.depth_setpoint == pytest.approx(5.0)
    assert ap.thrust_setpoint == pytest.approx(0.70)
    assert ap.set_mode(99) == Result.FAILED and ap.mode == MODE_ALT_HOLD


def test_heading_hold_turns_to_setpoint_and_holds_depth():
    ap = make()
    ap.arm(True)
    ap.set_mode(MODE_GUIDED)
    assert ap.set_heading(math.radians(60)) == Result.ACCEPTED
    run(ap, 60.0)
    assert math.degrees(ap.vehicle.state.yaw) == pytest.approx(60, abs=2)
    assert ap.vehicle.depth == pytest.approx(5.0, abs=0.2)


def test_rudder_override_is_open_loop_per_channel_and_expires_in_vehicle_time():
    ap = make()
    ap.arm(True)
    ap.set_mode(MODE_ALT_HOLD)
    run(ap, 5.0)
    assert ap.rc_override(255, [pwm_from_fin(0.2), 65535, 65535])
    run(ap, 2.0)
    assert ap.demand.rudder == pytest.approx(fin_from_pwm(pwm_from_fin(0.2)))
    assert ap.vehicle.yaw_rate > 0.05
    assert not ap.overridden(2)  # the elevator stays with the depth loop
    run(ap, 1.5)  # 3.5 s after the last refresh > RC_OVR_TIME = 3 s
    assert not ap.overridden(1)
    assert ap.demand.rudder < 0.1


def test_override_refused_from_other_system_and_ignored_in_guided():
    ap = make()
    ap.arm(True)
    ap.set_mode(MODE_ALT_HOLD)
    assert not ap.rc_override(100, [1800, 1800, 1800])
    assert not ap.overridden(1)
    ap.set_mode(MODE_GUIDED)
    assert ap.rc_override(255, [1800, 65535, 65535])
    run(ap, 0.5)
    assert ap.demand.rudder < 0.2  # GUIDED ignores RC
    ap.rc_override(255, [0, 65535, 65535])
    assert not ap.overridden(1)


def test_manual_mode_from_rc_and_setpoints_refused():
    ap = make()
    ap.arm(True)
    ap.set_mode(MODE_MANUAL)
    run(ap, 0.1)
    assert ap.demand.thrust_ratio == 0.0  # no RC: zero thrust
    ap.rc_override(255, [1500, 1500, 1650])
    run(ap, 0.1)
    assert ap.demand.thrust_ratio == pytest.approx(0.65)
    assert ap.set_thrust(0.5) == Result.TEMPORARILY_REJECTED


def test_set_servo_rules_and_live_parameters():
    ap = make()
    assert ap.set_servo(1, 1700) == Result.DENIED
    assert ap.set_servo(9, 2000) == Result.ACCEPTED
    assert ap.mass_angle_demand == pytest.approx(0.349)  # clamped to MASS_MAX
    assert ap.set_param("MASS_SERVO", 10).accepted
    assert ap.set_servo(10, 1500) == Result.ACCEPTED and ap.mass_angle_demand == 0.0
    assert ap.set_param("RUD_MAX", 0.2).accepted and ap.vehicle.limits.rudder_max == 0.2
    assert ap.set_param("HDG_P", 2.0).accepted and ap.heading_pi.kp == 2.0
    assert ap.set_param("SIM_CUR_VN", 0.3).accepted and ap.vehicle.current_north == 0.3
    assert ap.set_param("SIM_ROLL_KICK", 10.0).value == 10.0
    assert ap.vehicle.roll == pytest.approx(math.radians(10)) and ap.params["SIM_ROLL_KICK"] == 0.0


def _cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "sim", *args], capture_output=True, text=True,
                          timeout=60)


def test_cli_presets_and_linearize():
    presets = _cli("presets")
    assert presets.returncode == 0 and "starfish" in presets.stdout.split()
    lin = _cli("linearize", "--preset", "starfish", "--speed", "1.4", "--json")
    truth = json.loads(lin.stdout)
    assert set(truth) >= {"a22", "b2", "delta0", "speed"} and truth["speed"] == 1.4
    assert truth["a22"] < 0 < truth["b2"]


def test_cli_run_duration_exits_cleanly():
    done = _cli("run", "--listen", "udpin:127.0.0.1:0", "--speedup", "0", "--duration", "5")
    assert done.returncode == 0, done.stderr
    assert done.stdout.count("\n") == 1  # one line on stdout, with the port the OS gave
    # the line the companion's launcher waits for (its parser is the only one)
    assert parse_ready(done.stdout) is not None
    kind, host, port = parse_ready(done.stdout)
    assert (kind, host) == ("udpin", "127.0.0.1") and port > 0
