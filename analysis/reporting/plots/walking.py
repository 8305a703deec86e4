"""What walks and how far: the animation of a run, the basins of attraction, the
robustness trade-off and the survival on stochastic terrain."""
from __future__ import annotations

import numpy as np
from PIL import Image
from matplotlib import patheffects
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from biped_casadi.files import atomic_path

from .common import STANCE, SWING, TORSO, _figure, _legs_legend, run_label

__all__ = ["walking_animation", "OUTCOME_COLOURS", "FIXED_WINDOW", "basin_plot",
           "tradeoff_plot", "survival_plot", "mfpt_sigma_plot"]


# ------------------------------------------------------------------ animation
def walking_animation(res, model, path, fps: int = 25, max_steps: int | None = None,
                      title: str | None = None) -> str:
    """Stick-figure animation of a run, written as a GIF (Pillow).

    It shows the ground, the footprints of every stance foot, the stance leg, the swing
    leg and the torso, in real time at ``fps`` frames per second.

    Parameters
    ----------
    res : SimulationResult
    model : BipedModel
    path : str or Path
        The .gif to write.
    fps : int
    max_steps : int, optional
        Animate only the first steps.
    title : str, optional
        What is walking (default the robot, the controller and the run's status).

    Returns
    -------
    str
        ``path`` (written through a temporary file: complete or absent).
    """
    if isinstance(fps, bool) or not isinstance(fps, int) or fps < 1:
        raise ValueError(f"fps must be a positive integer, got {fps!r}")
    if res.t.size == 0:
        raise ValueError("res: the run has no logged states to animate")
    sel = np.ones(res.t.size, bool) if max_steps is None else res.step < max_steps
    t, q, step, sx = res.t[sel], res.q[sel], res.step[sel], res.stance_x[sel]
    frames = np.searchsorted(t, np.arange(t[0], t[-1] + 1e-12, 1.0 / fps))
    frames = np.unique(np.clip(frames, 0, t.size - 1))
    npts = model.points.size2_out(0)
    P = np.array(model.points.map(t.size)(q.T)).reshape(2, npts, t.size, order="F")
    P[0] += sx[None, :]
    landed = [s.step_length for s in res.steps if max_steps is None or s.index < max_steps]
    prints = np.r_[0.0, np.cumsum(landed)]       # the first stance foot and every landing
    fig = _figure(figsize=(7.5, 3.6))
    ax = fig.add_subplot()
    x_lo, x_hi = P[0].min() - 0.3, P[0].max() + 0.3
    ax.set_xlim(x_lo, x_hi)
    ax.set_ylim(-0.08, P[1].max() + 0.1)
    ax.set_aspect("equal")
    ax.axhline(0, color="0.3", lw=1.5)
    ax.fill_between([x_lo, x_hi], -0.08, 0, color="0.85")
    foot, = ax.plot(prints, np.zeros_like(prints), "k^", ms=6, label="footprints")
    stance, = ax.plot([], [], "-o", color=STANCE, lw=3, ms=4)
    swing, = ax.plot([], [], "-o", color=SWING, lw=3, ms=4)
    torso, = ax.plot([], [], "-", color=TORSO, lw=4)
    text = ax.text(0.99, 0.95, "", transform=ax.transAxes, va="top", ha="right", fontsize=9)
    ax.set_title(title or f"{model.params.name}, {run_label(res)}: {res.status}", fontsize=10)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("z [m]")
    _legs_legend(ax, [foot])

    st, to, sw = (list(c) for c in (model.stance_chain, model.torso_chain, model.swing_chain))

    def draw(i):
        k = frames[i]
        X, Z = P[0, :, k], P[1, :, k]
        stance.set_data(X[st], Z[st])
        swing.set_data(X[sw], Z[sw])
        torso.set_data(X[to], Z[to])
        text.set_text(f"t = {t[k]:.2f} s, step {step[k] + 1}")
        return stance, swing, torso, text

    # the still parts drawn once; per frame only the legs, the torso and the clock on a
    # copy of them (a whole redraw per frame took about 0.1-0.2 s)
    moving = (stance, swing, torso, text)
    for a in moving:
        a.set_animated(True)
    canvas = fig.canvas
    fig.tight_layout()                                   # the axis labels inside the frame
    canvas.draw()
    still = canvas.copy_from_bbox(fig.bbox)
    images = []
    for i in range(len(frames)):
        canvas.restore_region(still)
        for a in draw(i):
            ax.draw_artist(a)
        images.append(Image.fromarray(np.array(canvas.buffer_rgba()), "RGBA"))
    with atomic_path(path) as tmp:
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:],
                       duration=int(1000 / fps), loop=0)
    return str(path)


