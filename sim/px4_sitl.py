"""The real PX4 firmware as the autopilot of our simulated vehicle.

``python -m sim run --autopilot px4-rover|px4-uuv --px4-bin DIR`` starts PX4's SITL binary
(``DIR/bin/px4`` of a ``px4_sitl`` build folder, built from PX4's sources by the user; never shipped
with this project, ``$PX4_SITL_BIN`` is the default DIR) as MAVLink HIL simulator client of our
preset physics (:mod:`sim.px4_hil`). The companion then talks MAVLink to the real firmware, exactly
as it would to a vehicle, while the physics keep a known linearised truth (``python -m sim
linearize``) for scoring.

How PX4 is started (``ROMFS/px4fmu_common/init.d-posix/rcS`` and ``px4-rc.*``):

* ``DIR/bin/px4 -i I -d DIR/etc`` in a fresh working folder (PX4 keeps ``parameters.bson``, the
  dataman and logs there), with ``PX4_SYS_AUTOSTART`` the airframe (51000 generic Ackermann rover
  for the boat, 1021 HippoCampus UUV for the AUV) and ``PX4_SIMULATOR=mavlink`` plus
  ``SIM_GZ_EN 0``, so that ``px4-rc.simulator`` starts ``simulator_mavlink start -c 4560+I``:
  PX4 connects to our TCP port 4560+I on the local host and boots in lockstep with our clock.
* Parameters: this vehicle's file ``sim/px4/*.params`` plus any ``--param NAME=VALUE``, passed
  as ``PX4_PARAM_NAME=VALUE`` environment variables, which ``rcS`` applies with ``param set``
  after the airframe's defaults and before the simulator starts.
* MAVLink (``px4-rc.mavlink``): PX4 binds UDP 18570+I (GCS link, sends to 14550), 14580+I
  (onboard/API link, sends to 14540+I until a partner speaks), 14280+I and 13030+I (payload,
  gimbal). The companion's endpoint is the onboard link: PX4 listens there, so a client uses
  ``udpout:127.0.0.1:14580+I`` (the READY line says ``udpin:127.0.0.1:14580+I``, what PX4 listens
  on); its first datagram makes it PX4's partner.

Everything is on loopback (UDP binds are PX4's ``INADDR_ANY``: run it in a private network
namespace to keep them off other interfaces). A free instance I (its ports and PX4's
``/tmp/px4_lock-I`` free) is claimed for PX4's lifetime (:class:`Px4InstanceClaim`, sim/instance_claim.py).
"""
from __future__ import annotations

import fcntl
import logging
import math
import os
import socket
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

from sim.instance_claim import InstanceClaim
from sim.preset import load_preset
from sim.px4_hil import DECODERS, HilEndpoint, HilPhysics, Home
from sim.vehicle import Vehicle

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Px4Vehicle:
    """How one of our vehicles is flown by PX4."""

    autostart: int  # SYS_AUTOSTART: a stock PX4 airframe (ROMFS init.d-posix/airframes)
    params: str  # this project's parameter file (sim/px4/)
    preset: str  # the preset it flies by default
    decoder: str  # sim.px4_hil.DECODERS key
    limits: dict = field(default_factory=dict)  # sim.vehicle.ActuatorLimits overrides


AUTOPILOTS = {
    "px4-rover": Px4Vehicle(51000, "px4-rover.params", "boat", "ackermann"),
    # the HippoCampus yaws by thrust differential: it follows the mix within a step
    "px4-uuv": Px4Vehicle(1021, "px4-uuv.params", "starfish", "uuv-quad",
                          {"rudder_rate": math.inf, "elevator_rate": math.inf}),
}

HIL_BASE_PORT = 4560
ONBOARD_BASE_PORT = 14580
#: UDP ports PX4 binds per instance (px4-rc.mavlink): GCS, onboard, payload, gimbal
UDP_BASE_PORTS = (18570, ONBOARD_BASE_PORT, 14280, 13030)
LOCK_FILE = "/tmp/px4_lock-{instance}"  # PX4's per-instance server lock (platforms/posix main.cpp)
SOCKET_FILE = "/tmp/px4-sock-{instance}"  # its command socket (px4_daemon/sock_protocol.cpp)
ENV_BIN = "PX4_SITL_BIN"


