"""Adding a behaviour, an autopilot or a boat is one module plus one registration line.

A toy of each is registered here, and every place that lists them picks it up: the command line's
choices, the rehearsal's validation, the report's figures, the sweep's columns (behaviours); profile
detection and the command line's ``--profile`` (autopilots); the rehearsal's defaults (boats: a preset
file whose ``rehearsal`` section says what it flies)."""
from __future__ import annotations

import argparse
import json
import sys
import types
from dataclasses import dataclass
from pathlib import Path

import pytest

from companion.link import autopilots
from companion.link.profile import AutopilotProfile
from companion.procedures import registry
from companion.procedures.registry import PROCEDURES, ProcedureContext, ProcedureSpec, rehearsal_behaviors
from companion.procedures.results import ProcedureResult
from companion.records.report_section import ReportSection


@dataclass(frozen=True)
class WaveConfig:
    seconds: float = 3.0


@dataclass(frozen=True)
class WaveFigures:
    """What the toy procedure measured: how long it waited (s)."""

    seconds: float

    def to_dict(self) -> dict:
        return {"seconds": self.seconds}


class Wave:
    """A toy procedure: waits its configured seconds of vehicle time, then completes."""

    def __init__(self, config: WaveConfig) -> None:
        self.config, self.start, self.done = config, None, False

    def step(self, telemetry):
        self.start = telemetry.time_s if self.start is None else self.start
        self.done = telemetry.time_s - self.start >= self.config.seconds
        return []

    def abort(self, reason):
        self.done = True
        return []

    def result(self) -> ProcedureResult:
        return ProcedureResult("wave", "completed" if self.done else "aborted", None, WaveFigures(self.config.seconds))


def _wave_plot(result: dict, path: Path) -> str:
    path.write_bytes(b"\x89PNG")
    return path.name


WAVE = ProcedureSpec("wave", None, lambda link, context: Wave(context.config_for("wave")),
                     lambda stored: {"seconds": stored.get("seconds")}, WaveConfig,
                     report=ReportSection("Waving", "wave.png", _wave_plot),
                     sweep_columns=("wave_status", "wave_seconds"),
                     sweep_row=lambda section: {"wave_status": section.get("status"),
                                                "wave_seconds": section.get("seconds")},
                     after_campaign=True)


@pytest.fixture
def wave(monkeypatch):
    monkeypatch.setitem(PROCEDURES, "wave", WAVE)  # the one registration line
    return WAVE


def test_a_registered_behaviour_is_offered_and_built_everywhere_procedures_are_listed(wave):
    from companion.cli.main import build_parser
    from companion.rehearsal.rehearsal import RehearsalConfig
    from companion.sweep.case import figure_columns
    from companion.sweep.spec import Case

    assert "wave" in rehearsal_behaviors()
    RehearsalConfig(behaviors=("wave",))  # the rehearsal accepts it
    with pytest.raises(ValueError, match="unknown jump"):
        RehearsalConfig(behaviors=("jump",))
    parser = build_parser()
    assert parser.parse_args(["run-behavior", "wave", "--connect", "udp:127.0.0.1:1"]).behavior == "wave"
    assert "wave" in registry.report_sections()
    assert ("wave_status", "wave_seconds") == figure_columns()[-4:-2]
    assert registry.sweep_row({"wave": {"status": "completed", "seconds": 3.0}})["wave_seconds"] == 3.0
    assert "wave" in Case.__dataclass_fields__["behaviors"].default_factory()  # a sweep's default behaviours
    procedure = WAVE.build(None, ProcedureContext())
    assert procedure.config == WaveConfig()  # its registered default configuration
    assert WAVE.build(None, ProcedureContext(configs={"wave": WaveConfig(1.0)})).config.seconds == 1.0


def test_a_registered_behaviour_runs_by_name_and_its_figure_is_in_the_report(wave, tmp_path):
    from companion.procedures.app import AbortFlag, run_named_behavior
    from companion.records.report import write_report
    from companion.records.store import Store
    from harness.inprocess import InProcessLink

    link = InProcessLink(seed=1)
    with Store(tmp_path / "s.sqlite") as store:
        vehicle = store.add_vehicle("toy")
        campaign = store.start_campaign(vehicle, "identification")
        ran = run_named_behavior("wave", link, store, vehicle_id=vehicle, campaign_id=campaign, abort=AbortFlag(),
                                 config=WaveConfig(2.0))
        assert ran.result.status == "completed" and ran.summary == {"seconds": 2.0}
        store.finish_campaign(campaign, "completed", None)
        html = write_report(store, campaign, tmp_path / "report", sections=registry.report_sections()).read_text()
    assert "<h2>Waving</h2><img src='wave.png'" in html


def test_a_registered_autopilot_is_detected_offered_and_designed_for(monkeypatch, capsys):
    from companion.cli.commands._common import add_connect_arguments
    from companion.link import profiles

    toy = types.ModuleType("companion.link.autopilots.toy")
    toy.PROFILE = AutopilotProfile(name="toy", modes={"hold": 1}, channels={},
                                   params={"heading_p": "TOY_P", "heading_i": "TOY_I", "rudder_trim": "TOY_TRIM"},
                                   marker_param="TOY_P", strategy="toy", heading_controller="pi",
                                   shipped_gains={"TOY_P": 0.5, "TOY_I": 0.01, "TOY_TRIM": 0.0})
    monkeypatch.setitem(sys.modules, "companion.link.autopilots.toy", toy)
    monkeypatch.setattr(autopilots, "MODULES", autopilots.MODULES + ("toy",))  # the one registration line
    monkeypatch.setattr(profiles, "PROFILES", {p.name: p for p in autopilots.registered_profiles()})
    assert profiles.detect_profile({"TOY_P", "SYSID_THISMAV"}).name == "toy"
    parser = argparse.ArgumentParser()
    add_connect_arguments(parser)
    assert parser.parse_args(["--connect", "udp:127.0.0.1:1", "--profile", "toy"]).profile == "toy"
    from companion.cli.main import main

    # the designer predicts its steps under the controller its module declares, from its shipped gains
    assert main(["design", "--autopilot", "toy", "--a22", "-0.9", "--b2", "1.1", "--speed", "1.5"]) == 0
    assert "TOY_P" in capsys.readouterr().out


def test_a_boat_says_in_its_file_what_a_rehearsal_flies_on_it(tmp_path):
    from companion.rehearsal.rehearsal import preset_defaults
    from companion.records.vehicle_files import preset_path

    boat = json.loads(preset_path("boat").read_text())
    toy = tmp_path / "toy-boat.json"
    toy.write_text(json.dumps({**boat, "name": "toy-boat",
                               "rehearsal": {"behaviors": ["roll"], "steady_state": True, "current": [0.1, 0.0]}}))
    assert preset_defaults(str(toy)) == {"behaviors": ("roll",), "steady_state": True, "current": (0.1, 0.0)}
    assert preset_defaults("starfish")["behaviors"] == ("roll", "min_speed")
    assert preset_defaults("hugin") == {"behaviors": (), "steady_state": True, "current": (0.007, -0.012)}
    toy.write_text(json.dumps({**boat, "rehearsal": {"behaviors": ["jump"]}}))
    with pytest.raises(ValueError, match="unknown behaviours"):
        preset_defaults(str(toy))
