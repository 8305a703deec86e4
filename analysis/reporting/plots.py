"""Every figure of the toolkit: compute a result elsewhere, draw it here.

In the style of python-control: each ``*_plot`` function takes results computed by the
other modules and returns a :class:`matplotlib.figure.Figure`; :func:`save_figure`
writes it.  Figures are built with the object-oriented API on their own canvas: no
pyplot state is touched and the user's backend is never changed (in a notebook, a
returned figure displays itself).
"""
from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np
from matplotlib.animation import FuncAnimation, PillowWriter
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.colors import ListedColormap
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.patches import Patch

from biped_casadi.files import atomic_path

__all__ = ["COLOUR_NAMES", "STANCE", "SWING", "TORSO", "save_figure", "save_figures",
           "gait_stick_plot", "gait_profiles_plot", "one_d_sweeps_plot",
           "conjecture_plot", "stable_domains_plot", "m1_plane_plot", "unactuated_error_plot",
           "swing_torques_plot", "walking_animation", "run_label", "basin_plot",
           "tradeoff_plot", "OUTCOME_COLOURS", "survival_plot", "mfpt_sigma_plot"]

#: colours of the stance leg, the swing leg and the torso in every stick figure
STANCE, SWING, TORSO = "tab:blue", "tab:red", "0.25"
#: how captions name them (one place, so a caption never names a colour not drawn)
COLOUR_NAMES = {STANCE: "blue", SWING: "red", TORSO: "dark grey"}


def _figure(**kw) -> Figure:
    fig = Figure(**kw)
    FigureCanvasAgg(fig)
    return fig


def save_figure(fig: Figure, path, formats=("png",), dpi: int = 150) -> list[str]:
    """Write ``fig`` to ``path`` with each suffix of ``formats``.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
    path : str or Path
        File name; its suffix (if .png or .pdf) is replaced by each format.
    formats : sequence of str
        'png', 'pdf', ...
    dpi : int

    Returns
    -------
    list of str
        The files written.  Each is written through a temporary file: a failure leaves
        no partial figure and does not damage an earlier one.
    """
    base = Path(path)
    if base.suffix.lower() in (".png", ".pdf", ".svg"):
        base = base.with_suffix("")
    out = []
    for ext in formats:
        p = base.with_name(f"{base.name}.{ext}")
        with atomic_path(p) as tmp:
            fig.savefig(tmp, dpi=dpi, bbox_inches="tight", format=ext)
        out.append(str(p))
    return out


def save_figures(figures: dict, folder, formats=("png",), dpi: int = 150) -> list[str]:
    """Write several figures into ``folder`` (created if needed), all or none.

    Parameters
    ----------
    figures : dict
        File name (without suffix) -> Figure.
    folder : str or Path
    formats, dpi
        As :func:`save_figure`.

    Returns
    -------
    list of str
        The files written.  When one fails, those already written by this call are
        removed (and the folder too, if this call created it) before the error propagates.
    """
    folder = Path(folder)
    created = not folder.exists()
    folder.mkdir(parents=True, exist_ok=True)
    written: list[str] = []
    try:
        for name, fig in figures.items():
            written += save_figure(fig, folder / name, formats, dpi)
    except BaseException:
        for f in written:
            Path(f).unlink(missing_ok=True)
        if created:
            with contextlib.suppress(OSError):
                folder.rmdir()
        raise
    return written


# ------------------------------------------------------------------ the gait
def _stick(ax, model, P, alpha=1.0, lw=2.0):
    """One stick figure from the model's points (``model.points``: stance foot, stance
    joints, hip, torso top, swing joints, swing foot), drawn along its chains."""
    st, to, sw = (list(c) for c in (model.stance_chain, model.torso_chain, model.swing_chain))
    ax.plot(P[0, st], P[1, st], "-", color=STANCE, lw=lw, alpha=alpha)
    ax.plot(P[0, to], P[1, to], "-", color=TORSO, lw=lw + 1, alpha=alpha)
    ax.plot(P[0, sw], P[1, sw], "-", color=SWING, lw=lw, alpha=alpha)


