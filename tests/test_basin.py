"""Basins on windows that contain their boundary: the window grows until no cell on its
edges converges (or stops at a cap, and says so), the area is the converged cells times
the cell area, the section holds no state where a point of the robot is under the
ground, the fixed window computes what its walker computes, and the figure draws each
basin on its own window."""
from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from analysis.reporting.plots import basin_plot
from analysis.robustness import Design, basin, basin_to_boundary, edge_cells, section_cap
from analysis.robustness.basin_window import NO_STATE
from analysis.tasks import argument_key
from biped_casadi import SimulationOptions
from biped_casadi.control.output_law import SECTION
from biped_casadi.simulation import virtual_constraint_walker, zero_dynamics_walker

M1 = (-10.0, 7.5, 10.0, -5.0)
N = 21                                      # cells per axis: every test's grids


@pytest.fixture(scope="module")
def auto_vc(gait):
    return basin_to_boundary(Design.vc(gait), n=N)


@pytest.fixture(scope="module")
def auto_tv(gait):
    return basin_to_boundary(Design.tv(gait, M1, 0.5), n=N)


def _converged_on_edges(b):
    c = b.outcome == "converged"
    return int(c[0].sum() + c[-1].sum() + c[:, 0].sum() + c[:, -1].sum())


@pytest.mark.parametrize("which", ["auto_vc", "auto_tv"])
def test_the_window_contains_the_boundary(which, request):
    b = request.getfixturevalue(which)
    assert b.status == "contained" and b.success, b.message
    assert _converged_on_edges(b) == 0
    assert np.sum(b.outcome == "converged") > 0            # a basin, not an empty window
    assert b.outcome.shape == (N, N)
    assert np.isclose(b.q_u[-1], b.q_span) and np.isclose(b.dq_u[-1], b.dq_span)
    assert b.q_span <= max(0.05, b.cap["q_span"]) + 1e-12
    assert b.dq_span <= max(0.5, b.cap["dq_span"]) + 1e-12
    assert b.windows[0]["q_span"] == 0.05 and b.windows[0]["dq_span"] == 0.5
    assert "contains the basin's boundary" in b.message


def test_virtual_constraints_needed_a_larger_window(gait, auto_vc):
    # on the fixed window the basin reaches its edges; the window grew until it did not
    first = auto_vc.windows[0]
    fixed = basin(Design.vc(gait), n=N, refine=4)
    assert sum(first["edges"].values()) > 0 and sum(edge_cells(fixed).values()) > 0
    assert first["probe"] and first["area"] is None     # its edges alone were walked
    assert auto_vc.q_span > 0.05 and auto_vc.dq_span > 0.5
    assert auto_vc.area > fixed.area


def test_the_edges_walked_alone_are_the_whole_basins(gait, auto_vc):
    """A window whose edges decide its growth walks only them (at most 4 (n - 1) cells):
    the converged cells on each edge are those of the whole basin walked cell by cell
    on that window (refine=None), with the rows that hold no state of the robot out."""
    from analysis.robustness.basin_window import _mask
    d = Design.vc(gait)
    offsets = section_cap(d)["q_offsets"]
    probes = [w for w in auto_vc.windows if w.get("probe")]
    assert probes
    for w in probes:
        full = _mask(basin(d, n=N, q_span=w["q_span"], dq_span=w["dq_span"]), offsets)
        assert w["edges"] == edge_cells(full)
        assert 0 < w["walked_cells"] <= 4 * (N - 1)


def test_area_is_the_cell_count_times_the_cell_area(gait, auto_vc, auto_tv):
    fixed = basin(Design.tv(gait, M1, 0.5), n=N, refine=4)
    for b in (fixed, auto_vc, auto_tv):
        cell = np.diff(b.q_u[:2])[0] * np.diff(b.dq_u[:2])[0]
        count = int(np.sum(b.outcome == "converged"))
        assert b.cell_area == pytest.approx(cell, rel=1e-12)
        assert b.area == pytest.approx(count * cell, rel=1e-12)
        assert b.window_area == pytest.approx(N * N * cell, rel=1e-12)
        assert b.converged_fraction * b.window_area == pytest.approx(b.area, rel=1e-12)
        d = b.to_dict()
        for k in ("area", "cell_area", "window_area", "q_span", "dq_span"):
            assert d[k] == getattr(b, k)
        json.dumps(d)                                    # plain JSON types
    assert auto_tv.to_dict()["windows"] and auto_tv.to_dict()["cap"]["reason"]


