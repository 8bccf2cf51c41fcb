"""Designed gains as parameter files ground stations load (``companion results --export``): ArduPilot's
``.parm`` as MAVProxy's ``param load`` reads it, QGroundControl's ``.params``, per identified speed
or at a chosen speed; and, with ArduPilot SITL, a file loaded into the real firmware and read back."""
from __future__ import annotations

import dataclasses

import os
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pytest
from pymavlink import mavparm

from behaviors.cascade_schedule import cascade_kind
from behaviors.heading_schedule import heading_kind
from behaviors.identification import IdentificationAttempt
from companion.cli.main import main
from companion.link.profile import AutopilotProfile
from companion.link.profiles import get_profile
from companion.numerics.cascade_gains import CascadeRules
from companion.numerics.gains import GainBounds
from companion.numerics.identification import YawModel
from companion.procedures.campaign import CampaignConfig
from companion.records import gain_export
from companion.records.param_files import ParamFile, float32_text, read_parm, read_qgc, write_parm, write_qgc
from companion.records.store import Store

BIN = os.environ.get("ARDUPILOT_SITL_BIN")
MODELS = ((0.6, 1.2, -1.6, 0.9), (0.8, 1.6, -1.7, 1.5), (1.0, 2.0, -1.8, 2.3))  # thrust, speed, a22, b2


def attempts():
    return [IdentificationAttempt(attempt=1, axis="yaw", thrust=t, speed=u, model=YawModel(a22, b2, 0.01), r2=0.97,
                                  accepted=True, converged=True, converged_s=9.0, criterion_met_from_s=8.0,
                                  training_s=10.0, samples=200) for t, u, a22, b2 in MODELS]


def campaign_store(path: Path, profile: str, kind, config: dict | None = None, status: str = "completed",
                   vehicle: str = "sysid-7", with_rules: bool = True) -> int:
    """A campaign as a live one stores it: its runs, its design, its resolved configuration
    (``with_rules`` False: a design as stores kept it before designs carried their rules)."""
    with Store(path) as store:
        campaign = store.start_campaign(store.add_vehicle(vehicle, profile), "identification", config or {})
        for attempt in attempts():
            store.add_run(campaign, attempt)
        design = kind.design(attempts())
        store.add_design(campaign, design if with_rules else dataclasses.replace(design, rules=None, speed_law=None))
        store.finish_campaign(campaign, status, None if status == "completed" else "signal SIGTERM")
    return campaign


def rover_store(path: Path) -> int:
    config = CampaignConfig().resolved_for(get_profile("ardurover"))
    return campaign_store(path, "ardurover", cascade_kind(config.cascade), config.to_dict())


def export(capsys, store: Path, *argv: str) -> tuple[int, list[str], str]:
    code = main(["results", "--store", str(store), *argv])
    captured = capsys.readouterr()
    return code, captured.out.split(), captured.err


def test_float32_values_in_their_shortest_text():
    assert float32_text(0.2) == "0.2" and float32_text(1.0) == "1" and float32_text(-0.0353) == "-0.0353"
    for value in np.random.default_rng(3).uniform(-5.0, 5.0, 200):
        assert np.float32(float(float32_text(value))) == np.float32(value)


def test_parm_and_qgc_files_read_back(tmp_path):
    params = ParamFile({"ATC_STR_RAT_FF": 0.41, "SOME_COUNT": 3.0}, comments=("what", ""), types={"SOME_COUNT": 6},
                       system_id=7)
    parm = write_parm(params)
    assert parm.splitlines() == ["# what", "#", "ATC_STR_RAT_FF 0.41", "SOME_COUNT 3"]
    assert read_parm(parm) == {"ATC_STR_RAT_FF": pytest.approx(0.41), "SOME_COUNT": 3.0}
    qgc = write_qgc(params)
    assert "# Vehicle-Id Component-Id Name Value Type" in qgc.splitlines()
    assert read_qgc(qgc) == [(7, 1, "ATC_STR_RAT_FF", pytest.approx(0.41), 9), (7, 1, "SOME_COUNT", 3.0, 6)]
    path = tmp_path / "g.parm"
    path.write_text(parm)
    loaded = mavparm.MAVParmDict()
    assert loaded.load(str(path))  # MAVProxy's `param load` reader
    assert dict(loaded) == {"ATC_STR_RAT_FF": pytest.approx(0.41), "SOME_COUNT": 3.0}
    with pytest.raises(ValueError, match="whole number"):
        write_qgc(ParamFile({"SOME_COUNT": 2.5}, types={"SOME_COUNT": 6}))
    with pytest.raises(ValueError, match="finite"):
        ParamFile({"X": float("nan")})