# ------------------------------------------------------------------ basins
#: colour of every outcome of a walk (basin pictures)
OUTCOME_COLOURS = {
    "converged": ("#2ca02c", "converged"),
    "walked": ("#b8e6a0", "walked, not converged"),
    "slipped": ("#d62728", "slipped (friction cone or impulse)"),
    "negative_normal_force": ("#ff7f0e", "lost contact (F_z <= 0)"),
    "scuffed": ("#8c564b", "scuffed / no lift-off"),
    "torque_limit": ("#9467bd", "torque limit"),
    "fell": ("#222222", "fell"),
    "singular": ("#7f7f7f", "controller singular"),
    "no_impact": ("#1f77b4", "no impact (stalled)"),
    "out_of_range": ("#e377c2", "left the controller's range"),
    "diverged": ("#e377c2", "diverged"),
    "no_state": ("#e0e0e0", "no state of the robot (a point\nunder the ground, off the curve)"),
}


#: the window of the report's basins before they grew to their boundary (rad, rad/s)
FIXED_WINDOW = (0.05, 0.5)
_OUTLINE = [patheffects.withStroke(linewidth=2.4, foreground="k")]


def basin_plot(results, title: str | None = None, labels=None,
               reference_window=FIXED_WINDOW) -> Figure:
    """Basins of attraction on the section of the zero dynamics, side by side.

    Parameters
    ----------
    results : BasinResult or list of them
        From :func:`analysis.robustness.basin` or
        :func:`analysis.robustness.basin_to_boundary` (each on its own window).
    title : str, optional
    labels : list of str, optional
        A name per panel, written above its design (default: the design alone).
    reference_window : (float, float) or None
        Half-widths (rad, rad/s) of a window drawn dashed on panels whose own window is
        larger (default the fixed window of the report's basins); None: not drawn.

    Returns
    -------
    Figure
        One panel per result on its own window, axes the offsets from the fixed point in
        rad and rad/s: every cell coloured by its outcome after the result's number of
        steps (converged, walked, or the first failure's cause), the basin's boundary (a
        black line between converged cells and the rest), the fixed point marked; the
        title gives the converged fraction, the basin's area in rad x rad/s and the
        window.  One legend of outcomes for all panels.
    """
    results = results if isinstance(results, (list, tuple)) else [results]
    labels = labels or [None] * len(results)
    names = list(OUTCOME_COLOURS)
    cmap = ListedColormap([OUTCOME_COLOURS[k][0] for k in names])
    width = 5.2 * len(results) + 3.0
    fig = _figure(figsize=(width, 5.0))
    axes = np.atleast_1d(fig.subplots(1, len(results)))
    present, extra = set(), {}
    for ax, r, label in zip(axes, results, labels):
        present |= set(np.unique(r.outcome.astype(str)))
        extra.update(_basin_panel(ax, r, label, names, cmap, reference_window))
    axes[0].set_ylabel(r"$q_u - q_u^*$ at the section [rad]")
    handles = [Patch(color=OUTCOME_COLOURS[k][0], label=OUTCOME_COLOURS[k][1])
               for k in names if k in present]
    handles.append(Line2D([], [], marker="*", color="w", mec="k", ms=10, ls="",
                          label="fixed point x*"))
    handles += list(extra.values())
    fig.legend(handles=handles, loc="center right", fontsize=8, frameon=False)
    fig.suptitle(title or "Basins of attraction on the Poincaré section (tau = 0.75 T)")
    fig.tight_layout(rect=(0, 0, 1 - 2.9 / width, 1))
    return fig


