"""The robot and its control: symbolic dynamics (CasADi), the time-varying output law of
Wang & Chevallereau, the controllers and the full-order hybrid simulator.

This is the bottom layer of the toolkit: it imports nothing from :mod:`gait_opt` or
:mod:`analysis`.  Controllers and the simulator are written against the reference
interface :class:`~biped_casadi.control.reference.Reference`, which :class:`gait_opt.Gait`
implements.
"""
from importlib import metadata as _metadata

from .caching import cache_dir, cached
from .control import (HIP_PHASE, Design, PAPER_REJOIN, SECTION, Gains, Reference, SingularityReport,
                      TimeVaryingController, VirtualConstraintController, VirtualConstraints,
                      fit_virtual_constraints, require_same_robot)
from .model import (B_INPUT, E_RELABEL, RABBIT, RABBIT_DESCRIPTION, BipedModel, Link,
                    RobotDescription, RobotParams, description_from_dict, find_description,
                    load_description, load_params, rabbit, resolve_robot, robot)
from .results import Result, json_safe
from .simulation import (PAPER_SIZES, Perturbation, SimulationOptions,
                         SimulationResult, Simulator, directions, perturbed_initial_state,
                         simulate)

__all__ = ["rabbit", "robot", "resolve_robot", "RobotDescription", "Link",
           "load_description", "find_description", "description_from_dict",
           "RABBIT_DESCRIPTION", "BipedModel", "RobotParams", "RABBIT", "load_params", "E_RELABEL",
           "B_INPUT", "Design", "Reference", "require_same_robot", "Gains", "SingularityReport",
           "SECTION", "TimeVaryingController", "VirtualConstraintController",
           "VirtualConstraints", "fit_virtual_constraints", "HIP_PHASE", "PAPER_REJOIN",
           "Simulator", "SimulationOptions", "SimulationResult", "simulate",
           "perturbed_initial_state", "Result", "json_safe",
           "cached", "cache_dir", "Perturbation", "directions", "PAPER_SIZES"]
try:
    __version__ = _metadata.version("biped-casadi")
except _metadata.PackageNotFoundError:      # running from a source tree that is not installed
    __version__ = "0+unknown"
