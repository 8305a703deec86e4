"""The conditions a walking robot must satisfy, written once for every simulator.

A closed-loop run may never continue past a state the robot cannot be in.  At every
integration node of single support: the state is finite, the controller's reference is
defined, the controller is not singular, the robot has not fallen (hip too low, or the
torso leaning past the bound from its upright angle), the swing foot is not
in the ground where it cannot strike (scuffing), the stance foot is pressed on the
ground (F_z > 0, or above a floor), the reaction is inside the friction cone
(|F_x| <= mu F_z) and every torque is within the limit.  At the start of a step the
swing foot is not below the ground.  At every impact: the swing foot strikes moving
down, the impulse is pressed on the ground and inside the friction cone, and the old
stance foot lifts off.

The full-order :class:`~biped_casadi.simulation.full_order.Simulator` and the batched
walkers (:mod:`~biped_casadi.simulation.tv_walker`, :mod:`~biped_casadi.simulation.vc_walker`) call these functions, vectorised over
any number of nodes and scenarios, with the thresholds of :class:`Limits`.

At the nodes only: the fall and the singularity.  The swing foot, the stance force, the
friction cone and the torques are checked between the nodes too
(:mod:`~biped_casadi.simulation.margins`); 'fell' and 'singular' are not, and need not
be.  Between two nodes an output c goes beyond its values there by at most
max |c''| h^2 / 8 (h the step).  Measured on RABBIT's runs of s*, basins and the
simulator (every node before a run's first failure; the estimate from second
differences):

- 'fell': its bounds (hip height, torso lean) say when a robot has fallen, a judgment,
  not a state it cannot be in; beyond the nodes by at most 4.1e-5 m and 8.4e-5 rad at
  the coarsest step in use (the time-varying walker at T/128), 6.5e-6 m and 1.2e-5 rad
  on virtual constraints at 100 nodes, 1.5e-5 m and 2.3e-5 rad in the simulator at
  T/200, while no such node came within 0.16 m and 0.99 rad of the bounds.
- 'singular': at the nodes the denominator is at least ``singular_tolerance`` (1e-2) of
  its scale and of the step's sign (a lasting sign change is seen at the next node); a
  change of sign and back within a step needs |den''| >= 8e-2 of the scale / h^2 there.
  Away from the law's pole |den''| h^2 / 8 is at most 6e-5 of the scale (T/128; 3e-5 on
  virtual constraints at 100 nodes, 4.2e-5 in the simulator at T/200), 170 times short.
  Near the pole the accelerations, and with them the torques and the stance reaction
  (checked between the nodes), grow like 1 / den (eq. 23, ddq_u = (-D12 ddv - H1) /
  den): a design whose reference's denominator goes through 0 mid-step stops on them,
  without a tolerance band, while |den| is 6e-3 to 0.12 of its scale, 30 to 3e5 times
  the largest dip between two nodes; with the torque limit and the friction lifted the
  screen finds the pole itself between two nodes (``tests/test_nodes_only.py``).  On
  virtual constraints the denominator, the hip and the torso are functions of the phase
  alone, exact between the walker's nodes: the curve's, beyond the nodes by at most
  2e-5 of the scale, 1e-6 m and 1.3e-6 rad at 100 nodes.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..model.description import torso_lean
from .kernel import ground_height
from .options import friction_of

__all__ = ["NODE_CHECKS", "IMPACT_CHECKS", "Limits", "node_violations", "first_violation",
           "start_violation", "strike_violation", "impact_violation", "node_message",
           "impact_message", "between_message", "STRIKE_MESSAGE"]

#: why a strike is invalid when the swing foot does not move down
STRIKE_MESSAGE = "the swing foot reaches the ground without moving down"

#: tolerance of the friction cones on |F_x| / F_z, the gait problem's own (a gait with a
#: cone active holds it to the optimiser's tolerance: its own orbit is no slip)
FRICTION_TOL = 1e-7

#: single-support statuses in the order of priority at the same node
NODE_CHECKS = ("diverged", "out_of_range", "singular", "fell", "scuffed",
               "negative_normal_force", "slipped", "torque_limit")
#: impact statuses, in the order they are checked (after :func:`strike_violation`)
IMPACT_CHECKS = ("diverged", "negative_normal_force", "slipped", "scuffed")


@dataclass(frozen=True)
class Limits:
    """The thresholds of the validity conditions for one robot.

    Parameters
    ----------
    mu : float
        Friction coefficient (stance foot and impact impulse).
    min_normal_force : float
        Lowest admissible stance normal force, N.
    hip_floor : float
        The robot has fallen when the hip is lower, m.
    max_torso_angle : float
        ... or when the torso leans more than this from upright, rad.
    ground_tolerance : float
        How far below the ground the swing foot may graze where it cannot strike, m.
    singular_tolerance : float
        Fraction of the denominator's scale below which the controller is singular.
    torque_limit : float or tuple of float
        Bound on every ``|u_i|``, N m: a float, or one per torque u1 .. u_nu where the
        robot's joints' limits differ
        (:attr:`~biped_casadi.model.description.RobotDescription.torque_bound`).
    min_liftoff_speed : float
        Upward speed the old stance foot needs after an impact, m/s.
    scuffing_ignored : bool
        Legs without knees: the swing foot may pass below the ground (only a strike
        counts).
    saturate : bool
        Torques are clipped at ``torque_limit`` and the run goes on (the torque limit
        is then not a failure).
    torso_upright : float
        The torso's angle when upright (the robot's
        :attr:`~biped_casadi.model.description.RobotDescription.torso_upright`), rad: the
        lean is wrap(torso - torso_upright) (:func:`~biped_casadi.model.description.
        torso_lean`).
    """

    mu: float
    min_normal_force: float
    hip_floor: float
    max_torso_angle: float
    ground_tolerance: float
    singular_tolerance: float
    torque_limit: float | tuple
    min_liftoff_speed: float
    scuffing_ignored: bool = False
    saturate: bool = False
    torso_upright: float = 0.0

    @classmethod
    def of(cls, options, model, gait=None) -> "Limits":
        """The limits of simulation options for a robot.

        The robot's own torque limits (its ``torque_bound``: per joint where they differ)
        and fall height are used where the options leave them unset; a robot without a torque limit (a URDF without effort limits) is held
        to the one its gait was made for, as MuJoCo's motors are.  Without a friction
        coefficient in the options, the ground has the one the gait was made for
        (:func:`~biped_casadi.simulation.options.friction_of`).

        Parameters
        ----------
        options : SimulationOptions
            The thresholds.
        model : BipedModel
            The robot.
        gait : Gait, optional
            The reference (its ``options.torque_limit`` and ``options.mu``).

        Returns
        -------
        Limits
        """
        tl = options.torque_limit if options.torque_limit is not None \
            else model.description.torque_bound
        if options.torque_limit is None and not np.all(np.isfinite(tl)):
            tl = getattr(getattr(gait, "options", None), "torque_limit", None) or tl
        if getattr(options, "saturate", False) and not np.all(np.isfinite(tl)):
            raise ValueError(f"saturate: the robot {model.params.name} has no torque limit to "
                             f"clip the torques at (its URDF gives no effort limits): give "
                             f"torque_limit (--torque-limit N)")
        return cls(mu=friction_of(gait, options.mu),
                   min_normal_force=float(options.min_normal_force),
                   hip_floor=options.fall_height(model),
                   max_torso_angle=float(options.max_torso_angle),
                   ground_tolerance=float(options.ground_tolerance),
                   singular_tolerance=float(options.singular_tolerance),
                   torque_limit=_bound(tl, model.nu), min_liftoff_speed=float(options.min_liftoff_speed),
                   scuffing_ignored=bool(model.scuffing_ignored),
                   saturate=bool(getattr(options, "saturate", False)),
                   torso_upright=float(getattr(model.description, "torso_upright", 0.0)))


def _bound(limit, nu: int):
    """A resolved torque bound: a float, or a tuple of nu floats (one per torque)."""
    if np.ndim(limit) == 0:
        return float(limit)
    limit = tuple(float(v) for v in limit)
    if len(limit) != nu:
        raise ValueError(f"torque_limit: {len(limit)} bounds for {nu} torques")
    return limit


def _over(u, limit):
    """Per node, whether some |u_i| (u: (nu, *S)) exceeds its bound."""
    if np.ndim(limit) == 0:
        return np.max(np.abs(u), axis=0) > limit
    U = np.asarray(limit).reshape((-1,) + (1,) * (np.ndim(u) - 1))
    return np.any(np.abs(u) > U, axis=0)


def _torque_words(u, limit) -> str:
    """The torque-limit failure in words: the torque most beyond its bound."""
    if np.ndim(limit) == 0:
        return f"torque limit exceeded: |u| = {np.max(np.abs(u)):.4g} N m > {limit:g} N m"
    over = np.abs(np.asarray(u, float)) - np.asarray(limit)
    i = int(np.argmax(over))
    return (f"torque limit exceeded: |u{i + 1}| = {abs(float(u[i])):.4g} N m > its limit "
            f"{limit[i]:g} N m")


def node_violations(rows: dict, limits: Limits, den_scale, den_sign, z_prev=None,
                    ground=None) -> dict:
    """Masks of the violated conditions at integration nodes.

    Parameters
    ----------
    rows : dict of numpy.ndarray
        Per node (all of one shape S, nodes along the last axis): 'finite' (bool),
        'den' (the decoupling denominator, eq. 24 for the time-varying controller),
        'Fx', 'Fz' (stance reaction), 'xsw', 'zsw' (swing foot), 'hip' (hip height),
        'torso' (torso angle from the vertical); 'u' with shape (nu, *S); optionally
        'in_range' (0 where the controller's reference is undefined).
    limits : Limits
        The thresholds.
    den_scale, den_sign : float or array broadcastable to S
        The denominator's largest magnitude on the reference and its sign at the start
        of the step.
    z_prev : array, optional
        Swing-foot height at the previous node (a foot already under the ground cannot
        strike: going further down is scuffing).
    ground : tuple, optional
        (ahead, behind) ground heights under the swing foot on uneven ground
        (:func:`biped_casadi.simulation.kernel.ground_height`); heights are measured from
        there.  None: flat.

    Returns
    -------
    dict
        Status name -> boolean mask of shape S, in the priority order of
        :data:`NODE_CHECKS`.
    """
    lim = limits
    zsw = rows["zsw"]
    if ground is not None:
        g = ground_height(rows["xsw"], ground)
        zsw = zsw - g
        if z_prev is not None:
            z_prev = np.asarray(z_prev) - g
    finite = rows["finite"]
    bad = {"diverged": ~finite}
    with np.errstate(invalid="ignore"):
        if "in_range" in rows:
            bad["out_of_range"] = finite & (rows["in_range"] < 0.5)
        bad["singular"] = finite & (rows["den"] * den_sign <= lim.singular_tolerance * den_scale)
        bad["fell"] = finite & ((rows["hip"] < lim.hip_floor)
                                | (np.abs(torso_lean(rows["torso"], lim.torso_upright))
                                   > lim.max_torso_angle))
        behind = rows["xsw"] <= 0
        if z_prev is not None:
            behind = behind | (np.asarray(z_prev) < 0)
        bad["scuffed"] = finite & (zsw < -lim.ground_tolerance) & behind
        if lim.scuffing_ignored:
            bad["scuffed"] = np.zeros_like(bad["scuffed"])
        bad["negative_normal_force"] = finite & ~(rows["Fz"] > lim.min_normal_force)
        bad["slipped"] = finite & (np.abs(rows["Fx"]) > (lim.mu + FRICTION_TOL) * rows["Fz"])
        bad["torque_limit"] = finite & _over(rows["u"], lim.torque_limit)
        if lim.saturate:
            bad["torque_limit"] = np.zeros_like(bad["torque_limit"])
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
        if not mask.any():                        # the common case: nothing violated
            continue
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


def start_violation(z_sw, limits: Limits, behind=0.0):
    """'scuffed' where a step starts with the swing foot below the ground, else ''.

    Parameters
    ----------
    z_sw : array_like
        Swing-foot height at the start of the steps, m.
    limits : Limits
        The thresholds (``ground_tolerance``).
    behind : float or array_like
        The ground the foot starts from, m (the previous foothold on uneven ground).

    Returns
    -------
    numpy.ndarray of str
    """
    z_sw = np.asarray(z_sw) - behind
    with np.errstate(invalid="ignore"):
        return np.where(np.asarray(z_sw) < -limits.ground_tolerance, "scuffed", "").astype(object)


def strike_violation(dz_sw):
    """'scuffed' where the swing foot reaches the ground without moving down, else ''.

    Parameters
    ----------
    dz_sw : array_like
        Vertical velocity of the swing foot at the strikes, m/s.

    Returns
    -------
    numpy.ndarray of str
    """
    with np.errstate(invalid="ignore"):
        return np.where(np.asarray(dz_sw) < 0, "", "scuffed").astype(object)


def impact_violation(F, v_lift, finite, limits: Limits):
    """The status of impacts, '' where valid (vectorised over impacts).

    Parameters
    ----------
    F : array (..., 2)
        Impulse (F_x, F_z) on the new stance foot, N s.
    v_lift : array
        Vertical velocity of the old stance foot just after the impact, m/s.
    finite : array of bool
        Whether the post-impact state is finite.
    limits : Limits
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
                 ("slipped", np.abs(Fx) > (limits.mu + FRICTION_TOL) * Fz),
                 ("scuffed", ~(np.asarray(v_lift) > limits.min_liftoff_speed)))
    for name, mask in conds:
        out = np.where((out == "") & mask, name, out)
    return out


