"""Basins whose window contains their boundary.

A fixed window around the fixed point can lie inside the basin (the robust designs
converge from almost every cell of ±0.05 rad x ±0.5 rad/s), and then a picture of it
shows no boundary and its converged fraction does not compare designs.
:func:`basin_to_boundary` widens the window, axis by axis, until no cell on its edges
converges, up to a cap beyond which the section holds no state of a walking robot
(:func:`section_cap`), and gives the basin's area in rad x rad/s (docs/theory.md,
"Basins of attraction").
"""
from __future__ import annotations

import dataclasses
import math
import time

import numpy as np

from biped_casadi import Design, SimulationOptions
from biped_casadi.control.output_law import SECTION
from biped_casadi.numerics import as_number
from biped_casadi.simulation import virtual_constraint_walker

from ..tasks import task
from .basin import BasinResult, basin, grid_cells

__all__ = ["basin_to_boundary", "section_cap", "edge_cells", "NO_STATE"]

#: resolution of the scan of the section's configurations (rad of q_u)
CAP_SCAN_STEP = 1e-3
#: the outcome of a cell where the section holds no state of the robot (a point of it
#: under the ground, or no point of the constraint curve with that q_u)
NO_STATE = "no_state"


def section_cap(design: Design, nodes: int = 100) -> dict:
    """The largest window of the section that holds states of a walking robot.

    The window is centred on the fixed point x* = (q_u*, dq_u*) (docs/theory.md,
    "Basins of attraction"); beyond these half-widths both of its sides hold only
    states the robot cannot be in:

    - ``q_span``: the configuration at the section (on the design's zero-dynamics
      manifold: q_a = q_a^d(0.75 T) - M1 (q_u - q_u*) for a time-varying design, the
      point of the constraint curve with that q_u for virtual constraints) has a point
      of the robot (the swing foot, a knee, the hip, the torso's top) at or under the
      ground (or, for virtual constraints, no point of the curve has that q_u).  The
      cap is the farther of the two offsets where this starts, scanned every 1 mrad
      (``CAP_SCAN_STEP``) out to a horizontal stance leg, ``|q_u| = pi/2``; so it is exact
      to 1 mrad, rounded outward.
    - ``dq_span``: max(dq_u*, sqrt(g / r) - dq_u*), r the distance from the stance foot
      to the centre of mass at x*.  Below dq_u = 0 the stance leg turns backward (no
      forward step); above sqrt(g / r), the inverted pendulum's Froude limit
      r dq_u^2 = g, the stance foot's normal force is negative (the robot is in
      flight).  The limit treats the robot as a point mass turning at dq_u: an
      estimate of where flight starts, not its exact value.

    Parameters
    ----------
    design : Design
        The design on its gait.
    nodes : int
        Nodes per step of the virtual constraints' walker (its constraint curve).

    Returns
    -------
    dict
        ``q_span`` (rad), ``dq_span`` (rad/s), ``q_offsets`` (the two offsets, below
        and above x*, from which on the section holds no state of the robot, rad; just
        past the scan on a side where it always does), ``dq_lift`` (sqrt(g / r),
        rad/s) and ``reason`` (one line).
    """
    design = Design.require(design)
    gait = design.gait
    model = gait.model
    xs = gait.state_at(SECTION * gait.T)
    reach = math.pi / 2 - abs(float(xs[0]))
    d = np.arange(-reach, reach + CAP_SCAN_STEP / 2, CAP_SCAN_STEP)
    Q, ok = _section_configurations(design, xs, d, nodes)
    P = np.array(model.points.map(d.size)(Q))          # (2, m * points), per configuration
    z = P[1].reshape(d.size, -1)[:, 1:]                 # every point but the stance foot
    with np.errstate(invalid="ignore"):
        ok &= np.all(np.isfinite(z) & (z > 0), axis=1)
    i0 = int(np.argmin(np.abs(d)))
    lo, hi = _interval(ok, i0)
    # the first offsets without a state of the robot (past the scan where there is none)
    q_lo = float(-d[lo - 1]) if lo > 0 else reach + CAP_SCAN_STEP
    q_hi = float(d[hi + 1]) if hi < d.size - 1 else reach + CAP_SCAN_STEP
    r = float(np.linalg.norm(np.array(model.com(gait.q(SECTION * gait.T))).ravel()))
    lift = math.sqrt(model.description.gravity / r)
    dq_span = max(float(xs[1]), lift - float(xs[1]))
    return dict(q_span=min(max(q_lo, q_hi), reach), dq_span=dq_span,
                q_offsets=[-q_lo, q_hi], dq_lift=lift,
                reason=f"q_u: no state of the robot at the section from {-q_lo:+.3f} and "
                       f"{q_hi:+.3f} rad on (a point of it under the ground); dq_u: from 0 "
                       f"(the stance leg at rest) to the Froude limit sqrt(g/r) = "
                       f"{lift:.3f} rad/s (r = {r:.3f} m)")


