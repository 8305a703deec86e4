"""Errors of the gait optimiser."""
from __future__ import annotations

__all__ = ["GaitOptimizationError"]


class GaitOptimizationError(RuntimeError):
    """IPOPT did not find a feasible gait; the message names the status and the
    constraint families that are violated at the last iterate."""

    def __init__(self, message, status=None, violations=None):
        super().__init__(message)
        self.status = status
        self.violations = list(violations or [])
