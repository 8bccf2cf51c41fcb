"""ArduRover without SITL, against a fake link: the servo model's timing (a new command moves the
rudder only from when it took effect) and the held outputs of the open-loop excitation (trimmed on
their read-back until the output equals what the speed and heading loops had)."""
from __future__ import annotations

import math
from dataclasses import replace

import pytest

from companion.interface import Telemetry
from companion.link.autopilots.ardurover import PROFILE, Strategy
from tests.fake_ports import FakePorts

RATE = 5.0  # rad/s, the boat preset's rudder servo


class Rover(FakePorts):
    """The strategy's ports; ``output_of`` stands for MANUAL's stick-to-output mapping, which is not
    the identity on ArduRover (measured: 1801 µs of throttle gave 0.570). ``commanded`` holds each
    override as the strategy asked for it (SI units, before PWM rounding)."""

    def __init__(self, output_of=lambda actuator, value: value, **profile_changes) -> None:
        super().__init__(replace(PROFILE, actuator_rate_rad_s=RATE, **profile_changes), Strategy)
        self.output_of = output_of
        self.commanded: dict[str, float] = {}
        record = self.overrides.override

        def override(actuator: str, value: float, *, keep_alive: bool = True) -> None:
            self.commanded[actuator] = value
            record(actuator, value, keep_alive=keep_alive)

        self.overrides.override = override
        self.telemetry.latest = Telemetry(time_s=100.0, rudder=0.02, thrust_ratio=0.602)

    @property
    def mode(self) -> str:
        return self.announcements.mode

    def read_back(self, time_s: float) -> Telemetry:
        """The snapshot the autopilot would report: each output as MANUAL makes it of the stick."""
        self.clock.vehicle_time_s = time_s
        return Telemetry(time_s=time_s, rudder=self.output_of("rudder", self.commanded.get("rudder", 0.02)),
                         thrust_ratio=self.output_of("thrust", self.commanded.get("thrust", 0.602)))


def _servo_path(strategy: Strategy, samples: list[tuple[float, float]]) -> list[float]:
    return [strategy.servo_model(Telemetry(time_s=t, rudder=command)).rudder for t, command in samples]


def test_a_new_command_moves_the_servo_only_from_when_it_took_effect():
    path = _servo_path(Rover(output_lead_s=0.0).strategy, [(0.0, 0.0), (0.04, 0.25), (0.08, 0.25), (0.12, 0.25)])
    # seen at 0.04: applied after that loop, so the servo is still at 0 there, 0.2 rad 40 ms later
    assert path == pytest.approx([0.0, 0.0, 0.2, 0.25])


def test_the_output_lead_starts_the_slew_before_the_snapshot_that_shows_it():
    link = Rover()  # ArduRover: 10 ms, half a loop between two 25 Hz samples of the 50 Hz loop
    assert link.profile.output_lead_s == pytest.approx(0.010)
    path = _servo_path(link.strategy, [(0.0, 0.0), (0.04, 0.25), (0.08, 0.25), (0.12, -0.25)])
    assert path == pytest.approx([0.0, 0.05, 0.25, 0.2])


def test_without_a_servo_rate_the_snapshot_is_unchanged():
    link = Rover()
    link.profile = replace(link.profile, actuator_rate_rad_s=None)
    assert _servo_path(link.strategy, [(0.0, 0.0), (0.04, 0.25)]) == [0.0, 0.25]


def _excite(link: Rover, strategy: Strategy, until_s: float, start_s: float = 100.0) -> None:
    t = start_s
    while t < until_s - 1e-9:
        t += 0.04
        strategy.on_snapshot(link.read_back(t))


def test_held_throttle_is_trimmed_until_its_read_back_equals_the_speed_loops_output():
    # MANUAL scales the stick about trim by 0.947: 0.602 becomes 0.570 (ArduRover SITL, measured)
    link = Rover(output_of=lambda actuator, value: value * 0.947 if actuator == "thrust" else value)
    strategy = link.strategy
    strategy.override("rudder", 0.26)
    assert link.mode == "manual" and link.commanded["thrust"] == pytest.approx(0.602)
    _excite(link, strategy, until_s=100.4)
    assert link.output_of("thrust", link.commanded["thrust"]) == pytest.approx(0.602, abs=Strategy.HOLD_TOLERANCE["thrust"])
    assert link.commanded["rudder"] == pytest.approx(0.26)  # the doublet itself is never "corrected"


def test_held_steering_passes_a_dead_zone_and_the_correction_is_kept_for_the_next_excitation():
    def manual(actuator, value):  # a 30 µs steering dead zone (0.0314 rad), rescaled beyond it
        if actuator != "rudder":
            return value
        dead = 30 / 500 * 0.5236
        return 0.0 if abs(value) <= dead else math.copysign((abs(value) - dead) / (0.5236 - dead) * 0.5236, value)

    link = Rover(output_of=manual)
    strategy = link.strategy
    strategy.override("rudder", 0.26)
    strategy.release("rudder")  # the doublet ends: hold the steering the heading loop had (0.02)
    assert manual("rudder", link.commanded["rudder"]) == 0.0  # as sent, it would read back 0
    _excite(link, strategy, until_s=101.0)
    held = link.commanded["rudder"]
    assert manual("rudder", held) == pytest.approx(0.02, abs=Strategy.HOLD_TOLERANCE["rudder"])
    strategy.release(None)  # back to the holding mode (mode_changed ends the excitation); the next starts corrected
    assert link.mode == "hold"
    strategy.override("rudder", 0.26)
    strategy.release("rudder")
    assert link.commanded["rudder"] == pytest.approx(held)


def test_the_profile_gives_a_campaign_its_thrusts_and_axes_unless_the_user_set_them():
    from companion.link.profiles import get_profile
    from companion.procedures.campaign import CampaignConfig

    user = CampaignConfig(thrusts=(0.7,), axes=("yaw", "pitch"))
    rover = user.resolved_for(PROFILE)
    assert rover.thrusts == (0.6, 0.8, 1.0) and rover.axes == ("yaw",)  # a boat has no dive plane
    assert replace(user, user_set=("thrusts",)).resolved_for(PROFILE).thrusts == (0.7,)
    sub = CampaignConfig().with_profile_defaults(get_profile("ardusub"))
    assert sub.thrusts == (0.45, 0.55, 0.65) and sub.yaw.training_amplitude == 0.10
    assert CampaignConfig().with_profile_defaults(get_profile("sim")) == CampaignConfig()  # our simulator: as is
