"""The step-to-step map of the full-order closed loop and its exact linearisation, for
any controller, with respect to the state and to two disturbances.

One application takes the full state s = (q, dq) at the start of a step (just after an
impact and the relabelling) and two disturbances of that step, the height h of the
ground it strikes (:mod:`biped_casadi.simulation.terrain`) and a horizontal push P (N s)
on the torso's centre of mass at its start (:func:`biped_casadi.simulation.torso_push`),
to the state at the start of the next step; the step's indicators are its time (tau at
the impact) and its length (x_sw at the impact):

    s_(k+1) = S(s_k, h_k, P_k),      g_k = (t_k, l_k) = G(s_k, h_k, P_k).

It is the map of the full-order simulator (:class:`~biped_casadi.simulation.Simulator`,
the same RK4 steps, the same impact located by Newton on the length of the last RK4
step, the same plant): S is evaluated by exactly those operations, and its Jacobians

    A = dS/ds,  B = dS/d(h, P),  C = dG/ds,  D = dG/d(h, P)

by forward algorithmic differentiation through every RK4 step, the impact time (the
implicit function z_sw(RK4(x_N, eta)) = h, solved for d eta), the impact map, the push
and the controller's step start (the time-varying controller's y_i, dy_i of eq. 17, the
virtual constraints' correction).  Any controller with the law interface
(:mod:`biped_casadi.control.controller`) and any plant (model error) work the same way.

At the periodic walk on flat ground (h = 0) the full state's map of the time-varying
controller has rank 2 (from every step start the closed loop is its zero dynamics,
whatever the output gains: the transversal eigenvalues are 0) and its non-zero
eigenvalues are those of A^z of the restricted Poincaré map (eq. 20); for virtual
constraints, rank 1 and the eigenvalue of :mod:`analysis.stability.vc_map`; both to the
discretisations' accuracy (:mod:`analysis.terrain.gsn`).  Linearised at another point,
such as a step up of 10 µm, A has other eigenvalues (the map is not linear).
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from biped_casadi.caching import cached
from biped_casadi.results import Result
from biped_casadi.simulation import SimulationOptions, simulator, torso_push
from biped_casadi.simulation.kernel import locate_strike, strike

__all__ = ["StepMap", "StepLinearisation", "StepValue", "step_map", "DISTURBANCES",
           "INDICATORS"]

#: the disturbances of a step, in the order of the columns of B and D
DISTURBANCES = ("ground_height", "torso_push")
#: the indicators of a step, in the order of the rows of C and D
INDICATORS = ("step_time", "step_length")


@dataclass
class StepValue(Result):
    """One application of the step-to-step map.

    Parameters
    ----------
    state : numpy.ndarray
        (2 nq,) the state at the start of the step.
    next_state : numpy.ndarray
        (2 nq,) the state at the start of the next step.
    step_time : float
        tau at the impact, s.
    step_length : float
        x_sw at the impact, m.
    status : str
        'ok', or why the step could not be taken ('no_impact').
    message : str
        In words.
    """

    state: np.ndarray
    next_state: np.ndarray
    step_time: float
    step_length: float
    status: str = "ok"
    message: str = ""

    SUCCESS = ("ok",)


@dataclass
class StepLinearisation(Result):
    """The step-to-step map linearised at a state (module docstring).

    ``success`` means the linearisation was computed; ``status`` 'done'.

    Parameters
    ----------
    state : numpy.ndarray
        (2 nq,) the state s at the start of the step (a fixed point of the map when it
        comes from :meth:`StepMap.fixed_point`).
    A : numpy.ndarray
        (2 nq, 2 nq) dS/ds.
    B : numpy.ndarray
        (2 nq, 2) dS/d(h, P): ground height (per m) and torso push (per N s).
    C : numpy.ndarray
        (2, 2 nq) d(step time, step length)/ds.
    D : numpy.ndarray
        (2, 2) d(step time, step length)/d(h, P).
    step_time, step_length : float
        The step's indicators at ``state``, s and m.
    residual : float
        ``max |S(s) - s|`` (how far ``state`` is from a fixed point).
    eigenvalues : numpy.ndarray
        Of A, by decreasing magnitude.
    disturbances, indicators : tuple of str
        The columns of B, D and the rows of C, D.
    status : str
        'done'.
    message : str
        In words.
    """

    state: np.ndarray
    A: np.ndarray
    B: np.ndarray
    C: np.ndarray
    D: np.ndarray
    step_time: float
    step_length: float
    residual: float
    eigenvalues: np.ndarray
    disturbances: tuple = DISTURBANCES
    indicators: tuple = INDICATORS
    status: str = "done"
    message: str = ""

    SUCCESS = ("done",)

    @property
    def spectral_radius(self) -> float:
        """max ``|eigenvalue|`` of A."""
        return float(np.max(np.abs(self.eigenvalues))) if self.eigenvalues.size else 0.0


class StepMap:
    """The step-to-step map of one controller's full-order closed loop (module docstring).

    Parameters
    ----------
    controller : Design, TimeVaryingController or VirtualConstraintController
        The control law (any controller with ``law`` and ``start``).
    options : SimulationOptions, optional
        The simulator's (its ``rk4_steps`` set the discrete map); default
        ``SimulationOptions()``.
    plant : BipedModel, optional
        The robot that moves (default the controller's model).
    """

    def __init__(self, controller, options: SimulationOptions | None = None, plant=None):
        self.sim = simulator(controller, options, plant)
        self.controller, self.plant = self.sim.controller, self.sim.plant   # a Design's
        self.nq = self.plant.nq
        self.h = self.sim.h
        self._build()

    @property
    def cache_key(self):
        """What the map depends on: the simulator's controller, options and plant."""
        return self.sim.cache_key

    def _build(self):
        sim, c, m = self.sim, self.controller, self.plant
        nq, nr, npar = self.nq, c.n_ref, c.n_par
        nx = 2 * nq + nr
        nd = 2 * nq + len(DISTURBANCES)               # seeds: the state, then (h, P)
        self.n_seeds = nd
        s, e = ca.SX.sym("s", 2 * nq), ca.SX.sym("e", len(DISTURBANCES))
        q, dq = s[:nq], s[nq:]
        dq_p = torso_push(m)(q, dq, e[1])
        r0, p0 = c.start(q, dq_p)
        X0 = ca.vertcat(q, dq_p, r0)
        seeds = ca.vertcat(s, e)
        self.start = ca.Function("step_map_start", [s, e],
                                 [X0, p0, ca.jacobian(X0, seeds), ca.jacobian(p0, seeds)])
        X, tau, hs = ca.SX.sym("X", nx), ca.SX.sym("tau"), ca.SX.sym("h")
        p = ca.SX.sym("p", npar)
        J, Jp = ca.SX.sym("J", nx, nd), ca.SX.sym("Jp", npar, nd)
        Xn, tn = sim.rk4(X, tau, hs, p)
        Jn = ca.jtimes(Xn, X, J) + (ca.jtimes(Xn, p, Jp) if npar else 0)
        z = m.swing_foot(Xn[:nq])
        self.rk4_sens = ca.Function("step_map_rk4", [X, J, tau, hs, p, Jp],
                                    [Xn, ca.cse(Jn), tn, z[0], z[1]])
        eta = ca.SX.sym("eta")
        Xe, _ = sim.rk4(X, tau, eta, p)
        Je = ca.jtimes(Xe, X, J) + (ca.jtimes(Xe, p, Jp) if npar else 0)
        zY = ca.Function("z_sw_gradient", [X], [ca.jacobian(m.swing_foot(X[:nq])[1], X)])
        self.last = ca.Function("step_map_last", [X, J, tau, eta, p, Jp],
                                [Xe, ca.cse(Je), ca.jacobian(Xe, eta), zY(Xe)])
        qm, dqm = ca.SX.sym("q", nq), ca.SX.sym("dq", nq)
        qp, dqp = m.impact(qm, dqm)
        sp = ca.vertcat(qp, dqp)
        xs = m.swing_foot(qm)[0]
        xm = ca.vertcat(qm, dqm)
        self.impact = ca.Function("step_map_impact", [xm],
                                  [sp, xs, ca.jacobian(sp, xm), ca.jacobian(xs, xm)])

    # ------------------------------------------------------------------ values
    def _pass(self, s, h, push, derivatives: bool):
        """The map (and, with ``derivatives``, its Jacobians) at (s, h, P)."""
        nq, nd = self.nq, self.n_seeds
        sim = self.sim
        s = np.asarray(s, float).ravel()
        e = np.array([h, push], float)
        X, p, JX, Jp = (np.array(v) for v in self.start(s, e))
        X, p = X.ravel(), p.ravel()
        J = JX if derivatives else np.zeros_like(JX)
        Jp = Jp if derivatives else np.zeros((p.size, nd))
        tau = 0.0
        z_prev = float(self.plant.swing_foot(X[:nq])[1])
        n_max = int(np.ceil(sim.options.horizon * sim.options.rk4_steps))
        ground = (h, 0.0)
        for _ in range(n_max):
            Xn, Jn, tn, xs, zs = self.rk4_sens(X, J, tau, self.h, p, Jp)
            zs, xs = float(zs), float(xs)
            if strike(zs, z_prev, xs, self.plant.scuff_zone, ground):
                break
            X, J, tau, z_prev = np.array(Xn).ravel(), np.array(Jn), float(tn), zs
        else:
            return None

        def event(eta_):
            zz, dz, _ = sim.event(X, tau, float(eta_[0]), p)
            return np.array([zz.item() - h]), np.array([dz.item()])

        eta = float(locate_strike(event, self.h, z_prev - h, zs - h)[0])
        Xe, Je, Xeta, zX = (np.array(v) for v in self.last(X, J, tau, eta, p, Jp))
        Xe = Xe.ravel()
        sp, xs, Sx, xx = (np.array(v) for v in self.impact(Xe[:2 * nq]))
        out = dict(next_state=sp.ravel(), step_time=tau + eta, step_length=xs.item())
        if derivatives:
            eh = np.zeros((1, nd))
            eh[0, 2 * nq] = 1.0                                    # dz_sw = dh
            deta = (eh - zX @ Je) / (zX @ Xeta).item()
            dXe = (Je + Xeta @ deta)[:2 * nq]
            dS = Sx @ dXe
            dG = np.vstack([deta, xx @ dXe])
            out.update(A=dS[:, :2 * nq], B=dS[:, 2 * nq:], C=dG[:, :2 * nq], D=dG[:, 2 * nq:],
                       dX_minus=dXe)
        out["X_minus"] = Xe[:2 * nq]
        return out

    def step(self, s, h: float = 0.0, push: float = 0.0) -> StepValue:
        """One application S(s, h, P), G(s, h, P) (no derivatives).

        Parameters
        ----------
        s : array_like
            (2 nq,) the state at the start of the step.
        h : float
            Ground height of the step's strike, m.
        push : float
            Horizontal push on the torso at the start of the step, N s.

        Returns
        -------
        StepValue
        """
        s = np.asarray(s, float).ravel()
        out = self._pass(s, h, push, derivatives=False)
        if out is None:
            return StepValue(s, np.full_like(s, np.nan), np.nan, np.nan, "no_impact",
                             "no strike of the swing foot within the horizon")
        return StepValue(s, out["next_state"], out["step_time"], out["step_length"])

    def linearise(self, s=None, h: float = 0.0, push: float = 0.0) -> StepLinearisation:
        """The Jacobians A, B, C, D at (s, h, P) by forward AD (module docstring).

        Parameters
        ----------
        s : array_like, optional
            (2 nq,) the state at the start of the step; default the reference's start
            (q^d(0), dq^d(0)).
        h : float
            Ground height, m.
        push : float
            Torso push, N s.

        Returns
        -------
        StepLinearisation
        """
        if s is None:
            g = self.controller.reference
            s = np.r_[g.q(0.0), g.dq(0.0)]
        s = np.asarray(s, float).ravel()
        out = self._pass(s, h, push, derivatives=True)
        if out is None:
            raise ValueError("the step from this state does not strike the ground within the "
                             "horizon: no linearisation")
        ev = np.linalg.eigvals(out["A"])
        ev = ev[np.argsort(-np.abs(ev), kind="stable")]
        res = float(np.max(np.abs(out["next_state"] - s)))
        return StepLinearisation(state=s, A=out["A"], B=out["B"], C=out["C"], D=out["D"],
                                 step_time=out["step_time"], step_length=out["step_length"],
                                 residual=res, eigenvalues=ev,
                                 message=f"step map linearised (spectral radius "
                                         f"{np.max(np.abs(ev)):.4g}, fixed-point residual "
                                         f"{res:.2g})")

    def fixed_point(self, s=None, tol: float = 1e-11, max_iter: int = 12) -> StepLinearisation:
        """The periodic walk on flat ground: S(s*) = s* by Newton with the exact A.

        On flat ground with a perfect model the reference's start is a fixed point
        already; with model error the plant walks another orbit.

        Parameters
        ----------
        s : array_like, optional
            Start of the iteration (default the reference's start).
        tol : float
            Stop when ``max |S(s) - s| < tol``.
        max_iter : int
            Newton steps at most.

        Returns
        -------
        StepLinearisation
            At the fixed point (``residual`` says how well it holds).
        """
        lin = self.linearise(s)
        for _ in range(max_iter):
            if lin.residual < tol:
                break
            step = self.step(lin.state)
            r = step.next_state - lin.state
            lin = self.linearise(lin.state + np.linalg.solve(np.eye(r.size) - lin.A, r))
        return lin


@cached(maxsize=8)
def step_map(controller, options: SimulationOptions | None = None, plant=None) -> StepMap:
    """The :class:`StepMap` of a controller, options and plant, built once (memoised).

    Parameters
    ----------
    controller : Design, TimeVaryingController or VirtualConstraintController
        The control law.
    options : SimulationOptions, optional
        The simulator's options.
    plant : BipedModel, optional
        The robot that moves.

    Returns
    -------
    StepMap
    """
    return StepMap(controller, options, plant)
