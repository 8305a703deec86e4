"""Symbolic dynamics and controllers for underactuated planar bipeds (CasADi)."""
from .params import RABBIT, RobotParams, load_params
from .model import B_INPUT, E_RELABEL, BipedModel, rabbit

__all__ = ["rabbit", "BipedModel", "RobotParams", "RABBIT", "load_params",
           "E_RELABEL", "B_INPUT"]
__version__ = "0.1.0"
