"""The real ArduPilot firmware as the autopilot of our simulated vehicle.

``python -m sim run --autopilot ardurover|ardusub --ardupilot-bin DIR`` starts ArduPilot's SITL
binary (``DIR/ardurover`` or ``DIR/ardusub``, built from ArduPilot's sources by the user; never
shipped with this project) with the JSON physics backend, and serves the frames it sends with our
preset physics (:mod:`sim.ardupilot_json`). The companion then talks MAVLink to the real firmware
on its serial0 TCP port, exactly as it would to a vehicle, while the physics keep a known
linearised truth (``python -m sim linearize``) for scoring.

Everything runs on loopback: SITL's MAVLink port is ``5760 + 10·instance`` on 127.0.0.1 (a free
instance is claimed: :class:`InstanceClaim`), its servo frames go to our UDP port (bound to port 0, passed with
``--sim-port-out``). The parameter file written for SITL is this vehicle's configuration
(``sim/ardupilot/*.parm``), plus any ``--param NAME=VALUE`` given.

A twin-thruster preset (``boat-skid``) flies ArduRover with skid steering: its own parameter file
(``ardurover-skid.parm``: SERVO1/3_FUNCTION 73/74) and frame decoder (``RoverSkidDecoder``).
"""
from __future__ import annotations

import logging
import math
import socket
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

from sim.ardupilot_json import DECODERS, SKID_DECODERS, JsonBridge, JsonPhysics
from sim.build import build_vehicle
from sim.instance_claim import InstanceClaim as SharedClaim
from sim.preset import Preset, load_preset

log = logging.getLogger(__name__)

#: autopilot -> (binary name, parameter file, the preset it flies by default)
AUTOPILOTS = {
    "ardurover": ("ardurover", "ardurover-boat.parm", "boat"),
    "ardusub": ("ardusub", "ardusub-vectored.parm", "starfish"),
}
#: autopilot -> parameter file of a twin-thruster (skid-steered) preset
SKID_PARAMETER_FILES = {"ardurover": "ardurover-skid.parm"}
#: actuator limits (sim.vehicle.ActuatorLimits fields) an autopilot's frame imposes instead of the
#: preset's fin servos: ArduSub's equivalent rudder is the thrusters' yaw differential, which follows
#: the mix within a physics step (a 0.5 rad/s fin servo would lag it by 0.2-0.4 s in a doublet)
FRAME_LIMITS: dict[str, dict[str, float]] = {"ardusub": {"rudder_rate": math.inf}}

MAVLINK_BASE_PORT = 5760
DEFAULT_HOME = "-35.363262,149.165237,0,0"  # sea level (ArduSub needs a sea-level home)


@dataclass
class SitlConfig:
    autopilot: str
    bin_dir: Path
    preset: str | None = None
    speedup: float = 1.0
    seed: int = 0
    current: tuple[float, float] = (0.0, 0.0)
    depth: float = 0.0
    home: str = DEFAULT_HOME
    params: dict[str, float] = field(default_factory=dict)
    workdir: Path | None = None  # None: a temporary folder (SITL writes eeprom.bin and logs there)
    truth_log: Path | None = None  # CSV of the physics' own speed over vehicle time (for scoring)
    faults: tuple = ()  # sim.faults.Fault: injected into the physics at their vehicle time


def find_binary(config: SitlConfig) -> Path:
    if config.autopilot not in AUTOPILOTS:
        raise ValueError(f"unknown autopilot {config.autopilot!r} (known: {', '.join(AUTOPILOTS)})")
    binary = Path(config.bin_dir) / AUTOPILOTS[config.autopilot][0]
    if not binary.is_file():
        raise ValueError(f"no ArduPilot SITL binary {binary} (build ArduPilot for the 'sitl' board and "
                         "pass its build/sitl/bin folder with --ardupilot-bin)")
    return binary


def _ports_free(instance: int) -> bool:
    """Whether SITL instance ``instance``'s MAVLink port (5760 + 10·i) and its neighbours are free."""
    try:
        for port in (MAVLINK_BASE_PORT + 10 * instance + k for k in (0, 2, 3)):
            with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as probe:
                probe.bind(("127.0.0.1", port))
    except OSError:
        return False
    return True


class InstanceClaim(SharedClaim):
    """An ArduPilot SITL instance reserved for this process (:mod:`sim.instance_claim`): its
    MAVLink ports (5760 + 10·i and neighbours) free too."""

    def __init__(self, limit: int = 50) -> None:
        super().__init__("ardupilot-sitl", _ports_free, limit)


def free_instance(limit: int = 50) -> int:
    """The first SITL instance whose ports are free and that no other process has claimed, without
    claiming it (for a caller that starts SITL at once; :class:`InstanceClaim` reserves it)."""
    claim = InstanceClaim(limit)
    claim.release()
    return claim.instance


def preset_of(config: SitlConfig) -> Preset:
    """The preset SITL flies: ``config.preset``, else the autopilot's default."""
    return load_preset(config.preset or AUTOPILOTS[config.autopilot][2])


