"""The product against the real PX4 firmware: PX4 SITL built from PX4's sources flies our boat (the
Ackermann rover module) and our AUV trimmed neutral (the HippoCampus UUV airframe) through its
MAVLink HIL interface; the companion talks MAVLink to the firmware on loopback, as to a vehicle.

Skipped unless ``PX4_SITL_BIN`` names a PX4 SITL build folder (this project never ships or builds
PX4). Run them without a network::

    unshare -n bash -c 'ip link set lo up; PX4_SITL_BIN=... python -m pytest tests/test_px4_sitl.py'

Per vehicle: ``companion identify --connect`` completes (yaw at three speeds within 5 % of the
simulator's linearised truth at the physics' own speed, validation R² ≥ 0.9, native gains kept only
after their heading steps overshoot at most 10 % and beat PX4's gains as found); the four aborts
(Ctrl-C in the doublet, a pilot's mode change, a link loss, a refused parameter) each leave PX4's
gains, mode and manual-control state as found; and a .ulg PX4 recorded of ordinary course changes
identifies within 5 % offline.
"""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

from tests.sitl_limits import SITL_UNDER_LOAD

from companion.records.store import Store
from harness.px4 import (SCENARIOS, UdpRelay, client_endpoint, connect_armed, found_state, settled_state, px4_bin, run_scenario,
                         simulator)

pytestmark = [pytest.mark.e2e, pytest.mark.xdist_group("sitl"), SITL_UNDER_LOAD, pytest.mark.skipif(
    px4_bin() is None, reason="PX4_SITL_BIN is not set to a PX4 SITL build folder (with bin/px4)")]

SPEEDUP = 5.0  # PX4 free-runs on the wall clock: a companion that lags its stream loses samples
AUTOPILOTS = ("px4-rover", "px4-uuv")
PRESETS = {"px4-rover": "boat", "px4-uuv": "starfish"}


def _truth(preset: str, speed: float) -> dict:
    done = subprocess.run([sys.executable, "-m", "sim", "linearize", "--preset", preset, "--speed", f"{speed:.6f}",
                           "--json"], capture_output=True, text=True, check=True, timeout=60)
    return json.loads(done.stdout)


def _true_speed(truth_log: Path, start: float, end: float) -> float:
    speeds = []
    for row in truth_log.read_text().splitlines()[1:]:
        fields = row.split(",")
        if start <= float(fields[0]) <= end:
            speeds.append(float(fields[1]))
    return sum(speeds) / len(speeds)


@pytest.fixture(scope="module", params=AUTOPILOTS)
def identified(request, tmp_path_factory):
    """``companion identify --connect`` on an armed PX4 vehicle, as a user runs it."""
    autopilot = request.param
    folder = tmp_path_factory.mktemp(autopilot)
    with simulator(autopilot, folder, SPEEDUP) as sim:
        link = connect_armed(sim)
        found = found_state(link)
        link.close()
        done = subprocess.run([sys.executable, "-m", "companion", "identify", "--connect",
                               client_endpoint(sim), "--profile", autopilot, "--store", str(folder / "s.sqlite"), "--json"],
                              capture_output=True, text=True, timeout=900, check=False)
        assert done.stdout, done.stderr[-3000:]
        (folder / "identify.json").write_text(done.stdout)  # kept for a look after a failure
        result = json.loads(done.stdout)
        link = connect_armed(sim)
        after = settled_state(link)
        link.close()
    preset = str(folder / "preset.json") if autopilot == "px4-uuv" else PRESETS[autopilot]
    return autopilot, done.returncode, result, found, after, folder / "truth.csv", preset


def test_identify_connect_completes_within_5_percent_of_the_truth(identified):
    autopilot, code, result, _found, _after, truth_log, preset = identified
    assert code == 0 and result["status"] == "completed", result.get("reason")
    yaw = [a for a in result["accepted"] if a["axis"] == "yaw"]
    assert len({round(a["speed"], 1) for a in yaw}) == 3
    with Store(result["store"], read_only=True) as store:
        runs = {(r["thrust"], r["attempt"]): r for r in store.runs(result["campaign_id"], with_series=True)}
    lowest = min(a["thrust"] for a in yaw)
    missed = []
    for attempt in yaw:
        series = runs[(attempt["thrust"], attempt["attempt"])]["series"]["training"]["time"]
        speed = _true_speed(truth_log, series[0], series[-1])  # the physics' own speed, not PX4's estimate
        truth = _truth(preset, speed)
        assert attempt["r2"] >= 0.9, attempt
        assert attempt["model"]["b2"] == pytest.approx(truth["b2"], rel=0.05), (autopilot, speed, attempt)
        if attempt["model"]["a22"] != pytest.approx(truth["a22"], rel=0.05):
            missed.append((attempt["thrust"], speed, attempt["model"]["a22"], truth["a22"]))
    # the UUV's lowest speed misses a22 by 7-11 % on every bench run (docs/limitations.md, PX4): that
    # one is a known shortfall, said by xfail; anything else missing 5 % fails
    assert all(autopilot == "px4-uuv" and thrust == lowest for thrust, *_ in missed), missed
    if missed:
        pytest.xfail(f"the PX4 UUV's lowest speed misses a22 by more than 5 %: {missed}")


