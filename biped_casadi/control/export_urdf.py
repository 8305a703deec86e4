"""The exported law in the robot's own URDF angles: inputs the root link's pitch and the
URDF joint angles (and rates), outputs one torque per URDF joint in the file's order and
sign (divided by each joint's reduction on the motor side).

The stance leg is part of the controller's state: ``state[0]`` is 0 for the leg of the
first hip joint of the URDF map (leg 1), 1 for the other; ``state[1:]`` is the law's own
step state.  It is set at the start of every step, either named by the caller
(``biped_step_start_leg``) or found from the configuration (``biped_step_start``: just
after an impact the new stance foot is the one in front, ahead of the other along the
model's forward direction).  Inside, the law relabels: the URDF state becomes the
model's (q, dq) for that stance leg (:class:`~biped_casadi.model.urdf_map.UrdfMap`,
q = wrap(A_s x + c_s), dq = A_s dx), the toolkit's law gives u, and the torques go back
to the URDF's joints (tau = (A_s' B u) without the pitch row).  Nothing of the relabelling
is left to the robot's loop: after an impact it calls the step start again, with the
same joint angles it reads from its encoders.

:func:`urdf_functions` builds the CasADi Functions that :mod:`biped_casadi.control.export`
generates as C; :class:`UrdfAngleLaw` is the same law evaluated in Python with numpy's
conversions (what ``--verify`` compares the C code with).
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from ..model.urdf_map import UrdfMap, wrap_angle

__all__ = ["urdf_functions", "torque_matrix", "UrdfAngleLaw", "LEG_ORDER"]

#: how the exported code numbers the legs: 0 for the map's leg 1, 1 for leg 2
LEG_ORDER = (1, 2)


def torque_matrix(umap: UrdfMap, stance, motor_side: bool = False) -> np.ndarray:
    """T of tau = T u: the URDF joints' torques from the model's (entries 0, +-1, or
    +-1/reduction on the motor side).

    Parameters
    ----------
    umap : UrdfMap
        The robot's joint map.
    stance : str or int
        The stance leg's hip joint (or leg number).
    motor_side : bool
        Divide by each joint's reduction.

    Returns
    -------
    numpy.ndarray
        (nu, nu).
    """
    return umap.torques(np.eye(umap.nq - 1), stance, motor_side)


def _model_state(umap: UrdfMap, x, dx, s):
    """(q, dq) for the stance leg s (SX 0: leg 1, 1: leg 2), both relabellings computed
    and the one of s chosen."""
    qs, dqs = [], []
    for leg in LEG_ORDER:
        A, c = umap.matrices(leg)
        As = ca.sparsify(ca.DM(A))
        qs.append(wrap_angle(ca.mtimes(As, x) + ca.DM(c)))
        dqs.append(ca.mtimes(As, dx))
    second = s > 0.5
    return ca.if_else(second, qs[1], qs[0]), ca.if_else(second, dqs[1], dqs[0])


def urdf_functions(law: ca.Function, start: ca.Function, model, umap: UrdfMap,
                   motor_side: bool = False) -> tuple:
    """The export's Functions with URDF inputs and outputs (module docstring).

    Parameters
    ----------
    law : casadi.Function
        ``biped_law(q, dq, tau, state, node) -> (u, y, dy, den, in_range)`` in the
        model's coordinates.
    start : casadi.Function
        ``biped_start(q, dq) -> (state, go)``.
    model : BipedModel
        The robot (its swing foot finds the stance leg).
    umap : UrdfMap
        Its joint map.
    motor_side : bool
        Torques divided by each joint's reduction.

    Returns
    -------
    tuple
        ``biped_law(x, dx, tau, state, node) -> (u, y, dy, den, in_range)`` with u per URDF
        joint and state = (stance, law state); ``biped_start(x, dx, stance) -> (state,
        go)``; ``biped_front(x) -> ahead``: the swing foot's x with leg 1 in stance
        (negative: leg 1's foot is in front).
    """
    n = model.nq
    x, dx, tau = ca.SX.sym("x", n), ca.SX.sym("dx", n), ca.SX.sym("tau")
    ns = start.size1_out(0)
    state = ca.SX.sym("state", 1 + ns)
    node = ca.SX.sym("node", law.size1_in(4))
    s = state[0]
    q, dq = _model_state(umap, x, dx, s)
    u, y, dy, den, inr = law(q, dq, tau, state[1:], node)
    T1, T2 = (ca.sparsify(ca.DM(torque_matrix(umap, leg, motor_side))) for leg in LEG_ORDER)
    tq = ca.if_else(s > 0.5, ca.mtimes(T2, u), ca.mtimes(T1, u))
    f_law = ca.Function("biped_law", [x, dx, tau, state, node], [tq, y, dy, den, inr],
                        ["x", "dx", "tau", "state", "node"],
                        ["u", "y", "dy", "den", "in_range"])
    stance = ca.SX.sym("stance")
    q0, dq0 = _model_state(umap, x, dx, stance)
    p, go = start(q0, dq0)
    f_start = ca.Function("biped_start", [x, dx, stance], [ca.vertcat(stance, p), go],
                          ["x", "dx", "stance"], ["state", "go"])
    q1, _ = _model_state(umap, x, dx, ca.SX(0))
    ahead, _ = model.swing_foot(q1)
    f_front = ca.Function("biped_front", [x], [ahead], ["x"], ["ahead"])
    return f_law, f_start, f_front


class UrdfAngleLaw:
    """The toolkit's law in URDF angles, evaluated in Python (numpy's conversions
    around the controller's own law): what the generated C must equal.

    Parameters
    ----------
    controller : TimeVaryingController or VirtualConstraintController
        The exported controller.
    umap : UrdfMap
        The robot's joint map.
    motor_side : bool
        Torques divided by each joint's reduction.
    """

    def __init__(self, controller, umap: UrdfMap, motor_side: bool = False):
        self.controller, self.umap, self.motor_side = controller, umap, motor_side
        self.nu = controller.model.nu

    def step_start(self, x, dx, stance: int) -> np.ndarray:
        """The state (stance, law state) at the start of a step.

        Parameters
        ----------
        x, dx : array_like
            Pitch and URDF joint angles, and their rates.
        stance : int
            0 for the map's leg 1, 1 for leg 2 (the exported code's numbering).

        Returns
        -------
        numpy.ndarray
            (1 + law state,).
        """
        q, dq = self.umap.to_model(x, dx, LEG_ORDER[stance])
        return np.r_[float(stance), self.controller.step_start(q, dq).p]

    def evaluate(self, tau, x, dx, state) -> tuple:
        """(torques per URDF joint, y, dy, den) of the toolkit's law.

        Parameters
        ----------
        tau : float
            Time since the step started, s.
        x, dx : array_like
            Pitch and URDF joint angles, and their rates.
        state : array_like
            From :meth:`step_start`.

        Returns
        -------
        tuple
        """
        c, state = self.controller, np.asarray(state, dtype=float)
        leg = LEG_ORDER[int(state[0])]
        q, dq = self.umap.to_model(x, dx, leg)
        p = state[1:]
        if c.n_ref:
            out = c.torque(q, dq, tau, p[:self.nu], p[self.nu:])
        else:
            out = c.evaluate(q, dq, tau, np.zeros(0), p)
        u = self.umap.torques(np.asarray(out.u, float).ravel(), leg, self.motor_side)
        return u, out.y, out.dy, out.denominator
