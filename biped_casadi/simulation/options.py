"""Options of every closed-loop simulation: how many steps, the integration, and the
thresholds of the validity conditions (:mod:`biped_casadi.simulation.validity`)."""
from __future__ import annotations

import math
import numbers
from dataclasses import asdict, dataclass

from ..control.output_law import SECTION
from ..option_checks import FieldChecks

__all__ = ["SimulationOptions", "DEFAULT_MU", "friction_of"]

#: the friction coefficient of a run when neither its options nor its gait give one
DEFAULT_MU = 0.6


def friction_of(gait=None, mu=None) -> float:
    """The friction coefficient a run is held to.

    Parameters
    ----------
    gait : Gait or GaitFamily, optional
        The reference; its ``options.mu`` (the friction its optimisation assumed) counts
        when ``mu`` is None.
    mu : float, optional
        A given coefficient (it wins).

    Returns
    -------
    float
        ``mu``, else the gait's ``options.mu``, else :data:`DEFAULT_MU`.
    """
    if mu is not None:
        return float(mu)
    own = getattr(getattr(gait, "options", None), "mu", None)
    return float(own) if own is not None else DEFAULT_MU


@dataclass(frozen=True)
class SimulationOptions:
    """Options of :func:`simulate` and :class:`Simulator`; all have defaults.

    Parameters
    ----------
    steps : int
        Number of steps (impacts) to simulate.
    rk4_steps : int
        RK4 steps per reference step duration T (a positive multiple of 8).
    mu : float or None
        Friction coefficient for the stance foot and the impact impulse; None (default):
        the one the gait was optimised for (``gait.options.mu``, ``biped gait --mu``),
        else :data:`DEFAULT_MU` (0.6), see :func:`friction_of`.
    min_normal_force : float
        Lowest admissible stance normal force, N.
    min_hip_height : float or None
        The robot has fallen when the hip is lower, m; None (default): 0.5625 leg length
        (0.45 m for RABBIT), see :meth:`fall_height`.
    max_torso_angle : float
        The robot has also fallen when the torso leans more than this from upright
        (the vertical, or the robot's ``torso_upright`` angle: a torso hanging below
        the hip), rad.
    horizon : float
        A step without a valid impact within ``horizon`` T ends the run ('no_impact').
    ground_tolerance : float
        How far below the ground (m) the swing foot may graze behind the stance foot
        before the run counts as scuffed (round-off at lift-off).
    singular_tolerance : float
        The run stops as singular where the controller's decoupling denominator
        (D11 - D12 M1 for the time-varying controller, eq. 23-24) changes sign or falls
        below this fraction of its largest magnitude on the reference (the torques grow
        like its inverse).
    torque_limit : float or None
        The run stops ('torque_limit') where some ``|u_i|`` exceeds it, N m (one limit
        for every joint); None (default): the robot's own, each joint's where they differ
        (``model.description.torque_bound``), or for a robot without one the limit its
        gait was made for (``gait.options.torque_limit``).
    min_liftoff_speed : float
        The old stance foot must leave the ground after an impact with at least this
        upward speed, m/s (default 0: any upward speed).
    jit : bool
        Compile the closed loop to C (CasADi JIT, needs a C compiler; a few seconds
        once per controller, then about 5 times faster).
    saturate : bool
        Clip every torque at its torque limit and keep walking (real actuators
        saturate), instead of stopping the run with 'torque_limit'; the run reports the
        time it spent saturated.  Full-order simulator only (the walkers are the zero
        dynamics, exact only while the torques are those of the law).
    """
    steps: int = 10
    rk4_steps: int = 2000
    mu: float | None = None
    min_normal_force: float = 0.0
    min_hip_height: float | None = None
    max_torso_angle: float = math.pi / 2
    horizon: float = 2.0
    ground_tolerance: float = 1e-9
    singular_tolerance: float = 0.01
    torque_limit: float | None = None
    min_liftoff_speed: float = 0.0
    jit: bool = False
    saturate: bool = False

    def __post_init__(self):
        for name in ("steps", "rk4_steps"):          # numpy integers are integers too
            v = getattr(self, name)
            if isinstance(v, numbers.Integral) and not isinstance(v, bool):
                object.__setattr__(self, name, int(v))
        c = FieldChecks(self, "{}", flag="True or False",
                        real=lambda v: isinstance(v, (int, float)))   # bools too, as before
        c.integers(("steps",), 1, phrase="a positive integer")
        if not isinstance(self.rk4_steps, int) or self.rk4_steps < 8 or self.rk4_steps % 8:
            raise ValueError(f"rk4_steps must be a positive multiple of 8, got {self.rk4_steps!r}")
        c.numbers(("max_torso_angle", "horizon"))
        c.numbers(("mu", "min_hip_height"), none=True)
        c.numbers(("torque_limit",), none=True, inf=True, phrase="a positive number or None")
        c.numbers(("min_normal_force", "ground_tolerance", "singular_tolerance",
                   "min_liftoff_speed"), strict=False)
        c.flags(("jit", "saturate"))
        if self.horizon <= SECTION:
            raise ValueError(f"horizon must exceed {SECTION} (the Poincaré section), "
                             f"got {self.horizon!r}")

    def to_dict(self) -> dict:
        """The options by name.

        Returns
        -------
        dict
            Field name -> value.
        """
        return asdict(self)

    def fall_height(self, model) -> float:
        """The hip height below which ``model`` has fallen, m.

        Parameters
        ----------
        model : BipedModel
            The robot (its leg length sets the default).

        Returns
        -------
        float
            ``min_hip_height``, or 0.5625 leg length when it is None (0.45 m for
            RABBIT).
        """
        if self.min_hip_height is not None:
            return float(self.min_hip_height)
        return float(0.5625 * model.description.leg_length)