def node_message(which: str, node: dict, limits: Limits, den_scale: float) -> str:
    """A node failure in words, with the values that broke the condition.

    Parameters
    ----------
    which : str
        The status (:data:`NODE_CHECKS`).
    node : dict
        The rows at the failing node (as given to :func:`node_violations`, scalars; only
        those the status's words name are read).
    limits : Limits
        The thresholds.
    den_scale : float
        The denominator's largest magnitude on the reference.

    Returns
    -------
    str
    """
    d = node
    words = {
        "diverged": lambda: "the state is not finite",
        "out_of_range": lambda: "the state left the range where the controller's reference "
                                "is defined",
        "singular": lambda: f"controller singular: decoupling denominator {d['den']:.4g} "
                            f"(below {limits.singular_tolerance:g} of {den_scale:.4g}, "
                            f"eq. 23-24)",
        "fell": lambda: f"fell: hip height {d['hip']:.4f} m, torso angle {d['torso']:.4f} rad"
                        + ("" if limits.torso_upright == 0.0 else
                           f" (lean {float(torso_lean(d['torso'], limits.torso_upright)):.4f} "
                           f"rad from upright, {limits.torso_upright:.4f})"),
        "scuffed": lambda: f"swing foot below the ground where it cannot strike (behind the "
                           f"stance foot, or already under the ground): x_sw = "
                           f"{d['xsw']:.4f} m, z_sw = {d['zsw']:.3g} m",
        "negative_normal_force": lambda: f"stance normal force F_z = {d['Fz']:.4g} N",
        "slipped": lambda: f"stance foot slips: |F_x| / F_z = "
                           f"{_ratio(abs(d['Fx']) / max(d['Fz'], 1e-300))} > mu = {limits.mu}",
        "torque_limit": lambda: _torque_words(d["u"], limits.torque_limit),
    }
    return words[which]()


