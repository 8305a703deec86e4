"""The restricted Poincaré map P^z of the hybrid zero dynamics (paper §IV, docs: theory §4) and
its exact Jacobian A^z.

Zero dynamics (paper eq. 19 with M2 = I): the outputs follow v = v^d + v_c, so
q_a = v - M1 q_u (eq. 10), and the first row of eq. (1) gives ddq_u (eq. 23 with
ddv = ddv^d + ddv_c); both come from :mod:`biped_casadi.control.output_law`.  The reference
state (q_u^d, dq_u^d) is integrated alongside in the same scheme, so that past T it
continues exactly as the gait defines it and on the periodic orbit q_u == q_u^d holds to
round-off in the discrete map.

One application from the section tau = 0.75 T: integrate to the impact time tau_i
(z_sw = 0, x_sw > 0, foot moving down; tau_i found by Newton, ``casadi.rootfinder``, on a
time-scaled RK4 integration, so d tau_i / dx comes from the implicit-function theorem),
apply the impact map and relabelling, compute y_i, dy_i (eq. 17), integrate the zero
dynamics with v_c from tau = 0 to 0.75 T.

Two ways to A^z, which agree to integration accuracy (tests/test_poincare.py):

- ``method="variational"`` (default): the variational equation along the orbit
  (:mod:`analysis.stability.variational`), one SX Function of M1, well under a millisecond per M1;
- ``method="ad"``: AD through the whole discrete map (~0.3 s per M1), for verification
  and for the map away from the fixed point.

Integration is fixed-step RK4 (``n_pre`` steps from 0.75 T to the impact, ``n_post``
from 0 to 0.75 T); the Jacobian is the exact derivative of that discrete map.
"""
from __future__ import annotations

import math
import os
from dataclasses import dataclass

import casadi as ca
import numpy as np

from biped_casadi import require_same_robot
from biped_casadi.caching import cached
from biped_casadi.control import PAPER_REJOIN, Design, require_reference
from biped_casadi.control.zero_dynamics import denominator_samples, zero_dynamics
from biped_casadi.numerics import as_count, as_number, as_vector, rk4_step
from biped_casadi.simulation.kernel import strike
from biped_casadi.control.output_law import (SECTION, check_M1, check_M1_range, check_rejoin,
                                     decoupling_denominator, is_singular)
from biped_casadi.results import Result

from .variational import variational_jacobian

__all__ = ["PoincareMap", "PoincareResult", "JacobianBatch", "Screen", "ImpactBracket",
           "MapStep", "poincare_eigenvalues", "singular_m1_values", "STATUSES", "METHODS",
           "poincare_map", "FIXED_POINT_TOL"]

#: status of an analysed M1 (docs: theory §4), and 'open_orbit': x* is not a fixed point
#: (the gait is not a periodic orbit of the model), so A^z at x* says nothing of stability
STATUSES = ("stable", "unstable", "singular", "no_impact", "open_orbit")
#: |P(x*) - x*| beyond this is an open orbit (the discrete map closes the default gait
#: to ~5e-10; docs: theory §2 asks 1e-8 of the gait itself)
FIXED_POINT_TOL = 1e-6
#: how A^z is computed
METHODS = ("variational", "ad")


@dataclass
class PoincareResult(Result):
    """Linearised restricted Poincaré map at the fixed point for one M1.

    ``success`` means A^z was computed (the status is 'stable' or 'unstable').

    Parameters
    ----------
    M1 : numpy.ndarray
        The outputs analysed, (nu,).
    A : numpy.ndarray
        The 2x2 Jacobian A^z of eq. (20), in the section coordinates (q_u, dq_u); NaN
        when undefined.
    eigenvalues : numpy.ndarray
        Its two eigenvalues (complex), ``|.|`` descending.
    max_abs : float
        max ``|lambda|`` (inf when singular or without impact).
    status : str
        One of :data:`STATUSES`: 'stable' (max ``|lambda|`` < 1, eq. 22), 'unstable',
        'singular' (D11 - D12 M1 vanishes or changes sign on the step, eq. 24),
        'no_impact', or 'open_orbit': ``fixed_point_residual`` exceeds
        :data:`FIXED_POINT_TOL`, the gait is not a periodic orbit of the model (A^z and
        its eigenvalues are then those of the map at a point that is not a fixed point).
    x_star : numpy.ndarray
        The fixed point (q_u^d(0.75 T), dq_u^d(0.75 T)), rad and rad/s.
    fixed_point_residual : float
        max ``|P(x*) - x*|`` of the discrete map (every method checks it).
    tau_impact : float
        Impact time of the orbit, s (T on the reference).
    min_denominator : float
        The smallest ``|D11 - D12 M1|`` on the step (eq. 24).
    method : {'variational', 'ad'}
        How A^z was computed.
    message : str
        Why A^z is undefined (empty otherwise).
    """

    M1: np.ndarray
    A: np.ndarray
    eigenvalues: np.ndarray
    max_abs: float
    status: str
    x_star: np.ndarray
    fixed_point_residual: float = math.nan
    tau_impact: float = math.nan
    min_denominator: float = math.nan
    method: str = "variational"
    message: str = ""

    SUCCESS = ("stable", "unstable")


