"""Walks in MuJoCo: speed and error per step, the animation of a walk, and MuJoCo's
eigenvalues beside the exact ones."""
from __future__ import annotations

import numpy as np
from PIL import Image
from matplotlib.figure import Figure
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator

from biped_casadi.files import atomic_path

from .common import STANCE, SWING, TORSO, _figure, _legend_below

__all__ = ["mujoco_steps_plot", "mujoco_animation", "mujoco_eigen_plot"]

_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:purple", "tab:brown", "tab:cyan")


#: how the legend names a law
_LAW_NAMES = {"c": "C", "python": "Python"}


def _series(w, key):
    """Per-step values of a walk (a MujocoWalk or its summary dict)."""
    if isinstance(w, dict):
        return np.asarray(w[key], float)
    return np.array([getattr(s, {"speeds": "speed", "qu_errors": "qu_error",
                                 "dqu_errors": "dqu_error", "periods": "period"}[key])
                     for s in w.steps], float)


def _gait(w):
    return w["gait"] if isinstance(w, dict) else w.gait


def mujoco_steps_plot(walks, labels=None, title: str | None = None) -> Figure:
    """Speed, step duration and pre-impact error of MuJoCo walks, step by step.

    Parameters
    ----------
    walks : sequence of MujocoWalk (or their ``to_dict()`` with per-step lists)
        The walks.
    labels : sequence of str, optional
        One per walk (default the law and contact).
    title : str, optional
        The figure's title.

    Returns
    -------
    matplotlib.figure.Figure
    """
    walks = list(walks)
    if not walks:
        raise ValueError("walks: nothing to draw")
    labels = list(labels) if labels is not None else [
        f"{_LAW_NAMES.get(_get(w, 'law'), _get(w, 'law'))} law, "
        f"{_get(w, 'settings')['contact']} contact" for w in walks]
    fig = _figure(figsize=(7.5, 7.0))
    ax = fig.subplots(4, 1, sharex=True)
    for i, (w, lab) in enumerate(zip(walks, labels)):
        c = _COLOURS[i % len(_COLOURS)]
        g = _gait(w)
        n = np.arange(1, _series(w, "speeds").size + 1)
        ax[0].plot(n, _series(w, "speeds"), ".-", color=c, ms=3, lw=1,
                   label=f"{lab}: {_get(w, 'status')}")
        ax[1].plot(n, _series(w, "periods"), ".-", color=c, ms=3, lw=1)
        ax[2].plot(n, _series(w, "qu_errors"), ".-", color=c, ms=3, lw=1)
        ax[3].plot(n, _series(w, "dqu_errors"), ".-", color=c, ms=3, lw=1)
        if i == 0:
            ax[0].axhline(g["speed"], color="k", ls="--", lw=1, label="the gait's speed")
            ax[1].axhline(g["T"], color="k", ls="--", lw=1, label="the gait's T")
    for a in ax[2:]:
        a.axhline(0.0, color="k", ls="--", lw=1)
    ax[0].set_ylabel("speed [m/s]")
    ax[1].set_ylabel("step duration [s]")
    ax[2].set_ylabel(r"$q_u - q_u^d(T)$ [rad]")
    ax[3].set_ylabel(r"$\dot q_u - \dot q_u^d(T)$ [rad/s]")
    ax[3].set_xlabel("step")
    ax[3].xaxis.set_major_locator(MaxNLocator(integer=True, steps=[1, 2, 5, 10]))  # whole steps
    if max(_series(w, "speeds").size for w in walks) == 0:      # ended in its first step
        ax[3].set_xlim(0.5, 1.5)
        ax[3].set_xticks([1])
        ax[0].text(0.5, 0.2, "no step completed", transform=ax[0].transAxes, ha="center",
                   va="center", fontsize=10, bbox=dict(fc="white", ec="0.6"))
    for a in ax:
        a.grid(alpha=0.3)
    fig.suptitle(title or "In MuJoCo: speed, step duration and error at each touchdown",
                 fontsize=11)
    fig.tight_layout()
    _legend_below(fig, [ax[0], ax[1]], ncol=2)     # the walks fill their panels
    return fig


