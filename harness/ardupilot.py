"""What the ArduPilot SITL tests share: the SITL process under a ``python -m sim`` simulator (to freeze
it for a link-loss test) and the "as found" check of every heading gain, the overrides and the mode."""
from __future__ import annotations

from pathlib import Path

#: the neutral heading gains a cascaded ArduPilot campaign may change
HEADING_GAINS = ("heading_angle_p", "heading_rate_p", "heading_rate_i", "heading_rate_ff", "heading_rate_d",
                 "heading_rate_imax")


def sitl_pid(sim, binary: str) -> int:
    """The ArduPilot process named ``binary`` (``ardurover``, ``ardusub``) started by ``sim``'s process."""
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        parent = int(stat.rsplit(")", 1)[1].split()[1])
        if parent == sim.process.pid and binary in stat:
            return int(entry.name)
    raise AssertionError(f"no {binary} process under the simulator")


def found_state(link, gains: tuple[str, ...] = HEADING_GAINS) -> tuple[dict, str]:
    """The gains and the mode as a test finds them before a procedure."""
    return link.get_params(gains), link.mode


def assert_as_found(link, found: tuple[dict, str], *, mode: bool = True, rel: float = 1e-6) -> None:
    """Every gain, the overrides (none held) and, with ``mode``, the mode are as they were found."""
    params, found_mode = found
    now = link.get_params(tuple(params))
    for name, value in params.items():
        assert abs(now[name] - value) <= max(rel * abs(value), 1e-9), (name, now[name], value)
    assert not link.overrides.active, "no RC override may outlive a procedure"
    if mode:
        assert link.mode == found_mode, (link.mode, found_mode)
