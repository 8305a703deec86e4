"""Choosing the outputs M1 (paper §V-B): swing height at the desired impact, the Taylor
conditions a = b = 0 and their two solution groups, stable domains, and an NLP that
minimises max|lambda| of A^z.

Paper eq. (25)-(27): with v(T^d) = v^d(T^d) and an error dq_u on the unactuated joint,
q(T^d) = q^d(T^d) + M_T dq_u with M_T = [1, -M1]', and

    Z_sw(q(T^d)) ~ Z_sw(q^d(T^d)) + a dq_u + b dq_u^2,
    a = grad Z_sw . M_T,   b = 1/2 M_T' Hess Z_sw M_T           (exact, by AD).

a = 0 is linear in M1 and b = 0 quadratic: given the middle components M1(2) ..
M1(nu - 1) (RABBIT: M1(2), M1(3)), eliminating M1(1) with a = 0 leaves a quadratic in
the last component M1(nu) whose two roots are the two solution groups (group 1: the root
with +sqrt of the discriminant, group 2: with -sqrt; real where the discriminant is
>= 0).  With nu = 2 (the three-link biped) nothing is left free: a = b = 0 is a line
meeting a conic, :func:`ab_solution_set` finds every solution (isolated points, none,
or, when b vanishes identically on a = 0, the whole line).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np



__all__ = ["swing_height_at_Td", "TaylorAB", "taylor_ab", "solve_ab", "ABSolution",
           "conjecture_figures", "domain_grid",
           "isolated_ab_solutions", "ab_solution_set", "ABSet", "ABGroups", "ab_groups", "group_of",
           "coarse_grid_size"]


# ------------------------------------------------------------------ eq. (25)-(26)
def swing_height_at_Td(gait, M1s, dqu: float = 1e-2) -> np.ndarray:
    """The swing-foot height at the desired impact time with an error on q_u.

    Implements eqs. (25), (26): with the outputs on their reference at T^d = T
    (v(T^d) = v^d(T^d), eq. 25) and an error dq_u on the unactuated joint, the
    configuration is q(T^d) = q^d(T^d) + M_T dq_u with M_T = [1, -M1]' (eq. 26);
    this returns Z_sw of that configuration (paper Fig. 3).

    Parameters
    ----------
    gait : Reference
        The reference; T^d is its step duration T.
    M1s : array_like
        (n, nu) output matrices (or one M1).
    dqu : float
        The error dq_u, rad (the paper's 1e-2).

    Returns
    -------
    numpy.ndarray
        (n,) Z_sw(q(T^d)), m.
    """
    model = gait.model
    M1s = np.atleast_2d(np.asarray(M1s, dtype=float))
    if M1s.shape[1] != model.nu:
        raise ValueError(f"M1s must be (n, {model.nu}), got {M1s.shape}")
    qT = gait.q(gait.T)
    q = qT[:, None] + dqu * _MT(M1s).T
    return np.array(model.swing_foot.map(len(M1s))(q)[1]).ravel()


# ------------------------------------------------------------------ eq. (27)-(28)
@dataclass
class TaylorAB:
    """The second-order Taylor expansion of the swing-foot height at q^d(T^d).

    Implements eq. (27): Z_sw(q(T^d)) ~ Z_sw(q^d(T^d)) + a dq_u + b dq_u^2 with
    a = grad Z_sw . M_T and b = 1/2 M_T' Hess Z_sw M_T, M_T = [1, -M1]'
    (:meth:`a`, :meth:`b`).  Made by :func:`taylor_ab`.

    Parameters
    ----------
    grad : numpy.ndarray
        (nq,) gradient of Z_sw at q^d(T^d), m/rad.
    hess : numpy.ndarray
        (nq, nq) its Hessian, m/rad^2.
    z0 : float
        Z_sw(q^d(T^d)), m (~0 for a consistent gait).
    """
    grad: np.ndarray
    hess: np.ndarray
    z0: float

    @property
    def cache_key(self):
        """The coefficients themselves."""
        return (tuple(self.grad), tuple(self.hess.ravel()), self.z0)

    def a(self, M1s):
        """The first-order coefficient a = grad Z_sw . M_T of eq. (27).

        Parameters
        ----------
        M1s : array_like
            (n, nu) output matrices (or one M1).

        Returns
        -------
        numpy.ndarray
            (n,) a, m/rad.
        """
        MT = _MT(M1s)
        return MT @ self.grad

    def b(self, M1s):
        """The second-order coefficient b = 1/2 M_T' Hess Z_sw M_T of eq. (27).

        Parameters
        ----------
        M1s : array_like
            (n, nu) output matrices (or one M1).

        Returns
        -------
        numpy.ndarray
            (n,) b, m/rad^2.
        """
        MT = _MT(M1s)
        return 0.5 * np.einsum("ni,ij,nj->n", MT, self.hess, MT)


def _MT(M1s):
    """M_T = [1, -M1]' of eq. (26), one row per M1."""
    M1s = np.atleast_2d(np.asarray(M1s, dtype=float))
    return np.hstack([np.ones((len(M1s), 1)), -M1s])


def taylor_ab(gait) -> TaylorAB:
    """The coefficients of eq. (27): exact (AD) gradient and Hessian of Z_sw at q^d(T^d).

    Parameters
    ----------
    gait : Reference
        The reference; T^d is its step duration T.

    Returns
    -------
    TaylorAB
    """
    model = gait.model
    q = model.q_sym
    z = model.swing_foot(q)[1]
    H, g = ca.hessian(z, q)
    f = ca.Function("zsw_taylor", [q], [z, g, H])
    z0, g0, H0 = f(gait.q(gait.T))
    return TaylorAB(np.array(g0).ravel(), np.array(H0), float(z0))


@dataclass
class ABSolution:
    """Both solution groups of a = b = 0 for given middle components of M1.

    Parameters
    ----------
    free : tuple of numpy.ndarray
        The middle components M1(2) .. M1(nu - 1), broadcast together (empty for
        nu = 2).
    discriminant : numpy.ndarray
        Of the quadratic b = 0 in M1(nu) on a = 0; the groups are real where >= 0.
    group1, group2 : numpy.ndarray
        (..., nu) the M1 of group 1 (+sqrt of the discriminant) and group 2 (-sqrt);
        NaN where the roots are complex.
    """
    free: tuple
    discriminant: np.ndarray
    group1: np.ndarray
    group2: np.ndarray

    @property
    def m2(self) -> np.ndarray:
        """M1(2) (RABBIT's first domain coordinate, Fig. 4)."""
        return self.free[0]

    @property
    def m3(self) -> np.ndarray:
        """M1(3) (RABBIT's second domain coordinate, Fig. 4)."""
        return self.free[1]


def solve_ab(tay: TaylorAB, *free) -> ABSolution:
    """Closed-form solutions of a = b = 0 for M1(1) and M1(nu), given the others.

    Implements eq. (28) for nu >= 3: the middle components M1(2) .. M1(nu - 1) =
    ``free`` are given (RABBIT: ``solve_ab(tay, m2, m3)``), and M1(1), M1(nu) follow in
    closed form, two groups of solutions (for nu = 2 see :func:`ab_solution_set`, which
    also handles the degenerate cases).

    a = g0 - g1 M1(1) - sum_j g_j M1(j) - g_nu M1(nu) = 0 gives M1(1) = c0 + c_nu M1(nu);
    then M_T = p - M1(nu) r with p = (1, -c0, -free, 0), r = (0, c_nu, 0, ..., 0, 1), and
    b = 0 <=> (r'Hr) M1(nu)^2 - 2 (r'Hp) M1(nu) + p'Hp = 0.

    Parameters
    ----------
    tay : TaylorAB
        The coefficients of eq. (27).
    *free : array_like
        nu - 2 arrays (broadcast together): M1(2) .. M1(nu - 1).

    Returns
    -------
    ABSolution
        Both groups on the broadcast shape of ``free``.
    """
    g, H = tay.grad, tay.hess
    nu = g.size - 1
    if len(free) != nu - 2:
        raise ValueError(f"free: a = b = 0 leaves {nu - 2} components of M1 free "
                         f"(M1(2) .. M1({nu - 1})), got {len(free)} values")
    if abs(g[1]) < 1e-12:
        raise ValueError("dZ_sw/dq2 vanishes at q^d(T): M1(1) cannot be eliminated from a = 0")
    free = np.broadcast_arrays(*(np.asarray(m, float) for m in free)) if free else []
    num = g[0]
    for j, m in enumerate(free):
        num = num - g[j + 2] * m
    c0 = np.asarray(num / g[1], float)
    c_last = -g[nu] / g[1]
    zeros, ones = np.zeros_like(c0), np.ones_like(c0)
    p = np.stack([ones, -c0, *(-m for m in free), zeros], axis=-1)
    r = np.zeros(nu + 1)
    r[1], r[nu] = c_last, 1.0
    A2 = r @ H @ r
    A1 = -2 * (p @ H @ r)
    A0 = np.einsum("...i,ij,...j->...", p, H, p)
    disc = A1**2 - 4 * A2 * A0
    sq = np.sqrt(np.where(disc >= 0, disc, np.nan))
    out = []
    for sign in (+1, -1):
        with np.errstate(divide="ignore", invalid="ignore"):
            m_last = (-A1 + sign * sq) / (2 * A2)
        m1 = c0 + c_last * m_last
        out.append(np.stack([m1, *free, m_last], axis=-1))
    return ABSolution(tuple(free), disc, out[0], out[1])


@dataclass
class ABSet:
    """The solution set of a = b = 0 for a robot with nu = 2 (no component left free).

    Parameters
    ----------
    kind : {'points', 'line', 'none'}
        Isolated solutions, a whole line (b vanishes identically on the line a = 0: every
        M1 on it solves a = b = 0), or no solution.
    points : numpy.ndarray
        (k, 2), k = 1 or 2, group 1 first ((0, 2) unless ``kind`` is 'points').
    base, direction : numpy.ndarray
        The line a = 0 is M1 = ``base`` + t ``direction`` (``direction`` of unit length).
    b_coefficients : tuple of float
        b along that line per unit length: the (t^2, t, 1) coefficients.
    message : str
        Which case, in words.
    """
    kind: str
    points: np.ndarray
    base: np.ndarray
    direction: np.ndarray
    b_coefficients: tuple
    message: str = ""

    def to_dict(self) -> dict:
        """The fields in JSON types.

        Returns
        -------
        dict
            Field name -> value (arrays as lists).
        """
        return dict(kind=self.kind, points=self.points.tolist(), base=self.base.tolist(),
                    direction=self.direction.tolist(),
                    b_coefficients=[float(c) for c in self.b_coefficients],
                    message=self.message)

    def on_set(self, M1, tol: float = 1e-6) -> int | None:
        """Whether M1 solves a = b = 0.

        Parameters
        ----------
        M1 : array_like
            Two numbers.
        tol : float
            Relative tolerance.

        Returns
        -------
        int or None
            1 or 2 (which point, or 1 on the line), else None.
        """
        M1 = np.asarray(M1, float)
        scale = tol * max(1.0, float(np.max(np.abs(M1))))
        if self.kind == "line":
            r = M1 - self.base
            off = r - (r @ self.direction) * self.direction
            return 1 if np.max(np.abs(off)) <= scale else None
        for k, p in enumerate(self.points, start=1):
            if np.max(np.abs(p - M1)) <= scale:
                return k
        return None

    def sample(self, n: int, lo: float = -10.0, hi: float = 10.0) -> np.ndarray:
        """Points of the solution set.

        Parameters
        ----------
        n : int
            Points along a line.
        lo, hi : float
            Range of M1(2) along the line.

        Returns
        -------
        numpy.ndarray
            (n, 2) points of the line, or the isolated points when the set is not a line.
        """
        if self.kind != "line":
            return self.points.copy()
        m2 = np.linspace(lo, hi, n)
        if abs(self.direction[1]) > 1e-12:
            t = (m2 - self.base[1]) / self.direction[1]
        else:
            t = m2
        return self.base[None, :] + t[:, None] * self.direction[None, :]


def _line_text(g) -> str:
    """'M1(1) + 1 M1(2) = 2': the line a = g0 - g1 M1(1) - g2 M1(2) = 0, normalised."""
    if abs(g[1]) >= abs(g[2]):
        return f"M1(1) {'+' if g[2] / g[1] >= 0 else '-'} {abs(g[2] / g[1]):.6g} M1(2) = {g[0] / g[1]:.6g}"
    return f"{g[1] / g[2]:.6g} M1(1) + M1(2) = {g[0] / g[2]:.6g}"


def ab_solution_set(tay: TaylorAB, tol: float = 1e-9) -> ABSet:
    """Every real solution of a = b = 0 when nu = 2 (the three-link biped).

    a = 0 is a line in the (M1(1), M1(2)) plane, M1 = base + t d, and along it b is a
    quadratic in t; its real roots are the isolated solutions (two at most: group 1
    with +sqrt of the discriminant, group 2 with -sqrt).  When the quadratic vanishes
    identically (coefficients below ``tol`` of their scale) the whole line solves
    a = b = 0.  That is the three-link biped's case: the swing foot's height does not
    depend on the torso, and moving along the line keeps both legs symmetric, so Z_sw
    stays 0 to every order.

    Parameters
    ----------
    tay : TaylorAB
        Of a robot with nu = 2.
    tol : float
        Relative tolerance of the degeneracy tests.

    Returns
    -------
    ABSet
        Points, line or none, with a message.
    """
    g, H = tay.grad, tay.hess
    if g.size != 3:
        raise ValueError(f"ab_solution_set is for nu = 2 (this robot has nu = {g.size - 1}; "
                         f"use solve_ab with the free components)")
    empty = np.zeros((0, 2))
    # a = g0 - g1 M1(1) - g2 M1(2) = 0
    if max(abs(g[1]), abs(g[2])) <= tol * max(1.0, abs(g[0])):
        return ABSet("none", empty, np.zeros(2), np.zeros(2), (),
                     "a does not depend on M1 (dZ_sw/dq2 = dZ_sw/dq3 = 0 at q^d(T)): "
                     "a = b = 0 has no isolated solution")
    if abs(g[1]) >= abs(g[2]):
        base, d = np.array([g[0] / g[1], 0.0]), np.array([-g[2] / g[1], 1.0])
    else:
        base, d = np.array([0.0, g[0] / g[2]]), np.array([1.0, -g[1] / g[2]])
    P, R = np.r_[1.0, -base], np.r_[0.0, -d]          # M_T(t) = P + t R
    c2, c1, c0 = 0.5 * R @ H @ R, P @ H @ R, 0.5 * P @ H @ P
    scale = max(float(np.max(np.abs(H))), 1e-300) * (P @ P + R @ R)
    small = [abs(c) <= tol * scale for c in (c2, c1, c0)]
    n = np.linalg.norm(d)
    d_unit, coeffs = d / n, (c2 / n**2, c1 / n, c0)    # per unit length along the line
    if all(small):
        return ABSet("line", empty, base, d_unit, coeffs,
                     f"b vanishes identically on the line a = 0, {_line_text(g)}: every "
                     f"M1 on it solves a = b = 0")
    if small[0] and small[1]:
        return ABSet("none", empty, base, d_unit, coeffs,
                     f"b = {c0:.3g} is constant and non-zero on the line a = 0: "
                     "a = b = 0 has no solution")
    if small[0]:
        roots = [-c0 / c1]
    else:
        disc = c1**2 - 4 * c2 * c0
        if disc < -tol * max(c1**2, abs(4 * c2 * c0)):
            return ABSet("none", empty, base, d_unit, coeffs,
                         f"b = 0 has no real root on the line a = 0 (discriminant "
                         f"{disc:.3g}): a = b = 0 has no solution")
        sq = math.sqrt(max(disc, 0.0))
        roots = [(-c1 + sign * sq) / (2 * c2) for sign in (+1, -1)]
        if sq == 0.0:
            roots = roots[:1]
    pts = np.array([base + t * d for t in roots])
    return ABSet("points", pts, base, d_unit, coeffs,
                 f"{len(pts)} isolated solution(s) of a = b = 0: "
                 + "; ".join(f"group {k}: M1 = [{p[0]:.6g}, {p[1]:.6g}]"
                             for k, p in enumerate(pts, start=1)))


def isolated_ab_solutions(tay: TaylorAB) -> np.ndarray:
    """The isolated solutions of a = b = 0 when nu = 2.

    Parameters
    ----------
    tay : TaylorAB
        Of a robot with nu = 2.

    Returns
    -------
    numpy.ndarray
        (k, 2), k = 0, 1 or 2 (empty when there are none, or when a whole line solves
        it: see :func:`ab_solution_set`).
    """
    return ab_solution_set(tay).points


@dataclass
class ABGroups:
    """The solution groups of a = b = 0 of a robot and gait, and what they are.

    Parameters
    ----------
    groups : list of int
        [1, 2] when nu >= 3; for nu = 2, [1] when the solutions form a line, [1] or
        [1, 2] for isolated points, [] when there is none.
    explanation : str
        What the groups are, in words.
    """

    groups: list
    explanation: str


def ab_groups(gait) -> ABGroups:
    """The solution groups of a = b = 0 that :func:`optimize_m1` accepts, and what they are.

    Parameters
    ----------
    gait : Reference
        Its reference gait.

    Returns
    -------
    ABGroups
    """
    model = gait.model
    if model.nu >= 3:
        return ABGroups([1, 2], "two groups (the roots of b = 0 on a = 0)")
    ab = ab_solution_set(taylor_ab(gait))
    if ab.kind == "line":
        return ABGroups([1], f"one line of solutions, group 1 ({ab.message})")
    return ABGroups(list(range(1, len(ab.points) + 1)), ab.message)


def group_of(tay: TaylorAB, M1, tol: float = 1e-6):
    """The a = b = 0 group M1 lies on.

    Parameters
    ----------
    tay : TaylorAB
        The Taylor coefficients of the gait.
    M1 : array_like
        (nu,) outputs.
    tol : float
        Relative distance that counts as on the group.

    Returns
    -------
    int or None
        1 or 2 (which root; 1 anywhere on the line when the solutions of a robot with
        nu = 2 form a line), None when on neither.
    """
    M1 = np.asarray(M1, float)
    if M1.size == 2:
        return ab_solution_set(tay).on_set(M1, tol)
    s = solve_ab(tay, *M1[1:-1])
    for k, sol in ((1, s.group1), (2, s.group2)):
        if np.all(np.isfinite(sol)) and np.max(np.abs(sol - M1)) <= tol * max(1, np.max(np.abs(M1))):
            return k
    return None


# ------------------------------------------------------------------ conjecture (Fig. 3)
def conjecture_figures(zsw: np.ndarray, max_abs: np.ndarray, status: np.ndarray) -> dict:
    """The paper's conjecture 'Z_sw(T^d) ~ 0 for every stable case', in numbers.

    Parameters
    ----------
    zsw : numpy.ndarray
        (n,) Z_sw(T^d) of each M1 (:func:`swing_height_at_Td`), m.
    max_abs : numpy.ndarray
        (n,) max ``|lambda|`` of each M1 (not used in the figures; kept for symmetry
        with the plot).
    status : numpy.ndarray
        (n,) statuses of docs: theory §4.

    Returns
    -------
    dict
        ``n_stable``, ``n_unstable`` and, when some M1 is stable,
        ``max_abs_zsw_stable``, ``median_abs_zsw_stable``,
        ``median_abs_zsw_unstable`` (m) and ``fraction_unstable_below`` (the share of
        unstable M1 whose ``|Z_sw|`` is below the largest of the stable ones).
    """
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
    """The grid of the free components and both groups' M1 on it.

    Parameters
    ----------
    tay : TaylorAB
        Of a robot with nu >= 3.
    n : int
        Points per free component.
    lo, hi : float
        Range of each free component.

    Returns
    -------
    ABSolution
        On the (n, ..., n) meshgrid ('ij') of the nu - 2 middle components (RABBIT: the
        (M1(2), M1(3)) grid of Fig. 4).
    """
    if tay.grad.size < 4:
        raise ValueError("domain_grid needs nu >= 3 (a free component); for nu = 2 see "
                         "ab_solution_set")
    v = np.linspace(lo, hi, n)
    free = np.meshgrid(*([v] * (tay.grad.size - 3)), indexing="ij")
    return solve_ab(tay, *free)


def coarse_grid_size(nu: int, budget: int = 6561) -> int:
    """Points per component of the coarse grid of a free M1.

    Parameters
    ----------
    nu : int
        Components of M1.
    budget : int
        Most grid points.

    Returns
    -------
    int
        The largest n with n^nu <= ``budget`` (9 for RABBIT, the paper's grid; 81 for
        nu = 2), at least 2.
    """
    n = max(2, int(round(budget ** (1.0 / nu))))
    while n ** nu > budget and n > 2:
        n -= 1
    return n
