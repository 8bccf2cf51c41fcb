"""``companion sweep`` on Dask: specs, variants, rows, the store table, the report, and
real sweeps — on the local default and on a ``dask scheduler`` + 2 ``dask worker`` processes started
here on loopback — that give the same rows as each other and as a single ``companion rehearse`` of
a case; Ctrl-C keeps the finished rows, a rerun resumes, a failing case is recorded with its reason
and the sweep goes on.

The real sweeps fly tiny rehearsals (yaw at one thrust, no steps, no behaviours, 200x) so the module
stays well under a minute on 2 cores. No assertion depends on timing.
"""
from __future__ import annotations

import csv
import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import pytest

from companion.cli.main import main
from companion.records.store import MIGRATIONS, Store
from companion.records.variants import VariantError, derive_preset
from companion.sweep.case import row_from_summary
from companion.sweep.spec import SpecError, spec_from_dict

# ============================================================================ fast: specs, variants, rows


def run_cli(capsys, *argv: str) -> tuple[int, str, str]:
    try:
        code = main(list(argv))
    except SystemExit as exc:
        code = exc.code if isinstance(exc.code, int) else 1
    out = capsys.readouterr()
    return code, out.out, out.err


def test_a_spec_expands_into_the_cross_product_in_a_fixed_order():
    spec = spec_from_dict({"name": "t", "seeds": "1..3", "currents": {"speed": [0, 0.1], "direction_deg": [90]},
                           "perturb": {"mass": "±10%", "b2": [0.8]}, "noise": "1,2", "thrusts": [[0.6], [0.8, 1.0]],
                           "axes": "yaw", "behaviors": "none", "steps": False})
    cases = spec.cases()
    assert len(cases) == 3 * 2 * 2 * 3 * 2  # seeds, currents, noise, mass levels (b2 one level), thrust lists
    assert len({case.key for case in cases}) == len(cases)
    assert cases[0].seed == 1 and cases[-1].seed == 3
    assert cases[2].current == (0.0, 0.0) and cases[-1].current == pytest.approx((0.0, 0.1))  # towards east
    assert {dict(c.perturb).get("mass") for c in cases} == {0.9, None, 1.1}  # factor 1: the preset itself
    assert all(dict(c.perturb)["b2"] == 0.8 for c in cases)
    assert cases == spec.cases()  # deterministic


def test_a_case_is_fully_resolved_and_its_key_ignores_the_speedup():
    plain = spec_from_dict({"seeds": [4]}).cases()[0]
    assert plain.behaviors == ("roll", "min_speed") and plain.thrusts == (0.6, 0.7, 0.8, 0.9, 1.0)
    hugin = spec_from_dict({"presets": "hugin"}).cases()[0]
    assert hugin.steady_state and hugin.current == (0.007, -0.012) and hugin.behaviors == ()  # the preset's defaults
    fast = spec_from_dict({"seeds": [4], "speedup": 400}).cases()[0]
    assert fast.key == plain.key
    assert spec_from_dict({"seeds": [5]}).cases()[0].key != plain.key
    assert plain.command().startswith("companion rehearse --preset starfish --seed 4 --current 0,0 ")


def test_the_reproduce_command_is_a_valid_rehearse_command_line():
    from companion.cli.main import build_parser

    case = spec_from_dict({"seeds": [2], "currents": [[0.05, -0.02]], "perturb": {"mass": [1.1], "trim": [2]},
                           "noise": [1.5], "thrusts": [0.7], "axes": "yaw", "steps": False, "quick": True}).cases()[0]
    args = build_parser(("rehearse",)).parse_args(["rehearse", *case.rehearse_args()])
    assert (args.seed, args.current, args.thrusts, args.axes, args.no_steps) == (2, "0.05,-0.02", (0.7,), "yaw", True)
    assert args.perturb == [(("mass", 1.1), ("trim", 2.0))] and args.noise == 1.5 and args.procedure == "quick"
    assert args.behaviors == "roll,min-speed"
    # a case without "quick" runs the thesis procedure, as the cases recorded before the option did
    plain = spec_from_dict({"seeds": [2]}).cases()[0]
    assert build_parser(("rehearse",)).parse_args(["rehearse", *plain.rehearse_args()]).procedure == "thesis"


