"""``companion design --autopilot NAME``: the campaign's designer for one model at one speed (eq. D.1).

The autopilot's profile gives its heading controller (eq. A.1, A.2, A.4 or A.5), parameter names, full
scale, gain ranges and the gains and limits a vehicle has as shipped (``shipped_gains``), which
``--original NAME=VALUE,...`` (native names) replaces one by one. The design is
``companion.procedures.heading_design``'s, on one case: the model given, at the speed given. Every
candidate's predicted ±20° and ±40° steps are printed (overshoot, time to within 5 %, step error).
``--skid-throttle T`` (ArduRover with twin thrusters): the steps go through the skid mixer, the thrust
the steering leaves and the speed it costs (eq. A.2k), as a campaign on such a boat predicts them; ``--forward-thrust F``
(PX4's UUV): the yaw torque is allocated beside that surge thrust (eq. A.5a).
"""
from __future__ import annotations

import math
import sys
from dataclasses import replace

from companion.cli.commands._common import print_json
from companion.link.autopilots import registered_profiles
from companion.link.profile import AutopilotProfile
from companion.numerics.cascade_gains import CascadeRules
from companion.numerics.gains import CAMPAIGN_DAMPING, GainBounds
from companion.numerics.identification import YawModel
from companion.numerics.skid_step import SkidMixer
from companion.numerics.step_design import DesignChoice, DesignObjective, StepCase, design_by_prediction
from companion.numerics.step_figures import StepFigures
from companion.numerics.step_response import predict_step
from companion.procedures.heading_design import family_for, step_case
from companion.procedures.verified_design import CONTROLLERS, HeadingLimits, skid_plant

#: the --autopilot choices: every registered autopilot by its profile's name, our simulator's as
#: "builtin" (as ``rehearse --autopilot`` names it)
ALIASES = {"sim": "builtin"}


def autopilot_profiles() -> dict[str, AutopilotProfile]:
    """The registered autopilots by their ``--autopilot`` name."""
    return {ALIASES.get(profile.name, profile.name): profile for profile in registered_profiles()}

class DesignInputError(ValueError):
    """An --original entry that cannot be used (one sentence)."""


def parse_original(text: str | None, params: dict[str, str]) -> dict[str, float]:
    """``NAME=VALUE,...`` in native names → neutral names; DesignInputError for an unknown name or a
    value that is not a finite number."""
    native_to_neutral = {native: neutral for neutral, native in params.items()}
    out: dict[str, float] = {}
    for item in (text or "").split(","):
        if not item.strip():
            continue
        name, _, value = item.partition("=")
        name = name.strip().upper()
        if name not in native_to_neutral:
            raise DesignInputError(f"--original: {name!r} is not a heading parameter of this autopilot "
                                   f"(known: {', '.join(sorted(native_to_neutral))})")
        try:
            number = float(value)
        except ValueError:
            raise DesignInputError(f"--original: {name}={value!r} is not a number") from None
        if not math.isfinite(number):
            raise DesignInputError(f"--original: {name} must be finite")
        out[native_to_neutral[name]] = number
    return out


