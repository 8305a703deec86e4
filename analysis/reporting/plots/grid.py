"""The N^nu grid of M1 as a figure (``biped sweep --grid N --plot DIR``): the map of
max|lambda| over the plane of a robot with two torques, and the pairs (corner) figure of
a robot with more."""
from __future__ import annotations

from itertools import combinations

import numpy as np
from matplotlib.colors import ListedColormap, TwoSlopeNorm
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import FixedLocator, FuncFormatter, MaxNLocator

from .common import _figure

__all__ = ["grid_sweep_plot", "grid_cells"]

#: colour of the cells without a max|lambda| to draw, per status (the colour map of
#: max|lambda| is blue below 1 and red above: none of these is in it)
NO_VALUE_COLOURS = {"singular": "0.72", "no_impact": "0.30", "open_orbit": "tab:purple"}
#: markers of those points on the plane of a robot with two torques
NO_VALUE_MARKERS = {"singular": "x", "no_impact": "v", "open_orbit": "s"}
#: what the legend calls them
NO_VALUE_LABELS = {"singular": "singular controller, eq. (24)",
                   "no_impact": "no valid impact within the horizon",
                   "open_orbit": "open orbit (gait not a periodic orbit)"}
#: the colour scale spans at most 10^-3 .. 10^3 (beyond: the colour bar's arrows)
LOG_SPAN = 3.0
#: the pairs figure writes the stable points of each cell up to this many values per
#: component
MAX_COUNTS = 13
#: the plane marks each point without a value when there are at most this many
MAX_MARKED = 600


def grid_cells(sweep, i: int, j: int):
    """Reduce a grid sweep to the cells of the plane (M1(i+1), M1(j+1)).

    Parameters
    ----------
    sweep : SweepResult
        A sweep over a full grid (every combination of the values of each component, as
        :func:`analysis.sweeps.grid_points` makes; any order of the rows).
    i, j : int
        Two different components (0-based): the plane's horizontal and vertical axes.

    Returns
    -------
    xv, yv : numpy.ndarray
        The grid values of components i and j.
    best : numpy.ndarray
        (len(xv), len(yv)) the smallest max ``|lambda|`` over the other components of the
        points of each cell whose status is 'stable' or 'unstable' (for nu = 2: the
        point's own value); inf where the cell has no such point.
    n_stable : numpy.ndarray
        (len(xv), len(yv)) the number of stable points of each cell.
    n_points : int
        Points per cell (1 for nu = 2).
    other : numpy.ndarray
        (len(xv), len(yv)) strings: for a cell without a value, its most frequent
        status among 'singular', 'no_impact', 'open_orbit'; '' elsewhere.

    Raises
    ------
    ValueError
        When the points are not a full grid, or i, j are not two components.
    """
    P = np.asarray(sweep.points, float)
    nu = P.shape[1]
    if not (0 <= i < nu and 0 <= j < nu and i != j):
        raise ValueError(f"i, j must be two different components in 0..{nu - 1}, "
                         f"got {i}, {j}")
    values, idx = _grid_index(P)
    shape = tuple(len(v) for v in values)
    st = np.asarray(sweep.point_status).astype(str)
    mx = np.asarray(sweep.max_abs, float)
    has = np.isin(st, ("stable", "unstable")) & np.isfinite(mx)
    V = np.full(shape, np.inf)
    V[idx] = np.where(has, mx, np.inf)
    S = np.zeros(shape, bool)
    S[idx] = st == "stable"
    others = tuple(k for k in range(nu) if k not in (i, j))
    order = (i, j) + others
    V, S = V.transpose(order), S.transpose(order)
    best = V.reshape(shape[i], shape[j], -1).min(axis=2)
    n_stable = S.reshape(shape[i], shape[j], -1).sum(axis=2)
    other = np.full(best.shape, "", dtype="<U10")
    empty = ~np.isfinite(best)
    if empty.any():
        counts = []
        for name in NO_VALUE_COLOURS:
            C = np.zeros(shape, int)
            C[idx] = st == name
            counts.append(C.transpose(order).reshape(shape[i], shape[j], -1).sum(axis=2))
        pick = np.array(list(NO_VALUE_COLOURS))[np.argmax(np.stack(counts), axis=0)]
        other[empty] = pick[empty]
    per_cell = int(np.prod(shape)) // (shape[i] * shape[j])
    return values[i], values[j], best, n_stable, per_cell, other


