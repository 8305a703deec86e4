"""The outputs of a hybrid cycle's domain checked between its RK4 nodes: which steps may
dip below a bound, and where the outputs' minima are.

A domain of a hybrid cycle (:class:`~analysis.stability.hybrid_cycle.Domain`) may name
outputs that must hold on the continuous solution, not only at its nodes: constraints
(``dense_constraints``) and its guard (``dense_guard``).  Between two nodes the solution is
the RK4 step of length eta from the first, the one the crossing is located on.

Screening.  Each step is screened by the values at its nodes alone: an output c that dips
inside a step of length h goes below its lower node value by at most max |c''| h^2 / 8.
c'' h^2 is estimated by the second differences of the nodes around (centred on the step's
first node and on the one before, and their linear extrapolation to the step's end); the
step is refined where the lower node value less ``SCREEN_SAFETY`` times that bound is below
the output's bound (0 for a guard, ``-tolerance`` for a constraint), and always in a
domain's first step (no nodes before it).  Far from its bound an output's minima are not
searched: an estimate, not a proof, which holds while c'' changes by less than that
factor over three steps.

Refining takes the outputs' rates along the flow at both nodes (AD of the outputs:
exact); an output whose rate goes from <= 0 at one node to > 0 at the next has a minimum
in between (where the rate is 0 at the first node, the step's curvature there says
whether it goes down first), found by the safeguarded Newton of the strikes on its rate
in eta (:func:`~biped_casadi.simulation.kernel.locate_minimum`).  The rates and the
derivatives in eta are built the first time a step is refined.
"""
from __future__ import annotations

import numpy as np

from biped_casadi.simulation.kernel import SCREEN_SAFETY, minima_between, screen_steps

__all__ = ["SCREEN_SAFETY", "watch", "screened", "minima"]


def _col(v) -> np.ndarray:
    return np.array(v, float).ravel()


def watch(d, g, c) -> np.ndarray:
    """The watched outputs' values at a node of domain ``d`` from its guard's parts g and
    constraints c (numbers, the domain's ``watched`` order)."""
    return np.concatenate((np.atleast_1d(g), c))[d.watched_index]


def screened(d, w) -> np.ndarray:
    """Which watched outputs of domain ``d`` may go below their bounds between the last
    two of the nodes ``w`` (up to four consecutive nodes' watched values; module
    docstring, :func:`~biped_casadi.simulation.kernel.screen_steps`).

    Returns
    -------
    numpy.ndarray of bool
        One per watched output.
    """
    if len(w) < 2:
        return np.ones(len(d.watched), bool)
    return screen_steps(np.array(w[-4:], float), d.watched_bounds)[-1]


def minima(d, f, X, t, h, p, Xb, w) -> list:
    """The minima of domain ``d``'s watched outputs between the node (X, t) and the next
    one, Xb h later, the watched values ``w`` at the nodes up to Xb (module docstring).

    Parameters
    ----------
    d : Domain
        The domain.
    f : object
        Its compiled Functions (``rate``, ``between``).
    X, t, h, p
        The step's first node, its time, the step, the domain's parameters.
    Xb : array_like
        The step's last node.
    w : list of numpy.ndarray
        The watched values at up to four nodes, the last Xb's.

    Returns
    -------
    list of tuple
        (eta, watched index, value) by eta.
    """
    near = screened(d, w)
    if not near.any():
        return []
    ra, rb = _col(f.rate(X, t, p)), _col(f.rate(Xb, t + h, p))
    return minima_between(near, ra, rb, lambda eta: f.between(X, t, eta, p), h)
