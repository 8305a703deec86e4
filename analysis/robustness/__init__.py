"""Robustness: which controllers walk.  s*, the largest scale of the paper's perturbation
every kept direction survives with every step valid, for one design or many at once, and
basins of attraction on the Poincaré section (on a fixed window, or on one that
contains their boundary)."""
from .basin import BasinResult, basin
from .basin_window import basin_to_boundary, edge_cells, section_cap
from .s_star import (BatchSStar, Design, RobustnessResult, RobustnessSettings, decay_steps,
                     kept_directions, robustness, s_star_batch, start_states, steps_short)

__all__ = ["Design", "RobustnessSettings", "RobustnessResult", "kept_directions", "robustness",
           "start_states", "BatchSStar", "s_star_batch", "BasinResult", "basin",
           "basin_to_boundary", "section_cap", "edge_cells", "decay_steps", "steps_short"]