def test_per_identified_speed_the_stored_gains_exactly(tmp_path, capsys):
    store = tmp_path / "s.sqlite"
    campaign = rover_store(store)
    code, paths, err = export(capsys, store, "--campaign", str(campaign), "--export", str(tmp_path / "gains.parm"))
    assert code == 0, err
    assert [Path(p).name for p in paths] == ["gains-1.20ms.parm", "gains-1.60ms.parm", "gains-2.00ms.parm"]
    with Store(store, read_only=True) as opened:
        design = opened.designs(campaign)[0]
    profile = get_profile("ardurover")
    for path, point in zip(paths, design.points):
        text = Path(path).read_text()
        assert text.isascii() and f"campaign {campaign}" in text and "(ardurover)" in text
        values = read_parm(text)
        assert values == {profile.native_param(k): pytest.approx(v, rel=1e-6) for k, v in point.scheduled.items()}
        assert set(values) == {"ATC_STR_RAT_FF", "ATC_STR_RAT_P", "ATC_STR_RAT_I", "ATC_STR_ANG_P"}


def test_at_a_chosen_speed_from_the_stored_schedule(tmp_path, capsys):
    store = tmp_path / "s.sqlite"
    campaign = rover_store(store)
    target = tmp_path / "at.parm"
    code, paths, err = export(capsys, store, "--campaign", str(campaign), "--export", str(target), "--speed", "1.6")
    assert code == 0 and paths == [str(target)], err
    at_point = read_parm(target.read_text())
    with Store(store, read_only=True) as opened:
        point = opened.designs(campaign)[0].points[1]  # identified at 1.6 m/s
    assert at_point == {get_profile("ardurover").native_param(k): pytest.approx(v, rel=1e-6)
                        for k, v in point.scheduled.items()}
    code, _, _ = export(capsys, store, "--campaign", str(campaign), "--export", str(target), "--speed", "3.0")
    assert code == 0 and "outside the identified speeds" in target.read_text()


def test_a_design_is_exported_at_a_chosen_speed_under_the_rules_it_carries(tmp_path, capsys):
    """Rules the stored (empty) configuration does not say: the design itself carries them."""
    store = tmp_path / "s.sqlite"
    clamped = heading_kind(GainBounds(kp_max=0.3))
    campaign = campaign_store(store, "sim", clamped)
    code, paths, err = export(capsys, store, "--campaign", str(campaign), "--export", str(tmp_path / "g.parm"),
                              "--speed", "1.5")
    assert code == 0, err
    assert read_parm(Path(paths[0]).read_text())["HDG_P"] == pytest.approx(0.3)  # the default rules give more
    assert heading_kind().gains(opened_design(store, campaign).schedule, 1.5)["heading_p"] > 0.3


def test_a_design_stored_without_its_rules_is_exported_per_speed_only(tmp_path, capsys):
    store = tmp_path / "s.sqlite"
    campaign = campaign_store(store, "sim", heading_kind(GainBounds(kp_max=0.3)), with_rules=False)
    code, _, err = export(capsys, store, "--campaign", str(campaign), "--export", str(tmp_path / "g.parm"),
                          "--speed", "1.5")
    assert code == 1 and "stored without its design rules" in err and err.count("\n") == 1
    code, paths, _ = export(capsys, store, "--campaign", str(campaign), "--export", str(tmp_path / "g.parm"))
    assert code == 0 and read_parm(Path(paths[0]).read_text())["HDG_P"] == pytest.approx(0.3)


def opened_design(store: Path, campaign: int):
    with Store(store, read_only=True) as opened:
        return opened.designs(campaign)[0]


def test_only_a_completed_campaign_with_a_design(tmp_path, capsys):
    store = tmp_path / "s.sqlite"
    aborted = campaign_store(store, "sim", heading_kind(), status="aborted")
    code, _, err = export(capsys, store, "--campaign", str(aborted), "--export", str(tmp_path / "g.parm"))
    assert code == 1 and "is aborted (signal SIGTERM)" in err
    code, _, err = export(capsys, store, "--campaign", "99", "--export", str(tmp_path / "g.parm"))
    assert code == 1 and "no campaign 99" in err
    code, _, err = export(capsys, store, "--export", str(tmp_path / "g.parm"))
    assert code == 2 and "--campaign" in err
    assert not list(tmp_path.glob("g*.parm"))


@dataclass(frozen=True)
class TypedProfile(AutopilotProfile):
    """A PX4-like profile: its own names and the MAV_PARAM_TYPE of each (what a PX4 profile carries)."""

    param_types: dict = field(default_factory=dict)


