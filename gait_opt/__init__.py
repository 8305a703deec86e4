"""Optimal cyclic reference gaits for planar five-link bipeds (direct collocation)."""
from .options import GaitOptions
from .gait import Gait, GaitFileError
from .optimize import GaitOptimizationError, optimize_gait

__all__ = ["optimize_gait", "Gait", "GaitOptions", "GaitOptimizationError", "GaitFileError"]
