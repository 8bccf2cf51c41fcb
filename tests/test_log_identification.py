"""Identification from recorded missions: tlog from our simulator (ordinary course
changes by the autopilot's heading hold, no doublet), ArduPilot DataFlash .bin, PX4 .ulg and CSV
fixtures written here, the segment verdicts, the unit checks, the command line and the store."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from companion.cli.main import main
from companion.numerics.segments import SegmentRules, find_segments
from companion.procedures.log_identification import identify_log
from companion.records.flight_logs import LogError, read_steering_log
from companion.records.report import write_report
from companion.records.store import Store
from harness.dataflash_writer import DataFlashWriter
from harness.missions import SurveyPlan, record_survey_tlog
from harness.steering_data import SteeringTruth, synth_steering
from harness.ulog_writer import write_ulog
from sim.linearize import linearized_yaw
from sim.preset import load_preset

TRUTH = SteeringTruth(a22=-1.1, b2=1.0, delta0=0.01)
#: 2 thrusts × 180 s of the survey pattern: settle, then a course change every 30 s (one of 45°,
#: which saturates the rudder), a thrust change between them (≈ 9 s of wall time at full speed)
PLAN = SurveyPlan(thrusts=(0.6, 1.0), seconds_per_thrust=180.0)


def _strict(text: str):
    def refuse(constant):
        raise ValueError(f"non-strict JSON constant {constant}")
    return json.loads(text, parse_constant=refuse)


@pytest.fixture(scope="module")
def survey_tlog(tmp_path_factory):
    return str(record_survey_tlog(tmp_path_factory.mktemp("survey") / "survey.tlog", PLAN, seed=4))


def test_simulator_tlog_gives_the_live_models(survey_tlog):
    """Done-when: a tlog of ordinary manoeuvres gives yaw models within 5 % of the vehicle's
    (the live campaign identifies within ~2 % of this truth: README, bench_identification)."""
    record = read_steering_log(survey_tlog)
    assert record.kind == "tlog" and record.speed_source.startswith("VFR_HUD.airspeed")
    result = identify_log(record)
    preset = load_preset("starfish")
    reasons = [s.segment.reason for s in result.segments]
    assert any(r.startswith("speed not steady") for r in reasons)  # the thrust change
    speeds = set()
    for attempt in result.accepted:
        truth = linearized_yaw(preset, attempt.speed)
        assert attempt.model.a22 == pytest.approx(truth["a22"], rel=0.05)
        assert attempt.model.b2 == pytest.approx(truth["b2"], rel=0.05)
        assert attempt.model.delta0 == pytest.approx(truth["delta0"], abs=0.002)
        assert attempt.r2 > 0.9
        speeds.add(round(attempt.speed, 1))
    assert len(speeds) == 2 and len(result.accepted) >= 4
    assert result.status == "completed" and "heading" in result.designs


def test_command_line_stores_a_log_campaign(survey_tlog, tmp_path, capsys):
    store_path = str(tmp_path / "store.sqlite")
    assert main(["identify", "--log", survey_tlog, "--store", store_path, "--json"]) == 0
    out = _strict(capsys.readouterr().out)
    assert out["status"] == "completed" and out["gains_written"] is None
    assert out["export"].endswith(f"--campaign {out['campaign_id']} --export gains.parm")  # how to hand them on
    assert {"checks", "rudder_source", "speed_source"} <= set(out["log"])
    used = [s for s in out["segments"] if s["number"] is not None]
    assert all(s["validated_on"] not in (None, s["number"]) for s in used)
    with Store(store_path, read_only=True) as store:
        campaign = store.campaign(out["campaign_id"])
        assert campaign["kind"] == "log" and campaign["status"] == "completed"
        runs = store.runs(out["campaign_id"])
        assert len(runs) == len(used)
        assert len(store.models(out["campaign_id"], "yaw")) == len(out["accepted"])
        assert [d.kind for d in store.designs(out["campaign_id"])] == ["heading"]
        assert store.behavior_results(out["campaign_id"], "log_segments")
    assert main(["identify", "--store", store_path]) == 2  # neither --connect nor --log


# --------------------------------------------------------------------------- segments
def test_segment_verdicts():
    """Each reason a segment is not used: a gap, an unsteady speed, a saturated actuator, a straight leg."""
    d = synth_steering(480.0, speed=lambda t: 1.5 if t < 240 or t > 300 else 1.5 + 0.01 * (t - 240))
    t, heading, rudder, speed = d["t"], d["heading"], d["rudder"].copy(), d["speed"]
    heading = heading.copy()
    heading[(t > 100) & (t < 102)] = np.nan  # a gap
    rudder[(t > 130) & (t < 180)] = np.clip(rudder[(t > 130) & (t < 180)] * 8, -0.35, 0.35)  # saturated
    straight = (t >= 420)
    rudder[straight] = TRUTH.delta0
    heading[straight] = 0.3
    segments = find_segments(t, heading, rudder, speed, rudder_limit=0.35, rules=SegmentRules())
    reasons = [s.reason.split(":")[0] for s in segments]
    for expected in ("gap in the data", "actuator saturated", "speed not steady", "too little excitation", "used"):
        assert expected in reasons, (expected, reasons)
    gap = next(s for s in segments if s.reason.startswith("gap"))
    assert 99.0 < gap.t_start < 101.0 and 101.5 < gap.t_end < 103.0


# --------------------------------------------------------------------------- other formats
def _check_truth(result, tolerance=0.03):
    assert len(result.accepted) >= 2
    for attempt in result.accepted:
        assert attempt.model.a22 == pytest.approx(TRUTH.a22, rel=tolerance)
        assert attempt.model.b2 == pytest.approx(TRUTH.b2, rel=tolerance)


@pytest.fixture(scope="module")
def synthetic():
    return synth_steering(180.0, truth=TRUTH, seed=2)


def test_ulog_fixture(synthetic, tmp_path):
    """A PX4 .ulg (written by harness/ulog_writer.py): quaternion attitude, normalised yaw control,
    local velocity; the model and the report (a log without thrust)."""
    d, full = synthetic, 0.5236
    us = (d["t"] * 1e6).astype(int) + 10_000
    attitude = [(u, math.cos(y / 2), 0.0, 0.0, math.sin(y / 2)) for u, y in zip(us, d["heading"])]
    controls = [(u, 0.0, 0.0, r / full, 0.0) for u, r in zip(us, d["rudder"])]
    velocity = [(u, s * math.cos(y), s * math.sin(y)) for u, s, y in zip(us[::2], d["speed"][::2], d["heading"][::2])]
    path = write_ulog(tmp_path / "px4.ulg", {
        "vehicle_attitude": ([("uint64_t", "timestamp"), ("float[4]", "q")], attitude),
        "actuator_controls_0": ([("uint64_t", "timestamp"), ("float[4]", "control")], controls),
        "vehicle_local_position": ([("uint64_t", "timestamp"), ("float", "vx"), ("float", "vy")], velocity)})
    record = read_steering_log(str(path), rudder_full_scale=full)
    assert record.kind == "ulg" and record.rudder_source.startswith("actuator_controls_0.control[2]")
    assert record.speed == pytest.approx(1.5, abs=1e-4)
    result = identify_log(record)
    _check_truth(result)
    with Store(tmp_path / "s.sqlite") as store:
        from companion.procedures.log_identification import LogIdentificationConfig, store_log_identification

        campaign_id = store_log_identification(store, result, LogIdentificationConfig(), "sim")
        report = write_report(store, campaign_id, tmp_path / "report")
    assert (tmp_path / "report" / "convergence.png").exists() and report.exists()


def _dataflash(d, path, yaw_scale=1.0, time_scale=1e6, yaw_format="C"):
    w = DataFlashWriter()
    for ident, label in (("s", "s"), ("d", "deg"), ("n", "m/s"), ("Y", "PWM"), ("-", "")):
        w.unit(ident, label)
    w.mult("F", 1e-6)
    w.mult("0", 1.0)
    w.define("PARM", "QNf", "TimeUS,Name,Value")
    w.define("ATT", f"Qcc{yaw_format}", "TimeUS,Roll,Pitch,Yaw", units="sddd", mults="F000")
    w.define("RCOU", "QHHHH", "TimeUS,C1,C2,C3,C4", units="sYYYY", mults="F0000")
    w.define("GPS", "QBf", "TimeUS,I,Spd", units="s-n", mults="F00")
    for name, value in (("SERVO3_FUNCTION", 26.0), ("SERVO3_TRIM", 1500.0), ("SERVO3_MIN", 1100.0),
                        ("SERVO3_MAX", 1900.0)):
        w.write("PARM", 0, name, value)
    for k, t in enumerate(d["t"]):
        stamp = int(t * time_scale) + 5000
        w.write("ATT", stamp, 0.0, 0.0, (math.degrees(d["heading"][k]) % 360.0) * yaw_scale)
        w.write("RCOU", stamp + 100, 1500, 1500, int(round(1500 + 400 * d["rudder"][k] / 0.5236)), 1500)
        if k % 4 == 0:
            w.write("GPS", stamp + 200, 0, d["speed"][k])
    return str(w.save(path))


def test_dataflash_fixture(synthetic, tmp_path):
    """An ArduPilot .bin: ATT in degrees (FMTU unit), the steering output found by SERVOn_FUNCTION 26
    in the PARM messages and scaled by its min/trim/max, GPS speed."""
    record = read_steering_log(_dataflash(synthetic, tmp_path / "rover.bin"), "ardurover")
    assert record.kind == "bin" and record.rudder_source.startswith("RCOU C3")
    assert any("degrees" in c for c in record.checks)
    _check_truth(identify_log(record, profile=None))
    short = {k: v[:600] for k, v in synthetic.items()}  # 30 s are enough for the unit checks
    centi = read_steering_log(_dataflash(short, tmp_path / "centi.bin", yaw_scale=100.0, yaw_format="f"), "ardurover")
    assert any("centidegrees" in c for c in centi.checks)
    assert centi.heading == pytest.approx(record.heading[:600], abs=1e-4)
    with pytest.raises(LogError, match="not a time in seconds"):  # TimeUS written in milliseconds
        read_steering_log(_dataflash(short, tmp_path / "ms.bin", time_scale=1e3), "ardurover")


def test_csv_and_unit_refusals(synthetic, tmp_path):
    d = synthetic
    path = tmp_path / "log.csv"
    rows = ["t,yaw,rudder,speed"] + [f"{t:.3f},{y:.6f},{r:.6f},{s:.4f}"
                                     for t, y, r, s in zip(d["t"], d["heading"], d["rudder"], d["speed"])]
    path.write_text("\n".join(rows) + "\n")
    _check_truth(identify_log(read_steering_log(str(path))))
    degrees = tmp_path / "degrees.csv"
    degrees.write_text("\n".join(["t,yaw,rudder,speed"] + [f"{t:.3f},{math.degrees(np.unwrap(d['heading'])[i]):.4f},"
                                                           f"{d['rudder'][i]:.6f},1.5" for i, t in enumerate(d["t"])]))
    with pytest.raises(LogError, match="degrees"):
        read_steering_log(str(degrees))


def test_tlog_servo_clock_that_wraps(tmp_path):
    """SERVO_OUTPUT_RAW.time_usec is a uint32 that wraps after 71.6 min: a tlog crossing the wrap keeps
    its rudder paired with the attitude (the lap nearest the attitude's clock)."""
    import struct

    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    d = synth_steering(60.0, truth=TRUTH, seed=3)
    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    offset_ms = 4_270_000  # the wrap (4294.967 s) falls 25 s into the record
    with open(tmp_path / "late.tlog", "wb") as handle:
        for k, t in enumerate(d["t"]):
            ms = offset_ms + int(round(t * 1000))
            pwm = int(round(1500 + d["rudder"][k] / 0.5236 * 500))
            for msg in (mavlink.MAVLink_servo_output_raw_message((ms * 1000) % 2 ** 32, 0, pwm, 1500, 1700, 1500,
                                                                  1500, 1500, 1500, 1500),
                        mavlink.MAVLink_attitude_message(ms, 0.0, 0.0, d["heading"][k], 0.0, 0.0, 0.0),
                        mavlink.MAVLink_vfr_hud_message(1.5, 1.5, 0, 70, 0.0, 0.0)):
                handle.write(struct.pack(">Q", 1_700_000_000_000_000 + ms * 1000) + msg.pack(mav))
    record = read_steering_log(str(tmp_path / "late.tlog"))
    assert record.t[0] == pytest.approx(offset_ms / 1000.0)
    assert record.rudder == pytest.approx(d["rudder"], abs=0.0011)  # 1 µs of PWM
