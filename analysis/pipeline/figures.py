"""The reproduction's figures as tasks (kept by the figures' code, so an edit of a plot
draws it again and nothing else): each draws one figure from stage results and returns
its files' bytes by format."""
from __future__ import annotations

import io
import tempfile
from pathlib import Path

from ..reporting.plots import (basin_plot, conjecture_plot, family_designs_plot,
                               gait_profiles_plot, gait_stick_plot, speed_profile_plot,
                               m1_plane_plot, mfpt_sigma_plot, one_d_sweeps_plot,
                               stable_domains_plot, survival_plot, swing_torques_plot,
                               tradeoff_plot, unactuated_error_plot, walking_animation)
from ..reporting.plots.common import tight_box
from ..tasks import task

__all__ = ["FORMATS", "figure_files", "gait_figures", "fig2", "fig3", "fig4",
           "basins_default", "basins_robust", "family_figure",
           "tradeoff", "fig5_fig6", "animation", "terrain_figures"]

#: every figure is written in these formats
FORMATS = ("png", "pdf")


def figure_files(fig, formats=FORMATS, dpi: int = 150) -> dict:
    """A figure's files as bytes: format -> bytes.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        The figure.
    formats : tuple of str
        The formats.
    dpi : int
        Resolution of the raster formats.

    Returns
    -------
    dict
    """
    out = {}
    with tight_box(fig, dpi) as box:                      # measured once for all formats
        for ext in formats:
            buf = io.BytesIO()
            fig.savefig(buf, dpi=dpi, bbox_inches=box, format=ext)
            out[ext] = buf.getvalue()
    return out


@task(code="figures")
def gait_figures(gait_stage) -> dict:
    """The gait's stick diagram and profiles: name -> files."""
    g = gait_stage.gait
    return dict(gait_stick=figure_files(gait_stick_plot(g)),
                gait_profiles=figure_files(gait_profiles_plot(g)))


@task(code="figures")
def fig2(sweep_stage) -> dict:
    """Fig. 2: max|lambda| against each component of M1."""
    return dict(fig2=figure_files(one_d_sweeps_plot(sweep_stage.sweeps)))


@task(code="figures")
def fig3(conjecture_stage) -> dict:
    """Fig. 3: max|lambda| against the swing height at T^d."""
    c = conjecture_stage
    return dict(fig3=figure_files(conjecture_plot(c.zsw, c.max_abs, c.status)))


@task(code="figures")
def fig4(domain_stage) -> dict:
    """Fig. 4 (the groups' stable domains) or, for two torques, the M1 plane."""
    d, f = domain_stage, domain_stage.figure
    if d.kind == "groups":
        return dict(fig4=figure_files(stable_domains_plot(f["m2"], f["m3"], f["map1"],
                                                          f["map2"], f["best"])))
    if d.kind == "plane":
        return dict(m1_plane=figure_files(m1_plane_plot(
            f["m1"], f["m2"], f["max_abs"], ab_points=f["ab_points"], ab_line=f["ab_line"],
            best=f["best"], title=f["title"])))
    return {}


@task(code="figures")
def basins_default(basin_stage) -> dict:
    """The default gait's basins side by side."""
    return dict(basin_default=figure_files(basin_plot(basin_stage.basins,
                                                      title=basin_stage.title,
                                                      labels=basin_stage.labels)))


@task(code="figures")
def basins_robust(basin_stage) -> dict:
    """The robust designs' basins side by side."""
    return dict(basin_robust=figure_files(basin_plot(basin_stage.basins,
                                                     title=basin_stage.title,
                                                     labels=basin_stage.labels)))


