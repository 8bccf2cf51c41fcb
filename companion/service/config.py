"""The configuration file of ``companion run`` (TOML, read with the standard library's ``tomllib``).

Every key is listed in :data:`KEYS` with the option of ``companion run`` it stands for; a flag given
on the command line overrides the file. A file is refused, with its line and the reason in one
sentence (:class:`ConfigError`, exit code 2), when it is not TOML (``tomllib`` gives the position),
holds a section or key not listed here, or a value of the wrong kind or out of range (the line is
found by scanning the text for the key). The documented example is ``deploy/companion.toml``.

Relative paths (``store.path``, ``store.report_dir``, ``connection.signing_key_file``) are relative
to the working directory, as the flags' are: the systemd unit runs in its state directory.
"""
from __future__ import annotations

import re
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

from companion.checks import check_thrust_levels, is_number
from companion.errors import UserError

#: log levels a configuration may name, as ``logging`` spells them
LOG_LEVELS = ("debug", "info", "warning", "error")
LOG_FORMATS = ("auto", "text", "journal")


class ConfigError(UserError):
    """A configuration file that cannot be used: where and why, in one sentence (exit code 2)."""

    exit_code = 2


# ------------------------------------------------------------------ value converters
# Each takes the TOML value and returns what ``companion run`` uses, or raises ValueError with the
# reason (the loader adds the file, the line and the key).

def text(value: Any) -> str:
    if not isinstance(value, str) or not value.strip():
        raise ValueError(f"expected a non-empty string, not {value!r}")
    return value.strip()


def boolean(value: Any) -> bool:
    if not isinstance(value, bool):
        raise ValueError(f"expected true or false, not {value!r}")
    return value


def positive(value: Any) -> float:
    if not (is_number(value) and value > 0):
        raise ValueError(f"expected a finite number > 0, not {value!r}")
    return float(value)


def choice(*options: str) -> Callable[[Any], str]:
    def convert(value: Any) -> str:
        if value not in options:
            raise ValueError(f"expected one of {', '.join(repr(o) for o in options)}, not {value!r}")
        return value
    return convert


def names(allowed: tuple[str, ...]) -> Callable[[Any], tuple[str, ...]]:
    """A non-empty list of distinct names from ``allowed``."""
    def convert(value: Any) -> tuple[str, ...]:
        if not isinstance(value, list) or not value or not all(isinstance(v, str) for v in value):
            raise ValueError(f"expected a non-empty list of names ({', '.join(allowed)}), not {value!r}")
        unknown = [v for v in value if v not in allowed]
        if unknown:
            raise ValueError(f"{', '.join(map(repr, unknown))} is not one of {', '.join(allowed)}")
        if len(set(value)) != len(value):
            raise ValueError(f"{value!r} names one twice")
        return tuple(value)
    return convert


def thrusts(value: Any) -> tuple[float, ...]:
    """Fractions of full ahead (0.6) or, the whole list, percent (60), as ``--thrusts`` takes them."""
    if not isinstance(value, list) or not all(is_number(v) for v in value):
        raise ValueError(f"expected a list of numbers such as [0.6, 0.8, 1.0], not {value!r}")
    values = [float(v) for v in value]
    if values and all(v > 1.0 for v in values):
        values = [v / 100.0 for v in values]
    return check_thrust_levels(values, "thrust levels")


def system_ids(value: Any) -> tuple[int, ...]:
    if not isinstance(value, list) or not all(isinstance(v, int) and not isinstance(v, bool) and 1 <= v <= 255
                                              for v in value):
        raise ValueError(f"expected a list of MAVLink system ids 1-255, not {value!r}")
    return tuple(value)


def listen_address(value: Any) -> str:
    """``HOST:PORT`` (port 0: any free port); whether the host may be other than loopback is
    :class:`companion.service.http` 's decision, with ``http.allow_remote``."""
    host, port = split_listen(text(value))
    return f"{host}:{port}"


def split_listen(value: str) -> tuple[str, int]:
    """``"127.0.0.1:8080"`` → ``("127.0.0.1", 8080)``; ``":8080"`` means loopback; ValueError otherwise."""
    host, sep, port = value.strip().rpartition(":")
    host = host.strip("[]") or "127.0.0.1"
    if not sep or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise ValueError(f"{value!r} is not HOST:PORT with a port in 0-65535 (e.g. 127.0.0.1:8080)")
    if not re.fullmatch(r"[A-Za-z0-9.:-]+", host):
        raise ValueError(f"{value!r}: {host!r} is not a host name or address")
    return host, int(port)


def signing_key_file(value: Any) -> str:
    """The MAVLink 2 signing key read from the named file (64 hex characters), as hex text; the key
    stays out of the configuration, which may be readable by others."""
    path = Path(text(value))
    try:
        key = path.read_text(encoding="ascii").strip()
    except (OSError, UnicodeDecodeError) as exc:
        raise ValueError(f"cannot read the key file {str(path)!r} ({exc.strerror if isinstance(exc, OSError) else exc})") from None
    if not re.fullmatch(r"[0-9A-Fa-f]{64}", key):
        raise ValueError(f"{str(path)!r} does not hold a key of 64 hex characters (32 bytes)")
    return key


def level(value: Any) -> str:
    return choice(*LOG_LEVELS)(value.lower() if isinstance(value, str) else value)


@dataclass(frozen=True)
class Key:
    """One configuration key: the ``companion run`` option it stands for (its argparse dest) and
    the converter of its value."""

    dest: str
    convert: Callable[[Any], Any]
    flag: str = ""  # the option that overrides it ("" : the file only)


