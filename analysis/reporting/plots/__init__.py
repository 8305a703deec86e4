"""Every figure of the toolkit: compute a result elsewhere, draw it here.

In the style of python-control: each ``*_plot`` function takes results computed by the
other modules and returns a :class:`matplotlib.figure.Figure`; :func:`save_figure`
writes it.  Figures are built with the object-oriented API on their own canvas: no
pyplot state is touched and the user's backend is never changed (in a notebook, a
returned figure displays itself).
"""
from __future__ import annotations

from .common import (COLOUR_NAMES, STANCE, SWING, TORSO, _figure, _legs_legend, _stick,
                     run_label, save_figure, save_figures)
from .grid import grid_sweep_plot
from .mujoco import mujoco_animation, mujoco_eigen_plot, mujoco_steps_plot
from .speed_family import family_designs_plot, gait_family_plot
from .paper import (conjecture_plot, gait_profiles_plot, gait_stick_plot, m1_plane_plot,
                    one_d_sweeps_plot, stable_domains_plot, swing_torques_plot,
                    unactuated_error_plot)
from .running import running_plot, running_stability_plot
from .speed import speed_jumps_plot, speed_profile_plot
from .walking import (OUTCOME_COLOURS, basin_plot, mfpt_sigma_plot, survival_plot,
                      tradeoff_plot, walking_animation)

__all__ = ["COLOUR_NAMES", "STANCE", "SWING", "TORSO", "save_figure", "save_figures",
           "gait_stick_plot", "gait_profiles_plot", "one_d_sweeps_plot", "grid_sweep_plot",
           "conjecture_plot", "stable_domains_plot", "m1_plane_plot", "unactuated_error_plot",
           "swing_torques_plot", "walking_animation", "run_label", "basin_plot",
           "tradeoff_plot", "OUTCOME_COLOURS", "survival_plot", "mfpt_sigma_plot",
           "gait_family_plot", "family_designs_plot", "speed_profile_plot",
           "speed_jumps_plot", "mujoco_steps_plot", "mujoco_animation", "mujoco_eigen_plot",
           "running_plot", "running_stability_plot"]
