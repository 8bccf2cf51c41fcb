"""``companion run`` as the systemd unit runs it (``deploy/marine-companion.service``).

* The unit file passes ``systemd-analyze verify`` (skipped where systemd is absent).
* Its stop timeout exceeds the worst case of a restore (``companion.service.stop_budget``) for the
  largest footprint of any registered autopilot; it stops with one SIGTERM and restarts on failure.
* The exact stop path: ``companion run --config FILE --http 127.0.0.1:0`` beside the simulator, a
  campaign started by a ground station's COMMAND_LONG, the status page read during it, then the
  unit's KillSignal in the middle of a rudder doublet. The process exits 0 within TimeoutStopSec,
  and the vehicle is as found: mode, every gain, no RC override left holding a fin (the simulator is
  told to keep overrides for ever, so one not released would show), and the logs are journald's
  (priority prefixes, no traceback).
"""
from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
import urllib.request
from pathlib import Path

import pytest

from behaviors.schedules import schedule_kind
from companion.link.autopilots import registered_profiles
from companion.procedures.campaign import CampaignConfig, IdentificationCampaign
from companion.procedures.resident import ServeConfig
from companion.records.store import Store
from companion.service.stop_budget import stop_budget
from harness.mavlink_clients import wait_for_line
from tests.test_e2e_gcs import acks_for, arm, start, wait_for_companion

ROOT = Path(__file__).resolve().parents[1]
UNIT = ROOT / "deploy" / "marine-companion.service"
MAV_CMD_USER_1, IN_PROGRESS = 31010, 5
MANUAL, HOLD = 19, 2  # the simulator's modes (companion.link.autopilots.sim)
GAINS = ("HDG_P", "HDG_I", "HDG_TRIM", "PIT_P", "PIT_I")
SPEEDUP = 10  # acknowledgements keep their margin on a loaded machine (the product runs at 1x)


def unit_settings(section: str = "Service") -> dict[str, str]:
    """KEY=VALUE lines of one section of the unit file (the last value of a key wins, as in systemd)."""
    found, current = {}, None
    for line in UNIT.read_text().splitlines():
        line = line.strip()
        if line.startswith("[") and line.endswith("]"):
            current = line[1:-1]
        elif current == section and "=" in line and not line.startswith("#"):
            key, value = line.split("=", 1)
            found[key.strip()] = value.strip()
    return found


def seconds(text: str) -> float:
    """A systemd time span as this unit writes them: ``240``, ``240s``, ``4min``."""
    match = re.fullmatch(r"(\d+)\s*(s|sec|min)?", text)
    assert match, text
    return float(match.group(1)) * (60.0 if match.group(2) == "min" else 1.0)


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze is not installed")
def test_the_unit_passes_systemd_analyze_verify(tmp_path):
    """Verified as shipped, except its ExecStart program, which must exist where it is verified."""
    executable = shutil.which("companion") or sys.executable
    text = UNIT.read_text().replace("/opt/marine-companion/bin/companion", executable)
    unit = tmp_path / UNIT.name
    unit.write_text(text)
    done = subprocess.run(["systemd-analyze", "verify", str(unit)], capture_output=True, text=True, timeout=60)
    complaints = [line for line in (done.stdout + done.stderr).splitlines() if UNIT.name in line]
    assert done.returncode == 0 and complaints == [], done.stdout + done.stderr


def _largest_stop() -> tuple[int, int]:
    """(native parameters of the largest campaign footprint, scheduled natives) over the autopilots."""
    largest = (0, 0)
    for profile in registered_profiles():
        campaign = IdentificationCampaign(CampaignConfig(schedules=("heading", "pitch")).resolved_for(profile))
        natives = profile.natives_touched([n for n in campaign.footprint.parameters if n in profile.params])
        heading = getattr(profile, "heading_schedule", "heading")
        kinds = [schedule_kind(heading if k == "heading" else k) for k in ServeConfig().schedules]
        scheduled = profile.natives_touched([n for k in kinds for n in k.scheduled if n in profile.params])
        largest = max(largest, (len(natives), len(scheduled)))
    return largest