def _grid_index(P):
    """The values of each component and each row's index tuple; ValueError if the rows
    are not every combination of those values exactly once."""
    values, idx = [], []
    for k in range(P.shape[1]):
        v, inv = np.unique(P[:, k], return_inverse=True)
        values.append(v)
        idx.append(inv.ravel())
    shape = tuple(len(v) for v in values)
    flat = np.ravel_multi_index(tuple(idx), shape)
    if len(P) != int(np.prod(shape)) or len(np.unique(flat)) != len(P):
        raise ValueError(f"sweep: its {len(P)} points are not a full grid of M1 "
                         f"({' x '.join(map(str, shape))} values per component); "
                         f"grid_sweep_plot draws grids such as grid_points(n, lo, hi, nu)")
    return values, tuple(idx)


def grid_sweep_plot(sweep, gait=None, title: str | None = None) -> Figure:
    """The grid of M1 of ``biped sweep --grid N``: where max ``|lambda|`` < 1.

    With two components of M1 (the three-link biped) one panel shows max ``|lambda|`` of
    every point over the plane (M1(1), M1(2)).  With nu > 2 (RABBIT's 4) there is one
    panel per pair (M1(i), M1(j)), as in a corner plot, and each cell shows the
    *smallest* max ``|lambda|`` over the other nu - 2 components: blue where some choice
    of the other components is stable, so the boundary max ``|lambda|`` = 1 of a panel
    encloses the pairs that admit a stable M1, and the values say how stable the best of
    them is (the design question a grid answers).  The fraction of stable points of a
    cell, the other candidate, is at most 4 of 81 (4.9 %) in every cell of the paper's
    9^4 grid on RABBIT's default gait and would draw nearly uniform panels; the number
    of stable points of a cell is written in its corner instead, when the panels are
    small enough to read it (at most 13 values per component).

    Colour: log scale of max ``|lambda|`` that steps at 1 (blues: stable, darker the
    more; yellow to dark red: unstable), clipped to 10^-3 .. 10^3, with the boundary
    max ``|lambda|`` = 1 in black along the cell edges (a contour would cut through the
    cells of a coarse grid).  Cells without a value are painted per status (grey:
    singular controller; dark grey: no impact; purple: open orbit), and on the plane of
    two components each such point is marked too; in a pairs panel a cell is painted so
    only when none of its points has a value (the title counts every status).  The sweep's best point (smallest
    finite max ``|lambda|``, :meth:`SweepResult.best`) is starred in every panel.  The
    title names the gait, the grid and the counts, and says so when no point is stable
    or no point has a value.

    Parameters
    ----------
    sweep : SweepResult
        A sweep over a full grid (:func:`analysis.sweeps.grid_points`), computed or
        read back with :func:`analysis.sweeps.load_sweep`.
    gait : Reference, optional
        Its gait, named in the title (robot, speed, period); without it the title names
        the robot stored in the sweep's settings.
    title : str, optional
        Replaces the first line of the title.

    Returns
    -------
    Figure

    Raises
    ------
    ValueError
        When the sweep's points are not a full grid.
    """
    P = np.asarray(sweep.points, float)
    if P.ndim != 2 or len(P) == 0:
        raise ValueError("sweep: no points to draw")
    nu = P.shape[1]
    if nu < 2:
        raise ValueError("sweep: M1 has one component; one_d_sweeps_plot draws a line")
    _grid_index(P)                                   # a full grid, or say so now
    st = np.asarray(sweep.point_status).astype(str)
    mx = np.asarray(sweep.max_abs, float)
    valued = np.isin(st, ("stable", "unstable")) & np.isfinite(mx)
    best = sweep.best()
    cells = {(i, j): grid_cells(sweep, i, j) for (i, j) in combinations(range(nu), 2)}
    shown = np.concatenate([c[2][np.isfinite(c[2])] for c in cells.values()])
    norm, extend = _norm(shown)
    cmap = _cmap()
    fig, axes, legend_ax = _layout(nu)
    im, drawn, per_cell = None, set(), None
    for (i, j), (xv, yv, B, NS, n_cell, other) in cells.items():
        ax = axes[(i, j)]
        Z = np.ma.masked_invalid(np.log10(np.where(np.isfinite(B), B, np.nan)))
        im = ax.pcolormesh(xv, yv, Z.T, shading="nearest", cmap=cmap, norm=norm)
        for name, colour in NO_VALUE_COLOURS.items():
            sel = other == name
            if sel.any():
                drawn.add(name)
                ax.pcolormesh(xv, yv, np.ma.masked_where(~sel, np.ones(sel.shape)).T,
                              shading="nearest", cmap=ListedColormap([colour]),
                              vmin=0, vmax=2)
        _stability_boundary(ax, xv, yv, B < 1.0)
        if nu == 2:
            _mark_no_value(ax, P, st)
        elif max(len(xv), len(yv)) <= MAX_COUNTS:
            _write_counts(ax, xv, yv, NS)
            per_cell = n_cell
        if best is not None:
            ax.plot(best.M1[i], best.M1[j], marker="*", ms=15 if nu == 2 else 11,
                    color="gold", mec="k", mew=1.0, ls="none", zorder=5, gid="best")
            if nu == 2:
                ax.annotate(f"best: {best.max_abs:.3g}", (best.M1[i], best.M1[j]),
                            xytext=(8, 8), textcoords="offset points", fontsize=9,
                            fontweight="bold", zorder=6,
                            bbox=dict(boxstyle="round,pad=0.2", fc="white", ec="k",
                                      lw=0.6, alpha=0.9))
        _axes_style(ax, xv, yv, i, j, nu)
    cb = fig.colorbar(im, ax=list(axes.values()), extend=extend,
                      shrink=1.0 if nu == 2 else 0.8, aspect=30)
    cb.set_label("max|λ| of $A^z$ (log scale)" if nu == 2 else
                 "smallest max|λ| of $A^z$ over the other "
                 + ("component" if nu == 3 else f"{nu - 2} components") + " (log scale)")
    _log_ticks(cb, norm)
    cb.ax.axhline(0.0, color="k", lw=1.4)
    handles, labels = _legend(best, drawn, nu, st,
                              per_cell if np.any(st == "stable") else None)
    if legend_ax is None:                    # below the plane: it hides no cell
        fig.legend(handles, labels, loc="outside lower center", ncols=2, fontsize=8)
    else:
        leg = legend_ax.legend(handles, labels, loc="upper right", fontsize=9)
        leg.set_in_layout(False)             # the panels keep their size and places
    fig.suptitle(_title(sweep, gait, title, st, valued, best, nu), fontsize=11)
    return fig


