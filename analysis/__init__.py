"""Stability analysis, design and reproduction on top of the robot (:mod:`biped_casadi`)
and its reference gaits (:mod:`gait_opt`): :mod:`analysis.stability` (the restricted
Poincaré map and its exact Jacobian), :mod:`analysis.sweeps` (sweeps over M1),
:mod:`analysis.design` (output selection, the M1 NLP, the robust design),
:mod:`analysis.robustness` (s*, basins), :mod:`analysis.reporting` (figures, the report
of ``biped reproduce``) and the ``biped`` command line (:mod:`analysis.cli`).
"""
from .stability import (METHODS, STATUSES, PoincareMap, PoincareResult, VCEigenResult,
                        VirtualConstraintMap, poincare_eigenvalues, poincare_map,
                        singular_m1_values, vc_eigenvalue)

__all__ = ["poincare_eigenvalues", "PoincareMap", "PoincareResult", "poincare_map",
           "singular_m1_values", "STATUSES", "METHODS", "vc_eigenvalue", "VCEigenResult",
           "VirtualConstraintMap"]
