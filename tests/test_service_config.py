"""``companion run --config FILE``: the TOML file, its refusals (line and reason, exit code 2), the
flags over the file, and what the resident loop is given."""
from __future__ import annotations

import argparse
import re
from pathlib import Path

import pytest

from companion.cli.commands.run import settings_from
from companion.cli.main import build_parser, main
from companion.procedures.app import AbortFlag
from companion.procedures.resident import Companion, ServeConfig
from companion.records.store import Store
from companion.service.config import key_lines, keys
from harness.inprocess import InProcessLink
from pymavlink.dialects.v20.common import MAV_CMD_USER_1, MAV_CMD_USER_3

ROOT = Path(__file__).resolve().parents[1]
EXAMPLE = ROOT / "deploy" / "companion.toml"
MAV_RESULT_DENIED = 2


def args_for(*argv: str) -> argparse.Namespace:
    return build_parser(("run",)).parse_args(["run", *argv])


def run_main(capsys, *argv: str) -> tuple[int, str]:
    code = main(["run", *argv])
    return code, capsys.readouterr().err


def test_the_example_file_is_valid_and_documents_every_key():
    settings = settings_from(args_for("--config", str(EXAMPLE)))
    assert settings.connect == "udpin:127.0.0.1:14551" and settings.store == "companion.sqlite"
    assert settings.http == "127.0.0.1:8080" and not settings.http_allow_remote
    assert settings.report_dir == "reports" and settings.log_level == "info"
    assert settings.yes is True  # a service puts the vehicle back after a crash without asking
    text = EXAMPLE.read_text()
    for section, table in keys((), (), ()).items():
        assert f"[{section}]" in text, section
        for name in table:  # every key is shown, set or commented out, in its section
            assert re.search(rf"^#? ?{name} = ", text, re.M), f"[{section}] {name} is not in the example"


def test_flags_override_the_file(tmp_path):
    config = tmp_path / "c.toml"
    config.write_text('[connection]\nconnect = "udpin:127.0.0.1:14551"\n[health]\nenabled = true\n'
                      '[store]\npath = "file.sqlite"\n[procedures]\nthrusts = [60, 80]\n')
    settings = settings_from(args_for("--config", str(config), "--connect", "tcp:127.0.0.1:5760", "--no-health",
                                      "--thrusts", "0.7,0.9"))
    assert settings.connect == "tcp:127.0.0.1:5760" and settings.health is False
    assert settings.store == "file.sqlite" and settings.thrusts == (0.7, 0.9)
    assert settings_from(args_for("--config", str(config))).thrusts == (0.6, 0.8)  # percent, as a whole list


def test_the_store_comes_from_the_flag_then_the_file_then_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("COMPANION_STORE", "env.sqlite")
    config = tmp_path / "c.toml"
    config.write_text('[store]\npath = "file.sqlite"\n')
    assert settings_from(args_for("--connect", "tcp:127.0.0.1:5760")).store == "env.sqlite"
    assert settings_from(args_for("--config", str(config))).store == "file.sqlite"
    assert settings_from(args_for("--config", str(config), "--store", "flag.sqlite")).store == "flag.sqlite"


@pytest.mark.parametrize("text, expected", [
    ('[connection]\nconnect = "udpin:127.0.0.1:14551"\n\n[store]\npathh = "x"\n',
     r"line 5: unknown key 'pathh' in \[store\]"),
    ('[connection]\nconnect = "udpin:127.0.0.1:14551"\n[vehicles]\npreset = "boat"\n',
     r"line 3: unknown section \[vehicles\]"),
    ('# comment\n[scheduling]\n  min_interval_s = -1\n', r"line 3: \[scheduling\] min_interval_s: expected a finite number > 0"),
    ('[connection]\nconnect = "foo:bar"\n', r"line 2: \[connection\] connect: 'foo:bar' is not a connection string"),
    ('[procedures]\nallowed = ["identification", "selfdestruct"]\n', r"line 2: .*'selfdestruct' is not one of"),
    ('[procedures]\nthrusts = [0.6, 0.6]\n', r"line 2: .*repeats a thrust level"),
    ('[http]\nlisten = "127.0.0.1:99999"\n', r"line 2: \[http\] listen: .*port in 0-65535"),
    ('[health]\nenabled = "yes"\n', r"line 2: \[health\] enabled: expected true or false"),
    ('[http]\nlisten = "127.0.0.1:8080"\n[connection\n', r"line 3, column \d+: not valid TOML"),
    ('connect = "udpin:127.0.0.1:14551"\n', r"line 1: connect is outside any section: it belongs under \[connection\]"),
])
def test_a_bad_file_is_refused_with_its_line_and_reason(tmp_path, capsys, text, expected):
    config = tmp_path / "c.toml"
    config.write_text(text)
    code, err = run_main(capsys, "--config", str(config))
    assert code == 2, err
    assert re.search(expected, err), err
    assert err.count("\n") == 1 and "Traceback" not in err  # one sentence


