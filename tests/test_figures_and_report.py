"""Figures and report.md (issue 12): figures written completely or not at all, titles
and captions that name only the colours drawn, a report without duplicate headings,
uncaptioned figures, repeated sentences or a "see the message" with no message."""
from __future__ import annotations

import re
from pathlib import Path

import matplotlib.colors as mcolors
import numpy as np
import pytest
from matplotlib.figure import Figure

from analysis.reporting.plots import (COLOUR_NAMES, SWING, STANCE, TORSO, gait_stick_plot,
                            m1_plane_plot, save_figure, save_figures)
from analysis.reporting.report import _figure_captions, write_report

COLOUR_WORDS = ("blue", "red", "green", "black", "grey", "gray", "orange", "purple",
                "yellow", "white")


def _colour_words(text: str) -> set:
    return {w for w in COLOUR_WORDS if re.search(rf"\b{w}\b", text.lower())}


# ------------------------------------------------------------------ figures
def test_save_figure_is_complete_or_absent(tmp_path, monkeypatch):
    fig = Figure()
    fig.add_subplot().plot([0, 1], [0, 1])
    old = save_figure(fig, tmp_path / "f", ("png", "pdf"))
    before = {p: Path(p).read_bytes() for p in old}

    def broken(self, fname, *a, **k):             # half a file, then a failure
        Path(fname).write_bytes(b"\x89PNG half")
        raise RuntimeError("renderer failed")

    monkeypatch.setattr(Figure, "savefig", broken)
    with pytest.raises(RuntimeError):
        save_figure(fig, tmp_path / "f", ("png",))
    with pytest.raises(RuntimeError):
        save_figures({"g": fig}, tmp_path / "new_folder")
    assert {p: Path(p).read_bytes() for p in old} == before        # earlier figures intact
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.pdf", "f.png"]   # no temp, no folder


@pytest.mark.parametrize("layout", ["tight", "constrained"])
def test_figure_files_crop_as_savefig_tight(layout):
    """The tight box measured once gives the PNG savefig's bbox_inches='tight' gives
    (pixel for pixel), a PDF page within 2 pt of its own, and the layout engine back."""
    import io

    from PIL import Image

    from analysis.pipeline.figures import figure_files
    from analysis.reporting.plots.common import _figure

    def make():
        fig = _figure(figsize=(5, 3), layout="constrained" if layout == "constrained" else None)
        ax = fig.add_subplot()
        ax.semilogy([1, 2, 3], [1, 10, 100], label="a long legend entry")
        ax.set_ylabel(r"$\dot q_u$ [rad/s]")
        ax.legend()
        fig.suptitle("a title wider than the axes, to be cropped around it " * 2)
        if layout == "tight":
            fig.tight_layout()
        return fig

    ref, fig = make(), make()
    engine = type(fig.get_layout_engine())
    files = figure_files(fig)
    assert type(fig.get_layout_engine()) is engine
    want = {}
    for ext in ("png", "pdf"):
        buf = io.BytesIO()
        ref.savefig(buf, dpi=150, bbox_inches="tight", format=ext)
        want[ext] = buf.getvalue()
    a, b = (np.asarray(Image.open(io.BytesIO(f["png"]))) for f in (files, want))
    assert a.shape == b.shape and np.abs(a.astype(int) - b).max() == 0

    def box(pdf):
        return np.array(re.search(rb"/MediaBox\s*\[([-\d.\s]+)\]", pdf).group(1).split(), float)

    assert np.abs(box(files["pdf"]) - box(want["pdf"])).max() < 2.0


def test_save_figures_is_all_or_none(tmp_path, monkeypatch):
    ok, bad = Figure(), Figure()
    ok.add_subplot()
    real = Figure.savefig

    def savefig(self, *a, **k):
        if self is bad:
            raise OSError(28, "No space left on device")
        return real(self, *a, **k)

    monkeypatch.setattr(Figure, "savefig", savefig)
    with pytest.raises(OSError):
        save_figures({"a": ok, "b": bad}, tmp_path / "figs")
    assert not (tmp_path / "figs").exists()
    assert save_figures({"a": ok}, tmp_path / "figs") == [str(tmp_path / "figs" / "a.png")]


def test_stick_figure_names_only_the_colours_it_draws(gait):
    """Issue 12: the stick-figure title named colours the plot did not use."""
    fig = gait_stick_plot(gait)
    ax = fig.axes[0]
    drawn = {mcolors.to_hex(line.get_color()) for line in ax.get_lines()}
    assert {mcolors.to_hex(c) for c in (STANCE, SWING, TORSO)} <= drawn
    named = {COLOUR_NAMES[c] for c in (STANCE, SWING, TORSO)}
    texts = [ax.get_title()] + [t.get_text() for t in ax.get_legend().get_texts()]
    for text in texts:
        assert _colour_words(text) <= {w for n in named for w in n.split()}, text
    # the names themselves describe the colours (blue is blue, red is red, grey is grey)
    for c, name in COLOUR_NAMES.items():
        r, g, b = mcolors.to_rgb(c)
        word = name.split()[-1]
        assert {"blue": b > max(r, g), "red": r > max(g, b),
                "grey": abs(r - g) < 0.05 and abs(g - b) < 0.05}[word], (c, name)