@dataclass
class JacobianBatch:
    """A^z and the status of many M1 at once (row i = M1 i).

    ``success`` means the batch was analysed; each M1's verdict is in ``status``.

    Parameters
    ----------
    M1 : numpy.ndarray
        (n, nu) the outputs analysed.
    status : numpy.ndarray
        (n,) one of :data:`STATUSES` per M1.
    A : numpy.ndarray
        (n, 2, 2) A^z; NaN where singular or without impact.
    eigenvalues : numpy.ndarray
        (n, 2) complex; NaN where undefined.
    max_abs : numpy.ndarray
        (n,) max ``|lambda|``; inf where undefined.
    """

    M1: np.ndarray
    status: np.ndarray
    A: np.ndarray
    eigenvalues: np.ndarray
    max_abs: np.ndarray

    success = True


@dataclass
class Screen:
    """Many M1 validated and screened for the singularity of eq. (24).

    Parameters
    ----------
    M1 : numpy.ndarray
        (n, nu) the outputs as floats.
    denominator : numpy.ndarray
        (n, 1001) D11 - D12 M1 along the step.
    singular : numpy.ndarray
        (n,) True where it vanishes or changes sign.
    """

    M1: np.ndarray
    denominator: np.ndarray
    singular: np.ndarray


@dataclass
class ImpactBracket:
    """The scan-grid interval that holds the first valid impact after the section.

    Parameters
    ----------
    tau_a, tau_b : float
        The nodes before and at the strike, s.
    guess : float
        The linear interpolation of the strike between them, s (Newton's start).
    """

    tau_a: float
    tau_b: float
    guess: float


@dataclass
class MapStep:
    """One application of the restricted Poincaré map.

    Parameters
    ----------
    x_next : numpy.ndarray
        (q_u, dq_u) at the next section, rad and rad/s.
    tau_impact : float
        The impact time, s.
    """

    x_next: np.ndarray
    tau_impact: float