def _layout(nu):
    """The figure, its panels by pair (i, j) and the axes that holds the legend: the
    empty corner above the panels (None for nu = 2: the legend goes below the plane)."""
    if nu == 2:
        fig = _figure(figsize=(7.2, 6.9), layout="constrained")
        return fig, {(0, 1): fig.add_subplot()}, None
    k = nu - 1
    size = 3.0 if k <= 3 else 2.3
    fig = _figure(figsize=(size * k + 1.6, size * k + 0.9), layout="constrained")
    grid = fig.subplots(k, k, squeeze=False)
    axes = {}
    for r in range(k):
        for c in range(k):
            if c <= r:
                axes[(c, r + 1)] = grid[r, c]
            elif (r, c) == (0, k - 1):
                grid[r, c].axis("off")
            else:
                grid[r, c].set_visible(False)
    return fig, axes, grid[0, k - 1]


def _stability_boundary(ax, xv, yv, stable):
    """The edges between stable and other cells: the boundary max|lambda| = 1, drawn
    along the cells as they are coloured (a contour would cut through them)."""
    from matplotlib.collections import LineCollection
    xe, ye = _edges(xv), _edges(yv)
    seg = []
    pad = np.pad(stable, 1, constant_values=False)
    dx = pad[1:, 1:-1] != pad[:-1, 1:-1]            # (nx + 1, ny): edges x = xe[a]
    for a, b in zip(*np.nonzero(dx)):
        seg.append([(xe[a], ye[b]), (xe[a], ye[b + 1])])
    dy = pad[1:-1, 1:] != pad[1:-1, :-1]            # (nx, ny + 1): edges y = ye[b]
    for a, b in zip(*np.nonzero(dy)):
        seg.append([(xe[a], ye[b]), (xe[a + 1], ye[b])])
    if seg:
        ax.add_collection(LineCollection(seg, colors="k", linewidths=1.3, zorder=3,
                                         capstyle="projecting"))


