"""The stepping kernel every simulator shares: one diagnostics schema, one strike test,
one refinement of the impact time.

Diagnostics.  At every integration node a simulator logs one column of named rows
(:class:`Diagnostics`): the torques u, optionally the outputs y and their rates dy, the
controller's decoupling denominator ``den`` (eq. 24 for the time-varying controller),
the stance reaction ``Fx``, ``Fz``, ``in_range`` (0 where the controller's reference is
undefined), the swing foot ``xsw``, ``zsw``, ``dzsw``, the hip height ``hip`` and the torso
angle ``torso``, and (full order) ``saturated``: 1 where the commanded torque was clipped at
the limit (``SimulationOptions.saturate``).  :mod:`biped_casadi.simulation.validity` checks
them by name.

Strike.  The swing foot strikes between two nodes when it crosses the ground going down
in front of the stance foot (beyond ``model.scuff_zone``): z_sw(previous) >= 0 > z_sw
(:func:`strike`).  The impact time inside that RK4 interval is the length eta of the last
RK4 step with z_sw(RK4(x_k, eta)) = 0, found by a safeguarded Newton iteration
(:func:`locate_strike`), vectorised over scenarios: the event is exact to round-off for
the discrete scheme.

Terrain.  On uneven ground (:mod:`biped_casadi.simulation.terrain`) the one parameter
``ground = (ahead, behind)`` says where the ground is under the swing foot: at ``ahead``
in front of the stance foot (the height of this step's foothold) and at ``behind``
behind it; :func:`strike` and the validity conditions measure z_sw from there
(:func:`ground_height`), and the impact time solves z_sw = ``ahead``.
"""
from __future__ import annotations

import os

import casadi as ca
import numpy as np

__all__ = ["Diagnostics", "strike", "locate_strike", "locate_minimum", "foot_may_dip",
           "swing_foot_dip",
           "SCREEN_SAFETY", "screen_steps", "screen_far", "minima_between", "SUB_STEPS",
           "SAMPLED_TOL", "minima_sampled", "golden_minimum", "mapped", "threads",
           "NEWTON_ITERATIONS", "ground_height", "CHUNKS_PER_STEP"]

#: CasADi calls per reference step duration T of the simulators' integration: each call
#: integrates a quarter of T (the Poincaré section 0.75 T falls on a boundary); RK4 steps
#: per T are a multiple of 8
CHUNKS_PER_STEP = 4

#: a step's output is refined (its rates at both nodes, its minimum located) where its
#: lower node value less this many times the bound c'' h^2 / 8 on a dip inside the step
#: (c'' from the second differences of the nodes around) is below its bound
SCREEN_SAFETY = 2.0

#: equal parts of a flagged RK4 step at which :func:`minima_sampled` takes the outputs (a
#: law without derivatives: the compiled closed loop)
SUB_STEPS = 16

#: :func:`minima_sampled` locates a minimum to this fraction of the RK4 step
SAMPLED_TOL = 1e-9

#: most Newton iterations of :func:`locate_strike` (it stops at ``|z_sw| < 1e-15`` m, usually
#: after 3 to 5)
NEWTON_ITERATIONS = 60