class PoincareMap:
    """The restricted Poincaré map P^z and its Jacobian A^z for one model and gait.

    Implements eq. (20): one application of P^z integrates the hybrid zero
    dynamics of eq. (19) (outputs v = v^d + v_c, q from eq. 10, ddq_u from eq. 23) from
    the section tau = 0.75 T to the impact, applies the impact map and relabelling,
    takes y_i, dy_i (eq. 17) and integrates back to the section; A^z of eq. (20) is its
    exact Jacobian at the fixed point x* (the variational equation, or AD through the
    whole discrete map and the impact time).  Build once, evaluate for many M1.

    Parameters
    ----------
    model : BipedModel
        The robot.
    gait : Reference
        The reference step, made for ``model``.
    n_pre, n_post : int
        RK4 steps from the section to the impact, and from the impact to the section.
    n_scan : int
        Steps of the scan for the first valid impact away from the fixed point.
    horizon : float
        The swing foot must strike before ``horizon * T``.
    rejoin : float
        Rejoin time of v_c as a fraction of T (the paper: 1/2).
    threads : int, optional
        Threads for batch evaluation (default: the cores, at most 8).

    Notes
    -----
    ``evaluate(x, M1)`` -> (x_next, tau_impact) for any section state x = (q_u, dq_u);
    ``analyse(M1)`` -> :class:`PoincareResult` at the fixed point x* = the gait's state
    at 0.75 T; ``jacobian_batch(M1s)`` the same for an (n, nu) array, vectorised.
    """

    def __init__(self, model, gait, n_pre: int = 80, n_post: int = 240, n_scan: int = 250,
                 horizon: float = 2.0, rejoin: float = PAPER_REJOIN, threads: int | None = None):
        require_same_robot(model, require_reference(gait))
        self.model, self.gait = model, gait
        self.nu = model.nu
        self.T = T = gait.T
        self.n_pre, self.n_post, self.n_scan = map(as_count, (n_pre, n_post, n_scan),
                                                   ("n_pre", "n_post", "n_scan"))
        if (h := as_number(horizon, "horizon")) <= SECTION:
            raise ValueError(f"horizon must exceed {SECTION} (the section), got {horizon!r}")
        self.horizon, self.rejoin, self.tau_s = h, check_rejoin(rejoin), SECTION * T
        self.x_star = gait.state_at(self.tau_s)
        self.ref_s = gait.state(self.tau_s)           # reference state at the section
        self.ref_0 = np.asarray(gait.r0, dtype=float)
        self.threads = as_count(threads or min(os.cpu_count() or 1, 8), "threads")
        self._open = None
        self._build()
        #: D11 and D12 along the reference on [0, T] (1001 points), for eq. (23)-(24)
        self.D11_table, self.D12_table = denominator_samples(gait)

    @property
    def cache_key(self):
        """What the map depends on: the gait and the discretisation."""
        return (self.gait.cache_key, self.n_pre, self.n_post, self.n_scan, self.horizon,
                self.rejoin)

    # ---------------------------------------------------------------- build
    def _build(self):
        m, T, nu = self.model, self.T, self.nu
        zd = zero_dynamics(m)
        fz = zd.along(self.gait)                       # eq. (19), reference alongside
        t_c = self.rejoin * T
        z, tau, h = ca.SX.sym("z", fz.size1_in(0)), ca.SX.sym("tau"), ca.SX.sym("h")
        M1, yi, dyi = ca.SX.sym("M1", nu), ca.SX.sym("yi", nu), ca.SX.sym("dyi", nu)
        P = zd.params(M1, t_c, yi, dyi)
        z_next = rk4_step(lambda zz, c: fz(zz, tau + c * h, P)[0], z, h)
        step = ca.Function("zd_rk4", [z, tau, h, M1, yi, dyi], [z_next, tau + h])
        _, q_z, dq_z = fz(z, tau, P)
        self.configuration = ca.Function("zd_configuration", [z, tau, M1, yi, dyi], [q_z, dq_z],
                                         ["z", "tau", "M1", "yi", "dyi"], ["q", "dq"])

        zero = ca.DM.zeros(nu)
        q0, dq0 = self.configuration(z, tau, M1, zero, zero)        # v_c = 0 after rejoin
        xs, zsw = m.swing_foot(q0)
        _, dzsw = m.swing_foot_velocity(q0, dq0)
        self.guard = ca.Function("guard", [z, tau, M1], [zsw, xs, dzsw],
                                 ["z", "tau", "M1"], ["z_sw", "x_sw", "dz_sw"])

        # pre-impact segment 0.75T -> tau_i, time-scaled (MX)
        x = ca.MX.sym("x", 2)
        M1m = ca.MX.sym("M1", nu)
        ti = ca.MX.sym("tau_i")
        zs0 = ca.vertcat(x, ca.DM(self.ref_s))
        Zpre, _ = step.mapaccum("pre_acc", self.n_pre, [0, 1], [0, 1])(
            zs0, self.tau_s, (ti - self.tau_s) / self.n_pre, M1m, zero, zero)
        self.pre = ca.Function("pre_impact", [x, M1m, ti], [Zpre[:, -1]],
                               ["x", "M1", "tau_i"], ["z"])
        zg, _, _ = self.guard(Zpre[:, -1], ti, M1m)
        rf = ca.rootfinder("impact_time", "newton", ca.Function("guard_residual", [ti, x, M1m], [zg]),
                           {"abstol": 1e-14, "max_iter": 30, "error_on_fail": False})
        t_guess = ca.MX.sym("tau_guess")
        tau_i = rf(t_guess, x, M1m)
        q_m, dq_m = self.configuration(self.pre(x, M1m, tau_i), tau_i, M1m, zero, zero)
        q_p, dq_p = m.impact(q_m, dq_m)
        R0 = np.concatenate(self.gait.evaluate(0.0))
        _, y_i, dy_i = zd.step_start(q_p, dq_p, R0, M1m)                    # eq. (17)
        z_p = ca.vertcat(q_p[0], dq_p[0], ca.DM(self.ref_0))
        Zpost, _ = step.mapaccum("post_acc", self.n_post, [0, 1], [0, 1])(
            z_p, 0.0, self.tau_s / self.n_post, M1m, y_i, dy_i)
        x_next = Zpost[:2, -1]
        self.map = ca.Function("poincare_map", [x, M1m, t_guess], [x_next, tau_i],
                               ["x", "M1", "tau_guess"], ["x_next", "tau_i"])
        self.map_jac = ca.Function("poincare_jacobian", [x, M1m, t_guess],
                                   [ca.jacobian(x_next, x), x_next, tau_i],
                                   ["x", "M1", "tau_guess"], ["A", "x_next", "tau_i"])
        # scan for the first valid impact (for states away from the fixed point)
        hs = (self.horizon * T - self.tau_s) / self.n_scan
        Zs, taus = step.mapaccum("scan_acc", self.n_scan, [0, 1], [0, 1])(
            zs0, self.tau_s, hs, M1m, zero, zero)
        gz, gx, gd = self.guard.map(self.n_scan)(Zs, taus, M1m)
        self.scan = ca.Function("impact_scan", [x, M1m], [taus, gz, gx, gd],
                                ["x", "M1"], ["tau", "z_sw", "x_sw", "dz_sw"])

    # ----------------------------------------------------------- evaluation
    @property
    def fixed_point_residual(self) -> float:
        """``|P(x*) - x*|`` with M1 = 0 (never singular: D11 > 0), computed once per map.

        On a periodic gait x* is the fixed point for every M1 (the reference itself is
        the trajectory from x* with the outputs on it), so this one evaluation of the map
        qualifies :meth:`analyse` with the variational method and the batches of
        :meth:`jacobian_batch`."""
        if self._open is None:
            zero = np.zeros(self.nu)
            br = self.find_impact(self.x_star, zero)
            res = math.inf if br is None else float(np.max(np.abs(
                np.array(self.map(self.x_star, zero, br.guess)[0]).ravel() - self.x_star)))
            self._residual, self._open = res, not res <= FIXED_POINT_TOL
        return self._residual

    @property
    def open_orbit(self) -> bool:
        """Whether x* fails to be a fixed point of the map (the gait is not an orbit).

        That is, :attr:`fixed_point_residual` is above :data:`FIXED_POINT_TOL`."""
        self.fixed_point_residual
        return self._open

    @property
    def variational(self):
        """The variational-equation Jacobian of this map (:mod:`analysis.stability.variational`)."""
        return variational_jacobian(self.gait, self.tau_s, self.n_pre,
                                    self.n_post, self.rejoin)

    def denominator(self, M1) -> np.ndarray:
        """The decoupling denominator D11 - D12 M1 of eq. (24) along the reference.

        Parameters
        ----------
        M1 : array_like
            (nu,).

        Returns
        -------
        numpy.ndarray
            (1001,): at 1001 points of [0, T].
        """
        return decoupling_denominator(self.D11_table, self.D12_table, check_M1(M1, self.nu))

    def is_singular(self, M1) -> bool:
        """Whether D11 - D12 M1 vanishes or changes sign on the step (eq. 23-24).

        Parameters
        ----------
        M1 : array_like
            (nu,).

        Returns
        -------
        bool
        """
        return bool(self.screen(check_M1(M1, self.nu)[None]).singular[0])

    def screen(self, M1s):
        """Validate many M1 and find the singular ones.

        Parameters
        ----------
        M1s : array_like
            (n, nu) output matrices.

        Returns
        -------
        Screen
            The M1 as floats, D11 - D12 M1 along the step and the singular ones.

        Raises
        ------
        ValueError
            Wrong shape, a non-finite value, or a component beyond ``M1_LIMIT``.
        """
        M1s = np.asarray(M1s, dtype=float)
        if M1s.ndim != 2 or M1s.shape[1] != self.nu:
            raise ValueError(f"M1s must be an (n, {self.nu}) array, got shape {M1s.shape}")
        if not np.all(np.isfinite(M1s)):
            raise ValueError("M1s must be finite")
        check_M1_range(M1s, "M1s")
        den = decoupling_denominator(self.D11_table, self.D12_table, M1s.T)    # (n, 1001)
        return Screen(M1s, den, is_singular(den, axis=1))

    def find_impact(self, x, M1):
        """The first valid impact after 0.75 T within the horizon, on the scan grid.

        Valid: z_sw crosses 0 downward with x_sw > 0 (beyond ``model.scuff_zone`` for
        legs without knees).

        Parameters
        ----------
        x : array_like
            Section state (q_u, dq_u) at tau = 0.75 T.
        M1 : array_like
            (nu,).

        Returns
        -------
        ImpactBracket or None
            The interval that holds the impact; None when there is no valid impact.
        """
        taus, gz, gx, gd = (np.array(v).ravel() for v in self.scan(x, M1))
        prev = np.r_[self.tau_s, taus[:-1]]
        gz0 = float(self.guard(ca.vertcat(x, self.ref_s), self.tau_s, M1)[0])
        prev_z = np.r_[gz0, gz[:-1]]
        ok = np.isfinite(gz) & np.isfinite(prev_z)
        hit = ok & strike(gz, prev_z, gx, self.model.scuff_zone)
        if not hit.any():
            return None
        k = int(np.argmax(hit))
        t_lin = prev[k] + (taus[k] - prev[k]) * prev_z[k] / (prev_z[k] - gz[k])
        return ImpactBracket(float(prev[k]), float(taus[k]), float(t_lin))

    def evaluate(self, x, M1):
        """P^z(x) for a section state x = (q_u, dq_u) and outputs M1.

        Parameters
        ----------
        x : array_like
            (q_u, dq_u) at tau = 0.75 T, rad and rad/s (any state, not only x*).
        M1 : array_like
            (nu,).

        Returns
        -------
        MapStep
            The next section state and the impact time.

        Raises
        ------
        ValueError
            When no valid impact occurs within the horizon.
        """
        x = as_vector(np.ravel(x), 2, "x")
        M1 = check_M1(M1, self.nu)
        br = self.find_impact(x, M1)
        if br is None:
            raise ValueError(f"no valid impact of the swing foot within the horizon "
                             f"({self.horizon:g} T)")
        xn, ti = self.map(x, M1, br.guess)
        ti = float(ti)
        if not (br.tau_a - 1e-9 <= ti <= br.tau_b + 1e-9):
            raise ValueError("impact-time Newton left the bracket of the first impact")
        return MapStep(np.array(xn).ravel(), ti)

    def analyse(self, M1, method: str = "variational") -> PoincareResult:
        """A^z, eigenvalues and status (docs: theory §4) at the fixed point for one M1.

        Parameters
        ----------
        M1 : array_like
            (nu,).
        method : {'variational', 'ad'}
            'variational' (the variational equation along the orbit, about a
            millisecond) or 'ad' (AD through the whole discrete map, ~0.3 s).  Either
            way the fixed point is checked (status 'open_orbit' when x* is not one): by
            the map at x* with this M1 ('ad'), or once per map ('variational':
            :attr:`fixed_point_residual`, the same for every M1 on a periodic gait).

        Returns
        -------
        PoincareResult
        """
        if method not in METHODS:
            raise ValueError(f"method must be one of {METHODS}, got {method!r}")
        M1 = check_M1(M1, self.nu)
        min_den = float(np.min(np.abs(self.denominator(M1))))
        if self.is_singular(M1):
            return self._undefined(M1, "singular", min_den, method,
                                   "D11 - D12 M1 vanishes or changes sign on the step (eq. 24)")
        if method == "variational":
            A = self.variational.jacobian(M1)
            return self._result(M1, A, None, self.T, min_den, method,
                                residual=self.fixed_point_residual)
        br = self.find_impact(self.x_star, M1)
        if br is None:
            return self._undefined(M1, "no_impact", min_den, method,
                                   f"no valid swing-foot impact within {self.horizon:g} T")
        A, xn, ti = (np.array(v) for v in self.map_jac(self.x_star, M1, br.guess))
        return self._result(M1, A, xn.ravel(), ti.item(), min_den, method)

    def _undefined(self, M1, status, min_den, method, message, tau=math.nan, A=None):
        nan2 = np.full((2, 2), np.nan) if A is None else A
        return PoincareResult(M1, nan2, np.full(2, complex(np.nan, np.nan)), math.inf, status,
                              self.x_star, tau_impact=tau, min_denominator=min_den,
                              method=method, message=message)

    def _result(self, M1, A, xn, ti, min_den, method, residual=None):
        if not np.all(np.isfinite(A)):
            return self._undefined(M1, "no_impact", min_den, method,
                                   "integration of the zero dynamics broke down", ti, A)
        ev = np.linalg.eigvals(A).astype(complex)       # [re, im] pairs in to_dict()
        ev = ev[np.argsort(-np.abs(ev))]
        mx = float(np.max(np.abs(ev)))
        res = float(residual if residual is not None else np.max(np.abs(xn - self.x_star)))
        status, message = ("stable" if mx < 1 else "unstable"), ""
        if not res <= FIXED_POINT_TOL:
            status = "open_orbit"
            message = (f"x* is not a fixed point of the map: |P(x*) - x*| = {res:.2e}"
                       + (" (with M1 = 0)" if residual is not None else "") + " (> "
                       f"{FIXED_POINT_TOL:g}); the gait is not a periodic orbit of this model "
                       f"and the eigenvalues at x* say nothing of its stability")
        return PoincareResult(M1, A, ev, mx, status, self.x_star, fixed_point_residual=res,
                              tau_impact=ti, min_denominator=min_den, method=method,
                              message=message)

    def jacobian_batch(self, M1s, chunk: int = 512):
        """A^z and the status for many M1 at once, by the vectorised variational equation.

        Parameters
        ----------
        M1s : array_like
            (n, nu) output matrices.
        chunk : int
            M1 per call of the batched Function.

        Returns
        -------
        JacobianBatch
            Status, A^z, eigenvalues and max ``|lambda|`` per M1; NaN (and max_abs inf)
            where singular or without impact.
        """
        sc = self.screen(M1s)
        M1s, sing = sc.M1, sc.singular
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
        status = np.where(sing, "singular", np.where(bad, "no_impact", np.where(
            self.open_orbit, "open_orbit", np.where(max_abs < 1, "stable", "unstable"))))
        ev[sing | bad] = np.nan
        return JacobianBatch(M1s, status, A, ev, max_abs)

    def analyse_batch(self, M1s, chunk: int = 64) -> list[PoincareResult]:
        """:meth:`analyse` with ``method='ad'`` for many M1, on threads.

        Singular cases are screened first, the others evaluated with
        ``map(..., 'thread')`` starting Newton at tau = T (the fixed point's impact
        time), which converges in one or two iterations.

        Parameters
        ----------
        M1s : array_like
            (n, nu) output matrices.
        chunk : int
            M1 per threaded call.

        Returns
        -------
        list of PoincareResult
            One per row of ``M1s``.
        """
        sc = self.screen(M1s)
        M1s, den, sing = sc.M1, sc.denominator, sc.singular
        out: list = [None] * len(M1s)
        for i in np.flatnonzero(sing):
            out[i] = self._undefined(M1s[i], "singular", float(np.abs(den[i]).min()), "ad",
                                     "D11 - D12 M1 vanishes or changes sign on the step")
        idx = np.flatnonzero(~sing)
        for a in range(0, len(idx), chunk):
            part = idx[a:a + chunk]
            n = len(part)
            A, xn, ti = (np.array(v) for v in self.batch_function(n)(
                np.repeat(self.x_star[:, None], n, 1), M1s[part].T, np.full((1, n), self.T)))
            for j, i in enumerate(part):
                tij = float(ti[0, j])
                if not (np.isfinite(tij) and abs(tij - self.T) < 0.05 * self.T):
                    out[i] = self.analyse(M1s[i], method="ad")      # unusual: full scan
                else:
                    out[i] = self._result(M1s[i], A[:, 2 * j:2 * j + 2], xn[:, j], tij,
                                          float(np.abs(den[i]).min()), "ad")
        return out

    @cached(maxsize=4)
    def batch_function(self, n: int) -> ca.Function:
        """The AD map and Jacobian ``map_jac`` mapped over ``n`` M1 on threads (memoised).

        Parameters
        ----------
        n : int
            Number of M1 per call.

        Returns
        -------
        casadi.Function
            (x (2, n), M1 (nu, n), tau guess (1, n)) -> (A (2, 2 n), x_next, tau_i).
        """
        return self.map_jac.map(n, "thread", self.threads)