def _get(w, key):
    return w[key] if isinstance(w, dict) else getattr(w, key)


def mujoco_animation(walk, layout, path, fps: int = 25, max_steps: int | None = None) -> str:
    """Stick-figure animation of a MuJoCo walk (GIF, Pillow), in real time.

    Parameters
    ----------
    walk : MujocoWalk
        A walk run with ``log=True``.
    layout : Layout
        The robot's MuJoCo coordinates (:func:`biped_casadi.mujoco.layout`).
    path : str or Path
        The .gif to write.
    fps : int
        Frames per second.
    max_steps : int, optional
        Animate only the first steps (the title says so): the axes span the steps shown,
        and a long walk's would leave the robot a dot.

    Returns
    -------
    str
        ``path`` (written through a temporary file: complete or absent).
    """
    if isinstance(fps, bool) or not isinstance(fps, int) or fps < 1:
        raise ValueError(f"fps must be a positive integer, got {fps!r}")
    if walk.t.size == 0:
        raise ValueError("walk: the walk has no logged states (run it with log=True)")
    t, qpos, stance = walk.t, walk.qpos, walk.stance
    shown = walk.steps
    if max_steps is not None and len(walk.steps) > max_steps:
        keep = t <= walk.steps[max_steps - 1].t_touchdown
        t, qpos, stance = t[keep], qpos[keep], stance[keep]
        shown = walk.steps[:max_steps]
    frames = np.unique(np.clip(np.searchsorted(t, np.arange(t[0], t[-1] + 1e-12, 1.0 / fps)),
                               0, t.size - 1))
    P = layout.points(qpos)                         # (N, 2k + 3, 2)
    k = layout.k
    legs = (list(range(1, k + 2)), list(range(k + 2, 2 * k + 3)))
    fig = _figure(figsize=(7.5, 3.6))
    ax = fig.add_subplot()
    x_lo, x_hi = P[..., 0].min() - 0.3, P[..., 0].max() + 0.3
    ax.set_xlim(x_lo, x_hi)
    ax.set_ylim(-0.08, P[..., 1].max() + 0.1)
    ax.set_aspect("equal")
    ax.axhline(0, color="0.3", lw=1.5)
    ax.fill_between([x_lo, x_hi], -0.08, 0, color="0.85")
    prints = [s.step_length for s in shown]
    xs = np.r_[P[0, legs[0][-1], 0], P[0, legs[0][-1], 0] + np.cumsum(prints)]
    foot, = ax.plot(xs, np.zeros_like(xs), "k^", ms=6, label="touchdowns")
    st, = ax.plot([], [], "-o", color=STANCE, lw=3, ms=4)
    sw, = ax.plot([], [], "-o", color=SWING, lw=3, ms=4)
    to, = ax.plot([], [], "-", color=TORSO, lw=4)
    text = ax.text(0.99, 0.95, "", transform=ax.transAxes, va="top", ha="right", fontsize=9)
    s = walk.settings
    ax.set_title(f"In MuJoCo ({s['contact']} contact, dt {1e3 * s['timestep']:g} ms): "
                 f"{walk.status}, {walk.steps_walked} steps"
                 + (f" (the first {len(shown)} shown)" if len(shown) < len(walk.steps) else ""),
                 fontsize=10)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("z [m]")
    ax.legend(handles=[Line2D([], [], color=STANCE, lw=3, label="stance leg"),
                       Line2D([], [], color=SWING, lw=3, label="swing leg"),
                       Line2D([], [], color=TORSO, lw=4, label="torso"), foot],
              fontsize=8, loc="upper center", bbox_to_anchor=(0.5, -0.22), ncols=4)
    moving = (st, sw, to, text)
    for a in moving:
        a.set_animated(True)
    canvas = fig.canvas
    fig.tight_layout()
    canvas.draw()
    still = canvas.copy_from_bbox(fig.bbox)
    images = []
    for i in frames:
        X, Z = P[i, :, 0], P[i, :, 1]
        s_leg = legs[int(stance[i])]
        w_leg = legs[1 - int(stance[i])]
        st.set_data(X[s_leg], Z[s_leg])
        sw.set_data(X[w_leg], Z[w_leg])
        to.set_data(X[[0, 1]], Z[[0, 1]])
        text.set_text(f"t = {t[i]:.2f} s")
        canvas.restore_region(still)
        for a in moving:
            ax.draw_artist(a)
        images.append(Image.fromarray(np.array(canvas.buffer_rgba()), "RGBA"))
    with atomic_path(path) as tmp:
        images[0].save(tmp, format="GIF", save_all=True, append_images=images[1:],
                       duration=int(1000 / fps), loop=0)
    return str(path)