class Diagnostics:
    """The per-node diagnostics rows of a simulator, by name.

    Parameters
    ----------
    nu : int
        Number of torques.
    outputs : bool
        Whether the rows carry the controller's outputs y, their rates dy, ``in_range``
        and ``saturated`` (the full-order simulator's; on a zero dynamics the outputs
        vanish, the reference is defined everywhere and the torques are the law's, so
        they are left out).
    """

    SCALARS = ("den", "Fx", "Fz", "xsw", "zsw", "dzsw", "hip", "torso")

    def __init__(self, nu: int, outputs: bool = True):
        self.nu, self.outputs = nu, outputs
        blocks = [("u", nu)] + ([("y", nu), ("dy", nu)] if outputs else [])
        self.index, row = {}, 0
        for name, n in blocks:
            self.index[name] = slice(row, row + n)
            row += n
        self.scalars = self.SCALARS + (("in_range", "saturated") if outputs else ())
        for name in self.scalars:
            self.index[name] = row
            row += 1
        #: number of rows
        self.size = row

    def vector(self, model, q, dq, u, Fx, Fz, den, y=None, dy=None, in_range=1, saturated=0):
        """The diagnostics column at a state (CasADi).

        Parameters
        ----------
        model : BipedModel
            The robot (kinematics of the swing foot, hip and torso).
        q, dq : casadi
            Configuration and velocity.
        u : casadi
            Torques (nu).
        Fx, Fz : casadi
            Stance reaction, N.
        den : casadi
            The controller's decoupling denominator.
        y, dy : casadi, optional
            Outputs and rates (with ``outputs``).
        in_range : casadi or int
            1 while the controller's reference is defined.
        saturated : casadi or int
            1 where the commanded torque was clipped at the limit.

        Returns
        -------
        casadi.SX
            (size,) column in the order of :attr:`index`.
        """
        xs, zs = model.swing_foot(q)
        _, dzs = model.swing_foot_velocity(q, dq)
        parts = [u] + ([y, dy] if self.outputs else [])
        return ca.vertcat(*parts, den, Fx, Fz, xs, zs, dzs, model.points(q)[1, model.hip_index],
                          model.torso_angle(q),
                          *([in_range, saturated] if self.outputs else []))

    def row(self, D, name):
        """Row(s) ``name`` of diagnostics ``D`` (rows along the first axis).

        Parameters
        ----------
        D : numpy.ndarray
            (size, ...) diagnostics.
        name : str
            A row's name (:attr:`index`).

        Returns
        -------
        numpy.ndarray
        """
        return D[self.index[name]]

    def rows(self, D, finite=None) -> dict:
        """The named rows of diagnostics, as :func:`validity.node_violations` reads them.

        Parameters
        ----------
        D : numpy.ndarray
            (size, ...) diagnostics.
        finite : numpy.ndarray, optional
            Whether the states are finite (default: the diagnostics are).

        Returns
        -------
        dict
            'finite', 'u' and every scalar row by name.
        """
        out = {name: D[self.index[name]] for name in self.scalars}
        out["u"] = D[self.index["u"]]
        fin = np.all(np.isfinite(D), axis=0)
        out["finite"] = fin if finite is None else fin & finite
        return out


def ground_height(x_sw, ground=None):
    """The height of the ground under the swing foot, above the stance foot.

    Parameters
    ----------
    x_sw : array_like
        Swing-foot position ahead of the stance foot, m.
    ground : tuple, optional
        (ahead, behind): the ground in front of the stance foot (x_sw > 0) and behind
        it, m, each broadcastable against ``x_sw``; None: flat (0).

    Returns
    -------
    numpy.ndarray or float
        0 for flat ground.
    """
    if ground is None:
        return 0.0
    ahead, behind = ground
    with np.errstate(invalid="ignore"):
        return np.where(np.asarray(x_sw) > 0, ahead, behind)


def strike(z, z_prev, x_sw, scuff_zone: float, ground=None):
    """Where the swing foot strikes the ground between a node and the one before.

    It crosses the ground going down (z_sw at the previous node >= 0 > z_sw, both
    measured from the ground under the foot at the node) in front of the stance foot,
    beyond ``scuff_zone`` (docs: theory §4).

    Parameters
    ----------
    z, z_prev : array_like
        Swing-foot height at the nodes and at the nodes before, m (above the stance
        foot).
    x_sw : array_like
        Swing-foot position ahead of the stance foot at the nodes, m.
    scuff_zone : float
        ``model.scuff_zone``: a strike nearer the stance foot does not count, m.
    ground : tuple, optional
        (ahead, behind) ground heights (:func:`ground_height`); None: flat.

    Returns
    -------
    numpy.ndarray of bool
        True at the nodes where the foot strikes.
    """
    if ground is not None:
        g = ground_height(x_sw, ground)
        z, z_prev = np.asarray(z) - g, np.asarray(z_prev) - g
    with np.errstate(invalid="ignore"):
        return (np.asarray(z) < 0) & (np.asarray(x_sw) > scuff_zone) & (np.asarray(z_prev) >= 0)


