"""Choosing the outputs M1 (paper §V-B): swing height at the desired impact, the Taylor
conditions a = b = 0 and their two solution groups, stable domains, and an NLP that
minimises max|lambda| of A^z.

Paper eq. (25)-(27): with v(T^d) = v^d(T^d) and an error dq_u on the unactuated joint,
q(T^d) = q^d(T^d) + M_T dq_u with M_T = [1, -M1]', and

    Z_sw(q(T^d)) ~ Z_sw(q^d(T^d)) + a dq_u + b dq_u^2,
    a = grad Z_sw . M_T,   b = 1/2 M_T' Hess Z_sw M_T           (exact, by AD).

a = 0 is linear in M1 and b = 0 quadratic: given M1(2), M1(3), eliminating M1(1) with
a = 0 leaves a quadratic in M1(4) whose two roots are the two solution groups
(group 1: the root with +sqrt of the discriminant, group 2: with -sqrt; real where the
discriminant is >= 0).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from biped_casadi.caching import cached
from biped_casadi.output_law import decoupling_denominator
from biped_casadi.results import Result, internal

from .poincare import poincare_eigenvalues, poincare_map

__all__ = ["swing_height_at_Td", "TaylorAB", "taylor_ab", "solve_ab", "ABSolution",
           "conjecture_figures", "optimize_m1", "M1Result", "domain_grid"]


# ------------------------------------------------------------------ eq. (25)-(26)
def swing_height_at_Td(model, gait, M1s, dqu: float = 1e-2) -> np.ndarray:
    """Z_sw(q^d(T^d) + M_T dq_u) for each row of an (n, nu) array of M1 (eq. 26)."""
    M1s = np.atleast_2d(np.asarray(M1s, dtype=float))
    if M1s.shape[1] != model.nu:
        raise ValueError(f"M1s must be (n, {model.nu}), got {M1s.shape}")
    qT = gait.q(gait.T)
    q = qT[:, None] + dqu * _MT(M1s).T
    return np.array(model.swing_foot.map(len(M1s))(q)[1]).ravel()


# ------------------------------------------------------------------ eq. (27)-(28)
@dataclass
class TaylorAB:
    """Gradient and Hessian of z_sw at q^d(T^d): a(M1), b(M1) of eq. (27)."""
    grad: np.ndarray   # (5,)
    hess: np.ndarray   # (5, 5)
    z0: float          # Z_sw(q^d(T^d)), ~0 for a consistent gait

    @property
    def cache_key(self):
        """The coefficients themselves."""
        return (tuple(self.grad), tuple(self.hess.ravel()), self.z0)

    def a(self, M1s):
        MT = _MT(M1s)
        return MT @ self.grad

    def b(self, M1s):
        MT = _MT(M1s)
        return 0.5 * np.einsum("ni,ij,nj->n", MT, self.hess, MT)


def _MT(M1s):
    """M_T = [1, -M1]' of eq. (26), one row per M1."""
    M1s = np.atleast_2d(np.asarray(M1s, dtype=float))
    return np.hstack([np.ones((len(M1s), 1)), -M1s])


def taylor_ab(model, gait) -> TaylorAB:
    """Exact (AD) gradient and Hessian of Z_sw at q^d(T^d)."""
    q = model.q_sym
    z = model.swing_foot(q)[1]
    H, g = ca.hessian(z, q)
    f = ca.Function("zsw_taylor", [q], [z, g, H])
    z0, g0, H0 = f(gait.q(gait.T))
    return TaylorAB(np.array(g0).ravel(), np.array(H0), float(z0))


@dataclass
class ABSolution:
    """Both solution groups of a = b = 0 for given M1(2), M1(3) (arrays broadcast)."""
    m2: np.ndarray
    m3: np.ndarray
    discriminant: np.ndarray
    group1: np.ndarray      # (..., 4) M1, NaN where the roots are complex
    group2: np.ndarray


