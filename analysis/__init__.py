"""Stability analysis of time-varying output control: restricted Poincaré map, sweeps
over M1, output selection."""
from .poincare import (STATUSES, PoincareMap, PoincareResult, poincare_eigenvalues,
                       poincare_map, singular_m1_values)

def __getattr__(name):          # the virtual-constraint map on first use (it builds more)
    if name == "vc_eigenvalue":
        from .virtual_constraints import vc_eigenvalue
        return vc_eigenvalue
    raise AttributeError(f"module 'analysis' has no attribute {name!r}")


__all__ = ["vc_eigenvalue", "poincare_eigenvalues", "PoincareMap", "PoincareResult", "poincare_map",
           "singular_m1_values", "STATUSES"]
