"""What the PX4 SITL tests and bench share: PX4 SITL (``PX4_SITL_BIN``) flying our physics as a child
``python -m sim run``, the companion connected and PX4 armed in Hold; the state an abort must leave
as found (every heading gain, the mode, and the manual-control state: the companion streams no sticks
and PX4 has no manual control it did not have); and the four abort scenarios (Ctrl-C in the doublet,
a pilot's mode change, a link loss, a refused parameter).

Run it without a network, as the tests do: ``unshare -n bash -c 'ip link set lo up; ...'``.
"""
from __future__ import annotations

import os
import select
import socket
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from behaviors.identification import ManoeuvreConfig
from companion.procedures.campaign import CampaignConfig

ENV_BIN = "PX4_SITL_BIN"
#: the preset each PX4 airframe flies (the AUV trimmed neutral: companion.rehearsal.rehearsal.neutral_buoyancy)
PRESETS = {"px4-rover": "boat", "px4-uuv": "starfish"}
#: the neutral heading gains a PX4 campaign may change
HEADING_GAINS = {"px4-rover": ("heading_angle_p", "heading_rate_p", "heading_rate_i", "heading_ff_length",
                               "heading_ff_correction"),
                 "px4-uuv": ("heading_angle_p", "heading_rate_d")}
#: one thrust and short settles: the abort scenarios only need a campaign under way
SHORT_THRUST = {"px4-rover": 0.7, "px4-uuv": 0.55}


def px4_bin() -> str | None:
    """The PX4 SITL build folder of ``$PX4_SITL_BIN`` (with bin/px4), None without one."""
    folder = os.environ.get(ENV_BIN)
    if folder and ((Path(folder) / "bin" / "px4").is_file() or (Path(folder) / "px4").is_file()):
        return folder
    return None


def short_campaign(autopilot: str) -> CampaignConfig:
    return CampaignConfig(thrusts=(SHORT_THRUST[autopilot],), axes=("yaw",), step_labels=("scheduled",),
                          yaw=ManoeuvreConfig(settle_s=20.0, resettle_s=10.0), user_set=("thrusts", "axes"))


def simulator(autopilot: str, folder: Path, speedup: float = 5.0, seed: int = 1):
    """``python -m sim run --autopilot px4-…`` on a free instance (not started), its truth log in
    ``folder``; the AUV flies its neutrally trimmed variant."""
    from companion.records.variants import write_variant
    from companion.rehearsal.launcher import SimulatorProcess
    from companion.rehearsal.rehearsal import neutral_buoyancy

    preset = PRESETS[autopilot]
    if autopilot == "px4-uuv":
        preset = str(write_variant(preset, dict(neutral_buoyancy(preset)), 1.0, folder / "preset.json"))
    return SimulatorProcess(preset, speedup, seed, (0.0, 0.0), autopilot=autopilot, px4_bin=px4_bin(),
                            transport="udp", lockstep=False, ready_timeout_s=120.0, log_path=folder / "sim.log",
                            extra_args=["--truth-log", str(folder / "truth.csv")])


def client_endpoint(sim) -> str:
    """Where a companion listens for PX4 (``udpin:127.0.0.1:14540+I``, where PX4 sends first). PX4's
    UDP instance locks onto its first partner's address and port until it restarts: a client on an
    ephemeral port (``udpout:``) is heard, and every later one is not (measured); one that listens on
    PX4's remote port may come and go."""
    return f"udpin:127.0.0.1:{14540 + sim.port - 14580}"


def connect_armed(sim, relay: "UdpRelay | None" = None):
    """The companion's link to a started simulator (through ``relay`` if given), PX4 armed in Hold (a
    user arms it; a procedure never does)."""
    from companion.link.vehicle import VehicleLink
    from companion.rehearsal.rehearsal import arm_px4_when_ready

    link = VehicleLink.connect(relay.endpoint if relay is not None else client_endpoint(sim), heartbeat_timeout_s=60.0)
    arm_px4_when_ready(link, patience_s=120.0)
    return link


@dataclass
class Found:
    gains: dict
    mode: str
    manual_control: bool | None


def found_state(link) -> Found:
    """The gains, the mode and PX4's manual control as a test finds them before a procedure."""
    strategy = link.autopilot
    return Found(link.get_params(HEADING_GAINS[link.profile.name]), link.mode, strategy.manual_control_present)


def settled_state(link, settle_s: float = 12.0) -> Found:
    """:func:`found_state` after ``settle_s`` of vehicle time: PX4 forgets a MAVLink stick source only
    COM_RC_LOSS_T (5 s here) after its last stick, so a state read sooner after a companion stopped
    streaming still shows the companion's sticks (as :func:`as_found_problems` waits)."""
    start = link.vehicle_time_s
    while link.vehicle_time_s - start < settle_s:
        link.next_telemetry()
    return found_state(link)


def as_found_problems(link, found: Found, *, mode: bool = True, settle_s: float = 12.0) -> list[str]:
    """What is not as found, after ``settle_s`` of vehicle time (longer than the simulated vehicle's
    COM_RC_LOSS_T of 5 s plus what a companion lagging the stream may take to see it, so a
    manual-control failsafe would have shown): every gain, the mode (with
    ``mode``), no sticks or set-points streamed, PX4's manual control as found."""
    start = link.vehicle_time_s
    while link.vehicle_time_s - start < settle_s:
        link.next_telemetry()
    problems = []
    now = link.get_params(tuple(found.gains))
    for name, value in found.gains.items():
        if abs(now[name] - value) > max(1e-6 * abs(value), 1e-9):
            problems.append(f"{name} {now[name]!r}, found {value!r}")
    if link.autopilot.taken:
        problems.append("the companion still streams sticks and set-points")
    if link.autopilot.manual_control_present != found.manual_control:
        problems.append(f"PX4 manual control {link.autopilot.manual_control_present}, found {found.manual_control}")
    if mode and link.mode != found.mode:
        problems.append(f"mode {link.mode}, found {found.mode}")
    return problems