def _section_configurations(design, xs, d, nodes):
    """Configurations (nq, m) at the section for q_u = q_u* + d, and where they exist."""
    gait = design.gait
    if design.M1 is None:
        W = virtual_constraint_walker(gait, None, nodes, jit=True)
        x = np.c_[xs[0] + d, np.full(d.size, xs[1])]
        th, _ = W.section_states(x)
        Q = np.array(W.vmap.curve.map(d.size)(th[None, :])[0])
        lo, hi = sorted((W.vmap.theta_plus, W.vmap.theta_minus))
        with np.errstate(invalid="ignore"):
            ok = (np.abs(Q[0] - x[:, 0]) < 1e-9) & (th >= lo) & (th <= hi)
        return Q, ok
    q = np.asarray(gait.q(SECTION * gait.T), float).ravel()
    Q = q[:, None] + np.vstack([d, -np.outer(np.asarray(design.M1), d)])
    return Q, np.ones(d.size, bool)


def _interval(ok, i0):
    """The run of True around index i0 of ``ok``: (first, last)."""
    lo = hi = i0
    while lo > 0 and ok[lo - 1]:
        lo -= 1
    while hi < ok.size - 1 and ok[hi + 1]:
        hi += 1
    return lo, hi


def edge_cells(result: BasinResult) -> dict:
    """Converged cells on each edge of a basin's window.

    Parameters
    ----------
    result : BasinResult
        A basin.

    Returns
    -------
    dict
        ``q_low``, ``q_high`` (the first and last rows, q_u* -/+ q_span), ``dq_low``,
        ``dq_high`` (the first and last columns): the number of converged cells on each.
    """
    return _edge_counts(np.asarray(result.outcome == "converged"))


def _edge_counts(c) -> dict:
    """:func:`edge_cells` of an (n, n) boolean array of converged cells."""
    return dict(q_low=int(c[0].sum()), q_high=int(c[-1].sum()),
                dq_low=int(c[:, 0].sum()), dq_high=int(c[:, -1].sum()))


def _touches(e: dict) -> tuple:
    """(converged cells on a q_u edge, on a dq_u edge)."""
    return e["q_low"] + e["q_high"] > 0, e["dq_low"] + e["dq_high"] > 0


