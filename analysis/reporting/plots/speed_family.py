"""A gait family against speed: cost of transport, step length, period, peak torque,
impact impulse ratio and the virtual constraints' eigenvalue (computed by
:func:`analysis.gait_metrics.family_figures`)."""
from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from .common import _figure, _legend_below

__all__ = ["gait_family_plot", "family_designs_plot"]

#: (field, axis label, reference line field or value, its label)
_PANELS = (
    ("cost_of_transport", "mechanical cost of transport", None, None),
    ("step_length", "step length [m]", None, None),
    ("period", "step period T [s]", None, None),
    ("peak_torque", "peak |u| [N m]", "torque_limit", "torque limit"),
    ("impact_impulse_ratio", "friction ratio |F_x| / F_z", "impact_mu", "impulse bound"),
    ("vc_eigenvalue", "virtual constraints' eigenvalue", 1.0, "stability limit"),
)
_MARKERS = "osD^vP*X"
_COLOURS = ("tab:blue", "tab:green", "tab:purple", "tab:brown")
#: the most entries a panel's legend holds inside the panel (more go under the figure)
_LEGEND_INSIDE = 4


def gait_family_plot(figures, title: str | None = None) -> Figure:
    """Six panels against speed, one per figure of a gait family.

    Members on different branches (a fold crossed) get different colours and markers and
    are not joined; a grey band marks the speeds between which each fold was located;
    dotted lines mark where an inequality constraint becomes active (in the panel it
    bounds: torque limit, friction and impulse cones).  The impulse panel also shows the
    largest friction ratio along the step (dashed); the eigenvalue panel crosses out the
    members whose torso leans past the simulator's fall bound (their orbit is a fall).

    Parameters
    ----------
    figures : FamilyFigures
        From :func:`analysis.gait_metrics.family_figures`.
    title : str, optional

    Returns
    -------
    Figure
    """
    fig = _figure(figsize=(11, 6.4))
    axes = fig.subplots(2, 3, sharex=True).ravel()
    v = np.asarray(figures.speed, float)
    branch = np.asarray(figures.branch, int)
    folds = [e for e in figures.events if e["change"] == "branch"]
    for k, (ax, (name, label, ref, ref_label)) in enumerate(zip(axes, _PANELS)):
        y = np.asarray(getattr(figures, name), float)
        for b in np.unique(branch):
            on = branch == b
            ax.plot(v[on], y[on], _MARKERS[b % len(_MARKERS)] + "-", ms=4, lw=1.2,
                    color=_COLOURS[b % len(_COLOURS)],
                    label=_line_label(name, b, bool(folds), k))
        if name == "impact_impulse_ratio":
            ax.plot(v, figures.friction_ratio, "--", color="0.5", lw=1,
                    label="max |F_x| / F_z along the step")
            if figures.mu != figures.impact_mu:
                ax.axhline(figures.mu, color="tab:red", lw=1, ls=":", label="mu")
        level = getattr(figures, ref) if isinstance(ref, str) else ref
        if level is not None and np.isfinite(level) and (
                ref != "torque_limit" or np.nanmax(y) > 0.5 * level):
            ax.axhline(level, color="tab:red", lw=1, ls="--", label=ref_label)
        for e in folds:
            ax.axvspan(e.get("speed_low", e["speed"]), e.get("speed_high", e["speed"]),
                       color="0.6", alpha=0.35, lw=0,
                       label="fold located here" if k == 0 else None)
        _mark_activations(ax, name, figures.events)
        if name == "vc_eigenvalue":
            _mark_falls(ax, v, y, figures)
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
        if 0 < len(ax.get_legend_handles_labels()[0]) <= _LEGEND_INSIDE:
            ax.legend(fontsize=7, loc="best")
    for ax in axes[3:]:
        ax.set_xlabel("speed [m/s]")
    n_folds = f", {len(folds)} fold(s) crossed (grey)" if folds else ""
    fig.suptitle(title or f"Gait family of {figures.robot}: {len(v)} gaits from {v.min():g} "
                 f"to {v.max():g} m/s{n_folds}", fontsize=11)
    fig.tight_layout()
    for ax in axes:            # a long legend would cover the curves: under its panel
        if len(ax.get_legend_handles_labels()[0]) > _LEGEND_INSIDE:
            box = ax.get_position()
            _legend_below(fig, ax, fontsize=7, ncol=2, x=(box.x0 + box.x1) / 2)
    return fig


