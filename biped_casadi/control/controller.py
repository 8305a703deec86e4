"""What every closed-loop controller gives the simulators: the control law as one CasADi
Function and the per-step constants fixed at the start of a step.

``law(q, dq, tau, r, p) -> (u, y, dy, den, dr, in_range)``
    torques u, outputs y and their rates dy, the decoupling denominator ``den`` (zero
    where the controller is singular), the time derivative ``dr`` of the reference
    state r, and ``in_range`` (1 while the reference is defined at the current state).
``step_start(q, dq) -> StepStart(r, p)``
    the reference state r and the per-step constants p at the start of a step (just
    after an impact, or at the initial state).
``start(q, dq) -> (r, p)``
    the same as a CasADi Function (for derivatives through a step).

The time-varying controller (:mod:`biped_casadi.control.time_varying`) and the
virtual-constraint controller (:mod:`biped_casadi.control.virtual_constraints`)
implement it.
"""
from __future__ import annotations

import abc
from dataclasses import dataclass

import numpy as np

from ..numerics import as_number, as_vector

__all__ = ["StepStart", "ControlOutput", "Controller"]


@dataclass
class StepStart:
    """Controller state at the start of a step.

    Parameters
    ----------
    r : numpy.ndarray
        The reference state at tau = 0 (``n_ref`` numbers).
    p : numpy.ndarray
        The step constants (``n_par`` numbers; the time-varying controller's
        (y_i, dy_i) of eq. 17).
    problem : str
        Why the step cannot be controlled (empty when it can).
    """
    r: np.ndarray
    p: np.ndarray
    problem: str = ""


@dataclass
class ControlOutput:
    """One evaluation of a control law at a state.

    Parameters
    ----------
    u : numpy.ndarray
        Torques (nu), N m.
    y, dy : numpy.ndarray
        Outputs (nu) and their rates.
    denominator : float
        The decoupling denominator: zero where the controller is singular.
    """
    u: np.ndarray          # torques (nu)
    y: np.ndarray          # outputs (nu)
    dy: np.ndarray         # output rates (nu)
    denominator: float     # zero where the controller is singular


class Controller(abc.ABC):
    """A closed-loop controller: the law as one CasADi Function and its step constants.

    Subclasses build ``law`` (module docstring) and set ``model``, ``reference``,
    ``n_ref`` and ``n_par``; this class gives the numeric wrappers.
    """

    name = "controller"
    n_ref = 0
    n_par = 0

    @abc.abstractmethod
    def step_start(self, q, dq) -> StepStart:
        """The per-step parameters fixed at the start of a step (just after an impact).

        Parameters
        ----------
        q, dq : array_like
            The state at the start of the step, rad and rad/s.

        Returns
        -------
        StepStart
        """

    @abc.abstractmethod
    def describe(self) -> dict:
        """What defines the controller, as a JSON-ready dict.

        Returns
        -------
        dict
        """

    @property
    def gait(self):
        """The reference the controller tracks (alias of ``reference``)."""
        return self.reference

    def evaluate(self, q, dq, tau, r, p) -> ControlOutput:
        """The control law at one state (numeric), with an explicit reference state.

        Parameters
        ----------
        q, dq : array_like
            Configuration (nq,), rad, and velocity, rad/s.
        tau : float
            Time since the start of the step, s.
        r : array_like
            Reference state (``n_ref`` numbers; the time-varying controller's
            (q_u^d, dq_u^d), none for virtual constraints).
        p : array_like
            Step constants (``n_par`` numbers) from :meth:`step_start`.

        Returns
        -------
        ControlOutput
            Torques ``u`` (N m), outputs ``y`` and rates ``dy``, and the decoupling
            ``denominator`` (zero where the controller is singular).
        """
        nq = self.model.nq
        q = as_vector(q, nq, "q")
        dq = as_vector(dq, nq, "dq")
        tau = as_number(tau, "tau")
        r = as_vector(r, self.n_ref, "r")
        p = as_vector(p, self.n_par, "p")
        u, y, dy, den, _, _ = (np.array(v).ravel() for v in self.law(q, dq, tau, r, p))
        return ControlOutput(u=u, y=y, dy=dy, denominator=float(den[0]))
