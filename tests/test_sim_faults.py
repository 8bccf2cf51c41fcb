"""Fault injection in the simulator: a property scaled from a vehicle time on."""
from __future__ import annotations

import json
from importlib import resources

import pytest

from sim.__main__ import build_parser
from sim.faults import Fault, parse_fault
from sim.linearize import linearized_yaw
from sim.preset import load_preset, preset_from_dict
from sim.vehicle import ActuatorDemand, Vehicle


@pytest.fixture(scope="module")
def starfish():
    return load_preset("starfish")


def test_parse_fault_forms():
    assert parse_fault("b2=0.7@600") == Fault("b2", 0.7, 600.0)
    assert parse_fault("thrust=0.8") == Fault("thrust", 0.8, 0.0)
    assert parse_fault(" a22=1.5@10 ").kind == "damping"  # alias
    for bad in ("b2", "b2=", "b2=x@3", "fins=0.7@1", "b2=0@1", "b2=-1@1", "b2=0.7@-5", "b2=nan@1"):
        with pytest.raises(ValueError):
            parse_fault(bad)


def test_command_line_option():
    args = build_parser().parse_args(["run", "--fault", "b2=0.7@600", "--fault", "thrust=0.9@30"])
    assert args.fault == [Fault("b2", 0.7, 600.0), Fault("thrust", 0.9, 30.0)]
    with pytest.raises(SystemExit):
        build_parser().parse_args(["run", "--fault", "b2=0.7@soon"])


def _pair(preset, fault, speed=1.4):
    healthy = Vehicle(preset, seed=3, speed=speed)
    faulty = Vehicle(preset, seed=3, speed=speed, faults=(fault,))
    return healthy, faulty


def _run(vehicles, seconds, demand, dt=0.01):
    for _ in range(int(round(seconds / dt))):
        for vehicle in vehicles:
            vehicle.step(dt, demand)


def test_fin_effectiveness_scales_yaw_response_from_onset(starfish):
    """b2 ×0.7 from t = 2 s: identical before, 0.7 × the yaw acceleration after (r ≈ 0)."""
    healthy, faulty = _pair(starfish, Fault("b2", 0.7, 2.0))
    thrust = healthy.thrust_ratio
    offset = starfish.yaw.rudder_offset
    healthy.rudder = faulty.rudder = offset  # on the trim: no turn
    _run((healthy, faulty), 2.0, ActuatorDemand(rudder=offset, thrust_ratio=thrust))
    assert faulty.state == healthy.state and not faulty.active_faults
    assert abs(healthy.yaw_rate) < 1e-12
    healthy.rudder = faulty.rudder = 0.1 + offset
    _run((healthy, faulty), 0.02, ActuatorDemand(rudder=0.1 + offset, thrust_ratio=thrust))
    assert faulty.active_faults == [Fault("b2", 0.7, 2.0)]
    assert faulty.yaw_rate / healthy.yaw_rate == pytest.approx(0.7, rel=0.01)


def test_damping_fault_lowers_steady_turn_rate(starfish):
    """a22 ×1.5 from the start: the steady yaw rate under a small rudder is ≈ 1/1.5 of the healthy one."""
    healthy, faulty = _pair(starfish, Fault("damping", 1.5, 0.0))
    demand = ActuatorDemand(rudder=0.03 + starfish.yaw.rudder_offset, thrust_ratio=healthy.thrust_ratio)
    _run((healthy, faulty), 20.0, demand)
    assert faulty.yaw_rate / healthy.yaw_rate == pytest.approx(1 / 1.5, rel=0.05)


def test_thrust_efficiency_slows_the_vehicle(starfish):
    """Thrust ×0.7 from 5 s: same speed until then, clearly slower 60 s later (drag ∝ u²)."""
    healthy, faulty = _pair(starfish, Fault("thrust", 0.7, 5.0), speed=None)
    demand = ActuatorDemand(thrust_ratio=healthy.thrust_ratio)
    _run((healthy, faulty), 5.0, demand)
    assert faulty.state.speed_water == healthy.state.speed_water
    _run((healthy, faulty), 60.0, demand)
    ratio = faulty.state.speed_water / healthy.state.speed_water
    assert 0.75 < ratio < 0.92


def test_preset_file_faults(starfish):
    """A preset's optional ``faults`` list (what a preset file holds); bad entries are named."""
    data = json.loads((resources.files("sim") / "presets" / "starfish.json").read_text())
    data["faults"] = [{"kind": "b2", "factor": 0.7, "at_s": 600}]
    preset = preset_from_dict(data)
    assert preset.faults == (Fault("b2", 0.7, 600.0),)
    assert linearized_yaw(preset, 1.4) == linearized_yaw(starfish, 1.4)  # the truth is the healthy vehicle's
    vehicle = Vehicle(preset, speed=1.4)
    assert vehicle._pending_faults == [Fault("b2", 0.7, 600.0)]
    data["faults"] = [{"kind": "b2", "factor": "a lot"}]
    with pytest.raises(ValueError, match="faults\\[0\\]"):
        preset_from_dict(data)
