"""Figures for viewers that are not matplotlib: the colours of the stick figures as RGB
triples (so a 3-D view paints the legs as every figure does), and a figure rendered to
an array of pixels (the basin panel of ``biped view``)."""
from __future__ import annotations

import numpy as np
from matplotlib.colors import to_rgb

from .common import STANCE, SWING, TORSO
from .walking import basin_plot

__all__ = ["role_colours", "figure_pixels", "basin_image"]


def role_colours() -> dict:
    """The colours of the stance leg, the swing leg and the torso of every figure.

    Returns
    -------
    dict
        ``stance``, ``swing``, ``torso`` -> (r, g, b), integers 0-255.
    """
    return {role: tuple(int(round(255 * c)) for c in to_rgb(colour))
            for role, colour in (("stance", STANCE), ("swing", SWING), ("torso", TORSO))}


def figure_pixels(fig, dpi: int = 80) -> np.ndarray:
    """A figure drawn at ``dpi`` as an RGB image.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        A figure of :mod:`analysis.reporting.plots` (on its own Agg canvas).
    dpi : int
        Pixels per inch.

    Returns
    -------
    numpy.ndarray
        (height, width, 3) uint8.
    """
    fig.set_dpi(dpi)
    fig.canvas.draw()
    return np.asarray(fig.canvas.buffer_rgba())[..., :3].copy()


def basin_image(result, dpi: int = 100) -> np.ndarray:
    """The basin of attraction of one design (:func:`basin_plot`) as an RGB image.

    Parameters
    ----------
    result : BasinResult
        From :func:`analysis.robustness.basin` or
        :func:`analysis.robustness.basin_to_boundary`.
    dpi : int
        Pixels per inch (the figure is about 8 x 5 inches).

    Returns
    -------
    numpy.ndarray
        (height, width, 3) uint8.
    """
    return figure_pixels(basin_plot(result, title="Section basin (tau = 0.75 T)"), dpi)
