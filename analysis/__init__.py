"""Stability analysis, design and reproduction on top of the robot (:mod:`biped_casadi`)
and its reference gaits (:mod:`gait_opt`): :mod:`analysis.stability` (the restricted
Poincaré map and its exact Jacobian), :mod:`analysis.sweeps` (sweeps over M1),
:mod:`analysis.design` (output selection, the M1 NLP, the robust design),
:mod:`analysis.robustness` (s*, basins), :mod:`analysis.reporting` (figures, the report
of ``biped reproduce``) and the ``biped`` command line (:mod:`analysis.cli`).

The names below are those of :mod:`analysis.stability`, loaded on first use: importing
the package alone (as ``python -m analysis.cli`` does before the command line can catch
a Ctrl-C) loads nothing else.
"""
from importlib import import_module

__all__ = ["poincare_eigenvalues", "PoincareMap", "PoincareResult", "poincare_map",
           "singular_m1_values", "STATUSES", "METHODS", "vc_eigenvalue", "VCEigenResult",
           "VirtualConstraintMap"]


def __getattr__(name: str):
    """A name of :data:`__all__`, from :mod:`analysis.stability`."""
    if name in __all__:
        return getattr(import_module(".stability", __name__), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