def locate_strike(event, h: float, z_a, z_b):
    """The length eta in (0, h] of the last RK4 step that ends on the ground, z_sw = 0.

    Safeguarded Newton, vectorised over scenarios: a bracket [lo, hi] around the root
    (z_sw > 0 at lo), the Newton step where it stays inside, bisection otherwise; a
    scenario stops when ``|z_sw| < 1e-15`` m or its step is below 1e-17 s.

    Parameters
    ----------
    event : callable
        ``event(eta) -> (z_sw, dz_sw/deta)``, arrays (n,) for the n scenarios' last steps
        of lengths eta (n,).
    h : float
        The RK4 step, s.
    z_a, z_b : array_like
        (n,) z_sw at the node before the strike and at the strike's node, m.

    Returns
    -------
    numpy.ndarray
        (n,) eta, s.
    """
    z_a, z_b = np.atleast_1d(np.asarray(z_a, float)), np.atleast_1d(np.asarray(z_b, float))
    n = z_a.size
    lo, hi = np.zeros(n), np.full(n, h)
    with np.errstate(invalid="ignore", divide="ignore"):
        eta = np.where(z_a > z_b, h * z_a / (z_a - z_b), h)
    active = np.ones(n, bool)
    for _ in range(NEWTON_ITERATIONS):
        z, dz = (np.asarray(v, float).ravel() for v in event(eta))
        lo = np.where(active & (z > 0), eta, lo)
        hi = np.where(active & ~(z > 0), eta, hi)
        found = active & (np.abs(z) < 1e-15)
        active &= ~found
        with np.errstate(invalid="ignore", divide="ignore"):
            new = np.where(dz != 0, eta - z / dz, 0.5 * (lo + hi))
        new = np.where((lo < new) & (new < hi), new, 0.5 * (lo + hi))
        small = active & (np.abs(new - eta) < 1e-17)
        eta = np.where(active, new, eta)
        active &= ~small
        if not active.any():
            break
    return eta


def locate_minimum(rate, h: float, r_a: float, r_b: float, curvature=None):
    """The length eta in (0, h) of the last RK4 step that ends at an output's minimum.

    The output's rate goes from ``r_a`` <= 0 at the step's first node to ``r_b`` > 0 at its
    last: the minimum is the root of the rate, found by :func:`locate_strike` on the
    rate's negative.  At ``r_a`` = 0 (at rest at the node) there is a minimum inside only
    where the rate's slope there is negative.

    Parameters
    ----------
    rate : callable
        ``rate(eta) -> (r, dr/deta)``, arrays (1,): the output's rate in eta at the end of
        the last RK4 step of length eta, and its derivative.
    h : float
        The RK4 step, s.
    r_a, r_b : float
        The rates at the step's nodes.
    curvature : callable, optional
        ``curvature() -> dr/deta`` at eta = 0 (needed only where ``r_a`` = 0).

    Returns
    -------
    float or None
        eta, s; None where ``r_a`` = 0 and the output does not go down first.
    """
    if r_a == 0:
        c = float(curvature())
        if not c < 0:
            return None
        r_a = 0.5 * c * h                               # the Newton's first guess only

    def event(eta):
        r, dr = rate(eta)
        return -np.ravel(r), -np.ravel(dr)

    return float(locate_strike(event, h, -r_a, -r_b)[0])


def screen_steps(W, bounds) -> np.ndarray:
    """Which outputs may go below their bounds inside each step between consecutive
    nodes, from the nodes' values alone.

    An output c that dips inside a step of length h goes below its lower node value by at
    most max |c''| h^2 / 8; c'' h^2 is estimated by the second differences of the nodes
    around: centred on the step's first node and on the one before, and their linear
    extrapolation to the step's end; for a step without a node before it (the first, or
    after NaN rows: the nodes of a batch padded with them), centred on its last node and
    the one after, and their extrapolation back to its start.  A step is flagged where
    its lower node value less :data:`SCREEN_SAFETY` times that bound is below the bound,
    and where no estimate can be made (fewer than three nodes, or a NaN); an output
    above its bound by 3 max |c''| h^2 (over its nodes, NaN left out) at every node has
    no step flagged.  An estimate, not a proof: it holds while c'' changes by less than
    that factor over three steps.

    Parameters
    ----------
    W : array_like
        (n, ...): the outputs at n >= 2 consecutive nodes (axis 0), the last axis the m
        outputs.
    bounds : array_like
        (m,) the outputs' lower bounds.

    Returns
    -------
    numpy.ndarray of bool
        (n - 1, ...): per step (from node i to i + 1), per output.
    """
    W = np.asarray(W, float)
    if W.shape[0] < 3:
        return np.ones((W.shape[0] - 1,) + W.shape[1:], bool)
    far = screen_far(W, bounds)
    if far.all():
        return np.zeros((W.shape[0] - 1,) + W.shape[1:], bool)
    if far.any():                               # the full screen where it may matter
        out = np.zeros((W.shape[0] - 1,) + W.shape[1:], bool)
        near = ~far
        out[:, near] = screen_steps(W[:, near], np.broadcast_to(bounds, far.shape)[near])
        return out
    d1 = W[2:] - 2 * W[1:-1] + W[:-2]           # c'' h^2 centred on nodes 1 .. n - 2
    back = np.full((W.shape[0] - 1,) + W.shape[1:], np.nan)
    fwd = back.copy()
    back[1:] = np.abs(d1)                        # step i: on its first node i ...
    back[2:] = np.fmax(np.fmax(back[2:], np.abs(d1[:-1])),   # ... and on node i - 1
                       np.abs(2 * d1[1:] - d1[:-1]))
    fwd[:-1] = np.abs(d1)                        # step i: on its last node i + 1 ...
    fwd[:-2] = np.fmax(np.fmax(fwd[:-2], np.abs(d1[1:])),    # ... and on node i + 2
                       np.abs(2 * d1[:-1] - d1[1:]))
    curv = np.where(np.isnan(back), fwd, back)
    with np.errstate(invalid="ignore"):          # NaN: flagged
        return ~(np.minimum(W[:-1], W[1:]) - (SCREEN_SAFETY / 8) * curv >= bounds)


