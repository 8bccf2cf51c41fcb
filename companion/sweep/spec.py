"""What a sweep varies, and the cases it expands into.

A :class:`SweepSpec` comes from a small JSON or YAML file (``companion sweep --spec FILE``) and/or
flags; every axis is a list and the cases are their cross product, in a fixed order::

    {
      "name": "currents-and-seeds",
      "presets": ["starfish"],
      "seeds": "1..8",                                  # or [1, 2, 3], or {"from": 1, "to": 8}
      "currents": [[0, 0], [0.05, -0.02]],               # or {"north": [...], "east": [...]},
                                                         # or {"speed": [...], "direction_deg": [...]}
      "noise": [1, 2],                                   # factor on every sensor σ
      "perturb": {"mass": "±10%", "b2": [0.8, 1.2]},     # factors (companion.records.variants)
      "thrusts": [[0.6, 0.8, 1.0]],                      # one or several thrust lists
      "axes": ["yaw"], "steps": true, "behaviors": ["roll", "min_speed"],
      "steady_state": false, "schedules": ["heading"], "thesis_estimator": false, "quick": false,
      "speedup": 50, "timeout_s": 1800
    }

Number lists may be written as a list, one number, a string ``"1,2,3"``, a range ``"lo:hi:n"`` (n
values from lo to hi inclusive) or ``{"from": lo, "to": hi, "steps": n}`` (or ``"step": s``); seeds
also as ``"1..8"``; factors also as ``"±10%"`` (0.9, 1.0, 1.1). A :class:`Case` is fully resolved
(the preset's defaults written out: current, behaviours, steady state, thrusts), so its key — the
SHA-256 of its inputs — names exactly what runs, and :meth:`Case.command` is the ``companion
rehearse`` command that reproduces it alone. The speed-up is not an input: a rehearsal on the
built-in simulator gives the same numbers at any speed-up (lockstep, README "Same seed, same
numbers"). An option added after the first sweeps (``quick``) enters the inputs only when set, so
the keys of cases recorded before it stay valid; for the same reason a case without ``quick`` runs
the thesis procedure (``--procedure thesis``), although ``companion rehearse`` alone defaults to the
quick one.
"""
from __future__ import annotations

import hashlib
import itertools
import json
import math
import re
import shlex
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

from companion.errors import UserError
from companion.procedures.registry import rehearsal_behaviors

AXES = ("yaw", "pitch")


class SpecError(UserError, ValueError):
    """A sweep specification that cannot be used; the message names the field and the problem."""


# --------------------------------------------------------------------------------------------- values
def _number(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, str)):
        raise SpecError(f"{what}: expected a number, not {value!r}")
    try:
        number = float(value)
    except ValueError:
        raise SpecError(f"{what}: expected a number, not {value!r}") from None
    if not math.isfinite(number):
        raise SpecError(f"{what}: expected a finite number, not {value!r}")
    return number


def _linspace(lo: float, hi: float, steps: int, what: str) -> tuple[float, ...]:
    if steps < 1:
        raise SpecError(f"{what}: a range needs at least 1 step, not {steps}")
    if steps == 1:
        return (lo,)
    return tuple(round(lo + (hi - lo) * i / (steps - 1), 12) for i in range(steps))


def _range(value: Mapping, what: str) -> tuple[float, ...]:
    unknown = set(value) - {"from", "to", "steps", "step"}
    if unknown or "from" not in value or "to" not in value or ("steps" in value) == ("step" in value):
        raise SpecError(f"{what}: a range is {{\"from\": LO, \"to\": HI, \"steps\": N}} or "
                        f"{{\"from\": LO, \"to\": HI, \"step\": S}}, not {dict(value)!r}")
    lo, hi = _number(value["from"], what), _number(value["to"], what)
    if "steps" in value:
        steps = _number(value["steps"], what)
        if steps != int(steps):
            raise SpecError(f"{what}: steps must be a whole number, not {value['steps']!r}")
        return _linspace(lo, hi, int(steps), what)
    step = _number(value["step"], what)
    if step <= 0 or hi < lo:
        raise SpecError(f"{what}: a stepped range needs from <= to and step > 0")
    count = math.floor((hi - lo) / step + 1e-9) + 1
    if count > 100_000:
        raise SpecError(f"{what}: the range has {count} values")
    return tuple(round(lo + i * step, 12) for i in range(count))


_PLUS_MINUS = re.compile(r"^\s*(?:±|\+-|\+/-)\s*([0-9.]+)\s*%\s*$")