@dataclass
class Px4Config:
    autopilot: str
    bin_dir: Path
    preset: str | None = None
    speedup: float = 1.0
    seed: int = 0
    current: tuple[float, float] = (0.0, 0.0)
    depth: float = 0.0
    home: Home = field(default_factory=Home)
    params: dict[str, float] = field(default_factory=dict)
    workdir: Path | None = None  # None: a temporary folder
    truth_log: Path | None = None  # CSV of the physics' own speed over vehicle time (for scoring)
    faults: tuple = ()
    connect_timeout_s: float = 60.0


def find_build(bin_dir: Path | str) -> Path:
    """The PX4 SITL build folder (``…/build/px4_sitl_default``) from it or its ``bin`` folder."""
    folder = Path(bin_dir).expanduser()
    for candidate in (folder, folder.parent):
        if (candidate / "bin" / "px4").is_file() and (candidate / "etc" / "init.d-posix" / "rcS").is_file():
            return candidate
    raise ValueError(f"no PX4 SITL build in {folder} (expected bin/px4 and etc/init.d-posix/rcS: build PX4 "
                     f"with `make px4_sitl_default` and pass build/px4_sitl_default with --px4-bin or ${ENV_BIN})")


def parameter_text(autopilot: str) -> str:
    return (resources.files("sim") / "px4" / AUTOPILOTS[autopilot].params).read_text(encoding="utf-8")


def parse_parameters(text: str) -> dict[str, str]:
    """``NAME VALUE`` lines (``#`` comments, blank lines ignored) in order."""
    params: dict[str, str] = {}
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        name, value = line.split()[:2]
        params[name] = value
    return params


def _port_free(port: int, kind: int) -> bool:
    with socket.socket(socket.AF_INET, kind) as probe:
        try:
            probe.bind(("0.0.0.0" if kind == socket.SOCK_DGRAM else "127.0.0.1", port))
        except OSError:
            return False
    return True


