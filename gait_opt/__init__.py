"""Optimal cyclic reference gaits by direct collocation (CasADi + IPOPT).

Imports only :mod:`biped_casadi`.  :func:`optimize_gait` returns a :class:`Gait`, which
implements the reference interface :class:`biped_casadi.Reference` that the controllers,
the simulator and the maps of :mod:`analysis` use.
"""
from .errors import GaitOptimizationError
from .gait import ORBIT_TOL, Gait, GaitFileError, OpenOrbitWarning
from .optimize import GaitSolveResult, default_gait, optimize_gait, solve_gait
from .options import GaitOptions

__all__ = ["optimize_gait", "solve_gait", "GaitSolveResult", "default_gait", "Gait",
           "GaitOptions", "GaitOptimizationError", "GaitFileError", "OpenOrbitWarning",
           "ORBIT_TOL"]