def test_captions_name_only_drawn_colours():
    named = set(" ".join(COLOUR_NAMES.values()).split())
    # besides the stick figures' colours: red marks stable points and the max|lambda| = 1
    # contour (Fig. 2-4, the M1 plane), orange the solutions of a = b = 0 (the M1 plane)
    drawn = {"fig2": {"red"}, "fig3": {"red"}, "fig4": {"red"}, "m1_plane": {"red", "orange"}}
    for key, (title, caption) in _figure_captions({}).items():
        words = _colour_words(title + " " + caption)
        assert words <= named | drawn.get(key, set()), (key, words)
    g = np.linspace(-1, 1, 5)
    m1, m2 = np.meshgrid(g, g, indexing="ij")
    fig = m1_plane_plot(m1, m2, np.exp(m1 + m2), ab_points=[[0.0, 0.0]], best=[0.5, 0.5])
    colours = {mcolors.to_hex(line.get_color()) for line in fig.axes[0].get_lines()}
    assert mcolors.to_hex("orange") in colours


# ------------------------------------------------------------------ report
def _summary(tv_status="ok", tv_message=""):
    figs = {k: [f"figures/{k}.png", f"figures/{k}.pdf"] for k in
            ("gait_stick", "gait_profiles", "fig2", "fig3", "fig4")}
    figs["fig5_qu_error"] = ["figures/fig5_qu_error.png", "figures/fig5_qu_error.pdf"]
    figs["fig6_swing_torques"] = ["figures/fig6_swing_torques.png", "figures/fig6_swing_torques.pdf"]
    figs["walk_tv"] = ["figures/walk_tv.gif"]
    return {
        "mode": "full", "total_time": 50.0, "finished": "today",
        "options": dict(line_points=401, domain_n=81, nlp_starts=10, sim_steps=10,
                        animation_steps=4),
        "gait": dict(T=0.69, step_length=0.52, speed=0.75, cost=575.0, peak_torque=30.7,
                     periodicity_dq=3e-13),
        "singular": dict(D11_T=23.5, D12_T=[13.9, 4.75, 0.44, 0.10],
                         singular_values=[1.69, 4.94, 53.4, 227.0]),
        "fig2": dict(points_per_component=401),
        "grid": dict(counts=dict(stable=84, unstable=6284, singular=193, no_impact=0),
                     best_stable=dict(M1=[-2.5, 5, -2.5, 5], max_abs=0.51)),
        "conjecture": dict(max_abs_zsw_stable=0.011, fraction_unstable_below=0.25),
        "domains": dict(grid=81, range=[-10, 10], groups={
            "1": dict(stable_area=16.3, best=dict(M1=[2.2, -4.5, 3.0, 1.8], max_abs=0.23)),
            "2": dict(stable_area=25.4, best=dict(M1=[-0.6, 1.5, 2.0, -2.5], max_abs=0.52))}),
        "m1_nlp": {k: dict(M1=[1.0, 2.0, 3.0, 4.0], max_abs=1e-5, eigenvalue_uncertainty=1e-4)
                   for k in ("group1", "group2", "free")} | {
            "paper_example_M1": dict(max_abs=22.2)},
        "vc_comparison": dict(vc=dict(eigenvalue=0.54)),
        "simulation": dict(perturbation=[0.01, 0.1], mu=0.6, runs=dict(
            default_vc=dict(label="virtual constraints (default gait)", status="ok",
                            steps=10, steps_to_converge=5),
            default_deadbeat=dict(label="deadbeat M1 (default gait)", status=tv_status,
                                  message=tv_message, steps=1 if tv_message else 10,
                                  steps_to_converge=None if tv_message else 3))),
        "stages": {"gait": dict(status="ok", time=1.0)},
        "figures": figs,
        "paper": dict(D11_T=24.2445, D12_T=[13.4, 3.6, 0.54, 0.04],
                      singular_values=[1.8, 6.7, 45.1, 592.8],
                      grid_counts=dict(stable=19, unstable=5363, singular_or_no_impact=1179),
                      example_M1=[1.9121, -4.0, -3.0, -1.4090], example_max_abs=0.2392,
                      tv_convergence_steps=4),
    }


@pytest.mark.parametrize("tv_status, tv_message", [("ok", ""),
                                                   ("slipped", "step 1: stance foot slips")])