def screen_far(W, bounds, axis: int = 0) -> np.ndarray:
    """Which outputs :func:`screen_steps` flags in none of the steps between their nodes.

    Every estimate of the screen is at most 3 max |c''| h^2 over the nodes (the second
    differences' largest, NaN left out), so an output above its bound by
    :data:`SCREEN_SAFETY` / 8 times that at every node is far from it in every step.

    Parameters
    ----------
    W : array_like
        The outputs at n >= 3 consecutive nodes along ``axis``.
    bounds : array_like
        Their lower bounds, broadcastable to W without ``axis``.
    axis : int
        The nodes' axis.

    Returns
    -------
    numpy.ndarray of bool
        W's shape without ``axis``: True where no step can be flagged.
    """
    W = np.asarray(W, float)
    with np.errstate(invalid="ignore"):
        return np.fmin.reduce(W, axis=axis) - (3 * SCREEN_SAFETY / 8) * np.fmax.reduce(
            np.abs(np.diff(W, 2, axis=axis)), axis=axis) >= bounds


def _flat(v) -> np.ndarray:
    return np.array(v, float).ravel()


def minima_between(near, r_a, r_b, between, h: float) -> list:
    """The minima inside one RK4 step of the outputs flagged ``near``.

    An output whose rate goes from <= 0 at the step's first node to > 0 at its last has
    a minimum in between (where the rate is 0 at the first node, its slope there says
    whether it goes down first), found by :func:`locate_minimum`.

    Parameters
    ----------
    near : array_like of bool
        (m,) the outputs to look at (:func:`screen_steps`).
    r_a, r_b : array_like
        (m,) the outputs' rates at the step's nodes.
    between : callable
        ``between(eta) -> (W, dW/deta, d2W/deta2)``, each (m,): the outputs at the end of
        the last RK4 step of length eta from the step's first node.
    h : float
        The step, s.

    Returns
    -------
    list of tuple
        (eta, output index, value), by eta.
    """
    found = []
    for j in np.flatnonzero(np.asarray(near) & (r_a <= 0) & (r_b > 0)):
        def rate(eta_, j=j):
            _, dw, ddw = between(float(eta_[0]))
            return _flat(dw)[j:j + 1], _flat(ddw)[j:j + 1]

        eta = locate_minimum(rate, h, r_a[j], r_b[j], lambda j=j: _flat(between(0.0)[2])[j])
        if eta is not None:
            found.append((eta, int(j), float(_flat(between(eta)[0])[j])))
    return sorted(found)


def golden_minimum(f, a: float, b: float, tol: float):
    """The minimum of ``f`` on [a, b] by golden-section search, from values alone.

    The bracket shrinks by the golden ratio per evaluation, keeping the lower of its two
    inner points, until it is at most ``tol`` wide (f unimodal on [a, b]; where f is
    lowest at an end, the bracket closes on that end and keeps it).

    Parameters
    ----------
    f : callable
        ``f(x) -> float``.
    a, b : float
        The interval, a < b.
    tol : float
        The final bracket's width.

    Returns
    -------
    tuple
        (x, f(x), (lo, hi)): the lowest point found and the final bracket.
    """
    g = 0.5 * (np.sqrt(5.0) - 1.0)
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = f(c), f(d)
    while b - a > tol:
        if fc <= fd:                                    # the minimum is in [a, d]
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = f(c)
        else:                                           # ... in [c, b]
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = f(d)
    return (c, fc, (a, b)) if fc <= fd else (d, fd, (a, b))


