"""The paper's 9^4 grid (§V-A) for a gait, computed once and reused: stored with the
resumable sweep machinery in the cache folder ($BIPED_CACHE_DIR or
~/.cache/biped-casadi), keyed by the gait; a stored sweep made with other settings or
other code is replaced, never mixed; a cache folder that cannot be written is not an
error (the grid is then computed in memory)."""
from __future__ import annotations

import shutil

import numpy as np

from biped_casadi.caching import ResultStore, cached, task_key

from .storage import SweepStoreError
from .sweep import RESULTS_VERSION, SweepResult, grid_points, run_sweep

__all__ = ["grid_results", "grid_best"]


@cached(maxsize=4)
def grid_results(gait, n: int = 9, lo: float = -10.0, hi: float = 10.0,
                 folder=None, progress: bool = False) -> SweepResult:
    """The sweep of the n^nu grid on [lo, hi]^nu, computed once and kept.

    Memoised, and stored as a resumable sweep folder in the cache folder (under its key,
    :class:`biped_casadi.caching.ResultStore`); nu = ``model.nu``: the paper's 9^4 for
    RABBIT.

    Parameters
    ----------
    gait : Reference
        The reference step.
    n : int
        Points per component.
    lo, hi : float
        The range of every component.
    folder : str or Path, optional
        The cache folder (default :func:`biped_casadi.cache_dir`).
    progress : bool
        Show a progress bar.

    Returns
    -------
    SweepResult
    """
    model = gait.model
    folder = ResultStore(folder).path(task_key(
        "analysis.sweeps.grid_results", RESULTS_VERSION, "sweep", (gait, n, lo, hi)), "")
    P = grid_points(n, lo, hi, model.nu)
    try:
        return run_sweep(gait, P, out_dir=folder, progress=progress)
    except SweepStoreError:           # other settings or other code: recompute
        shutil.rmtree(folder, ignore_errors=True)
    except OSError:                   # a cache folder we cannot write: keep it in memory
        return run_sweep(gait, P, out_dir=None, progress=progress)
    return run_sweep(gait, P, out_dir=folder, progress=progress)


def grid_best(gait, n: int = 9, lo: float = -10.0, hi: float = 10.0) -> dict:
    """The best stable point of the grid.

    Parameters
    ----------
    gait : Reference
        The reference step.
    n : int
        Points per component.
    lo, hi : float
        The range of every component.

    Returns
    -------
    dict
        ``M1`` (list) and ``max_abs``; both None when no point is stable.
    """
    r = grid_results(gait, n, lo, hi)
    stable = np.flatnonzero(r.point_status == "stable")
    if not stable.size:
        return dict(M1=None, max_abs=None)
    i = stable[np.argmin(r.max_abs[stable])]
    return dict(M1=r.points[i].tolist(), max_abs=float(r.max_abs[i]))
