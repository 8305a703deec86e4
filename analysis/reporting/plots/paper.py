"""The paper's figures: the reference gait, the sweeps of M1 (Fig. 2-4, the plane of a
robot with two torques) and the closed-loop walking of Fig. 5 and 6."""
from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from biped_casadi.control import require_reference
from biped_casadi.numerics import as_count

from .common import SWING, _figure, _legend_below, _legs_legend, _stick, run_label

__all__ = ["gait_stick_plot", "gait_profiles_plot", "one_d_sweeps_plot", "conjecture_plot",
           "stable_domains_plot", "m1_plane_plot", "unactuated_error_plot",
           "swing_torques_plot"]


# ------------------------------------------------------------------ the gait
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
    T, model = require_reference(gait).T, gait.model
    frames = as_count(frames, "frames", low=2)
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
    _legs_legend(ax, [path], outside=True)      # the first poses reach the upper left
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
    a1.set_title(f"{gait.model.params.name}: reference joint angles and torques over one "
                 f"step (T = {gait.T:.3f} s, {gait.speed:.2f} m/s)")
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
                    label="unstable" + ("" if (fin & ~st).any() else " (none)"))
        ax.semilogy(x[st], r.max_abs[st], ".", ms=5, color="red",
                    label="stable, max|λ| < 1" + ("" if st.any() else " (none)"))
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
    beyond = int(np.count_nonzero(np.isfinite(max_abs) & (max_abs >= limit)))
    none = int(np.count_nonzero(~np.isfinite(max_abs)))
    ax.set_xlabel(r"max $|\lambda_{1,2}|$" + (f"  (not drawn: {beyond} at {limit:g} or more, "
                                               f"{none} without a value)"
                                               if beyond or none else ""))
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
            ax.plot(b[1], b[2], "w*", ms=12, mec="k", label="best point of the group")
        ax.set_title(f"group {k}: contour max|λ| = 1 (red)")
        ax.set_xlabel("$M_1(2)$ (dimensionless)")
    axes[0].set_ylabel("$M_1(3)$ (dimensionless)")
    fig.colorbar(im, ax=list(axes), label="log10 max|λ|")
    fig.suptitle("Fig. 4: stable domains of the a = b = 0 groups")
    _legend_below(fig, list(axes))           # inside, it sat on a group's contour
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
    ax.set_xlabel("$M_1(1)$ (dimensionless)")
    ax.set_ylabel("$M_1(2)$ (dimensionless)")
    fig.colorbar(im, ax=ax, label="log10 max|λ|")
    ax.set_title(title or "Stable domain of M1: contour max|λ| = 1 (red)")
    return fig


# ------------------------------------------------------- walking (Fig. 5, 6)
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
    ax[1].xaxis.set_major_locator(MaxNLocator(integer=True))         # whole steps
    for a in ax:
        a.axhline(0, color="0.6", lw=0.8)
        a.grid(alpha=0.3)
    if not any(len(res.steps) for res in results):        # nothing to draw: step 1 shown
        ax[1].set_xlim(0.5, 1.5)
        ax[1].set_xticks([1])
        ax[0].text(0.5, 0.5, "no run reached an impact", transform=ax[0].transAxes,
                   ha="center", va="center", color="0.3")
    fig.suptitle(title or "Fig. 5: error of the unactuated variable at the end of each step")
    fig.tight_layout()
    if len(results) > 1:                 # several runs: under the panels, off the curves
        _legend_below(fig, ax[0])
    else:
        ax[0].legend(fontsize=8)
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
        one = np.size(res.t) < 2                    # stopped at its start: a marker
        for i, j in enumerate(joints):
            ax[i].plot(res.t, res.u[:, j], "o" if one else "-", lw=1.0, label=name)
    if all(np.size(r.t) == 0 or np.ptp(r.t) == 0 for r in results):
        ax[0].set_xlim(-0.05 * gait.T, gait.T)
        ax[0].text(0.5, 0.5, "every run stopped at t = 0", transform=ax[0].transAxes,
                   ha="center", va="center", color="0.3")
    res = results[0]
    ref_label = (f"reference $u^d$ on the steps of {labels[0]}" if len(results) > 1
                 else "reference $u^d$")
    for k in np.unique(res.step):
        sel = res.step == k
        if np.count_nonzero(sel) < 2:               # one sample: no dashed line to draw
            continue
        tau = np.clip(res.tau[sel], 0, gait.t_max)
        ud = gait.u(tau)
        for i, j in enumerate(joints):
            ax[i].plot(res.t[sel], ud[j], "k--", lw=0.8, label=ref_label)
        ref_label = None                            # listed once, with the first drawn
    for i, j in enumerate(joints):
        ax[i].set_ylabel(f"u{j + 1}, {model.joint_names[j + 1]} [N m]")
    ax[-1].set_xlabel("t [s]")
    for a in ax:
        a.grid(alpha=0.3)
    fig.suptitle(title or f"Fig. 6: torques of the swing leg ({model.params.name})")
    fig.tight_layout()
    if len(results) > 1:                 # several runs: under the panels, off the curves
        _legend_below(fig, ax[0])
    else:
        ax[0].legend(fontsize=8)
    return fig
