"""The conditions a walking robot must satisfy, written once for every simulator.

A closed-loop run may never continue past a state the robot cannot be in.  At every
integration node of single support: the state is finite, the controller's reference is
defined, the controller is not singular, the robot has not fallen, the swing foot is not
in the ground where it cannot strike (scuffing), the stance foot is pressed on the
ground (F_z > 0, or above a floor), the reaction is inside the friction cone
(|F_x| <= mu F_z) and every torque is within the limit.  At every impact: the impulse is
pressed on the ground and inside the friction cone, and the old stance foot lifts off.

The full-order :class:`~biped_casadi.simulation.full_order.Simulator` and the batched zero-dynamics
walker of :mod:`biped_casadi.simulation.walkers` both call these functions, vectorised over any number
of nodes and scenarios.
"""
from __future__ import annotations

import numpy as np

__all__ = ["NODE_CHECKS", "IMPACT_CHECKS", "node_violations", "first_violation",
           "impact_violation"]

#: single-support statuses in the order of priority at the same node
NODE_CHECKS = ("diverged", "out_of_range", "singular", "fell", "scuffed",
               "negative_normal_force", "slipped", "torque_limit")
#: impact statuses, in the order they are checked
IMPACT_CHECKS = ("diverged", "negative_normal_force", "slipped", "scuffed")


def node_violations(rows: dict, options, torque_limit: float, den_scale, den_sign,
                    z_prev=None, min_hip_height: float | None = None,
                    scuffing_ignored: bool = False) -> dict:
    """Masks of the violated conditions at integration nodes.

    Parameters
    ----------
    rows : dict of numpy.ndarray
        Per node (all of one shape S, nodes along the last axis): 'finite' (bool),
        'den' (the decoupling denominator, eq. 24 for the time-varying controller),
        'Fx', 'Fz' (stance reaction), 'xsw', 'zsw' (swing foot), 'hip' (hip height),
        'torso' (torso angle from the vertical); 'u' with shape (nu, *S); optionally
        'in_range' (0 where the controller's reference is undefined).
    options : SimulationOptions
        The thresholds (mu, min_normal_force, min_hip_height, max_torso_angle,
        ground_tolerance, singular_tolerance).
    torque_limit : float
        |u_i| bound, N m.
    den_scale, den_sign : float or array broadcastable to S
        The denominator's largest magnitude on the reference and its sign at the start
        of the step.
    z_prev : array, optional
        Swing-foot height at the previous node (a foot already under the ground cannot
        strike: going further down is scuffing).
    min_hip_height : float, optional
        The hip height below which the robot has fallen (default ``options``').
    scuffing_ignored : bool
        Legs without knees (``model.scuffing_ignored``): the swing foot passing below the
        ground is the model's idealisation, never 'scuffed' (only a strike counts).

    Returns
    -------
    dict
        Status name -> boolean mask of shape S, in the priority order of
        :data:`NODE_CHECKS`.
    """
    o = options
    hip_floor = o.min_hip_height if min_hip_height is None else min_hip_height
    finite = rows["finite"]
    bad = {"diverged": ~finite}
    with np.errstate(invalid="ignore"):
        if "in_range" in rows:
            bad["out_of_range"] = finite & (rows["in_range"] < 0.5)
        bad["singular"] = finite & (rows["den"] * den_sign <= o.singular_tolerance * den_scale)
        bad["fell"] = finite & ((rows["hip"] < hip_floor)
                                | (np.abs(rows["torso"]) > o.max_torso_angle))
        behind = rows["xsw"] <= 0
        if z_prev is not None:
            behind = behind | (np.asarray(z_prev) < 0)
        bad["scuffed"] = finite & (rows["zsw"] < -o.ground_tolerance) & behind
        if scuffing_ignored:
            bad["scuffed"] = np.zeros_like(bad["scuffed"])
        bad["negative_normal_force"] = finite & ~(rows["Fz"] > o.min_normal_force)
        bad["slipped"] = finite & (np.abs(rows["Fx"]) > o.mu * rows["Fz"])
        bad["torque_limit"] = finite & (np.max(np.abs(rows["u"]), axis=0) > torque_limit)
    return bad


def first_violation(masks: dict, stop=None):
    """The first violated node along the last axis and its status.

    Parameters
    ----------
    masks : dict
        From :func:`node_violations` (priority order).
    stop : array of int, optional
        Only nodes before this index count (e.g. the node where the swing foot strikes).

    Returns
    -------
    tuple
        (index, status): index of the first violated node (the length of the last axis
        where none), status name ('' where none); arrays over the leading axes.
    """
    shape = next(iter(masks.values())).shape
    n = shape[-1]
    first = np.full(shape[:-1], n)
    which = np.full(shape[:-1], "", dtype=object)
    if n == 0:
        return first, which
    for name, mask in masks.items():
        has = mask.any(axis=-1)
        idx = np.where(has, np.argmax(mask, axis=-1), n)
        better = idx < first
        first = np.where(better, idx, first)
        which = np.where(better, name, which)
    if stop is not None:
        late = first >= np.asarray(stop)
        first = np.where(late, n, first)
        which = np.where(late, "", which)
    return first, which


def impact_violation(F, v_lift, finite, options):
    """The status of impacts, '' where valid (vectorised over impacts).

    Parameters
    ----------
    F : array (..., 2)
        Impulse (F_x, F_z) on the new stance foot, N s.
    v_lift : array
        Vertical velocity of the old stance foot just after the impact, m/s.
    finite : array of bool
        Whether the post-impact state is finite.
    options : SimulationOptions
        mu and min_liftoff_speed.

    Returns
    -------
    numpy.ndarray of str
        'diverged', 'negative_normal_force' (impulse not pressing on the ground),
        'slipped' (impulse outside the friction cone), 'scuffed' (the old stance foot
        does not lift off), or ''.
    """
    F = np.asarray(F, float)
    Fx, Fz = F[..., 0], F[..., 1]
    out = np.full(np.shape(Fz), "", dtype=object)
    with np.errstate(invalid="ignore"):
        conds = (("diverged", ~np.asarray(finite)), ("negative_normal_force", ~(Fz > 0)),
                 ("slipped", np.abs(Fx) > options.mu * Fz),
                 ("scuffed", ~(np.asarray(v_lift) > options.min_liftoff_speed)))
    for name, mask in conds:
        out = np.where((out == "") & mask, name, out)
    return out
