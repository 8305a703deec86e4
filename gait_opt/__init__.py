"""Optimal cyclic reference gaits by direct collocation (CasADi + IPOPT).

Imports only :mod:`biped_casadi`.  :func:`optimize_gait` returns a :class:`Gait`, which
implements the reference interface :class:`biped_casadi.Reference` that the controllers,
the simulator and the maps of :mod:`analysis` use.
"""
from .errors import GaitOptimizationError
from .gait import ORBIT_TOL, Gait, GaitFileError, OpenOrbitWarning
from .hzd_orbit import BezierConstraints, fit_bezier_constraints
from .importing import IMPORT_TOL, GaitImport, GaitImportError, import_gait
from .nodes import Nodes, read_nodes
from .optimize import GaitSolveResult, default_gait, optimize_gait, solve_gait
from .options import GaitOptions
from .polish import ClosedOrbit, close_orbit

__all__ = ["optimize_gait", "solve_gait", "GaitSolveResult", "default_gait", "Gait",
           "GaitOptions", "GaitOptimizationError", "GaitFileError", "OpenOrbitWarning",
           "ORBIT_TOL", "import_gait", "GaitImport", "GaitImportError", "IMPORT_TOL", "Nodes",
           "read_nodes", "BezierConstraints", "fit_bezier_constraints", "close_orbit",
           "ClosedOrbit"]