def test_fixed_window_is_the_walkers_outcome(gait):
    """The fixed window walks each cell (q_u* + a, dq_u* + b) with the walker and keeps its
    verdict: the same outcomes, cell by cell, as walking the grid here."""
    n, qs, dqs, steps = 5, 0.02, 0.2, 4
    xs = gait.state_at(SECTION * gait.T)
    a, b = np.linspace(-qs, qs, n), np.linspace(-dqs, dqs, n)
    A, B = np.meshgrid(a, b, indexing="ij")
    X = np.c_[xs[0] + A.ravel(), xs[1] + B.ravel()]
    opts = SimulationOptions()
    runs = {"tv": zero_dynamics_walker(gait, opts, 128, jit=True).walk_from_section(
                X, np.array(M1), 0.5, steps),
            "vc": virtual_constraint_walker(gait, opts, 100, jit=True).walk_from_section(
                X, steps)}
    for d in (Design.tv(gait, M1, 0.5), Design.vc(gait)):
        r = basin(d, n=n, q_span=qs, dq_span=dqs, steps=steps)
        w = runs[d.controller]
        e = w.final_error
        want = np.where(w.ok, np.where(e < 1e-3, "converged", "walked"), w.status)
        np.testing.assert_array_equal(r.outcome.ravel().astype(str), want.astype(str))
        np.testing.assert_array_equal(r.final_error.ravel(), e)
        assert r.status == "done" and r.windows == [] and r.cap is None


def test_the_last_window_is_the_fixed_basin_on_it(gait, auto_tv):
    """The kept window's basin is :func:`basin` on that window (its row also counts the
    edge cells walked before it)."""
    fixed = basin(Design.tv(gait, M1, 0.5), n=N, refine=4, q_span=auto_tv.q_span,
                  dq_span=auto_tv.dq_span)
    w = auto_tv.windows[-1]
    assert w["converged_fraction"] == fixed.converged_fraction == auto_tv.converged_fraction
    assert w["area"] == fixed.area == auto_tv.area
    np.testing.assert_array_equal(auto_tv.outcome, fixed.outcome)
    assert fixed.walked_cells <= w["walked_cells"] <= fixed.walked_cells + 4 * (N - 1)


def test_a_capped_window_says_so(gait):
    b = basin_to_boundary(Design.vc(gait), n=N, max_q_span=0.06, max_dq_span=0.6)
    assert b.status == "capped" and not b.success
    assert (b.q_span, b.dq_span) == (0.06, 0.6)
    assert _converged_on_edges(b) > 0
    assert "capped" in b.message and "lower bound" in b.message
    assert "max_q_span" in b.cap["reason"]


def test_section_cap_is_where_the_robot_meets_the_ground(gait):
    """Just inside the cap's offsets every point of the robot is above the ground at the
    section; at them, one is on or under it."""
    d = Design.tv(gait, M1, 0.5)
    cap = section_cap(d)
    q0 = np.asarray(gait.q(SECTION * gait.T), float).ravel()

    def lowest(delta):
        q = q0 + np.r_[delta, -np.asarray(M1) * delta]
        return float(np.min(np.array(gait.model.points(q))[1, 1:]))
    lo, hi = cap["q_offsets"]
    assert lo < 0 < hi
    assert lowest(lo) <= 0 and lowest(hi) <= 0
    assert lowest(lo + 2e-3) > 0 and lowest(hi - 2e-3) > 0
    assert cap["q_span"] == pytest.approx(max(-lo, hi))
    xs = gait.state_at(SECTION * gait.T)
    assert cap["dq_span"] >= xs[1]                          # down to the stance leg at rest
    r = np.linalg.norm(np.array(gait.model.com(q0)).ravel())
    assert cap["dq_lift"] == pytest.approx(np.sqrt(9.81 / r))


def test_rows_without_a_state_are_not_in_the_basin(gait, auto_vc):
    lo, hi = auto_vc.cap["q_offsets"]
    rows = (auto_vc.q_u <= lo) | (auto_vc.q_u >= hi)
    assert rows.any()               # the virtual constraints' window reaches the curve's end
    assert np.all(auto_vc.outcome[rows] == NO_STATE)
    assert np.all(auto_vc.outcome[~rows] != NO_STATE)
    assert auto_vc.counts[NO_STATE] == rows.sum() * N


def test_the_search_is_a_pure_task(gait, auto_tv):
    d = Design.tv(gait, M1, 0.5)
    assert basin_to_boundary.task_info.name.endswith("basin_to_boundary")
    assert argument_key([d, N]) == argument_key([Design.tv(gait, M1, 0.5), N])
    again = basin_to_boundary(d, n=N)
    np.testing.assert_array_equal(again.outcome, auto_tv.outcome)
    assert (again.q_span, again.dq_span, again.area) == (auto_tv.q_span, auto_tv.dq_span,
                                                         auto_tv.area)


def test_bad_arguments_name_themselves(gait):
    d = Design.vc(gait)
    for kw, name in ((dict(factor=1.0), "factor"), (dict(zoom=-1), "zoom"),
                     (dict(max_q_span=0.0), "max_q_span"), (dict(q_span=-1), "q_span")):
        with pytest.raises(ValueError, match=name):
            basin_to_boundary(d, n=N, **kw)


