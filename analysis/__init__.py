"""Stability analysis, design and reproduction on top of the robot (:mod:`biped_casadi`)
and its reference gaits (:mod:`gait_opt`): the restricted Poincaré map and its exact
Jacobian, sweeps over M1, output selection, the virtual-constraint comparison, figures,
the report of ``biped reproduce`` and the ``biped`` command line (:mod:`analysis.cli`).
"""
from .poincare import (METHODS, STATUSES, PoincareMap, PoincareResult, poincare_eigenvalues,
                       poincare_map, singular_m1_values)
from .virtual_constraints import VCEigenResult, VirtualConstraintMap, vc_eigenvalue

__all__ = ["poincare_eigenvalues", "PoincareMap", "PoincareResult", "poincare_map",
           "singular_m1_values", "STATUSES", "METHODS", "vc_eigenvalue", "VCEigenResult",
           "VirtualConstraintMap"]
