"""Errors of the gait optimiser."""
from __future__ import annotations

__all__ = ["GaitOptimizationError"]


class GaitOptimizationError(RuntimeError):
    """IPOPT did not find a feasible gait (or the request is out of reach).

    The message names IPOPT's status, the constraint families violated at the last
    iterate, and what to try.

    Parameters
    ----------
    message : str
        The message.
    status : str, optional
        IPOPT's return status ('not_run' when the request was refused before IPOPT).
    violations : list of (str, float), optional
        The violated constraint families and by how much, worst first.
    """

    def __init__(self, message, status=None, violations=None):
        super().__init__(message)
        self.status = status
        self.violations = list(violations or [])