def _probe(design: Design, spans, offsets, kw: dict) -> dict:
    """A window's row from its edges alone: the cells of its first and last rows and
    columns, each walked (those beyond ``offsets``, where the section holds no state of
    the robot, are not)."""
    t0 = time.perf_counter()
    n = kw["n"]
    _, a, _, cells, _ = grid_cells(design, n, spans[0], spans[1], kw["steps"], kw["tol"],
                                   kw["options"], kw["rk4_steps"], kw["nodes"])
    flat = np.arange(n * n).reshape(n, n)
    edge = np.unique(np.r_[flat[0], flat[-1], flat[:, 0], flat[:, -1]])
    idx = edge[((a > offsets[0]) & (a < offsets[1]))[edge // n]]
    conv = np.zeros(n * n, bool)
    if idx.size:
        conv[idx] = cells(idx)[0] == "converged"
    return dict(q_span=float(spans[0]), dq_span=float(spans[1]), converged_fraction=None,
                area=None, walked_cells=int(idx.size), edges=_edge_counts(conv.reshape(n, n)),
                elapsed=round(time.perf_counter() - t0, 3), probe=True)


def _window_row(b: BasinResult, edges: dict) -> dict:
    return dict(q_span=b.q_span, dq_span=b.dq_span, converged_fraction=b.converged_fraction,
                area=b.area, walked_cells=b.walked_cells, edges=edges,
                elapsed=round(b.elapsed, 3))


@task
def basin_to_boundary(design: Design, n: int = 101, q_span: float = 0.05,
                      dq_span: float = 0.5, steps: int = 10, tol: float = 1e-3,
                      options: SimulationOptions | None = None, rk4_steps: int = 128,
                      nodes: int = 100, refine: int | None = 4, factor: float = 2.0,
                      zoom: int = 2, max_q_span: float | None = None,
                      max_dq_span: float | None = None) -> BasinResult:
    """The basin of attraction on a window that contains its boundary.

    The definitions are those of docs/theory.md, "Basins of attraction".  Starting from
    ±``q_span`` x ±``dq_span`` around x*, the window's edges (every cell of its first
    and last rows and columns) are walked; while converged cells lie on the first or
    last row, ``q_span`` grows by ``factor``, and while they lie on the first or last
    column, ``dq_span`` does, each up to its cap (:func:`section_cap`, or
    ``max_q_span`` / ``max_dq_span``).  On the first window whose edges hold no
    converged cell (or at the caps) the whole basin (:func:`basin`) is walked; should
    its adaptive grid still put converged cells on an edge, the window grows again.  Rows
    where the section holds no state of the robot (beyond :func:`section_cap`'s
    ``q_offsets``: a point of it under the ground, or no point of the constraint curve)
    are marked :data:`NO_STATE` instead of the walk's outcome (it would start from a
    state the robot cannot be in), and are not in the basin.  Then, up
    to ``zoom`` times, an axis that did not grow and whose converged cells all lie
    inside the middle 1/``factor`` of the window shrinks by ``factor`` (a finer grid of
    the same basin); a zoomed window with converged cells on an edge is dropped.  The
    basin's area (converged cells times the cell area, rad x rad/s) then compares
    designs on any windows.

    Parameters
    ----------
    design : Design
        The design and its gait (time-varying, or virtual constraints).
    n : int
        Cells per axis of every window.
    q_span, dq_span : float
        Half-widths of the first window, rad and rad/s.
    steps, tol, options, rk4_steps, nodes
        As :func:`basin`.
    refine : int, optional
        The adaptive grid of :func:`basin` (``n - 1`` a multiple of it); None: every cell
        walked.
    factor : float
        Growth (and zoom) factor of a half-width, > 1.
    zoom : int
        Most zoom steps (0: the window only grows).
    max_q_span, max_dq_span : float, optional
        Caps of the half-widths (default :func:`section_cap`'s).

    Returns
    -------
    BasinResult
        The last window's basin; ``status`` 'contained' (no converged cell on an edge),
        'empty' (no converged cell at all: area 0) or 'capped' (converged cells on an
        edge of a window at its cap: the boundary is not all inside and ``area`` is a
        lower bound); ``windows`` lists every window
        walked (half-widths, converged cells per edge, cells walked, time, and the
        fraction and area of a whole basin; ``probe`` True and no area for a window of
        which the edges alone were walked), ``cap``
        the caps and why; ``elapsed`` the time of all windows.

    Raises
    ------
    ValueError
        Naming ``factor``, ``zoom``, ``max_q_span`` or ``max_dq_span`` (and the
        arguments :func:`basin` checks).
    """
    design = Design.require(design)
    factor = as_number(factor, "factor", positive=True)
    if factor <= 1:
        raise ValueError(f"factor must be > 1, got {factor!r}")
    if isinstance(zoom, bool) or not isinstance(zoom, int) or zoom < 0:
        raise ValueError(f"zoom must be an integer >= 0, got {zoom!r}")
    spans = [as_number(q_span, "q_span", positive=True),
             as_number(dq_span, "dq_span", positive=True)]
    t0 = time.perf_counter()
    cap = section_cap(design, nodes)
    for k, (name, given) in enumerate((("max_q_span", max_q_span),
                                       ("max_dq_span", max_dq_span))):
        key = ("q_span", "dq_span")[k]
        if given is not None:
            cap[key] = as_number(given, name, positive=True)
            cap["reason"] += f"; {key} capped at {cap[key]:g} by {name}"
    caps = [max(spans[0], cap["q_span"]), max(spans[1], cap["dq_span"])]
    kw = dict(n=n, steps=steps, tol=tol, options=options, rk4_steps=rk4_steps, nodes=nodes,
              refine=refine)
    rows, grew = [], [False, False]

    def walk(s):
        b = _mask(basin(design, q_span=s[0], dq_span=s[1], **kw), cap["q_offsets"])
        e = edge_cells(b)
        row = _window_row(b, e)
        if rows and rows[-1].get("probe") and [rows[-1]["q_span"], rows[-1]["dq_span"]] == s:
            edges_walk = rows.pop()         # this window's edges, walked first: one row
            row["walked_cells"] += edges_walk["walked_cells"]
            row["elapsed"] = round(row["elapsed"] + edges_walk["elapsed"], 3)
        rows.append(row)
        return b, _touches(e)

    def probe(s):
        rows.append(_probe(design, s, cap["q_offsets"], kw))
        return _touches(rows[-1]["edges"])

    def grow(touch):
        nonlocal spans
        grown = [min(s * factor, c) if t else s for s, c, t in zip(spans, caps, touch)]
        if grown == spans:
            return False
        grew[:] = [g or t for g, t in zip(grew, touch)]
        spans = grown
        return True

    # the edges decide the growth; the whole basin is walked once they hold no converged
    # cell (or at the caps), and again on a larger window if its adaptive grid put
    # converged cells on an edge that the walk of the edges did not
    touch = probe(spans)
    while True:
        while any(touch) and grow(touch):
            touch = probe(spans)
        b, touch = walk(spans)
        if not (any(touch) and grow(touch)):
            break
        touch = probe(spans)
    status = "capped" if any(touch) else "contained" if (b.outcome == "converged").any() \
        else "empty"
    for _ in range(zoom if status == "contained" else 0):
        inner = _zoomable(b, factor, grew)
        if not any(inner):
            break
        trial = [s / factor if z else s for s, z in zip(spans, inner)]
        bz, tz = walk(trial)
        if any(tz):
            rows[-1]["dropped"] = True
            break
        b, spans = bz, trial
    return _finish(b, status, rows, cap, time.perf_counter() - t0)


def _mask(b: BasinResult, offsets) -> BasinResult:
    """The basin with the rows beyond ``offsets`` (no state of the robot there:
    :func:`section_cap`) marked :data:`NO_STATE` instead of walked."""
    rows = (b.q_u <= offsets[0]) | (b.q_u >= offsets[1])
    if not rows.any():
        return b
    outcome, err = b.outcome.copy(), b.final_error.copy()
    outcome[rows, :], err[rows, :] = NO_STATE, np.inf
    names, counts = np.unique(outcome.astype(str), return_counts=True)
    conv = int(np.sum(outcome == "converged"))
    return dataclasses.replace(b, outcome=outcome, final_error=err,
                               counts={str(k): int(v) for k, v in zip(names, counts)},
                               converged_fraction=conv / outcome.size,
                               area=conv * b.cell_area)


def _zoomable(b: BasinResult, factor: float, grew) -> list:
    """Per axis (q_u, dq_u): whether every converged cell lies strictly inside the
    middle 1/factor of the window, and the axis did not grow."""
    c = np.asarray(b.outcome == "converged")
    if not c.any():
        return [False, False]
    ii, jj = np.nonzero(c)
    return [not grew[0] and np.max(np.abs(b.q_u[ii])) < b.q_span / factor,
            not grew[1] and np.max(np.abs(b.dq_u[jj])) < b.dq_span / factor]


def _finish(b: BasinResult, status: str, rows: list, cap: dict, elapsed: float):
    e = rows[-1]["edges"] if not rows[-1].get("dropped") else edge_cells(b)
    where = ", ".join(k for k, v in e.items() if v)
    windows = " -> ".join(f"±{r['q_span']:.3g} rad x ±{r['dq_span']:.3g} rad/s"
                          + (" (edges)" if r.get("probe") else "")
                          + (" (dropped)" if r.get("dropped") else "") for r in rows)
    n = b.outcome.shape[0]
    at_cap = [name for name, span, c in (("q_u", b.q_span, cap["q_span"]),
                                         ("dq_u", b.dq_span, cap["dq_span"])) if span >= c]
    say = (f"the window contains the basin's boundary: {100 * b.converged_fraction:.1f} % "
           f"of {n}x{n} cells, area {b.area:.4g} rad x rad/s"
           + (f" (the {' and '.join(at_cap)} window at its cap: {cap['reason']})"
              if at_cap else "")
           if status == "contained" else
           f"empty: none of the {n}x{n} cells around the fixed point converged, so this "
           f"grid finds no basin (area 0)"
           if status == "empty" else
           f"capped: converged cells on the {where} edge(s) of the largest window, so the "
           f"area {b.area:.4g} rad x rad/s is a lower bound ({cap['reason']})")
    return dataclasses.replace(b, status=status, elapsed=elapsed, windows=rows, cap=cap,
                               message=f"{say}; windows {windows}")