def minima_sampled(near, between, h: float, first, last, samples: int = SUB_STEPS) -> list:
    """The minima inside one RK4 step of the outputs flagged ``near``, from values alone.

    For a law without derivatives (:func:`minima_between` takes the rates).  The outputs
    are taken at ``samples`` equal parts of the step (the RK4 step of length eta = i h /
    samples from its first node); each output's parts are screened as the steps are
    (:func:`screen_steps` on the samples, the first part by the samples after it).  A
    flagged part's minimum is located by :func:`golden_minimum`, to :data:`SAMPLED_TOL`
    h, on the two parts beside its lower end where that sample is the lowest of its
    neighbours, else on the part itself; a minimum is one where the final bracket keeps
    off both ends of the one searched (at a node, the lowest point is that node's,
    checked there, as where the rate has no root inside).

    Parameters
    ----------
    near : array_like of bool
        (m,) the outputs to look at (:func:`screen_steps`).
    between : callable
        ``between(eta) -> W`` (m,): the outputs at the end of the last RK4 step of length
        eta from the step's first node.
    h : float
        The step, s.
    first, last : array_like
        (m,) the outputs at the step's nodes.
    samples : int
        Equal parts of the step.

    Returns
    -------
    list of tuple
        (eta, output index, value), by eta.
    """
    near = np.flatnonzero(near)
    if near.size == 0:
        return []
    etas = np.linspace(0.0, h, samples + 1)
    V = np.array([_flat(first)] + [_flat(between(e)) for e in etas[1:-1]] + [_flat(last)])
    found = []
    for i in near:
        s = V[:, i:i + 1]
        parts = screen_steps(s, 0.0)[:, 0]
        parts[0] = screen_steps(s[::-1], 0.0)[-1, 0]    # the first part: the samples after
        brackets = set()
        for k in np.flatnonzero(parts):
            m = k + int(s[k + 1, 0] < s[k, 0])           # the part's lower end
            lowest = all(s[m, 0] <= s[n, 0] for n in (m - 1, m + 1) if 0 <= n <= samples)
            brackets.add((max(m - 1, 0), min(m + 1, samples)) if lowest else (k, k + 1))
        for a, b in sorted(brackets):
            eta, v, (lo, hi) = golden_minimum(lambda e, i=i: _flat(between(e))[i],
                                              etas[a], etas[b], SAMPLED_TOL * h)
            if etas[a] < lo and hi < etas[b]:
                found.append((float(eta), int(i), float(v)))
    return sorted(found)


def foot_may_dip(z_prev, dz_a, dz_b, dt, ground=None) -> np.ndarray:
    """Which steps between two nodes may hold a minimum of the swing foot below the ground.

    A minimum is where the foot's vertical velocity goes from dz_a <= 0 at a step's first
    node to dz_b > 0 at its last.  While that velocity stays above dz_a in the step (it
    rises to dz_b), the foot goes below its height at the first node by at most |dz_a| dt
    (dt the step's duration); a step is flagged where that height less
    :data:`SCREEN_SAFETY` times this is below the higher of the ground's two heights
    (:func:`ground_height`), or where any of them is NaN.  An estimate as
    :func:`screen_steps`: a foot's minimum a few centimetres above the ground is not
    refined.

    Parameters
    ----------
    z_prev, dz_a, dz_b : array_like
        Per step: the foot's height at its first node, its vertical velocity there and at
        its last node (m, m/s).
    dt : array_like
        The steps' durations, s (broadcastable against ``z_prev``).
    ground : tuple, optional
        (ahead, behind) ground heights, each broadcastable against ``z_prev``; None: flat.

    Returns
    -------
    numpy.ndarray of bool
        ``z_prev``'s shape: True where the step's minimum is to be located.
    """
    top = 0.0 if ground is None else np.maximum(ground[0], ground[1])
    with np.errstate(invalid="ignore"):
        low = np.asarray(z_prev) + SCREEN_SAFETY * np.asarray(dz_a) * dt
        return (np.asarray(dz_a) <= 0) & (np.asarray(dz_b) > 0) & ~(low >= top)


