"""What the stride map over a cycle of domains returns
(:mod:`analysis.stability.hybrid_cycle`): each domain's pass, one stride, one stride with
its exact Jacobian."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from biped_casadi.results import Result

__all__ = ["DomainPass", "StrideValue", "StrideLinearisation"]


@dataclass
class DomainPass:
    """One domain's part of a stride.

    Parameters
    ----------
    name : str
        The domain.
    entry : numpy.ndarray
        (nX,) the augmented state at entry.
    parameters : numpy.ndarray
        (n_par,) the domain's parameters.
    duration : float
        Time from entry to the crossing, s.
    exit_state : numpy.ndarray
        (n,) x at the crossing (before the reset).
    next_state : numpy.ndarray
        The reset's output.
    times, nodes : numpy.ndarray or None
        With ``record``: the RK4 nodes' times (N,) and augmented states (nX, N) from entry
        to the crossing (the last node is the crossing).
    dips : list of tuple
        (t, name, value): each minimum of a domain's ``dense_constraints`` and dense guard
        found between two nodes before the crossing (module docstring), in time order.
    part : str or None
        The guard's part that fired (``Domain.guard_parts``; at entry for a domain that
        ended there), None for a domain an earlier part skipped (``Domain.skip``).
    """

    name: str
    entry: np.ndarray
    parameters: np.ndarray
    duration: float
    exit_state: np.ndarray
    next_state: np.ndarray
    times: np.ndarray | None = None
    nodes: np.ndarray | None = None
    dips: list = field(default_factory=list)
    part: str | None = None


@dataclass
class StrideValue(Result):
    """One application of the stride map.

    Parameters
    ----------
    state : numpy.ndarray
        x_0, the first domain's state at entry.
    next_state : numpy.ndarray
        P(x_0).
    durations : numpy.ndarray
        Each domain's duration, s.
    passes : list of DomainPass
        Each domain's part.
    status, message : str
        'ok'.
    """

    state: np.ndarray
    next_state: np.ndarray
    durations: np.ndarray
    passes: list = field(default_factory=list, metadata={"dict": False})
    status: str = "ok"
    message: str = ""

    SUCCESS = ("ok",)


@dataclass
class StrideLinearisation(Result):
    """The stride map and its exact Jacobian at a state.

    Parameters
    ----------
    state, next_state : numpy.ndarray
        x_0 and P(x_0).
    A : numpy.ndarray
        dP/dx_0.
    durations : numpy.ndarray
        Each domain's duration, s.
    duration_gradients : numpy.ndarray
        (domains, n) their derivatives with respect to x_0.
    eigenvalues : numpy.ndarray
        Of A, by decreasing magnitude.
    residual : float
        ``max |P(x_0) - x_0|``.
    passes : list of DomainPass
        Each domain's part.
    status, message : str
        'done'.
    """

    state: np.ndarray
    next_state: np.ndarray
    A: np.ndarray
    durations: np.ndarray
    duration_gradients: np.ndarray
    eigenvalues: np.ndarray
    residual: float
    passes: list = field(default_factory=list, metadata={"dict": False})
    status: str = "done"
    message: str = ""

    SUCCESS = ("done",)

    @property
    def spectral_radius(self) -> float:
        """max ``|eigenvalue|`` of A."""
        return float(np.max(np.abs(self.eigenvalues))) if self.eigenvalues.size else 0.0
