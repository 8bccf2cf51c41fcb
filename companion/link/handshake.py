"""Meeting a vehicle: which autopilot it is and what it needs before any procedure (SPEC C1).

After the autopilot's first HEARTBEAT: ask for AUTOPILOT_VERSION, recognise the autopilot from a
marker parameter only it has (cheaper than a full PARAM_REQUEST_LIST of ~1000 ArduPilot parameters
over a radio) unless the caller named it, build its strategy, ask for the telemetry streams it
needs, let the strategy read what it needs from the vehicle (a boat's actuation: which outputs
steer and drive it, ``companion.link.actuation``), and read the ground station's system id, the RC
override timeout and the integer parameter encoding (AUTOPILOT_VERSION.capabilities, falling back
to the profile's).
"""
from __future__ import annotations

import dataclasses
import logging
from typing import Any

from companion.link import param_codec
from companion.link.autopilots import strategy_for
from companion.link.autopilots.base import AutopilotStrategy, LinkPorts
from companion.link.errors import ProfileError
from companion.link.profiles import AutopilotProfile, detect_profile, get_profile, marker_params
from companion.link.snapshot import DepthSensor, TelemetryAssembler

log = logging.getLogger(__name__)

MAV_CMD_SET_MESSAGE_INTERVAL = 511
MAV_CMD_REQUEST_MESSAGE = 512
MSG_ID_AUTOPILOT_VERSION = 148
MSG_ID_ATTITUDE = 30


def detect(ports: LinkPorts) -> AutopilotProfile:
    """The profile whose marker parameter the vehicle answers for (ProfileError when none does)."""
    markers = marker_params()
    parameters = ports.parameters
    for _attempt in range(3):
        for name in markers:
            parameters.request(name)
        ports.clock.wait_until(lambda: any(n in parameters.cache for n in markers), ports.clock.timeouts.param_try_s)
        found = {n for n in markers if n in parameters.cache}
        if found:
            heartbeat = ports.announcements.last_heartbeat
            return detect_profile(found, getattr(heartbeat, "type", None))
    heartbeat = ports.announcements.last_heartbeat
    if vehicle_signs(heartbeat) and not ports.transport.signing:
        raise ProfileError(f"no answer to the profile marker parameters {', '.join(markers)}: the vehicle signs its "
                           "messages (MAVLink 2 signing) and ignores unsigned requests; give its key with "
                           "--signing-key (or signing_key_file in the configuration file)")
    raise ProfileError(f"no answer to the profile marker parameters {', '.join(markers)}: the vehicle did not "
                       "answer parameter requests (a link too slow or one-way?); name the autopilot with --profile")


#: MAVLink 2 incompatibility flag of a signed frame
MAVLINK_IFLAG_SIGNED = 0x01


def vehicle_signs(message: Any) -> bool:
    """``message`` came in a signed MAVLink 2 frame (whether or not this link can check the signature)."""
    header = getattr(message, "_header", None)
    return bool(header is not None and getattr(header, "incompat_flags", 0) & MAVLINK_IFLAG_SIGNED)


def _configured(ports: LinkPorts, chosen: AutopilotProfile, strategy: AutopilotStrategy) -> AutopilotProfile:
    """The profile completed with what the strategy reads from this vehicle (its actuation: which
    outputs steer and drive it); ProfileError when the vehicle cannot be understood."""
    configured = strategy.configure()
    if configured is not chosen:
        assembler = ports.telemetry.assembler
        if assembler is None:
            raise RuntimeError("the profile is configured only once telemetry is assembled (TelemetryFeed.use)")
        ports.profile = configured
        for part in (ports.modes, ports.parameters, ports.overrides, assembler):
            part.profile = configured
        if configured.actuation is not None:
            log.info("actuation: %s", configured.actuation.describe())
    return configured


