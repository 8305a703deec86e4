"""Stability analysis of time-varying output control: restricted Poincaré map, sweeps
over M1, output selection."""
from .poincare import (STATUSES, PoincareMap, PoincareResult, poincare_eigenvalues,
                       poincare_map, singular_m1_values)

__all__ = ["poincare_eigenvalues", "PoincareMap", "PoincareResult", "poincare_map",
           "singular_m1_values", "STATUSES"]
