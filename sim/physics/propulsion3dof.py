"""Control forces of the 3-DOF surface vessels: a stern rudder, or two thrusters (skid steering).

**Rudder** at x = x_R < 0 (behind the centre of gravity), a lifting surface in the hull's flow
(Fossen 2021, ch. 9 "rudder forces", and the linear maneuvering model's Y_δ·δ, N_δ·δ terms with
Y_δ, N_δ ∝ U²):

    δe = δ − δ_offset                       (a misaligned rudder: the straight course needs δ0 = δ_offset)
    Y_R = −k_L·u|u|·δe,   N_R = x_R·Y_R,    X_R = −k_D·u²·δe²  (rudder drag: more speed loss in turns)

with k_L = ½ρ·A_R·C_Lα (N per rad per (m/s)²). A positive rudder pushes the stern to port (Y_R < 0
at x_R < 0), so N_R > 0 turns the bow to starboard: positive rudder → positive (clockwise) yaw rate.

**Twin thrusters** (a skid-steered catamaran, as Fossen's Otter USV in ``vehicles/otter.py``): motor
demands d_L, d_R ∈ [−1, 1], each through the preset's quadratic thruster map F(d) (SPEC §3.5) ahead
and a reduced-efficiency reverse −η_rev·F(|d|) astern, at y = ∓y_arm (port = left at −y_arm):

    T_L = F±(d_L),  T_R = η_R·F±(d_R),   X = T_L + T_R,   Y = 0,   N = (T_L − T_R)·y_arm

(N = x·F_y − y·F_x for a force along x at y = ∓y_arm.) η_R ≤ 1 is a motor mismatch: the boat needs
a steering trim δ0 to run straight, as real skid boats do. Positive steering raises the left motor
(``sim.skid_mixer``), so it turns the boat clockwise, like a positive rudder.
"""
from __future__ import annotations

from dataclasses import dataclass

from sim.physics.thruster import thrust_force
from sim.preset import Rudder, ThrusterMap, TwinThrusters


@dataclass(frozen=True)
class RudderConstants:
    x_r: float
    lift: float  # k_L, N/(rad·(m/s)²)
    drag: float  # k_D, N/(rad²·(m/s)²)
    offset: float  # rad

    @classmethod
    def from_preset(cls, rudder: Rudder) -> "RudderConstants":
        return cls(rudder.x_r, rudder.lift, rudder.drag, rudder.offset)


def rudder_forces(c: RudderConstants, surge: float, rudder: float) -> tuple[float, float, float]:
    """(X_R, Y_R, N_R) of the stern rudder at surge speed ``surge`` (m/s) and angle ``rudder`` (rad)."""
    effective = rudder - c.offset
    dynamic = surge * abs(surge)
    y = -c.lift * dynamic * effective
    return -c.drag * surge * surge * effective * effective, y, c.x_r * y


def motor_thrust(thruster: ThrusterMap, demand: float, reverse_efficiency: float) -> float:
    """One motor's thrust (N): the thruster map ahead, ``reverse_efficiency`` × the map astern."""
    if demand >= 0.0:
        return thrust_force(thruster, demand)
    return -reverse_efficiency * thrust_force(thruster, -demand)


def twin_thruster_forces(
    twin: TwinThrusters, thruster: ThrusterMap, left: float, right: float, efficiency: float = 1.0,
    arm_factor: float = 1.0,
) -> tuple[float, float, float]:
    """(X, Y, N) of the two thrusters; ``efficiency`` scales both (a ``thrust`` fault), ``arm_factor``
    the yaw moment (a ``b2`` fault: lost steering authority)."""
    thrust_left = motor_thrust(thruster, left, twin.reverse_efficiency) * efficiency
    thrust_right = motor_thrust(thruster, right, twin.reverse_efficiency) * efficiency * twin.right_efficiency
    return thrust_left + thrust_right, 0.0, (thrust_left - thrust_right) * twin.y_arm * arm_factor
