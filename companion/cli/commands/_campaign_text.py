"""Text lines shared by the commands that run a campaign: its vehicle time by phase and what its
verification flew beside what the model predicted."""
from __future__ import annotations


def _fmt(value, spec: str) -> str:
    return format(value, spec) if isinstance(value, (int, float)) and not isinstance(value, bool) else "-"


def phase_line(total_s, phases: dict) -> str | None:
    """``campaign: 258 s of vehicle time (settle 87 s, excitation 40 s, ...)``, or None without phases;
    without ``total_s`` the total is the phases' sum."""
    if not phases:
        return None
    if total_s is None:
        total_s = sum(seconds for seconds in phases.values() if isinstance(seconds, (int, float)))
    return (f"campaign: {_fmt(total_s, '.0f')} s of vehicle time ("
            + ", ".join(f"{name.replace('_', ' ')} {seconds:.0f} s" for name, seconds in phases.items()) + ")")


def verification_lines(verified: dict | None) -> list[str]:
    """The flown verification steps with their predictions, then the schedule's and the original
    gains' predicted overshoot at every identified speed (companion.procedures.verified_design)."""
    if not verified:
        return []
    lines = ["heading steps flown to verify the design (flown vs predicted by the accepted model)",
             f"{'thrust':>6} {'gains':>10} {'overshoot %':>12} {'predicted':>9} {'IAE s':>6} {'predicted':>9} "
             f"{'flights':>7}"]
    for step in verified.get("flown", []):
        predicted = step.get("predicted") or {}
        lines.append(f"{_fmt(step.get('thrust'), '6.2f')} {step.get('label', '-'):>10} "
                     f"{_fmt(step.get('max_overshoot_pct'), '12.1f')} {_fmt(predicted.get('overshoot_pct'), '9.1f')} "
                     f"{_fmt(step.get('iae_s'), '6.2f')} {_fmt(predicted.get('iae_s'), '9.2f')} "
                     f"{_fmt(step.get('flights'), '7d')}"
                     + ("" if step.get("decided", True) else f"  undecided: {step.get('why_undecided')}"))
    by_thrust: dict[float, dict[str, dict]] = {}
    for step in verified.get("predicted", []):
        by_thrust.setdefault(step["thrust"], {})[step["label"]] = step
    if by_thrust:
        lines.append("predicted ±step at every speed, overshoot % (scheduled / original gains)")
        for thrust, steps in sorted(by_thrust.items()):
            lines.append(f"{thrust:6.2f} {_fmt(steps.get('scheduled', {}).get('overshoot_pct'), '10.1f')} "
                         f"{_fmt(steps.get('original', {}).get('overshoot_pct'), '10.1f')}")
    return lines


def loop_lines(loops: dict | None, heading_design: dict | None) -> list[str]:
    """Loop by loop, what the campaign left on the vehicle and why (``IdentificationCampaign.loop_outcomes``),
    then the heading design's candidates (eq. D.1)."""
    lines = [f"{name} loop: {entry['outcome']}" + (f" ({entry['why']})" if entry.get("why") else "")
             for name, entry in (loops or {}).items()]
    if heading_design:
        scored = ", ".join(f"{name} {_fmt(c.get('iae_s'), '.2f')} s / {_fmt(c.get('worst_overshoot_pct'), '.1f')} %"
                           + ("" if c.get("feasible") else " (too much overshoot)")
                           for name, c in (heading_design.get("candidates") or {}).items())
        lines.append(f"heading design by prediction: {heading_design.get('chosen')} chosen; predicted step error / "
                     f"worst overshoot: {scored}")
    return lines
