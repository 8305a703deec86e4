"""Speed changes: a profile's speed and errors per step
(:func:`biped_casadi.simulation.simulate_profile`), and the largest single-step change each
controller survives (:func:`analysis.robustness.speed.speed_jumps`)."""
from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import MaxNLocator

from .common import _figure

__all__ = ["speed_profile_plot", "speed_jumps_plot"]

_COLOURS = ("tab:blue", "tab:orange", "tab:green", "tab:purple")
_MARKERS = "os^D"


def speed_profile_plot(runs: dict, tol: float = 1e-3, title: str | None = None) -> Figure:
    """Speed per step (top) and the error against each step's gait (bottom, log scale).

    Parameters
    ----------
    runs : dict
        Label -> :class:`~biped_casadi.simulation.ProfileResult` (the same profile
        walked by several controllers).
    tol : float
        The convergence tolerance, drawn on the error panel.
    title : str, optional

    Returns
    -------
    Figure
        A cross marks the step where a run failed, with its status.
    """
    fig = _figure(figsize=(9, 6.2))
    ax_v, ax_e = fig.subplots(2, 1, sharex=True, gridspec_kw=dict(height_ratios=(1, 1.4)))
    first = next(iter(runs.values()))
    k = np.arange(1, len(first.speeds) + 1)
    ax_v.step(k, first.speeds, where="mid", color="0.3", lw=1.2, label="profile (requested)")
    for i, (label, r) in enumerate(runs.items()):
        c, m = _COLOURS[i % len(_COLOURS)], _MARKERS[i % len(_MARKERS)]
        walked = np.array([s.index + 1 for s in r.steps if s.status == "ok"])
        if walked.size:
            # open markers of decreasing size: runs that walked the same steps all show
            ax_v.plot(walked, np.asarray(r.speeds)[walked - 1], m, color=c,
                      ms=max(7 - 2 * i, 3), mfc="none", mew=1.2, label=f"{label}: walked")
        e = r.errors()
        ax_e.semilogy(k, np.where(e > 0, e, np.nan), m + "-", color=c, ms=3.5, lw=1,
                      label=f"{label} ({r.status})")
        if not r.ok:
            f = r.fail_step
            ax_v.plot([f + 1], [r.speeds[f]], "x", color=c, ms=10, mew=2)
            ax_e.axvline(f + 1, color=c, ls=":", lw=1)
            ax_e.annotate(f"{label}: {r.status} at step {f + 1}", (f + 1, 1.0),
                          xycoords=("data", "axes fraction"), xytext=(3, -12 - 12 * i),
                          textcoords="offset points", fontsize=7, color=c)
    ax_e.axhline(tol, color="tab:red", ls="--", lw=1, label=f"converged ({tol:g})")
    ax_v.set_ylabel("speed of the step's gait [m/s]")
    ax_e.set_ylabel("max(|q_u err|, |dq_u err|) before impact\n(rad, rad/s; vs the step's gait)",
                    fontsize=8)
    ax_e.set_xlabel("step")
    ax_e.xaxis.set_major_locator(MaxNLocator(integer=True))
    for ax in (ax_v, ax_e):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    fig.suptitle(title or "Speed profile in full order: speed and error per step", fontsize=11)
    fig.tight_layout()
    return fig


def speed_jumps_plot(jumps: dict, family_range=None, title: str | None = None) -> Figure:
    """The largest single-step change survived against the start speed, per controller.

    Parameters
    ----------
    jumps : dict
        Label -> :class:`~analysis.robustness.speed.SpeedJumps`.
    family_range : tuple of float, optional
        (lowest, highest) speed of the family: the changes possible from each v1 are
        drawn as a grey band (a limit at its edge is censored).
    title : str, optional

    Returns
    -------
    Figure
        Left: the signed changes up (faster) and down (slower); right: the largest
        ``|dv|``.  Open markers are censored (every member that way survived).  Dotted
        lines: the largest changes with every step valid, whether converged or not.
    """
    fig = _figure(figsize=(11, 4.6))
    ax_s, ax_m = fig.subplots(1, 2)
    first = next(iter(jumps.values()))
    v1 = np.asarray(first.v1, float)
    if family_range is not None:
        lo, hi = family_range
        ax_s.fill_between(v1, lo - v1, hi - v1, color="0.85", lw=0,
                          label="changes within the family")
        ax_m.plot(v1, np.maximum(hi - v1, v1 - lo), color="0.6", lw=1, ls="--",
                  label="largest change within the family")
    n = len(jumps)
    for i, (label, j) in enumerate(jumps.items()):
        c, m = _COLOURS[i % len(_COLOURS)], _MARKERS[i % len(_MARKERS)]
        x = np.asarray(j.v1, float) + (i - (n - 1) / 2) * 0.006
        for vals, failed in ((j.up, j.up_failed), (j.down, j.down_failed)):
            y = np.asarray(vals, float)
            cens = np.array([f is None for f in failed])
            ax_s.plot(x, y, "-", color=c, lw=1)
            ax_s.plot(x[~cens], y[~cens], m, color=c, ms=5)
            ax_s.plot(x[cens], y[cens], m, color=c, ms=5, mfc="none")
        ax_s.plot([], [], m + "-", color=c, label=label)
        big = j.largest()
        cens = np.array([_censored(u, d, fu, fd) for u, d, fu, fd in
                         zip(j.up, j.down, j.up_failed, j.down_failed)])
        valid = np.asarray(j.valid, float)
        ax_s.plot(x, valid[:, 0], ":", color=c, lw=1)
        ax_s.plot(x, valid[:, 1], ":", color=c, lw=1)
        ax_m.plot(x, big, "-", color=c, lw=1)
        ax_m.plot(x[~cens], big[~cens], m, color=c, ms=5, label=label)
        ax_m.plot(x[cens], big[cens], m, color=c, ms=5, mfc="none")
    ax_s.plot([], [], ":", color="0.4", label="dotted: every step valid, not converged")
    ax_s.axhline(0, color="0.3", lw=0.8)
    ax_s.set_ylabel("largest single-step change survived, dv = v2 - v1 [m/s]")
    ax_m.set_ylabel("largest |dv| survived [m/s]")
    ax_m.plot([], [], "o", color="0.4", mfc="none", label="open: censored (family edge)")
    for ax in (ax_s, ax_m):
        ax.set_xlabel("start speed v1 [m/s]")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, loc="best")
    fig.suptitle(title or f"Largest single-step speed change survived (then "
                          f"{first.after} steps at v2, converged below 1e-3)", fontsize=11)
    fig.tight_layout()
    return fig


def _censored(up, down, up_failed, down_failed) -> bool:
    """Whether the larger of the two limits is censored (a tie: only if both are)."""
    sides = [(up, up_failed), (-down, down_failed)]
    top = max(v for v, _ in sides)
    return all(f is None for v, f in sides if v == top)