FAKE_PX4 = TypedProfile(name="fake-px4", modes={"manual": 0}, channels={"rudder": 1},
                        params={"heading_p": "UUV_YAW_P", "heading_i": "UUV_YAW_I", "rudder_trim": "UUV_YAW_TRIM"},
                        param_types={"UUV_YAW_P": 9, "UUV_YAW_I": 9}, int_encoding="bytewise")


def test_qgc_params_from_a_profile_names_and_types(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(gain_export, "get_profile", lambda name: FAKE_PX4 if name == "fake-px4" else get_profile(name))
    store = tmp_path / "s.sqlite"
    campaign = campaign_store(store, "fake-px4", heading_kind())
    target = tmp_path / "gains.params"  # the suffix chooses QGroundControl's format
    code, paths, err = export(capsys, store, "--campaign", str(campaign), "--export", str(target), "--speed", "1.6")
    assert code == 0 and paths == [str(target)], err
    text = target.read_text()
    rows = read_qgc(text)
    assert [(r[0], r[1], r[2], r[4]) for r in rows] == [(7, 1, "UUV_YAW_P", 9), (7, 1, "UUV_YAW_I", 9),
                                                        (7, 1, "UUV_YAW_TRIM", 9)]
    assert text.splitlines()[-4] == "# Vehicle-Id Component-Id Name Value Type"
    assert all(len(line.split("\t")) == 5 for line in text.splitlines() if not line.startswith("#"))


def test_the_log_path_prints_the_export_command(tmp_path, capsys):
    """``identify --log`` names the command; here it is run on a log campaign (never flown)."""
    from companion.cli.commands.results import export_command

    store = tmp_path / "s.sqlite"
    with Store(store) as opened:
        campaign = opened.start_campaign(opened.add_vehicle("log:x.bin", "ardurover"), "log", {"profile": "ardurover"})
        opened.add_design(campaign, cascade_kind(CascadeRules()).design(attempts()))
        opened.finish_campaign(campaign, "completed")
    command = export_command(str(store), campaign)
    assert command.startswith("companion results --store ") and command.endswith(f"--campaign {campaign} --export gains.parm")
    code, paths, err = export(capsys, store, "--campaign", str(campaign), "--export", str(tmp_path / "g.parm"))
    assert code == 0, err
    assert "never flown" in Path(paths[0]).read_text()


@pytest.mark.e2e
@pytest.mark.xdist_group("sitl")
@pytest.mark.skipif(not (BIN and (Path(BIN) / "ardurover").is_file()),
                    reason="ARDUPILOT_SITL_BIN is not set to a folder with ArduPilot's ardurover SITL binary")
def test_an_exported_parm_loads_into_ardurover_sitl(tmp_path, capsys):
    """MAVProxy's loader (pymavlink ``MAVParmDict.load``, what ``param load`` runs) writes the file into
    the real firmware; every value reads back as written (float32)."""
    from pymavlink import mavutil

    from companion.rehearsal.launcher import SimulatorProcess

    store = tmp_path / "s.sqlite"
    campaign = rover_store(store)
    target = tmp_path / "rover.parm"
    assert export(capsys, store, "--campaign", str(campaign), "--export", str(target), "--speed", "1.5")[0] == 0
    written = read_parm(target.read_text())
    with SimulatorProcess("boat", 1.0, 1, (0.0, 0.0), autopilot="ardurover", ardupilot_bin=BIN, lockstep=False,
                          ready_timeout_s=120.0) as sim:
        master = mavutil.mavlink_connection(sim.endpoint, source_system=255, source_component=190)
        try:
            assert master.wait_heartbeat(timeout=60) is not None
            before = {name: _read(master, name) for name in written}
            assert before != pytest.approx(written)  # the firmware did not already hold these values
            assert mavparm.MAVParmDict().load(str(target), mav=master, check=False)
            after = {name: _read(master, name) for name in written}
        finally:
            master.close()
    assert after == {name: pytest.approx(float(np.float32(value)), rel=1e-7) for name, value in written.items()}


def _read(master, name: str, timeout_s: float = 10.0) -> float:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        master.mav.param_request_read_send(master.target_system, master.target_component, name.encode(), -1)
        msg = master.recv_match(type="PARAM_VALUE", blocking=True, timeout=1.0)
        while msg is not None and msg.param_id != name:
            msg = master.recv_match(type="PARAM_VALUE", blocking=True, timeout=1.0)
        if msg is not None:
            return float(msg.param_value)
    raise AssertionError(f"no PARAM_VALUE for {name}")