def _legs_legend(ax, extra=()):
    handles = [Line2D([], [], color=STANCE, lw=2, label="stance leg"),
               Line2D([], [], color=SWING, lw=2, label="swing leg"),
               Line2D([], [], color=TORSO, lw=3, label="torso"), *extra]
    ax.legend(handles=handles, loc="upper left", fontsize=8)


def gait_stick_plot(gait, frames: int = 9) -> Figure:
    """Stick diagram of one reference step over the ground, with the swing foot's path.

    Earlier poses are drawn fainter.

    Parameters
    ----------
    gait : Reference
    frames : int
        Poses drawn, evenly spaced in time from 0 to T.

    Returns
    -------
    Figure
    """
    T = gait.T
    model = gait.model
    fig = _figure(figsize=(8, 4.5))
    ax = fig.add_subplot()
    for k, tk in enumerate(np.linspace(0.0, T, frames)):
        _stick(ax, model, np.array(model.points(gait.q(tk))),
               alpha=0.25 + 0.75 * k / (frames - 1))
    t = np.linspace(0.0, T, 400)
    feet = np.array(model.swing_foot.map(t.size)(gait.q(t))).reshape(2, -1)
    path, = ax.plot(feet[0], feet[1], ":", color=SWING, lw=1, label="swing-foot path")
    xs = [min(-0.4, feet[0].min() - 0.1), max(0.8, feet[0].max() + 0.1)]
    ax.fill_between(xs, [-0.05, -0.05], [0, 0], color="0.85")
    ax.axhline(0.0, color="k", lw=1)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("z [m]")
    ax.set_title(f"{model.params.name}, reference step: T = {T:.3f} s, step length "
                 f"{gait.step_length:.3f} m, {gait.speed:.2f} m/s ({frames} poses, later "
                 f"ones darker)", fontsize=10)
    _legs_legend(ax, [path])
    return fig


def gait_profiles_plot(gait) -> Figure:
    """Reference joint angles q^d(t) and torques u^d(t) over one step.

    Parameters
    ----------
    gait : Reference

    Returns
    -------
    Figure
    """
    t = np.linspace(0.0, gait.T, 400)
    q, u = gait.q(t), gait.u(t)
    names = getattr(gait.model, "joint_names", None) or [""] * q.shape[0]
    fig = _figure(figsize=(8, 6))
    a1, a2 = fig.subplots(2, 1, sharex=True)
    for i in range(q.shape[0]):
        a1.plot(t, q[i], label=f"q{i + 1}: {names[i]}")
    a1.set_ylabel(r"$q^d(t)$ [rad]")
    a1.legend(ncol=min(q.shape[0], 3), fontsize=7)
    for i in range(u.shape[0]):
        a2.plot(t, u[i], label=f"u{i + 1} (on q{i + 2})")
    a2.set_ylabel(r"$u^d(t)$ [N m]")
    a2.set_xlabel("t [s]")
    a2.legend(ncol=min(u.shape[0], 4), fontsize=8)
    a1.set_title("Reference joint angles and torques over one step")
    fig.tight_layout()
    return fig


# ------------------------------------------------------------ sweeps (Fig. 2-4)
def one_d_sweeps_plot(lines) -> Figure:
    """Paper Fig. 2: max|lambda| against each component M1(j), the others zero.

    Parameters
    ----------
    lines : OneDSweeps
        From :func:`analysis.sweeps.sweep.one_d_sweeps`: one sweep per component and the
        singular values of eq. (24), drawn as dashed lines where inside the range.

    Returns
    -------
    Figure
    """
    results, sv = lines.results, np.asarray(lines.singular_values, float).ravel()
    n = len(results)
    cols = 2 if n > 1 else 1
    rows = (n + cols - 1) // cols
    fig = _figure(figsize=(4.5 * cols, 3.25 * rows), constrained_layout=True)
    axes = np.atleast_1d(fig.subplots(rows, cols)).ravel()
    for j, (ax, r) in enumerate(zip(axes, results)):
        x = r.points[:, j]
        fin = np.isfinite(r.max_abs)
        st = r.point_status == "stable"
        ax.semilogy(x[fin & ~st], r.max_abs[fin & ~st], ".", ms=3, color="0.25",
                    label="unstable")
        ax.semilogy(x[st], r.max_abs[st], ".", ms=5, color="red", label="stable, max|λ| < 1")
        sing = r.point_status == "singular"
        if sing.any():
            ax.plot(x[sing], np.full(sing.sum(), 1.0), "|", color="tab:blue", ms=6,
                    transform=ax.get_xaxis_transform(), clip_on=False,
                    label="singular controller")
        ax.axhline(1.0, color="0.5", lw=0.8, ls=":")
        if x.min() <= sv[j] <= x.max():
            ax.axvline(sv[j], color="tab:blue", lw=1, ls="--", label=f"eq. (24): {sv[j]:.4g}")
        ax.set_xlabel(f"$M_1({j + 1})$")
        ax.set_ylabel(r"max $|\lambda_{1,2}|$")
        ax.legend(fontsize=7, loc="best")
        ax.grid(True, which="major", alpha=0.3)
    for ax in axes[n:]:
        ax.set_visible(False)
    fig.suptitle("Fig. 2: max|λ| of $A^z$ against one component of $M_1$, the others zero")
    return fig


