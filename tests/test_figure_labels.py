"""What a reader of the figures needs from their texts: the robot named where the figure is
of one robot, legends that do not sit on the curves, every series visible when series
coincide.  Checks the Figure objects (titles, labels, legends, artists), not pixels."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from matplotlib.colors import to_hex

from analysis.reporting.plots import (gait_profiles_plot, gait_stick_plot, mfpt_sigma_plot,
                                      mujoco_steps_plot, speed_profile_plot, survival_plot,
                                      swing_torques_plot, tradeoff_plot, unactuated_error_plot)


def _overlaps(fig, legend, axes) -> list:
    """The axes whose drawn area the legend's box enters."""
    fig.canvas.draw()
    box = legend.get_window_extent()
    return [ax for ax in axes if box.overlaps(ax.get_window_extent())]


@pytest.mark.parametrize("which", ["gait", "gait3"])
def test_gait_profiles_name_the_robot(which, request):
    """The profiles' title named no robot (the stick diagram beside it did)."""
    g = request.getfixturevalue(which)
    fig = gait_profiles_plot(g)
    title = fig.axes[0].get_title()
    assert title.startswith(g.model.params.name + ":"), title
    assert ("RABBIT" in title) == (g.model.params.name == "RABBIT")
    q_labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert len(q_labels) == g.model.nq                      # one curve per joint of this robot
    assert "[rad]" in fig.axes[0].get_ylabel() and "[N m]" in fig.axes[1].get_ylabel()


@pytest.fixture(scope="module")
def two_runs(gait):
    from biped_casadi import Design, SimulationOptions, perturbed_initial_state, simulate
    x0 = perturbed_initial_state(gait, 0.01, 0.1)
    opts = SimulationOptions(steps=2)
    return [simulate(Design.vc(gait).controller_for(), *x0, options=opts),
            simulate(Design.tv(gait, [0.0, 0.0, 0.0, 0.0]).controller_for(), *x0,
                     options=opts)]


def test_fig5_fig6_of_several_runs_keep_their_legend_off_the_panels(two_runs, gait):
    """With several runs (the reproduction's five) the legend covered the curves of
    Fig. 5's upper panel and Fig. 6's hip torque: it is under the figure."""
    for fig in (unactuated_error_plot(two_runs), swing_torques_plot(two_runs, gait)):
        assert all(ax.get_legend() is None for ax in fig.axes)
        (legend,) = fig.legends
        labels = [t.get_text() for t in legend.get_texts()]
        assert any(lab.startswith("virtual constraints") for lab in labels)
        assert any(lab.startswith("time-varying") for lab in labels)
        assert _overlaps(fig, legend, fig.axes) == []


def test_fig6_names_the_robot(gait3):
    from biped_casadi import Design, SimulationOptions, perturbed_initial_state, simulate
    run = simulate(Design.vc(gait3).controller_for(), *perturbed_initial_state(gait3, 0.01, 0.1),
                   options=SimulationOptions(steps=1))
    fig = swing_torques_plot([run], gait3)
    (title,) = [t.get_text() for t in fig.texts]                    # the suptitle
    assert "three_link" in title and "RABBIT" not in title
    assert [ax.get_ylabel() for ax in fig.axes] == ["u2, swing hip [N m]"]   # no knee


def _mc(survival, mfpt, lo):
    est = SimpleNamespace(survival=survival, mfpt=mfpt, mfpt_ci=(lo, np.inf))
    return SimpleNamespace(estimate=est, spec={"controller": "vc"}, settings={"sigma": 0.008})


def test_survival_curves_that_coincide_stay_visible():
    """Two controllers that both walked every run drew one line over the other."""
    runs = [_mc([1.0] * 13, np.inf, 51), _mc([1.0] * 13, np.inf, 51),
            _mc([1.0, 1.0, 0.5, 0.0], 2.5, 2)]
    fig = survival_plot(runs, labels=["a", "b", "c"])
    styles = [line.get_linestyle() for line in fig.axes[0].lines]
    assert len(styles) == 3 and len(set(styles)) == 3
    # the legend gives the MFPT's unit (or the lower bound where no run failed)
    texts = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert texts == ["a (MFPT > 51 steps)", "b (MFPT > 51 steps)", "c (MFPT 2.5 steps)"]


def test_mfpt_legend_lists_only_what_is_drawn():
    """A controller without any failure had an entry (a marker and a line) for points
    that are not drawn, beside its 'no failure (lower bound)' entry."""
    fig = mfpt_sigma_plot({"never fails": [(0.004, np.inf, 51, np.inf),
                                           (0.008, np.inf, 51, np.inf)],
                           "fails": [(0.004, 8.0, 4.0, 16.0), (0.008, 4.0, 2.0, 8.0)]})
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert labels == ["never fails: no failure (lower bound)", "fails"]


def test_tradeoff_reference_line_is_not_a_design_colour():
    """The s = 1 line was green, the colour of the third design's marker (virtual
    constraints in the reproduction)."""
    fig = tradeoff_plot([], {"a": (0.1, 1.5), "b": (0.2, 1.2), "c": (0.3, 1.1)}, bound=0.3)
    ax = fig.axes[0]
    marks = [to_hex(line.get_color()) for line in ax.lines
             if line.get_marker() not in ("None", "")]
    (ref,) = [line for line in ax.lines if "s = 1" in line.get_label()]
    assert len(marks) == 3 and to_hex(ref.get_color()) not in marks


