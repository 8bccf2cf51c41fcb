"""Record a PX4 ``.ulg`` of ordinary manoeuvres on the real firmware, for log identification: PX4 SITL
flying our boat (``px4-rover``) or our AUV trimmed neutral (``px4-uuv``) through a survey — course
changes by PX4's own OFFBOARD heading hold at a few speeds or thrusts, no doublet — flown over
MAVLink with :class:`companion.link.vehicle.VehicleLink`. PX4 writes the log itself (``log/`` of
its working folder, from boot until it disarms); this copies it out, with the physics' truth log.

Needs a PX4 SITL build (``PX4_SITL_BIN``); run it without a network, as the tests do::

    unshare -n bash -c 'ip link set lo up; python -m harness.record_px4_ulg --autopilot px4-rover --out boat.ulg'
"""
from __future__ import annotations

import argparse
import logging
import os
import select
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from harness.missions import SurveyPlan, fly_plan
from harness.recording import keep_largest_log, stop_child

log = logging.getLogger(__name__)

#: a course change every 30 s at three speeds (fractions of RO_MAX_THR_SPEED on the boat, thrusts on the AUV)
PLANS = {
    "px4-rover": SurveyPlan(thrusts=(0.5, 0.7, 0.9), seconds_per_thrust=180.0, depth=None,
                            course_changes_deg=(30.0, -40.0, 20.0, -30.0, 35.0, -15.0)),
    # the UUV's course turns at 3°/s: a step saturates its yaw torque, and its four thrusters then lose
    # forward thrust (measured: 0.42–0.75 m/s at thrust 0.45, no steady segment); its speed settles
    # slower than the boat's (a 30 s settle left segments still accelerating by ±2.9 %: a22 +5.3 %)
    "px4-uuv": SurveyPlan(thrusts=(0.45, 0.55, 0.65), seconds_per_thrust=210.0, settle_s=60.0, depth=None,
                          course_changes_deg=(30.0, -40.0, 20.0, -30.0, 35.0, -15.0), turn_rate_deg_s=3.0),
}

_CHILD = """
import sys
from pathlib import Path
from sim.px4_sitl import Px4Config, Px4Sitl
config = Px4Config(autopilot=sys.argv[1], bin_dir=Path(sys.argv[2]), speedup=float(sys.argv[3]), seed=int(sys.argv[4]),
                   workdir=Path(sys.argv[5]), truth_log=Path(sys.argv[5]) / "truth.csv",
                   preset=sys.argv[6] or None, depth=0.0 if sys.argv[1] == "px4-rover" else 5.0)
sitl = Px4Sitl(config, on_ready=lambda endpoint: print("READY " + endpoint, flush=True))
sys.exit(sitl.run())
"""


def record_px4_ulg(out: str | Path, autopilot: str = "px4-rover", *, bin_dir: str | None = None, seed: int = 1,
                   speedup: float = 5.0, plan: SurveyPlan | None = None) -> Path:
    """Fly ``plan`` on PX4 SITL and copy the .ulg it wrote to ``out`` (the truth log beside it, ``.truth.csv``)."""
    from companion.link.vehicle import VehicleLink
    from companion.records.variants import write_variant
    from companion.rehearsal.rehearsal import arm_px4_when_ready, neutral_buoyancy

    bin_dir = bin_dir or os.environ.get("PX4_SITL_BIN")
    if not bin_dir:
        raise RuntimeError("PX4_SITL_BIN is not set")
    plan = plan or PLANS[autopilot]
    out = Path(out)
    with tempfile.TemporaryDirectory(prefix="px4-ulg-") as workdir:
        preset = ""
        if autopilot == "px4-uuv":
            preset = str(write_variant("starfish", dict(neutral_buoyancy("starfish")), 1.0,
                                       Path(workdir) / "preset.json"))
        child = subprocess.Popen([sys.executable, "-c", _CHILD, autopilot, bin_dir, str(speedup), str(seed), workdir,
                                  preset], stdout=subprocess.PIPE, stderr=open(Path(workdir) / "bridge.log", "w"),
                                 text=True)
        try:
            endpoint = None
            deadline = time.monotonic() + 120.0
            while endpoint is None and time.monotonic() < deadline and child.poll() is None:
                if select.select([child.stdout], [], [], 0.5)[0]:
                    line = child.stdout.readline()
                    if line.startswith("READY "):
                        endpoint = line.split()[1].replace("udpin:", "udpout:")
            if endpoint is None:
                raise RuntimeError(f"PX4 SITL did not start: {(Path(workdir) / 'bridge.log').read_text()[-500:]}")
            link = VehicleLink.connect(endpoint, heartbeat_timeout_s=60.0)
            try:
                arm_px4_when_ready(link, patience_s=120.0)
                found = link.mode
                link.set_mode("hold")
                fly_plan(link, plan)
                link.autopilot.release(None)
                link.set_mode(found)
                link.arm(False)  # PX4 closes its log when it disarms
                for _ in range(100):
                    link.next_telemetry()
            finally:
                link.close()
        finally:
            stop_child(child, 20.0)
        keep_largest_log(Path(workdir) / "log", "*/*.ulg", out, "PX4 wrote no .ulg")
        shutil.copy(Path(workdir) / "truth.csv", out.with_suffix(".truth.csv"))
    log.info("recorded %s (%d bytes)", out, out.stat().st_size)
    return out


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--autopilot", choices=sorted(PLANS), default="px4-rover")
    parser.add_argument("--out", required=True)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--speedup", type=float, default=5.0)
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO)
    record_px4_ulg(args.out, args.autopilot, seed=args.seed, speedup=args.speedup)
    return 0


if __name__ == "__main__":
    sys.exit(main())
