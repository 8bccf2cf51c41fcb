"""What ``companion run`` runs with, once the configuration file and the flags are merged.

:func:`merge` takes the file's values (:func:`companion.service.config.load_config`) and the
flags given (anything not None overrides the file); :class:`RunSettings` checks the result in
``__post_init__`` and builds the resident loop's :class:`~companion.procedures.resident.ServeConfig`.
"""
from __future__ import annotations

import logging
from dataclasses import dataclass, fields, replace
from typing import Any, Mapping

from companion.checks import check_thrust_levels, is_number, require_choice
from companion.service.config import LOG_FORMATS, LOG_LEVELS, split_listen

DEFAULT_STORE = "companion.sqlite"


@dataclass(frozen=True)
class RunSettings:
    """Every setting of ``companion run`` (each is a flag, a configuration key, or both)."""

    connect: str | None = None
    profile: str | None = None
    signing_key: str | None = None  # 64 hex characters
    allowed_senders: tuple[int, ...] = ()  # system ids besides MAV_GCS_SYSID allowed to start procedures
    rudder_full_scale: float | None = None
    rudder_rate: float | None = None
    preset: str | None = None
    store: str = DEFAULT_STORE
    report_dir: str | None = None  # write each identification campaign's report here
    procedures: tuple[str, ...] | None = None  # allowed from the ground station (None: all)
    procedure: str = "quick"
    thrusts: tuple[float, ...] | None = None
    yes: bool = False  # put the vehicle back after an interrupted procedure without asking (a service)
    schedule_gains: bool = True
    schedules: tuple[str, ...] | None = None
    scheduling_min_interval_s: float | None = None
    scheduling_hysteresis: float | None = None
    health: bool = True
    health_window_s: float | None = None
    health_tolerance: float | None = None
    health_threshold: float | None = None
    learn: bool = False  # tune during ordinary missions (the operator's opt-in)
    http: str | None = None  # HOST:PORT of the status page (None: no page)
    http_allow_remote: bool = False
    log_level: str | None = None
    log_format: str | None = None
    max_vehicle_time: float | None = None

    def __post_init__(self) -> None:
        require_choice(self, "procedure", ("quick", "thesis"))
        if self.thrusts is not None:
            check_thrust_levels(self.thrusts, "RunSettings.thrusts")
        for name in ("rudder_full_scale", "rudder_rate", "scheduling_min_interval_s", "scheduling_hysteresis",
                     "health_window_s", "health_tolerance", "health_threshold", "max_vehicle_time"):
            value = getattr(self, name)
            if value is not None and not (is_number(value) and value > 0):
                raise ValueError(f"RunSettings.{name} must be a finite number > 0, not {value!r}")
        if self.http is not None:
            split_listen(self.http)
        if self.log_level is not None:
            require_choice(self, "log_level", LOG_LEVELS)
        if self.log_format is not None:
            require_choice(self, "log_format", LOG_FORMATS)
        if not self.store:
            raise ValueError("RunSettings.store: the store path is empty")

    @property
    def http_address(self) -> tuple[str, int] | None:
        return None if self.http is None else split_listen(self.http)

    @property
    def log_level_number(self) -> int | None:
        return None if self.log_level is None else getattr(logging, self.log_level.upper())

    def serve_config(self):
        """The resident loop's configuration (``companion.procedures.resident.ServeConfig``)."""
        from behaviors.gain_scheduling import SchedulingConfig
        from companion.numerics.drift import DriftConfig
        from companion.procedures.campaign import CampaignConfig
        from companion.procedures.min_speed import MinSpeedProcedureConfig
        from companion.procedures.resident import ServeConfig

        campaign = CampaignConfig(user_set=("thrusts",) if self.thrusts else ())
        if self.thrusts:
            campaign = replace(campaign, thrusts=self.thrusts)
        campaign = campaign.for_procedure(self.procedure)
        scheduling = SchedulingConfig()
        if self.scheduling_min_interval_s is not None:
            scheduling = replace(scheduling, min_interval_s=self.scheduling_min_interval_s)
        if self.scheduling_hysteresis is not None:
            scheduling = replace(scheduling, relative_hysteresis=self.scheduling_hysteresis)
        drift = DriftConfig()
        for name, field_name in (("health_window_s", "window_s"), ("health_tolerance", "tolerance"),
                                 ("health_threshold", "threshold")):
            if getattr(self, name) is not None:
                drift = replace(drift, **{field_name: getattr(self, name)})
        extra: dict[str, Any] = {}
        if self.procedures is not None:
            extra["procedures"] = self.procedures
        if self.schedules is not None:
            extra["schedules"] = self.schedules
        return ServeConfig(schedule_gains=self.schedule_gains, preset=self.preset, max_vehicle_s=self.max_vehicle_time,
                           health=self.health, learn=self.learn, campaign=campaign, min_speed=MinSpeedProcedureConfig.levelled(),
                           scheduling=scheduling, drift=drift, **extra)


def merge(from_file: Mapping[str, Any], from_flags: Mapping[str, Any], defaults: Mapping[str, Any] = {}) -> RunSettings:
    """The settings: ``defaults`` (e.g. ``$COMPANION_STORE``), then the file, then the flags that
    were given (not None); keys that are no setting are ignored. ValueError for a bad combination."""
    known = {f.name for f in fields(RunSettings)}
    values = {k: v for k, v in defaults.items() if k in known and v is not None}
    values.update({k: v for k, v in from_file.items() if k in known})
    values.update({k: v for k, v in from_flags.items() if k in known and v is not None})
    return RunSettings(**values)