def solve_ab(tay: TaylorAB, m2, m3) -> ABSolution:
    """Closed-form solutions of a = b = 0 for M1(1), M1(4) given M1(2) = m2, M1(3) = m3.

    a = g0 - g1 M1(1) - g2 m2 - g3 m3 - g4 M1(4) = 0 gives M1(1) = c0 + c4 M1(4); then
    M_T = p - M1(4) r with p = (1, -c0, -m2, -m3, 0), r = (0, c4, 0, 0, 1), and
    b = 0 <=> (r'Hr) M1(4)^2 - 2 (r'Hp) M1(4) + p'Hp = 0.
    """
    g, H = tay.grad, tay.hess
    if abs(g[1]) < 1e-12:
        raise ValueError("dZ_sw/dq2 vanishes at q^d(T): M1(1) cannot be eliminated from a = 0")
    m2, m3 = np.broadcast_arrays(np.asarray(m2, float), np.asarray(m3, float))
    c0 = (g[0] - g[2] * m2 - g[3] * m3) / g[1]
    c4 = -g[4] / g[1]
    zeros, ones = np.zeros_like(m2), np.ones_like(m2)
    p = np.stack([ones, -c0, -m2, -m3, zeros], axis=-1)
    r = np.array([0.0, c4, 0.0, 0.0, 1.0])
    A2 = r @ H @ r
    A1 = -2 * (p @ H @ r)
    A0 = np.einsum("...i,ij,...j->...", p, H, p)
    disc = A1**2 - 4 * A2 * A0
    sq = np.sqrt(np.where(disc >= 0, disc, np.nan))
    out = []
    for sign in (+1, -1):
        m4 = (-A1 + sign * sq) / (2 * A2)
        m1 = c0 + c4 * m4
        out.append(np.stack([m1, m2, m3, m4], axis=-1))
    return ABSolution(m2, m3, disc, out[0], out[1])


def group_of(tay: TaylorAB, M1, tol: float = 1e-6):
    """1 or 2 when M1 satisfies a = b = 0 (which root), else None."""
    M1 = np.asarray(M1, float)
    s = solve_ab(tay, M1[1], M1[2])
    for k, sol in ((1, s.group1), (2, s.group2)):
        if np.all(np.isfinite(sol)) and np.max(np.abs(sol - M1)) <= tol * max(1, np.max(np.abs(M1))):
            return k
    return None


# ------------------------------------------------------------------ conjecture (Fig. 3)
def conjecture_figures(zsw: np.ndarray, max_abs: np.ndarray, status: np.ndarray) -> dict:
    """The paper's conjecture 'Z_sw(T^d) ~ 0 for every stable case', in numbers."""
    stable = status == "stable"
    unstable = status == "unstable"
    res = dict(n_stable=int(stable.sum()), n_unstable=int(unstable.sum()))
    if stable.any():
        zmax = float(np.max(np.abs(zsw[stable])))
        res.update(max_abs_zsw_stable=zmax,
                   median_abs_zsw_stable=float(np.median(np.abs(zsw[stable]))),
                   median_abs_zsw_unstable=float(np.median(np.abs(zsw[unstable])))
                   if unstable.any() else math.nan,
                   fraction_unstable_below=float(np.mean(np.abs(zsw[unstable]) <= zmax))
                   if unstable.any() else math.nan)
    return res


def domain_grid(tay: TaylorAB, n: int = 81, lo: float = -10.0, hi: float = 10.0):
    """The (M1(2), M1(3)) grid of Fig. 4 and both groups' M1 on it."""
    v = np.linspace(lo, hi, n)
    m2, m3 = np.meshgrid(v, v, indexing="ij")
    return solve_ab(tay, m2, m3)


# ------------------------------------------------------------------ the M1 NLP
@dataclass
class M1Result(Result):
    """The M1 chosen by :func:`optimize_m1`.

    ``max_abs`` and ``eigenvalues`` are verified by the full-AD Poincaré map;
    ``max_abs_nlp`` is the NLP's own value (variational A^z); ``status`` is the stability
    status of the chosen M1 ('stable' or 'unstable'); ``success`` means stable.
    ``history`` (left out of ``to_dict``) lists every local solution found.
    """

    M1: np.ndarray
    max_abs: float               # verified by the full-AD Poincaré map
    eigenvalues: np.ndarray
    group: int | None
    a: float
    b: float
    status: str
    max_abs_nlp: float           # the NLP's own value (variational A^z)
    eigenvalue_uncertainty: float
    starts: int
    solve_time: float
    message: str = ""
    history: list = internal(default_factory=list)

    SUCCESS = ("stable",)