def test_the_unit_stops_with_one_sigterm_and_waits_longer_than_any_restore():
    service = unit_settings()
    parameters, scheduled = _largest_stop()
    budget = stop_budget(parameters, scheduled)
    assert parameters >= 4 and scheduled >= 2
    assert service["KillSignal"] == "SIGTERM" and service["KillMode"] == "mixed"
    assert seconds(service["TimeoutStopSec"]) > budget.total_s, budget.parts
    assert f"{budget.total_s:.0f} s" in UNIT.read_text()  # the comment states the number it was chosen for
    assert service["Restart"] == "on-failure" and service["RestartPreventExitStatus"] == "2"
    assert service["WorkingDirectory"] == f"/var/lib/{service['StateDirectory']}"
    assert " run --config " in service["ExecStart"]


def _read_param(gcs, name: str) -> float:
    for _ in range(5):
        gcs.mav.param_request_read_send(1, 1, name.encode(), -1)
        deadline = time.monotonic() + 2.0
        while time.monotonic() < deadline:
            msg = gcs.recv_match(type="PARAM_VALUE", blocking=True, timeout=0.5)
            if msg is not None and msg.param_id == name:
                return float(msg.param_value)
    raise AssertionError(f"no PARAM_VALUE for {name}")


def _status(url: str) -> dict:
    with urllib.request.urlopen(url + "status.json", timeout=5) as response:
        return json.loads(response.read())


_wait_for_line = wait_for_line  # the shared step (harness.mavlink_clients)


def _servo_after(gcs, vehicle_s: float, wall_limit_s: float = 60.0):
    """The first SERVO_OUTPUT_RAW stamped ``vehicle_s`` of vehicle time after the first one read now
    (its ``time_usec``: the autopilot's clock, whatever the machine's pace); None if none came."""
    first = gcs.recv_match(type="SERVO_OUTPUT_RAW", blocking=True, timeout=5)
    if first is None:
        return None
    deadline = time.monotonic() + wall_limit_s  # a watchdog only: the wait itself is on vehicle time
    while time.monotonic() < deadline:
        msg = gcs.recv_match(type="SERVO_OUTPUT_RAW", blocking=True, timeout=1.0)
        if msg is not None and msg.time_usec - first.time_usec >= vehicle_s * 1e6:
            return msg
    return None