def _lock_free(instance: int) -> bool:
    path = LOCK_FILE.format(instance=instance)
    if not os.path.exists(path):
        return True
    try:
        with open(path, "a") as handle:
            fcntl.lockf(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
            fcntl.lockf(handle, fcntl.LOCK_UN)
    except OSError:
        return False
    return True


def _instance_free(instance: int) -> bool:
    """PX4 instance ``instance``'s ports (HIL TCP 4560+I, PX4's UDP ports) and its own lock are free."""
    return (_lock_free(instance) and _port_free(HIL_BASE_PORT + instance, socket.SOCK_STREAM)
            and all(_port_free(base + instance, socket.SOCK_DGRAM) for base in UDP_BASE_PORTS))


class Px4InstanceClaim(InstanceClaim):
    """A PX4 instance reserved for this process until PX4 holds its own lock and ports (and after):
    probing them free and starting PX4 later let two simulators started together take the same one."""

    def __init__(self, limit: int = 10) -> None:
        super().__init__("px4-sitl", _instance_free, limit)


def free_instance(limit: int = 10) -> int:
    """The first PX4 instance free and claimed by no process of ours, without claiming it."""
    claim = Px4InstanceClaim(limit)
    claim.release()
    return claim.instance


def _die_with_parent() -> None:
    """In the PX4 child: be SIGKILLed when this process dies (Linux prctl)."""
    try:
        import ctypes
        import signal

        ctypes.CDLL("libc.so.6", use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


class Px4Sitl:
    """PX4 process + HIL endpoint; ``run()`` steps the physics until stopped or PX4 exits."""

    def __init__(self, config: Px4Config, on_ready=None) -> None:
        if config.autopilot not in AUTOPILOTS:
            raise ValueError(f"unknown autopilot {config.autopilot!r} (known: {', '.join(AUTOPILOTS)})")
        self.config = config
        self.spec = AUTOPILOTS[config.autopilot]
        self.build = find_build(config.bin_dir)
        preset = load_preset(config.preset or self.spec.preset)
        self.vehicle = Vehicle(preset, seed=config.seed, current_north=config.current[0],
                               current_east=config.current[1], depth=config.depth, speed=0.0, faults=config.faults)
        for name, value in self.spec.limits.items():
            setattr(self.vehicle.limits, name, value)
        factory = DECODERS[self.spec.decoder]
        decoder = factory.for_preset(preset) if hasattr(factory, "for_preset") else factory()
        self._truth_file = open(config.truth_log, "w", encoding="utf-8") if config.truth_log else None  # noqa: SIM115
        self.physics = HilPhysics(self.vehicle, decoder, home=config.home, seed=config.seed, truth_log=self._truth_file)
        self._claim = Px4InstanceClaim()  # held for PX4's lifetime: released in close()
        self.instance = self._claim.instance
        self.endpoint_hil = HilEndpoint(self.physics, port=HIL_BASE_PORT + self.instance,
                                        speedup=config.speedup)
        self.port = ONBOARD_BASE_PORT + self.instance
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
        """What a client passes to pymavlink: PX4's onboard link listens on this UDP port."""
        return f"udpout:127.0.0.1:{self.port}"

    def parameters(self) -> dict[str, str]:
        params = parse_parameters(parameter_text(self.config.autopilot))
        params.update({name: f"{value:g}" for name, value in self.config.params.items()})
        return params

    def environment(self) -> dict[str, str]:
        env = {k: v for k, v in os.environ.items() if not k.startswith(("PX4_", "ROS_"))}
        env.update(PX4_SYS_AUTOSTART=str(self.spec.autostart), PX4_SIMULATOR="mavlink", PX4_SIM_MODEL="none")
        env.update({f"PX4_PARAM_{name}": value for name, value in self.parameters().items()})
        return env

    def command(self) -> list[str]:
        return [str(self.build / "bin" / "px4"), "-i", str(self.instance), "-d", str(self.build / "etc")]

    def start(self) -> None:
        command = self.command()
        log.info("starting PX4 SITL (instance %d): %s", self.instance, " ".join(command))
        self.log_path = self.workdir / "px4.log"
        self._log_file = open(self.log_path, "w")  # noqa: SIM115 - closed with the process
        self.process = subprocess.Popen(command, cwd=self.workdir, env=self.environment(), stdout=self._log_file,
                                        stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL,
                                        preexec_fn=_die_with_parent)
        self.endpoint_hil.accept(self.config.connect_timeout_s, alive=lambda: self.process.poll() is None)
        self._wait_mavlink()
        if self.on_ready is not None:
            self.on_ready(f"udpin:127.0.0.1:{self.port}")

    def _wait_mavlink(self, timeout_s: float = 120.0) -> None:
        """Step the physics (PX4 boots on our clock) until PX4's onboard MAVLink link is up."""
        deadline = time.monotonic() + timeout_s
        marker = f"on udp port {self.port} remote port"
        self.endpoint_hil.run(alive=lambda: self.process.poll() is None and time.monotonic() < deadline,
                              until=lambda: marker in self.log_path.read_text(errors="replace"))
        if self.process.poll() is not None:
            raise RuntimeError(f"PX4 exited ({self.process.returncode}): {self.log_tail()}")
        if self.endpoint_hil.closed:
            raise RuntimeError(f"PX4 closed the simulator connection: {self.log_tail()}")
        if marker not in self.log_path.read_text(errors="replace"):
            raise RuntimeError(f"PX4 did not open its onboard MAVLink port within {timeout_s:.0f} s: "
                               f"{self.log_tail()}")

    def log_tail(self, lines: int = 15) -> str:
        try:
            return " | ".join(self.log_path.read_text(errors="replace").splitlines()[-lines:])
        except OSError:
            return "(no log)"

    def run(self) -> int:
        self.start()
        try:
            self.endpoint_hil.run(alive=lambda: not self._stop and self.process.poll() is None)
        finally:
            self.close()
        return 0

    def stop(self) -> None:
        self._stop = True
        self.endpoint_hil.stop()

    def close(self) -> None:
        if self.process is not None and self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=3)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        if self.process is not None and _lock_free(self.instance):
            try:  # PX4 stopped by a signal leaves its command socket behind
                os.unlink(SOCKET_FILE.format(instance=self.instance))
            except OSError:
                pass
        if getattr(self, "_log_file", None) is not None:
            self._log_file.close()
        self.endpoint_hil.close()
        if self._truth_file is not None:
            self._truth_file.close()
        if self._tmp is not None:
            self._tmp.cleanup()
        self._claim.release()
