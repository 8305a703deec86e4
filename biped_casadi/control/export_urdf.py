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

import math

import casadi as ca
import numpy as np

from ..model.urdf_map import UrdfMap, wrap_angle
from .saturation import clip_torques

__all__ = ["urdf_functions", "torque_matrix", "UrdfAngleLaw", "LEG_ORDER", "c_number",
           "urdf_header_doc", "urdf_readme_doc", "URDF_START_C", "comment_safe"]

#: how the exported code numbers the legs: 0 for the map's leg 1, 1 for leg 2
LEG_ORDER = (1, 2)


def torque_matrix(umap: UrdfMap, stance, motor_side: bool = False) -> np.ndarray:
    """T of tau = T u: the URDF joints' torques from the model's u.

    :meth:`UrdfMap.torque_matrix`: entries 0 and +-1 (+-1/reduction on the motor side).

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
    return umap.torque_matrix(stance, motor_side)


def _model_state(umap: UrdfMap, x, dx, s, centre=None):
    """(q, dq) for the stance leg s (SX 0: leg 1, 1: leg 2), both relabellings computed
    and the one of s chosen; angles within pi of ``centre`` (the robot's upright pose)
    when it is not all zeros."""
    qs, dqs = [], []
    centre = None if centre is None or not any(centre) else ca.DM(list(centre))
    for leg in LEG_ORDER:
        A, c = umap.matrices(leg)
        As = ca.sparsify(ca.DM(A))
        if centre is None:
            qs.append(wrap_angle(ca.mtimes(As, x) + ca.DM(c)))
        else:
            qs.append(wrap_angle(ca.mtimes(As, x) + ca.DM(c) - centre) + centre)
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
    centre = model.description.upright_q
    q, dq = _model_state(umap, x, dx, s, centre)
    u, y, dy, den, inr = law(q, dq, tau, state[1:], node)
    T1, T2 = (ca.sparsify(ca.DM(torque_matrix(umap, leg, motor_side))) for leg in LEG_ORDER)
    tq = ca.if_else(s > 0.5, ca.mtimes(T2, u), ca.mtimes(T1, u))
    f_law = ca.Function("biped_law", [x, dx, tau, state, node], [tq, y, dy, den, inr],
                        ["x", "dx", "tau", "state", "node"],
                        ["u", "y", "dy", "den", "in_range"])
    stance = ca.SX.sym("stance")
    q0, dq0 = _model_state(umap, x, dx, stance, centre)
    p, go = start(q0, dq0)
    f_start = ca.Function("biped_start", [x, dx, stance], [ca.vertcat(stance, p), go],
                          ["x", "dx", "stance"], ["state", "go"])
    q1, _ = _model_state(umap, x, dx, ca.SX(0), centre)
    ahead, _ = model.swing_foot(q1)
    f_front = ca.Function("biped_front", [x], [ahead], ["x"], ["ahead"])
    return f_law, f_start, f_front


class UrdfAngleLaw:
    """The toolkit's law in URDF angles, evaluated in Python: what the C must equal.

    numpy's conversions around the controller's own law.

    Parameters
    ----------
    controller : TimeVaryingController or VirtualConstraintController
        The exported controller.
    umap : UrdfMap
        The robot's joint map.
    motor_side : bool
        Torques divided by each joint's reduction.
    torque_limit : float or tuple of float, optional
        The model's torques clipped at +-torque_limit (N m; one per torque where the
        joints' limits differ) before the mapping, as an
        export that saturates clips them.
    """

    def __init__(self, controller, umap: UrdfMap, motor_side: bool = False,
                 torque_limit: float | None = None):
        self.controller, self.umap, self.motor_side = controller, umap, motor_side
        self.limit = math.inf if torque_limit is None else \
            (float(torque_limit) if np.ndim(torque_limit) == 0 else tuple(torque_limit))
        self.nu = controller.model.nu
        #: the angles' centre: the robot's upright pose (hips near +-pi for a hanging torso)
        self.centre = controller.model.description.upright_q

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
        q, dq = self.umap.to_model(x, dx, LEG_ORDER[stance], centre=self.centre)
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
        q, dq = self.umap.to_model(x, dx, leg, centre=self.centre)
        p = state[1:]
        if c.n_ref:
            out = c.torque(q, dq, tau, p[:self.nu], p[self.nu:])
        else:
            out = c.evaluate(q, dq, tau, np.zeros(0), p)
        u = self.umap.torques(clip_torques(np.asarray(out.u, float).ravel(), self.limit), leg,
                              self.motor_side)
        return u, out.y, out.dy, out.denominator


# ======================================================================= C text
def c_number(x) -> str:
    """A double as C source, read back exactly.

    Parameters
    ----------
    x : float

    Returns
    -------
    str
    """
    x = float(x)
    if math.isinf(x):
        return "HUGE_VAL" if x > 0 else "-HUGE_VAL"
    s = repr(x)
    return s if ("e" in s or "." in s or "n" in s) else s + ".0"


_num = c_number


def c_array(name: str, values, per_line: int = 4) -> str:
    """A static const double array of ``values`` as C source (exact numbers)."""
    vals = [_num(v) for v in np.ravel(values)]
    lines = [", ".join(vals[i:i + per_line]) for i in range(0, len(vals), per_line)]
    body = ",\n    ".join(lines) if lines else "0.0"
    return f"static const double {name}[{max(len(vals), 1)}] = {{\n    {body}\n}};\n"


def casadi_c(name: str, functions) -> str:
    """CasADi's C for some Functions, one file (int and double, no header of its own)."""
    cg = ca.CodeGenerator(name, {"with_header": False, "casadi_int": "int",
                                 "casadi_real": "double"})
    for f in functions:
        cg.add(f)
    return cg.dump()


#: C text shared by the exports' wrappers: whether n doubles are all finite
ALL_FINITE_C = """static int all_finite(const double *x, int n)
{
    int j;
    for (j = 0; j < n; ++j)
        if (!(x[j] - x[j] == 0.0)) return 0;
    return 1;
}

"""

#: the step starts of an export in URDF angles (C)
URDF_START_C = """int biped_step_start_leg(int stance, const double *q, const double *dq, double *state)
{
    double go = 0.0, leg = (double)stance;
    if (stance != 0 && stance != 1) return 2;
    work_arg[0] = q; work_arg[1] = dq; work_arg[2] = &leg;
    work_res[0] = state; work_res[1] = &go;
    if (biped_start(work_arg, work_res, work_iw, work_w, 0)) return 3;
    if (!all_finite(q, NQ) || !all_finite(dq, NQ)) return 3;
    if (!(go > 0.0)) return 2;
    return all_finite(state, NSTATE) ? 0 : 3;
}

/* the stance leg: the one whose foot is in front (the swing foot behind it) */
int biped_step_start(const double *q, const double *dq, double *state)
{
    double ahead = 0.0;   /* the other foot's distance in front of leg 0's foot */
    work_arg[0] = q;
    work_res[0] = &ahead;
    if (biped_front(work_arg, work_res, work_iw, work_w, 0)) return 3;
    if (!all_finite(&ahead, 1)) return 3;
    if (ahead == 0.0) return 2;
    return biped_step_start_leg(ahead < 0.0 ? 0 : 1, q, dq, state);
}
"""



def comment_safe(text: str) -> str:
    """Text that can stand inside a C comment.

    A ``*/`` of a name (URDF names, file paths) would end the comment early: it is
    written ``* /``.

    Parameters
    ----------
    text : str
        The comment's text.

    Returns
    -------
    str
        The same text without ``*/``.
    """
    return text.replace("*/", "* /")


def urdf_header_doc(m: UrdfMap, nu: int, motor_side: bool) -> str:
    """The header's comment on the inputs, outputs and state of a law in URDF angles.

    Parameters
    ----------
    m : UrdfMap
        The robot's joint map.
    nu : int
        Torques.
    motor_side : bool
        Torques divided by the reductions.

    Returns
    -------
    str
        C comment lines (`` * ...``).
    """
    names = list(m.names)
    legs = {leg: [j.name for j in sorted(m.joints, key=lambda j: j.position) if j.leg == leg]
            for leg in (1, 2)}
    axis = ", ".join(_num(v) for v in m.axis)
    torque = ("the motor side: each joint's torque divided by its transmission's reduction "
              "(" + ", ".join(f"{j.name} {j.reduction:g}" for j in m.joints) + ")"
              if motor_side else "the joint side")
    lines = [
        "The robot's own URDF coordinates (no relabelling, no sign or offset to apply):",
        f"q[0] = pitch: the absolute angle of link '{m.root}' about the joints' axis n = "
        f"[{axis}] (its frame), right-handed about n, 0 when the link's frame is aligned "
        "with the world's (z up);",
        "q[1..] the URDF joint angles in the file's order: " + ", ".join(
            f"q[{i + 1}] {n}" for i, n in enumerate(names)) + ";",
        "dq: their rates; rad and rad/s.",
        f"u[0..{nu - 1}]: the torque of each of those joints (u[i] on q[i + 1]) in the "
        f"URDF's sign (about the joint's own <axis>), N m, on {torque}.",
        "state[0] is the stance leg: 0 for the leg of hip joint '" + legs[1][0] + "' ("
        + ", ".join(legs[1]) + "), 1 for the leg of '" + legs[2][0] + "' ("
        + ", ".join(legs[2]) + "); state[1..] the law's step constants.",
        "biped_step_start finds the stance leg from q (the leg whose foot is in front, as "
        "it is just after an impact); biped_step_start_leg is told.  Call one of them at "
        "start-up and just after every impact, with the angles as read: the law relabels "
        "the legs inside.",
        "tau: time since the step started, s.",
        "The map to the toolkit's coordinates (each joint's child link relative to its "
        "parent, in the model's sense, = sign * angle + offset; docs/howto/export.md):",
    ] + [f"  {j.name}: {'+' if j.sign > 0 else '-'}angle {'+' if j.offset >= 0 else '-'} "
         f"{_num(abs(j.offset))}" for j in m.joints] + [
        f"  the torso: pitch + {_num(m.pitch_offset)}"]
    out = []
    for line in lines:
        words, cur = line.split(" "), " *"
        for w in words:
            if len(cur) + 1 + len(w) > 88:
                out.append(cur)
                cur = " *  " + w if line.startswith("  ") else " * " + w
            else:
                cur += " " + w
        out.append(cur)
    return comment_safe("\n".join(out))




def urdf_readme_doc(m: UrdfMap, nq: int, nu: int, nstate: int, motor_side: bool,
                    state_doc: str, tau: str) -> str:
    """The README's bullets on the inputs, outputs and state of a law in URDF angles.

    Parameters
    ----------
    m : UrdfMap
        The robot's joint map.
    nq, nu, nstate : int
        Sizes.
    motor_side : bool
        Torques divided by the reductions.
    state_doc : str
        What the law's own step state is.
    tau : str
        The sentence on tau.

    Returns
    -------
    str
        Markdown.
    """
    hips = m.hips
    joints = ", ".join(f"`{n}`" for n in m.names)
    side = ("divided by each joint's transmission reduction (the motor's torque: "
            + ", ".join(f"{j.name} {j.reduction:g}" for j in m.joints) + ")"
            if motor_side else "at the joint")
    return f"""- `q`, `dq` ({nq} each): the robot's own URDF coordinates, as its encoders and
  attitude estimate give them: `q[0]` the pitch of link `{m.root}` (its absolute angle
  about the joints' axis [{", ".join(f"{v:g}" for v in m.axis)}], right-handed, 0 when its
  frame is aligned with the world's, z up), then the joint angles {joints} (the URDF's
  order, its zero and its sign), rad and rad/s. No relabelling: the law does it.
- `u` ({nu}): the torque of each of those joints in the same order and sign, N m,
  {side}. {tau}
- `state` ({nstate}): `state[0]` the stance leg (0: the leg of `{hips[0]}`, 1: the leg
  of `{hips[1]}`), then {state_doc}. `biped_step_start` sets the leg whose foot is in
  front (the new stance foot just after an impact; code 2 when the feet are level);
  `biped_step_start_leg(stance, q, dq, state)` takes it from the caller."""