def swing_foot_dip(dip, h: float, step_start, z_prev, dz_a, dz_b, ground, scuff_zone: float,
                   scuffing_ignored: bool, tolerance: float, steps=None):
    """The first of the swing foot's minima between two nodes that is below the ground.

    The minima are in the steps where the foot's vertical velocity goes from <= 0 at the
    first node to > 0 at the last (:func:`locate_minimum`), those of them that may be below
    the ground (:func:`foot_may_dip`).  Below the ground (measured
    from the ground under the foot there, :func:`ground_height`) it is a 'strike' when
    the foot was above it at the step's first node and is beyond ``scuff_zone`` (it
    crossed the ground going down: the strike is the first root before the minimum),
    else 'scuffed' when more than ``tolerance`` below it, unless ``scuffing_ignored``.

    Parameters
    ----------
    dip : callable
        ``dip(X, tau, eta) -> (z_sw, dz/deta, d2z/deta2, x_sw, X_eta)`` at the end of the
        last RK4 step of length eta from the node (X, tau).
    h : float
        The RK4 step, s.
    step_start : callable
        ``step_start(j) -> (X, tau)``: the first node of step j.
    z_prev, dz_a, dz_b : numpy.ndarray
        Per step: the height at its first node, the vertical velocity there and at its
        last node (m, m/s; the steps to look at).
    ground : tuple or None
        (ahead, behind) ground heights (:func:`ground_height`).
    scuff_zone : float
        ``model.scuff_zone``, m.
    scuffing_ignored : bool
        ``model.scuffing_ignored``.
    tolerance : float
        How far below the ground the foot may graze, m.
    steps : array_like of bool, optional
        The steps to look at; default: :func:`foot_may_dip` with durations h.

    Returns
    -------
    tuple or None
        (j, 'strike' or 'scuffed', eta, z_sw, x_sw, X_eta) at the minimum.
    """
    if steps is None:
        steps = foot_may_dip(z_prev, dz_a, dz_b, h, ground)
    for j in np.flatnonzero(steps):
        Xa, ta = step_start(j)

        def rate(eta, Xa=Xa, ta=ta):
            return dip(Xa, ta, eta[0])[1:3]

        eta = locate_minimum(rate, h, dz_a[j], dz_b[j],
                             lambda Xa=Xa, ta=ta: np.ravel(dip(Xa, ta, 0.0)[2])[0])
        if eta is None:
            continue
        z, _, _, x, Xe = (np.ravel(v) for v in dip(Xa, ta, eta))
        z, x = float(z[0]), float(x[0])
        g = float(ground_height(x, ground))
        if not z < g:
            continue
        if z_prev[j] >= g and x > scuff_zone:
            return int(j), "strike", eta, z, x, Xe
        if not scuffing_ignored and z - g < -tolerance:
            return int(j), "scuffed", eta, z, x, Xe
    return None


def threads() -> int:
    """Threads a batched simulator maps its scenarios over: the cores, at most 8, or
    the environment variable ``BIPED_THREADS`` when set (1 in each process of a Dask
    cluster that already runs one task per core)."""
    env = os.environ.get("BIPED_THREADS", "").strip()
    if env.isdigit() and int(env) > 0:
        return min(int(env), 64)
    return max(1, min(os.cpu_count() or 1, 8))


def mapped(f: ca.Function, n: int) -> ca.Function:
    """``f`` mapped over n scenarios, on the machine's cores when n is large.

    Parameters
    ----------
    f : casadi.Function
        A Function of one scenario.
    n : int
        Scenarios.

    Returns
    -------
    casadi.Function
        ``f.map(n)``, threaded when n >= 4 threads.
    """
    k = threads()
    return f.map(n, "thread", k) if n >= 4 * k and k > 1 else f.map(n)


def call_batched(simd_kernels, mapped_of, name: str, *args) -> list:
    """A walker's Function ``name`` over scenarios (the columns of ``args``).

    Parameters
    ----------
    simd_kernels : dict or None
        The walker's SIMD kernels (:func:`biped_casadi.simd.kernels`), used when one is
        given for ``name``.
    mapped_of : callable
        ``mapped_of(name, n)``: the CasADi Function mapped over n scenarios, else.
    name : str
        Which Function.
    *args : array_like
        Its inputs: (n_i, n) per scenario, or one column for all.

    Returns
    -------
    list of numpy.ndarray
        Its outputs, (n_out, n) each.
    """
    if simd_kernels is not None and name in simd_kernels:
        return [o[:, :, 0] for o in simd_kernels[name](*args, threads=threads())]
    n = max(np.shape(a)[1] if np.ndim(a) == 2 else 1 for a in args)
    return [np.array(v) for v in mapped_of(name, n).call(list(args))]
