"""The paper's 9^4 grid (§V-A) for a gait, computed once and reused: stored with the
resumable sweep machinery in the cache folder ($BIPED_CACHE_DIR or
~/.cache/biped-casadi), keyed by the gait; a stored sweep made with other settings or
other code is replaced, never mixed."""
from __future__ import annotations

import shutil

import numpy as np

from .storage import SweepStoreError, digest_json
from .sweep import gait_to_dict, grid_points, run_sweep

_MEMO: dict = {}


def grid_results(model, gait, n: int = 9, lo: float = -10.0, hi: float = 10.0,
                 cache_dir=None, progress: bool = False):
    """(points, status, max_abs) of the n^4 grid."""
    key = (id(gait), n, lo, hi)
    if key in _MEMO and _MEMO[key][0] is gait:
        return _MEMO[key][1]
    from gait_opt.cache import cache_dir as _cache_dir
    folder = _cache_dir(cache_dir) / "sweeps" / f"{digest_json(gait_to_dict(gait))[:16]}_grid{n}_{lo:g}_{hi:g}"
    P = grid_points(n, lo, hi)
    try:
        r = run_sweep(model, gait, P, out_dir=folder, progress=progress)
    except SweepStoreError:           # other settings or other code: recompute
        shutil.rmtree(folder, ignore_errors=True)
        r = run_sweep(model, gait, P, out_dir=folder, progress=progress)
    res = (r.points, r.status, r.max_abs)
    _MEMO[key] = (gait, res)
    return res


def grid_best(model, gait, n: int = 9, lo: float = -10.0, hi: float = 10.0) -> dict:
    """The best stable point of the grid: {"M1": [...], "max_abs": x} (None if none)."""
    P, st, mx = grid_results(model, gait, n, lo, hi)
    stable = np.flatnonzero(st == "stable")
    if not stable.size:
        return dict(M1=None, max_abs=None)
    i = stable[np.argmin(mx[stable])]
    return dict(M1=P[i].tolist(), max_abs=float(mx[i]))