def request_streams(ports: LinkPorts, rates: dict[int, float]) -> None:
    """MAV_CMD_SET_MESSAGE_INTERVAL for each message id → Hz (0 or less: stop it); the attitude
    period asked for is the clock's (a stalled lockstep steps on by it)."""
    for message_id, rate_hz in rates.items():
        ports.commands.send(MAV_CMD_SET_MESSAGE_INTERVAL, (message_id, 1e6 / rate_hz if rate_hz > 0 else -1))
    if rates.get(MSG_ID_ATTITUDE, 0) > 0:
        ports.clock.requested_period_ms = 1000.0 / rates[MSG_ID_ATTITUDE]


@dataclasses.dataclass
class Setup:
    """What the handshake settled: the profile, its strategy, and the vehicle's own settings."""

    profile: AutopilotProfile
    strategy: AutopilotStrategy
    stream_rates: dict[int, float]
    override_timeout_s: float = 3.0


def _rebooted(ports: LinkPorts, strategy: AutopilotStrategy) -> None:
    """The vehicle rebooted: set-points sent to the old boot are no longer awaited, and the strategy
    forgets what it kept of it (targets, an excitation)."""
    ports.commands.abandon()
    strategy.on_reboot()


def setup(ports: LinkPorts, profile: str | None, stream_rates: dict[int, float] | None, depth_sensor: DepthSensor,
          vehicle: dict | None = None) -> Setup:
    """The handshake (module docstring); ``vehicle`` overrides the profile's defaults with this
    vehicle's properties (rudder full scale, servo rate)."""
    ports.ground.send_heartbeat()
    ports.commands.send(MAV_CMD_REQUEST_MESSAGE, (MSG_ID_AUTOPILOT_VERSION,))
    chosen = get_profile(profile) if profile is not None else detect(ports)
    if vehicle:
        chosen = dataclasses.replace(chosen, **vehicle)
    ports.profile = chosen
    for part in (ports.modes, ports.parameters, ports.overrides):
        part.profile = chosen
    ports.announcements.mode_name = chosen.mode_name
    strategy = strategy_for(ports, chosen)
    ports.overrides.send = strategy.send_overrides
    ports.telemetry.refine = strategy.on_snapshot
    ports.modes.on_change(strategy.mode_changed)
    ports.modes.before_change(strategy.before_mode_change)
    ports.modes.on_accepted(strategy.mode_accepted)
    ports.telemetry.on_reboot(lambda: _rebooted(ports, strategy))
    rates = dict(strategy.streams if stream_rates is None else stream_rates)
    request_streams(ports, rates)
    ports.parameters.int_encoding = chosen.int_encoding
    ports.telemetry.use(TelemetryAssembler(chosen, depth_sensor=depth_sensor), ports.announcements.last_heartbeat)
    chosen = _configured(ports, chosen, strategy)
    if "gcs_sysid" in chosen.params:  # PX4 has no such parameter: any ground station may command it
        ports.ground.gcs_sysid = int(ports.parameters.read_first(chosen.native_candidates("gcs_sysid"), default=255.0))
    result = Setup(chosen, strategy, rates)
    if "override_timeout" in chosen.params:
        result.override_timeout_s = ports.parameters.read_first(chosen.native_candidates("override_timeout"),
                                                                default=3.0)
    announcements = ports.announcements
    if announcements.capabilities is None:  # AUTOPILOT_VERSION may already have arrived while reading
        ports.clock.wait_until(lambda: announcements.capabilities is not None, ports.clock.timeouts.command_s)
    if announcements.capabilities is not None:
        ports.parameters.int_encoding = param_codec.encoding_from_capabilities(announcements.capabilities,
                                                                               chosen.int_encoding)
    log.info("connected: system %d, profile %s, GCS sysid %d, override timeout %.1f s, int encoding %s",
             ports.transport.system_id, chosen.name, ports.ground.gcs_sysid, result.override_timeout_s,
             ports.parameters.int_encoding)
    return result
