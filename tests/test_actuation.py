"""A boat's actuation read from the vehicle: which outputs steer and drive it (SERVOn_FUNCTION), the
skid-steered pair un-mixed exactly (ArduRover's mixer, its output scaling and thrust curve run
forward here and inverted by the product), the refusals a user can act on, the snapshot fields, the
ArduRover strategy's configuration and its doublet kept inside a skid mixer's room."""
from __future__ import annotations

import itertools
import math
from dataclasses import replace
from types import SimpleNamespace

import pytest

from companion.interface import Telemetry
from companion.link.actuation import Actuation, OutputScale, actuation_from_functions, actuation_from_params
from companion.link.autopilots.ardurover import PROFILE as ROVER
from companion.link.autopilots.ardurover import Strategy as RoverStrategy
from companion.link.autopilots.skid_room import SKID_THRUSTS, doublet_scale, scaled
from companion.link.errors import ProfileError
from companion.link.snapshot import TelemetryAssembler
from sim.skid_mixer import skid_mix
from tests.fake_ports import FakePorts


# ------------------------------------------------------------------ ArduPilot's output path, forward
def scaled_throttle(value: float, throttle_min_pct: float, expo: float) -> float:
    """``AP_MotorsUGV::get_scaled_throttle`` on a ±1 value (percent in the C++)."""
    pct = 100.0 * value
    if pct == 0.0:
        return 0.0
    if throttle_min_pct > 0:
        pct = (throttle_min_pct if pct > 0 else -throttle_min_pct) + pct * (100.0 - throttle_min_pct) * 0.01
    if expo == 0.0 or not -1.0 <= expo <= 1.0:
        return pct / 100.0
    sign = -1.0 if pct < 0 else 1.0
    p = min(abs(pct), 100.0) * 0.01
    return sign * ((expo - 1.0) + math.sqrt((1.0 - expo) ** 2 + 4.0 * expo * p)) / (2.0 * expo)


def pwm_from_angle(value: float, low: float, trim: float, high: float, reversed_: bool = False) -> int:
    """``SRV_Channel::pwm_from_angle`` of a ±1 value (C++ uint16 truncation)."""
    if reversed_:
        value = -value
    value = max(-1.0, min(1.0, value))
    return int(trim + int(value * (high - trim))) if value > 0 else int(trim - int(-value * (trim - low)))


def rover_outputs(steering: float, throttle: float, *, asym=1.0, mix=0.5, thr_min=0.0, expo=0.0,
                  left=(1000, 1500, 2000, False), right=(1000, 1500, 2000, False)) -> list[int]:
    """SERVO1/SERVO3 PWM of ArduRover's skid mixer for a steering and throttle demand."""
    motor_left, motor_right = skid_mix(steering, throttle, asym, mix)  # output_skid_steering, checked in test_sim_skid
    pwm = [0] * 16
    pwm[0] = pwm_from_angle(scaled_throttle(motor_left, thr_min, expo), *left)
    pwm[2] = pwm_from_angle(scaled_throttle(motor_right, thr_min, expo), *right)
    return pwm


def applied(steering: float, throttle: float, asym=1.0, mix=0.5) -> tuple[float, float]:
    """The steering and throttle the mixer applied (after resolving saturation)."""
    left, right = skid_mix(steering, throttle, asym, mix)
    left, right = (left / asym if left < 0 else left), (right / asym if right < 0 else right)
    return (left - right) / 2, (left + right) / 2


def skid(**mixer) -> Actuation:
    params = {"SERVO1_MIN": 1100, "SERVO1_TRIM": 1520, "SERVO1_MAX": 1900, "SERVO3_MIN": 1000, "SERVO3_TRIM": 1500,
              "SERVO3_MAX": 2000, "SERVO3_REVERSED": 1, **mixer}
    return actuation_from_functions({1: 73, 2: 0, 3: 74}, params)


