"""Figures of a reference gait: the stick diagram of the step over the ground and the
joint profiles q^d(t), u^d(t) (matplotlib, Agg backend, PNG)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

__all__ = ["plot_gait"]


def plot_gait(gait, directory, formats=("png",)) -> list:
    """Write ``gait_stick.<ext>`` (stick diagram of the step over the ground) and
    ``gait_profiles.<ext>`` (q^d(t), u^d(t)) into ``directory`` for every extension in
    ``formats``; returns their paths."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    T = gait.T
    t = np.linspace(0.0, T, 400)
    q, u = gait.q(t), gait.u(t)

    fig, ax = plt.subplots(figsize=(8, 4.5))
    pts_fn = gait.model.points
    for tk in np.linspace(0.0, T, 9):
        P = np.array(pts_fn(gait.q(tk)))           # 2 x 6: st foot, st knee, hip, torso, sw knee, sw foot
        shade = 0.25 + 0.6 * tk / T
        ax.plot(P[0, [0, 1, 2]], P[1, [0, 1, 2]], "-", color=(0.1, 0.3, shade), lw=2)
        ax.plot(P[0, [2, 3]], P[1, [2, 3]], "-", color=(0.3, 0.3, 0.3), lw=2)
        ax.plot(P[0, [2, 4, 5]], P[1, [2, 4, 5]], "-", color=(shade, 0.3, 0.1), lw=1.5)
    feet = np.array([np.array(gait.model.swing_foot(gait.q(tk))).ravel() for tk in t])
    ax.plot(feet[:, 0], feet[:, 1], ":", color="tab:red", lw=1, label="swing foot path")
    xs = [min(-0.4, feet[:, 0].min() - 0.1), max(0.8, feet[:, 0].max() + 0.1)]
    ax.fill_between(xs, [-0.05, -0.05], [0, 0], color="0.8")
    ax.axhline(0.0, color="k", lw=1)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("z (m)")
    ax.set_title(f"one step: T = {T:.3f} s, step {gait.step_length:.3f} m, "
                 f"{gait.speed:.2f} m/s (stance leg blue, swing leg red)")
    ax.legend(loc="upper left")
    stick = [directory / f"gait_stick.{ext}" for ext in formats]
    for p in stick:
        fig.savefig(p, dpi=120, bbox_inches="tight")
    plt.close(fig)

    fig, (a1, a2) = plt.subplots(2, 1, figsize=(8, 6), sharex=True)
    for i in range(5):
        a1.plot(t, q[i], label=f"q{i + 1}" + (" (unactuated)" if i == 0 else ""))
    a1.set_ylabel(r"$q^d(t)$ (rad)")
    a1.legend(ncol=5, fontsize=8)
    for i in range(4):
        a2.plot(t, u[i], label=f"u{i + 1}")
    a2.set_ylabel(r"$u^d(t)$ (N m)")
    a2.set_xlabel("t (s)")
    a2.legend(ncol=4, fontsize=8)
    a1.set_title("reference joint profiles and torques over one step")
    prof = [directory / f"gait_profiles.{ext}" for ext in formats]
    for p in prof:
        fig.savefig(p, dpi=120, bbox_inches="tight")
    plt.close(fig)
    return stick + prof
