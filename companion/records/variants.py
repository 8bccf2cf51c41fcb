"""Vehicle variants: a shipped simulator preset with some parameters scaled, written as a preset file.

A parameter sweep varies the vehicle as well as the sea: ±10 % mass, ±20 % rudder
effectiveness, another trim, noisier sensors. A variant is the base preset's JSON (read as data,
never imported: the companion does not import the simulator, SPEC §5) with named groups of fields
multiplied by factors, written to a file that ``python -m sim run --preset FILE.json`` and
``python -m sim linearize --preset FILE.json`` read like a shipped preset. So the simulator stays
independent of the companion, and the truth a rehearsal scores against is the variant's own.

Named perturbations (a factor multiplies every field of the group):

* ``mass``: the dive plane's inertia (``mass``, ``mass_surge``, ``mass_heave``, ``inertia_pitch``)
  together with ``weight`` and ``buoyancy``: a heavier or lighter vehicle re-ballasted as before
  (the yaw model is parametric and does not depend on mass);
* ``b2``: rudder effectiveness (``yaw.b2_constant``, ``yaw.b2_per_speed_squared``);
* ``a22``: yaw damping (``yaw.a22_constant``, ``yaw.a22_per_speed``);
* ``trim``: the rudder trim offset δ0 (``yaw.rudder_offset``);
* ``elevator``: elevator effectiveness (``dive_plane.lift_elevator``);
* ``drag``: the body's drag coefficient (``dive_plane.drag_coefficient``);
* ``thrust``: the thruster map (``thruster.quadratic``, ``linear``, ``constant``; the dead zone stays);
* ``SECTION.FIELD``: any one numeric field of the preset (e.g. ``roll.damping_linear``).

The sensor-noise level is a separate factor on every σ of the ``sensors`` section.
"""
from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path

from companion.errors import UserError

#: named perturbations: the ``section.field`` entries one factor multiplies
PERTURBATIONS: dict[str, tuple[str, ...]] = {
    "mass": ("dive_plane.mass", "dive_plane.mass_surge", "dive_plane.mass_heave", "dive_plane.inertia_pitch",
             "dive_plane.weight", "dive_plane.buoyancy"),
    "b2": ("yaw.b2_constant", "yaw.b2_per_speed_squared"),
    "a22": ("yaw.a22_constant", "yaw.a22_per_speed"),
    "trim": ("yaw.rudder_offset",),
    "elevator": ("dive_plane.lift_elevator",),
    "drag": ("dive_plane.drag_coefficient",),
    "thrust": ("thruster.quadratic", "thruster.linear", "thruster.constant"),
}

#: the preset sections a ``SECTION.FIELD`` perturbation may name (the simulator's preset form)
SECTIONS = ("thruster", "dive_plane", "yaw", "sway", "roll", "actuators", "autopilot", "sensors")


class VariantError(UserError, ValueError):
    """A perturbation or base preset that cannot make a variant; the message says which."""


def check_perturbation(name: str, factor: float) -> None:
    """Refuse an unknown perturbation name or a factor that is not a finite number > 0."""
    if name not in PERTURBATIONS:
        section, _, field = name.partition(".")
        if section not in SECTIONS or not field:
            raise VariantError(f"unknown perturbation {name!r}: use {', '.join(PERTURBATIONS)} or SECTION.FIELD "
                               f"with a section of {', '.join(SECTIONS)}")
    if isinstance(factor, bool) or not isinstance(factor, (int, float)) or not math.isfinite(factor) or factor <= 0:
        raise VariantError(f"perturbation {name}: the factor must be a finite number > 0, not {factor!r}")


def derive_preset(base: Mapping, perturb: Mapping[str, float], noise: float = 1.0) -> dict:
    """The preset dictionary ``base`` with each perturbation's fields multiplied by its factor and
    every sensor σ by ``noise``; its ``name`` and ``description`` say what was changed."""
    if not (isinstance(noise, (int, float)) and math.isfinite(noise) and noise >= 0):
        raise VariantError(f"the noise factor must be a finite number >= 0, not {noise!r}")
    data = json.loads(json.dumps(base))  # a deep copy of plain JSON
    for name, factor in sorted(perturb.items()):
        check_perturbation(name, factor)
        for target in PERTURBATIONS.get(name, (name,)):
            section, field = target.split(".", 1)
            values = data.get(section)
            if not isinstance(values, dict) or not isinstance(values.get(field), (int, float)) \
                    or isinstance(values.get(field), bool):
                raise VariantError(f"perturbation {name}: the preset {base.get('name')!r} has no numeric {target}")
            values[field] = values[field] * factor
    if noise != 1.0:
        sensors = data.get("sensors")
        if not isinstance(sensors, dict):
            raise VariantError(f"the preset {base.get('name')!r} has no sensors section to scale")
        for field, value in sensors.items():
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                sensors[field] = value * noise
    changes = [f"{name}×{factor:g}" for name, factor in sorted(perturb.items())]
    if noise != 1.0:
        changes.append(f"noise×{noise:g}")
    if changes:
        data["name"] = f"{base.get('name')}[{','.join(changes)}]"
        data["description"] = f"{base.get('description', '')} Variant: {', '.join(changes)}.".strip()
    return data


def write_variant(preset: str, perturb: Mapping[str, float], noise: float, path: Path) -> Path:
    """Write the variant of the shipped ``preset`` to ``path`` (a preset file the simulator reads with
    ``--preset PATH``); returns its absolute path."""
    from companion.records.vehicle_files import preset_path

    try:
        base = json.loads(preset_path(preset).read_text(encoding="utf-8"))
    except FileNotFoundError as exc:
        raise VariantError(str(exc)) from None
    except (OSError, ValueError) as exc:
        raise VariantError(f"cannot read the preset {preset!r}: {exc}") from None
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(derive_preset(base, perturb, noise), indent=1), encoding="utf-8")
    return path.resolve()