@pytest.mark.parametrize("mixer", [{}, {"MOT_THST_ASYM": 1.7, "MOT_STR_THR_MIX": 0.2},
                                   {"MOT_THR_MIN": 8.0, "MOT_THST_EXPO": 0.4}, {"MOT_THST_EXPO": -0.5}])
def test_a_skid_pair_un_mixes_to_the_steering_and_throttle_the_mixer_applied(mixer):
    actuation = skid(**mixer)
    asym, mix = mixer.get("MOT_THST_ASYM", 1.0), mixer.get("MOT_STR_THR_MIX", 0.5)
    worst = 0.0
    for steering, throttle in itertools.product((-0.9, -0.35, 0.0, 0.12, 0.5), (-0.4, 0.0, 0.3, 0.6, 0.95)):
        pwm = rover_outputs(steering, throttle, asym=asym, mix=mix, thr_min=mixer.get("MOT_THR_MIN", 0.0),
                            expo=mixer.get("MOT_THST_EXPO", 0.0), left=(1100, 1520, 1900, False),
                            right=(1000, 1500, 2000, True))
        got = actuation.demands(pwm)
        want = applied(steering, throttle, asym, mix)
        worst = max(worst, abs(got[0] - want[0]), abs(got[1] - want[1]))
    # what is left is the PWM's whole-microsecond truncation (amplified where a thrust curve is steep)
    assert worst < 0.012
    assert worst > 0.0  # the truncation is really there: the test does not compare a value with itself


def test_un_mixing_is_not_the_raw_outputs():
    """Without undoing the thrust curve the throttle is visibly wrong: the inversion matters."""
    curved = skid(MOT_THST_EXPO=0.6)
    raw = replace(curved, thrust_expo=0.0)
    pwm = rover_outputs(0.1, 0.5, expo=0.6, left=(1100, 1520, 1900, False), right=(1000, 1500, 2000, True))
    assert curved.demands(pwm)[1] == pytest.approx(0.5, abs=0.01)
    assert abs(raw.demands(pwm)[1] - 0.5) > 0.05


def test_a_steering_servo_reads_its_own_range_and_direction():
    actuation = actuation_from_functions({1: 0, 2: 26, 3: 70, 4: 73.0 - 73},
                                         {"SERVO2_MIN": 1200, "SERVO2_TRIM": 1450, "SERVO2_MAX": 1800,
                                          "SERVO2_REVERSED": 1})
    assert actuation.kind == "steering" and actuation.outputs() == {"steering": 2, "throttle": 3}
    pwm = [0] * 16
    pwm[1], pwm[2] = pwm_from_angle(0.4, 1200, 1450, 1800, True), 1750
    steering, throttle = actuation.demands(pwm)
    assert steering == pytest.approx(0.4, abs=0.005) and throttle == pytest.approx(0.5)
    assert actuation_from_functions({1: 21, 3: 70}).steering_function == 21  # a rudder servo steers too
    assert math.isnan(actuation.demands([0] * 16)[0])  # a disabled output is no data


@pytest.mark.parametrize("functions, words", [
    ({1: 0, 3: 70}, "SERVOn_FUNCTION 26"),
    ({1: 73, 3: 70}, "74 ThrottleRight"),
    ({1: 26, 3: 73, 4: 74}, "cannot tell which one steers"),
    ({1: 26}, "70 (Throttle)"),
])
def test_outputs_that_cannot_be_understood_are_refused_with_what_to_set(functions, words):
    with pytest.raises(ProfileError) as info:
        actuation_from_functions(functions, where="this boat")
    assert words in str(info.value) and "this boat" in str(info.value)


def test_a_log_without_servo_functions_is_refused():
    with pytest.raises(ProfileError, match="no SERVOn_FUNCTION"):
        actuation_from_params({"ATC_STR_ANG_P": 2.0})
    assert actuation_from_params({"SERVO1_FUNCTION": 73, "SERVO3_FUNCTION": 74}).skid