def run_for_autopilot(args, model: YawModel) -> int:
    """The design for ``args.autopilot`` on ``model`` (validated from the flags by ``companion design``)."""
    profile = autopilot_profiles()[args.autopilot]
    kind_name = profile.heading_schedule
    if kind_name not in CONTROLLERS:
        print(f"companion design: error: {args.autopilot}'s heading controller ({kind_name}) has no step model, "
              "so no design by prediction is possible for it; use no --autopilot for the thesis PI rule",
              file=sys.stderr)
        return 2
    if args.speed is None:
        print("companion design: error: --autopilot needs --speed (the output's speed scaling and the speed "
              "the gains are for)", file=sys.stderr)
        return 2
    params = profile.params
    shipped = {neutral: profile.shipped_gains.get(native) for neutral, native in params.items()}
    found = {k: v for k, v in shipped.items() if v is not None}
    try:
        found.update(parse_original(args.original, params))
    except DesignInputError as exc:
        print(f"companion design: error: {exc}", file=sys.stderr)
        return 2
    controller = CONTROLLERS[kind_name]
    skid_throttle = args.skid_throttle
    if skid_throttle is not None and not (controller == "cascade" and "steering_scale_speed" in params):
        print(f"companion design: error: --skid-throttle is for ArduRover's twin-thruster boats, not {args.autopilot}",
              file=sys.stderr)
        return 2
    forward = args.forward_thrust
    if forward is not None and controller != "px4_uuv":
        print(f"companion design: error: --forward-thrust is for PX4's UUV, not {args.autopilot}", file=sys.stderr)
        return 2
    if forward is not None and not 0.0 <= forward <= 1.0:
        print(f"companion design: error: --forward-thrust must be in [0, 1], not {forward:g}", file=sys.stderr)
        return 2
    if skid_throttle is not None and not 0.0 < skid_throttle <= 1.0:
        print(f"companion design: error: --skid-throttle must be in (0, 1], not {skid_throttle:g}", file=sys.stderr)
        return 2
    scaled = controller == "cascade" and "steering_scale_speed" in params and skid_throttle is None
    base = args.scale_base if args.scale_base is not None else found.get("steering_scale_speed") if scaled else None
    base = base if base and base > 0 and skid_throttle is None else None
    rules = CascadeRules(full_scale=profile.angle_full_scale_rad, output_scale_base=base, **profile.gain_ranges)
    bounds = GainBounds(damping=CAMPAIGN_DAMPING)
    if controller == "pi":
        found.setdefault("rudder_max", args.delta_max)
    limits = HeadingLimits.from_vehicle(found, full_scale=profile.angle_full_scale_rad,
                                        rudder_rate=profile.actuator_rate_rad_s, output_scale_base=base)
    if forward is not None and args.speed is not None:  # eq. A.5a: the torque allocated beside it
        limits = replace(limits, forward_thrust=((args.speed, forward),))
    if skid_throttle is not None:  # eq. A.2k: one steady level known, b2 ∝ u (a skid pair's law, eq. S.3)
        skid = skid_plant(SkidMixer(), [(skid_throttle, args.speed)], None, [args.speed], [model.a22], [model.b2],
                          "u", found)
        if skid is None:
            print("companion design: error: no skid drive can be made of --skid-throttle and --speed", file=sys.stderr)
            return 2
        limits = replace(limits, skid=skid)
    objective = DesignObjective()
    if profile.prediction_margin_pct is not None:
        objective = replace(objective, margin_pct=profile.prediction_margin_pct)
    kind_parameters = module_heading_parameters(kind_name)
    original = {k: v for k, v in found.items() if k in kind_parameters}
    try:
        case = step_case(controller, model, args.speed, limits)
        choice = design_by_prediction(family_for(controller, rules, bounds), [case], [model], objective,
                                      original=original)
    except ValueError as exc:
        print(f"companion design: error: {exc}", file=sys.stderr)
        return 2
    chosen = choice.chosen.gains[0]
    native = {params.get(k, k): v for k, v in chosen.items()}
    steps = predicted_steps(choice, case, objective)
    result = {"autopilot": args.autopilot, "controller": controller, "speed": args.speed,
              "skid_throttle": skid_throttle, "forward_thrust": forward,
              "chosen": choice.chosen.name, "parameters": native, **{"design": choice.to_dict()},
              "predicted_steps": {name: [step_row(size_deg, figures) for size_deg, figures in rows]
                                  for name, rows in steps.items()}}
    if args.json:
        print_json(result)
        return 0
    through = f", through the skid mixer at throttle {skid_throttle:g} (eq. A.2k)" if skid_throttle is not None else \
        f", the yaw allocated beside a surge thrust of {forward:g} (eq. A.5a)" if forward is not None else ""
    print(f"{args.autopilot}: {controller} heading controller at {args.speed:g} m/s{through}; "
          f"design target: overshoot ≤ {choice.target_overshoot_pct:.1f} % on ±20° and ±40° steps")
    print(f"chosen: {choice.chosen.name}" + (" (the vehicle's own gains: nothing better is predicted)"
                                            if choice.keeps_original else ""))
    for name, value in native.items():
        print(f"  {name:<18} {value:10.4f}")
    print("candidate      step error s  worst overshoot %  feasible")
    for candidate in choice.candidates:
        score = candidate.score
        print(f"  {candidate.name:<12} {score.iae_s:12.2f}  {score.worst_overshoot_pct:17.1f}  "
              f"{'yes' if score.feasible else 'no'}")
    print("predicted step  candidate     overshoot %  time to 5 % s  step error s")
    for name, rows in steps.items():
        for size_deg, figures in rows:
            settle = figures.settling_time_s
            print(f"  ±{size_deg:<4.0f}         {name:<12} {figures.overshoot_pct:11.1f}  "
                  f"{settle if math.isfinite(settle) else math.nan:13.2f}  {figures.iae_s:12.2f}")
    return 0


def step_row(size_deg: float, figures: StepFigures) -> dict:
    """One predicted step as ``--json`` prints it: ``step_deg``, ``overshoot_pct``, ``settling_time_s``,
    ``iae_s`` (NaN as the JSON printer writes it: null)."""
    return {"step_deg": size_deg, "overshoot_pct": figures.overshoot_pct,
            "settling_time_s": figures.settling_time_s, "iae_s": figures.iae_s}


def predicted_steps(choice: DesignChoice, case: StepCase,
                    objective: DesignObjective) -> dict[str, list[tuple[float, StepFigures]]]:
    """Each candidate's predicted step of every size of ``objective`` on ``case`` (eq. A.1–A.5), by
    candidate: the size (degrees) and the step's figures (overshoot, time to within 5 % for good,
    ``settling_time_s``, NaN if never, and step error); all NaN for gains the autopilot refuses."""
    out: dict[str, list[tuple[float, StepFigures]]] = {}
    for candidate in choice.candidates:
        rows = []
        for size in objective.step_sizes_rad:
            try:
                figures = predict_step(case.plant, case.controller, dict(candidate.gains[0]), size,
                                       objective.duration_s, dt=objective.dt, skid=case.skid, **case.limits).figures
            except ValueError:  # gains the autopilot refuses to fly (PX4 without a wheel base)
                figures = StepFigures.unmeasured()
            rows.append((math.degrees(size), figures))
        out[candidate.name] = rows
    return out


def module_heading_parameters(kind_name: str) -> tuple[str, ...]:
    """The neutral parameters the heading schedule ``kind_name`` writes."""
    from behaviors.schedules import schedule_kind

    return schedule_kind(kind_name).parameters
