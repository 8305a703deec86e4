"""Simulation: the full-order hybrid closed loop, the batched walkers on the hybrid zero
dynamics, the stepping kernel and the validity conditions they share, one outcome type
for every run, perturbations and pushes, uneven ground, and speed profiles (one design per
step)."""
from .full_order import (SimulationResult, Simulator, StepRecord, perturbed_initial_state,
                         simulate, simulator)
from .kernel import Diagnostics, locate_strike, strike
from .options import SimulationOptions
from .outcome import NOT_CONVERGED, STATUSES, WalkBatch, WalkOutcome, failure_text, verdict
from .perturbation import (PAPER_SIZES, Perturbation, direction_errors, directions,
                           start_states, torso_push)
from .speed_profile import (ProfileResult, ProfileSegment, ProfileStep, simulate_profile,
                            walk_profile)
from .terrain import Terrain, TerrainFileError, random_heights, step_heights
from .tv_walker import ZeroDynamicsWalker, zero_dynamics_walker
from .validity import Limits
from .vc_walker import VirtualConstraintWalker, virtual_constraint_walker

__all__ = ["SimulationOptions", "SimulationResult", "StepRecord", "Simulator", "simulate",
           "simulator", "perturbed_initial_state", "STATUSES", "NOT_CONVERGED", "WalkOutcome",
           "WalkBatch", "verdict", "failure_text", "Perturbation", "directions", "direction_errors",
           "start_states", "PAPER_SIZES", "ZeroDynamicsWalker", "VirtualConstraintWalker",
           "zero_dynamics_walker", "virtual_constraint_walker", "Diagnostics", "strike",
           "locate_strike", "Limits", "torso_push", "Terrain", "TerrainFileError",
           "random_heights", "step_heights", "simulate_profile", "walk_profile",
           "ProfileResult", "ProfileStep", "ProfileSegment"]