def test_an_output_range_that_cannot_be_a_servo_is_refused():
    with pytest.raises(ProfileError, match="SERVO2"):
        OutputScale(2, minimum=1500, trim=1500, maximum=2000)


def test_the_snapshot_of_a_skid_boat_carries_the_equivalent_rudder_and_the_throttle():
    profile = replace(ROVER, actuation=skid())
    assembler = TelemetryAssembler(profile)
    pwm = rover_outputs(0.2, 0.5, left=(1100, 1520, 1900, False), right=(1000, 1500, 2000, True))
    message = SimpleNamespace(get_type=lambda: "SERVO_OUTPUT_RAW", time_usec=1_000_000,  # paired by its time stamp
                              **{f"servo{i + 1}_raw": value for i, value in enumerate(pwm)})
    assembler.on_message(message)
    snapshot = assembler.on_message(SimpleNamespace(get_type=lambda: "ATTITUDE", time_boot_ms=1000, roll=0.0,
                                                    pitch=0.0, yaw=0.1, rollspeed=0.0, pitchspeed=0.0,
                                                    yawspeed=0.0))
    assert snapshot.rudder == pytest.approx(0.2 * profile.angle_full_scale_rad, abs=0.003)
    assert snapshot.thrust_ratio == pytest.approx(0.5, abs=0.003)


def test_a_boats_steering_is_paired_with_the_attitude_of_its_own_time_stamp():
    """ArduPilot sends each loop's outputs just after that loop's ATTITUDE: a snapshot must wait for
    its own, not take the previous loop's (one sample of delay biased a22 by 6-10 % on ArduRover)."""
    profile = replace(ROVER, actuation=skid())
    assembler = TelemetryAssembler(profile)
    snapshots = []
    for k in range(12):  # 25 Hz; the steering changes every loop
        steering = 0.02 * k
        attitude = SimpleNamespace(get_type=lambda: "ATTITUDE", time_boot_ms=1000 + 40 * k, roll=0.0, pitch=0.0,
                                   yaw=0.1, rollspeed=0.0, pitchspeed=0.0, yawspeed=0.0)
        pwm = rover_outputs(steering, 0.5, left=(1100, 1520, 1900, False), right=(1000, 1500, 2000, True))
        outputs = SimpleNamespace(get_type=lambda: "SERVO_OUTPUT_RAW", time_usec=(1000 + 40 * k) * 1000 + 200,
                                  **{f"servo{i + 1}_raw": value for i, value in enumerate(pwm)})
        snapshots += assembler.take(attitude) + assembler.take(outputs)
    paired = [s for s in snapshots if s.time_s >= 1.2]  # once the output stream is known
    assert len(paired) >= 5
    for snapshot in paired:
        k = round((snapshot.time_s - 1.0) / 0.04)
        assert snapshot.rudder == pytest.approx(0.02 * k * profile.angle_full_scale_rad, abs=0.003)


# ------------------------------------------------------------------ the ArduRover strategy
class Parameters:
    """A vehicle's parameter table answering requests in order (the fence of ``read_present``)."""

    def __init__(self, table: dict) -> None:
        self.table, self.cache, self.events, self.reads = dict(table), {}, {}, []

    def request(self, name: str) -> None:
        self.reads.append(name)
        if name in self.table:
            self.cache[name] = self.table[name]
            self.events[name] = self.events.get(name, 0) + 1

    def get_param(self, name: str, retries: int = 3) -> float:
        from companion.link.errors import ParamTimeout

        self.request(name)
        if name not in self.table:
            raise ParamTimeout(name)
        return self.table[name]


def rover(table: dict) -> FakePorts:
    ports = FakePorts(ROVER, RoverStrategy, mode="guided")
    ports.parameters = Parameters({"ATC_STR_ANG_P": 2.0, **table})
    ports.strategy.ports = ports
    ports.ground = SimpleNamespace(gcs_sysid=255, texts=[], status_text=lambda text, severity=6: ports.ground.texts.append(text))
    return ports


