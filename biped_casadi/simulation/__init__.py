"""Simulation: the full-order hybrid closed loop, the batched walkers on the hybrid zero
dynamics, the validity conditions every simulator checks, and perturbations."""
from .full_order import (PAPER_PERTURBATION, STATUSES, SimulationOptions, SimulationResult,
                         Simulator, StepRecord, perturbed_initial_state, simulate, simulator)
from .perturbation import PAPER_SIZES, Perturbation, directions
from .walkers import (VirtualConstraintWalker, WalkBatch, ZeroDynamicsWalker,
                      virtual_constraint_walker, zero_dynamics_walker)

__all__ = ["SimulationOptions", "SimulationResult", "StepRecord", "Simulator", "simulate",
           "simulator", "perturbed_initial_state", "STATUSES", "PAPER_PERTURBATION",
           "Perturbation", "directions", "PAPER_SIZES", "ZeroDynamicsWalker",
           "VirtualConstraintWalker", "WalkBatch", "zero_dynamics_walker",
           "virtual_constraint_walker"]
