"""ArduPilot SITL flying one of its own vehicles as a user finds it: the frame's shipped defaults
(``Tools/autotest/default_params``) plus what the rig needs, for the SITL tests and benches of
``companion run --learn`` on physics this project did not write (``harness.rover_mission`` flies the
survey).

* :data:`VECTORED_ROV`: ``ardusub --model vectored`` (SITL's BlueROV2-like ROV, ``sub.parm``).
  ArduSub's AUTO (AC_WPNav) flies a holonomic vehicle: at a corner it translates sideways while the
  yaw turns toward the next leg (WP_YAW_BEHAVIOR 4). The vectored frame's lateral thrust is what
  makes that possible, and its yaw moment does not depend on the speed; our own AUV physics behind
  the JSON backend (``sim.ardupilot_json.SubVectoredDecoder``) has neither (no lateral force; its yaw
  is a rudder whose authority falls with u²), so in AUTO it stops at the first corner and cannot turn
  (measured). The rig arms it from one client: ``FS_PILOT_INPUT 0``, ``FS_GCS_ENABLE 0`` (as
  ``bench/bench_ardupilot.py``).
* :data:`MOTORBOAT`, :data:`MOTORBOAT_SKID`: ``ardurover --model motorboat`` (a rudder and one
  thruster; ``rover.parm`` + ``motorboat.parm``) and ``motorboat-skid`` (twin thrusters, with
  ``rover-skid.parm``). SITL's boat turns at a rate set by the rudder and the speed with no yaw lag of
  its own. The rig turns SITL's waves and wind off (``SIM_WAVE_ENABLE 0``, ``SIM_WIND_SPD 0``), as the
  campaign's bench does by default.

SITL runs on loopback (run inside ``unshare -n``); its serial0 (``endpoint``) is the companion's,
serial1 (``station_endpoint``) the ground station's. Started and stopped by process id.
"""
from __future__ import annotations

import logging
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from sim.ardupilot_sitl import DEFAULT_HOME, MAVLINK_BASE_PORT, free_instance

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class OwnVehicle:
    """One of SITL's own vehicles: its binary, ``--model`` and shipped parameter files."""

    binary: str
    model: str
    defaults: tuple[str, ...]
    rig: tuple[tuple[str, float], ...] = ()  # parameters the rig sets beside the shipped ones

    def __post_init__(self) -> None:
        if not (self.binary and self.model and self.defaults):
            raise ValueError("OwnVehicle needs a binary, a model and its parameter files")


VECTORED_ROV = OwnVehicle("ardusub", "vectored", ("sub.parm",), (("FS_PILOT_INPUT", 0.0), ("FS_GCS_ENABLE", 0.0)))
_CALM = (("SIM_WAVE_ENABLE", 0.0), ("SIM_WIND_SPD", 0.0))
MOTORBOAT = OwnVehicle("ardurover", "motorboat", ("rover.parm", "motorboat.parm"), _CALM)
MOTORBOAT_SKID = OwnVehicle("ardurover", "motorboat-skid", ("rover.parm", "motorboat.parm", "rover-skid.parm"), _CALM)
#: by the name a bench or test gives them
OWN_VEHICLES = {"sitl-rov": VECTORED_ROV, "motorboat": MOTORBOAT, "motorboat-skid": MOTORBOAT_SKID}


@dataclass
class OwnSitl:
    """One of SITL's own vehicles on a free instance (module docstring)."""

    bin_dir: str
    vehicle: OwnVehicle = VECTORED_ROV
    speedup: float = 10.0
    params: dict[str, float] = field(default_factory=dict)
    home: str = DEFAULT_HOME
    workdir: Path | None = None  # SITL's eeprom and logs (None: a temporary folder)
    instance: int = -1
    process: subprocess.Popen | None = None
    _tmp: tempfile.TemporaryDirectory | None = None

    def __post_init__(self) -> None:
        if not self.speedup > 0:
            raise ValueError(f"OwnSitl.speedup must be > 0, not {self.speedup!r}")

    @property
    def port(self) -> int:
        return MAVLINK_BASE_PORT + 10 * self.instance

    @property
    def endpoint(self) -> str:
        return f"tcp:127.0.0.1:{self.port}"

    @property
    def station_endpoint(self) -> str:
        return f"tcp:127.0.0.1:{self.port + 2}"

    def start(self) -> "OwnSitl":
        binary = Path(self.bin_dir) / self.vehicle.binary
        folder = Path(self.bin_dir).resolve().parents[2] / "Tools" / "autotest" / "default_params"
        shipped = [folder / name for name in self.vehicle.defaults]
        missing = [str(path) for path in [binary, *shipped] if not path.is_file()]
        if missing:
            raise FileNotFoundError(f"need {', '.join(missing)} (an ArduPilot tree built for SITL)")
        if self.workdir is None:
            self._tmp = tempfile.TemporaryDirectory(prefix="own-sitl-")
            self.workdir = Path(self._tmp.name)
        self.workdir.mkdir(parents=True, exist_ok=True)
        extra = self.workdir / "rig.parm"
        extra.write_text("".join(f"{name} {value:g}\n" for name, value in {**dict(self.vehicle.rig), **self.params}.items()))
        self.instance = free_instance()
        command = [str(binary), "--model", self.vehicle.model, "--speedup", f"{self.speedup:g}", "-I", str(self.instance),
                   "--home", self.home, "--defaults", ",".join(str(path) for path in [*shipped, extra])]
        log.info("starting SITL: %s", " ".join(command))
        self.process = subprocess.Popen(command, cwd=self.workdir, stdout=subprocess.DEVNULL, stderr=subprocess.STDOUT)
        return self

    def wait_listening(self, patience_s: float = 30.0) -> None:
        """Until serial0 accepts connections (a process start, wall clock)."""
        import socket

        deadline = time.monotonic() + patience_s
        while time.monotonic() < deadline:
            if self.process is not None and self.process.poll() is not None:
                raise RuntimeError(f"SITL exited with code {self.process.returncode}")
            with socket.socket() as probe:
                probe.settimeout(0.5)
                if probe.connect_ex(("127.0.0.1", self.port)) == 0:
                    return
            time.sleep(0.5)
        raise RuntimeError(f"SITL did not listen on {self.endpoint} within {patience_s:g} s")

    def stop(self) -> int | None:
        if self.process is None:
            return None
        if self.process.poll() is None:
            self.process.terminate()
            try:
                self.process.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.process.kill()
                self.process.wait()
        if self._tmp is not None:
            self._tmp.cleanup()
            self._tmp = None
        return self.process.returncode

    def __enter__(self) -> "OwnSitl":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.stop()
