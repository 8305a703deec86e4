"""Basins of attraction on the Poincaré section: which zero-dynamics states of a
controller walk and converge.

Every cell of a grid around the fixed point x* = (q_u^d, dq_u^d)(0.75 T) is a state on
the controller's zero-dynamics manifold at the section, walked for a number of impacts
with every validity condition checked (the batched walkers of
:mod:`biped_casadi.simulation`).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from biped_casadi import Design, SimulationOptions
from biped_casadi.control.output_law import SECTION
from biped_casadi.numerics import as_number
from biped_casadi.results import Result, internal
from biped_casadi.simulation import virtual_constraint_walker, zero_dynamics_walker

from ..tasks import task

__all__ = ["BasinResult", "basin", "grid_cells"]


@dataclass
class BasinResult(Result):
    """Outcome of every cell of a grid of zero-dynamics states on the Poincaré section.

    ``dq_u`` (columns) and ``q_u`` (rows) are the offsets of the cells from the fixed
    point x* = (q_u^d, dq_u^d)(0.75 T).  ``status`` is always 'done' (``success``).  The
    grid arrays are left out of ``to_dict()``.

    Parameters
    ----------
    controller : str
        'tv' (time-varying design) or 'vc' (virtual constraints).
    design : dict
        :meth:`Design.to_dict` of the time-varying design, or ``{"controller": "vc"}``.
    x_star : list of float
        The fixed point (q_u^d, dq_u^d) at 0.75 T, rad and rad/s.
    steps : int
        Impacts walked from each cell.
    tol : float
        Convergence threshold on the final error.
    converged_fraction : float
        Fraction of the cells that converged.
    counts : dict
        Outcome -> number of cells.
    elapsed : float
        Wall time, s.
    status : str
        'done' (a fixed window); from :func:`analysis.robustness.basin_to_boundary`
        'contained' (no cell on the window's edges converges: the basin's boundary is
        inside the window), 'empty' (no cell converges: the area is 0) or 'capped' (the
        window reached its cap with converged cells on an edge: the area is a lower
        bound).
    message : str
        The converged percentage and the area in words.
    q_u : numpy.ndarray
        (n,) offsets of the rows from q_u*, rad.
    dq_u : numpy.ndarray
        (n,) offsets of the columns from dq_u*, rad/s.
    outcome : numpy.ndarray
        (n, n) ``outcome[i, j]`` is 'converged' (every step valid, final error below
        ``tol``), 'walked' (valid but not converged) or the status of the first invalid
        state.
    final_error : numpy.ndarray
        (n, n) ``max(|q_u err|, |dq_u err|)`` at the last step; inf where failed; NaN
        where an adaptive grid filled the cell without walking it.
    walked_cells : int
        Cells walked (n^2 on the full grid; fewer with ``refine``).
    q_span, dq_span : float
        Half-widths of the window, rad and rad/s.
    cell_area : float
        Area of one cell, (2 q_span / (n - 1)) (2 dq_span / (n - 1)), rad x rad/s.
    area : float
        The basin's area on the section: converged cells times ``cell_area``, rad x
        rad/s (docs/theory.md, "Basins of attraction").
    window_area : float
        The area of the n x n cells (``area / converged_fraction``), rad x rad/s.
    windows : list of dict
        The windows walked by :func:`analysis.robustness.basin_to_boundary`, in order
        (empty for a fixed window).
    cap : dict or None
        The largest window :func:`analysis.robustness.basin_to_boundary` may reach and
        why (None for a fixed window).
    """

    controller: str
    design: dict
    x_star: list
    steps: int
    tol: float
    converged_fraction: float
    counts: dict
    elapsed: float
    status: str = "done"
    message: str = ""
    walked_cells: int = 0
    q_span: float = 0.0
    dq_span: float = 0.0
    cell_area: float = 0.0
    area: float = 0.0
    window_area: float = 0.0
    windows: list = field(default_factory=list)
    cap: dict | None = None
    q_u: np.ndarray = internal(default=None)
    dq_u: np.ndarray = internal(default=None)
    outcome: np.ndarray = internal(default=None)
    final_error: np.ndarray = internal(default=None)

    SUCCESS = ("done", "contained", "empty")


@task
def basin(design: Design, n: int = 101,
          q_span: float = 0.05, dq_span: float = 0.5, steps: int = 10, tol: float = 1e-3,
          options: SimulationOptions | None = None, rk4_steps: int = 128,
          nodes: int = 100, refine: int | None = None) -> BasinResult:
    """The basin of attraction on the 2-D section of the zero dynamics.

    Every cell (q_u* + a, dq_u* + b), a in [-q_span, q_span], b in [-dq_span, dq_span],
    is a state on the controller's zero-dynamics manifold at the section (for the
    time-varying controller tau = 0.75 T with v_c = 0; for virtual constraints the point
    of the constraint surface with that q_u and dq_u), walked for ``steps`` impacts with
    every validity condition checked.

    ``basin(Design.vc(gait))`` is the basin of virtual constraints on the gait,
    ``basin(Design.tv(gait, M1, rejoin))`` a time-varying design's.

    Parameters
    ----------
    design : Design
        The design and its gait (time-varying, or virtual constraints).
    n : int
        Cells per axis.
    q_span, dq_span : float
        Half-widths of the grid, rad and rad/s.
    steps : int
        Impacts walked from each cell.
    tol : float
        Convergence threshold on ``max(|q_u err|, |dq_u err|)`` at the last step.
    options : SimulationOptions, optional
        Validity thresholds (default: mu 0.6, the robot's torque limit).
    rk4_steps, nodes : int
        Integration of the time-varying walker (RK4 steps per T) and of the virtual
        constraints (nodes per step).
    refine : int, optional
        An adaptive grid: the cells every ``refine``-th row and column are walked first;
        a block between four walked corners of one outcome takes that outcome, any
        other block is walked cell by cell, and so is every block next to a walked cell
        whose outcome differs from its filled neighbour, until none is left.  ``n - 1``
        must be a multiple of ``refine``.  It draws the boundary cell by cell; an island
        smaller than a block with one outcome at its four corners is missed
        (``benchmarks/bench_basin.py``, the five basins of the report at n = 101 and
        refine = 4: 8.5x faster, 47 of 51,005 cells differ, converged fractions equal to
        0.04 points).  None: every cell is walked.

    Returns
    -------
    BasinResult
    """
    design = Design.require(design)
    if isinstance(n, bool) or not isinstance(n, int) or n < 2:
        raise ValueError(f"n (cells per axis) must be an integer >= 2, got {n!r}")
    q_span = as_number(q_span, "q_span", positive=True)
    dq_span = as_number(dq_span, "dq_span", positive=True)
    t0 = time.perf_counter()
    xs, a, b, cells, design_dict = grid_cells(design, n, q_span, dq_span, steps, tol,
                                              options, rk4_steps, nodes)
    if refine is None:
        outcome, err = cells(np.arange(n * n))
        walked = n * n
    else:
        outcome, err, walked = _adaptive(cells, n, refine)
    names, counts = np.unique(outcome.astype(str), return_counts=True)
    frac = float(np.mean(outcome == "converged"))
    cell = (2 * q_span / (n - 1)) * (2 * dq_span / (n - 1))
    area = int(np.sum(outcome == "converged")) * cell
    return BasinResult(
        controller=design.controller, design=design_dict,
        x_star=xs.tolist(), steps=steps, tol=tol, converged_fraction=frac,
        counts={str(k): int(v) for k, v in zip(names, counts)},
        elapsed=time.perf_counter() - t0,
        message=f"{100 * frac:.1f} % of {n}x{n} cells converge within {steps} steps "
                f"(area {area:.4g} rad x rad/s)"
                + ("" if refine is None else f" (adaptive grid: {walked} cells walked)"),
        walked_cells=int(walked), q_span=q_span, dq_span=dq_span, cell_area=cell,
        area=area, window_area=n * n * cell,
        q_u=a, dq_u=b, outcome=outcome.reshape(n, n), final_error=err.reshape(n, n))


def grid_cells(design: Design, n: int, q_span: float, dq_span: float, steps: int,
               tol: float, options, rk4_steps: int, nodes: int) -> tuple:
    """A basin's grid on the section and the walk of its cells (the arguments of
    :func:`basin`).

    Returns
    -------
    tuple
        (x*, the q_u offsets (n,), the dq_u offsets (n,), ``cells``, the design as a dict);
        ``cells(idx)`` walks the cells of flat indices ``idx`` (row-major, q_u by row)
        and returns their outcomes ('converged', 'walked' or the walker's failure) and
        final errors.
    """
    gait = design.gait
    xs = gait.state_at(SECTION * gait.T)
    a, b = np.linspace(-q_span, q_span, n), np.linspace(-dq_span, dq_span, n)
    A, Bg = np.meshgrid(a, b, indexing="ij")
    X = np.c_[xs[0] + A.ravel(), xs[1] + Bg.ravel()]
    opts = options or SimulationOptions()
    if design.M1 is None:
        W = virtual_constraint_walker(gait, opts, nodes, jit=True)

        def walk(Xs):
            return W.walk_from_section(Xs, steps)
        design_dict = dict(controller="vc")
    else:
        W = zero_dynamics_walker(gait, opts, rk4_steps, jit=True)

        def walk(Xs):
            return W.walk_from_section(Xs, np.array(design.M1), design.rejoin, steps)
        design_dict = dict(controller="tv", M1=list(design.M1), rejoin=design.rejoin)

    def cells(idx):
        """Walk the cells of flat indices idx: (outcome, final error)."""
        batch = walk(X[idx])
        e = batch.final_error
        return (np.where(batch.ok, np.where(e < tol, "converged", "walked"),
                         batch.status).astype(object), e)

    return xs, a, b, cells, design_dict


def _adaptive(cells, n: int, k: int):
    """The adaptive grid of :func:`basin` (``refine=k``): (outcome, final error, cells
    walked), flat arrays of n^2."""
    if isinstance(k, bool) or not isinstance(k, int) or k < 2:
        raise ValueError(f"refine must be an integer >= 2 dividing n - 1 = {n - 1}, "
                         f"got {k!r}")
    if (n - 1) % k:
        lo = (n - 1) // k * k + 1                 # the sizes that fit, around n
        a, b = (lo, lo + k) if lo > 1 else (lo + k, lo + 2 * k)
        raise ValueError(f"refine = {k} must divide n - 1 = {n - 1}: take n = {a} or {b}, "
                         f"another refine, or refine=None (every cell walked)")
    outcome = np.full(n * n, None, dtype=object)
    err = np.full(n * n, np.nan)
    walked = np.zeros(n * n, bool)
    flat = np.arange(n * n).reshape(n, n)
    nb = (n - 1) // k

    def walk(idx):
        idx = np.unique(idx)
        idx = idx[~walked[idx]]
        if idx.size:
            o, e = cells(idx)
            outcome[idx], err[idx], walked[idx] = o, e, True

    def block(bi, bj):
        return flat[bi * k:(bi + 1) * k + 1, bj * k:(bj + 1) * k + 1].ravel()

    walk(flat[::k, ::k].ravel())
    uniform, mixed = [], []
    for bi in range(nb):
        for bj in range(nb):
            c = outcome[[bi * k * n + bj * k, bi * k * n + (bj + 1) * k,
                         (bi + 1) * k * n + bj * k, (bi + 1) * k * n + (bj + 1) * k]]
            (uniform if all(x == c[0] for x in c) else mixed).append((bi, bj, c[0]))
    if mixed:
        walk(np.concatenate([block(bi, bj) for bi, bj, _ in mixed]))
    for bi, bj, o in uniform:
        b = block(bi, bj)
        outcome[b[~walked[b]]] = o
    while True:           # a walked cell disagreeing with a filled neighbour: walk its block
        O, Wk = outcome.reshape(n, n), walked.reshape(n, n)
        need = set()
        for sa, sb in (((slice(None), slice(0, -1)), (slice(None), slice(1, None))),
                       ((slice(0, -1), slice(None)), (slice(1, None), slice(None)))):
            diff = O[sa] != O[sb]
            for wa, wb, off in ((Wk[sa], Wk[sb], sb), (Wk[sb], Wk[sa], sa)):
                ii, jj = np.nonzero(diff & wa & ~wb)
                ii = ii + (off[0].start or 0)
                jj = jj + (off[1].start or 0)
                for i, j in zip(ii, jj):
                    for bi in {min(i // k, nb - 1), max(min((i - 1) // k, nb - 1), 0)}:
                        for bj in {min(j // k, nb - 1), max(min((j - 1) // k, nb - 1), 0)}:
                            need.add((bi, bj))
        if not need:
            break
        before = int(walked.sum())
        walk(np.concatenate([block(bi, bj) for bi, bj in need]))
        if int(walked.sum()) == before:
            break
    return outcome, err, int(walked.sum())