def _basin_panel(ax, r, label, names, cmap, reference_window) -> dict:
    """Draw one basin on ``ax``; the legend entries it adds beyond the outcomes."""
    codes = np.vectorize(lambda o: names.index(o) if o in names else names.index("diverged"))(
        r.outcome.astype(str))
    da, db = np.diff(r.q_u[:2])[0] / 2, np.diff(r.dq_u[:2])[0] / 2
    extent = [r.dq_u[0] - db, r.dq_u[-1] + db, r.q_u[0] - da, r.q_u[-1] + da]
    ax.imshow(codes, origin="lower", aspect="auto", cmap=cmap, vmin=-0.5,
              vmax=len(names) - 0.5, interpolation="nearest", extent=extent)
    extra = {}
    conv = (r.outcome == "converged").astype(float)
    if 0 < conv.sum() < conv.size:
        ax.contour(r.dq_u, r.q_u, conv, levels=[0.5], colors="k", linewidths=0.9)
        extra["boundary"] = Line2D([], [], color="k", lw=0.9, label="basin boundary")
    if reference_window is not None:
        qw, dw = reference_window
        if r.q_u[-1] > qw * (1 + 1e-9) or r.dq_u[-1] > dw * (1 + 1e-9):
            ax.plot([-dw, dw, dw, -dw, -dw], [-qw, -qw, qw, qw, -qw], "w--", lw=1.2,
                    path_effects=_OUTLINE)
            extra["window"] = Line2D([], [], color="w", ls="--", lw=1.2, path_effects=_OUTLINE,
                                     label=f"fixed window ±{qw:g} rad x ±{dw:g} rad/s")
    ax.plot(0, 0, "w*", ms=12, mec="k")
    # the axes span the basin's window: a reference window taller (or wider) than it is
    # cut at the edge, not drawn over an empty band
    ax.set_xlim(extent[:2])
    ax.set_ylim(extent[2:])
    design = ("virtual constraints" if r.controller == "vc" else
              "time-varying, M1 = [" + ", ".join(f"{v:.3g}" for v in r.design["M1"])
              + f"], v_c rejoins at {r.design['rejoin']:g} T")
    # the name (which design of the study) and the design (its numbers): both, once each
    label = design if label in (None, design) else f"{label}\n{design}"
    area = getattr(r, "area", 0.0)
    capped = " (capped: boundary not all inside)" if r.status == "capped" else ""
    ax.set_title(f"{label}\n{100 * r.converged_fraction:.1f} % of the window converges in "
                 f"{r.steps} steps{capped}\narea {area:.3g} rad x rad/s; window "
                 f"±{r.q_u[-1]:.3g} rad x ±{r.dq_u[-1]:.3g} rad/s", fontsize=9)
    ax.set_xlabel(r"$\dot q_u - \dot q_u^*$ at the section [rad/s]")
    return extra


def tradeoff_plot(front, others=None, bound=None, title: str | None = None,
                  front_label: str = "best s* found at or below each max|λ| "
                                     "(search estimates)",
                  front_style: str = "step") -> Figure:
    """Robustness against stability: s* against max ``|lambda|``, named designs marked.

    The front is the best robustness s* found at each eigenvalue bound.

    Parameters
    ----------
    front : list of (max_abs, s_star)
        The Pareto front of a search (:attr:`analysis.design.robust_search.RobustDesignResult.tradeoff`).
    others : dict, optional
        Label -> (max_abs, s_star) of designs to mark (e.g. virtual constraints, the
        deadbeat designs, the robust design).
    bound : float, optional
        The eigenvalue bound of the search (a vertical line).
    title : str, optional
    front_label : str, optional
        The front's legend entry.
    front_style : str, optional
        'step' (a front: the best s* at or below each max ``|lambda|``) or 'points'
        (designs in the order given, joined by a dashed line).

    Returns
    -------
    Figure
    """
    fig = _figure(figsize=(6.4, 4.4))
    ax = fig.add_subplot()
    if front:
        f = np.array(front, float)
        if front_style == "points":
            ax.plot(f[:, 0], f[:, 1], "o--", color="0.3", lw=1, ms=5, label=front_label)
        else:
            ax.step(f[:, 0], f[:, 1], where="post", color="0.3", lw=1.2, label=front_label)
            ax.plot(f[:, 0], f[:, 1], ".", color="0.3", ms=4)
    for (label, (lam, s)), mk in zip((others or {}).items(), "o^sDvP*X"):
        ax.plot([lam], [s], mk, ms=8, label=f"{label}: s* {s:.3g}, max|λ| {lam:.2g}")
    if bound is not None:
        ax.axvline(bound, color="tab:red", ls=":", lw=1, label=f"bound max|λ| = {bound:.3g}")
    ax.axhline(1.0, color="0.5", ls="--", lw=1, label="the paper's perturbation (s = 1)")
    lams = [p[0] for p in front] + [v[0] for v in (others or {}).values()]
    if lams and min(lams) < 0.02:                        # deadbeat designs: log scale
        ax.set_xscale("symlog", linthresh=1e-3)
        ax.set_xlabel("max |λ| of $A^z$ (symmetric log scale)")
    else:
        ax.set_xlabel("max |λ| of $A^z$")
    ax.set_ylabel("s*: largest scale of the paper's perturbation survived")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    ax.set_title(title or "Robustness against the linear rate: s* vs max|λ|", fontsize=10)
    fig.tight_layout()
    return fig


