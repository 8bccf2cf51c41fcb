"""The one launcher of the simulator: ``python -m sim run`` as a child process on loopback.

Used by the rehearsal, the tests' fixtures and the bench scripts. The simulator is reached only
over MAVLink and started as a separate process, so the companion still never imports ``sim``
(SPEC §5). It binds port 0 (the OS picks a free port: no race between parallel starts) and
reports the endpoint it got on one ``READY <listen>`` line on stdout, which is parsed here and
nowhere else.
"""
from __future__ import annotations

import json
import logging
import os
import select
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

log = logging.getLogger(__name__)

#: the simulator's start-up line (sim/__main__.py), e.g. ``READY tcpin:127.0.0.1:40892``
READY_PREFIX = "READY "
#: its last line at exit under ``--lockstep``: ``STATS {json}`` (counters and the lockstep record)
STATS_PREFIX = "STATS "


class SimulatorError(RuntimeError):
    pass


def parse_stats(text: str) -> dict | None:
    """The ``STATS {json}`` line among the simulator's last stdout lines (None without one)."""
    for line in reversed(text.splitlines()):
        if line.startswith(STATS_PREFIX):
            try:
                stats = json.loads(line[len(STATS_PREFIX):])
            except ValueError:
                return None
            return stats if isinstance(stats, dict) else None
    return None


def parse_ready(line: str) -> tuple[str, str, int] | None:
    """``(kind, host, port)`` of a ``READY udpin:127.0.0.1:40892`` line, None for any other line."""
    if not line.startswith(READY_PREFIX):
        return None
    kind, address = line[len(READY_PREFIX):].strip().split(":", 1)
    host, port = address.rsplit(":", 1)
    return kind, host, int(port)


@dataclass
class SimulatorProcess:
    """``python -m sim run`` as a child process on a free loopback port.

    The rehearsal uses TCP by default: at 50x the simulator sends ~4,000 messages per wall second,
    one UDP datagram each, and the kernel charges ~1 KB per datagram against the receive buffer, so
    a companion descheduled for some tens of milliseconds on a busy 2-core machine loses samples
    over UDP. TCP on loopback is flow-controlled and lossless; a vehicle at 1x has no such burst.

    Waiting for its READY line is the one wall-clock wait of the companion: it is a process start,
    not vehicle logic.

    ``endpoint`` is what a CLIENT passes to pymavlink (``tcp:``/``udpout:``), ``listen`` what the
    simulator listens on (``tcpin:``/``udpin:``), ``port`` the bound port (0 until started: the
    simulator picks a free one; set it to listen on a fixed port).
    """

    preset: str = "starfish"
    speedup: float = 50.0
    seed: int = 1
    current: tuple[float, float] = (0.0, 0.0)
    extra_args: list[str] = field(default_factory=list)  # more ``sim run`` options, e.g. --signing-key
    ready_timeout_s: float = 60.0
    transport: str = "tcp"  # or "udp"
    log_path: Path | None = None  # the simulator's stderr (None: discarded)
    lockstep: bool = True  # results independent of the speed-up (docs/PROTOCOL.md, "Lockstep")
    # "builtin" (our autopilot) or "ardurover"/"ardusub": the real ArduPilot SITL flying our physics;
    # "px4-rover"/"px4-uuv": PX4 SITL (its MAVLink is UDP: use transport "udp")
    autopilot: str = "builtin"
    ardupilot_bin: str | None = None
    px4_bin: str | None = None
    process: subprocess.Popen | None = None
    port: int = 0
    #: what the simulator reported at exit (``STATS`` line, lockstep only; None before or without)
    stats: dict | None = None

    @property
    def endpoint(self) -> str:
        """The connection string a client uses (the simulator listens with ``tcpin``/``udpin``)."""
        return f"tcp:127.0.0.1:{self.port}" if self.transport == "tcp" else f"udpout:127.0.0.1:{self.port}"

    @property
    def listen(self) -> str:
        """What the simulator listens on. Before the start the port is 0: the simulator binds a free
        port itself and reports it on its READY line (no race)."""
        return f"{'tcpin' if self.transport == 'tcp' else 'udpin'}:127.0.0.1:{self.port}"

    @property
    def real_autopilot(self) -> bool:
        return self.autopilot != "builtin"

    def command(self) -> list[str]:
        """The command line of the child process."""
        if self.real_autopilot:  # ArduPilot SITL serves MAVLink on its own TCP port (lockstep with the physics)
            return [sys.executable, "-m", "sim", "run", "--autopilot", self.autopilot, "--preset", self.preset,
                    "--speedup", str(self.speedup), "--seed", str(self.seed),
                    "--current", f"{self.current[0]},{self.current[1]}",
                    *(["--ardupilot-bin", self.ardupilot_bin] if self.ardupilot_bin else []),
                    *(["--px4-bin", self.px4_bin] if self.px4_bin else []), *self.extra_args]
        return [sys.executable, "-m", "sim", "run", "--preset", self.preset, "--speedup", str(self.speedup),
                "--listen", self.listen, "--seed", str(self.seed),
                "--current", f"{self.current[0]},{self.current[1]}",
                *(["--lockstep"] if self.lockstep else []), *self.extra_args]

    def start(self) -> "SimulatorProcess":
        if self.transport not in ("tcp", "udp"):
            raise SimulatorError(f"transport must be tcp or udp, not {self.transport!r}")
        if self.process is not None:
            raise SimulatorError("this simulator was already started")
        command = self.command()
        log.info("starting simulator: %s", " ".join(command))
        # stderr goes to a file, never to an undrained pipe (a full pipe would block the simulator)
        log_file = open(self.log_path, "w") if self.log_path else subprocess.DEVNULL  # noqa: SIM115
        self.process = subprocess.Popen(command, stdout=subprocess.PIPE, stderr=log_file, text=True,
                                        env={**os.environ, "PYTHONUNBUFFERED": "1"})
        if not isinstance(log_file, int):  # a file of ours (log_path), not DEVNULL
            log_file.close()
        deadline = time.monotonic() + self.ready_timeout_s
        assert self.process.stdout is not None
        while time.monotonic() < deadline and self.process.poll() is None:
            ready, _, _ = select.select([self.process.stdout], [], [], 0.2)
            ready_line = parse_ready(self.process.stdout.readline()) if ready else None
            if ready_line is not None:
                self.port = ready_line[2]
                return self
        exit_code = self.process.poll()
        self.stop()
        detail = self.log_text()[-500:].strip()
        why = (f"exited with code {exit_code}" if exit_code is not None
               else f"not READY within {self.ready_timeout_s:.0f} s")
        raise SimulatorError(f"simulator did not start (preset {self.preset!r}): {why}"
                             + (f": {detail}" if detail else ""))

    def alive(self) -> bool:
        return self.process is not None and self.process.poll() is None

    def log_text(self) -> str:
        """The simulator's stderr so far ("" without a log file)."""
        try:
            return self.log_path.read_text(errors="replace") if self.log_path else ""
        except OSError:
            return ""

    def stop(self, timeout_s: float = 10.0) -> int | None:
        """SIGTERM, then SIGKILL if it does not exit; returns the exit code (None if never started)."""
        if self.process is None:
            return None
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=timeout_s)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        if self.process.stdout is not None and not self.process.stdout.closed:
            try:
                self.stats = parse_stats(self.process.stdout.read()) or self.stats
            except (OSError, ValueError):
                pass
            self.process.stdout.close()
        return self.process.returncode

    def __enter__(self) -> "SimulatorProcess":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
