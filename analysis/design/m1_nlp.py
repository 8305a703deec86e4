"""The M1 NLP (paper §V-B): choose the outputs that minimise max|lambda| of A^z, on a group
of a = b = 0 (:mod:`analysis.design.output_selection`) or with every component free.

The spectral radius enters through the epigraph of the 2x2 Jury conditions on A^z (exact
derivatives in M1 by AD of the variational Jacobian), then a Newton iteration on
tr A^z = det A^z = 0 restricted to the group brings a near-deadbeat point to deadbeat.

Where the least max|lambda| is zero (a deadbeat point) the epigraph is degenerate: at
rho = 0 its four conditions reduce to det = 0 and no longer see the trace, and max|lambda|
grows like the square root of a perturbation of a nilpotent A^z.  IPOPT then converges
slowly: on RABBIT's default gait it stopped at its 300-iteration cap from every start of
the coarse map (2.5 s each), ending above its start, while Newton from the same starts
reached deadbeat.  So IPOPT runs from a start only while no deadbeat point has been found
(nothing is below zero); ``M1Result.ipopt_runs`` says how often it ran.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from biped_casadi.caching import cached
from biped_casadi.control.output_law import M1_LIMIT, decoupling_denominator
from biped_casadi.control.reference import require_reference
from biped_casadi.numerics import ipopt_solver
from biped_casadi.results import Result, internal

from ..stability.poincare import poincare_eigenvalues, poincare_map
from .output_selection import (ab_solution_set, coarse_grid_size, domain_grid, group_of,
                               solve_ab, taylor_ab)

__all__ = ["optimize_m1", "M1Result", "coarse_map_points", "COARSE_N"]

#: points per free component of a group's coarse map (the full run's Fig. 4 grid)
COARSE_N = 81
#: the box of the M1 NLP, |M1(i)| <= M1_BOX: a result on it says max|lambda| still falls
#: beyond it (an asymptote, M1 growing without bound), not an optimum
M1_BOX = 1e3


# ------------------------------------------------------------------ the M1 NLP
@dataclass
class M1Result(Result):
    """The M1 chosen by :func:`optimize_m1`.

    ``success`` means an M1 was chosen (and verified); whether it is stable is
    ``status``.

    Parameters
    ----------
    M1 : numpy.ndarray
        (nu,) the chosen outputs.
    max_abs : float
        max ``|lambda|`` of A^z, verified by the full-AD Poincaré map.
    eigenvalues : numpy.ndarray
        The two eigenvalues (complex), from the same map.
    group : int or None
        The a = b = 0 group M1 lies on (1 or 2), None when on neither.
    a, b : float
        The coefficients of eq. (27) at M1.
    status : {'stable', 'unstable'}
        The stability status of the chosen M1.
    max_abs_nlp : float
        The NLP's own value (variational A^z).
    eigenvalue_uncertainty : float
        Estimated error of max ``|lambda|``, from a map with twice the RK4 steps.
    starts : int
        Starting points tried.
    ipopt_runs : int
        Starts IPOPT ran from (it is not run once a deadbeat point is found).
    solve_time : float
        Wall time, s.
    message : str
        The result in words.
    at_bound : bool
        Whether a component of M1 lies on the NLP's box ``|M1(i)| <= M1_BOX`` (to 1e-3
        relative): max|lambda| still falls beyond it, so M1 is where the search stopped,
        not an optimum.
    history : list of dict
        Every local solution found (start, M1, max_abs, how); left out of
        ``to_dict()``.
    """

    M1: np.ndarray
    max_abs: float
    eigenvalues: np.ndarray
    group: int | None
    a: float
    b: float
    status: str
    max_abs_nlp: float
    eigenvalue_uncertainty: float
    starts: int
    solve_time: float
    message: str = ""
    ipopt_runs: int = 0
    at_bound: bool = False
    history: list = internal(default_factory=list)

    SUCCESS = ("stable", "unstable")


#: which swing-height conditions constrain the M1 NLP
_CONSTRAINTS = ("none", "ab", "a")


def _conditions(tay, M1, constraints: str) -> list:
    """a (and b) of eq. (27) as CasADi expressions of M1, for ``constraints``."""
    if constraints == "none":
        return []
    MT = ca.vertcat(1, -M1)
    a = ca.dot(ca.DM(tay.grad), MT)
    if constraints == "a":
        return [a]
    return [a, 0.5 * ca.mtimes([MT.T, ca.DM(tay.hess), MT])]


@cached(maxsize=8)
def _epigraph_nlp(pm, tay, constraints: str, den_margin: float):
    """min rho over (M1, rho) with the Jury conditions of a 2x2 A^z scaled by rho:
    rho^2 -+ det >= 0, rho^2 + det -+ rho tr >= 0 (all eigenvalues in |z| <= rho);
    a = b = 0 (``constraints`` 'ab') or a = 0 ('a', where b vanishes with a);
    D11 - D12 M1 >= margin along the step.  Built once per map, constraints and margin.
    The Hessian is exact for nu = 2 (cheap, and the limited-memory approximation strays
    off the three-link biped's a = 0 line), limited-memory otherwise (RABBIT)."""
    var = pm.variational
    M1 = ca.SX.sym("M1", pm.nu)
    rho = ca.SX.sym("rho")
    tr, det = var.trace_det(M1)
    g = [rho**2 - det, rho**2 + det, rho**2 + det - rho * tr, rho**2 + det + rho * tr]
    lbg, ubg = [0.0] * 4, [np.inf] * 4
    cond = _conditions(tay, M1, constraints)
    g += cond
    lbg += [0.0] * len(cond)
    ubg += [0.0] * len(cond)
    den = decoupling_denominator(ca.DM(pm.D11_table[::10]),
                                 ca.DM(pm.D12_table[:, ::10]).T, M1)          # eq. (24)
    g.append(den)
    nd = den.numel()
    lbg += [den_margin] * nd
    ubg += [np.inf] * nd
    nlp = {"x": ca.vertcat(M1, rho), "f": rho, "g": ca.vertcat(*g)}
    solver = ipopt_solver("m1_nlp", nlp, {
        "ipopt": {"print_level": 0, "sb": "yes", "max_iter": 300, "tol": 1e-10,
                  "hessian_approximation": "exact" if pm.nu <= 2 else "limited-memory"},
        "print_time": False, "error_on_fail": False})
    return solver, np.array(lbg), np.array(ubg)


@cached(maxsize=8)
def _deadbeat_residual(pm, tay, constraints: str) -> ca.Function:
    """(trace, det[, a[, b]]) of A^z and its Jacobian in M1, as one Function (built once
    per map and constraints)."""
    X = ca.SX.sym("M1", pm.nu)
    tr, det = pm.variational.trace_det(X)
    r = ca.vertcat(tr, det, *_conditions(tay, X, constraints))
    return ca.Function("deadbeat", [X], [r, ca.jacobian(r, X)])


def _deadbeat_newton(pm, tay, M1, constraints: str, iters: int = 30):
    """Newton on trace = det = 0 (and the swing-height conditions): the deadbeat point
    near M1."""
    F = _deadbeat_residual(pm, tay, constraints)
    x = np.array(M1, float)
    for _ in range(iters):
        rv, J = (np.array(v) for v in F(x))
        rv = rv.ravel()
        norm = np.linalg.norm(rv)
        if np.max(np.abs(rv)) < 1e-13:
            break
        step = np.linalg.lstsq(J, -rv, rcond=None)[0]
        if not np.all(np.isfinite(step)):
            return None
        lam = 1.0                              # backtracking on the residual norm
        while lam > 1e-3:
            trial = x + lam * step
            rt = np.array(F(trial)[0]).ravel()
            with np.errstate(over="ignore"):   # a far trial point: its norm is inf, rejected
                worse = not np.linalg.norm(rt) < norm
            # a trial beyond the outputs' valid range (|M1| <= M1_LIMIT) is rejected too
            if (np.all(np.isfinite(rt)) and not worse and np.max(np.abs(trial)) <= M1_LIMIT
                    and not pm.is_singular(trial)):
                break
            lam /= 2
        else:
            return None
        x = trial
    rv = np.array(F(x)[0]).ravel()
    return x if np.max(np.abs(rv)) < 1e-10 and not pm.is_singular(x) else None


def _feasible_set(tay, group, nu):
    """(constraints, sampler, in_group) for a group: the NLP's conditions, a function
    giving n candidate points of the set (numbers or a coarse sample), and the
    membership test of a solution."""
    if group is None:
        return "none", None, lambda M1: True
    if nu >= 3:
        def sample(rng, n):
            s = solve_ab(tay, *rng.uniform(-10, 10, (nu - 2, n)))
            return (s.group1 if group == 1 else s.group2).reshape(-1, nu)
        return "ab", sample, lambda M1: group_of(tay, M1) == group
    ab = ab_solution_set(tay)
    if ab.kind == "line":
        if group != 1:
            raise ValueError(f"group: a = b = 0 is one line for this robot ({ab.message}); "
                             "use group=1 (the line) or None")

        def sample(rng, n):
            return ab.sample(n) if rng is None else ab.sample(1, *(2 * [rng.uniform(-10, 10)]))
        return "a", sample, lambda M1: ab.on_set(M1) == 1
    if ab.kind == "none" or group > len(ab.points):
        raise ValueError(f"group: no solution group {group} of a = b = 0 for this gait "
                         f"({ab.message})")
    point = ab.points[group - 1]
    return "ab", (lambda rng, n: point[None, :].copy()), lambda M1: ab.on_set(M1) == group


def coarse_map_points(tay, group, nu, n=COARSE_N):
    """The points of the coarse map that :func:`optimize_m1` starts from.

    Parameters
    ----------
    tay : TaylorAB
        The gait's Taylor coefficients (eq. 27).
    group : {1, 2, None}
        The a = b = 0 group, or None (all components free).
    nu : int
        Components of M1.
    n : int
        Points per free component of a group's grid.

    Returns
    -------
    numpy.ndarray
        (m, nu): the group's grid of the middle components (RABBIT: (M1(2), M1(3)), n x n,
        the grid of Fig. 4; nu = 2: n^2 points of the line, or the isolated point), or
        the grid of :func:`~analysis.design.output_selection.coarse_grid_size` points per
        component on [-10, 10] when all are free (the paper's 9^4 for RABBIT); the rows
        with a real solution only.
    """
    if group is None:
        v = np.linspace(-10, 10, coarse_grid_size(nu))
        P = np.stack(np.meshgrid(*([v] * nu), indexing="ij"), -1).reshape(-1, nu)
    elif nu >= 3:
        s = domain_grid(tay, n)
        P = (s.group1 if group == 1 else s.group2).reshape(-1, nu)
    else:
        P = _feasible_set(tay, group, nu)[1](None, n * n)
    return P[np.all(np.isfinite(P), axis=1)]


def _coarse_best(pm, tay, group, k, coarse=None):
    """The k best non-singular points of the coarse map (:func:`coarse_map_points`),
    evaluated here or given (``coarse``: its :class:`JacobianBatch`)."""
    jb = coarse if coarse is not None else pm.jacobian_batch(coarse_map_points(tay, group, pm.nu))
    order = np.argsort(np.where(jb.status == "singular", np.inf, jb.max_abs))
    return np.asarray(jb.M1, float)[order[:k]]


def optimize_m1(gait, group: int | None = 1, starts=None, n_random: int = 2,
                n_best: int = 10, n_ipopt: int = 4, seed: int = 0, den_margin: float = 1.0,
                deadbeat: bool = True, coarse=None) -> M1Result:
    """Choose M1 minimising max|lambda| of A^z (exact derivatives of A^z in M1 by AD).

    ``group`` 1 or 2: M1 restricted to that solution group of a = b = 0; for nu = 2
    (the three-link biped) the groups are the isolated solutions of
    :func:`ab_solution_set` (only evaluated), or, when the solutions form a line,
    ``group=1`` is that line (a = 0, on which b vanishes); ``None``: all components
    free.  Starts: ``starts`` (k, nu) if given, else the ``n_best`` best points of a
    coarse map (for RABBIT 81 x 81 on the group, or the 9^4 grid when free), plus
    ``n_random`` random ones.  From every start Newton on trace = det = 0 (a deadbeat
    point, max|lambda| = 0, when one is near); from the first ``n_ipopt`` also IPOPT on
    the epigraph formulation, followed by the same Newton, as long as no deadbeat point
    has been found (see the module's note).
    The best result is verified by the full-AD map (:func:`poincare_eigenvalues`), and
    its eigenvalue uncertainty estimated from a map with twice the RK4 steps (near
    deadbeat eigenvalues move like the square root of an error in A^z).

    Parameters
    ----------
    gait : Reference
        Its reference gait.
    group : {1, 2, None}
        The a = b = 0 group M1 is restricted to, or None (all components free).
    starts : array_like, optional
        (k, nu) starting points.
    n_random, n_best, n_ipopt : int
        Random starts, starts from the coarse map, starts also given to IPOPT.
    seed : int
        Of the random starts.
    den_margin : float
        D11 - D12 M1 must stay above this along the step (eq. 24).
    deadbeat : bool
        Try Newton on trace = det = 0.
    coarse : JacobianBatch, optional
        The coarse map already evaluated (at :func:`coarse_map_points`, e.g. by the sweep
        of Fig. 4 or the 9^4 grid), instead of evaluating it here.

    Returns
    -------
    M1Result
        The best M1 found, verified.
    """
    model = require_reference(gait).model
    if group not in (1, 2, None):
        raise ValueError(f"group must be 1, 2 or None, got {group!r}")
    for name, v in (("n_random", n_random), ("n_best", n_best), ("n_ipopt", n_ipopt),
                    ("seed", seed)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
            raise ValueError(f"{name} must be a non-negative integer, got {v!r}")
    if starts is not None:
        try:
            starts = np.atleast_2d(np.asarray(starts, dtype=float))
        except (TypeError, ValueError):
            raise ValueError(f"starts must be numbers, (k, {model.nu}), got {starts!r}") \
                from None
        if starts.ndim != 2 or starts.shape[1] != model.nu or not starts.size:
            raise ValueError(f"starts must be an array (k, {model.nu}) of M1, got shape "
                             f"{starts.shape}")
        if not np.all(np.isfinite(starts)):
            raise ValueError("starts must be finite")
    t0 = time.perf_counter()
    pm = poincare_map(gait)
    tay = taylor_ab(gait)
    nu = model.nu
    constrained = group is not None
    constraints, sampler, in_group = _feasible_set(tay, group, nu)
    cand = _m1_starts(pm, tay, group, nu, sampler, starts, n_random, n_best, seed,
                      den_margin, coarse)
    fixed = nu - len(_conditions(tay, ca.SX.sym("M1", nu), constraints)) == 0
    history, ipopt_runs, ipopt_skipped = _search(pm, tay, nu, cand, fixed, constrained,
                                                 constraints, in_group, deadbeat, n_ipopt,
                                                 den_margin)
    if not history:
        raise RuntimeError("the M1 NLP found no non-singular local optimum (IPOPT); try more starts")
    r, val, unc = _verified_best(gait, pm, history)
    M1 = r.M1
    label = f"group {group}" if constrained else "all components free"
    at_bound = bool(np.any(np.abs(np.abs(M1) - M1_BOX) <= 1e-3 * M1_BOX))
    bound = (f"; M1({int(np.argmin(np.abs(np.abs(M1) - M1_BOX))) + 1}) is on the NLP's bound {M1_BOX:g}: "
             "max|lambda| still falls beyond it, so this M1 is where the search stopped, "
             "not an optimum") if at_bound else ""
    return M1Result(M1=M1, max_abs=r.max_abs, eigenvalues=r.eigenvalues,
                    group=group_of(tay, M1) if constrained else group_of(tay, M1, 1e-9),
                    a=float(tay.a(M1)[0]), b=float(tay.b(M1)[0]), status=r.status,
                    max_abs_nlp=val, eigenvalue_uncertainty=unc, starts=len(cand),
                    solve_time=time.perf_counter() - t0,
                    message=f"{label}: max|lambda| = {r.max_abs:.3g} (verified by the "
                            f"full-AD map) from {len(cand)} starts"
                            + (f", IPOPT from {ipopt_runs}" if ipopt_runs else "")
                            + (f" (skipped from {ipopt_skipped}: a deadbeat point was "
                               "already found)" if ipopt_skipped else "") + bound,
                    ipopt_runs=ipopt_runs, at_bound=at_bound, history=history)


def _m1_starts(pm, tay, group, nu, sampler, starts, n_random, n_best, seed, den_margin,
               coarse):
    """The starts: ``starts`` or the best points of the coarse map, plus ``n_random``
    random ones (on the group, or uniform in [-5, 5]), all non-singular."""
    constrained = group is not None
    rng = np.random.default_rng(seed)
    cand = [] if starts is None else [np.asarray(s, float) for s in np.atleast_2d(starts)]
    if starts is None:            # the best points of a coarse map of the feasible set
        cand += list(_coarse_best(pm, tay, group, n_best, coarse))
    tries, n0 = 0, len(cand)
    while len(cand) < n0 + n_random and tries < 50 * max(n_random, 1):
        tries += 1
        M1 = sampler(rng, 1)[0] if constrained else rng.uniform(-5, 5, nu)
        if np.all(np.isfinite(M1)) and np.all(pm.denominator(M1) > den_margin):
            cand.append(np.asarray(M1, float))
    cand = [c for c in cand if np.all(np.isfinite(c)) and np.all(pm.denominator(c) > den_margin)]
    if not cand:
        raise ValueError(f"no non-singular start found on group {group}")
    return cand


def _search(pm, tay, nu, cand, fixed, constrained, constraints, in_group, deadbeat, n_ipopt,
            den_margin):
    """From every start Newton on trace = det = 0, from the first ``n_ipopt`` also IPOPT
    then Newton until a deadbeat point is found: (history of the valid points found,
    IPOPT runs, IPOPT runs skipped)."""
    history = []
    ipopt_runs = ipopt_skipped = 0

    def keep(found, start):
        """Add the valid points of ``found`` to the history; whether one is deadbeat."""
        zero = False
        for Mx, how in found:
            if Mx is None or pm.is_singular(Mx):
                continue
            if constrained and not in_group(Mx):
                continue                  # Newton may cross to the other group's root
            val = float(pm.jacobian_batch(Mx[None]).max_abs[0])
            history.append(dict(start=start.tolist(), M1=Mx.tolist(), max_abs=val, how=how))
            zero |= how.endswith("newton")     # Newton converged: trace = det = 0
        return zero

    reached_zero = False          # a deadbeat point found: rho = 0, the NLP's minimum
    for i, M1 in enumerate(cand):
        if fixed:                 # an isolated solution: nothing to choose
            keep([(M1, "isolated solution")], M1)
            continue
        # the start itself too: the result is never worse
        reached_zero |= keep([(M1, "start"),
                              (_deadbeat_newton(pm, tay, M1, constraints) if deadbeat
                               else None, "newton")], M1)
        if i >= n_ipopt:
            continue
        if reached_zero:
            ipopt_skipped += 1    # nothing beats max|lambda| = 0 (see the module's note)
            continue
        ipopt_runs += 1
        x = _ipopt_from(pm, tay, nu, M1, constraints, den_margin)
        reached_zero |= keep([(x, "ipopt"),
                              (_deadbeat_newton(pm, tay, x, constraints) if deadbeat
                               else None, "ipopt+newton")], M1)
    return history, ipopt_runs, ipopt_skipped


def _ipopt_from(pm, tay, nu, M1, constraints, den_margin):
    """IPOPT on the epigraph formulation from M1 (rho from its max|lambda|): its M1."""
    solver, lbg, ubg = _epigraph_nlp(pm, tay, constraints, den_margin)
    mx = pm.jacobian_batch(M1[None]).max_abs
    rho0 = float(mx[0]) * 1.01 + 1e-3 if np.isfinite(mx[0]) else 100.0
    sol = solver(x0=np.r_[M1, rho0], lbg=lbg, ubg=ubg, lbx=np.r_[[-M1_BOX] * nu, 0.0],
                 ubx=np.r_[[M1_BOX] * nu, 1e6])
    return np.array(sol["x"]).ravel()[:nu]


def _verified_best(gait, pm, history):
    """The best of the three best points verified by the full-AD map: (its analysis, its
    max|lambda| in the NLP, the eigenvalue uncertainty from a map with twice the RK4
    steps)."""
    # verify the best few by the full-AD map and keep the best verified one
    ranked = sorted(history, key=lambda h: h["max_abs"])
    verified = [(poincare_eigenvalues(gait, h["M1"], method="ad"), h["max_abs"])
                for h in ranked[:3]]
    r, val = min(verified, key=lambda v: v[0].max_abs)
    M1 = r.M1
    # integration-error estimate of A^z: a map with twice the RK4 steps
    fine = poincare_map(gait, n_pre=2 * pm.n_pre, n_post=2 * pm.n_post).analyse(
        M1, method="ad")
    dA = float(np.max(np.abs(fine.A - r.A)))
    unc = float(max(abs(fine.max_abs - r.max_abs), math.sqrt(dA * np.max(np.abs(r.A)))))
    return r, val, unc