def survival_plot(results, labels=None, title: str | None = None) -> Figure:
    """Survival curves of Monte Carlo runs on stochastic terrain.

    Parameters
    ----------
    results : sequence of MonteCarloResult
        From :func:`analysis.terrain.monte_carlo`.
    labels : sequence of str, optional
        One per result (default its controller and sigma).
    title : str, optional

    Returns
    -------
    Figure
        S(k), the fraction of runs that walked at least k steps, against k.
    """
    fig = _figure(figsize=(6.4, 4.2))
    ax = fig.add_subplot()
    for i, r in enumerate(results):
        S = np.asarray(r.estimate.survival, float)
        lab = labels[i] if labels is not None else (
            f"{r.spec['controller']}, sigma = {r.settings['sigma']:g} m")
        mf = r.estimate.mfpt
        lab += f" (MFPT {mf:.3g} steps)" if np.isfinite(mf) else \
            f" (MFPT > {r.estimate.mfpt_ci[0]:.3g} steps)"
        # a line style each: equal curves (every run walked) stay visible, one over another
        ax.step(np.arange(S.size), S, where="post", lw=1.4, label=lab,
                ls=("-", "--", ":", "-.")[i % 4])
    ax.set_xlabel("steps k")
    ax.set_ylabel("fraction of runs that walked at least k steps")
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="best")
    ax.set_title(title or "Survival on stochastic terrain", fontsize=10)
    fig.tight_layout()
    return fig


def mfpt_sigma_plot(curves, title: str | None = None) -> Figure:
    """The mean first-passage time against the terrain's sigma, log axis, with intervals.

    Parameters
    ----------
    curves : dict
        Label -> sequence of (sigma, mfpt, mfpt_lo, mfpt_hi), sigma in m, MFPT in steps
        (mfpt inf when no run failed: drawn at its lower bound, an open triangle).  The
        curves' points are dodged sideways by about 1 % of the sigma range.
    title : str, optional

    Returns
    -------
    Figure
    """
    fig = _figure(figsize=(6.4, 4.4))
    ax = fig.add_subplot()
    allsig = [1000 * float(row[0]) for rows in curves.values() for row in rows]
    span = (max(allsig) - min(allsig)) if len(set(allsig)) > 1 else 1.0
    n = len(curves)
    for i, ((label, rows), mk) in enumerate(zip(curves.items(), "osD^vP*X")):
        r = np.array(rows, float).reshape(-1, 4)
        # each curve dodged sideways a little, so equal values (lower bounds) stay visible
        sig = 1000 * r[:, 0] + (i - (n - 1) / 2) * 0.012 * span
        finite = np.isfinite(r[:, 1])
        y = np.where(finite, r[:, 1], r[:, 2])
        lo = np.maximum(y - r[:, 2], 0)
        hi = np.where(np.isfinite(r[:, 3]), r[:, 3] - y, 0)
        # no legend entry for a curve with nothing drawn (no run failed at any sigma)
        line = ax.errorbar(sig[finite], y[finite], yerr=[lo[finite], hi[finite]], fmt=mk + "-",
                           capsize=3, ms=5, lw=1.2,
                           label=label if finite.any() else "_nolegend_")
        if (~finite).any():
            ax.plot(sig[~finite], y[~finite], "^", ms=8, mfc="none",
                    color=line[0].get_color(), label=f"{label}: no failure (lower bound)")
    ax.set_yscale("log")
    ax.set_xlabel("sigma of the ground height per step, mm")
    ax.set_ylabel("mean first-passage time, steps (log)")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7, loc="best")
    ax.set_title(title or "MFPT against terrain roughness (95 % intervals)", fontsize=10)
    fig.tight_layout()
    return fig
