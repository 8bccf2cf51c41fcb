"""``companion design --autopilot NAME``: the campaign's designer for one model at one speed (eq. D.1).

The autopilot's profile gives its heading controller (eq. A.1, A.2, A.4 or A.5), parameter names, full
scale and gain ranges; :data:`SHIPPED_DEFAULTS` the gains and limits a vehicle has as shipped, which
``--original NAME=VALUE,...`` (native names) replaces one by one. The design is
``companion.procedures.heading_design``'s, on one case: the model given, at the speed given. Every
candidate's predicted ±20° and ±40° steps are printed (overshoot, time to within 5 %, step error).
"""
from __future__ import annotations

import math
import sys
from dataclasses import replace

from companion.cli.commands._common import print_json
from companion.link.autopilots import module_of
from companion.numerics.cascade_gains import CascadeRules
from companion.numerics.gains import CAMPAIGN_DAMPING, GainBounds
from companion.numerics.identification import YawModel
from companion.numerics.step_design import DesignChoice, DesignObjective, StepCase, design_by_prediction
from companion.numerics.step_response import predict_step
from companion.procedures.heading_design import family_for, step_case
from companion.procedures.verified_design import CONTROLLERS, HeadingLimits

#: the --autopilot choices and their modules under companion.link.autopilots
AUTOPILOT_MODULES = {"builtin": "sim", "ardurover": "ardurover", "ardusub": "ardusub",
                     "px4-rover": "px4_rover", "px4-uuv": "px4_uuv"}
AUTOPILOT_CHOICES = tuple(AUTOPILOT_MODULES)

#: heading gains and limits as each autopilot ships them (native names): our simulator's PROTOCOL.md
#: defaults; ArduPilot 4.7's AR_AttitudeControl (Rover) and AC_AttitudeControl_Sub parameter defaults;
#: PX4's generic Ackermann rover airframe (51000: ROMFS rc defaults, RO_YAW_RATE_TH from
#: rovercontrol_params.yaml) and uuv_att_control_params.yaml (the HippoCampus airframe sets none of them)
SHIPPED_DEFAULTS: dict[str, dict[str, float]] = {
    "px4-rover": {"RO_YAW_P": 3.0, "RO_YAW_RATE_P": 0.25, "RO_YAW_RATE_I": 0.01, "RA_WHEEL_BASE": 0.5,
                  "RO_YAW_RATE_CORR": 1.0, "RO_YAW_RATE_LIM": 130.0, "RO_YAW_ACCEL_LIM": 800.0,
                  "RA_STR_RATE_LIM": 360.0, "RA_MAX_STR_ANG": 0.5236, "RO_YAW_RATE_TH": 3.0},
    "px4-uuv": {"UUV_YAW_P": 4.0, "UUV_YAW_D": 2.0, "UUV_TORQUE_SAT": 0.3},
    "builtin": {"HDG_P": 1.0, "HDG_I": 0.05, "HDG_IMAX": 0.15, "HDG_TRIM": 0.0, "RUD_MAX": 0.35, "RUD_RATE": 0.5},
    "ardurover": {"ATC_STR_ANG_P": 2.0, "ATC_STR_RAT_P": 0.2, "ATC_STR_RAT_I": 0.2, "ATC_STR_RAT_FF": 0.2,
                  "ATC_STR_RAT_IMAX": 1.0, "ATC_STR_RAT_MAX": 120.0, "ATC_STR_ACC_MAX": 120.0,
                  "MOT_SPD_SCA_BASE": 1.0},
    # AC_AttitudeControl_Sub sets ANG_YAW_P 6 (AC_ATC_SUB_ANGLE_P) and ACCEL_Y_MAX 110000 cdeg/s²; the rest
    # are AC_AttitudeControl's (INPUT_TC 0.15, SLEW_YAW 6000 cdeg/s, RATE_FF_ENAB 1, RATE_Y_MAX 0: no limit)
    "ardusub": {"ATC_ANG_YAW_P": 6.0, "ATC_RAT_YAW_P": 0.18, "ATC_RAT_YAW_I": 0.018, "ATC_RAT_YAW_FF": 0.0,
                "ATC_RAT_YAW_IMAX": 0.222, "ATC_ACCEL_Y_MAX": 110000.0, "ATC_INPUT_TC": 0.15, "ATC_SLEW_YAW": 6000.0,
                "ATC_RATE_FF_ENAB": 1.0},
}


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


