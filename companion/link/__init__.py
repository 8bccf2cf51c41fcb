"""MAVLink vehicle interface (SPEC C1): connection, vehicle clock, telemetry snapshots, commands,
parameter protocol and autopilot profiles. Public API re-exported here."""
from companion.link.errors import (CommandFailed, HeartbeatTimeout, LinkError, LinkLost, ModeChangeFailed,
                                   ParamError, ParamRefused, ParamTimeout, ProfileError, VehicleRebooted)
from companion.link.profiles import PROFILES, AutopilotProfile, detect_profile, get_profile
from companion.link.snapshot import DepthSensor, TelemetryAssembler
from companion.link.vehicle import LinkTimeouts, UserCommand, VehicleLink

__all__ = [
    "AutopilotProfile", "CommandFailed", "DepthSensor", "HeartbeatTimeout", "LinkError", "LinkLost", "LinkTimeouts",
    "ModeChangeFailed", "PROFILES", "ParamError", "ParamRefused", "ParamTimeout", "ProfileError", "TelemetryAssembler",
    "UserCommand", "VehicleLink", "VehicleRebooted", "detect_profile", "get_profile",
]