@pytest.mark.parametrize("data, words", [
    ({"seed": [1], "seeds": [2]}, "twice"),
    ({"colour": "red"}, "unknown field"),
    ({"seeds": "8..1"}, "backwards"),
    ({"seeds": [1.5]}, "whole numbers"),
    ({"currents": [[0.1]]}, "[north, east]"),
    ({"perturb": {"wingspan": [1.1]}}, "unknown perturbation"),
    ({"perturb": {"mass": [0]}}, "> 0"),
    ({"thrusts": [0]}, "(0, 1]"),
    ({"behaviors": "dance"}, "unknown dance"),
    ({"noise": "nan"}, "finite"),
    ({"schedules": "heading,pitch", "axes": "yaw"}, "pitch axis"),
])
def test_a_bad_spec_is_refused_in_one_sentence(data, words):
    with pytest.raises(SpecError, match=None) as caught:
        spec_from_dict(data)
    assert words.lower() in str(caught.value).lower()


def test_spec_files_json_and_yaml_and_flags_over_them(tmp_path, capsys):
    (tmp_path / "s.yaml").write_text("seeds: 1..2\ncurrents:\n  - [0, 0]\n  - [0.05, 0]\naxes: [yaw]\n")
    code, out, err = run_cli(capsys, "sweep", "--spec", str(tmp_path / "s.yaml"), "--seeds", "7", "--dry-run",
                             "--json")
    assert code == 0, err
    listing = json.loads(out)
    assert listing["spec"]["name"] == "s" and [c["inputs"]["seed"] for c in listing["cases"]] == [7, 7]
    assert [c["inputs"]["current_north"] for c in listing["cases"]] == [0, 0.05]
    (tmp_path / "bad.json").write_text('{"seeds": [1], "presets": 3}')
    code, out, err = run_cli(capsys, "sweep", "--spec", str(tmp_path / "bad.json"), "--dry-run")
    assert code == 1 and "presets" in err and "Traceback" not in err
    code, _, err = run_cli(capsys, "sweep", "--spec", str(tmp_path / "missing.json"))
    assert code == 1 and "cannot read" in err
    code, _, err = run_cli(capsys, "sweep", "--scheduler", "localhost:8786", "--dry-run")
    assert code == 1 and "tcp://" in err


def test_a_variant_scales_the_named_fields_and_the_noise():
    base = json.loads((Path(__file__).parents[1] / "sim" / "presets" / "starfish.json").read_text())
    variant = derive_preset(base, {"mass": 1.1, "b2": 0.8, "roll.damping_linear": 2.0}, noise=3.0)
    plane, yaw = variant["dive_plane"], variant["yaw"]
    assert plane["mass"] == pytest.approx(66.0 * 1.1) and plane["weight"] == pytest.approx(647.5 * 1.1)
    assert plane["buoyancy"] == pytest.approx(649.4 * 1.1) and plane["rho"] == 1000.0
    assert yaw["b2_constant"] == pytest.approx(0.2592 * 0.8) and yaw["a22_constant"] == base["yaw"]["a22_constant"]
    assert variant["roll"]["damping_linear"] == pytest.approx(-0.266)
    assert variant["sensors"]["attitude_deg"] == pytest.approx(0.9)
    assert "mass×1.1" in variant["name"] and base["dive_plane"]["mass"] == 66.0  # the base is not touched
    with pytest.raises(VariantError, match="no numeric yaw.nothing"):
        derive_preset(base, {"yaw.nothing": 1.1})


def test_the_simulator_reads_a_variant_file(tmp_path):
    base = json.loads((Path(__file__).parents[1] / "sim" / "presets" / "starfish.json").read_text())
    path = tmp_path / "v.json"
    path.write_text(json.dumps(derive_preset(base, {"b2": 0.5})))
    truth = [json.loads(subprocess.run([sys.executable, "-m", "sim", "linearize", "--preset", preset, "--speed", "1.5",
                                        "--json"], capture_output=True, text=True, check=True).stdout)
             for preset in ("starfish", str(path))]
    assert truth[1]["b2"] == pytest.approx(0.5 * truth[0]["b2"]) and truth[1]["a22"] == pytest.approx(truth[0]["a22"])


SUMMARY = {
    "status": "completed", "reason": None, "vehicle_time_s": 300.0,
    "runs": [{"a22": -1.1, "true_a22": -1.0, "b2": 0.99, "true_b2": 1.0, "r2": 0.95, "converged_s": 12.0},
             {"a22": -1.02, "true_a22": -1.0, "b2": 1.0, "true_b2": 1.0, "r2": 0.99, "converged_s": 11.0}],
    "heading_steps": [{"label": "scheduled", "max_overshoot_pct": 7.0}, {"label": "constant", "max_overshoot_pct": 15.0},
                      {"label": "scheduled", "max_overshoot_pct": 6.5}],
    "roll": {"status": "completed", "std_open_deg": 1.6, "std_closed_deg": 0.5},
    "min_speed": {"status": "failed", "thrust_ratio_final": 0.45, "thrust_ratio_star": 0.432, "settle_time_s": None},
    "reproducibility": {"exact": True},
}


