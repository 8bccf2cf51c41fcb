"""Pure vehicle physics of the simulator (SPEC C2): plain-float scalar functions, no I/O, no clock.

- :mod:`.thruster` — thrust ratio → thrust force (SPEC §3.5).
- :mod:`.dive_plane` — surge/heave/pitch accelerations of thesis eq. 5.3–5.13.
- :mod:`.yaw` — yaw-rate and sway dynamics (SPEC C3 linearisation plus a quadratic damping).
- :mod:`.roll` — nonlinear roll with the internal rolling mass (thesis eq. 4.11).
- :mod:`.equilibrium` — level-flight trim and steady speed (scipy root finding).
- :mod:`.disturbance` — seeded band-limited random roll moment.
"""
from sim.physics.dive_plane import DivePlaneConstants, dive_plane_accelerations
from sim.physics.roll import RollConstants, roll_acceleration
from sim.physics.thruster import thrust_force, thrust_ratio_for_force
from sim.physics.yaw import YawConstants, sway_acceleration, yaw_acceleration

__all__ = [
    "DivePlaneConstants",
    "dive_plane_accelerations",
    "RollConstants",
    "roll_acceleration",
    "thrust_force",
    "thrust_ratio_for_force",
    "YawConstants",
    "yaw_acceleration",
    "sway_acceleration",
]