def _mark_falls(ax, v, y, figures):
    """A cross on the members whose torso leans past the simulator's fall bound: their
    orbit is a fall, whatever its eigenvalue says."""
    lean = np.asarray(getattr(figures, "torso_lean", []) or [], float)
    if lean.shape != v.shape:
        return
    past = lean > getattr(figures, "fall_bound", np.pi / 2)
    if past.any():
        ax.plot(v[past], y[past], "x", color="tab:red", ms=10, mew=2,
                label="torso past the fall bound:\nthe orbit is a fall")


def _line_label(panel, branch, folds, k):
    """The legend label of a branch's line: branches in the first panel, and what the
    friction panel's solid line is."""
    if panel == "impact_impulse_ratio":
        return "impact impulse" + (f" (branch {branch + 1})" if folds else "")
    return f"branch {branch + 1}" if folds and k == 0 else None


#: the panel where each constraint family's activation is marked
_BOUNDS = {"torque limit": "peak_torque", "friction cone": "impact_impulse_ratio",
           "impact impulse cone": "impact_impulse_ratio", "step length": "step_length",
           "step time bounds": "period"}


def _mark_activations(ax, panel, events):
    """Dotted vertical lines where a constraint bounding this panel becomes active (in
    the legend once per constraint: a label on the line would cross the curves)."""
    styles = {}                                  # a line style per constraint
    for e in events:
        if e["change"] == "active" and _BOUNDS.get(e["constraint"]) == panel:
            c = e["constraint"]
            first = c not in styles
            ls = styles.setdefault(c, (":", "-.", "--")[len(styles) % 3])
            ax.axvline(e["speed"], color="tab:orange", lw=1, ls=ls,
                       label=f"{c} active from here" if first else None)


_DESIGN_STYLE = {"co-design at each speed": ("tab:blue", "o", "-"),
                 "M1 scheduled over speed": ("tab:orange", "s", "--"),
                 "one M1 for all speeds": ("tab:purple", "^", ":"),
                 "virtual constraints": ("tab:green", "D", "-")}


def family_designs_plot(designs, title: str | None = None) -> Figure:
    """max|λ|, s* and the basin against speed for the designs over a gait family.

    Parameters
    ----------
    designs : FamilyDesigns
        From :func:`analysis.design.designs_over_speed.family_designs` (or any object with
        ``records``: per speed ``speed`` and ``designs``, label -> ``max_abs``,
        ``s_star`` and optionally ``basin_area``; ``deadbeat`` optional).
    title : str, optional
        The figure's title.

    Returns
    -------
    matplotlib.figure.Figure
    """
    rec = designs.records
    v = np.array([r["speed"] for r in rec])
    basins = any("basin_area" in d for r in rec for d in r["designs"].values())
    panels = [("max_abs", "max |λ| of $A^z$ (VC: |eigenvalue|)"),
              ("s_star", "s*: largest scale of the paper's\nperturbation survived")]
    if basins:
        panels.append(("basin_area", "basin: converged area\n(rad x rad/s)"))
    fig = _figure(figsize=(7.0, 2.4 * len(panels) + 0.6))
    axes = fig.subplots(len(panels), 1, sharex=True)
    names = list(dict.fromkeys(n for r in rec for n in r["designs"]))
    for ax, (key, label) in zip(np.atleast_1d(axes), panels):
        for i, name in enumerate(names):
            c, m, ls = _DESIGN_STYLE.get(name, (_COLOURS[i % len(_COLOURS)],
                                                _MARKERS[i % len(_MARKERS)], "-"))
            y = [r["designs"].get(name, {}).get(key, np.nan) for r in rec]
            ax.plot(v, y, color=c, marker=m, ls=ls, ms=4, label=name)
        dead = [(r["speed"], r["deadbeat"]["max_abs"]) for r in rec
                if "max_abs" in r.get("deadbeat", {})]
        if key == "max_abs" and dead:
            # deadbeat points are below the map's accuracy (about 1e-4): drawn at 1e-4
            ax.plot([x for x, _ in dead], [max(y, 1e-4) for _, y in dead], color="grey",
                    marker="x", ls="", label="deadbeat M1 NLP, group 1 (below 1e-4: at 1e-4)")
        if key == "max_abs":
            ax.axhline(1.0, color="red", lw=0.8, ls=":", label="stability limit")
            ax.set_yscale("log")
        if key == "s_star":
            ax.axhline(1.0, color="grey", lw=0.8, ls="--", label="the paper's perturbation")
        ax.set_ylabel(label)
        ax.grid(alpha=0.3)
    np.atleast_1d(axes)[0].legend(fontsize=7, loc="best")
    np.atleast_1d(axes)[-1].set_xlabel("speed [m/s]")
    fig.suptitle(title or "Designs over the gait family: max|λ|, s* and basin against "
                          "speed", fontsize=10)
    fig.tight_layout()
    return fig