@task(code="figures")
def tradeoff(robust_stage, tradeoff_stage, robustness_stage) -> dict:
    """s* against max|lambda|: the NLP at four eigenvalue bounds, the co-design, the
    sampling search's design and virtual constraints (every s* from the s* table)."""
    rb = robust_stage.result
    rows = robustness_stage.summary["robustness"]["rows"]
    pts = [(p["max_abs"], p["s_star"]) for p in
           (tradeoff_stage.summary["robust_design"]["tradeoff"] if tradeoff_stage else [])
           if p.get("s_star") is not None]
    vc = next((r["s_star"] for r in rows if r["gait"] == "robust"
               and r["controller"] == "vc"), None)
    ss = next((r for r in rows if r["label"] == "the sampling search's design"), None)
    mine = next((r for r in rows if r["label"] == "robust design (co-design NLP)"), None)
    others = {"co-design NLP": (rb.max_abs, mine["s_star"] if mine else rb.s_star)}
    if ss is not None:
        others["sampling search's design"] = (ss["max_abs"], ss["s_star"])
    if vc is not None:
        others["virtual constraints"] = (rb.vc_eigenvalue, vc)
    return dict(tradeoff=figure_files(tradeoff_plot(
        pts, others, bound=rb.vc_eigenvalue, front_style="points",
        front_label="the NLP, gait fixed, max|λ| <= 1/4, 1/2, 3/4, 1 x virtual constraints' "
                    "(s* verified)",
        title="s* against max|λ| on the co-design's gait")))


def _pair(sim_stage, robust_sim_stage):
    """The runs of Fig. 6 and the gait they ran on: virtual constraints and the co-design
    on the co-design's gait, else the default gait's runs."""
    if robust_sim_stage is not None:
        return robust_sim_stage.runs[:2], robust_sim_stage.gait
    return sim_stage.runs, sim_stage.gait


@task(code="figures")
def fig5_fig6(sim_stage, robust_sim_stage) -> dict:
    """Fig. 5 (the q_u error before each impact of every run) and Fig. 6 (the swing-leg
    torques of virtual constraints and the co-design, or of the default gait's runs)."""
    runs = list(sim_stage.runs) + (list(robust_sim_stage.runs) if robust_sim_stage else [])
    pair, gait = _pair(sim_stage, robust_sim_stage)
    return dict(
        fig5_qu_error=figure_files(unactuated_error_plot(
            [r for r, _ in runs], labels=[lab for _, lab in runs],
            title="Fig. 5 at the paper's full perturbation: q_u error just before each "
                  "impact")),
        fig6_swing_torques=figure_files(swing_torques_plot(
            [r for r, _ in pair], gait, labels=[lab for _, lab in pair],
            title="Fig. 6 at the paper's full perturbation: swing-leg torques")))


@task(code="figures")
def animation(sim_stage, robust_sim_stage, res) -> dict:
    """The stick-figure animation of the co-design's run (else the deadbeat M1's), GIF
    (none when ``res.animation_steps`` is 0)."""
    steps = res.animation_steps
    if not steps:
        return {}
    pair, gait = _pair(sim_stage, robust_sim_stage)
    (run, label), model = pair[-1], gait.model
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "walk.gif"
        walking_animation(run, model, path, max_steps=steps,
                          title=f"{model.params.name}, {label}: {run.status}")
        return dict(walk_tv=dict(gif=path.read_bytes()))


@task(code="figures")
def terrain_figures(terrain_stage) -> dict:
    """The MFPT against sigma and the survival curves at the largest sigma."""
    t = terrain_stage
    return dict(terrain_mfpt=figure_files(mfpt_sigma_plot(t.curves)),
                terrain_survival=figure_files(survival_plot(
                    [r for r, _ in t.survival], labels=[lab for _, lab in t.survival],
                    title=f"Survival at sigma = {1000 * t.sigma:g} mm")))


@task(code="figures")
def family_figure(family_stage) -> dict:
    """s* and max|lambda| against speed on the reproduction's gait family."""
    out = dict(family=figure_files(family_designs_plot(
        family_stage, title="The co-design's M1 and virtual constraints over the gait "
                            "family: max|λ| and s* against speed")))
    if family_stage.ramps:
        rp = family_stage.summary["family"]["ramp"]
        out["speed_ramp"] = figure_files(speed_profile_plot(
            family_stage.ramps, title=f"Speed ramp {rp['v1']:g} -> {rp['v2']:g} -> "
                                      f"{rp['v1']:g} m/s by {rp['dv']:g} per step in full "
                                      "order"))
    return out