def number_list(value: Any, what: str, factors: bool = False) -> tuple[float, ...]:
    """A list of finite numbers from any of the forms of the module docstring."""
    if isinstance(value, Mapping):
        out = _range(value, what)
    elif isinstance(value, str):
        text = value.strip()
        match = _PLUS_MINUS.match(text) if factors else None
        if match:
            pct = _number(match.group(1), what) / 100.0
            out = (round(1.0 - pct, 12), 1.0, round(1.0 + pct, 12))
        elif text.count(":") == 2:
            lo, hi, steps = text.split(":")
            out = _range({"from": lo, "to": hi, "steps": steps}, what)
        else:
            out = tuple(_number(part, what) for part in text.split(",") if part.strip())
    elif isinstance(value, Sequence):
        out = tuple(_number(v, what) for v in value)
    else:
        out = (_number(value, what),)
    if not out:
        raise SpecError(f"{what}: the list is empty")
    return out


def seed_list(value: Any) -> tuple[int, ...]:
    """Seeds: whole numbers >= 0, as a list, one number, ``"1..8"``/``"1-8"``, ``"1,2,5"`` or a range."""
    if isinstance(value, str):
        match = re.match(r"^\s*(\d+)\s*(?:\.\.|-)\s*(\d+)\s*$", value)
        if match:
            lo, hi = int(match.group(1)), int(match.group(2))
            if hi < lo:
                raise SpecError(f"seeds: {value!r} runs backwards")
            value = list(range(lo, hi + 1))
    numbers = number_list(value, "seeds")
    if any(n != int(n) or n < 0 for n in numbers):
        raise SpecError(f"seeds must be whole numbers >= 0, not {value!r}")
    return tuple(int(n) for n in numbers)


def current_list(value: Any) -> tuple[tuple[float, float], ...]:
    """Currents (north, east in m/s): pairs ``[[vn, ve], ...]`` or ``"vn,ve;vn,ve"``, the cross product
    ``{"north": [...], "east": [...]}``, or polar ``{"speed": [...], "direction_deg": [...]}`` (the
    direction the water flows towards, from north, clockwise)."""
    if isinstance(value, Mapping):
        keys = set(value)
        if keys == {"north", "east"}:
            return tuple(itertools.product(number_list(value["north"], "currents.north"),
                                           number_list(value["east"], "currents.east")))
        if keys == {"speed", "direction_deg"}:
            out = []
            for speed, direction in itertools.product(number_list(value["speed"], "currents.speed"),
                                                      number_list(value["direction_deg"], "currents.direction_deg")):
                angle = math.radians(direction)
                out.append((round(speed * math.cos(angle), 12) + 0.0, round(speed * math.sin(angle), 12) + 0.0))
            return tuple(out)
        raise SpecError("currents: a mapping takes north and east, or speed and direction_deg")
    if isinstance(value, str):
        value = [pair.split(",") for pair in value.split(";") if pair.strip()]
    if not isinstance(value, Sequence) or not value:
        raise SpecError(f"currents: expected a list of [north, east] pairs, not {value!r}")
    out = []
    for pair in value:
        if isinstance(pair, str) or not isinstance(pair, Sequence) or len(pair) != 2:
            raise SpecError(f"currents: each current is [north, east] in m/s, not {pair!r}")
        out.append((_number(pair[0], "currents"), _number(pair[1], "currents")))
    return tuple(out)


def thrust_sets(value: Any) -> tuple[tuple[float, ...], ...]:
    """Thrust lists: ``[0.6, 0.8]`` (one list), ``[[0.6], [0.8, 1.0]]`` (several), ``"0.6,0.8;1.0"``;
    percent (> 1) is divided by 100; each thrust in (0, 1]."""
    if isinstance(value, str):
        groups: list = [number_list(part, "thrusts") for part in value.split(";") if part.strip()]
    elif isinstance(value, Sequence) and value and all(isinstance(v, Sequence) and not isinstance(v, str)
                                                      for v in value):
        groups = [number_list(v, "thrusts") for v in value]
    else:
        groups = [number_list(value, "thrusts")]
    out = []
    for group in groups:
        thrusts = tuple(t / 100.0 if t > 1.0 else t for t in group)
        if not thrusts or any(not 0.0 < t <= 1.0 for t in thrusts):
            raise SpecError(f"thrusts must be in (0, 1] (or percent), not {list(group)!r}")
        out.append(thrusts)
    if not out:
        raise SpecError("thrusts: the list is empty")
    return tuple(out)


