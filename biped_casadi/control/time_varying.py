"""The time-varying output controller of the paper (§III, eq. 12-13, 17), with the
stride-to-stride correction v_c, as a :class:`~biped_casadi.control.controller.Controller`.

Reference state r.  The controller needs q_u^d(tau); a gait defines it as the solution of
the unactuated row of eq. (1) with q_a = q_a^d(tau) (docs: theory §2), carried as the reference
state r = (q_u^d, dq_u^d) and reset to its value at tau = 0 at every impact: a function of
tau alone, so the hybrid closed loop is still the system in (q, dq, tau) of eq. (9).
From every step start the closed loop is its hybrid zero dynamics
(:mod:`biped_casadi.control.zero_dynamics`), whatever the output gains.
"""
from __future__ import annotations

import numpy as np
import casadi as ca

from ..numerics import as_number, as_vector
from .controller import ControlOutput, Controller, StepStart
from .output_law import (Gains, SingularityReport, actuated_torque, check_M1, check_rejoin,
                         correction, decoupling_denominator, initial_output_errors,
                         output_acceleration, output_matrix, outputs, singularity_report,
                         unactuated_acceleration)
from .reference import require_reference, require_same_robot
from .zero_dynamics import denominator_samples

__all__ = ["TimeVaryingController", "PAPER_REJOIN"]

#: the paper's rejoin time of the correction v_c, as a fraction of T (eq. 18)
PAPER_REJOIN = 0.5