class UdpRelay:
    """A loopback UDP relay between the companion and PX4's onboard MAVLink port that can go silent
    for a while in both directions (a radio dropout), in its own thread.

    The companion connects to :attr:`endpoint`; PX4 answers the relay's socket (its partner). Freezing
    PX4 itself is no link loss: PX4 stopped for 6.5 s of wall clock came back with its angular velocity
    timed out and terminated the flight (measured), which no procedure can undo."""

    def __init__(self, vehicle_port: int) -> None:
        self.vehicle = ("127.0.0.1", vehicle_port)
        self.front = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.front.bind(("127.0.0.1", 0))
        self.back = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.back.bind(("127.0.0.1", 0))
        self.companion = None
        self.silent_until = 0.0
        self.dropped = 0
        self._stop = False
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    @property
    def endpoint(self) -> str:
        return f"udpout:127.0.0.1:{self.front.getsockname()[1]}"

    def cut(self, seconds: float) -> None:
        """Drop every datagram of both directions for ``seconds`` of wall clock."""
        self.silent_until = time.monotonic() + seconds

    def _run(self) -> None:
        while not self._stop:
            ready, _, _ = select.select([self.front, self.back], [], [], 0.2)
            for sock in ready:
                data, address = sock.recvfrom(65536)
                if time.monotonic() < self.silent_until:
                    self.dropped += 1
                    continue
                if sock is self.front:
                    self.companion = address
                    self.back.sendto(data, self.vehicle)
                elif self.companion is not None:
                    self.front.sendto(data, self.companion)

    def close(self) -> None:
        self._stop = True
        self._thread.join(timeout=1.0)
        self.front.close()
        self.back.close()


# ------------------------------------------------------------------------- abort scenarios
def run_short(link, abort, tmp: Path):
    from companion.procedures.app import run_campaign
    from companion.records.store import Store

    with Store(tmp / f"abort-{time.monotonic_ns()}.sqlite") as store:
        return run_campaign(link, store, short_campaign(link.profile.name),
                            vehicle_id=store.add_vehicle(link.profile.name), abort=abort)


def ctrl_c_in_the_doublet(link, relay, tmp: Path):
    """What the signal handler does, inside the MANUAL excitation (the first doublet)."""
    state = {"manual_seen": None}

    def ctrl_c():
        if link.mode == "manual" and state["manual_seen"] is None:
            state["manual_seen"] = link.vehicle_time_s
        seen = state["manual_seen"]
        return "signal SIGINT" if seen is not None and link.vehicle_time_s - seen > 1.0 else None

    return run_short(link, ctrl_c, tmp)


def pilot_mode_change(link, relay, tmp: Path):
    """Another client selects Return (PX4's own RTL), by number, 12 s in."""
    from companion.link.autopilots.px4 import main_sub

    start = link.vehicle_time_s
    state = {"done": False}

    def pilot():
        if not state["done"] and link.vehicle_time_s - start > 12.0:
            state["done"] = True
            main, sub = main_sub(link.profile.modes["rtl"])
            link.transport.command_long(176, (1.0, float(main), float(sub)))
        return None

    return run_short(link, pilot, tmp)


def link_loss(link, relay, tmp: Path):
    """The link goes silent for 6.5 s of wall clock (longer than the 5 s link watchdog) 22 s in;
    PX4's own loss failsafes act meanwhile, as designed."""
    start = link.vehicle_time_s
    state = {"cut": False}

    def dropout():
        if not state["cut"] and link.vehicle_time_s - start > 22.0:
            state["cut"] = True
            relay.cut(6.5)
        return None

    return run_short(link, dropout, tmp)


def refused_parameter(link, relay, tmp: Path):
    """The vehicle refuses the first write of the rate or derivative gain (what an echo with another
    value makes ParamRefused), when the step check writes the design."""
    from companion.link.errors import ParamRefused

    names = {"px4-rover": "RO_YAW_RATE_P", "px4-uuv": "UUV_YAW_D"}
    refused = names[link.profile.name]
    original = link.parameters.set_param
    state = {"refused": False}

    def set_param(name, value, *, retries=3):
        if name == refused and not state["refused"]:
            state["refused"] = True
            raise ParamRefused(f"{name}={value!r} refused: the vehicle echoed another value", name=name, value=value)
        return original(name, value, retries=retries)

    link.parameters.set_param = set_param
    try:
        return run_short(link, lambda: None, tmp)
    finally:
        link.parameters.set_param = original


SCENARIOS = {"ctrl-c": ctrl_c_in_the_doublet, "pilot": pilot_mode_change, "link-loss": link_loss,
             "refused-parameter": refused_parameter}


def run_scenario(name: str, link, relay: UdpRelay, tmp: Path) -> dict:
    """One abort scenario from as found (the link through ``relay``); its outcome and what it left
    not as found."""
    found = found_state(link)
    _campaign, outcome, _ = SCENARIOS[name](link, relay, tmp)
    pilot = name == "pilot"
    problems = as_found_problems(link, found, mode=not pilot)
    if pilot and link.mode != "rtl":
        problems.append(f"the pilot's mode did not stand: {link.mode}")
    if pilot:
        link.set_mode(found.mode)
    return {"scenario": name, "status": outcome.status, "reason": outcome.reason,
            "restore_problems": list(outcome.restore_problems), "not_as_found": problems}
