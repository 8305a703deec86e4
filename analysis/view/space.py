"""Where the M1 sliders of ``biped view`` start and how far they reach.

The start: the M1 given, else the most stable point of the paper's 9^nu grid
(:func:`analysis.sweeps.grid_cache.grid_results`, kept in the cache) among those whose
walk is valid, else the most stable point, else zero.  The reach of slider j: the
interval of M1(j) that stays stable with the other components held at the start (an
exact scan of max|lambda| along that axis), widened on each side by its own width and
at least :data:`MIN_PAD`, so that a slider crosses the stability boundary on both
sides; where the start is not stable on that axis, :data:`FALLBACK_HALF_WIDTH` around
it.  The stable sets of RABBIT are thin (about 0.1 to 0.7 wide along an axis), so the
sliders cover a few units, not the whole grid; the number boxes take any value inside.
Both are kept in the cache folder, so a warm start reads one small file.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass

import numpy as np

from biped_casadi.caching import ResultStore, task_key
from biped_casadi.control.output_law import M1_LIMIT
from biped_casadi.files import write_bytes_atomic

from ..stability import poincare_map
from ..sweeps.grid_cache import grid_results

__all__ = ["SliderSpace", "slider_space", "axis_ranges", "SCAN_HALF_WIDTH", "SCAN_POINTS",
           "MIN_PAD", "FALLBACK_HALF_WIDTH", "ROUND_TO"]

#: the scan of each axis: this far on each side of the start, at this many points
SCAN_HALF_WIDTH, SCAN_POINTS = 3.0, 301
#: the least margin beyond the stable interval on each side
MIN_PAD = 1.0
#: half the reach of a slider whose axis has no stable interval through the start
FALLBACK_HALF_WIDTH = 2.5
#: slider ends are rounded outward to multiples of this
ROUND_TO = 0.1
#: stable grid points whose walks are tried, most stable first, for the start
CANDIDATES = 8
#: the version of the slider spaces kept in the cache (bump it when the rule changes)
SPACES_VERSION = 1


@dataclass(frozen=True)
class SliderSpace:
    """The start and the reach of the M1 sliders.

    Parameters
    ----------
    M1 : tuple of float
        The start design.
    ranges : tuple of (float, float)
        (low, high) of each slider.
    stable : tuple
        Per component, the stable interval (low, high) through the start along that
        axis, or None where the start is not stable on it.
    source : str
        How the start was chosen (for the page).
    """

    M1: tuple
    ranges: tuple
    stable: tuple
    source: str


def axis_ranges(gait, M1, rejoin: float = 0.5) -> tuple:
    """The reach of every slider around ``M1`` (the module's rule).

    Parameters
    ----------
    gait : Reference
        The gait.
    M1 : array_like
        The start, one number per torque.
    rejoin : float
        Rejoin time of v_c, fraction of T.

    Returns
    -------
    tuple
        (ranges, stable): per component (low, high) of the slider, and the stable
        interval or None.
    """
    c = np.asarray(M1, dtype=float)
    offsets = np.linspace(-SCAN_HALF_WIDTH, SCAN_HALF_WIDTH, SCAN_POINTS)
    pmap = poincare_map(gait, rejoin=float(rejoin))
    ranges, stable = [], []
    for j in range(c.size):
        P = np.repeat(c[None, :], SCAN_POINTS, axis=0)
        P[:, j] = np.clip(c[j] + offsets, -M1_LIMIT, M1_LIMIT)
        ok = pmap.jacobian_batch(P).status == "stable"
        i0 = SCAN_POINTS // 2
        if ok[i0]:
            lo, hi = _run_through(ok, i0)
            a, b = P[lo, j], P[hi, j]
            pad = max(b - a, MIN_PAD)
            ranges.append(_rounded(a - pad, b + pad))
            stable.append((float(a), float(b)))
        else:
            ranges.append(_rounded(c[j] - FALLBACK_HALF_WIDTH, c[j] + FALLBACK_HALF_WIDTH))
            stable.append(None)
    return tuple(ranges), tuple(stable)


def _run_through(ok, i0):
    """The first and last index of the run of True values through ``i0``."""
    lo = hi = i0
    while lo > 0 and ok[lo - 1]:
        lo -= 1
    while hi < len(ok) - 1 and ok[hi + 1]:
        hi += 1
    return lo, hi


def _rounded(lo, hi):
    return (float(round(math.floor(lo / ROUND_TO) * ROUND_TO, 6)),
            float(round(math.ceil(hi / ROUND_TO) * ROUND_TO, 6)))


def _start(gait, rejoin, walks_ok):
    """(M1, source): the most stable grid point that walks, else the most stable one,
    else zero."""
    nu = gait.model.nu
    if float(rejoin) != 0.5:
        return tuple([0.0] * nu), "zero (the stored grid is for rejoin 0.5)"
    grid = grid_results(gait)
    stable = np.flatnonzero(grid.point_status == "stable")
    if not stable.size:
        return tuple([0.0] * nu), f"zero (no stable point on the paper's 9^{nu} grid)"
    order = stable[np.argsort(grid.max_abs[stable])]
    for i in order[:CANDIDATES]:
        if walks_ok(grid.points[i]):
            return (tuple(map(float, grid.points[i])),
                    f"the most stable point of the paper's 9^{nu} grid whose walk is valid")
    return (tuple(map(float, grid.points[order[0]])),
            f"the most stable point of the paper's 9^{nu} grid (no walk of the first "
            f"{min(CANDIDATES, order.size)} valid)")


def slider_space(gait, M1=None, rejoin: float = 0.5, walks_ok=None, walk_key=None,
                 cache: bool = True) -> SliderSpace:
    """The start and the reach of the sliders, kept in the cache folder.

    Parameters
    ----------
    gait : Reference
        The gait.
    M1 : array_like, optional
        The start; None: chosen as the module says.
    rejoin : float
        Rejoin time of v_c, fraction of T.
    walks_ok : callable, optional
        ``walks_ok(M1) -> bool``: whether the walk of a candidate start is valid (used
        only when ``M1`` is None; default: every candidate walks).
    walk_key : object, optional
        What ``walks_ok`` depends on (JSON-able; part of the cache key).
    cache : bool
        Read and write the kept result.

    Returns
    -------
    SliderSpace
    """
    body = dict(gait=gait.cache_key, M1=None if M1 is None else [float(v) for v in M1],
                rejoin=float(rejoin), walk=walk_key if M1 is None else None,
                rule=[2, SCAN_HALF_WIDTH, SCAN_POINTS, MIN_PAD, FALLBACK_HALF_WIDTH, ROUND_TO,
                      CANDIDATES])
    path = ResultStore().path(task_key("analysis.view.space.slider_space", SPACES_VERSION,
                                       "numerical", (body,)), ".json")
    if cache:
        kept = _read(path)
        if kept is not None:
            return kept
    if M1 is None:
        start, source = _start(gait, rejoin, walks_ok or (lambda _: True))
    else:
        start, source = tuple(float(v) for v in M1), "given (--m1)"
    ranges, stable = axis_ranges(gait, start, rejoin)
    space = SliderSpace(start, ranges, stable, source)
    if cache:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            write_bytes_atomic(path, json.dumps(asdict(space)).encode())
        except OSError:                  # a cache folder we cannot write: not an error
            pass
    return space


def _read(path):
    try:
        d = json.loads(path.read_text())
        return SliderSpace(tuple(d["M1"]), tuple(tuple(r) for r in d["ranges"]),
                           tuple(None if s is None else tuple(s) for s in d["stable"]),
                           str(d["source"]))
    except (OSError, ValueError, KeyError, TypeError):
        return None