def conjecture_plot(zsw, max_abs, status, limit: float = 50.0) -> Figure:
    """Paper Fig. 3: Z_sw(T^d) against max ``|lambda|``, stable cases in red.

    Only cases with max ``|lambda|`` < ``limit`` are drawn.

    Parameters
    ----------
    zsw, max_abs, status : array_like
        Per M1: the swing height of eq. (26), max|lambda|, the status.
    limit : float

    Returns
    -------
    Figure
    """
    zsw, max_abs, status = (np.asarray(a) for a in (zsw, max_abs, status))
    sel = np.isfinite(max_abs) & (max_abs < limit)
    st = sel & (status == "stable")
    un = sel & (status != "stable")
    fig = _figure(figsize=(6, 4))
    ax = fig.add_subplot()
    ax.scatter(max_abs[un], zsw[un], s=4, c="0.5", label=f"unstable ({un.sum()})")
    ax.scatter(max_abs[st], zsw[st], s=10, c="red", label=f"stable ({st.sum()})")
    ax.axvline(1.0, color="k", lw=0.8, ls="--")
    ax.set_xlabel(r"max $|\lambda_{1,2}|$")
    ax.set_ylabel(r"$Z_{sw}(T^d)$ [m]  ($\Delta q_u = 10^{-2}$ rad)")
    ax.set_title(r"Fig. 3: swing-foot height at $T^d$ vs. max $|\lambda|$ (the M1 grid)")
    ax.legend(loc="best", fontsize=8)
    return fig


def stable_domains_plot(m2, m3, max_abs_1, max_abs_2, best=None) -> Figure:
    """Paper Fig. 4: stable domains of (M1(2), M1(3)) for both a = b = 0 groups.

    The contour max ``|lambda|`` = 1 is drawn over a log colour scale of max
    ``|lambda|``.

    Parameters
    ----------
    m2, m3 : array_like
        The grid (meshgrid, 'ij').
    max_abs_1, max_abs_2 : array_like
        max|lambda| of each group on the grid (NaN where the roots are complex).
    best : dict, optional
        Group -> best M1, marked with a star.

    Returns
    -------
    Figure
    """
    fig = _figure(figsize=(11, 4.6))
    axes = fig.subplots(1, 2, sharey=True)
    im = None
    for k, (ax, mx) in enumerate(zip(axes, (max_abs_1, max_abs_2)), start=1):
        mx = np.asarray(mx, float)
        filled = np.where(np.isfinite(mx), mx, 1e3)
        z = np.log10(np.clip(filled, 1e-4, 1e3))
        im = ax.pcolormesh(m2, m3, z, shading="auto", cmap="viridis", vmin=-3, vmax=3)
        if np.nanmin(mx) < 1 < np.nanmax(filled):
            ax.contour(m2, m3, filled, levels=[1.0], colors="red", linewidths=1.5)
        if best is not None and best.get(k) is not None:
            b = best[k]
            ax.plot(b[1], b[2], "w*", ms=12, mec="k", label="best point")
            ax.legend(loc="lower right", fontsize=8)
        ax.set_title(f"group {k}: contour max|λ| = 1 (red)")
        ax.set_xlabel("M1(2)")
    axes[0].set_ylabel("M1(3)")
    fig.colorbar(im, ax=list(axes), label="log10 max|λ|")
    fig.suptitle("Fig. 4: stable domains of the a = b = 0 groups")
    return fig