def perturbation_axes(value: Any) -> tuple[tuple[str, tuple[float, ...]], ...]:
    """``{"mass": "±10%", "b2": [0.8, 1.2]}`` (or ``"mass=0.9,1.1 b2=0.8"`` strings) → sorted
    ``(name, factors)`` pairs; names and factors are checked."""
    from companion.records.variants import VariantError, check_perturbation

    if isinstance(value, str):
        value = perturbation_strings([value])
    if not isinstance(value, Mapping):
        raise SpecError(f"perturb: expected {{NAME: FACTORS}}, not {value!r}")
    out = []
    for name, factors in sorted(value.items()):
        values = number_list(factors, f"perturb.{name}", factors=True)
        for factor in values:
            try:
                check_perturbation(str(name), factor)
            except VariantError as exc:
                raise SpecError(str(exc)) from None
        out.append((str(name), values))
    return tuple(out)


def perturbation_strings(items: Sequence[str]) -> dict[str, str]:
    """``["mass=0.9,1.1", "b2=±20%"]`` (the ``--perturb`` flags) → ``{"mass": "0.9,1.1", "b2": "±20%"}``."""
    out: dict[str, str] = {}
    for item in items:
        for part in item.split() if " " in item.strip() else [item]:
            name, sep, factors = part.partition("=")
            if not sep or not name.strip() or not factors.strip():
                raise SpecError(f"perturb: expected NAME=FACTORS (e.g. mass=0.9,1.1 or b2=±20%), not {part!r}")
            out[name.strip()] = factors.strip()
    return out


def _names(value: Any, what: str, allowed: Sequence[str] | None = None, none_ok: bool = False,
           dashed: bool = False) -> tuple[str, ...]:
    """A list of names (a comma-separated string or a list) among ``allowed``; ``dashed``: a name may
    be written with dashes (``min-speed``) for its underscores."""
    if isinstance(value, str):
        value = [v for v in value.split(",") if v.strip()]
        if none_ok and [v.strip() for v in value] == ["none"]:
            value = []
    if not isinstance(value, Sequence) or not all(isinstance(v, str) for v in value):
        raise SpecError(f"{what}: expected a list of names, not {value!r}")
    names = tuple(v.strip().replace("-", "_") if dashed else v.strip() for v in value)
    if allowed is not None:
        unknown = [n for n in names if n not in allowed]
        if unknown:
            raise SpecError(f"{what}: unknown {', '.join(unknown)}; use {', '.join(allowed)}"
                            + (" or none" if none_ok else ""))
    if not names and not none_ok:
        raise SpecError(f"{what}: the list is empty")
    return names


def _flag(value: Any, what: str) -> bool:
    if not isinstance(value, bool):
        raise SpecError(f"{what}: expected true or false, not {value!r}")
    return value


# --------------------------------------------------------------------------------------------- cases
def _number_text(value: float) -> str:
    """The shortest text that reads back as the same float (``repr``), integers without ``.0``."""
    return str(int(value)) if float(value).is_integer() and abs(value) < 1e15 else repr(float(value))