def _profile(n, status="ok"):
    steps = [SimpleNamespace(index=i, status="ok") for i in range(n)]
    return SimpleNamespace(speeds=[0.6 + 0.05 * min(i, n - 1 - i) for i in range(n)],
                           steps=steps, status=status, ok=True,
                           errors=lambda: np.geomspace(1e-1, 1e-4, n))


def test_speed_profile_runs_that_walked_the_same_steps_all_show():
    """The second controller's filled squares hid the first one's circles."""
    fig = speed_profile_plot({"virtual constraints": _profile(7), "M1": _profile(7)})
    walked = [line for line in fig.axes[0].lines if line.get_label().endswith(": walked")]
    assert len(walked) == 2
    assert all(line.get_markerfacecolor() == "none" for line in walked)
    assert walked[0].get_markersize() > walked[1].get_markersize()


def test_mujoco_steps_legend_is_off_the_panels():
    """The legend sat on the speed and duration of a long walk, which fill their panels."""
    n = 30
    w = dict(law="c", settings=dict(contact="stiff"), status="walked",
             gait=dict(speed=0.75, T=0.69), speeds=0.74 + 0.01 * np.sin(np.arange(n)),
             periods=0.70 + 0.01 * np.cos(np.arange(n)), qu_errors=np.zeros(n),
             dqu_errors=np.zeros(n))
    fig = mujoco_steps_plot([w])
    assert all(ax.get_legend() is None for ax in fig.axes)
    (legend,) = fig.legends
    assert {"C law, stiff contact: walked", "the gait's speed", "the gait's T"} <= {
        t.get_text() for t in legend.get_texts()}
    assert _overlaps(fig, legend, fig.axes) == []


@pytest.mark.parametrize("which", ["gait", "gait3"])
def test_stick_diagram_legend_is_beside_the_poses(which, request):
    """The legend in the upper left covered the three-link biped's first torsos."""
    g = request.getfixturevalue(which)
    fig = gait_stick_plot(g)
    ax = fig.axes[0]
    assert ax.get_title().startswith(g.model.params.name + ", reference step")
    assert _overlaps(fig, ax.get_legend(), [ax]) == []


def test_fig3_says_what_it_leaves_out():
    """Points beyond the drawn range and points without a value were left out silently:
    the legend's counts did not add up to the grid."""
    from analysis.reporting.plots import conjecture_plot
    max_abs = np.array([0.5, 2.0, 60.0, 70.0, np.inf, np.nan])
    status = np.array(["stable", "unstable", "unstable", "unstable", "singular", "singular"])
    fig = conjecture_plot(np.zeros(6), max_abs, status, limit=50.0)
    assert "not drawn: 2 at 50 or more, 2 without a value" in fig.axes[0].get_xlabel()
    labels = [t.get_text() for t in fig.axes[0].get_legend().get_texts()]
    assert labels == ["unstable (1)", "stable (1)"]


def test_fig4_legend_is_off_the_contours():
    """The star's legend sat in each panel's lower right corner, on group 2's contour."""
    from analysis.reporting.plots import stable_domains_plot
    m2, m3 = np.meshgrid(np.linspace(-10, 10, 9), np.linspace(-10, 10, 9), indexing="ij")
    fig = stable_domains_plot(m2, m3, np.exp(m2 / 5), np.exp(m3 / 5),
                              best={1: [0, 1, 2, 3], 2: [0, -1, -2, 3]})
    panels = fig.axes[:2]
    assert all(ax.get_legend() is None for ax in panels)
    (legend,) = fig.legends
    assert [t.get_text() for t in legend.get_texts()] == ["best point of the group"]
    assert _overlaps(fig, legend, fig.axes) == []


def test_animation_names_the_robot_and_takes_a_title(gait3, tmp_path, monkeypatch):
    """The animation's title was the controller alone: neither the robot nor, in the
    reproduction, which design of the study was walking."""
    from analysis.reporting.plots import walking
    from biped_casadi import Design, SimulationOptions, perturbed_initial_state, simulate
    made, real = [], walking._figure              # keep the figures the animation draws on
    monkeypatch.setattr(walking, "_figure", lambda **kw: made.append(real(**kw)) or made[-1])
    run = simulate(Design.vc(gait3).controller_for(), *perturbed_initial_state(gait3, 0.01, 0.1),
                   options=SimulationOptions(steps=1))
    walking.walking_animation(run, gait3.model, tmp_path / "a.gif", fps=5)
    walking.walking_animation(run, gait3.model, tmp_path / "b.gif", fps=5, title="the design")
    assert made[0].axes[0].get_title() == f"three_link, virtual constraints: {run.status}"
    assert made[1].axes[0].get_title() == "the design"


def test_cli_simulate_fig5_names_the_robot(gait3, tmp_path, capsys, monkeypatch):
    from analysis.cli import main as biped_main
    from analysis.cli import simulate as cli
    made, real = [], cli.unactuated_error_plot
    monkeypatch.setattr(cli, "unactuated_error_plot",
                        lambda *a, **kw: made.append(real(*a, **kw)) or made[-1])
    path = gait3.save(tmp_path / "gait.json")
    assert biped_main(["simulate", "--gait", str(path), "--controller", "vc", "--steps", "1",
                       "--plot", str(tmp_path / "fig")]) == 0
    capsys.readouterr()
    (title,) = [t.get_text() for t in made[0].texts]
    assert title.startswith("Fig. 5") and title.endswith("(three_link)")