def m1_plane_plot(m1, m2, max_abs, ab_points=(), ab_line=None, best=None,
                  title: str | None = None) -> Figure:
    """The stable domain in the (M1(1), M1(2)) plane of a robot with two torques.

    For the three-link biped: max ``|lambda|`` on a grid with the contour
    max ``|lambda|`` = 1, the solutions of a = b = 0 and the best point.

    Parameters
    ----------
    m1, m2 : array_like
        The grid (meshgrid, 'ij').
    max_abs : array_like
        max|lambda| on the grid (inf or NaN where singular or without impact).
    ab_points : array_like, optional
        (k, 2) isolated solutions of a = b = 0, marked with diamonds.
    ab_line : array_like, optional
        (k, 2) points of a line of solutions of a = b = 0, drawn dashed.
    best : array_like, optional
        An M1 to mark with a star (e.g. the M1 NLP's).
    title : str, optional

    Returns
    -------
    Figure
    """
    mx = np.asarray(max_abs, float)
    filled = np.where(np.isfinite(mx), mx, 1e3)
    fig = _figure(figsize=(6.4, 5.2))
    ax = fig.add_subplot()
    im = ax.pcolormesh(m1, m2, np.log10(np.clip(filled, 1e-4, 1e3)), shading="auto",
                       cmap="viridis", vmin=-3, vmax=3)
    if np.nanmin(filled) < 1 < np.nanmax(filled):
        ax.contour(m1, m2, filled, levels=[1.0], colors="red", linewidths=1.5)
    if ab_line is not None and len(ab_line):
        L = np.asarray(ab_line, float)
        ax.plot(L[:, 0], L[:, 1], "--", color="orange", lw=2, label="a = b = 0")
    pts = np.asarray(ab_points, float).reshape(-1, 2)
    for k, p in enumerate(pts, start=1):
        ax.plot(p[0], p[1], "D", color="orange", mec="k", ms=8,
                label="a = b = 0" if k == 1 else None)
    if best is not None:
        ax.plot(best[0], best[1], "w*", ms=13, mec="k", label="best point of the map")
    if len(pts) or best is not None or ab_line is not None:
        ax.legend(loc="lower right", fontsize=8)
    ax.set_xlim(np.min(m1), np.max(m1))
    ax.set_ylim(np.min(m2), np.max(m2))
    ax.set_xlabel("M1(1)")
    ax.set_ylabel("M1(2)")
    fig.colorbar(im, ax=ax, label="log10 max|λ|")
    ax.set_title(title or "Stable domain of M1: contour max|λ| = 1 (red)")
    return fig


# ------------------------------------------------------- walking (Fig. 5, 6)
def run_label(res) -> str:
    """A legend label for a simulation result.

    Parameters
    ----------
    res : SimulationResult
        A closed-loop run.

    Returns
    -------
    str
        The controller (and M1 for the time-varying one).
    """
    c = res.controller
    if c.get("controller") == "tv":
        return "time-varying, M1 = [" + ", ".join(f"{v:.4g}" for v in c["M1"]) + "]"
    return "virtual constraints"


def unactuated_error_plot(results, title: str | None = None, labels=None) -> Figure:
    """Paper Fig. 5: q_u - q_u^d(T) and dq_u - dq_u^d(T) just before each impact.

    Parameters
    ----------
    results : SimulationResult or list of them
    title : str, optional
    labels : list of str, optional
        Legend labels of the runs (default: the controller and its M1).

    Returns
    -------
    Figure
    """
    results = results if isinstance(results, (list, tuple)) else [results]
    fig = _figure(figsize=(6.4, 5.6))
    ax = fig.subplots(2, 1, sharex=True)
    labels = labels or [run_label(r) for r in results]
    for res, mk, name in zip(results, "os^dv", labels):
        k = np.arange(1, len(res.steps) + 1)
        lab = name + ("" if res.ok else f" ({res.status} at t = {res.failure_time:.3f} s)")
        ax[0].plot(k, res.qu_error[:k.size], mk + "-", label=lab)
        ax[1].plot(k, res.dqu_error[:k.size], mk + "-", label=lab)
    ax[0].set_ylabel(r"$q_u - q_u^d(T)$ [rad]")
    ax[1].set_ylabel(r"$\dot q_u - \dot q_u^d(T)$ [rad/s]")
    ax[1].set_xlabel("step (error just before its impact)")
    for a in ax:
        a.axhline(0, color="0.6", lw=0.8)
        a.grid(alpha=0.3)
    ax[0].legend(fontsize=8)
    fig.suptitle(title or "Fig. 5: error of the unactuated variable at the end of each step")
    fig.tight_layout()
    return fig