@dataclass(frozen=True)
class Case:
    """One rehearsal of a sweep, every input written out (nothing left to a default that could change)."""

    preset: str
    seed: int
    current: tuple[float, float]
    thrusts: tuple[float, ...]
    noise: float = 1.0
    perturb: tuple[tuple[str, float], ...] = ()
    axes: tuple[str, ...] = AXES
    steps: bool = True
    behaviors: tuple[str, ...] = field(default_factory=rehearsal_behaviors)
    steady_state: bool = False
    schedules: tuple[str, ...] = ("heading",)
    thesis_estimator: bool = False
    quick: bool = False  # the quick procedure (rehearse --procedure quick); False: --procedure thesis

    def inputs(self) -> dict:
        """The case's inputs as plain JSON (the columns of its row, and what its key hashes)."""
        out = {"preset": self.preset, "seed": self.seed, "current_north": self.current[0],
               "current_east": self.current[1], "thrusts": list(self.thrusts), "noise": self.noise,
               "perturb": dict(self.perturb), "axes": list(self.axes), "steps": self.steps,
               "behaviors": list(self.behaviors), "steady_state": self.steady_state,
               "schedules": list(self.schedules), "thesis_estimator": self.thesis_estimator}
        if self.quick:
            out["quick"] = True
        return out

    @property
    def key(self) -> str:
        """SHA-256 (hex) of the inputs: the same case has the same key in any sweep (resume)."""
        text = json.dumps(self.inputs(), sort_keys=True, separators=(",", ":"))
        return hashlib.sha256(text.encode()).hexdigest()

    def rehearse_args(self) -> list[str]:
        """The ``companion rehearse`` options that run exactly this case."""
        args = ["--preset", self.preset, "--seed", str(self.seed),
                "--current", f"{_number_text(self.current[0])},{_number_text(self.current[1])}",
                "--thrusts", ",".join(_number_text(t) for t in self.thrusts),
                "--axes", ",".join(self.axes), "--behaviors", ",".join(b.replace("_", "-") for b in self.behaviors) or "none",
                "--steady-state" if self.steady_state else "--no-steady-state",
                "--schedules", ",".join(self.schedules)]
        if not self.steps:
            args.append("--no-steps")
        if self.thesis_estimator:
            args.append("--thesis-estimator")
        args += ["--procedure", "quick" if self.quick else "thesis"]  # a sweep's default stays the thesis' (keys)
        if self.perturb:
            args += ["--perturb", ",".join(f"{name}={_number_text(factor)}" for name, factor in self.perturb)]
        if self.noise != 1.0:
            args += ["--noise", _number_text(self.noise)]
        return args

    def command(self, speedup: float | None = None) -> str:
        """The shell command that reproduces this case alone."""
        extra = ["--speedup", _number_text(speedup)] if speedup is not None else []
        return shlex.join(["companion", "rehearse", *self.rehearse_args(), *extra])


@dataclass(frozen=True)
class SweepSpec:
    """The axes of a sweep (module docstring); :meth:`cases` is their cross product.

    ``currents``/``behaviors``/``steady_state`` of None take each preset's defaults (as ``companion
    rehearse`` does); ``thrusts`` entries of None the campaign's default thrusts."""

    name: str = "sweep"
    presets: tuple[str, ...] = ("starfish",)
    seeds: tuple[int, ...] = (1,)
    currents: tuple[tuple[float, float], ...] | None = None
    noise: tuple[float, ...] = (1.0,)
    perturb: tuple[tuple[str, tuple[float, ...]], ...] = ()
    thrusts: tuple[tuple[float, ...] | None, ...] = (None,)
    axes: tuple[str, ...] = AXES
    steps: bool = True
    behaviors: tuple[str, ...] | None = None
    steady_state: bool | None = None
    schedules: tuple[str, ...] = ("heading",)
    thesis_estimator: bool = False
    quick: bool = False
    speedup: float = 50.0
    timeout_s: float = 1800.0

    def cases(self) -> list[Case]:
        """Every case, in a fixed order (presets, seeds, currents, noise, perturbations, thrust lists)."""
        from companion.rehearsal.rehearsal import preset_defaults
        from companion.procedures.campaign import CampaignConfig

        default_thrusts = tuple(CampaignConfig().thrusts)
        names = [name for name, _ in self.perturb]
        combos = list(itertools.product(*(factors for _, factors in self.perturb))) or [()]
        out = []
        for preset in self.presets:
            try:
                defaults = preset_defaults(preset)
            except ValueError as exc:
                raise SpecError(f"presets: {exc}") from None
            currents = self.currents if self.currents is not None else (tuple(defaults["current"]),)
            for seed, current, noise, combo, thrusts in itertools.product(self.seeds, currents, self.noise, combos,
                                                                          self.thrusts):
                perturb = tuple((name, factor) for name, factor in zip(names, combo) if factor != 1.0)
                out.append(Case(
                    preset=preset, seed=seed, current=(float(current[0]), float(current[1])),
                    thrusts=tuple(thrusts) if thrusts else default_thrusts, noise=float(noise), perturb=perturb,
                    axes=self.axes, steps=self.steps,
                    behaviors=tuple(defaults["behaviors"]) if self.behaviors is None else self.behaviors,
                    steady_state=bool(defaults["steady_state"]) if self.steady_state is None else self.steady_state,
                    schedules=self.schedules, thesis_estimator=self.thesis_estimator, quick=self.quick))
        unique = list(dict.fromkeys(out))  # e.g. factor 1.0 listed under two names: one case
        return unique

    def as_json(self) -> dict:
        """The spec as plain JSON (what ``--dry-run --json`` shows; readable back by :func:`spec_from_dict`)."""
        out: dict = {}
        for item in fields(self):
            value = getattr(self, item.name)
            if item.name == "perturb":
                value = {name: list(factors) for name, factors in value}
            elif item.name in ("thrusts", "currents") and value is not None:
                value = [list(v) if v is not None else None for v in value]
            elif isinstance(value, tuple):
                value = list(value)
            out[item.name] = value
        if all(t is None for t in out["thrusts"]):
            del out["thrusts"]
        return {k: v for k, v in out.items() if v is not None}