def frame_of(autopilot: str, preset: Preset) -> tuple[str, type]:
    """(parameter file, frame decoder class) for this autopilot flying this preset: a skid-steered
    vessel gets ArduRover's skid-steering outputs, everything else the autopilot's own frame."""
    if preset.is_skid:
        if autopilot not in SKID_DECODERS:
            raise ValueError(f"{autopilot} cannot fly the twin-thruster preset {preset.name!r} "
                             f"(skid steering: {', '.join(SKID_DECODERS)})")
        return SKID_PARAMETER_FILES[autopilot], SKID_DECODERS[autopilot]
    return AUTOPILOTS[autopilot][1], DECODERS[autopilot]


def parameter_file(config: SitlConfig, folder: Path) -> Path:
    """This vehicle's parameters for SITL (``--defaults``), with the ``--param`` overrides appended."""
    name = frame_of(config.autopilot, preset_of(config))[0]
    text = (resources.files("sim") / "ardupilot" / name).read_text(encoding="utf-8")
    extra = "".join(f"{key} {value:g}\n" for key, value in config.params.items())
    path = folder / name
    path.write_text(text + extra, encoding="utf-8")
    return path


def _die_with_parent() -> None:
    """In the SITL child: be SIGKILLed when this process dies, however it dies (Linux prctl)."""
    try:
        import ctypes
        import signal

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):  # not Linux: the close() path still stops SITL
        pass


class ArduPilotSitl:
    """SITL process + JSON bridge; ``run()`` serves frames until stopped or SITL exits."""

    def __init__(self, config: SitlConfig, on_ready=None) -> None:
        self.config = config
        self.binary = find_binary(config)
        preset = preset_of(config)
        factory = frame_of(config.autopilot, preset)[1]
        self.vehicle = build_vehicle(preset, seed=config.seed, current_north=config.current[0],
                                     current_east=config.current[1], depth=config.depth, speed=0.0,
                                     faults=config.faults)
        for name, value in FRAME_LIMITS.get(config.autopilot, {}).items():
            setattr(self.vehicle.limits, name, value)
        decoder = factory.for_preset(preset) if hasattr(factory, "for_preset") else factory()
        self._truth_file = open(config.truth_log, "w", encoding="utf-8") if config.truth_log else None  # noqa: SIM115
        self.bridge = JsonBridge(JsonPhysics(self.vehicle, decoder, truth_log=self._truth_file))
        self._claim = InstanceClaim()
        self.instance = self._claim.instance
        self.port = MAVLINK_BASE_PORT + 10 * self.instance
        self._tmp = None
        if config.workdir is None:
            self._tmp = tempfile.TemporaryDirectory(prefix=f"sitl-{config.autopilot}-")
            self.workdir = Path(self._tmp.name)
        else:
            self.workdir = Path(config.workdir)
            self.workdir.mkdir(parents=True, exist_ok=True)
        self.on_ready = on_ready
        self.process: subprocess.Popen | None = None
        self._stop = False

    @property
    def endpoint(self) -> str:
        return f"tcp:127.0.0.1:{self.port}"

    def command(self) -> list[str]:
        defaults = parameter_file(self.config, self.workdir)
        return [str(self.binary), "--model", "JSON:127.0.0.1", "--sim-port-out", str(self.bridge.port),
                "--speedup", f"{self.config.speedup:g}", "-I", str(self.instance), "--home", self.config.home,
                "--defaults", str(defaults)]

    def start(self) -> None:
        command = self.command()
        log.info("starting ArduPilot SITL: %s", " ".join(command))
        self.log_path = self.workdir / "sitl.log"
        log_file = open(self.log_path, "w")  # noqa: SIM115 - closed with the process
        self.process = subprocess.Popen(command, cwd=self.workdir, stdout=log_file, stderr=subprocess.STDOUT,
                                        stdin=subprocess.DEVNULL, preexec_fn=_die_with_parent)
        self._log_file = log_file
        self._wait_listening()
        if self.on_ready is not None:
            self.on_ready(f"tcpin:127.0.0.1:{self.port}")

    def _wait_listening(self, timeout_s: float = 30.0) -> None:
        """SITL's serial0 listens before it boots (it waits for the first client): wait for that,
        reading its log (a probe connection would be taken as the client)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if self.process.poll() is not None:
                raise RuntimeError(f"ArduPilot SITL exited ({self.process.returncode}): {self.log_tail()}")
            if "Waiting for connection" in self.log_path.read_text(errors="replace"):
                return
            time.sleep(0.05)
        raise RuntimeError(f"ArduPilot SITL did not open its MAVLink port within {timeout_s:.0f} s: {self.log_tail()}")

    def log_tail(self, lines: int = 15) -> str:
        try:
            return " | ".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return "(no log)"

    def run(self) -> int:
        self.start()
        try:
            while not self._stop and self.process.poll() is None:
                self.bridge.serve_once(0.5)
        finally:
            self.close()
        return 0

    def stop(self) -> None:
        self._stop = True

    def close(self) -> None:
        if self.process is not None and self.process.poll() is None:
            # SITL waiting for a physics answer cannot act on SIGTERM (measured: orphans busy-looping),
            # so it gets a short grace and then SIGKILL
            self.process.terminate()
            try:
                self.process.wait(timeout=2)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        if getattr(self, "_log_file", None) is not None:
            self._log_file.close()
        self.bridge.close()
        if self._truth_file is not None:
            self._truth_file.close()
        if self._tmp is not None:
            self._tmp.cleanup()
        self._claim.release()
