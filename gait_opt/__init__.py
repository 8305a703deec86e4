"""Optimal cyclic reference gaits by direct collocation (CasADi + IPOPT).

Imports only :mod:`biped_casadi`.  :func:`optimize_gait` returns a :class:`Gait`, which
implements the reference interface :class:`biped_casadi.Reference` that the controllers,
the simulator and the maps of :mod:`analysis` use.  :func:`gait_family` gives gaits over
a range of speeds by continuation (a :class:`GaitFamily`, with gaits between its members
by :meth:`GaitFamily.gait_at`).
"""
from .errors import GaitOptimizationError
from .speed_family import FamilyGait, GaitFamily, MemberRecord, parse_speed_range, speed_range
from .family_solve import gait_family
from .gait import ORBIT_TOL, Gait, GaitFileError, OpenOrbitWarning
from .hzd_orbit import BezierConstraints, fit_bezier_constraints
from .importing import IMPORT_TOL, MAX_IMPORT_TOL, GaitImport, GaitImportError, import_gait
from .nodes import Nodes, read_nodes
from .optimize import GaitSolveResult, optimize_gait
from .options import (REFERENCE_LEG_LENGTH, REFERENCE_SPEED, GaitOptions, LegScaled,
                      default_step_length_bounds, gait_fields, guess_step_length, leg_scale,
                      reference_speed)
from .polish import ClosedOrbit, close_orbit

__all__ = ["optimize_gait", "GaitSolveResult", "Gait",
           "GaitOptions", "GaitOptimizationError", "GaitFileError", "OpenOrbitWarning",
           "ORBIT_TOL", "import_gait", "GaitImport", "GaitImportError", "IMPORT_TOL",
           "MAX_IMPORT_TOL", "Nodes",
           "read_nodes", "BezierConstraints", "fit_bezier_constraints", "close_orbit",
           "ClosedOrbit", "gait_family", "GaitFamily", "MemberRecord",
           "FamilyGait", "speed_range", "parse_speed_range", "REFERENCE_LEG_LENGTH",
           "leg_scale", "LegScaled", "gait_fields", "REFERENCE_SPEED", "reference_speed",
           "default_step_length_bounds", "guess_step_length"]