def test_the_rover_strategy_reads_a_skid_boat_and_its_pilot_channels():
    functions = {f"SERVO{n}_FUNCTION": 0 for n in range(1, 17)}
    ports = rover({**functions, "SERVO2_FUNCTION": 73, "SERVO4_FUNCTION": 74, "RCMAP_ROLL": 1, "RCMAP_THROTTLE": 2,
                   "MOT_THST_ASYM": 1.5, "SERVO2_TRIM": 1490})
    profile = ports.strategy.configure()
    assert profile.actuation.skid and profile.actuation.outputs() == {"left": 2, "right": 4}
    assert profile.actuation.thrust_asymmetry == 1.5 and profile.actuation.left.trim == 1490
    assert profile.channels == {"rudder": 1, "thrust": 2}  # the sticks an override moves
    assert profile.campaign_defaults.thrusts == SKID_THRUSTS  # below full throttle, where it can steer
    assert "SERVO16_FUNCTION" in ports.parameters.reads


def test_the_rover_strategy_refuses_a_boat_without_steering():
    ports = rover({f"SERVO{n}_FUNCTION": 0 for n in range(1, 17)})
    with pytest.raises(ProfileError, match="no steering output"):
        ports.strategy.configure()


def test_a_skid_doublet_is_scaled_into_the_room_manual_leaves():
    actuation, fs = skid(), 0.5236
    assert doublet_scale(actuation, fs, 0.5, 0.0, 0.15) == (1.0, None)  # 0.5 ± 0.29: both ahead of 0.1, below 0.97
    scale, text = doublet_scale(actuation, fs, 0.7, 0.02, 0.02 + 0.26)
    assert 0.02 / fs + scale * 0.26 / fs == pytest.approx(1.0 - 0.7 - 0.03)  # exactly to the room
    scale, _ = doublet_scale(actuation, fs, 0.3, 0.0, 0.26)
    assert scale * 0.26 / fs == pytest.approx(0.3 - 0.1 - 0.03)  # the slower motor stays above 0.1
    assert "x0." in text
    assert doublet_scale(actuation, fs, 0.99, 0.0, 0.26)[0] == 0.0  # full throttle: no room at all
    assert scaled(0.02 + 0.26, 0.02, scale) == pytest.approx(0.02 + scale * 0.26)
    steering = actuation_from_functions({1: 26, 3: 70})
    assert doublet_scale(steering, fs, 0.99, 0.0, 0.26) == (1.0, None)  # a rudder needs no room


def test_the_rover_strategy_flies_the_scaled_doublet_and_says_so():
    ports = rover({})
    ports.profile = replace(ROVER, actuation=skid())
    ports.telemetry.latest = Telemetry(time_s=100.0, rudder=0.0, thrust_ratio=0.8)
    sent = []
    record = ports.overrides.override
    ports.overrides.override = lambda actuator, value, **kw: (sent.append((actuator, value)), record(actuator, value, **kw))
    ports.strategy.override("rudder", 0.26)
    ports.strategy.override("rudder", -0.26)
    rudder = [value for actuator, value in sent if actuator == "rudder"]
    room = (1.0 - 0.8 - 0.03) * 0.5236
    assert rudder == pytest.approx([room, -room])  # one factor for the whole doublet: still symmetric
    assert any("skid: doublet" in text for text in ports.ground.texts)


def test_a_doublet_with_no_room_is_refused_with_what_to_change():
    from companion.link.autopilots.skid_room import refusal

    ports = rover({})
    ports.profile = replace(ROVER, actuation=skid())
    ports.telemetry.latest = Telemetry(time_s=100.0, rudder=0.0, thrust_ratio=0.03)  # ArduPilot's motorboat-skid
    with pytest.raises(ProfileError, match="raise WP_SPEED"):
        ports.strategy.override("rudder", 0.26)
    assert ports.modes.changes == [] and not ports.overrides.active  # refused before anything moved
    assert "fly slower" in refusal(0.99, 0.0) and refusal(0.5, 0.2) is None
