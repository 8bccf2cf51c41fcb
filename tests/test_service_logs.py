"""Log lines for journald: the syslog priority prefix, no timestamp, one line for an exception unless
at DEBUG, and systemd's JOURNAL_STREAM recognised only for the stream it names."""
from __future__ import annotations

import io
import logging
import os

import pytest

from companion.link.errors import LinkLost
from companion.service.logs import ServiceFormatter, configure_logging, journal_stream, priority


@pytest.fixture
def restore_root_logger():
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    yield
    for handler in list(root.handlers):
        root.removeHandler(handler)
    for handler in handlers:
        root.addHandler(handler)
    root.setLevel(level)


def _log_failure(logger: logging.Logger) -> None:
    try:
        raise LinkLost("no telemetry snapshot for 5 s of wall clock")
    except LinkLost:
        logger.exception("procedure failed")


def test_journal_lines_carry_the_priority_and_no_timestamp(restore_root_logger):
    stream = io.StringIO()
    assert configure_logging("journal", logging.INFO, stream, alongside=True) == "journal"
    log = logging.getLogger("companion.test")
    log.info("gain scheduling on")
    log.warning("aborting: signal SIGTERM")
    _log_failure(log)
    lines = stream.getvalue().splitlines()
    assert lines == ["<6>INFO companion.test: gain scheduling on",
                     "<4>WARNING companion.test: aborting: signal SIGTERM",
                     "<3>ERROR companion.test: procedure failed: LinkLost: no telemetry snapshot for 5 s of wall clock"]


def test_a_traceback_only_at_debug(restore_root_logger):
    stream = io.StringIO()
    configure_logging("text", logging.DEBUG, stream, alongside=True)
    _log_failure(logging.getLogger("companion.test"))
    text = stream.getvalue()
    assert "Traceback (most recent call last)" in text and "ERROR companion.test: procedure failed" in text
    assert text[:4].isdigit()  # the text format keeps its timestamp


def test_journal_stream_names_the_stream_systemd_connected(tmp_path):
    with open(tmp_path / "stderr", "w") as stream, open(tmp_path / "other", "w") as other:
        status = os.fstat(stream.fileno())
        env = {"JOURNAL_STREAM": f"{status.st_dev}:{status.st_ino}"}
        assert journal_stream(env, stream)
        assert not journal_stream(env, other)  # a process whose stderr was redirected elsewhere
        assert not journal_stream({}, stream) and not journal_stream({"JOURNAL_STREAM": "garbage"}, stream)


def test_a_logger_configured_elsewhere_is_left_alone(restore_root_logger):
    root = logging.getLogger()
    foreign = logging.NullHandler()
    root.addHandler(foreign)
    assert configure_logging("journal", logging.DEBUG, io.StringIO()) is None
    assert foreign in root.handlers and not any(isinstance(h.formatter, ServiceFormatter) for h in root.handlers)


def test_priorities_of_levels():
    assert [priority(level) for level in (5, 10, 20, 25, 30, 40, 50)] == [7, 7, 6, 6, 4, 3, 2]
    record = logging.LogRecord("x", logging.WARNING, __file__, 1, "two\nlines", None, None)
    assert ServiceFormatter(journal=True).format(record) == "<4>WARNING x: two\n<4>lines"
