"""The figure of a running gait (:mod:`gait_opt.running`): poses over the ground and the
joint profiles over one step, stance then flight."""
from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from biped_casadi.model import flight_model
from biped_casadi.model.description import torque_bound_text
from gait_opt.running_checks import dense

from .common import STANCE, SWING, _figure, _stick

__all__ = ["running_plot", "running_stability_plot"]


def _poses(ax, model, gait, frames):
    """Stick figures at evenly spaced times of the step and both feet's paths."""
    fl = flight_model(model)
    n, ne = model.nq, fl.ne
    ts, xs, _ = dense(model, gait, "stance")
    tf, xf, _ = dense(model, gait, "flight")
    for k, tk in enumerate(np.linspace(0.0, gait.T, frames)):
        alpha = 0.25 + 0.75 * k / (frames - 1)
        if tk <= gait.T_stance:
            q = xs[:n, np.argmin(np.abs(ts - tk))]
            _stick(ax, model, np.array(model.points(q)), alpha=alpha)
        else:
            qe = xf[:ne, np.argmin(np.abs(tf - (tk - gait.T_stance)))]
            _stick(ax, model, np.array(fl.points(qe)), alpha=alpha)
    sw_s = np.array(model.swing_foot.map(ts.size)(xs[:n])).reshape(2, -1)
    feet = np.array(fl.feet.map(tf.size)(xf[:ne]))
    ax.plot(np.r_[sw_s[0], feet[0, 1::2]], np.r_[sw_s[1], feet[1, 1::2]], ":", color=SWING,
            lw=1.2)
    ax.plot(feet[0, 0::2], feet[1, 0::2], ":", color=STANCE, lw=1.2)
    x_lo, x_hi = min(-0.5, sw_s[0].min() - 0.1), max(gait.step_length + 0.2, 1.0)
    ax.fill_between([x_lo, x_hi], [-0.05, -0.05], [0, 0], color="0.85")
    ax.axhline(0.0, color="k", lw=1)
    ax.set_xlim(x_lo, x_hi)
    ax.set_aspect("equal")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("z [m]")
    ax.set_title(f"poses over the step ({frames}, later ones darker) and the feet's paths",
                 fontsize=9)
    ax.legend(handles=[Line2D([], [], color=STANCE, lw=2, label="leg that pushes off"),
                       Line2D([], [], color=SWING, lw=2, label="leg that lands"),
                       Line2D([], [], color="0.25", lw=3, label="torso"),
                       Line2D([], [], color="k", ls=":", lw=1.2, label="foot paths")],
              loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=8)


def _profiles(ax_q, ax_u, model, gait):
    """Joint angles and torques against time, the flight phase shaded."""
    n = model.nq
    ts, xs, us = dense(model, gait, "stance")
    tf, xf, uf = dense(model, gait, "flight")
    t = np.r_[ts, gait.T_stance + tf]
    q = np.hstack([xs[:n], xf[:n]])
    u = np.hstack([us, uf])
    for i in range(n):
        ax_q.plot(t, q[i], lw=1.5, label=f"q{i + 1}: {model.joint_names[i]}")
    for i in range(model.nu):
        ax_u.plot(t, u[i], lw=1.5, label=f"u{i + 1}: {model.joint_names[i + 1]}")
    limit = gait.options.limit(model)
    for ax in (ax_q, ax_u):
        ax.axvspan(gait.T_stance, gait.T, color="0.9", label="flight")
        ax.set_xlim(0.0, gait.T)
        ax.grid(alpha=0.3)
        ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize=7)
    for v in sorted(set(np.atleast_1d(limit).tolist())):   # each joint's where they differ
        ax_u.axhline(v, color="k", ls="--", lw=0.8)
        ax_u.axhline(-v, color="k", ls="--", lw=0.8)
    ax_q.set_ylabel("joint angle [rad]")
    ax_u.set_ylabel(f"torque [N m] (limit ±{torque_bound_text(limit)} dashed)")
    ax_u.set_xlabel("time from landing [s]")


def running_plot(model, gait, frames: int = 10) -> Figure:
    """A running step: poses over the ground, joint angles and torques over time.

    Parameters
    ----------
    model : BipedModel
        The robot the gait was optimised for.
    gait : RunningGait
        The gait (:func:`gait_opt.running.optimize_running`).
    frames : int
        Poses drawn, evenly spaced over the step.

    Returns
    -------
    Figure
    """
    fig = _figure(figsize=(9, 10))
    ax_p = fig.add_subplot(3, 1, 1)
    ax_q = fig.add_subplot(3, 1, 2)
    ax_u = fig.add_subplot(3, 1, 3, sharex=ax_q)
    _poses(ax_p, model, gait, max(2, int(frames)))
    _profiles(ax_q, ax_u, model, gait)
    fig.suptitle(f"{model.description.name}, running step at {gait.speed:.2f} m/s: "
                 f"stance {gait.T_stance:.3f} s + flight {gait.T_flight:.3f} s, "
                 f"step length {gait.step_length:.3f} m", fontsize=10)
    fig.tight_layout()
    return fig


def running_stability_plot(robot: str, speed: float, families: dict, singles: dict | None = None,
                           single_label: str = "") -> Figure:
    """The spectral radius of a running gait's stride map against the output's M1.

    Parameters
    ----------
    robot : str
        The robot's name (in the title).
    speed : float
        The gait's speed, m/s (in the title).
    families : dict
        label -> (c, radius): the spectral radius along M1 = (0, c, c, 0) for one set of
        gains (the label names them), NaN where no fixed point was found.
    singles : dict, optional
        label -> (value, radius): one component of M1 swept alone (a second panel).
    single_label : str
        The gains of the second panel, in words.

    Returns
    -------
    matplotlib.figure.Figure
    """
    panels = 2 if singles else 1
    fig = _figure(figsize=(5.2 * panels, 4.0), layout="constrained")
    axes = [fig.add_subplot(1, panels, i + 1) for i in range(panels)]
    for label, (c, r) in families.items():
        axes[0].semilogy(c, r, "o-", ms=3, lw=1.4, label=label)
    axes[0].set_xlabel("c in M1 = (0, c, c, 0), on both hips [rad/rad]")
    axes[0].set_title("both hips' outputs lean on q1", fontsize=9)
    if singles:
        for label, (v, r) in singles.items():
            axes[1].semilogy(v, r, "o-", ms=3, lw=1.4, label=label)
        axes[1].set_xlabel("one component of M1, the others 0 [rad/rad]")
        axes[1].set_title(f"one joint's output leans on q1 ({single_label})", fontsize=9)
    for ax in axes:
        ax.axhline(1.0, color="k", ls="--", lw=0.8, label="spectral radius 1")
        ax.set_ylabel("spectral radius of the stride map [-]")
        ax.grid(alpha=0.3, which="both")
        ax.legend(fontsize=7, loc="upper left")
    fig.suptitle(f"{robot} running at {speed:g} m/s, tracked in stance and flight: "
                 "exact stride-map spectral radius (below 1: stable)", fontsize=10)
    return fig