def _ratio(x: float) -> str:
    """A friction ratio in words: four decimals, or four digits where it is huge (near
    the law's pole |F_x| / F_z reaches 1e306)."""
    return f"{x:.4f}" if abs(x) < 1e4 else f"{x:.4g}"


def between_message(which: str, node: dict, limits: Limits, den_scale: float = 1.0) -> str:
    """A failure found between two integration nodes (a minimum inside an RK4 step), in
    words: :func:`node_message` at that state, naming where it was found.

    Parameters
    ----------
    which, node, limits, den_scale
        As :func:`node_message`'s.

    Returns
    -------
    str
    """
    return node_message(which, node, limits, den_scale) + ", between two RK4 nodes"


def impact_message(which: str, F, v_lift: float, limits: Limits) -> str:
    """An impact failure in words.

    Parameters
    ----------
    which : str
        The status from :func:`impact_violation`.
    F : array_like
        The impulse (F_x, F_z), N s.
    v_lift : float
        The old stance foot's vertical velocity after the impact, m/s.
    limits : Limits
        The thresholds.

    Returns
    -------
    str
    """
    return {
        "diverged": "the impact map is not finite",
        "negative_normal_force": f"impact impulse has normal component {F[1]:.4g} N s",
        "slipped": (f"impact impulse outside the friction cone: |F_x| / F_z = "
                    f"{_ratio(abs(F[0]) / F[1])} > mu = {limits.mu}"),
        "scuffed": (f"the old stance foot does not lift off after the impact "
                    f"(vertical velocity {v_lift:.4g} m/s, needs more than "
                    f"{limits.min_liftoff_speed:g})"),
    }[which]
