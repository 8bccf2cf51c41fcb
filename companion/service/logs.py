"""Log lines for a terminal or for journald.

* ``text``: ``TIME LEVEL logger: message`` (a terminal, a file).
* ``journal``: no timestamp (journald stamps each line itself) and each line prefixed with its
  syslog priority, ``<4>WARNING companion.procedures.resident: ...``: journald reads the prefix
  (systemd's ``SyslogLevelPrefix=``, on by default), so ``journalctl -p warning`` filters by level,
  and the level name stays in the text for a plain ``journalctl -u``.
* ``auto`` (the default): ``journal`` when standard error is the journal's stream, as systemd
  says in ``JOURNAL_STREAM`` (device:inode of that stream), else ``text``.

In both, an exception logged with its traceback (a lost link in the middle of a procedure, a
refused parameter: conditions a vehicle meets) shows as one line, ``message: Type: reason``; the
traceback itself is printed only when the log level is DEBUG (``-vv``, or ``level = "debug"``).
"""
from __future__ import annotations

import logging
import os
import sys
from typing import Mapping, TextIO

TEXT_FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"
JOURNAL_FORMAT = "%(levelname)s %(name)s: %(message)s"
#: logging level → syslog priority (journald's ``<N>`` prefix)
PRIORITIES = {logging.DEBUG: 7, logging.INFO: 6, logging.WARNING: 4, logging.ERROR: 3, logging.CRITICAL: 2}


def journal_stream(environ: Mapping[str, str] = os.environ, stream: TextIO | None = None) -> bool:
    """True when ``stream`` (standard error) is the stream systemd connected to the journal."""
    value = environ.get("JOURNAL_STREAM", "")
    try:
        device, inode = (int(part) for part in value.split(":"))
        status = os.fstat((stream or sys.stderr).fileno())
    except (ValueError, OSError, AttributeError):
        return False
    return (status.st_dev, status.st_ino) == (device, inode)


def priority(levelno: int) -> int:
    """The syslog priority of a logging level (levels between the named ones round down in severity)."""
    for level in sorted(PRIORITIES, reverse=True):
        if levelno >= level:
            return PRIORITIES[level]
    return 7


class ServiceFormatter(logging.Formatter):
    """:data:`TEXT_FORMAT` or :data:`JOURNAL_FORMAT`, exceptions on one line unless at DEBUG."""

    def __init__(self, journal: bool = False) -> None:
        super().__init__(JOURNAL_FORMAT if journal else TEXT_FORMAT)
        self.journal = journal

    def format(self, record: logging.LogRecord) -> str:
        if record.exc_info and record.exc_info[1] is not None \
                and logging.getLogger().getEffectiveLevel() > logging.DEBUG:
            exc = record.exc_info[1]
            record = logging.makeLogRecord(record.__dict__)
            record.msg, record.args = f"{record.getMessage()}: {type(exc).__name__}: {exc}", None
            record.exc_info, record.exc_text = None, None
        text = super().format(record)
        if not self.journal:
            return text
        prefix = f"<{priority(record.levelno)}>"
        return "\n".join(prefix + line for line in text.splitlines() or [""])


def configure_logging(log_format: str = "auto", level: int = logging.WARNING, stream: TextIO | None = None,
                      *, alongside: bool = False) -> str | None:
    """One handler on the root logger writing to ``stream`` (standard error) in ``log_format``
    (``auto``/``text``/``journal``), replacing the one set by an earlier call (a configuration file
    read after the flags may change the level and the format). Like ``logging.basicConfig``, it
    leaves a root logger configured by someone else alone (a host program, pytest), unless
    ``alongside``. Returns the format used, None when it left the logger alone."""
    stream = stream or sys.stderr
    if log_format not in ("auto", "text", "journal"):
        raise ValueError(f"log format {log_format!r}: use auto, text or journal")
    root = logging.getLogger()
    for old in [h for h in root.handlers if isinstance(h.formatter, ServiceFormatter)]:
        root.removeHandler(old)
    if root.handlers and not alongside:
        return None
    journal = log_format == "journal" or (log_format == "auto" and journal_stream(stream=stream))
    handler = logging.StreamHandler(stream)
    handler.setFormatter(ServiceFormatter(journal))
    root.addHandler(handler)
    root.setLevel(level)
    return "journal" if journal else "text"
