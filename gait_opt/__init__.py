"""Optimal cyclic reference gaits by direct collocation (CasADi + IPOPT).

Imports only :mod:`biped_casadi`.  :func:`optimize_gait` returns a :class:`Gait`, which
implements the reference interface :class:`biped_casadi.Reference` that the controllers,
the simulator and the maps of :mod:`analysis` use.  :func:`gait_family` gives gaits over
a range of speeds by continuation (a :class:`GaitFamily`, with gaits between its members
by :meth:`GaitFamily.gait_at`).
"""
from .cache import default_gait
from .errors import GaitOptimizationError
from .family import FamilyGait, GaitFamily, MemberRecord, parse_speed_range, speed_range
from .family_solve import gait_family
from .gait import ORBIT_TOL, Gait, GaitFileError, OpenOrbitWarning
from .optimize import GaitSolveResult, optimize_gait, solve_gait
from .options import GaitOptions

__all__ = ["optimize_gait", "solve_gait", "GaitSolveResult", "default_gait", "Gait",
           "GaitOptions", "GaitOptimizationError", "GaitFileError", "OpenOrbitWarning",
           "ORBIT_TOL", "gait_family", "GaitFamily", "MemberRecord", "FamilyGait",
           "speed_range", "parse_speed_range"]
