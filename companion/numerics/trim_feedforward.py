"""A pitch feed-forward through the depth set-point (SPEC C7; thesis ch. 5, eq. 5.25–5.29).

A companion can command only the autopilot's set-points (depth, heading, thrust), not its desired
pitch. The autopilot's depth PI, θd = Kpz·(z_sp − z) + I with İ = Kiz·(z_sp − z) (Table 5.1),
holds a level-flight pitch that changes with the thrust (eq. 5.27/5.29: the slower, the more
nose-down) only once its integrator I has moved there, which at Kiz = −0.01 needs ∫e dt = Δθ/|Kiz|
of depth error. An offset Δ on the depth set-point makes the P term give the pitch change at once:

    z_cmd = z_sp + Δ,   Δ = (F − D) / Kpz,   D = ∫ Kiz·Δ dt,   F = θff(t) − θff(0)

F is the level-flight pitch change fed forward (θff from the model's trim curve); D is the part of
it the autopilot's integrator has already absorbed, because it integrates the offset too. With the
true depth error e = z_sp − z the autopilot then computes θd = Kpz·e + (I − D) + F: the PI it had,
with the feed-forward F added, and the offset fades by itself once F stops changing,
d(F − D)/dt = −(Kiz/Kpz)·(F − D), with the time constant Kpz/Kiz (15 s for Table 5.1), whatever the
depth error, since D integrates the offset alone. Pure numerics: no I/O, no clock.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from companion.checks import require_finite, require_positive


@dataclass(frozen=True)
class FeedForwardConfig:
    """The autopilot's depth gains (DPT_P, DPT_I, rad of pitch per m and per m·s) and the offset's limits."""

    depth_p: float = -0.15
    depth_i: float = -0.01
    quantum_m: float = 0.01  # the offset is sent again only when it moved this much (one message each)
    max_offset_m: float = 1.5  # never command further than this from the depth to hold

    def __post_init__(self) -> None:
        require_finite(self, "depth_p", "depth_i")
        if self.depth_p == 0.0:
            raise ValueError("FeedForwardConfig.depth_p must not be 0: no P term to feed the pitch through")
        require_positive(self, "quantum_m", "max_offset_m")

    @property
    def fade_time_constant_s(self) -> float:
        """Kpz/Kiz: how fast the autopilot's integrator absorbs a constant feed-forward (inf without I)."""
        return self.depth_p / self.depth_i if self.depth_i != 0.0 else math.inf


class DepthSetpointFeedForward:
    """The depth set-point offset of the module docstring, one sample at a time.

    ``reference`` is θff at the start (the pitch the autopilot's integrator holds then). Call
    :meth:`advance` with the sample interval and the offset in effect over it (what was last sent),
    then :meth:`offset` with the feed-forward pitch now; :meth:`to_send` says whether it differs
    enough from what was sent to send it."""

    def __init__(self, config: FeedForwardConfig, reference: float) -> None:
        if not math.isfinite(reference):
            raise ValueError(f"DepthSetpointFeedForward: reference pitch must be finite, not {reference!r}")
        self.config = config
        self.reference = reference
        self.absorbed = 0.0  # D, rad of pitch the autopilot's integrator has taken over

    def advance(self, dt: float, offset_in_effect: float) -> None:
        """The autopilot integrated ``offset_in_effect`` (m) for ``dt`` s."""
        if dt > 0.0 and math.isfinite(offset_in_effect):
            self.absorbed += self.config.depth_i * offset_in_effect * dt

    def remaining(self, theta_ff: float) -> float:
        """F − D: the feed-forward pitch the P term must still carry (rad)."""
        return (theta_ff - self.reference) - self.absorbed

    def offset(self, theta_ff: float) -> float:
        """Δ (m, positive deeper) that makes the P term give F − D, within ±``max_offset_m``."""
        limit = self.config.max_offset_m
        return min(limit, max(-limit, self.remaining(theta_ff) / self.config.depth_p))

    def to_send(self, wanted: float, sent: float) -> bool:
        """The wanted offset moved a quantum from the one in effect (or must return to exactly 0)."""
        return abs(wanted - sent) >= self.config.quantum_m - 1e-12