# ===================================================== time-varying controller
class TimeVaryingController(Controller):
    """Time-varying output control of paper §III with the stride-to-stride correction.

    Implements eqs. (6), (7), (17): the outputs y = v - v^d(tau) that the control
    zeroes, with tau the time since the last impact (the caller restarts it at 0 at
    every impact, as the simulator does, and calls :meth:`step_start`, which restarts
    the reference state), corrected to y_c of eq. (17) (docs: theory §3):

    Outputs:  y_c = M q - v^d(tau) - v_c(tau),  M = [M1, I],
    v^d = M q^d(tau), v_c the correction of eq. (18) from y_i = v - v^d and
    dy_i = dv - dv^d just after each impact, rejoining the reference at
    tau = ``rejoin`` T (the paper: T/2).  Torque, eq. (12) with the output acceleration
    of eq. (13) applied to y_c (:mod:`biped_casadi.control.output_law`); singular where
    D11 - D12 M1 = 0 (eq. 24), which :meth:`singularity` checks along the reference.

    Parameters
    ----------
    reference : Reference
        The reference step (a :class:`gait_opt.Gait`) (it carries its model).
    M1 : array_like, optional
        One number per actuated joint (default zeros: the outputs are q_a).
    gains : Gains, optional
        Output PD of eq. (13) (default ``Gains()``).
    rejoin : float
        Rejoin time of v_c as a fraction of T, in (0, SECTION] (default 1/2, the paper's).

    Notes
    -----
    ``law(q, dq, tau, r, p)``: r = the reference state, p = (y_i, dy_i);
    ``start(q, dq) -> (r, p)``: :meth:`step_start` as a CasADi Function.
    """

    name = "tv"

    def __init__(self, reference, M1=None, gains: Gains | None = None,
                 rejoin: float = PAPER_REJOIN):
        model = require_reference(reference, "reference").model
        require_same_robot(model, reference)
        self.model, self.reference = model, reference
        nu = model.nu
        self.M1 = check_M1(np.zeros(nu) if M1 is None else M1, nu)
        self.gains = gains if gains is not None else Gains()
        if not isinstance(self.gains, Gains):
            raise ValueError(f"gains must be a Gains, got {type(self.gains).__name__}")
        self.rejoin = check_rejoin(rejoin)
        self.T = reference.T
        self.t_c = self.rejoin * self.T
        self.M = output_matrix(self.M1)
        self.n_ref = reference.n_state
        self.n_par = 2 * nu
        self._build()

    @property
    def cache_key(self):
        """What the compiled law depends on."""
        return ("tv", self.reference.cache_key, tuple(self.M1), self.gains, self.rejoin)

    def _build(self):
        m, nq, nu = self.model, self.model.nq, self.model.nu
        ref = self.reference.symbolic()
        M1 = ca.DM(self.M1)
        q, dq = ca.SX.sym("q", nq), ca.SX.sym("dq", nq)
        tau = ca.SX.sym("tau")
        r = ca.SX.sym("r", self.n_ref)
        p = ca.SX.sym("p", self.n_par)
        yi, dyi = p[:nu], p[nu:]
        qd, dqd, ddqd, dr = ref(tau, r)
        vc, dvc, ddvc = correction(tau, yi, dyi, self.t_c)
        y = outputs(M1, q) - outputs(M1, qd) - vc                              # eq. (17)
        dy = outputs(M1, dq) - outputs(M1, dqd) - dvc
        ddv = output_acceleration(outputs(M1, ddqd) + ddvc, y, dy, self.gains)  # eq. (13)
        D, H = m.D(q), m.H(q, dq)
        den = decoupling_denominator(D[0, 0], D[0, 1:], M1)                     # eq. (24)
        ddqu = unactuated_acceleration(D, H, M1, ddv)                           # eq. (23)
        u = actuated_torque(D, H, M1, ddqu, ddv)                                # eq. (12)
        self.law = ca.Function("tv_law", [q, dq, tau, r, p], [u, y, dy, den, dr, ca.DM(1)],
                               ["q", "dq", "tau", "r", "p"],
                               ["u", "y", "dy", "den", "dr", "in_range"])
        self._ref0 = self.reference.evaluate(0.0)[:2]
        self._r0 = np.array(self.reference.r0, dtype=float)
        qs, dqs = ca.SX.sym("q", nq), ca.SX.sym("dq", nq)
        yi0, dyi0 = initial_output_errors(M1, qs, dqs, ca.DM(self._ref0[0]),
                                          ca.DM(self._ref0[1]))                  # eq. (17)
        self.start = ca.Function("tv_step_start", [qs, dqs],
                                 [ca.DM(self._r0), ca.vertcat(yi0, dyi0)],
                                 ["q", "dq"], ["r", "p"])

    def step_start(self, q, dq) -> StepStart:
        """The step constants y_i = v - v^d(0), dy_i = dv - dv^d(0) of eq. (17).

        Parameters
        ----------
        q, dq : array_like
            The state at the start of the step (just after an impact), rad and rad/s.

        Returns
        -------
        StepStart
            ``r`` the reference state at tau = 0, ``p`` = (y_i, dy_i).
        """
        nq = self.model.nq
        q = as_vector(q, nq, "q")
        dq = as_vector(dq, nq, "dq")
        yi, dyi = initial_output_errors(self.M1, q, dq, *self._ref0)          # eq. (17)
        return StepStart(r=self._r0.copy(), p=np.r_[yi, dyi])

    def torque(self, q, dq, tau, y_i=None, dy_i=None) -> ControlOutput:
        """The control law at (q, dq, tau), the reference state read from the reference.

        Parameters
        ----------
        q, dq : array_like
            Configuration (nq,), rad, and velocity, rad/s.
        tau : float
            Time since the start of the step, s, within the reference's range
            [0, ``reference.t_max``].
        y_i, dy_i : array_like, optional
            The correction's initial output error and rate (nu each; default zero: no
            correction).

        Returns
        -------
        ControlOutput
            Torques, outputs y_c and rates, decoupling denominator.
        """
        nu = self.model.nu
        yi = np.zeros(nu) if y_i is None else as_vector(y_i, nu, "y_i")
        dyi = np.zeros(nu) if dy_i is None else as_vector(dy_i, nu, "dy_i")
        tau = as_number(tau, "tau")
        if not 0 <= tau <= self.reference.t_max:
            raise ValueError(f"tau must lie in [0, {self.reference.t_max:.6g}], got {tau!r}")
        return self.evaluate(q, dq, tau, self.reference.state(tau), np.r_[yi, dyi])

    def singularity(self, n: int = 1001) -> SingularityReport:
        """Whether D11 - D12 M1 vanishes or changes sign along the reference (eq. 23-24).

        Parameters
        ----------
        n : int
            Samples on [0, T].

        Returns
        -------
        SingularityReport
        """
        D11, D12 = denominator_samples(self.reference, n)
        return singularity_report(decoupling_denominator(D11, D12, self.M1))

    def describe(self) -> dict:
        """What defines the controller, as a JSON-ready dict.

        Returns
        -------
        dict
            ``controller`` ('tv'), ``M1``, ``gains``, ``rejoin``.
        """
        return dict(controller="tv", M1=self.M1.tolist(), gains=self.gains.to_dict(),
                    rejoin=self.rejoin)