def test_a_row_holds_inputs_outcome_and_figures():
    case = spec_from_dict({"seeds": [3], "perturb": {"mass": [1.1]}}).cases()[0]
    row = row_from_summary(case, SUMMARY)
    assert row["case_key"] == case.key and row["seed"] == 3 and row["perturb_mass"] == 1.1
    assert row["status"] == "completed" and row["failure"] is None
    assert row["a22_error_max_pct"] == pytest.approx(10.0) and row["b2_error_max_pct"] == pytest.approx(1.0)
    assert row["r2_min"] == 0.95 and row["overshoot_scheduled_max_pct"] == 7.0
    assert row["overshoot_constant_max_pct"] == 15.0 and row["roll_sigma_reduction"] == pytest.approx(3.2)
    assert row["min_speed_status"] == "failed" and row["min_speed_settle_s"] is None
    failed = row_from_summary(case, None, "error", "simulator did not start (preset 'x'): exited with code 2: …")
    assert failed["failure"] == "simulator did not start" and failed["models"] == 0


def test_the_report_shows_distributions_failures_and_worst_cases(tmp_path):
    from companion.sweep.report import write_sweep_report

    cases = spec_from_dict({"seeds": "1..4", "currents": "0,0;0.1,0"}).cases()
    rows = [{**row_from_summary(case, SUMMARY), "command": case.command()} for case in cases[:-1]]
    rows.append({**row_from_summary(cases[-1], None, "error", "timed out after 60 s"), "command": cases[-1].command()})
    path = write_sweep_report(rows, tmp_path, name="t", spec={"seeds": [1, 2, 3, 4]})
    text = path.read_text()
    assert (tmp_path / "sweep_overview.png").stat().st_size > 10_000
    assert "Failures by reason" in text and "error: timed out after # s" in text
    assert "min-speed failed (campaign completed)" in text
    assert "By current" in text and cases[-1].command().replace("'", "&#x27;") in text


def test_the_store_migrates_to_the_sweep_table_and_keeps_what_it_held(tmp_path):
    path = tmp_path / "old.sqlite"
    db = sqlite3.connect(path)
    db.executescript(MIGRATIONS[0])
    db.execute("PRAGMA user_version=1")
    db.execute("INSERT INTO vehicles(name, config_json, created_utc) VALUES ('auv', '{}', 'then')")
    db.commit()
    db.close()
    with Store(path) as store:
        assert store.schema_version == len(MIGRATIONS) >= 2
        assert len(store._db.execute("SELECT * FROM vehicles").fetchall()) == 1
        store.put_sweep_case("k1", "s", "failed", "why", {"seed": 1}, {"seed": 1, "status": "failed"})
        store.put_sweep_case("k1", "s2", "completed", None, {"seed": 1}, {"seed": 1, "status": "completed"})
        store.put_sweep_case("k2", "s2", "completed", None, {"seed": 2}, {"seed": 2}, {"runs": []})
        cases = store.sweep_cases(with_summary=True)
    assert [(c["case_key"], c["sweep"], c["status"]) for c in cases] == [("k1", "s2", "completed"),
                                                                         ("k2", "s2", "completed")]
    assert cases[1]["summary"] == {"runs": []}


# ============================================================================ real sweeps on Dask
TINY = ["--axes", "yaw", "--thrusts", "0.8", "--no-steps", "--behaviors", "none", "--speedup", "200"]
AXES = ["--seeds", "1..2", "--currents", "0,0;0.05,-0.02"]
#: what describes one run of a case, not the case: wall time, where, the command, and whether the
#: run was exact (a wall-clock guard may act on a badly overloaded machine; README "Same seed")
RUN_COLUMNS = ("wall_s", "host", "command", "exact")


def sweep_cli(workdir: Path, *args: str) -> subprocess.CompletedProcess:
    """``companion sweep ARGS --json`` in a child process (it must succeed), its cases' temporary
    folders under workdir/tmp."""
    done = subprocess.run([sys.executable, "-m", "companion", "sweep", *args, "--json"], cwd=workdir,
                          capture_output=True, text=True, timeout=600, env=_env(workdir), check=False)
    assert done.returncode == 0, done.stderr[-3000:]
    return done


def _env(workdir: Path) -> dict:
    tmp = workdir / "tmp"
    tmp.mkdir(exist_ok=True)
    return {**os.environ, "TMPDIR": str(tmp), "PYTHONUNBUFFERED": "1"}


