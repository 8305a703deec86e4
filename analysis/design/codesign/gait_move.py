"""The user's gait moved to the robust gait constraints, staying near it.

A gait made for another purpose (the toolkit's default options, another tool) usually
keeps the impact impulse near the friction cone's edge and the swing foot just above
the ground: a perturbation then makes the foot slip at the impact or scuff, whatever the
outputs.  The robust co-design's gait constraints (:data:`analysis.design.ROBUST_GAIT`:
impulse ratio at most 0.15, swing clearance 5 cm mid-step, the reference continued past
T) leave room for that.  They are reached here by continuation from the gait's own
values, each step the gait nearest the user's (weighted least squares in its
parameters) under the constraints of that step:

1. the gait's own values of the continued constraints: its impulse ratio |F_x| / F_z
   and the largest clearance c with z_sw(s) >= c 4 s (1 - s) over the step; where the
   gait already meets a target, the target;
2. the gait's parameters G = (alpha, T, r0) that minimise sum ((G - G_user) / scale)^2
   + effort x E(G) / E(G_user), E = int u'u ds the nominal step's effort (the distance
   alone makes gaits near the user's but with jerky torques, which perturbations
   punish), under the gait's constraints
   (:class:`~analysis.design.codesign.transcription.GaitTable`: periodic through the
   impact, the speed and step length, torque, friction, impulse cone, clearance, strike
   and lift-off speeds, knees) at the targets, with exact Jacobians, from the user's
   gait;
   An infinite effort weight is the effort alone: the toolkit's optimal gait under the
   robust gait options at the user's speed, in the toolkit's Bezier degree
   (:func:`gait_opt.optimize_gait`, warm-started from the user's gait when it is of that
   degree), the farthest move;
3. when that solve fails: the continuation, ``steps`` steps from the gait's own values
   to the targets (linear), each solved from the last on the distance alone, a step
   that fails halved (at most ``halvings`` times; the move ends where it cannot go on
   and the result says how far it got); then the effort term from there;
4. every solution made an exact periodic orbit (:func:`gait_opt.polish.polish`) and
   checked on the dense grid (:meth:`gait_opt.Gait.violations`).

Constraints the user's gait itself violates (an imported gait is not held to the
default options) are relaxed to its own values, so the move starts feasible.  The speed
stays the user's.  :func:`gait_change` says how far a gait moved.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from biped_casadi.model.torque_limits import torque_bound_text
from biped_casadi.results import Result, internal
from gait_opt import Gait, GaitOptimizationError, GaitOptions, optimize_gait

from ...tasks import task
from .functions import TranscriptionSettings
from .reduced import NoStrikeAtStart, solve_nlp
from .settings import MoveSettings
from .transcription import GaitTable, _Rows
from .units import gait_step

__all__ = ["MoveSettings", "GaitMove", "GaitProjection", "move_gait", "gait_change",
           "own_values", "optimal_options", "continue_gait"]


@dataclass
class GaitMove(Result):
    """The user's gait moved to the robust gait constraints (:func:`move_gait`).

    ``success`` means the move ran; ``status`` says how far it got.

    Parameters
    ----------
    status : str
        'moved' (the targets reached), 'partly' (the last step that succeeded), 'kept'
        (the gait already meets them, or no step succeeded: the user's gait).
    message : str
        In words.
    start : dict
        The user's gait's own values (``impact_mu``, ``clearance``).
    targets : dict
        The targets.
    reached : dict
        The values of the moved gait's constraints.
    steps : list of dict
        Every continuation step: its bounds, IPOPT's status and iterations, the
        distance to the user's gait.
    change : dict
        :func:`gait_change` from the user's gait.
    gait : Gait
        The moved gait (left out of ``to_dict()``).
    """

    status: str
    message: str
    start: dict
    targets: dict
    reached: dict
    steps: list = field(default_factory=list)
    change: dict = field(default_factory=dict)
    gait: object = internal(default=None)

    SUCCESS = ("moved", "partly", "kept")


#: the constraints reached by continuation from the gait's own values
CONTINUED = ("impact_mu", "clearance", "mu", "torque_limit")


def own_values(gait) -> dict:
    """The gait's own values of the continued constraints.

    Parameters
    ----------
    gait : Gait
        The gait.

    Returns
    -------
    dict
        ``impact_mu``: its impulse ratio ``|F_x| / F_z``; ``clearance``: the largest c
        with z_sw >= c 4 s (1 - s) inside the step, m; ``mu``: its largest friction
        ratio ``|F_x| / F_z`` in single support; ``torque_limit``: its peak torque, N m
        (each torque's peak where its options bound each torque: a robot whose joints'
        limits differ).
    """
    c = gait.check()
    t = np.linspace(0.0, gait.T, 2001)[1:-1]
    q, _, _ = gait.evaluate(t)
    z = np.array(gait.model.swing_foot.map(t.size)(q)[1]).ravel()
    s = t / gait.T
    return dict(impact_mu=float(c["impact_friction_ratio"]),
                clearance=float(np.min(z / (4 * s * (1 - s)))),
                mu=float(c["max_friction_ratio"]),
                torque_limit=float(c["max_abs_torque"]) if np.ndim(gait.options.torque_limit)
                == 0 else tuple(float(v) for v in c["max_abs_torques"]))


def _each(fn, *bounds):
    """``fn`` of numbers, or torque by torque of per-torque bounds (tuples)."""
    if np.ndim(bounds[0]) == 0:
        return fn(*bounds)
    return tuple(fn(*v) for v in zip(*bounds))


def gait_change(g_from, g_to) -> dict:
    """How far a gait moved from another (of the same robot).

    Parameters
    ----------
    g_from, g_to : Gait
        The two gaits.

    Returns
    -------
    dict
        ``speed``, ``step_length`` (m), ``T`` (s): each [from, to]; ``max_joint_change``:
        max over the joints and the normalised time s = t / T of ``|q_to(s) -
        q_from(s)|``, rad; ``max_velocity_change`` likewise for dq, rad/s.
    """
    s = np.linspace(0.0, 1.0, 201)
    q0, dq0, _ = g_from.evaluate(s * g_from.T)
    q1, dq1, _ = g_to.evaluate(s * g_to.T)
    return dict(speed=[float(g_from.speed), float(g_to.speed)],
                step_length=[float(g_from.step_length), float(g_to.step_length)],
                T=[float(g_from.T), float(g_to.T)],
                max_joint_change=float(np.max(np.abs(q1 - q0))),
                max_velocity_change=float(np.max(np.abs(dq1 - dq0))))


def optimal_options(gait, targets: dict) -> GaitOptions:
    """The options of the toolkit's optimal gait for a given gait (an infinite effort
    weight): the gait's options with the targets, in the toolkit's own Bezier degree.

    An imported gait's Bezier degree is the one that fits its samples best
    (:func:`gait_opt.import_gait`), not a design choice; the optimal gait is the toolkit's
    (the default co-design's gait is of the default degree).

    Parameters
    ----------
    gait : Gait
        The given gait.
    targets : dict
        GaitOptions fields (the robust gait constraints).

    Returns
    -------
    GaitOptions
    """
    return gait.options.replace(**targets, bezier_degree=GaitOptions().bezier_degree)


def continue_gait(gait, speed: float) -> Gait:
    """The gait at another speed, by continuation from ``gait`` (a neighbour's design gait).

    The toolkit's optimal gait under ``gait``'s own options (its robust gait constraints,
    torque and friction bounds) at ``speed``, warm-started from ``gait``
    (:func:`gait_opt.optimize_gait`); faster than ``gait``, its step length is held at
    most ``gait``'s, so that the speed rises by cadence.  Along the default family the
    optimiser lengthens the step and leans the torso forward as the speed rises (RABBIT,
    largest lean over the step: 0.94 rad at 1.1 m/s, 1.19 rad at 1.15 m/s) until, at
    1.2 m/s, the optimum leans it past the horizontal (2.10 rad; the simulator's fall
    bound is pi/2, :func:`analysis.gait_metrics.torso_fall`), from which no controller
    walks; at 1.15 m/s's step length the 1.2 m/s gait leans at most 0.87 rad.

    Parameters
    ----------
    gait : Gait
        The gait continued from.
    speed : float
        The new speed, m/s.

    Returns
    -------
    Gait
        Polished to an exact orbit and checked on the dense grid (its
        ``solver_stats['continued_from']`` is ``gait``'s key).

    Raises
    ------
    ValueError
        Naming 'speed' when it is not a positive finite number.
    gait_opt.GaitOptimizationError
        When the gait problem at that speed has no solution from ``gait``.
    """
    if isinstance(speed, bool) or not isinstance(speed, (int, float, np.floating)) \
            or not math.isfinite(speed) or speed <= 0:
        raise ValueError(f"speed must be a positive number (m/s), got {speed!r}")
    opts = gait.options.replace(speed=float(speed))
    if speed > gait.speed:
        lo, hi = opts.step_length_bounds
        opts = opts.replace(step_length_bounds=(lo, max(lo, min(hi, gait.step_length))))
    g2 = optimize_gait(gait.model, opts, warm_start=gait)
    g2.solver_stats.update(continued_from=gait.cache_key)
    return g2


def _optimal(gait, targets: dict, own: dict, tgt: dict) -> GaitMove:
    """The effort alone (an infinite effort weight): the toolkit's optimal gait under the
    gait's options with the targets (:func:`optimal_options`), at its speed, warm-started
    from it when it is of the same Bezier degree (:func:`gait_opt.optimize_gait`, exact
    Hessian)."""
    opts = optimal_options(gait, targets)
    same = opts.bezier_degree == gait.options.bezier_degree
    try:
        g2 = optimize_gait(gait.model, opts, warm_start=gait if same else None)
    except GaitOptimizationError as e:
        return GaitMove("kept", f"no optimal gait under the robust gait constraints ({e})",
                        own, tgt, own, [dict(effort=math.inf, nlp_status=str(e.status))],
                        gait=gait)
    change = gait_change(gait, g2)
    return GaitMove("moved", f"the optimal gait at {gait.speed:.3g} m/s under the gait's "
                    f"options and {targets}, Bezier degree {opts.bezier_degree} (gait_opt"
                    f"{', warm-started from the given gait' if same else ''}); "
                    f"T {change['T'][0]:.4g} -> {change['T'][1]:.4g} s, step length "
                    f"{change['step_length'][0]:.4g} -> {change['step_length'][1]:.4g} m, "
                    f"joints moved by at most {change['max_joint_change']:.3g} rad", own,
                    tgt, own_values(g2), [dict(effort=math.inf, nlp_status=g2.solver_stats.get(
                        "status", ""), iterations=g2.solver_stats.get("iterations", 0))],
                    change, gait=g2)


class GaitProjection(GaitTable):
    """The gait nearest a reference gait under the constraints of ``gait.options``.

    The NLP in G = (alpha, T, r0): minimise sum ((G - G_ref) / scale)^2 under the gait's
    own rows (:meth:`GaitTable._gait_rows`); the interface of
    :class:`~analysis.design.codesign.reduced.Reduced` that
    :func:`~analysis.design.codesign.reduced.solve_nlp` solves.

    Parameters
    ----------
    gait : Gait
        A gait whose options are the constraints (its parameters are not used).
    reference : numpy.ndarray
        G_ref.
    scale : array_like
        (alpha, T, r0) units of the distance.
    settings : TranscriptionSettings, optional
        The grid of the rows.
    """

    def __init__(self, gait, reference, scale, settings: TranscriptionSettings | None = None,
                 effort: float = 0.0):
        super().__init__(gait.model, gait, settings, True)
        self.n_max = self.N            # the rows need the table on [0, T] only
        self.nd = self.nG
        self.ref = np.asarray(reference, float)
        self.effort = float(effort)
        # Simpson's weights on the half-grid s_i = i / 2N of [0, 1]
        n = 2 * self.N
        sw = np.ones(n + 1)
        sw[1:-1:2], sw[2:-1:2] = 4.0, 2.0
        self.simpson = sw / (3 * n)
        self.effort0 = None
        if self.effort:
            self.effort0 = self._effort(self.table(self.ref))[0]
        w = np.empty(self.nG)
        w[:self.na], w[self.na], w[self.na + 1:] = scale[0], scale[1], scale[2]
        self.weight = 1.0 / w**2
        self.evaluations = 0
        self._last = None

    def evaluate(self, d):
        """(f, grad f, g, dg/dd, lo, hi) at G = d (kept for the last d)."""
        d = np.asarray(d, float)
        if self._last is not None and np.array_equal(self._last[0], d):
            return self._last[1]
        self.evaluations += 1
        e = d - self.ref
        f, grad = float(np.sum(self.weight * e**2)), 2 * self.weight * e
        rows = _Rows()
        try:
            tab = self.table(d)
            if self.effort:
                E, dE = self._effort(tab)
                f += self.effort * E / self.effort0
                grad = grad + self.effort * dE / self.effort0
            self._gait_rows(rows, d, tab)
            self._end_rows(rows, tab)
            g, lo, hi, ri, ci, vals = rows.stack()
            J = np.zeros((g.size, self.nd))
            np.add.at(J, (ri, ci), vals)
            self._shape = (g.size, lo, hi)
        except (RuntimeError, ValueError, FloatingPointError):
            n, lo, hi = self._shape
            g, J = np.full(n, np.nan), np.full((n, self.nd), np.nan)
        res = (f, grad, g, J, lo, hi)
        self._last = (d.copy(), res)
        return res

    def _effort(self, tab):
        """int_0^1 u'u ds of the nominal step (Simpson) and its gradient in G."""
        n = 2 * self.N + 1
        u, du = tab["nominal"][:self.nu, :n], tab["dnominal"][:self.nu, :, :n]
        E = float(np.sum(self.simpson * np.sum(u**2, axis=0)))
        dE = 2 * np.einsum("in,ign,n->g", u, du, self.simpson)
        return E, dE

    def _end_rows(self, rows, tab):
        """Torque, normal force and friction at both ends of the step too (the gait's
        rows hold them inside; the dense-grid check includes the ends)."""
        o, nu, G = self.gait.options, self.nu, self.i_G
        idx = np.array([0, 2 * self.N])
        nom, dnom = tab["nominal"][:, idx], tab["dnominal"][:, :, idx]
        U = self.torque_bound(idx.size)
        rows.add(nom[:nu].T.ravel(), dnom[:nu].transpose(2, 0, 1).reshape(-1, self.nG), G,
                 -U, U, "gait torque limit")
        Fx, Fz, dFx, dFz = nom[nu], nom[nu + 1], dnom[nu], dnom[nu + 1]
        rows.add(Fz, dFz.T, G, o.min_normal_force, np.inf, "gait normal force")
        rows.add(np.r_[o.mu * Fz - Fx, o.mu * Fz + Fx], np.vstack([(o.mu * dFz - dFx).T,
                                                                  (o.mu * dFz + dFx).T]),
                 G, 0.0, np.inf, "gait friction cone")

    def distance(self, d) -> float:
        """The weighted distance of G = d to the reference."""
        return float(np.sqrt(np.sum(self.weight * (np.asarray(d) - self.ref) ** 2)))


def _relaxed(gait) -> dict:
    """Option changes that make the gait meet its own options where it does not (an
    imported gait is not held to them)."""
    o, c, m = gait.options, gait.check(), gait.model
    out = {}
    if np.ndim(o.torque_limit) == 0 and c["max_abs_torque"] > o.torque_limit:
        out["torque_limit"] = float(c["max_abs_torque"]) + 1e-6
    elif np.ndim(o.torque_limit) and np.any(np.greater(c["max_abs_torques"], o.torque_limit)):
        out["torque_limit"] = _each(lambda p, u: max(u, p + 1e-6), tuple(c["max_abs_torques"]),
                                    o.torque_limit)
    if c["max_friction_ratio"] > o.mu:
        out["mu"] = float(c["max_friction_ratio"]) + 1e-6
    if c["min_normal_force"] < o.min_normal_force:
        out["min_normal_force"] = max(float(c["min_normal_force"]) - 1e-6, 0.0)
    if c["liftoff_velocity"] < o.min_liftoff_speed:
        out["min_liftoff_speed"] = max(float(c["liftoff_velocity"]) - 1e-6, 0.0)
    if -c["strike_velocity"] < o.min_strike_speed:
        out["min_strike_speed"] = max(-float(c["strike_velocity"]) - 1e-6, 0.0)
    if m.has_knees:
        if c["max_stance_knee"] > o.stance_knee_max:
            out["stance_knee_max"] = float(np.max(gait.alpha[[i - 1 for i in m.stance_knees]]))
        if c["min_swing_knee"] < o.swing_knee_min:
            out["swing_knee_min"] = float(np.min(gait.alpha[[i - 1 for i in m.swing_knees]]))
    lo, hi = o.step_length_bounds
    if not lo <= gait.step_length <= hi:
        out["step_length_bounds"] = (min(lo, gait.step_length * 0.99),
                                     max(hi, gait.step_length * 1.01))
    lo, hi = o.step_time_bounds
    if not lo <= gait.T <= hi:
        out["step_time_bounds"] = (min(lo, gait.T * 0.99), max(hi, gait.T * 1.01))
    return out


class _Move:
    """One move of a gait: its bounds from the gait's own values to the targets, and the
    solves at a fraction of the way (records kept)."""

    def __init__(self, gait, targets: dict, ms: MoveSettings, transcription):
        self.gait, self.ms, self.tst = gait, ms, transcription
        self.own = own_values(gait)
        self.base = gait.options.replace(**_relaxed(gait), **{
            k: v for k, v in targets.items() if k not in CONTINUED})
        # the continued constraints: those of the targets, and margins on the path's
        # friction ratio and torques (a gait at the cone's edge or the torque limit slips
        # or saturates under the smallest perturbation)
        b = self.base
        self.tgt = dict(impact_mu=float(targets.get("impact_mu", b.impulse_mu)),
                        clearance=float(targets.get("clearance", b.clearance)),
                        mu=min(float(ms.path_mu), b.mu),
                        torque_limit=_each(lambda u: float(ms.torque_fraction * u),
                                           b.torque_limit))
        own, tgt = self.own, self.tgt
        self.start = {k: (min(max(own[k], 0.0), tgt[k]) if k == "clearance"
                          else _each(max, own[k], tgt[k])) for k in tgt}
        self.G_user = GaitTable(gait.model, gait, transcription).gait_vector(gait)
        self.records = []

    def bounds_at(self, f: float) -> dict:
        """The continued constraints' bounds at fraction f of the way (a bound that
        does not move stays as it is: an infinite torque limit stays infinite)."""
        return {k: _each(lambda a, b: a if a == b else a + f * (b - a), self.start[k],
                         self.tgt[k]) for k in self.tgt}

    def attempt(self, f: float, d_from, effort: float):
        """One solve at the bounds of fraction f from d_from: (G, gait) or None."""
        ms, g, b = self.ms, self.gait, self.bounds_at(f)
        solve_opts = self.base.replace(
            impact_mu=max(b["impact_mu"] - ms.impulse_margin, 1e-3),
            clearance=b["clearance"] + ms.clearance_margin, mu=b["mu"] - ms.friction_margin,
            torque_limit=_each(lambda u: u - ms.torque_margin, b["torque_limit"]))
        nlp = GaitProjection(Gait(g.model, solve_opts, g.alpha, g.x0, g.T), self.G_user,
                             ms.scale, self.tst, effort)
        lb, ub = nlp.gait_bounds()
        try:
            res = solve_nlp(nlp, np.clip(d_from, lb, ub), lb, ub,
                            {"max_iter": ms.max_iter, "tol": 1e-8})
            ok = res.success and np.all(np.isfinite(res.d))
        except NoStrikeAtStart:
            res, ok = None, False
        rec = dict(fraction=f, effort=effort, **b,
                   nlp_status=res.status if res else "not_evaluable",
                   iterations=res.iterations if res else 0)
        self.records.append(rec)
        if not ok:
            return None
        rec["distance"] = nlp.distance(res.d)
        step = gait_step(Gait(g.model, self.base.replace(**b), g.alpha, g.x0, g.T), res.d,
                         res.status)
        if step.gait is None:
            rec["rejected"] = step.rejected
            return None
        return res.d, step.gait

    def run(self):
        """(the moved gait or None, the fraction of the way reached)."""
        ms = self.ms
        # 1. straight to the targets with the effort term (one solve when it goes)
        got = self.attempt(1.0, self.G_user, ms.effort) if ms.effort else None
        if got is not None:
            return got[1], 1.0
        # an effort term IPOPT did not solve in its iteration budget is not tried again
        # from the nearest gait (measured: where the first ran out of iterations, the
        # second did too, 200 iterations of a degree-12 import in vain)
        effort = ms.effort if not (ms.effort and self.records[-1]["nlp_status"] ==
                                   "Maximum_Iterations_Exceeded") else 0.0
        # 2. the nearest gait, by continuation from the gait's own values (a failed step
        # halved), then the effort term from there
        d, step, halvings, f_done, last = self.G_user.copy(), 1.0 / ms.steps, 0, 0.0, None
        while f_done < 1.0 - 1e-12:
            f = min(1.0, f_done + step)
            got = self.attempt(f, d, 0.0)
            if got is not None:
                (d, last), f_done = got, f
                continue
            if halvings >= ms.halvings:
                break
            step, halvings = step / 2, halvings + 1
        if last is not None and effort:
            got = self.attempt(f_done, d, effort)
            if got is not None:
                last = got[1]
        return last, f_done

    def message(self, f_done: float, change: dict) -> str:
        """The move in words."""
        own, b = self.own, self.bounds_at(f_done)
        return (f"gait moved to impulse ratio <= {b['impact_mu']:.3g} (the given gait "
                f"{own['impact_mu']:.3g}), swing-foot clearance >= {b['clearance']:.3g} m "
                f"(given {own['clearance']:.3g}), friction ratio <= {b['mu']:.3g} (given "
                f"{own['mu']:.3g}), {_torques_text(b['torque_limit'], own['torque_limit'])} in "
                f"{len(self.records)} solve(s)"
                + ("" if f_done >= 1.0 - 1e-12 else
                   f", {100 * f_done:.0f} % of the way to the targets")
                + f"; T {change['T'][0]:.4g} -> {change['T'][1]:.4g} s, step length "
                f"{change['step_length'][0]:.4g} -> {change['step_length'][1]:.4g} m, joints "
                f"moved by at most {change['max_joint_change']:.3g} rad")


@task
def move_gait(gait, targets: dict, settings: MoveSettings,
              transcription: TranscriptionSettings) -> GaitMove:
    """The gait nearest ``gait`` that meets the robust gait constraints (module docstring).

    Parameters
    ----------
    gait : Gait
        The user's gait.
    targets : dict
        GaitOptions fields: ``impact_mu`` and ``clearance`` are reached by continuation,
        the others (``continuation``, ...) are set at once.
    settings : MoveSettings
        The continuation (its defaults filled in for the gait's robot:
        :meth:`MoveSettings.for_model`).
    transcription : TranscriptionSettings
        The grid of the gait's rows (and the torque limit).

    Returns
    -------
    GaitMove
    """
    if gait.model.scuffing_ignored:
        return GaitMove("kept", "the gait is kept: its swing foot may pass below the ground "
                        "(legs without knees), which the gait rows of the move do not "
                        "model", {}, dict(targets), {}, gait=gait)
    settings = settings.for_model(gait.model)
    mv = _Move(gait, targets, settings, transcription)
    own, tgt = mv.own, mv.tgt
    if all(np.all(np.abs(np.subtract(mv.start[k], tgt[k])) < 1e-12) for k in tgt):
        moved = Gait(gait.model, mv.base.replace(**tgt), gait.alpha, gait.x0, gait.T,
                     solver_stats=dict(gait.solver_stats))
        return GaitMove("kept", "the gait meets the robust gait constraints already",
                        own, tgt, own_values(moved), change=gait_change(gait, moved),
                        gait=moved)
    if np.isinf(settings.effort):
        return _optimal(gait, targets, own, tgt)
    last, f_done = mv.run()
    if last is None:
        first = mv.records[0].get("rejected", mv.records[0]["nlp_status"])
        return GaitMove("kept", "the gait could not be moved toward the robust gait "
                        f"constraints (first step: {first})", own, tgt, own, mv.records,
                        gait=gait)
    last.solver_stats.update(moved_from=gait.cache_key, move_fraction=f_done)
    change = gait_change(gait, last)
    return GaitMove("moved" if f_done >= 1.0 - 1e-12 else "partly",
                    mv.message(f_done, change), own, tgt, own_values(last), mv.records,
                    change, gait=last)


def _torques_text(bound, own) -> str:
    """The torque bound and the given gait's peak torques in words: ``'torques <= 120 N m
    (given 130)'``, per torque ``'16/32/32/16'``; ``'no torque limit (largest 30.72 N
    m)'`` where no torque has one."""
    if not np.any(np.isfinite(bound)):
        return f"no torque limit (largest {torque_bound_text(own, '.4g')} N m)"
    return f"torques <= {torque_bound_text(bound, '.4g')} N m (given " \
           f"{torque_bound_text(own, '.4g')})"