#: spec fields and how each is read
_READERS = {
    "name": lambda v: _name(v),
    "presets": lambda v: _names(v, "presets"),
    "seeds": seed_list,
    "currents": current_list,
    "noise": lambda v: _noise(v),
    "perturb": perturbation_axes,
    "thrusts": thrust_sets,
    "axes": lambda v: _names(v, "axes", AXES),
    "steps": lambda v: _flag(v, "steps"),
    "behaviors": lambda v: _names(v, "behaviors", rehearsal_behaviors(), none_ok=True, dashed=True),
    "steady_state": lambda v: _flag(v, "steady_state"),
    "schedules": lambda v: _schedules(v),
    "thesis_estimator": lambda v: _flag(v, "thesis_estimator"),
    "quick": lambda v: _flag(v, "quick"),
    "speedup": lambda v: _positive(v, "speedup"),
    "timeout_s": lambda v: _positive(v, "timeout_s"),
}
#: accepted spellings of the fields (singular forms, the command line's)
_ALIASES = {"preset": "presets", "seed": "seeds", "current": "currents", "thrust": "thrusts",
            "perturbations": "perturb", "timeout": "timeout_s", "steady-state": "steady_state",
            "thesis-estimator": "thesis_estimator"}


def _name(value: Any) -> str:
    if not isinstance(value, str) or not re.match(r"^[A-Za-z0-9_.-]{1,80}$", value):
        raise SpecError(f"name: letters, digits, '.', '_' or '-' (1-80), not {value!r}")
    return value


def _noise(value: Any) -> tuple[float, ...]:
    levels = number_list(value, "noise")
    if any(level < 0 for level in levels):
        raise SpecError(f"noise: factors must be >= 0, not {value!r}")
    return levels


def _positive(value: Any, what: str) -> float:
    number = _number(value, what)
    if number <= 0:
        raise SpecError(f"{what} must be > 0, not {value!r}")
    return number


def _schedules(value: Any) -> tuple[str, ...]:
    from behaviors.schedules import GAIN_SCHEDULES

    return _names(value, "schedules", tuple(GAIN_SCHEDULES))


def spec_from_dict(data: Mapping, base: SweepSpec | None = None) -> SweepSpec:
    """A spec from a mapping (a spec file's object, or the flags given); unknown fields are refused;
    fields absent keep ``base``'s values."""
    if not isinstance(data, Mapping):
        raise SpecError(f"a sweep specification is a JSON/YAML object, not {type(data).__name__}")
    values: dict = {}
    for key, value in data.items():
        name = _ALIASES.get(str(key), str(key))
        if name not in _READERS:
            raise SpecError(f"unknown field {key!r}; the fields are {', '.join(_READERS)}")
        if name in values:
            raise SpecError(f"field {name!r} given twice")
        if value is None and name in ("currents", "behaviors", "steady_state"):
            values[name] = None  # explicit null: the preset's defaults
            continue
        values[name] = _READERS[name](value)
        if name == "thrusts":
            values[name] = tuple(values[name])
    spec = SweepSpec(**{**(base.__dict__ if base else {}), **values})
    if "pitch" in spec.schedules and "pitch" not in spec.axes:
        raise SpecError("schedules: the pitch schedule needs the pitch axis identified (axes yaw,pitch)")
    return spec


def load_spec_file(path: str) -> dict:
    """The object of a ``.json``, ``.yaml`` or ``.yml`` spec file (SpecError with the reason)."""
    file = Path(path)
    try:
        text = file.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise SpecError(f"cannot read the sweep specification {path}: {getattr(exc, 'strerror', None) or exc}") \
            from None
    if file.suffix.lower() in (".yaml", ".yml"):
        import yaml  # a dependency of dask

        try:
            data = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise SpecError(f"{path} is not valid YAML: {str(exc).splitlines()[0]}") from None
    else:
        try:
            data = json.loads(text)
        except ValueError as exc:
            raise SpecError(f"{path} is not valid JSON: {exc}") from None
    if not isinstance(data, Mapping):
        raise SpecError(f"{path}: a sweep specification is an object of fields, not {type(data).__name__}")
    return dict(data)
