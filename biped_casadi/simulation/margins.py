"""The walking simulator's stance force, friction cone and torques checked between its
RK4 nodes.

The margins: F_z - ``min_normal_force`` (> 0), the two faces of the friction cone
(mu + tol) F_z -+ F_x (>= 0, tol the nodes' :data:`~biped_casadi.simulation.validity.
FRICTION_TOL`) and U -+ u_i per torque (>= 0; left out with ``saturate`` or without a
finite limit).  Each is smooth where |F_x| or |u_i| is not (a kink at 0, far from its
bound).  Between two nodes the state is the RK4 step of length eta from the first.  Every
step is screened by the margins at its nodes (:func:`~biped_casadi.simulation.kernel.
screen_steps`, the running cycle's screen); where a margin may dip below 0 its rates in
eta at both ends of the step are taken (AD, exact) and its minimum located by Newton's
method on the rate (:func:`~biped_casadi.simulation.kernel.minima_between`).  A law
without derivatives (a compiled library, :mod:`~biped_casadi.simulation.compiled_loop`)
has the same screen; in a flagged step the margins are taken at
:data:`~biped_casadi.simulation.kernel.SUB_STEPS` (16) equal parts of it (each the RK4
step of that length from the first node), the parts screened alike, and a minimum
located by golden-section search on the margin's values
(:func:`~biped_casadi.simulation.kernel.minima_sampled`).  A minimum below its bound is
the first invalid state, named with "between two RK4 nodes".  The fall and the
controller's singularity are checked at the nodes only, and why that suffices is
:mod:`~biped_casadi.simulation.validity`'s ("At the nodes only").

The batched walkers (:mod:`~biped_casadi.simulation.tv_walker`,
:mod:`~biped_casadi.simulation.vc_walker`) screen the steps of all their scenarios at once
(:meth:`MarginCheck.first_dips`) and look inside the flagged ones only, scenario by
scenario, with the same locator; the swing foot's minima between their nodes likewise
(:func:`foot_dips`, :func:`~biped_casadi.simulation.kernel.swing_foot_dip`).
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from ..numerics import FastCall
from .kernel import (SCREEN_SAFETY, foot_may_dip, minima_between, minima_sampled,
                     screen_steps, swing_foot_dip)
from .validity import FRICTION_TOL, between_message

__all__ = ["MarginCheck", "dip_function", "foot_dips"]


class MarginCheck:
    """The margins of one simulator's limits, at its nodes and between them.

    Parameters
    ----------
    limits : Limits
        The thresholds.
    schema : Diagnostics
        The simulator's diagnostics rows.
    """

    def __init__(self, limits, schema):
        self.limits, self.schema = limits, schema
        nu = schema.nu
        self.status = ["negative_normal_force"]
        if np.isfinite(limits.mu):
            self.status += ["slipped"] * 2
        #: per torque, its bound (the run's limit, or the joints' where they differ)
        self.U = np.broadcast_to(np.asarray(limits.torque_limit, float), (nu,))
        if not limits.saturate and np.all(np.isfinite(self.U)):
            self.status += ["torque_limit"] * (2 * nu)
        self._between = None
        u = schema.index["u"]
        self._rows = np.r_[np.arange(u.start, u.stop), schema.index["Fx"], schema.index["Fz"]]
        # per slack of _slacks, the rows (of rows()) it is bounded through
        self._margin_rows = [(nu + 1,)] + ([(nu, nu + 1)] if np.isfinite(limits.mu) else []) \
            + [(i,) for i in range(nu) if "torque_limit" in self.status]

    def values(self, u, Fx, Fz, lib=np):
        """The margins from torques (nu, ...), F_x and F_z (numbers or CasADi with
        ``lib=ca``), stacked along the first axis."""
        lim = self.limits
        out = [Fz - lim.min_normal_force]
        if np.isfinite(lim.mu):
            cone = (lim.mu + FRICTION_TOL) * Fz
            out += [cone - Fx, cone + Fx]
        if "torque_limit" in self.status:
            U = [lim.torque_limit] * self.schema.nu if np.ndim(lim.torque_limit) == 0 \
                else lim.torque_limit
            out += [U[i] - u[i] for i in range(self.schema.nu)] + \
                   [U[i] + u[i] for i in range(self.schema.nu)]
        return lib.vertcat(*out) if lib is ca else np.array(out, float)

    def rows(self, D) -> np.ndarray:
        """The torques, F_x and F_z of diagnostics D (rows, ...), stacked: (nu + 2, ...)."""
        return np.asarray(D)[self._rows]

    def of_rows(self, R) -> np.ndarray:
        """(n, s, m) margins at the n nodes (last axis) of s scenarios' rows R (:meth:`rows`,
        (nu + 2, s, n))."""
        nu = self.schema.nu
        return self.values(R[:nu], R[nu], R[nu + 1]).T

    def near(self, R) -> np.ndarray:
        """Per scenario, whether the screen may flag a margin in a step between n >= 3
        consecutive nodes (the last axis of rows R, :meth:`rows`).

        Each margin of :meth:`values` is bounded through the rows it is linear in (its
        lowest value, the largest of its second differences; the torques' and the
        cone's by |u_i| and |F_x|): False where every margin is above 0 by
        :data:`~biped_casadi.simulation.kernel.SCREEN_SAFETY` / 8 times 3 max |c''| h^2
        at every node, as :func:`~biped_casadi.simulation.kernel.screen_far`; a NaN is
        near.  The whole batch's extremes decide first (its lowest and highest rows, their
        ranges' bound |c''| h^2 <= 2 (max - min), then the largest second differences of
        the rows of the margins that bound leaves near): every scenario is far where
        they are far; else per scenario, far where both bounds say so.  A margin added to
        :meth:`values` must be bounded here too: one missing is never screened in a
        scenario this calls far.
        """
        flat = R.reshape(R.shape[0], -1)
        lo, hi = flat.min(axis=1), flat.max(axis=1)
        d1 = 2 * (hi - lo)
        slack = self._slacks(lo.tolist(), hi.tolist(), d1.tolist())
        if all(v >= 0 for v in slack):
            return np.zeros(R.shape[1], bool)         # the whole batch's extremes decide
        need = sorted({r for v, rows in zip(slack, self._margin_rows) if not v >= 0
                       for r in rows})
        Rn = R[need]                                  # the rows of the margins left near
        d = Rn[..., 2:] - Rn[..., 1:-1]
        d -= Rn[..., 1:-1]
        d += Rn[..., :-2]
        dflat = d.reshape(len(need), -1)
        d1[need] = np.maximum(dflat.max(axis=1), -dflat.min(axis=1))
        if self._far(lo.tolist(), hi.tolist(), d1.tolist()):
            return np.zeros(R.shape[1], bool)
        lo, hi = R.min(axis=-1), R.max(axis=-1)
        d1 = 2 * (hi - lo)
        d2 = d1.copy()
        d2[need] = np.maximum(d.max(axis=-1), -d.min(axis=-1))
        return self._near(lo, hi, d1) & self._near(lo, hi, d2)

    def _slacks(self, lo, hi, d1) -> list:
        """The margins' lower bounds less their screen's allowance (:meth:`near`), from the
        rows' extremes lo, hi and bounds d1 on their |c''| h^2 (lists of numbers: each the
        bound of every scenario's, lo the lowest, hi the highest, d1 the largest), in the
        arithmetic of :meth:`_near`."""
        lim, nu = self.limits, self.schema.nu
        c = 3 * SCREEN_SAFETY / 8
        slack = [lo[nu + 1] - lim.min_normal_force - c * d1[nu + 1]]
        if np.isfinite(lim.mu):
            k = lim.mu + FRICTION_TOL
            slack.append(k * lo[nu + 1] - max(hi[nu], -lo[nu]) - c * (k * d1[nu + 1] + d1[nu]))
        if "torque_limit" in self.status:
            slack.extend(self.U[i] - max(hi[i], -lo[i]) - c * d1[i] for i in range(nu))
        return slack

    def _far(self, lo, hi, d1) -> bool:
        """Whether every margin is far from its bound for every scenario (:meth:`_slacks`
        of the whole batch's extremes); a NaN is near."""
        return all(v >= 0 for v in self._slacks(lo, hi, d1))

    def _near(self, lo, hi, d1) -> np.ndarray:
        """:meth:`near` from the rows' extremes lo, hi and bounds d1 on their |c''| h^2."""
        lim, nu = self.limits, self.schema.nu
        c = 3 * SCREEN_SAFETY / 8
        with np.errstate(invalid="ignore"):
            far = lo[nu + 1] - lim.min_normal_force - c * d1[nu + 1] >= 0
            if np.isfinite(lim.mu):
                k = lim.mu + FRICTION_TOL
                far &= k * lo[nu + 1] - np.maximum(hi[nu], -lo[nu]) \
                    - c * (k * d1[nu + 1] + d1[nu]) >= 0
            if "torque_limit" in self.status:
                U = self.U.reshape((-1,) + (1,) * (np.ndim(hi[:nu]) - 1))
                far &= np.all(U - np.maximum(hi[:nu], -lo[:nu]) - c * d1[:nu] >= 0, axis=0)
        return ~far

    def at_nodes(self, D) -> np.ndarray:
        """(n, m) margins at the n nodes of diagnostics D (rows x n)."""
        S = self.schema
        return self.values(S.row(D, "u"), S.row(D, "Fx"), S.row(D, "Fz")).T

    def build(self, rk4, margins):
        """``between(X, tau, eta, p) -> (W, dW/deta, d2W/deta2)`` on the RK4 step of
        length eta (:meth:`function`, built at first use and kept)."""
        if self._between is None:
            self._between = FastCall(self.function(rk4, margins))
        return self._between

    def function(self, rk4, margins) -> ca.Function:
        """The margins on the RK4 step of length eta and their first two rates in eta.

        Parameters
        ----------
        rk4 : casadi.Function
            ``(X, tau, eta, p) -> (X_eta, tau_eta)``: the closed loop's step.
        margins : callable
            ``margins(X, tau, p)``: the margins at a state (CasADi).

        Returns
        -------
        casadi.Function
            ``(X, tau, eta, p) -> (W, dW/deta, d2W/deta2)``.
        """
        X = ca.SX.sym("X", rk4.size1_in(0))
        tau, eta = ca.SX.sym("tau"), ca.SX.sym("eta")
        p = ca.SX.sym("p", rk4.size1_in(3))
        Xe, te = rk4(X, tau, eta, p)
        W = margins(Xe, te, p)
        dW = ca.jacobian(W, eta)
        return ca.Function("margins_between", [X, tau, eta, p], [W, dW, ca.jacobian(dW, eta)],
                           ["X", "tau", "eta", "p"], ["W", "dW_deta", "d2W_deta2"])

    def first_dip(self, between, W, steps, samples: int = 0):
        """The first minimum below its bound inside the steps, or None.

        Parameters
        ----------
        between : callable
            From :meth:`build`; with ``samples``, ``between(X, tau, eta, p) -> W`` (m,):
            the margins alone (a law without derivatives).
        W : numpy.ndarray
            (n, m) margins at consecutive nodes (up to three before the steps').
        steps : list of tuple
            (Xa, ta, length, p) of the last len(steps) steps between the rows of W.
        samples : int
            0: the minima located by their rates (:func:`~biped_casadi.simulation.
            kernel.minima_between`); else by the margins at this many equal parts of
            the step (:func:`~biped_casadi.simulation.kernel.minima_sampled`).

        Returns
        -------
        tuple or None
            (step index, eta, status) at the minimum.
        """
        base = len(W) - 1 - len(steps)
        near = screen_steps(W, np.zeros(W.shape[1]))[base:]
        ends = (lambda j: (W[base + j], W[base + j + 1])) if samples else None
        return self._first_flagged(between, near, steps.__getitem__, samples, ends)

    def first_dips(self, between, W, n_steps: int, step, stop) -> dict:
        """Per scenario of a batch, the first minimum below its bound inside its steps.

        Parameters
        ----------
        between : callable
            ``between(X, tau, eta, p) -> (W, dW/deta, d2W/deta2)`` (:meth:`build`).
        W : numpy.ndarray
            (n, s, m) margins at consecutive nodes of s scenarios, the last ``n_steps`` + 1
            rows bracketing the steps, up to three before them (NaN where missing).
        n_steps : int
            Steps.
        step : callable
            ``step(i, j) -> (Xa, ta, length, p)``: scenario i's step j.
        stop : array_like of int
            (s,) how many of its steps count per scenario.

        Returns
        -------
        dict
            Scenario -> (step index, eta, status) at its first minimum below its bound.
        """
        near = screen_steps(W, np.zeros(W.shape[-1]))[W.shape[0] - 1 - n_steps:]
        near &= (np.arange(n_steps)[:, None] < np.asarray(stop)[None, :])[:, :, None]
        found = {}
        for i in np.flatnonzero(near.any(axis=(0, 2))):
            got = self._first_flagged(between, near[:, i], lambda j, i=i: step(i, j))
            if got is not None:
                found[int(i)] = got
        return found

    def _first_flagged(self, between, near, step, samples: int = 0, ends=None):
        """The first minimum below its bound inside the steps ``near`` flags (steps, m):
        (step index, eta, status) or None; ``step(j)`` the step j's (Xa, ta, length, p);
        with ``samples``, ``ends(j)`` the margins at its nodes (:meth:`first_dip`)."""
        for j in np.flatnonzero(near.any(axis=1)):
            Xa, ta, h, p = step(j)

            def at(eta, Xa=Xa, ta=ta, p=p):
                return between(Xa, ta, eta, p)

            if samples:
                found = minima_sampled(near[j], at, h, *ends(j), samples)
            else:
                r_a, r_b = (np.asarray(at(e)[1], float).ravel() for e in (0.0, h))
                found = minima_between(near[j], r_a, r_b, at, h)
            for eta, i, v in found:
                if v < 0 or (i == 0 and not v > 0):
                    return int(j), eta, self.status[i]
        return None

    def message(self, status, D, den_scale) -> str:
        """The failure in words at the state of diagnostics D (one column)."""
        node = {k: (v[..., 0] if isinstance(v, np.ndarray) else v)
                for k, v in self.schema.rows(D).items()}
        return between_message(status, node, self.limits, den_scale)


def dip_function(rk4, foot) -> ca.Function:
    """The swing foot at the end of the RK4 step of length eta, with its rates in eta.

    Parameters
    ----------
    rk4 : casadi.Function
        ``(X, tau, eta, p) -> (X_eta, tau_eta)``: the closed loop's step.
    foot : callable
        ``foot(X, tau, p) -> (x_sw, z_sw)`` at a state (CasADi).

    Returns
    -------
    casadi.Function
        ``(X, tau, eta, p) -> (z_sw, dz/deta, d2z/deta2, x_sw, X_eta)``, the ``dip`` of
        :func:`~biped_casadi.simulation.kernel.swing_foot_dip`.
    """
    X, tau, eta = ca.SX.sym("X", rk4.size1_in(0)), ca.SX.sym("tau"), ca.SX.sym("eta")
    p = ca.SX.sym("p", rk4.size1_in(3))
    Xe, te = rk4(X, tau, eta, p)
    x, z = foot(Xe, te, p)
    dz = ca.jacobian(z, eta)
    return ca.Function("swing_foot_dip", [X, tau, eta, p], [z, dz, ca.jacobian(dz, eta), x, Xe],
                       ["X", "tau", "eta", "p"],
                       ["z_sw", "dz_deta", "d2z_deta2", "x_sw", "X_event"])


def foot_dips(dip, h, step, z_prev, dz_a, dz_b, stop, ground, scuff_zone: float,
              limits, dt=None) -> dict:
    """Per scenario of a batch, the first of the swing foot's minima between two nodes
    that is below the ground (:func:`~biped_casadi.simulation.kernel.swing_foot_dip`).

    Parameters
    ----------
    dip : callable
        ``dip(X, tau, eta, p)`` (:func:`dip_function`).
    h : float or array_like
        The RK4 step, s (or (s,) per scenario).
    step : callable
        ``step(i, j) -> (Xa, ta, p)``: the first node of scenario i's step j.
    z_prev, dz_a, dz_b : numpy.ndarray
        (s, K) per step: the height at its first node, the foot's vertical rate there
        and at its last node.
    stop : array_like of int
        (s,) how many of its steps count per scenario.
    ground : tuple of numpy.ndarray
        (ahead, behind) per scenario, (s,) each.
    scuff_zone : float
        ``model.scuff_zone`` (inf: every dip below the ground is a scuff), m.
    limits : Limits
        ``scuffing_ignored`` and ``ground_tolerance``.
    dt : array_like, optional
        The steps' durations, s, broadcastable to (s, K) (default h): the steps whose
        minimum may be below the ground (:func:`~biped_casadi.simulation.kernel.
        foot_may_dip`) are looked at.

    Returns
    -------
    dict
        Scenario -> (j, 'strike' or 'scuffed', eta, z_sw, x_sw, X_eta).
    """
    if not ((dz_a <= 0) & (dz_b > 0)).any():            # no minimum in any step
        return {}
    K = z_prev.shape[1]
    h = np.broadcast_to(np.asarray(h, float), (len(z_prev),))
    cand = foot_may_dip(z_prev, dz_a, dz_b, h[:, None] if dt is None else dt,
                        (ground[0][:, None], ground[1][:, None])) \
        & (np.arange(K)[None, :] < np.asarray(stop)[:, None])
    found = {}
    for i in np.flatnonzero(cand.any(axis=1)):
        n = int(stop[i])
        p = step(i, 0)[2]
        got = swing_foot_dip(lambda X, t, eta, p=p: dip(X, t, eta, p), float(h[i]),
                             lambda j, i=i: step(i, j)[:2], z_prev[i, :n], dz_a[i, :n],
                             dz_b[i, :n], (ground[0][i], ground[1][i]), scuff_zone,
                             limits.scuffing_ignored, limits.ground_tolerance, cand[i, :n])
        if got is not None:
            found[int(i)] = got
    return found
