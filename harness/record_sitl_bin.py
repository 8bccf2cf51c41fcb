"""Record an ArduPilot DataFlash ``.bin`` of ordinary manoeuvres on the real firmware, for log identification:
ArduRover SITL flying our boat physics (``sim.ardupilot_sitl``) through a survey — course changes
by its own GUIDED heading hold at a few speeds (fractions of WP_SPEED), no doublet — flown over
MAVLink with :class:`companion.link.vehicle.VehicleLink`. SITL writes the log itself (``logs/`` of
its working folder, while armed); this copies it out.

Needs ArduPilot's SITL binaries (``ARDUPILOT_SITL_BIN``); run it without a network, as the tests do::

    unshare -n bash -c 'ip link set lo up; python -m harness.record_sitl_bin --out rover.bin'
"""
from __future__ import annotations

import argparse
import logging
import os
import select
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from harness.missions import SurveyPlan, fly_plan
from harness.recording import keep_largest_log, stop_child

log = logging.getLogger(__name__)

#: a boat: no depth, speeds as fractions of WP_SPEED, a course change every 30 s
BOAT_PLAN = SurveyPlan(thrusts=(0.6, 0.8, 1.0), seconds_per_thrust=180.0, depth=None,
                       course_changes_deg=(30.0, -40.0, 20.0, -30.0, 35.0, -15.0))

_CHILD = """
import sys
from pathlib import Path
from sim.ardupilot_sitl import ArduPilotSitl, SitlConfig
config = SitlConfig(autopilot="ardurover", bin_dir=Path(sys.argv[1]), preset="boat", speedup=float(sys.argv[2]),
                    seed=int(sys.argv[3]), depth=0.0, workdir=Path(sys.argv[4]))
sitl = ArduPilotSitl(config, on_ready=lambda endpoint: print("READY tcp:127.0.0.1:%d" % sitl.port, flush=True))
sys.exit(sitl.run())
"""


def record_sitl_bin(out: str | Path, plan: SurveyPlan = BOAT_PLAN, *, bin_dir: str | None = None, seed: int = 1,
                    speedup: float = 10.0) -> Path:
    """Fly ``plan`` on ArduRover SITL + the boat physics and copy the DataFlash log it wrote to ``out``."""
    from companion.rehearsal.rehearsal import arm_when_ready, preset_vehicle
    from companion.link.vehicle import VehicleLink

    bin_dir = bin_dir or os.environ.get("ARDUPILOT_SITL_BIN")
    if not bin_dir:
        raise RuntimeError("ARDUPILOT_SITL_BIN is not set")
    out = Path(out)
    with tempfile.TemporaryDirectory(prefix="sitl-bin-") as workdir:
        child = subprocess.Popen([sys.executable, "-c", _CHILD, bin_dir, str(speedup), str(seed), workdir],
                                 stdout=subprocess.PIPE, stderr=open(Path(workdir) / "bridge.log", "w"), text=True)
        try:
            endpoint = None
            deadline = time.monotonic() + 120.0
            while endpoint is None and time.monotonic() < deadline and child.poll() is None:
                if select.select([child.stdout], [], [], 0.5)[0]:
                    line = child.stdout.readline()
                    if line.startswith("READY "):
                        endpoint = line.split()[1]
            if endpoint is None:
                raise RuntimeError(f"SITL did not start: {(Path(workdir) / 'bridge.log').read_text()[-500:]}")
            link = VehicleLink.connect(endpoint, heartbeat_timeout_s=60.0, vehicle=preset_vehicle("boat"))
            try:
                arm_when_ready(link, patience_s=120.0)
                link.set_mode("hold")
                fly_plan(link, plan)
                link.set_mode("manual")
                link.arm(False)
            finally:
                link.close()
        finally:
            stop_child(child, 10.0)
        keep_largest_log(Path(workdir) / "logs", "*.BIN", out, "SITL wrote no DataFlash log")
    log.info("recorded %s (%d bytes)", out, out.stat().st_size)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", required=True)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--speedup", type=float, default=10.0)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO)
    record_sitl_bin(args.out, seed=args.seed, speedup=args.speedup)
    return 0


if __name__ == "__main__":
    sys.exit(main())