def stored_rows(store: Path) -> dict[str, dict]:
    with Store(store, read_only=True) as db:
        return {c["case_key"]: c["row"] for c in db.sweep_cases()}


def comparable(row: dict) -> dict:
    return {k: v for k, v in row.items() if k not in RUN_COLUMNS}


def no_case_left(workdir: Path) -> None:
    """Every case's temporary folder is gone and no process of ours still runs from it."""
    assert not list((workdir / "tmp").glob("sweep-*"))
    ps = subprocess.run(["ps", "-eo", "args"], capture_output=True, text=True, check=True).stdout
    assert str(workdir / "tmp") not in ps


#: the tests of the local sweep run on one worker: its sweep (about 25 s) is made once, not once per
#: worker that one of them lands on; session-scoped, because the worker may run other modules' tests
#: between these, and a module fixture would be made again after them (twice, measured)
ONE_WORKER = pytest.mark.xdist_group("local-sweep")


@pytest.fixture(scope="session")
def local_sweep(tmp_path_factory) -> dict:
    """The 2 x 2 sweep on the local default cluster (2 workers), interrupted by SIGINT once its first
    two rows are in (the other two cases have just started) and resumed: the workdir, what the
    interrupted run kept, the resume's outcome and the final rows."""
    workdir = tmp_path_factory.mktemp("local")
    command = [sys.executable, "-m", "companion", "sweep", *AXES, *TINY, "--workers", "2", "--out", "out", "--json"]
    process = subprocess.Popen(command, cwd=workdir, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                               env=_env(workdir))
    csv_path = workdir / "out" / "sweep.csv"
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline and process.poll() is None:
        if csv_path.is_file() and len(csv_path.read_text().splitlines()) >= 3:  # a header and two rows
            break
        time.sleep(0.2)
    process.send_signal(signal.SIGINT)
    out, err = process.communicate(timeout=300)
    first = {"code": process.returncode, "out": json.loads(out) if out.strip() else None, "err": err,
             "rows": stored_rows(workdir / "out" / "sweep.sqlite"),
             "csv_rows": list(csv.DictReader(csv_path.open()))}
    no_case_left(workdir)
    resumed = json.loads(sweep_cli(workdir, *AXES, *TINY, "--workers", "2", "--out", "out").stdout)
    return {"workdir": workdir, "first": first, "resumed": resumed,
            "rows": stored_rows(workdir / "out" / "sweep.sqlite")}


@pytest.mark.e2e
@ONE_WORKER
def test_ctrl_c_keeps_every_finished_row_and_a_rerun_resumes(local_sweep):
    first, resumed = local_sweep["first"], local_sweep["resumed"]
    assert first["code"] in (130, 0), first["err"][-2000:]  # 0 only if every case had finished already
    kept = first["rows"]
    assert kept and all(row["status"] == "completed" for row in kept.values())
    assert {r["case_key"] for r in first["csv_rows"]} == set(kept)  # the CSV holds what the store holds
    if first["code"] == 130:
        assert first["out"]["stopped"] and first["out"]["unfinished"] == 4 - len(kept)
    assert resumed["skipped"] == len(kept) and resumed["ran"] == 4 - len(kept) and not resumed["stopped"]
    if first["code"] == 130:
        assert resumed["ran"] >= 1  # what the interrupted run did not finish, the resume did
    assert resumed["statuses"] == {"completed": 4}
    for key, row in kept.items():  # a resume leaves the rows it skipped as they were
        assert local_sweep["rows"][key] == row
    no_case_left(local_sweep["workdir"])


@pytest.mark.e2e
@ONE_WORKER
def test_the_local_sweep_writes_rows_csv_and_report(local_sweep):
    rows, out = local_sweep["rows"], local_sweep["workdir"] / "out"
    assert len(rows) == 4
    assert {(r["seed"], r["current_north"], r["current_east"]) for r in rows.values()} == \
        {(1, 0, 0), (1, 0.05, -0.02), (2, 0, 0), (2, 0.05, -0.02)}
    for row in rows.values():
        assert row["status"] == "completed" and row["models"] == 1 and row["exact"] in (True, False)
        assert row["a22_error_max_pct"] < 10 and row["r2_min"] > 0.9
        assert row["command"].startswith("companion rehearse --preset starfish --seed ")
    table = list(csv.DictReader((out / "sweep.csv").open()))
    assert [r["seed"] for r in table] == ["1", "1", "2", "2"]  # case order
    assert {r["case_key"] for r in table} == set(rows)
    report = (out / "report.html").read_text()
    assert "sweep_overview.png" in report and (out / "sweep_overview.png").is_file()


