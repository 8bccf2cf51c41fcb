"""The text lines the campaign commands print: the vehicle time by phase."""
from __future__ import annotations

from companion.cli.commands._campaign_text import phase_line


def test_the_phase_line_gives_the_total_it_is_told_or_the_phases_sum():
    phases = {"settle": 55.7, "excitation": 45.0, "speed_steps": 50.0}
    assert phase_line(258.0, phases).startswith("campaign: 258 s of vehicle time (settle 56 s, excitation 45 s, ")
    assert phase_line(None, phases).startswith("campaign: 151 s of vehicle time (")
    assert "speed steps 50 s" in phase_line(None, phases)
    assert phase_line(None, {}) is None