def _edges(v):
    """Cell edges around grid values (midpoints, and half a step beyond the ends)."""
    mid = (v[1:] + v[:-1]) / 2
    return np.concatenate([[v[0] - (mid[0] - v[0])], mid, [v[-1] + (v[-1] - mid[-1])]])


def _cmap():
    """Blues below max|lambda| = 1 (darker: more stable), yellow to dark red above: the
    colour steps at 1, so a stable cell stands out at a glance."""
    from matplotlib import colormaps
    below = colormaps["Blues_r"](np.linspace(0.05, 0.6, 128))
    above = colormaps["YlOrRd"](np.linspace(0.08, 1.0, 128))
    return ListedColormap(np.vstack([below, above]),
                          name="stable_unstable").with_extremes(bad=(1.0, 1.0, 1.0, 0.0))


def _norm(values):
    """Log10 colour scale, white at max|lambda| = 1, both sides at least one decade."""
    if values.size:
        lo, hi = np.log10(values.min()), np.log10(values.max())
    else:
        lo, hi = -1.0, 1.0
    vmin, vmax = max(min(lo, -1.0), -LOG_SPAN), min(max(hi, 1.0), LOG_SPAN)
    extend = {(False, False): "neither", (True, False): "min", (False, True): "max",
              (True, True): "both"}[(lo < -LOG_SPAN, hi > LOG_SPAN)]
    return TwoSlopeNorm(0.0, vmin, vmax), extend


def _log_ticks(cb, norm):
    """Colour-bar ticks at the decades (and at 2 and 5 of each when it spans at most
    three decades), labelled as max|lambda| values."""
    d = np.arange(np.floor(norm.vmin), np.ceil(norm.vmax) + 1)
    steps = (1.0, 2.0, 5.0) if norm.vmax - norm.vmin <= 3.0 + 1e-9 else (1.0,)
    ticks = np.log10([m * 10.0 ** k for k in d for m in steps])
    ticks = ticks[(ticks >= norm.vmin - 1e-9) & (ticks <= norm.vmax + 1e-9)]
    cb.ax.yaxis.set_major_locator(FixedLocator(ticks))
    cb.ax.yaxis.set_major_formatter(FuncFormatter(
        lambda v, _: np.format_float_positional(10.0 ** v, precision=3, unique=False,
                                                fractional=False, trim="-")))
    cb.ax.yaxis.set_minor_locator(FixedLocator([]))


def _mark_no_value(ax, P, st):
    for name, marker in NO_VALUE_MARKERS.items():
        sel = st == name
        if sel.any() and sel.sum() <= MAX_MARKED:
            ax.plot(P[sel, 0], P[sel, 1], marker=marker, ls="none", ms=4, mew=1.0,
                    color=_marker_colour(name), zorder=3)


def _marker_colour(name):
    return "white" if name == "no_impact" else "k"


def _write_counts(ax, xv, yv, NS):
    """The number of stable points of each cell, small in its lower right corner (the
    best point's star sits at the centre)."""
    xe, ye = _edges(xv), _edges(yv)
    for a in range(len(xv)):
        for b in range(len(yv)):
            if NS[a, b]:
                ax.text(xe[a + 1] - 0.08 * (xe[a + 1] - xe[a]),
                        ye[b] + 0.08 * (ye[b + 1] - ye[b]), str(NS[a, b]), ha="right",
                        va="bottom", fontsize=5.5, color="k", zorder=4)