def test_edge_cells_counts_each_edge(auto_tv):
    o = np.full((N, N), "slipped", dtype=object)
    o[N // 2, N // 2] = "converged"                          # inside: on no edge
    o[0, 1:4] = "converged"                                  # the first row (q_u* - q_span)
    o[2:4, -1] = "converged"                                 # the last column
    o[-1, 0] = "converged"                                   # a corner: two edges
    e = edge_cells(dataclasses.replace(auto_tv, outcome=o))
    assert e == dict(q_low=3, q_high=1, dq_low=1, dq_high=2)


def test_the_figure_draws_each_basin_on_its_window(auto_vc, auto_tv):
    fig = basin_plot([auto_vc, auto_tv])
    axes = fig.axes[:2]
    for ax, b in zip(axes, (auto_vc, auto_tv)):
        da, db = np.diff(b.q_u[:2])[0] / 2, np.diff(b.dq_u[:2])[0] / 2
        assert ax.get_ylim() == pytest.approx((-b.q_span - da, b.q_span + da))
        assert ax.get_xlim() == pytest.approx((-b.dq_span - db, b.dq_span + db))
        assert f"area {b.area:.3g} rad x rad/s" in ax.get_title()
    assert axes[0].get_ylim() != axes[1].get_ylim()           # not shared
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert "converged" in labels and "basin boundary" in labels
    assert any(t.startswith("fixed window") for t in labels)


def test_the_figure_names_each_panel_and_keeps_its_design(auto_vc, auto_tv):
    """The reproduction's robust basins showed two panels titled 'time-varying, M1 = [...]'
    only: which was the co-design and which the sampling search's design was left to the
    order of the words in the figure's title."""
    fig = basin_plot([auto_vc, auto_tv], labels=["virtual constraints", "the co-design"])
    vc, tv = (ax.get_title().splitlines() for ax in fig.axes[:2])
    assert vc[0] == "virtual constraints" and vc.count("virtual constraints") == 1
    assert tv[0] == "the co-design" and tv[1].startswith("time-varying, M1 = [")


@pytest.mark.slow
def test_the_robust_designs_compare_on_windows_that_contain_their_boundary():
    """The co-design of `biped m1 --robust` and virtual constraints on its gait converge
    from (almost) all of the fixed window, which shows no boundary; to their boundaries
    both are contained and their areas are larger than the fixed window's."""
    from analysis.design.codesign import FULL, codesign
    from biped_casadi import rabbit
    r = codesign(rabbit(), FULL, workers=1)
    for d in (r.design, Design.vc(r.design.gait)):
        fixed = basin(d, n=41, refine=4)
        auto = basin_to_boundary(d, n=41)
        assert fixed.converged_fraction > 0.95 and _converged_on_edges(fixed) > 0
        assert auto.status == "contained", auto.message
        assert _converged_on_edges(auto) == 0
        assert auto.area > fixed.area and auto.converged_fraction < 0.5


def test_a_window_without_a_converged_cell_is_empty_not_contained(gait):
    # one step and a tolerance no error meets: no cell converges, not even the fixed point
    b = basin_to_boundary(Design.vc(gait), n=5, steps=1, tol=1e-300)
    assert not (b.outcome == "converged").any()
    assert b.status == "empty" and b.success and b.area == 0
    assert b.message.startswith("empty: none of the 5x5 cells") and "contains" not in b.message


def test_a_grid_the_adaptive_refinement_cannot_fill_says_which_sizes_fit():
    from analysis.robustness.basin import _adaptive
    with pytest.raises(ValueError, match=r"^refine = 4 must divide n - 1 = 10: take n = 9 or "
                                         r"13, another refine, or refine=None"):
        _adaptive(None, 11, 4)
    with pytest.raises(ValueError, match=r"refine = 4 must divide n - 1 = 2: take n = 5 or 9"):
        _adaptive(None, 3, 4)
    with pytest.raises(ValueError, match="refine must be an integer >= 2"):
        _adaptive(None, 11, 1)


def test_a_reference_window_taller_than_the_basin_leaves_no_empty_band(auto_vc):
    """A basin on a window narrower in q_u than the fixed window but wider in dq_u (the
    three-link biped's deadbeat M1) had its axes stretched to the fixed window: white
    bands above and below the cells."""
    qw, dw = auto_vc.q_span * 2, auto_vc.dq_span / 2
    fig = basin_plot(auto_vc, reference_window=(qw, dw))
    ax = fig.axes[0]
    da, db = np.diff(auto_vc.q_u[:2])[0] / 2, np.diff(auto_vc.dq_u[:2])[0] / 2
    assert ax.get_ylim() == pytest.approx((-auto_vc.q_span - da, auto_vc.q_span + da))
    assert ax.get_xlim() == pytest.approx((-auto_vc.dq_span - db, auto_vc.dq_span + db))
    assert any(t.startswith("fixed window")
               for t in (t.get_text() for t in fig.legends[0].get_texts()))
