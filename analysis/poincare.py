"""The restricted Poincaré map P^z of the hybrid zero dynamics (paper §IV, SPEC §4) and
its exact Jacobian A^z by algorithmic differentiation.

Zero dynamics (paper eq. 19 with M2 = I): with v = v^d + v_c and q_a = v - M1 q_u,

    (D11 - D12 M1) ddq_u = -D12 (ddv^d + ddv_c) - H1(q, dq),    v^d = M1 q_u^d + q_a^d.

The reference q_u^d(tau) enters through its own ODE (the unactuated row with q_a = q_a^d),
integrated alongside in the same scheme, so that past T it continues exactly as the gait
defines it and on the periodic orbit q_u == q_u^d holds to round-off in the discrete map.

One application from the section tau = 0.75 T: integrate to the impact time tau_i
(z_sw = 0, x_sw > 0, foot moving down; tau_i found by Newton, ``casadi.rootfinder``, on a
time-scaled RK4 integration, so d tau_i / dx comes from the implicit-function theorem),
apply the impact map and relabelling, compute y_i, dy_i (eq. 17), integrate the zero
dynamics with v_c from tau = 0 to 0.75 T.  A^z = dP^z/dx by AD through all of it.

Integration is fixed-step RK4 (``n_pre`` steps from 0.75 T to the impact, ``n_post``
from 0 to 0.75 T); the Jacobian is the exact derivative of that discrete map, which
agrees with finite differences of a tolerance-1e-12 integration to ~1e-8 relative at
the defaults (tests/test_poincare.py measures it).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import casadi as ca
import numpy as np

from biped_casadi.correction import v_correction

__all__ = ["PoincareMap", "PoincareResult", "poincare_eigenvalues", "singular_m1_values",
           "STATUSES", "poincare_map"]

#: status of an analysed M1 (SPEC section 4)
STATUSES = ("stable", "unstable", "singular", "no_impact")
SECTION = 0.75   # tau = 0.75 T


@dataclass
class PoincareResult:
    """Linearised restricted Poincaré map at the fixed point for one M1."""
    M1: np.ndarray
    A: np.ndarray               # 2x2 Jacobian A^z
    eigenvalues: np.ndarray     # complex, |.| descending
    max_abs: float
    status: str
    x_star: np.ndarray          # (q_u^d(0.75T), dq_u^d(0.75T))
    fixed_point_residual: float = math.nan
    tau_impact: float = math.nan
    min_denominator: float = math.nan   # min over the step of |D11 - D12 M1|
    message: str = ""

    def to_dict(self) -> dict:
        return dict(M1=self.M1.tolist(), A=self.A.tolist(),
                    eigenvalues=[[float(e.real), float(e.imag)] for e in self.eigenvalues],
                    max_abs=self.max_abs, status=self.status, x_star=self.x_star.tolist(),
                    fixed_point_residual=self.fixed_point_residual,
                    tau_impact=self.tau_impact, min_denominator=self.min_denominator,
                    message=self.message)


def _check_M1(M1) -> np.ndarray:
    a = np.asarray(M1, dtype=float)
    if a.shape != (4,):
        raise ValueError(f"M1 must have 4 components, got shape {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"M1 must be finite, got {a.tolist()}")
    return a


class PoincareMap:
    """P^z and A^z for one (model, gait) pair.  Build once, evaluate for many M1.

    ``evaluate(x, M1)`` -> (x_next, tau_impact) for any section state x = (q_u, dq_u);
    ``analyse(M1)`` -> :class:`PoincareResult` at the fixed point x* = the gait's state at
    0.75 T; ``analyse_batch(M1s)`` the same for an (n, 4) array, in parallel threads.
    """

    def __init__(self, model, gait, n_pre: int = 80, n_post: int = 240, n_scan: int = 250,
                 horizon: float = 2.0, threads: int | None = None):
        if gait.model.params != model.params:
            raise ValueError("gait was made for other robot parameters than the model")
        self.model, self.gait = model, gait
        self.T = T = gait.T
        self.n_pre, self.n_post, self.n_scan = n_pre, n_post, n_scan
        self.horizon = horizon
        self.tau_s = SECTION * T
        self.x_star = gait.state_at(self.tau_s)
        self.ref_s = self.x_star.copy()          # reference (q_u^d, dq_u^d) at 0.75 T
        self.ref_0 = np.array(gait.x0, dtype=float)
        import os
        self.threads = threads or max(1, min(os.cpu_count() or 1, 8))
        self._build()
        self._denominator_table()
        self._variational = None

    # ---------------------------------------------------------------- build
    def _build(self):
        m, g, T = self.model, self.gait, self.T
        ref = g._ref
        alpha = ca.DM(g.alpha)
        M1 = ca.SX.sym("M1", 4)
        yi = ca.SX.sym("yi", 4)
        dyi = ca.SX.sym("dyi", 4)
        z = ca.SX.sym("z", 4)          # (q_u, dq_u, q_u^d, dq_u^d)
        tau = ca.SX.sym("tau")
        qa_d, dqa_d, ddqa_d = ref.qa(alpha, tau / T, T)
        # reference: unactuated row with q_a = q_a^d
        qd = ca.vertcat(z[2], qa_d)
        dqd = ca.vertcat(z[3], dqa_d)
        ddr = ref.ddqu(qd, dqd, ddqa_d)
        vc, dvc, ddvc = v_correction(tau, yi, dyi, T)
        qa = qa_d + M1 * (z[2] - z[0]) + vc
        dqa = dqa_d + M1 * (z[3] - z[1]) + dvc
        ddv = M1 * ddr + ddqa_d + ddvc
        q = ca.vertcat(z[0], qa)
        dq = ca.vertcat(z[1], dqa)
        D = m.D(q)
        H = m.H(q, dq)
        den = D[0, 0] - ca.mtimes(D[0, 1:], M1)
        ddqu = (-ca.mtimes(D[0, 1:], ddv) - H[0]) / den          # eq. (19)
        rhs = ca.vertcat(z[1], ddqu, z[3], ddr)
        f = ca.Function("zero_dynamics", [z, tau, M1, yi, dyi], [rhs],
                        ["z", "tau", "M1", "yi", "dyi"], ["dz"])
        self.zero_dynamics = f
        self.configuration = ca.Function("zd_configuration", [z, tau, M1, yi, dyi], [q, dq],
                                         ["z", "tau", "M1", "yi", "dyi"], ["q", "dq"])
        h = ca.SX.sym("h")
        k1 = f(z, tau, M1, yi, dyi)
        k2 = f(z + h / 2 * k1, tau + h / 2, M1, yi, dyi)
        k3 = f(z + h / 2 * k2, tau + h / 2, M1, yi, dyi)
        k4 = f(z + h * k3, tau + h, M1, yi, dyi)
        step = ca.Function("zd_rk4", [z, tau, h, M1, yi, dyi],
                           [z + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4), tau + h])
        self._step = step

        q0, dq0 = self.configuration(z, tau, M1, ca.DM.zeros(4), ca.DM.zeros(4))  # v_c = 0
        xs, zsw = m.swing_foot(q0)
        dxs, dzsw = m.swing_foot_velocity(q0, dq0)
        self.guard = ca.Function("guard", [z, tau, M1], [zsw, xs, dzsw],
                                 ["z", "tau", "M1"], ["z_sw", "x_sw", "dz_sw"])
        zero4 = ca.DM.zeros(4)

        # pre-impact segment 0.75T -> tau_i, time-scaled (MX)
        x = ca.MX.sym("x", 2)
        M1m = ca.MX.sym("M1", 4)
        ti = ca.MX.sym("tau_i")
        zs0 = ca.vertcat(x, ca.DM(self.ref_s))
        acc_pre = step.mapaccum("pre_acc", self.n_pre, [0, 1], [0, 1])
        hpre = (ti - self.tau_s) / self.n_pre
        Zpre, _ = acc_pre(zs0, self.tau_s, hpre, M1m, zero4, zero4)
        z_minus = Zpre[:, -1]
        self.pre = ca.Function("pre_impact", [x, M1m, ti], [z_minus], ["x", "M1", "tau_i"], ["z"])
        zg, _, _ = self.guard(z_minus, ti, M1m)
        G = ca.Function("guard_residual", [ti, x, M1m], [zg])
        rf = ca.rootfinder("impact_time", "newton", G,
                           {"abstol": 1e-14, "max_iter": 30, "error_on_fail": False})
        t_guess = ca.MX.sym("tau_guess")
        tau_i = rf(t_guess, x, M1m)
        z_m = self.pre(x, M1m, tau_i)
        q_m, dq_m = self.configuration(z_m, tau_i, M1m, zero4, zero4)
        q_p, dq_p = m.impact(q_m, dq_m)
        Mq = lambda v: M1m * v[0] + v[1:]                               # noqa: E731
        qd0 = ca.vertcat(self.ref_0[0], ref.qa(alpha, 0, T)[0])
        dqd0 = ca.vertcat(self.ref_0[1], ref.qa(alpha, 0, T)[1])
        y_i = Mq(q_p) - Mq(qd0)
        dy_i = Mq(dq_p) - Mq(dqd0)
        z_p = ca.vertcat(q_p[0], dq_p[0], ca.DM(self.ref_0))
        acc_post = step.mapaccum("post_acc", self.n_post, [0, 1], [0, 1])
        Zpost, _ = acc_post(z_p, 0.0, self.tau_s / self.n_post, M1m, y_i, dy_i)
        x_next = Zpost[:2, -1]
        self.map = ca.Function("poincare_map", [x, M1m, t_guess], [x_next, tau_i],
                               ["x", "M1", "tau_guess"], ["x_next", "tau_i"])
        A = ca.jacobian(x_next, x)
        self.map_jac = ca.Function("poincare_jacobian", [x, M1m, t_guess], [A, x_next, tau_i],
                                   ["x", "M1", "tau_guess"], ["A", "x_next", "tau_i"])
        # scan for the first valid impact (for states away from the fixed point)
        hs = (self.horizon * T - self.tau_s) / self.n_scan
        acc_scan = step.mapaccum("scan_acc", self.n_scan, [0, 1], [0, 1])
        Zs, taus = acc_scan(zs0, self.tau_s, hs, M1m, zero4, zero4)
        gz, gx, gd = self.guard.map(self.n_scan)(Zs, taus, M1m)
        self.scan = ca.Function("impact_scan", [x, M1m], [taus, gz, gx, gd],
                                ["x", "M1"], ["tau", "z_sw", "x_sw", "dz_sw"])
        self._batch = {}

    def _denominator_table(self, n: int = 1001):
        """D11 and D12 along the reference on [0, T] for the singularity test (eq. 23-24)."""
        t = np.linspace(0, self.T, n)
        q = self.gait.q(t)
        D = np.array(self.model.D.map(n)(q)).reshape(5, 5, n, order="F")
        self._D11 = D[0, 0]
        self._D12 = D[0, 1:]          # 4 x n

    # ----------------------------------------------------------- evaluation
    def denominator(self, M1) -> np.ndarray:
        """D11 - D12 M1 along the reference (1001 points on [0, T])."""
        return self._D11 - _check_M1(M1) @ self._D12

    def is_singular(self, M1) -> bool:
        """eq. (23)-(24): D11 - D12 M1 vanishes or changes sign on the step."""
        return bool(self._screen(_check_M1(M1)[None])[2][0])

    def _screen(self, M1s):
        """Validated (n, 4) M1 array, D11 - D12 M1 along the step (n, 1001), singular mask."""
        M1s = np.asarray(M1s, dtype=float)
        if M1s.ndim != 2 or M1s.shape[1] != 4:
            raise ValueError(f"M1s must be an (n, 4) array, got shape {M1s.shape}")
        if not np.all(np.isfinite(M1s)):
            raise ValueError("M1s must be finite")
        den = self._D11[None, :] - M1s @ self._D12
        sing = (den.min(1) * den.max(1) <= 0) | (np.abs(den).min(1) < 1e-9 * np.abs(den).max(1))
        return M1s, den, sing

    def find_impact(self, x, M1):
        """First valid impact after 0.75T within the horizon (z_sw crosses 0 downward with
        x_sw > 0): a bracket [tau_a, tau_b] on the scan grid, or None."""
        taus, gz, gx, gd = (np.array(v).ravel() for v in self.scan(x, M1))
        prev = np.r_[self.tau_s, taus[:-1]]
        gz0 = float(self.guard(ca.vertcat(x, self.ref_s), self.tau_s, M1)[0])
        prev_z = np.r_[gz0, gz[:-1]]
        ok = np.isfinite(gz) & np.isfinite(prev_z)
        hit = ok & (prev_z > 0) & (gz <= 0) & (gx > 0)
        if not hit.any():
            return None
        k = int(np.argmax(hit))
        # linear interpolation inside the bracket as Newton's start
        t_lin = prev[k] + (taus[k] - prev[k]) * prev_z[k] / (prev_z[k] - gz[k])
        return prev[k], taus[k], t_lin

    def evaluate(self, x, M1):
        """P^z(x) for a section state x = (q_u, dq_u) and output matrix M1; returns
        (x_next, tau_impact) or raises ValueError when no valid impact occurs."""
        x = np.asarray(x, dtype=float).ravel()
        if x.shape != (2,) or not np.all(np.isfinite(x)):
            raise ValueError(f"x must be 2 finite numbers (q_u, dq_u), got {x.tolist()}")
        M1 = _check_M1(M1)
        br = self.find_impact(x, M1)
        if br is None:
            raise ValueError("no valid impact of the swing foot within the horizon (2 T)")
        xn, ti = self.map(x, M1, br[2])
        ti = float(ti)
        if not (br[0] - 1e-9 <= ti <= br[1] + 1e-9):
            raise ValueError("impact-time Newton left the bracket of the first impact")
        return np.array(xn).ravel(), ti

    def analyse(self, M1) -> PoincareResult:
        """A^z, eigenvalues and status (SPEC section 4) at the fixed point for one M1."""
        M1 = _check_M1(M1)
        d = self.denominator(M1)
        min_den = float(np.min(np.abs(d)))
        nan2 = np.full((2, 2), np.nan)
        if self.is_singular(M1):
            return PoincareResult(M1, nan2, np.full(2, complex(np.nan, np.nan)), math.inf, "singular",
                                  self.x_star, min_denominator=min_den,
                                  message="D11 - D12 M1 vanishes or changes sign on the step")
        br = self.find_impact(self.x_star, M1)
        if br is None:
            return PoincareResult(M1, nan2, np.full(2, complex(np.nan, np.nan)), math.inf, "no_impact",
                                  self.x_star, min_denominator=min_den,
                                  message="no valid swing-foot impact within 2 T")
        A, xn, ti = (np.array(v) for v in self.map_jac(self.x_star, M1, br[2]))
        return self._result(M1, A, xn.ravel(), ti.item(), min_den)

    def _result(self, M1, A, xn, ti, min_den):
        if not np.all(np.isfinite(A)):
            return PoincareResult(M1, A, np.full(2, complex(np.nan, np.nan)), math.inf, "no_impact",
                                  self.x_star, tau_impact=ti, min_denominator=min_den,
                                  message="integration of the zero dynamics broke down")
        ev = np.linalg.eigvals(A)
        ev = ev[np.argsort(-np.abs(ev))]
        mx = float(np.max(np.abs(ev)))
        return PoincareResult(M1, A, ev, mx, "stable" if mx < 1 else "unstable", self.x_star,
                              fixed_point_residual=float(np.max(np.abs(xn - self.x_star))),
                              tau_impact=ti, min_denominator=min_den)

    @property
    def variational(self):
        """The batched variational-equation Jacobian (analysis.variational)."""
        if self._variational is None:
            from .variational import VariationalJacobian
            self._variational = VariationalJacobian(self.model, self.gait, self.tau_s,
                                                    self.n_pre, self.n_post)
        return self._variational

    def jacobian_batch(self, M1s, chunk: int = 512):
        """Statuses, A^z (n, 2, 2) and max|lambda| for an (n, 4) array of M1 by the
        vectorised variational equation (fast path for sweeps; agrees with
        :meth:`analyse` to integration accuracy).  Singular M1 get NaN."""
        M1s, den, sing = self._screen(M1s)
        A = np.full((len(M1s), 2, 2), np.nan)
        ok = np.flatnonzero(~sing)
        for a in range(0, len(ok), chunk):
            part = ok[a:a + chunk]
            A[part] = self.variational.jacobians(M1s[part], threads=self.threads)
        with np.errstate(invalid="ignore"):
            ev = np.linalg.eigvals(np.where(np.isfinite(A), A, 0.0))
        max_abs = np.where(sing, np.inf, np.abs(ev).max(axis=1))
        bad = ~sing & ~np.all(np.isfinite(A), axis=(1, 2))
        max_abs[bad] = np.inf
        status = np.where(sing, "singular", np.where(bad, "no_impact",
                          np.where(max_abs < 1, "stable", "unstable")))
        ev[sing | bad] = np.nan
        return status, A, ev, max_abs

    def analyse_batch(self, M1s, chunk: int = 64) -> list[PoincareResult]:
        """:meth:`analyse` (full AD through the discrete map) for an (n, 4) array;
        singular cases are screened first, the others evaluated with
        ``map(..., 'thread')`` starting Newton at tau = T (the fixed point's impact time),
        which converges in one or two iterations."""
        M1s, den, sing = self._screen(M1s)
        out: list = [None] * len(M1s)
        idx = np.flatnonzero(~sing)
        for i in np.flatnonzero(sing):
            out[i] = PoincareResult(M1s[i], np.full((2, 2), np.nan), np.full(2, complex(np.nan, np.nan)),
                                    math.inf, "singular", self.x_star,
                                    min_denominator=float(np.abs(den[i]).min()),
                                    message="D11 - D12 M1 vanishes or changes sign on the step")
        for a in range(0, len(idx), chunk):
            part = idx[a:a + chunk]
            n = len(part)
            f = self._batch_fn(n)
            A, xn, ti = (np.array(v) for v in f(np.repeat(self.x_star[:, None], n, 1),
                                                  M1s[part].T, np.full((1, n), self.T)))
            for j, i in enumerate(part):
                Aj = A[:, 2 * j:2 * j + 2]
                tij = float(ti[0, j])
                if not (np.isfinite(tij) and abs(tij - self.T) < 0.05 * self.T):
                    out[i] = self.analyse(M1s[i])      # unusual: full scan
                else:
                    out[i] = self._result(M1s[i], Aj, xn[:, j], tij,
                                          float(np.abs(den[i]).min()))
        return out

    def _batch_fn(self, n):
        if n not in self._batch:
            self._batch[n] = self.map_jac.map(n, "thread", self.threads)
        return self._batch[n]


def singular_m1_values(model, gait) -> np.ndarray:
    """M1(j) = D11 / D12(j) at q^d(T), the single-component singular values (eq. 24)."""
    D = np.array(model.D(gait.q(gait.T)))
    return D[0, 0] / D[0, 1:]


_CACHE: dict = {}


def poincare_map(model, gait, **kw) -> PoincareMap:
    """A cached :class:`PoincareMap` per (model, gait object, options)."""
    key = (id(model), id(gait), tuple(sorted(kw.items())))
    pm = _CACHE.get(key)
    if pm is None or pm.gait is not gait or pm.model is not model:
        pm = _CACHE[key] = PoincareMap(model, gait, **kw)
    return pm


def poincare_eigenvalues(m, g, M1) -> PoincareResult:
    """SPEC section 5: ``r.A`` (2x2 A^z), ``r.eigenvalues``, ``r.max_abs``, ``r.status``."""
    return poincare_map(m, g).analyse(M1)
