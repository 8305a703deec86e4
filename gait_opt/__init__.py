"""Optimal cyclic reference gaits for planar five-link bipeds (direct collocation)."""
from .options import GaitOptions
from .gait import Gait, GaitFileError
from .optimize import GaitOptimizationError, optimize_gait
from .cache import default_gait

__all__ = ["optimize_gait", "default_gait", "Gait", "GaitOptions", "GaitOptimizationError",
           "GaitFileError"]
