"""The crash trail's decisions, without a simulator: who owns a trail (a reused PID is not its owner),
one trail per procedure of a campaign, what the recorder keeps, and what a recovery puts back —
a value the procedure wrote, never one someone set after the crash; the mode only if it is still
the procedure's; a recovery that could not finish leaves the trail open (the killed-process cases
over MAVLink are in tests/test_crash_recovery.py)."""
from __future__ import annotations

import dataclasses
import subprocess
import sys

import pytest

from companion.interface import OverrideActuator, ReleaseActuator
from companion.procedures.restore import RestorePoint
from companion.procedures.trail import TrailRecorder, interrupted, recover
from companion.records.owner import ProcessOwner
from companion.records.store import Store
from tests.fake_autopilot import fake_link, wire  # noqa: F401 - fake_link is a fixture

from pymavlink.dialects.v20 import ardupilotmega as mavlink  # noqa: E402  (after fake_autopilot: MAVLink 2)


# ---------------------------------------------------------------------------- the owner
def _dead_process() -> ProcessOwner:
    child = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
    me = ProcessOwner.current()
    return ProcessOwner(int(child.stdout), me.host, me.boot_id, "1")


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="/proc")
def test_a_process_owns_a_trail_only_while_it_runs_as_the_same_process():
    me = ProcessOwner.current()
    assert me.started and me.boot_id and me.alive()
    assert not dataclasses.replace(me, started=str(int(me.started) + 1)).alive()  # the PID reused by another
    assert not dataclasses.replace(me, boot_id="0" * 32).alive()  # the computer restarted since
    assert not dataclasses.replace(me, host="another-computer").alive()
    assert not _dead_process().alive()


def _mark_dead(store: Store) -> None:
    dead = _dead_process()
    store._db.execute("UPDATE trails SET owner_pid=?, owner_started=?", (dead.pid, dead.started))
    store._db.commit()


def test_each_procedure_has_its_own_trail_and_a_live_campaign_is_not_interrupted(tmp_path):
    with Store(tmp_path / "s.sqlite") as store:
        campaign = store.start_campaign(store.add_vehicle("v"), "rehearsal")
        assert interrupted(store) == []  # running, and its process (this one) is alive
        first = store.save_restore_point(campaign, {"mode": "hold", "native": {"HDG_P": 0.6}}, {"system_id": 1})
        store.add_change(first, 1.0, "ParamWrite", {"name": "HDG_P", "value": 0.8})
        store.finish_restore(first, [], [])
        second = store.save_restore_point(campaign, {"mode": "hold", "native": {"MASS_P": 1.0}}, {"system_id": 1})
        store.add_change(second, 9.0, "ParamWrite", {"name": "MASS_P", "value": 2.0})
        assert second != first and interrupted(store) == []
        _mark_dead(store)
        (trail,) = interrupted(store)  # the first procedure's restore ran: only the second is open
        assert trail.trail_id == second and trail.restore.native == {"MASS_P": 1.0}
        assert trail.wrote("MASS_P", 2.0) and not trail.wrote("HDG_P", 0.8)


def test_a_campaign_whose_process_died_before_its_first_change_is_closed_without_a_restore(tmp_path):
    with Store(tmp_path / "s.sqlite") as store:
        campaign = store.start_campaign(store.add_vehicle("v"), "identification")
        _mark_dead(store)
        (trail,) = interrupted(store)
        assert trail.restore is None and trail.changes == []


# ---------------------------------------------------------------------------- the recorder
class _Changes:
    def __init__(self) -> None:
        self.rows: list[tuple[str, dict]] = []

    def add_change(self, trail_id, vehicle_time_s, kind, detail) -> None:
        self.rows.append((kind, detail))


def test_the_recorder_keeps_each_override_once_and_every_write_the_link_makes(fake_link):
    _fake, link = fake_link
    changes = _Changes()
    recorder = TrailRecorder(changes, 1, link)
    recorder([OverrideActuator("rudder", 0.1), OverrideActuator("rudder", 0.2), ReleaseActuator("rudder"),
              OverrideActuator("rudder", 0.3), OverrideActuator("rudder", 0.1)])
    assert [kind for kind, _ in changes.rows] == ["OverrideActuator", "ReleaseActuator", "OverrideActuator"]
    link.set_param("HDG_P", 0.7)
    link.overrides.override("rudder", 0.1)  # a channel held by whoever asks (here the link itself)
    link.overrides.override("rudder", 0.2)  # already held: not recorded again
    assert changes.rows[3:] == [("ParamWrite", {"name": "HDG_P", "value": 0.7}),
                                ("ChannelHeld", {"channel": link.profile.channel("rudder")})]
    recorder.close()
    link.set_param("HDG_P", 0.8)
    assert len(changes.rows) == 5  # closed: the next procedure's recorder records its own


# ---------------------------------------------------------------------------- the recovery
def _interrupted_trail(store: Store, restore: RestorePoint, written: float):
    campaign = store.start_campaign(store.add_vehicle("v"), "identification")
    trail_id = store.save_restore_point(campaign, restore.as_json(), {"system_id": 1, "profile": "sim"})
    store.add_change(trail_id, 10.0, "ParamWrite", {"name": "HDG_P", "value": written})
    _mark_dead(store)
    (trail,) = interrupted(store)
    return trail


