"""``companion analyze`` and the log readers (SPEC C10): CSV and tlog written by the test, JSON
keys, figures, and clear errors on bad input."""
from __future__ import annotations

import csv
import json
import math
import struct

import numpy as np
import pytest

from companion.cli.main import main
from companion.records.logs import LogError, read_csv, read_tlog
from harness.datasets import angle_error_deg, current_vector, romeo_points, surge_experiment, synth_square, synth_turn


def write_csv(path, columns: dict[str, np.ndarray]) -> None:
    names = list(columns)
    with open(path, "w", newline="") as handle:
        writer = csv.writer(handle)
        writer.writerow(names)
        for row in zip(*(columns[n] for n in names)):
            writer.writerow([f"{v:.9g}" for v in row])


def square_csv(path, current, seed=1) -> None:
    d = synth_square(current, seed, dt=1.0)
    write_csv(path, {"t": d["t"], "north": d["north"], "east": d["east"], "down": d["down"], "roll": d["roll"],
                     "pitch": d["pitch"], "yaw": d["yaw"], "u": d["vel_body"][:, 0], "v": d["vel_body"][:, 1],
                     "w": d["vel_body"][:, 2]})


def run_cli(capsys, *argv) -> tuple[int, str, str]:
    code = main(["analyze", *argv])
    out = capsys.readouterr()
    return code, out.out, out.err


def test_squares_csv_json(tmp_path, capsys):
    cur = current_vector(0.012, 140.0)
    path = tmp_path / "square.csv"
    square_csv(path, cur)
    code, out, _ = run_cli(capsys, "squares", "--input", str(path), "--json")
    assert code == 0
    result = json.loads(out)
    for key in ("surge_water", "sway_water", "heave_water", "current_speed", "current_dir_deg", "condition_number"):
        assert key in result
    assert result["current_speed"] == pytest.approx(0.012, abs=0.003)
    assert angle_error_deg(result["current_dir_deg"], 140.0) < 15.0
    assert result["surge_water"] == pytest.approx(1.8, abs=0.005)


def test_squares_human_output_and_plot(tmp_path, capsys):
    path = tmp_path / "square.csv"
    square_csv(path, current_vector(0.01, 20.0))
    png = tmp_path / "square.png"
    code, out, _ = run_cli(capsys, "squares", "--input", str(path), "--plot", str(png))
    assert code == 0
    assert "current" in out and "towards" in out and "condition number" in out
    assert png.stat().st_size > 1000


def test_turns_csv_json_and_plot(tmp_path, capsys):
    cur = current_vector(0.015, 200.0)
    d = synth_turn(cur, 3, rate_deg_s=4.8)
    n = d["t"].size
    path = tmp_path / "turn.csv"
    write_csv(path, {"t": d["t"], "north": d["north"], "east": d["east"], "down": np.full(n, 100.0),
                     "roll": np.zeros(n), "pitch": np.zeros(n), "yaw": d["yaw"], "u": np.full(n, 1.3),
                     "v": np.zeros(n), "w": np.zeros(n), "rudder": np.full(n, -0.22)})
    png = tmp_path / "turn.png"
    code, out, _ = run_cli(capsys, "turns", "--input", str(path), "--json", "--plot", str(png))
    assert code == 0
    result = json.loads(out)
    for key in ("radius_m", "turn_rate_deg_s", "current_speed", "current_dir_deg", "residual_std_m"):
        assert key in result
    assert result["radius_m"] == pytest.approx(d["radius"], rel=0.01)
    assert result["turn_rate_deg_s"] == pytest.approx(4.8, rel=0.01)
    assert result["current_speed"] == pytest.approx(0.015, abs=0.003)
    assert png.stat().st_size > 1000


# --------------------------------------------------------------------------- tlog
def write_tlog(path, current, seed=4) -> None:
    """A tlog as the simulator would record it: SERVO_OUTPUT_RAW + ATTITUDE at 2 Hz, LOCAL_POSITION_NED
    at 1 Hz, each message preceded by its 8-byte big-endian µs time stamp (the tlog format)."""
    from pymavlink.dialects.v20 import ardupilotmega as mavlink

    mav = mavlink.MAVLink(None, srcSystem=1, srcComponent=1)
    d = synth_square(current, seed, dt=0.5)
    with open(path, "wb") as handle:
        for i, t in enumerate(d["t"]):
            ms = int(round(t * 1000))
            stamp = struct.pack(">Q", 1_700_000_000_000_000 + ms * 1000)
            msgs = [
                mavlink.MAVLink_servo_output_raw_message(ms * 1000, 0, 1600, 1500, 1800, 1500, 1500, 1500, 1500, 1500),
                mavlink.MAVLink_attitude_message(ms, d["roll"][i], d["pitch"][i], d["yaw"][i], 0.0, 0.0, 0.0),
            ]
            if i % 2 == 0:
                vn, ve, vd = d["vel_ned"][i]
                msgs.append(mavlink.MAVLink_local_position_ned_message(ms, d["north"][i], d["east"][i], d["down"][i],
                                                                       vn, ve, vd))
            for msg in msgs:
                handle.write(stamp + msg.pack(mav))