def test_missing_file_and_missing_connection_are_one_sentence(tmp_path, capsys):
    code, err = run_main(capsys, "--config", str(tmp_path / "absent.toml"))
    assert code == 2 and "cannot read the configuration file" in err
    empty = tmp_path / "empty.toml"
    empty.write_text("[health]\nenabled = false\n")
    code, err = run_main(capsys, "--config", str(empty))
    assert code == 2 and "no vehicle to connect to" in err


def test_a_signing_key_comes_from_its_own_file(tmp_path, capsys):
    key = tmp_path / "signing.key"
    key.write_text("ab" * 32 + "\n")
    config = tmp_path / "c.toml"
    config.write_text(f'[connection]\nconnect = "tcp:127.0.0.1:5760"\nsigning_key_file = "{key}"\n')
    assert settings_from(args_for("--config", str(config))).signing_key == "ab" * 32
    key.write_text("not a key")
    code, err = run_main(capsys, "--config", str(config))
    assert code == 2 and "line 3" in err and "64 hex characters" in err


def test_key_lines_follow_tables_and_dotted_keys():
    lines = key_lines('a = 1\n[http]\n# x = 2\nlisten = "x"\n[ "store" ]\npath.sub = 3\n')
    assert lines[("a",)] == 1 and lines[("http",)] == 2 and lines[("http", "listen")] == 4
    assert lines[("store",)] == 5 and lines[("store", "path", "sub")] == 6 and ("http", "x") not in lines


def test_the_resident_loop_gets_the_settings(tmp_path):
    config = tmp_path / "c.toml"
    config.write_text('[connection]\nconnect = "tcp:127.0.0.1:5760"\n[procedures]\nallowed = ["min_speed"]\n'
                      'procedure = "thesis"\n[scheduling]\nmin_interval_s = 30\nhysteresis = 0.2\n'
                      '[health]\nwindow_s = 25\n')
    serve = settings_from(args_for("--config", str(config))).serve_config()
    assert serve.procedures == ("min_speed",)
    assert serve.scheduling.min_interval_s == 30 and serve.scheduling.relative_hysteresis == 0.2
    assert serve.drift.window_s == 25
    assert serve.campaign.yaw.settle_s == 40.0  # the thesis' timings


def test_a_procedure_the_configuration_does_not_allow_is_denied(tmp_path):
    link = InProcessLink(seed=3)
    link.inject_user_command(MAV_CMD_USER_1, at_s=1.0)
    with Store(tmp_path / "s.sqlite") as store:
        config = ServeConfig(procedures=("min_speed",), max_vehicle_s=5.0)
        history = Companion(link, store, store.add_vehicle("v"), config, AbortFlag()).run()
    assert history == [] and (MAV_CMD_USER_1, MAV_RESULT_DENIED, 0) in link.acks
    assert any("not allowed" in text for text in link.status_texts)
    with pytest.raises(ValueError, match="unknown procedure"):
        ServeConfig(procedures=("identification", "launch"))
    assert MAV_CMD_USER_3  # the allowed one is covered by the ground-station tests


@pytest.mark.parametrize("command", ["run", "identify", "results"])
def test_the_help_names_the_default_store_file(command, capsys):
    with pytest.raises(SystemExit):
        main([command, "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "$COMPANION_STORE or ./companion.sqlite" in text and "./None" not in text


@pytest.mark.parametrize("text", ["1e-9", "1.5", "0.6,0.02"])
def test_a_thrust_level_too_small_to_move_the_vehicle_is_refused_with_the_unit(text):
    from companion.checks import parse_thrust_levels

    with pytest.raises(ValueError, match="least thrust level a campaign flies"):
        parse_thrust_levels(text)
    assert parse_thrust_levels("5,60") == pytest.approx((0.05, 0.6))


def test_a_serial_port_that_is_not_there_is_one_sentence_not_a_missing_module(capsys):
    import serial  # noqa: F401 - a declared dependency: the serial link needs it

    code = main(["status", "--connect", "/dev/ttyNOSUCHPORT0,57600"])
    err = capsys.readouterr().err
    assert code != 0 and "cannot reach a vehicle on /dev/ttyNOSUCHPORT0,57600" in err
    assert "Traceback" not in err and "ModuleNotFoundError" not in err
