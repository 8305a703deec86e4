"""The 9^4 grid of the paper (§V-A), computed once per gait and reused."""
from __future__ import annotations

import numpy as np

from .poincare import poincare_map

_GRID: dict = {}


def paper_grid(n: int = 9, lo: float = -10.0, hi: float = 10.0) -> np.ndarray:
    v = np.linspace(lo, hi, n)
    return np.stack(np.meshgrid(v, v, v, v, indexing="ij"), -1).reshape(-1, 4)


def grid_results(model, gait, n: int = 9, lo: float = -10.0, hi: float = 10.0):
    """(points, status, max_abs) of the n^4 grid, memoised per gait."""
    key = (id(gait), n, lo, hi)
    if key not in _GRID:
        P = paper_grid(n, lo, hi)
        st, _, _, mx = poincare_map(model, gait).jacobian_batch(P)
        _GRID[key] = (P, st, mx)
    return _GRID[key]


def grid_best(model, gait, n: int = 9, lo: float = -10.0, hi: float = 10.0) -> dict:
    """The best stable point of the grid: {"M1": [...], "max_abs": x} (None if none)."""
    P, st, mx = grid_results(model, gait, n, lo, hi)
    stable = np.flatnonzero(st == "stable")
    if not stable.size:
        return dict(M1=None, max_abs=None)
    i = stable[np.argmin(mx[stable])]
    return dict(M1=P[i].tolist(), max_abs=float(mx[i]))
