"""A campaign's vehicle time by phase (companion/procedures/campaign_phases.py)."""
from __future__ import annotations

from companion.procedures.campaign_phases import PhaseClock, add_times, phase_of


def test_the_time_between_samples_counts_to_the_earlier_samples_phase_in_flying_order():
    clock = PhaseClock()
    for now, phase in ((0.0, "design_writes"), (1.0, "settle"), (4.0, "excitation"), (4.0, "excitation"),
                       (10.0, "settle")):
        clock.count(now, phase)
    assert clock.seconds == {"design_writes": 1.0, "settle": 3.0, "excitation": 6.0}
    assert list(clock.in_order()) == ["settle", "excitation", "design_writes"]


def test_no_running_step_is_design_and_writes_and_stage_times_add_up():
    assert phase_of(None) == "design_writes"
    assert add_times({"train": 1.0}, {"train": 2.0, "validate": 0.5}) == {"train": 3.0, "validate": 0.5}