@cached(maxsize=8)
def _epigraph_nlp(pm, tay, constrained: bool, den_margin: float):
    """min rho over (M1, rho) with the Jury conditions of a 2x2 A^z scaled by rho:
    rho^2 -+ det >= 0, rho^2 + det -+ rho tr >= 0 (all eigenvalues in |z| <= rho);
    a = b = 0 when ``constrained``; D11 - D12 M1 >= margin along the step.
    Built once per map, group kind and margin."""
    var = pm.variational
    M1 = ca.SX.sym("M1", pm.nu)
    rho = ca.SX.sym("rho")
    tr, det = var.trace_det(M1)
    g = [rho**2 - det, rho**2 + det, rho**2 + det - rho * tr, rho**2 + det + rho * tr]
    lbg, ubg = [0.0] * 4, [np.inf] * 4
    if constrained:
        MT = ca.vertcat(1, -M1)
        g += [ca.dot(ca.DM(tay.grad), MT), 0.5 * ca.mtimes([MT.T, ca.DM(tay.hess), MT])]
        lbg += [0.0, 0.0]
        ubg += [0.0, 0.0]
    den = decoupling_denominator(ca.DM(pm.D11_table[::10]),
                                 ca.DM(pm.D12_table[:, ::10]).T, M1)          # eq. (24)
    g.append(den)
    nd = den.numel()
    lbg += [den_margin] * nd
    ubg += [np.inf] * nd
    nlp = {"x": ca.vertcat(M1, rho), "f": rho, "g": ca.vertcat(*g)}
    solver = ca.nlpsol("m1_nlp", "ipopt", nlp, {
        "ipopt": {"print_level": 0, "sb": "yes", "max_iter": 300, "tol": 1e-10,
                  "hessian_approximation": "limited-memory"},
        "print_time": False, "error_on_fail": False})
    return solver, np.array(lbg), np.array(ubg)


@cached(maxsize=8)
def _deadbeat_residual(pm, tay, constrained: bool) -> ca.Function:
    """(trace, det[, a, b]) of A^z and its Jacobian in M1, as one Function (built once
    per map and group kind)."""
    X = ca.SX.sym("M1", pm.nu)
    tr, det = pm.variational.trace_det(X)
    res = [tr, det]
    if constrained:
        MT = ca.vertcat(1, -X)
        res += [ca.dot(ca.DM(tay.grad), MT), 0.5 * ca.mtimes([MT.T, ca.DM(tay.hess), MT])]
    r = ca.vertcat(*res)
    return ca.Function("deadbeat", [X], [r, ca.jacobian(r, X)])


def _deadbeat_newton(pm, tay, M1, constrained: bool, iters: int = 30):
    """Newton on trace = det = 0 (and a = b = 0): the deadbeat point near M1."""
    F = _deadbeat_residual(pm, tay, constrained)
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
            if np.all(np.isfinite(rt)) and np.linalg.norm(rt) < norm and not pm.is_singular(trial):
                break
            lam /= 2
        else:
            return None
        x = trial
    rv = np.array(F(x)[0]).ravel()
    return x if np.max(np.abs(rv)) < 1e-10 and not pm.is_singular(x) else None


def _coarse_best(pm, tay, group, k, n=81):
    """The k best non-singular points of a coarse map: the (M1(2), M1(3)) grid of the
    group, or the n_free^4 grid on [-10, 10] when all components are free."""
    if group is None:
        v = np.linspace(-10, 10, 9)
        P = np.stack(np.meshgrid(v, v, v, v, indexing="ij"), -1).reshape(-1, 4)
    else:
        s = domain_grid(tay, n)
        P = (s.group1 if group == 1 else s.group2).reshape(-1, 4)
        P = P[np.all(np.isfinite(P), axis=1)]
    st, _, _, mx = pm.jacobian_batch(P)
    order = np.argsort(np.where(st == "singular", np.inf, mx))
    return P[order[:k]]