@pytest.mark.e2e
@ONE_WORKER
def test_a_row_equals_a_single_rehearse_of_its_case(local_sweep, tmp_path):
    cases = spec_from_dict({"seeds": "1..2", "currents": "0,0;0.05,-0.02", "axes": "yaw", "thrusts": [0.8],
                            "steps": False, "behaviors": "none"}).cases()
    case = cases[3]
    row = local_sweep["rows"][case.key]
    done = subprocess.run([sys.executable, "-m", "companion", "rehearse", *case.rehearse_args(), "--speedup", "100",
                           "--json", "--no-report", "--out", str(tmp_path / "alone")],
                          capture_output=True, text=True, timeout=300, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    assert row["command"] == case.command()
    assert comparable(row_from_summary(case, json.loads(done.stdout))) == comparable(row)


@pytest.fixture
def dask_cluster(tmp_path):
    """A real ``dask scheduler`` and two ``dask worker`` processes on 127.0.0.1, random ports; only
    these processes are stopped afterwards, by PID."""
    scheduler_file = tmp_path / "scheduler.json"
    env = _env(tmp_path)
    started: list[subprocess.Popen] = []

    def start(args: list[str], log: str) -> subprocess.Popen:
        with open(tmp_path / log, "w") as handle:
            process = subprocess.Popen([sys.executable, "-m", "dask", *args], cwd=tmp_path, stdout=handle,
                                       stderr=subprocess.STDOUT, env=env)
        started.append(process)
        return process

    try:
        start(["scheduler", "--host", "127.0.0.1", "--port", "0", "--dashboard-address", "127.0.0.1:0",
               "--scheduler-file", str(scheduler_file)], "scheduler.log")
        deadline = time.monotonic() + 120
        while not scheduler_file.is_file() and time.monotonic() < deadline:
            time.sleep(0.2)
        address = json.loads(scheduler_file.read_text())["address"]
        assert address.startswith("tcp://127.0.0.1:")
        for n in (1, 2):
            start(["worker", address, "--host", "127.0.0.1", "--no-nanny", "--nthreads", "1", "--no-dashboard",
                   "--dashboard-address", "127.0.0.1:0", "--name", f"w{n}", "--local-directory", str(tmp_path / f"w{n}")],
                  f"worker{n}.log")
        while time.monotonic() < deadline and not all(
                "Registered to" in (tmp_path / f"worker{n}.log").read_text() for n in (1, 2)):
            time.sleep(0.2)
        yield address
    finally:
        for process in reversed(started):  # each worker, then the scheduler, each gone before the next
            if process.poll() is None:
                process.terminate()
            try:
                process.wait(timeout=30)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()


@pytest.mark.slow
@pytest.mark.e2e
@ONE_WORKER
def test_a_real_dask_cluster_gives_the_same_rows_and_records_a_failing_case(local_sweep, dask_cluster, tmp_path):
    """Two of the local sweep's cases (one per worker, to keep the suite short; the README reports
    the whole 8 x 2 sweep compared the same way) and the same two on a preset that does not exist:
    those fail, their reason comes back from the worker, and the sweep goes on."""
    done = sweep_cli(tmp_path, "--presets", "starfish,nope", "--seeds", "1..2", "--currents", "0.05,-0.02", *TINY,
                     "--scheduler", dask_cluster, "--out", "out")
    outcome = json.loads(done.stdout)
    assert outcome["engine"] == f"Dask {dask_cluster}, 2 worker(s)"
    assert (outcome["ran"], outcome["completed"], outcome["failed"]) == (4, 2, 2)
    rows = stored_rows(tmp_path / "out" / "sweep.sqlite")
    failed = [row for row in rows.values() if row["preset"] == "nope"]
    assert len(failed) == 2 and all(row["status"] == "error" for row in failed)
    assert all("unknown vehicle preset 'nope'" in row["reason"] for row in failed)
    assert {row["failure"] for row in failed} == {"simulator did not start"}
    with Store(tmp_path / "out" / "sweep.sqlite", read_only=True) as store:
        assert all("unknown vehicle preset" in item["log_tail"] for item in store.sweep_cases(with_summary=True)
                   if item["row"]["preset"] == "nope")
    report = (tmp_path / "out" / "report.html").read_text()
    assert "simulator did not start" in report and "companion rehearse --preset nope --seed 1" in report
    remote = {key: row for key, row in rows.items() if row["preset"] == "starfish"}
    local = {key: local_sweep["rows"][key] for key in remote}  # a KeyError: a case the local sweep did not have
    assert len(remote) == 2 and {row["current_north"] for row in remote.values()} == {0.05}
    for key in remote:
        assert comparable(remote[key]) == comparable(local[key])
    no_case_left(tmp_path)
