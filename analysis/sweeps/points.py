"""The points of a sweep: the paper's grid over M1, one component along a line, and the
checks of user-given points."""
from __future__ import annotations

import math

import numpy as np

from biped_casadi.control.output_law import check_M1_range

__all__ = ["grid_points", "max_grid_n", "line_points"]


def grid_points(n: int, lo: float, hi: float, dim: int = 4) -> np.ndarray:
    """The n^dim grid of M1, component 1 varying slowest.

    Parameters
    ----------
    n : int
        Points per component (at least 2: the grid spans LO to HI), each in
        ``linspace(lo, hi, n)``.
    lo, hi : float
        Range of every component.
    dim : int
        Components of M1: the robot's nu (4 for RABBIT, 2 for the three-link biped).

    Returns
    -------
    numpy.ndarray
        (n^dim, dim).  The paper's grid is ``grid_points(9, -10, 10)``.
    """
    if isinstance(dim, bool) or not isinstance(dim, (int, np.integer)) or dim < 1:
        raise ValueError(f"dim (components of M1) must be a positive integer, got {dim!r}")
    if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or n < 2:
        raise ValueError(f"n (grid points per component) must be an integer >= 2 (the grid "
                         f"spans LO to HI), got {n!r}")
    if float(n) ** dim > 50_000_000:
        raise ValueError(f"n = {n} gives {n ** dim} points; at most 50 million "
                         f"(n <= {max_grid_n(dim)})")
    lo, hi = _check_range(lo, hi)
    v = np.linspace(lo, hi, int(n))
    return np.stack(np.meshgrid(*([v] * int(dim)), indexing="ij"), axis=-1).reshape(-1, int(dim))


def max_grid_n(dim: int = 4) -> int:
    """The most points per component of a grid of at most 50 million M1.

    Parameters
    ----------
    dim : int
        Components of M1.

    Returns
    -------
    int
        84 for RABBIT's 4.
    """
    return int(50_000_000 ** (1 / dim) + 1e-9)


def line_points(j: int, values, nu: int = 4) -> np.ndarray:
    """M1 with one component set to each of ``values`` and the others zero.

    Parameters
    ----------
    j : int
        The component, 0-based (the paper's M1(j+1)).
    values : array_like
        Its values.
    nu : int
        Components of M1 (4 for RABBIT).

    Returns
    -------
    numpy.ndarray
        (len(values), nu).
    """
    if isinstance(j, bool) or not isinstance(j, (int, np.integer)) or not 0 <= j < nu:
        raise ValueError(f"j (component of M1, 0..{nu - 1}) must be one of "
                         f"{', '.join(map(str, range(nu)))}, got {j!r}")
    try:
        v = np.asarray(values, dtype=float).ravel()
    except (TypeError, ValueError):
        raise ValueError("values must be a non-empty list of finite numbers") from None
    if v.size == 0 or not np.all(np.isfinite(v)):
        raise ValueError("values must be a non-empty list of finite numbers")
    P = np.zeros((v.size, nu))
    P[:, j] = v
    return P


def _check_range(lo, hi):
    try:
        lo, hi = float(lo), float(hi)
    except (TypeError, ValueError):
        raise ValueError(f"lo, hi must be two numbers, got {lo!r} {hi!r}") from None
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ValueError(f"lo, hi must be finite, got {lo} {hi}")
    if not lo < hi:
        raise ValueError(f"lo must be less than hi, got lo = {lo:g}, hi = {hi:g}")
    check_M1_range([lo, hi], "lo, hi")
    return lo, hi


def _check_points(points, m: int = 4) -> np.ndarray:
    P = np.asarray(points, dtype=float)
    if P.ndim != 2 or P.shape[1] != m or P.shape[0] == 0:
        raise ValueError(f"points must be a non-empty (n, {m}) array of M1, got shape {P.shape}")
    if not np.all(np.isfinite(P)):
        raise ValueError("points must be finite")
    check_M1_range(P, "points")
    return np.ascontiguousarray(P)