def mujoco_eigen_plot(rows) -> Figure:
    """MuJoCo's stride-map eigenvalues beside the exact ones, and the errors per step.

    Parameters
    ----------
    rows : sequence of dict
        One per design and contact: ``label``, ``contact`` ('stiff' or 'default'),
        ``eigenvalues`` (MuJoCo's, [re, im] pairs or complex), ``exact`` (the toolkit's),
        ``dqu_errors`` (per step of the walk from the gait, rad/s).

    Returns
    -------
    matplotlib.figure.Figure
    """
    rows = list(rows)
    if not rows:
        raise ValueError("rows: nothing to draw")
    fig = _figure(figsize=(11, 4.4))
    ax, bx = fig.subplots(1, 2, gridspec_kw=dict(width_ratios=(1, 1.5)))
    th = np.linspace(0, 2 * np.pi, 200)
    ax.plot(np.cos(th), np.sin(th), color="0.6", lw=1)
    names = list(dict.fromkeys(r["label"] for r in rows))
    colour = {n: _COLOURS[i % len(_COLOURS)] for i, n in enumerate(names)}
    done = set()
    for r in rows:
        c = colour[r["label"]]
        ev = np.array([complex(*e) if isinstance(e, (list, tuple)) else complex(e)
                       for e in r["eigenvalues"]])
        mk = "o" if r["contact"] == "stiff" else "s"
        ax.plot(ev.real, ev.imag, mk, color=c, ms=7, mfc="none" if mk == "s" else c)
        if r["label"] not in done:
            ex = np.array([complex(*e) if isinstance(e, (list, tuple)) else complex(e)
                           for e in r["exact"]])
            ax.plot(ex.real, ex.imag, "x", color=c, ms=9, mew=2)
            done.add(r["label"])
        e = np.abs(np.asarray(r["dqu_errors"], float))
        bx.semilogy(np.arange(1, e.size + 1), np.maximum(e, 1e-6), "-" if mk == "o" else "--",
                    color=c, lw=1)
    ax.set_aspect("equal")
    lim = max(1.1, max(np.abs(np.array([complex(*e) if isinstance(e, (list, tuple))
                                         else complex(e) for r in rows
                                         for e in r["eigenvalues"]] or [0]))) + 0.1)
    ax.set_xlim(-lim, lim)
    ax.set_ylim(-lim, lim)
    ax.axhline(0, color="0.8", lw=0.8)
    ax.axvline(0, color="0.8", lw=0.8)
    ax.set_xlabel("Re")
    ax.set_ylabel("Im")
    ax.set_title("stride-map eigenvalues", fontsize=10)
    handles = [Line2D([], [], color=colour[n], lw=3, label=n) for n in names]
    handles += [Line2D([], [], marker="x", ls="", color="k", mew=2, label="exact (A^z)"),
                Line2D([], [], marker="o", ls="", color="k", label="MuJoCo, stiff"),
                Line2D([], [], marker="s", ls="", color="k", mfc="none",
                       label="MuJoCo, default contact")]
    ax.legend(handles=handles, fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.14),
              ncols=2)
    bx.set_xlabel("step")
    bx.set_ylabel(r"$|\dot q_u - \dot q_u^d(T)|$ at touchdown [rad/s]")
    bx.set_title("error at each touchdown, from the gait (solid: stiff, dashed: default)",
                 fontsize=10)
    bx.grid(alpha=0.3, which="both")
    fig.suptitle("Each design walked in MuJoCo", fontsize=11)
    fig.tight_layout()
    return fig