@pytest.mark.parametrize("on_vehicle, expected, kept", [(0.8, 0.6, False), (0.95, 0.95, True)])
def test_a_recovery_puts_back_what_the_procedure_wrote_and_keeps_what_someone_set_after(
        fake_link, tmp_path, on_vehicle, expected, kept):
    fake, link = fake_link
    fake.params["HDG_P"] = (on_vehicle, fake.params["HDG_P"][1])
    with Store(tmp_path / "s.sqlite") as store:
        trail = _interrupted_trail(store, RestorePoint(mode=None, native={"HDG_P": 0.6}), written=0.8)
        done = recover(link, store, trail, decide=lambda found: True)
        assert done.complete and fake.params["HDG_P"][0] == pytest.approx(expected)
        assert any("set by someone else after the companion stopped" in note for note in done.notes) == kept
        assert interrupted(store) == []  # closed
        assert store._db.execute("SELECT status FROM campaigns").fetchone()[0] == "interrupted"


def test_a_recovery_that_cannot_finish_leaves_the_trail_open(fake_link, tmp_path):
    fake, link = fake_link
    fake.params["HDG_P"] = (0.8, fake.params["HDG_P"][1])
    fake.silent_params = {"HDG_P"}  # the write is never answered
    with Store(tmp_path / "s.sqlite") as store:
        trail = _interrupted_trail(store, RestorePoint(mode=None, native={"HDG_P": 0.6}), written=0.8)
        done = recover(link, store, trail, decide=lambda found: True)
        assert done.applied and not done.complete and any("HDG_P" in p for p in done.problems)
        assert [t.trail_id for t in interrupted(store)] == [trail.trail_id]  # the next start tries again
        assert store._db.execute("SELECT status FROM campaigns").fetchone()[0] == "running"
        fake.silent_params = set()
        again = recover(link, store, interrupted(store)[0], decide=lambda found: True)
        assert again.complete and fake.params["HDG_P"][0] == pytest.approx(0.6) and interrupted(store) == []


def _show_mode(fake, link, custom_mode: int) -> None:
    fake.custom_mode = custom_mode
    fake.emit(mavlink.MAVLink_heartbeat_message(12, 3, 1, custom_mode, 4, 3))
    link.next_telemetry()
    link.next_telemetry()


@pytest.mark.parametrize("asked, restored", [(True, True), (False, False)])
def test_the_mode_goes_back_only_if_it_is_still_one_the_procedure_asked_for(fake_link, tmp_path, asked, restored):
    fake, link = fake_link
    hold, guided = link.profile.mode_number("hold"), link.profile.mode_number("guided")
    _show_mode(fake, link, guided)
    with Store(tmp_path / "s.sqlite") as store:
        trail = _interrupted_trail(store, RestorePoint(mode="hold", native={"HDG_P": 0.6}), written=0.6)
        if asked:
            trail.changes.append({"vehicle_time_s": 11.0, "kind": "ModeRequest", "detail": {"mode": "guided"}})
        done = recover(link, store, trail, decide=lambda found: True)
        assert done.complete
        assert fake.custom_mode == (hold if restored else guided)
        assert any("chosen by someone else" in note for note in done.notes) == (not restored)


@pytest.mark.parametrize("answer, words", [(None, "nobody could be asked"), (False, "the operator declined")])
def test_a_recovery_nobody_agreed_to_says_whether_anyone_was_asked(fake_link, tmp_path, answer, words):
    fake, link = fake_link
    fake.params["HDG_P"] = (0.8, fake.params["HDG_P"][1])
    with Store(tmp_path / "s.sqlite") as store:
        trail = _interrupted_trail(store, RestorePoint(mode=None, native={"HDG_P": 0.6}), written=0.8)
        done = recover(link, store, trail, decide=lambda found: answer)
    assert not done.applied and fake.params["HDG_P"][0] == pytest.approx(0.8)
    assert done.notes == [next(n for n in done.notes if n.startswith(words))]


def test_results_show_a_campaign_whose_process_died_as_interrupted(tmp_path, capsys):
    """The store still reads ``running`` until the next start closes it; ``companion results`` says
    what happened meanwhile (a live campaign stays ``running``)."""
    import json

    from companion.cli.main import main

    path = tmp_path / "s.sqlite"
    with Store(path) as store:
        vehicle = store.add_vehicle("v")
        dead = store.start_campaign(vehicle, "identification")
        _mark_dead(store)
        alive = store.start_campaign(vehicle, "identification")  # this process: alive
    assert main(["results", "--store", str(path), "--json"]) == 0
    shown = {c["id"]: c for c in json.loads(capsys.readouterr().out)["campaigns"]}
    assert shown[dead]["status"] == "interrupted" and "companion recover" in shown[dead]["reason"]
    assert shown[alive]["status"] == "running"
    assert main(["results", "--store", str(path), "--campaign", str(dead)]) == 0
    assert f"campaign {dead} (identification) on v: interrupted" in capsys.readouterr().out