def keys(profiles: tuple[str, ...], procedures: tuple[str, ...], schedules: tuple[str, ...],
         endpoint: Callable[[str], str] = text) -> dict[str, dict[str, Key]]:
    """Section → key → :class:`Key`. The lists of names come from the layers that own them (the
    command line passes them), and ``endpoint`` is the connection-string check of the command line."""
    return {
        "connection": {
            "connect": Key("connect", lambda v: endpoint(text(v)), "--connect"),
            "profile": Key("profile", choice(*profiles), "--profile"),
            "signing_key_file": Key("signing_key", signing_key_file, "--signing-key"),
            "allowed_senders": Key("allowed_senders", system_ids),
        },
        "vehicle": {
            "rudder_full_scale": Key("rudder_full_scale", positive, "--rudder-full-scale"),
            "rudder_rate": Key("rudder_rate", positive, "--rudder-rate"),
            "preset": Key("preset", text, "--preset"),
        },
        "store": {
            "path": Key("store", text, "--store"),
            "report_dir": Key("report_dir", text, "--report-dir"),
        },
        "procedures": {
            "allowed": Key("procedures", names(procedures), "--procedures"),
            "procedure": Key("procedure", choice("quick", "thesis"), "--procedure"),
            "thrusts": Key("thrusts", thrusts, "--thrusts"),
            "recover_interrupted": Key("yes", boolean, "--yes"),
        },
        "scheduling": {
            "enabled": Key("schedule_gains", boolean, "--no-scheduling"),
            "schedules": Key("schedules", names(schedules)),
            "min_interval_s": Key("scheduling_min_interval_s", positive),
            "hysteresis": Key("scheduling_hysteresis", positive),
        },
        "health": {
            "enabled": Key("health", boolean, "--no-health"),
            "window_s": Key("health_window_s", positive),
            "tolerance": Key("health_tolerance", positive),
            "threshold": Key("health_threshold", positive),
        },
        "learning": {
            "enabled": Key("learn", boolean, "--learn"),
        },
        "http": {
            "listen": Key("http", listen_address, "--http"),
            "allow_remote": Key("http_allow_remote", boolean, "--http-allow-remote"),
        },
        "logging": {
            "level": Key("log_level", level, "-v"),
            "format": Key("log_format", choice(*LOG_FORMATS), "--log-format"),
        },
    }


# ------------------------------------------------------------------ reading
_HEADER = re.compile(r"^\s*\[\s*([^\[\]]+?)\s*\]\s*(#.*)?$")
_KEY = re.compile(r"^\s*((?:[A-Za-z0-9_-]+|\"[^\"]*\"|'[^']*')(?:\s*\.\s*(?:[A-Za-z0-9_-]+|\"[^\"]*\"|'[^']*'))*)\s*=")


def _parts(dotted: str) -> tuple[str, ...]:
    return tuple(part.strip().strip("\"'") for part in dotted.split("."))


def key_lines(source: str) -> dict[tuple[str, ...], int]:
    """Where each table and key first appears (1-based line), by its full dotted path: tomllib
    reports positions only for syntax errors, so a value's line is found by scanning the text."""
    found: dict[tuple[str, ...], int] = {}
    table: tuple[str, ...] = ()
    for number, line in enumerate(source.splitlines(), 1):
        header = _HEADER.match(line)
        if header:
            table = _parts(header.group(1))
            found.setdefault(table, number)
            continue
        key = _KEY.match(line)
        if key:
            found.setdefault(table + _parts(key.group(1)), number)
    return found


def load_config(path: str | Path, schema: Mapping[str, Mapping[str, Key]]) -> dict[str, Any]:
    """The file's values by option (argparse dest), converted and checked; :class:`ConfigError`
    with the line and the reason otherwise."""
    path = Path(path)
    try:
        source = path.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
        raise ConfigError(f"cannot read the configuration file {str(path)!r}: {reason}") from None
    try:
        data = tomllib.loads(source)
    except tomllib.TOMLDecodeError as exc:
        found = re.search(r"^(.*) \(at line (\d+), column (\d+)\)$", str(exc))
        if found:
            raise ConfigError(f"{path}, line {found.group(2)}, column {found.group(3)}: not valid TOML: "
                              f"{found.group(1)}") from None
        raise ConfigError(f"{path}: not valid TOML: {exc}") from None
    lines = key_lines(source)

    def where(*key: str) -> str:
        line = lines.get(tuple(key)) or lines.get(tuple(key[:1]))
        return f"{path}, line {line}" if line else str(path)

    values: dict[str, Any] = {}
    for section, table in data.items():
        if not isinstance(table, dict):
            owner = next((s for s, table_keys in schema.items() if section in table_keys), None)
            hint = f": it belongs under [{owner}]" if owner else f" (sections: {', '.join(f'[{s}]' for s in schema)})"
            raise ConfigError(f"{where(section)}: {section} is outside any section{hint}")
        if section not in schema:
            raise ConfigError(f"{where(section)}: unknown section [{section}] "
                              f"(known: {', '.join(f'[{s}]' for s in schema)})")
        for name, value in table.items():
            spec = schema[section].get(name)
            if spec is None:
                raise ConfigError(f"{where(section, name)}: unknown key {name!r} in [{section}] "
                                  f"(known: {', '.join(schema[section])})")
            try:
                values[spec.dest] = spec.convert(value)
            except ValueError as exc:
                raise ConfigError(f"{where(section, name)}: [{section}] {name}: {exc}") from None
    return values

