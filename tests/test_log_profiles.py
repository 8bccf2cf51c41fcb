"""tlog decoding goes through the vehicle's autopilot profile (companion.link.profiles), not the
simulator's PWM mapping: the same SERVO_OUTPUT_RAW means different actuator values on ArduRover
and ArduSub than on the simulator."""
from __future__ import annotations

import json
import math
import struct

import numpy as np
import pytest

from companion.cli.main import main
from companion.link.profiles import ARDUROVER, ARDUSUB, SIM
from companion.records.logs import read_log, read_tlog
from harness.datasets import current_vector, synth_square

RUDDER_PWM, THRUST_PWM = 1600, 1300  # servo outputs 1 and 3; 1300 is astern on a centred throttle


def write_tlog(path, servo1: int = RUDDER_PWM, servo3: int = THRUST_PWM, seconds: float = 600.0) -> None:
    """A square under a known current as a tlog: SERVO_OUTPUT_RAW + ATTITUDE at 2 Hz and
    LOCAL_POSITION_NED at 1 Hz, each message after its 8-byte big-endian µs time stamp."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    d = synth_square(current_vector(0.01, 90.0), 4, dt=0.5)
    with open(path, "wb") as handle:
        for i, t in enumerate(d["t"]):
            if t > seconds:
                break
            ms = int(round(t * 1000))
            stamp = struct.pack(">Q", 1_700_000_000_000_000 + ms * 1000)
            msgs = [
                mavlink.MAVLink_servo_output_raw_message(ms * 1000, 0, servo1, 1500, servo3, 1500, 1500, 1500, 1500, 1500),
                mavlink.MAVLink_attitude_message(ms, d["roll"][i], d["pitch"][i], d["yaw"][i], 0.0, 0.0, 0.0),
            ]
            if i % 2 == 0:
                vn, ve, vd = d["vel_ned"][i]
                msgs.append(mavlink.MAVLink_local_position_ned_message(ms, d["north"][i], d["east"][i], d["down"][i],
                                                                       vn, ve, vd))
            for msg in msgs:
                handle.write(stamp + msg.pack(mav))


@pytest.fixture(scope="module")
def tlog(tmp_path_factory):
    path = tmp_path_factory.mktemp("tlog") / "run.tlog"
    write_tlog(path)
    return str(path)


def test_default_is_the_simulator_mapping(tlog):
    nav = read_tlog(tlog)
    assert nav.rudder == pytest.approx(np.full(len(nav), (RUDDER_PWM - 1500) / 500 * 0.5236))
    assert nav.thrust == pytest.approx(np.full(len(nav), (THRUST_PWM - 1000) / 1000))  # 0.3 ahead
    assert np.array_equal(read_tlog(tlog, SIM).thrust, nav.thrust)


def test_ardurover_decodes_the_centred_throttle(tlog):
    """Boats: throttle PWM 1500 is stop, 2000 full ahead; 1300 is 40 % astern (the sim reads 30 % ahead)."""
    nav = read_tlog(tlog, ARDUROVER)
    assert nav.thrust == pytest.approx(np.full(len(nav), (THRUST_PWM - 1500) / 500))
    assert nav.thrust[0] == pytest.approx(-0.4)
    assert nav.thrust[0] != pytest.approx(read_tlog(tlog).thrust[0])
    assert nav.rudder == pytest.approx(np.full(len(nav), (RUDDER_PWM - 1500) / 500 * ARDUROVER.angle_full_scale_rad))
    # by name, through read_log as the CLI calls it: the same result
    by_name = read_log(tlog, "ardurover")
    assert np.array_equal(by_name.thrust, nav.thrust) and np.array_equal(by_name.rudder, nav.rudder)


def test_ardusub_reads_no_fin_or_thrust_back(tlog):
    """ArduSub mixes thrusters: no servo output reports a fin angle or the thrust ratio, so the log
    has none (not the simulator's numbers); the navigation channels are unchanged."""
    assert ARDUSUB.servo_outputs == {}
    nav = read_tlog(tlog, ARDUSUB)
    assert nav.rudder is None and nav.thrust is None
    sim = read_tlog(tlog)
    assert np.array_equal(nav.u, sim.u) and np.array_equal(nav.yaw, sim.yaw)


def test_a_pwm_meaning_no_data_decodes_to_nan(tmp_path):
    path = tmp_path / "nodata.tlog"
    write_tlog(path, servo1=0, servo3=65535, seconds=20.0)
    nav = read_tlog(str(path))
    assert np.all(np.isnan(nav.rudder)) and np.all(np.isnan(nav.thrust))


def test_cli_profile_option(tlog, capsys):
    assert main(["analyze", "squares", "--input", tlog, "--profile", "ardurover", "--json"]) == 0
    result = json.loads(capsys.readouterr().out)
    assert math.isfinite(result["current_north"])
    with pytest.raises(SystemExit):
        main(["analyze", "squares", "--input", tlog, "--profile", "px4"])