def optimize_m1(model, gait, group: int | None = 1, starts=None, n_random: int = 2,
                n_best: int = 10, n_ipopt: int = 4, seed: int = 0, den_margin: float = 1.0,
                deadbeat: bool = True) -> M1Result:
    """Choose M1 minimising max|lambda| of A^z (exact derivatives of A^z in M1 by AD).

    ``group`` 1 or 2: M1 restricted to that solution group of a = b = 0; ``None``: all
    four components free.  Starts: ``starts`` (k, 4) if given, else the ``n_best`` best
    points of a coarse map (81 x 81 on the group, or the 9^4 grid when free), plus
    ``n_random`` random ones.  From every start Newton on trace = det = 0 (a deadbeat
    point, max|lambda| = 0, when one is near); from the first ``n_ipopt`` also IPOPT on
    the epigraph formulation, followed by the same Newton.
    The best result is verified by the full-AD map (:func:`poincare_eigenvalues`), and
    its eigenvalue uncertainty estimated from a map with twice the RK4 steps (near
    deadbeat eigenvalues move like the square root of an error in A^z).
    """
    if group not in (1, 2, None):
        raise ValueError(f"group must be 1, 2 or None, got {group!r}")
    t0 = time.perf_counter()
    pm = poincare_map(model, gait)
    tay = taylor_ab(model, gait)
    constrained = group is not None
    rng = np.random.default_rng(seed)
    cand = [] if starts is None else [np.asarray(s, float) for s in np.atleast_2d(starts)]
    if starts is None:            # the best points of a coarse map of the feasible set
        cand += list(_coarse_best(pm, tay, group, n_best))
    tries, n0 = 0, len(cand)
    while len(cand) < n0 + n_random and tries < 50 * max(n_random, 1):
        tries += 1
        if constrained:
            s = solve_ab(tay, *rng.uniform(-10, 10, 2))
            M1 = s.group1 if group == 1 else s.group2
        else:
            M1 = rng.uniform(-5, 5, 4)
        if np.all(np.isfinite(M1)) and np.all(pm.denominator(M1) > den_margin):
            cand.append(np.asarray(M1, float))
    cand = [c for c in cand if np.all(np.isfinite(c)) and np.all(pm.denominator(c) > den_margin)]
    if not cand:
        raise ValueError(f"no non-singular start found on group {group}")
    solver, lbg, ubg = _epigraph_nlp(pm, tay, constrained, den_margin)
    history = []
    for i, M1 in enumerate(cand):
        found = [(_deadbeat_newton(pm, tay, M1, constrained) if deadbeat else None, "newton")]
        if i < n_ipopt:
            st, A, ev, mx = pm.jacobian_batch(M1[None])
            rho0 = float(mx[0]) * 1.01 + 1e-3 if np.isfinite(mx[0]) else 100.0
            sol = solver(x0=np.r_[M1, rho0], lbg=lbg, ubg=ubg, lbx=np.r_[[-1e3] * 4, 0.0],
                         ubx=np.r_[[1e3] * 4, 1e6])
            x = np.array(sol["x"]).ravel()[:4]
            found += [(x, "ipopt"),
                      (_deadbeat_newton(pm, tay, x, constrained) if deadbeat else None,
                       "ipopt+newton")]
        for Mx, how in found:
            if Mx is None or pm.is_singular(Mx):
                continue
            if constrained and group_of(tay, Mx) != group:
                continue                  # Newton may cross to the other group's root
            val = float(pm.jacobian_batch(Mx[None])[3][0])
            history.append(dict(start=M1.tolist(), M1=Mx.tolist(), max_abs=val, how=how))
    if not history:
        raise RuntimeError("the M1 NLP found no non-singular local optimum (IPOPT); try more starts")
    # verify the best few by the full-AD map and keep the best verified one
    ranked = sorted(history, key=lambda h: h["max_abs"])
    verified = []
    for h in ranked[:3]:
        r = poincare_eigenvalues(model, gait, h["M1"], method="ad")
        verified.append((r.max_abs, np.array(h["M1"]), h["max_abs"]))
    _, M1, val = min(verified, key=lambda v: v[0])
    r = poincare_eigenvalues(model, gait, M1, method="ad")
    # integration-error estimate of A^z: a map with twice the RK4 steps
    fine = poincare_map(model, gait, n_pre=2 * pm.n_pre, n_post=2 * pm.n_post).analyse(
        M1, method="ad")
    dA = float(np.max(np.abs(fine.A - r.A)))
    unc = float(max(abs(fine.max_abs - r.max_abs), math.sqrt(dA * np.max(np.abs(r.A)))))
    label = f"group {group}" if constrained else "all components free"
    return M1Result(M1=M1, max_abs=r.max_abs, eigenvalues=r.eigenvalues,
                    group=group_of(tay, M1) if constrained else group_of(tay, M1, 1e-9),
                    a=float(tay.a(M1)[0]), b=float(tay.b(M1)[0]), status=r.status,
                    max_abs_nlp=val, eigenvalue_uncertainty=unc, starts=len(cand),
                    solve_time=time.perf_counter() - t0,
                    message=f"{label}: max|lambda| = {r.max_abs:.3g} (verified by the "
                            f"full-AD map) from {len(cand)} starts",
                    history=history)