def swing_torques_plot(results, gait, title: str | None = None, labels=None) -> Figure:
    """Paper Fig. 6: the swing leg's torques against time, the reference torques dashed.

    RABBIT: u3 (swing hip) and u4 (swing knee); the three-link biped: u2 (swing hip).
    The reference torques u^d(tau) are restarted at every step.

    Parameters
    ----------
    results : SimulationResult or list of them
        Runs on ``gait`` (its reference torques are drawn for the first run's steps).
    gait : Reference
    title : str, optional
    labels : list of str, optional
        Legend labels of the runs.

    Returns
    -------
    Figure
    """
    results = results if isinstance(results, (list, tuple)) else [results]
    model = gait.model
    joints = tuple(range(model.k, model.nu))       # the swing leg's hip and knees
    fig = _figure(figsize=(7.2, 2.0 + 1.8 * len(joints)))
    ax = np.atleast_1d(fig.subplots(len(joints), 1, sharex=True))
    labels = labels or [run_label(r) for r in results]
    for res, name in zip(results, labels):
        for i, j in enumerate(joints):
            ax[i].plot(res.t, res.u[:, j], lw=1.0, label=name)
    res = results[0]
    for k in np.unique(res.step):
        sel = res.step == k
        tau = np.clip(res.tau[sel], 0, gait.t_max)
        ud = gait.u(tau)
        for i, j in enumerate(joints):
            ax[i].plot(res.t[sel], ud[j], "k--", lw=0.8,
                       label=(f"reference $u^d$ on the steps of {labels[0]}"
                              if len(results) > 1 else "reference $u^d$") if k == 0 else None)
    for i, j in enumerate(joints):
        ax[i].set_ylabel(f"u{j + 1}, {model.joint_names[j + 1]} [N m]")
    ax[-1].set_xlabel("t [s]")
    for a in ax:
        a.grid(alpha=0.3)
    ax[0].legend(fontsize=8)
    fig.suptitle(title or "Fig. 6: torques of the swing leg")
    fig.tight_layout()
    return fig


def walking_animation(res, model, path, fps: int = 25, max_steps: int | None = None) -> str:
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
    text = ax.text(0.01, 0.95, "", transform=ax.transAxes, va="top", fontsize=9)
    ax.set_title(f"{run_label(res)}: {res.status}", fontsize=10)
    ax.set_xlabel("x [m]")
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

    anim = FuncAnimation(fig, draw, frames=len(frames), blit=True)
    with atomic_path(path) as tmp:
        anim.save(str(tmp), writer=PillowWriter(fps=fps))
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
}