def run_for_autopilot(args) -> int:
    module = module_of(AUTOPILOT_MODULES[args.autopilot])
    profile = module.PROFILE
    kind_name = "cascade" if profile.heading_schedule == "cascade" else profile.heading_schedule
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
    shipped = {neutral: SHIPPED_DEFAULTS.get(args.autopilot, {}).get(native)
               for neutral, native in params.items()}
    found = {k: v for k, v in shipped.items() if v is not None}
    try:
        found.update(parse_original(args.original, params))
    except DesignInputError as exc:
        print(f"companion design: error: {exc}", file=sys.stderr)
        return 2
    controller = CONTROLLERS[kind_name]
    scaled = controller == "cascade" and "steering_scale_speed" in params
    base = args.scale_base if args.scale_base is not None else found.get("steering_scale_speed") if scaled else None
    base = base if base and base > 0 else None
    rules = CascadeRules(full_scale=profile.angle_full_scale_rad, output_scale_base=base, **profile.gain_ranges)
    bounds = GainBounds(damping=CAMPAIGN_DAMPING)
    if controller == "pi":
        found.setdefault("rudder_max", args.delta_max)
    limits = HeadingLimits.from_vehicle(found, full_scale=profile.angle_full_scale_rad,
                                        rudder_rate=profile.actuator_rate_rad_s, output_scale_base=base)
    objective = DesignObjective()
    if profile.prediction_margin_pct is not None:
        objective = replace(objective, margin_pct=profile.prediction_margin_pct)
    model = YawModel(a22=args.a22, b2=args.b2, delta0=args.delta0)
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
              "chosen": choice.chosen.name, "parameters": native, **{"design": choice.to_dict()},
              "predicted_steps": steps}
    if args.json:
        print_json(result)
        return 0
    print(f"{args.autopilot}: {controller} heading controller at {args.speed:g} m/s; "
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
        for row in rows:
            settle = row["settling_time_s"]
            print(f"  ±{row['step_deg']:<4.0f}         {name:<12} {row['overshoot_pct']:11.1f}  "
                  f"{settle if math.isfinite(settle) else math.nan:13.2f}  {row['iae_s']:12.2f}")
    return 0


def predicted_steps(choice: DesignChoice, case: StepCase, objective: DesignObjective) -> dict[str, list[dict]]:
    """Each candidate's predicted step of every size of ``objective`` on ``case`` (eq. A.1–A.5):
    overshoot, time to within 5 % for good (``settling_time_s``, NaN if never) and step error."""
    out: dict[str, list[dict]] = {}
    for candidate in choice.candidates:
        rows = []
        for size in objective.step_sizes_rad:
            try:
                metrics = predict_step(case.plant, case.controller, dict(candidate.gains[0]), size,
                                       objective.duration_s, dt=objective.dt, **case.limits)
            except ValueError:  # gains the autopilot refuses to fly (PX4 without a wheel base)
                metrics = {"overshoot_pct": math.nan, "settling_time_s": math.nan, "iae_s": math.nan}
            rows.append({"step_deg": math.degrees(size), "overshoot_pct": metrics["overshoot_pct"],
                         "settling_time_s": metrics["settling_time_s"], "iae_s": metrics["iae_s"]})
        out[candidate.name] = rows
    return out


def module_heading_parameters(kind_name: str) -> tuple[str, ...]:
    """The neutral parameters the heading schedule ``kind_name`` writes."""
    from behaviors.schedules import schedule_kind

    return schedule_kind(kind_name).parameters