@pytest.mark.slow
@pytest.mark.e2e
def test_the_units_stop_signal_mid_campaign_restores_the_vehicle(sim_factory, mav_client, tmp_path):
    service = unit_settings()
    stop_signal = getattr(signal, service["KillSignal"])
    sim = sim_factory(transport="tcp", speedup=SPEEDUP, seed=2)  # lossless on a loaded machine
    gcs = mav_client(sim.endpoint)
    config = tmp_path / "companion.toml"
    config.write_text(f'[connection]\nconnect = "{sim.endpoint}"\n[store]\npath = "companion.sqlite"\n'
                      f'report_dir = "reports"\n[http]\nlisten = "127.0.0.1:0"\n'
                      f'[logging]\nlevel = "info"\nformat = "journal"\n')
    stderr = tmp_path / "stderr.log"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")])}
    with open(stderr, "w") as err:
        process = subprocess.Popen([sys.executable, "-m", "companion", "run", "--config", str(config)], cwd=tmp_path,
                                   stdout=subprocess.PIPE, stderr=err, text=True, env=env)
    try:
        url = _wait_for_line(stderr, "status page: ", process)
        wait_for_companion(gcs)
        found = {name: _read_param(gcs, name) for name in GAINS}
        gcs.mav.param_set_send(1, 1, b"RC_OVR_TIME", -1.0, 9)  # an override not released would hold for ever
        assert acks_for(gcs, 0, lambda seen: False, 0.5) == [] and _read_param(gcs, "RC_OVR_TIME") == -1.0
        arm(gcs)
        started = start(gcs, MAV_CMD_USER_1)
        assert started and started[0][0] == IN_PROGRESS, started
        deadline = time.monotonic() + 20.0
        page = _status(url)  # the page follows the vehicle within a snapshot or two
        while not (page["procedure"]["state"] == "running" and page["vehicle"]["armed"]) and time.monotonic() < deadline:
            time.sleep(0.1)
            page = _status(url)
        assert page["procedure"]["name"] == "identification" and page["connection"]["profile"] == "sim"
        assert page["vehicle"]["armed"] is True and page["vehicle"]["mode"] in ("manual", "hold"), json.dumps(page)
        # the stop signal in the middle of the training doublet: once the live estimates stream (training
        # has begun), the first sample in the hold mode with the rudder far off centre is the doublet's
        mode, training, deadline = None, False, time.monotonic() + 120.0
        while time.monotonic() < deadline:
            msg = gcs.recv_match(type=["HEARTBEAT", "SERVO_OUTPUT_RAW", "NAMED_VALUE_FLOAT"], blocking=True, timeout=0.5)
            if msg is None:
                continue
            if msg.get_type() == "HEARTBEAT" and msg.get_srcComponent() == 1:
                mode = msg.custom_mode
            elif msg.get_type() == "NAMED_VALUE_FLOAT" and msg.name == "a22":
                training = True
            elif msg.get_type() == "SERVO_OUTPUT_RAW" and training and mode == HOLD and abs(msg.servo1_raw - 1500) > 180:
                break
        else:
            raise AssertionError("no rudder doublet seen within 120 s")
        during = _status(url)
        sent = time.monotonic()
        process.send_signal(stop_signal)
        restored_s = None
        while process.poll() is None and time.monotonic() - sent < seconds(service["TimeoutStopSec"]):
            if restored_s is None and "procedure finished" in stderr.read_text():
                restored_s = time.monotonic() - sent  # logged right after the restore
            time.sleep(0.005)
        process.wait(timeout=1.0)
        stopped_s = time.monotonic() - sent
    finally:
        if process.poll() is None:
            process.kill()
            process.wait()
    log = stderr.read_text()
    assert process.returncode == 0, log[-3000:]
    restored = "?" if restored_s is None else f"{restored_s:.3f}"
    print(f"\nstop: restored {restored} s and exited {stopped_s:.2f} s (wall) after the signal, x{SPEEDUP} simulator; "
          f"campaign progress at the signal {during['procedure'].get('progress_pct')} %")
    # as found: the mode, every gain, no override holding a fin
    mode, deadline = None, time.monotonic() + 10.0
    while mode != MANUAL and time.monotonic() < deadline:
        msg = gcs.recv_match(type="HEARTBEAT", blocking=True, timeout=0.5)
        if msg is not None and msg.get_srcComponent() == 1:
            mode = msg.custom_mode
    assert mode == MANUAL
    assert {name: _read_param(gcs, name) for name in GAINS} == found
    # 15 s of vehicle time (on the vehicle's own clock): fins released to MANUAL's centred stick have long arrived
    servo = _servo_after(gcs, 15.0)
    assert servo is not None and abs(servo.servo1_raw - 1500) <= 2 and abs(servo.servo2_raw - 1500) <= 2, servo
    # journald's lines: a priority on every log line, the abort a warning, no traceback
    logged = [line for line in log.splitlines() if not line.startswith(("status page:", "companion running on"))]
    assert logged and all(re.match(r"<[0-7]>[A-Z]+ ", line) for line in logged), logged
    assert any(line.startswith("<4>WARNING") and "aborting: signal SIGTERM" in line for line in logged), logged
    assert "Traceback" not in log
    with Store(tmp_path / "companion.sqlite", read_only=True) as store:
        campaign = store.campaign(store.latest_campaign_id("identification"))
    assert campaign["status"] == "aborted" and "SIGTERM" in campaign["reason"]
    assert not (tmp_path / "reports").exists()  # a stopping companion does not wait for plots
