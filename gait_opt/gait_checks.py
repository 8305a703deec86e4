"""A gait's checks on a dense grid of its step: the physics and consistency figures
(:meth:`Gait.check <gait_opt.Gait.check>`), the constraints of its options they violate
(:meth:`Gait.violations <gait_opt.Gait.violations>`), and the step-length and step-time
bounds it lies on (:meth:`Gait.bounds_hit <gait_opt.Gait.bounds_hit>`): the docstrings
are the methods'."""
from __future__ import annotations

import math

import numpy as np

__all__ = ["dense_check", "dense_violations", "bounds_hit", "clearance_dip"]


def dense_check(gait, n: int) -> dict:
    """:meth:`Gait.check <gait_opt.Gait.check>` of ``gait`` on ``n`` points."""
    m = gait.model
    t = np.linspace(0, gait.T, n)
    q, dq, ddq = gait.evaluate(t)
    u = np.array(gait.model.inverse_dynamics.map(n)(q, dq, ddq))
    Fx, Fz = (np.array(v).ravel() for v in m.ground_reaction_acc.map(n)(q, dq, ddq))
    xs, zs = (np.array(v).ravel() for v in m.swing_foot.map(n)(q))
    qm, dqm = q[:, -1], dq[:, -1]
    qp, dqp, F, _, v_old = (np.array(v).ravel() for v in m.impact_full(qm, dqm))
    _, dz_end = m.swing_foot_velocity(qm, dqm)
    # unactuated row of eq. (1) with the reference accelerations
    D = np.array(m.D.map(n)(q)).reshape(m.nq, m.nq, n, order="F")
    H = np.array(m.H.map(n)(q, dq))
    row1 = np.einsum("jn,jn->n", D[0], ddq) + H[0]
    inner = slice(1, n - 1)
    height, margin = _clearance(gait, t / gait.T, xs, zs)
    knees = (q[list(m.stance_knees)], q[list(m.swing_knees)])
    lean = m.description.torso_lean(np.array(m.torso_angle.map(n)(q)).ravel())
    return dict(
        n_points=n,
        max_abs_torque=float(np.max(np.abs(u))),
        max_abs_torques=[float(v) for v in np.max(np.abs(u), axis=1)],
        min_normal_force=float(np.min(Fz)),
        max_friction_ratio=float(np.max(np.abs(Fx) / np.maximum(Fz, 1e-300))),
        min_swing_height_inside=float(np.min(height[inner])),
        min_clearance_margin=float(np.min(margin[inner])),
        swing_height_at_T=float(zs[-1]),
        strike_velocity=float(dz_end),
        liftoff_velocity=float(v_old[1]),
        impact_impulse=F.tolist(),
        impact_friction_ratio=float(abs(F[0]) / F[1]) if F[1] > 0 else math.inf,
        max_stance_knee=float(np.max(knees[0])) if m.has_knees else None,
        min_swing_knee=float(np.min(knees[1])) if m.has_knees else None,
        max_torso_lean=float(np.max(np.abs(lean))),
        periodicity_q=float(np.max(np.abs(qp - q[:, 0]))),
        periodicity_dq=float(np.max(np.abs(dqp - dq[:, 0]))),
        unactuated_row_residual=float(np.max(np.abs(row1))),
    )


def _clearance(gait, s, xs, zs) -> tuple:
    """(swing foot's height, its height above the clearance bound) at s = t / T."""
    m = gait.model
    profile = gait.options.clearance * 4 * s * (1 - s)
    if m.scuffing_ignored:
        # legs without knees: the swing foot must be above the ground beyond the
        # scuff zone in front of the stance foot (transcription.py); nearer, or
        # behind, it may graze below
        height = np.where(xs > m.scuff_zone, zs, np.inf)
        return height, zs - profile * (xs - m.scuff_zone) / m.description.leg_length
    return zs, zs - profile


def clearance_dip(gait, n: int = 2001) -> float:
    """Where the swing foot is lowest under its clearance bound, on ``n`` points.

    Parameters
    ----------
    gait : Gait
        The gait.
    n : int
        Points of the dense grid (those of :meth:`Gait.check <gait_opt.Gait.check>`).

    Returns
    -------
    float
        s = t / T of the inner point of least height above the bound.
    """
    t = np.linspace(0, gait.T, n)
    xs, zs = (np.array(v).ravel() for v in gait.model.swing_foot.map(n)(gait.q(t)))
    _, margin = _clearance(gait, t / gait.T, xs, zs)
    return float(t[1 + np.argmin(margin[1:-1])] / gait.T)


def dense_violations(gait, check: dict, tol: float) -> list:
    """:meth:`Gait.violations <gait_opt.Gait.violations>` of ``gait`` from ``check``."""
    c = check
    o = gait.options
    F = c["impact_impulse"]
    amounts = {
        "torque limit": (c["max_abs_torque"] - o.torque_limit if np.ndim(o.torque_limit) == 0
                         else float(np.max(np.subtract(c["max_abs_torques"],
                                                       o.torque_limit)))),
        "normal force": o.min_normal_force - c["min_normal_force"],
        "friction cone": c["max_friction_ratio"] - o.mu,
        "swing foot above ground": (-c["min_swing_height_inside"] + 2 * tol
                                    if c["min_swing_height_inside"] <= 0 else 0.0),
        "swing-foot clearance": -c["min_clearance_margin"],
        "strike velocity": c["strike_velocity"] + o.min_strike_speed,
        "lift-off velocity": o.min_liftoff_speed - c["liftoff_velocity"],
        "impact impulse cone": max(-F[1], abs(F[0]) - o.impulse_mu * F[1]),
    }
    if o.torso_lean_max is not None:
        amounts["torso lean"] = c["max_torso_lean"] - o.torso_lean_max
    if gait.model.has_knees:
        amounts["stance knee (hyperextension)"] = c["max_stance_knee"] - o.stance_knee_max
        amounts["swing knee (hyperextension)"] = o.swing_knee_min - c["min_swing_knee"]
    bad = [(k, float(v)) for k, v in amounts.items() if v > tol]
    return sorted(bad, key=lambda t: -t[1])


def bounds_hit(gait, rtol: float) -> list:
    """:meth:`Gait.bounds_hit <gait_opt.Gait.bounds_hit>` of ``gait``."""
    hit = []
    for name, value in (("step_length_bounds", gait.step_length),
                        ("step_time_bounds", gait.T)):
        for side, b in zip(("lower", "upper"), getattr(gait.options, name)):
            if abs(value - b) <= rtol * abs(b):
                hit.append([name, side, float(b)])
    return hit