def test_tlog_reader_rotates_velocity_and_converts_servos(tmp_path):
    path = tmp_path / "run.tlog"
    write_tlog(path, current_vector(0.01, 90.0))
    nav = read_tlog(str(path))
    assert len(nav) == 600  # 600 s of LOCAL_POSITION_NED at 1 Hz
    assert nav.rudder == pytest.approx(np.full(len(nav), 100 / 500 * 0.5236))
    assert nav.thrust == pytest.approx(np.full(len(nav), 0.8))
    # velocity over ground back in body axes: surge ≈ 1.8 m/s on the steady legs
    assert np.median(nav.u) == pytest.approx(1.8, abs=0.02)


def test_squares_from_tlog(tmp_path, capsys):
    cur = current_vector(0.015, 300.0)
    path = tmp_path / "run.tlog"
    write_tlog(path, cur)
    code, out, _ = run_cli(capsys, "squares", "--input", str(path), "--json")
    assert code == 0
    result = json.loads(out)
    assert math.hypot(result["current_north"] - cur[0], result["current_east"] - cur[1]) < 0.003
    assert angle_error_deg(result["current_dir_deg"], 300.0) < 15.0


# --------------------------------------------------------------------------- eta / inertia
def test_eta_table_csv(tmp_path, capsys):
    velocity, force, second = romeo_points(5)
    path = tmp_path / "eta.csv"
    write_csv(path, {"velocity": velocity, "force": force, "mapping": second.astype(float)})
    code, out, _ = run_cli(capsys, "eta", "--input", str(path), "--json")
    assert code == 0
    result = json.loads(out)
    assert set(result["models"]) == {"LNB", "LB", "LQNB", "LQB"}
    lnb = result["models"]["LNB"]
    assert set(lnb) >= {"estimates", "sigma", "j_ls", "dof"}
    assert lnb["dof"] == 12
    assert lnb["estimates"]["k"] == pytest.approx(36.11, rel=0.15)
    assert result["best"] in result["models"]


def test_eta_raw_record_fits_regime_velocities(tmp_path, capsys):
    """Raw record: constant-force runs, position only; the regime velocities come from x = u·t + x0."""
    rng = np.random.default_rng(9)
    k, eta = 36.11, 0.89
    rows = {"t": [], "yaw": [], "force": [], "mapping": []}
    t0, psi = 0.0, 0.0
    for mapping, forces in ((0, np.linspace(1, 6.5, 7)), (1, -np.linspace(1, 6.5, 7))):
        for f in forces:
            rate = (eta if mapping else 1.0) * f / k
            tt = np.arange(0.0, 40.0, 0.1)
            rows["t"].extend(t0 + tt)
            rows["yaw"].extend(np.arctan2(np.sin(psi + rate * tt), np.cos(psi + rate * tt)) + rng.normal(0, 0.002, tt.size))
            rows["force"].extend(np.full(tt.size, f))
            rows["mapping"].extend(np.full(tt.size, mapping))
            psi += rate * 40.0
            t0 += 40.0
    path = tmp_path / "raw.csv"
    write_csv(path, {key: np.array(v) for key, v in rows.items()})
    code, out, _ = run_cli(capsys, "eta", "--input", str(path), "--axis", "yaw", "--json")
    assert code == 0, out
    result = json.loads(out)
    assert len(result["regime_points"]) == 14
    lnb = result["models"]["LNB"]["estimates"]
    assert lnb["k"] == pytest.approx(k, rel=0.01) and lnb["eta"] == pytest.approx(eta, rel=0.01)
    assert result["best"] == "LNB"


def test_inertia_csv(tmp_path, capsys):
    t, x, u, force = surge_experiment()
    path = tmp_path / "inertia.csv"
    write_csv(path, {"t": t, "position": x, "force": force})
    code, out, _ = run_cli(capsys, "inertia", "--input", str(path), "--k", "38", "--kq", "333", "--json")
    assert code == 0
    result = json.loads(out)
    assert result["mass"] == pytest.approx(675.0, rel=0.01)
    assert result["sigma"] > 0 and "omega_opt_rad_s" in result


# --------------------------------------------------------------------------- bad input
@pytest.mark.parametrize(
    "content,message",
    [
        ("", "empty"),
        ("t,north,east\n1,2,3\n", "missing column"),
        ("t,north,east,down,roll,pitch,yaw,u,v,w\n", "no data rows"),
        ("t,north,east,down,roll,pitch,yaw,u,v,w\n0,1,2,3,4,5,6,7,8,abc\n", "not a number"),
        ("t,north,east,down,roll,pitch,yaw,u,v,w\n0,1,2,3\n", "fields"),
    ],
)
def test_bad_csv_exits_1_with_message(tmp_path, capsys, content, message):
    path = tmp_path / "bad.csv"
    path.write_text(content)
    code, out, err = run_cli(capsys, "squares", "--input", str(path))
    assert code == 1
    assert message in err and str(path) in err
    with pytest.raises(LogError, match=message):
        read_csv(str(path))


def test_missing_file_and_garbage_tlog(tmp_path, capsys):
    code, _, err = run_cli(capsys, "turns", "--input", str(tmp_path / "nope.csv"))
    assert code == 1 and "no such file" in err
    garbage = tmp_path / "garbage.tlog"
    garbage.write_bytes(bytes(range(256)) * 4)
    code, _, err = run_cli(capsys, "squares", "--input", str(garbage))
    assert code == 1 and "error" in err


def test_inertia_needs_drag(tmp_path, capsys):
    path = tmp_path / "inertia.csv"
    write_csv(path, {"t": np.arange(30.0), "position": np.arange(30.0), "force": np.ones(30)})
    code, _, err = run_cli(capsys, "inertia", "--input", str(path))
    assert code == 1 and "--k" in err