def singular_m1_values(gait) -> np.ndarray:
    """The single-component singular outputs M1(j) = D11 / D12(j) at q^d(T) (eq. 24).

    With the other components zero, D11 - D12 M1 vanishes at the desired impact for
    M1(j) = D11 / D12(j) (the paper's 1.8046, 6.6821, 45.1060, 592.7751 for RABBIT).

    Parameters
    ----------
    gait : Reference
        The reference; D is evaluated at q^d(T).

    Returns
    -------
    numpy.ndarray
        (nu,).
    """
    D = np.array(require_reference(gait).model.D(gait.q(gait.T)))
    return D[0, 0] / D[0, 1:]


@cached(maxsize=8)
def poincare_map(gait, **options) -> PoincareMap:
    """The :class:`PoincareMap` of a model, gait and options, built once.

    Memoised by content: the gait's digest and the options.

    Parameters
    ----------
    gait : Reference
        The reference, made for ``model``.
    **options
        Keyword arguments of :class:`PoincareMap` (``n_pre``, ``n_post``, ...).

    Returns
    -------
    PoincareMap
    """
    return PoincareMap(require_reference(gait).model, gait, **options)


def poincare_eigenvalues(gait, M1=None, *args, method: str | None = None,
                         rejoin: float = PAPER_REJOIN) -> PoincareResult:
    """A^z, its eigenvalues and the stability status for outputs M1 (docs: theory, §4).

    Implements eq. (22): the fixed point is locally exponentially stable, status
    'stable', when max ``|lambda|`` of A^z is below 1.  ``poincare_eigenvalues(model, gait,
    M1)``, the form of the toolkit's specification, is the same call (the model must be
    the gait's), also with the method: ``poincare_eigenvalues(model, gait, M1, 'ad')``.

    Parameters
    ----------
    gait : Reference
        The gait (it carries its model).
    M1 : array_like or Design
        One number per actuated joint, or a time-varying :class:`~biped_casadi.Design`
        (its M1 and rejoin time; its gait must be ``gait``).
    *args
        The method, as the argument after M1 (also after the model, gait and M1).
    method : {'variational', 'ad'}
        'variational' (default, well under a millisecond per call once the map is built)
        or 'ad' (automatic differentiation through the whole discrete map, ~0.3 s; also
        gives the fixed-point residual).
    rejoin : float
        When v_c rejoins the reference, fraction of T (default 1/2, the paper's).

    Returns
    -------
    PoincareResult
        ``r.A`` (2x2 A^z), ``r.eigenvalues``, ``r.max_abs``, ``r.status``.
    """
    if not hasattr(gait, "T") and hasattr(M1, "T"):     # (model, gait, M1[, method])
        require_same_robot(gait, M1)
        gait, M1, args = M1, (args[0] if args else None), args[1:]
    if not hasattr(gait, "T") or not hasattr(gait, "model"):
        raise TypeError(f"poincare_eigenvalues(): a gait is needed first (Gait.load(path) or "
                        f"optimize_gait(model)), got {type(gait).__name__}")
    if len(args) > 1 or (args and method is not None):
        raise TypeError("poincare_eigenvalues() takes (gait, M1[, method]) or (model, gait, "
                        "M1[, method]), the method once")
    method = args[0] if args else "variational" if method is None else method
    if isinstance(M1, Design):
        d = Design.of(M1, gait)
        if d.M1 is None:
            raise ValueError("M1: virtual constraints have no A^z (use vc_eigenvalue)")
        M1, rejoin = d.M1, d.rejoin
    if M1 is None:
        raise ValueError("M1: give the outputs (one number per torque) or a Design")
    return poincare_map(gait, rejoin=check_rejoin(rejoin)).analyse(M1, method=method)