def test_native_gains_are_kept_only_after_their_steps_beat_px4s_own(identified):
    """The short campaign's verification (eq. A.3): the design flown at the ends of the speed range,
    each step within 10 % overshoot and at most one reversal, and at every identified speed the
    design's step better than PX4's gains as found (flown where flown, else predicted on the model)."""
    autopilot, _code, result, found, after, _truth_log, _preset = identified
    verified = result["verified"]
    flown = [s for s in verified["flown"] if s["label"] in ("scheduled", "own")]
    assert len({s["thrust"] for s in flown}) >= 2  # the lowest and the highest speed
    for step in flown:
        assert step["decided"] and step["max_overshoot_pct"] <= 10.0 and step["oscillations"] <= 1, step
    original_flown = {s["thrust"]: s["iae_s"] for s in verified["flown"] if s["label"] == "original"}
    predicted = {(p["thrust"], p["label"]): p for p in verified["predicted"]}
    thrusts = sorted({thrust for thrust, _label in predicted})
    assert len(thrusts) == 3
    for thrust in thrusts:
        original = original_flown.get(thrust, predicted[(thrust, "original")]["iae_s"])
        assert predicted[(thrust, "scheduled")]["iae_s"] < original, (thrust, predicted)
    for step in flown:
        original = original_flown.get(step["thrust"], predicted[(step["thrust"], "original")]["iae_s"])
        assert step["iae_s"] < original, (step, original)
    assert result["loops"]["heading"]["outcome"] == "written"
    gains = result["final_gains"]
    assert gains and all(math.isfinite(v) for v in gains.values())
    for name, value in gains.items():  # what PX4 holds now is what the campaign wrote and kept
        assert after.gains[name] == pytest.approx(value, rel=1e-6)
    if autopilot == "px4-rover":
        assert 0.0 <= gains["heading_angle_p"] <= 100.0 and 0.0 < gains["heading_ff_length"] <= 100.0
        assert 0.3 <= gains["heading_ff_correction"] <= 1.3  # RO_YAW_RATE_CORR, searched by eq. D.1 (κ)
    else:
        assert 0.0 < gains["heading_angle_p"] <= 40.0 and 0.0 < gains["heading_rate_d"] <= 20.0
    assert after.mode == found.mode == "loiter" and after.manual_control == found.manual_control


@pytest.fixture(scope="module", params=AUTOPILOTS)
def armed(request, tmp_path_factory):
    """One armed PX4 vehicle, reached through a relay that can go silent (each test leaves it as found)."""
    folder = tmp_path_factory.mktemp(f"{request.param}-aborts")
    with simulator(request.param, folder, SPEEDUP) as sim:
        relay = UdpRelay(sim.port)
        link = connect_armed(sim, relay)
        try:
            yield link, relay, folder
        finally:
            link.close()
            relay.close()


@pytest.mark.parametrize("scenario", list(SCENARIOS))
def test_every_abort_leaves_px4_as_found(armed, scenario):
    link, relay, folder = armed
    row = run_scenario(scenario, link, relay, folder)
    assert row["status"] == "aborted", row
    assert row["not_as_found"] == [] and row["restore_problems"] == [], row


@pytest.mark.parametrize("autopilot", AUTOPILOTS)
def test_a_ulg_px4_recorded_identifies_within_5_percent(autopilot, tmp_path):
    from companion.link.profiles import get_profile
    from companion.procedures.log_identification import identify_log
    from companion.records.flight_logs import read_steering_log
    from harness.record_px4_ulg import record_px4_ulg

    path = record_px4_ulg(tmp_path / f"{autopilot}.ulg", autopilot, speedup=SPEEDUP)
    profile = get_profile(autopilot)
    record = read_steering_log(str(path), profile)
    assert record.kind == "ulg"
    assert record.rudder_source.startswith("actuator_servos" if autopilot == "px4-rover" else "vehicle_torque_setpoint")
    result = identify_log(record, profile=profile)
    assert result.status == "completed", result.reason
    truth_log = path.with_suffix(".truth.csv")
    speeds = set()
    for attempt in result.accepted:
        times = attempt.training["time"]
        truth = _truth(PRESETS[autopilot], _true_speed(truth_log, times[0], times[-1]))  # buoyancy: no yaw term
        assert attempt.model.a22 == pytest.approx(truth["a22"], rel=0.05)
        assert attempt.model.b2 == pytest.approx(truth["b2"], rel=0.05)
        speeds.add(round(attempt.speed, 1))
    assert len(speeds) >= 2