def test_report_reads_well(tmp_path, tv_status, tv_message):
    """Issue 12: two figure headings both called 'gait', figures without captions, one
    sentence repeated on five rows, 'see the message' with no message."""
    text = write_report(tmp_path, _summary(tv_status, tv_message)).read_text()
    headings = [line for line in text.splitlines() if line.startswith("#")]
    assert len(headings) == len(set(headings)), headings
    lines = text.splitlines()
    for i, line in enumerate(lines):                  # every image has a caption after it
        if line.startswith("!["):
            caption = next(x for x in lines[i + 1:] if x.strip())
            assert not caption.startswith(("#", "!")) and len(caption) > 40, caption
    n_images = sum(line.startswith("![") for line in lines)
    assert n_images == 8 and "figures/walk_tv.gif" in text
    rows = [line.split(" | ") for line in lines if line.startswith("| ") and " | " in line]
    why = [r[3].rstrip(" |") for r in rows if len(r) >= 4 and len(r[3]) > 25]
    assert len(why) == len(set(why)), why            # no long reason repeated
    assert "see the message" not in text
    assert "Full run" in text and "every stage ok" in text
    if tv_status == "ok":
        assert "| ok |" in text and "friction cone" not in text
    else:
        assert f"slipped: {tv_message}" in text and "friction cone" in text


def test_report_of_a_failed_stage_says_so(tmp_path):
    s = _summary()
    for key in ("domains", "m1_nlp", "simulation"):
        s.pop(key)
    s["stages"]["a, b and Fig. 4"] = dict(status="failed", error="ValueError: boom\nline 2",
                                          time=0.1)
    text = write_report(tmp_path, s).read_text()
    assert "1 of 2 stages not ok" in text and "failed: ValueError: boom line 2" in text
    assert "n/a at n/a" not in text and "not computed" in text


def test_fig5_of_runs_without_an_impact_has_a_step_axis(gait):
    """Runs that fail before their first impact (``biped simulate --perturb 1 0
    --compare --plot``): Fig. 5 drew an empty axis from -0.04 to 0.04 "steps"; it shows
    step 1 and says no run reached an impact."""
    from analysis.reporting.plots import unactuated_error_plot
    from biped_casadi import Design, perturbed_initial_state, simulate
    run = simulate(Design.vc(gait).controller_for(), *perturbed_initial_state(gait, 1.0, 0.0))
    assert len(run.steps) == 0 and not run.ok
    fig = unactuated_error_plot([run])
    ax = fig.axes[1]
    lo, hi = ax.get_xlim()
    assert lo < 1 < hi and lo >= 0 and hi <= 2
    assert any("no run reached an impact" in t.get_text() for t in fig.axes[0].texts)


def test_fig5_ticks_whole_steps(gait):
    """A short run (3 steps, notebook 04) had ticks at 1.25, 1.5, ... steps."""
    from analysis.reporting.plots import unactuated_error_plot
    from biped_casadi import Design, SimulationOptions, perturbed_initial_state, simulate
    run = simulate(Design.vc(gait).controller_for(), *perturbed_initial_state(gait, 0.001, 0.01),
                   options=SimulationOptions(steps=3))
    assert len(run.steps) == 3
    fig = unactuated_error_plot([run])
    fig.canvas.draw()
    lo, hi = fig.axes[1].get_xlim()
    ticks = [t for t in fig.axes[1].get_xticks() if lo <= t <= hi]
    assert ticks and all(float(t).is_integer() for t in ticks), ticks


def test_fig6_of_runs_stopped_at_the_start_shows_them(gait):
    """Runs stopped at t = 0 have one sample: Fig. 6 drew no visible line on an axis of
    -0.04 to 0.04 s; the sample is a marker, the axis starts at 0, and a note says so."""
    from analysis.reporting.plots import run_label, swing_torques_plot
    from biped_casadi import Design, perturbed_initial_state, simulate
    run = simulate(Design.vc(gait).controller_for(), *perturbed_initial_state(gait, 1.0, 0.0))
    assert np.ptp(run.t) == 0
    fig = swing_torques_plot([run], gait)
    ax = fig.axes[0]
    assert ax.lines[0].get_marker() == "o"
    lo, hi = ax.get_xlim()
    assert lo <= 0 < hi and lo > -0.2 * gait.T
    assert any("stopped at t = 0" in t.get_text() for t in ax.texts)
    # the legend lists what is drawn: the run, not a reference no step drew
    assert [t.get_text() for t in ax.get_legend().get_texts()] == [run_label(run)]
    assert not any(line.get_linestyle() == "--" for line in ax.lines)


def test_stick_plot_names_bad_arguments(gait):
    """frames = 0 drew an empty figure; a path for the gait was an AttributeError."""
    from analysis.reporting.plots import gait_stick_plot
    for bad in (0, 1, 2.5):
        with pytest.raises(ValueError, match=r"^frames must be an integer >= 2"):
            gait_stick_plot(gait, frames=bad)
    with pytest.raises(TypeError, match="^gait: a gait is needed"):
        gait_stick_plot("gait.json")
