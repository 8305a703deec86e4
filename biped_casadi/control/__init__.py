"""Control: the time-varying output law of the paper (each equation written once), the
reference interface, the hybrid zero dynamics of the time-varying controller, the two
closed-loop controllers and the surface of virtual constraints."""
from .controller import ControlOutput, Controller, StepStart
from .output_law import (M1_LIMIT, SECTION, SINGULAR_RTOL, Gains, SingularityReport, check_M1)
from .reference import Reference, require_reference, require_same_robot
from .saturation import clip_torques
from .time_varying import PAPER_REJOIN, TimeVaryingController
from .zero_dynamics import Linearisation, ZeroDynamics, zero_dynamics
from .virtual_constraints import (HIP_PHASE, ConstraintSurface, VirtualConstraintController,
                                  VirtualConstraints, constraint_surface,
                                  fit_virtual_constraints)
from .design import Design

__all__ = ["Controller", "StepStart", "ControlOutput", "SECTION", "SINGULAR_RTOL", "M1_LIMIT",
           "Gains", "SingularityReport", "check_M1", "Reference", "require_same_robot",
           "Design", "require_reference", "clip_torques",
           "TimeVaryingController", "PAPER_REJOIN", "VirtualConstraints",
           "VirtualConstraintController", "fit_virtual_constraints", "ConstraintSurface",
           "constraint_surface", "HIP_PHASE", "ZeroDynamics", "zero_dynamics", "Linearisation"]