def basin_plot(results, title: str | None = None) -> Figure:
    """Basins of attraction on the section of the zero dynamics, side by side.

    Parameters
    ----------
    results : BasinResult or list of them
        From :func:`analysis.robustness.s_star.basin` (e.g. a time-varying design and virtual
        constraints on the same gait and grid).
    title : str, optional

    Returns
    -------
    Figure
        One panel per result: every cell coloured by its outcome after the result's
        number of steps (converged, walked, or the first failure's cause); the fixed point
        marked.
    """
    results = results if isinstance(results, (list, tuple)) else [results]
    names = list(OUTCOME_COLOURS)
    cmap = ListedColormap([OUTCOME_COLOURS[k][0] for k in names])
    fig = _figure(figsize=(5.2 * len(results) + 2.2, 4.8))
    axes = np.atleast_1d(fig.subplots(1, len(results), sharey=True))
    present = set()
    for ax, r in zip(axes, results):
        codes = np.vectorize(lambda o: names.index(o) if o in names else names.index("diverged"))(
            r.outcome.astype(str))
        present |= set(np.unique(r.outcome.astype(str)))
        da, db = np.diff(r.q_u[:2])[0] / 2, np.diff(r.dq_u[:2])[0] / 2
        ax.imshow(codes, origin="lower", aspect="auto", cmap=cmap, vmin=-0.5,
                  vmax=len(names) - 0.5, interpolation="nearest",
                  extent=[r.dq_u[0] - db, r.dq_u[-1] + db, r.q_u[0] - da, r.q_u[-1] + da])
        ax.plot(0, 0, "w*", ms=12, mec="k")
        label = ("virtual constraints" if r.controller == "vc" else
                 "time-varying, M1 = [" + ", ".join(f"{v:.3g}" for v in r.design["M1"])
                 + f"], v_c rejoins at {r.design['rejoin']:g} T")
        ax.set_title(f"{label}\n{100 * r.converged_fraction:.1f} % of cells converge in "
                     f"{r.steps} steps", fontsize=9)
        ax.set_xlabel(r"$\dot q_u - \dot q_u^*$ at the section [rad/s]")
    axes[0].set_ylabel(r"$q_u - q_u^*$ at the section [rad]")
    handles = [Patch(color=OUTCOME_COLOURS[k][0], label=OUTCOME_COLOURS[k][1])
               for k in names if k in present]
    handles.append(Line2D([], [], marker="*", color="w", mec="k", ms=10, ls="",
                          label="fixed point x*"))
    fig.legend(handles=handles, loc="center right", fontsize=8, frameon=False)
    fig.suptitle(title or "Basins of attraction on the Poincaré section (tau = 0.75 T)")
    fig.tight_layout(rect=(0, 0, 1 - 2.0 / (5.2 * len(results) + 2.2), 1))
    return fig


def tradeoff_plot(front, others=None, bound=None, title: str | None = None) -> Figure:
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

    Returns
    -------
    Figure
    """
    fig = _figure(figsize=(6.4, 4.4))
    ax = fig.add_subplot()
    if front:
        f = np.array(front, float)
        ax.step(f[:, 0], f[:, 1], where="post", color="0.3", lw=1.2,
                label="best s* found at or below each max|λ| (search estimates)")
        ax.plot(f[:, 0], f[:, 1], ".", color="0.3", ms=4)
    for (label, (lam, s)), mk in zip((others or {}).items(), "o^sDvP*X"):
        ax.plot([lam], [s], mk, ms=8, label=f"{label}: s* {s:.3g}, max|λ| {lam:.2g}")
    if bound is not None:
        ax.axvline(bound, color="tab:red", ls=":", lw=1, label=f"bound max|λ| = {bound:.3g}")
    ax.axhline(1.0, color="tab:green", ls="--", lw=1, label="the paper's perturbation (s = 1)")
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
        lab += f" (MFPT {mf:.3g})" if np.isfinite(mf) else \
            f" (MFPT > {r.estimate.mfpt_ci[0]:.3g})"
        ax.step(np.arange(S.size), S, where="post", lw=1.4, label=lab)
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
        (mfpt inf when no run failed: drawn at its lower bound with an arrow).
    title : str, optional

    Returns
    -------
    Figure
    """
    fig = _figure(figsize=(6.4, 4.4))
    ax = fig.add_subplot()
    for (label, rows), mk in zip(curves.items(), "osD^vP*X"):
        r = np.array(rows, float).reshape(-1, 4)
        sig = 1000 * r[:, 0]
        finite = np.isfinite(r[:, 1])
        y = np.where(finite, r[:, 1], r[:, 2])
        lo = np.maximum(y - r[:, 2], 0)
        hi = np.where(np.isfinite(r[:, 3]), r[:, 3] - y, 0)
        line = ax.errorbar(sig[finite], y[finite], yerr=[lo[finite], hi[finite]], fmt=mk + "-",
                           capsize=3, ms=5, lw=1.2, label=label)
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