def _axes_style(ax, xv, yv, i, j, nu):
    ax.set_xlim(_edges(xv)[[0, -1]])
    ax.set_ylim(_edges(yv)[[0, -1]])
    for axis, v in ((ax.xaxis, xv), (ax.yaxis, yv)):
        if len(v) <= 9:                     # ticks at grid values, at most 5 labelled
            axis.set_major_locator(FixedLocator(v[::-(-len(v) // 5)]))
            axis.set_major_formatter(FuncFormatter(lambda t, _: f"{t:.3g}"))
        else:
            axis.set_major_locator(MaxNLocator(6))
    ax.tick_params(labelsize=8 if nu > 2 else 9)
    if nu == 2 or j == nu - 1:
        ax.set_xlabel(f"$M_1({i + 1})$" + (" (dimensionless)" if nu == 2 else ""))
    else:
        ax.tick_params(labelbottom=False)
    if nu == 2 or i == 0:
        ax.set_ylabel(f"$M_1({j + 1})$" + (" (dimensionless)" if nu == 2 else ""))
    else:
        ax.tick_params(labelleft=False)
    ax.set_aspect("auto")


def _legend(best, drawn, nu, st, per_cell):
    """The legend's handles and labels (a handle may be a tuple: drawn on top of each
    other)."""
    h = [Patch(fc=_cmap()(0.25), ec="none", label="stable: max|λ| < 1"),
         Patch(fc=_cmap()(0.75), ec="none", label="unstable: max|λ| ≥ 1"),
         Line2D([], [], color="k", lw=1.4, label="boundary max|λ| = 1")]
    for name in NO_VALUE_COLOURS:
        if name not in drawn:
            continue
        n = int(np.count_nonzero(st == name))
        label = NO_VALUE_LABELS[name] + (f" ({n} point{'s' * (n != 1)})" if nu == 2 else
                                         "\n  (every point of the cell)")
        patch = Patch(fc=NO_VALUE_COLOURS[name], ec="0.4", lw=0.5, label=label)
        if nu == 2 and n <= MAX_MARKED:        # the cell's colour with the point's marker
            patch = (patch, Line2D([], [], marker=NO_VALUE_MARKERS[name], ls="none", ms=5,
                                   mew=1.0, color=_marker_colour(name), label=label))
        h.append(patch)
    if per_cell is not None:
        h.append(Line2D([], [], ls="none", marker="$n$", color="k", ms=7,
                        label=f"n: stable points of the cell's {per_cell}"))
    if best is not None:
        where = ", ".join(f"{v:.3g}" for v in best.M1)
        h.append(Line2D([], [], marker="*", ms=12, color="gold", mec="k", ls="none",
                        label=f"best: max|λ| = {best.max_abs:.3g}"
                              + ("" if best.status == "stable" else f" ({best.status})")
                              + f"\n  at M1 = [{where}]"))
    return h, [(x[0] if isinstance(x, tuple) else x).get_label() for x in h]


def _title(sweep, gait, title, st, valued, best, nu):
    P = np.asarray(sweep.points, float)
    n_val = len(np.unique(P[:, 0]))
    lo, hi = P.min(), P.max()
    if title is None:
        if gait is not None:
            name = getattr(getattr(gait.model, "params", None), "name", None) or "robot"
            title = (f"{name} gait at {gait.speed:.2f} m/s (T = {gait.T:.3f} s)")
        else:
            title = f"{(sweep.settings or {}).get('robot', 'robot')} gait"
        title += (f": max|λ| of $A^z$ on the ${n_val}^{{{nu}}}$ grid of $M_1$, "
                  f"each component in [{lo:g}, {hi:g}]")
    n, n_st = len(st), int(np.count_nonzero(st == "stable"))
    parts = [f"{n_st} of {n} points stable ({100.0 * n_st / n:.2g} %)"]
    for name in NO_VALUE_COLOURS:
        c = int(np.count_nonzero(st == name))
        if c:
            parts.append(f"{c} {name.replace('_', ' ')}")
    line2 = ", ".join(parts)
    if not valued.any():
        only = [name for name in NO_VALUE_COLOURS if np.all(st == name)]
        line2 = (f"every one of the {n} points {only[0].replace('_', ' ')}" if only
                 else line2) + " - no point has a max|λ| to draw"
    elif n_st == 0:
        line2 += " - NO STABLE POINT"
        if best is not None:
            line2 += f" (smallest max|λ| {best.max_abs:.3g})"
    return title + "\n" + line2
