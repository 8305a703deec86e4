"""The figure of the N^nu grid of M1 (``biped sweep --grid N --plot DIR``): the plane of the
three-link biped (nu = 2), the pairs figure of RABBIT (nu = 4), sweeps without a stable
point or without any value, and the command line (also from a stored, resumed folder)."""
from __future__ import annotations

import json
from itertools import combinations
from pathlib import Path

import numpy as np
import pytest

from analysis.cli import main as biped_main
from analysis.reporting.plots import grid_sweep_plot
from analysis.reporting.plots.grid import grid_cells
from analysis.sweeps import grid_points, line_points, run_sweep
from analysis.sweeps.results import _result


@pytest.fixture(scope="module")
def sweep2(gait3):
    """The three-link biped's 5^2 grid on [-10, 10]."""
    return run_sweep(gait3, grid_points(5, -10, 10, 2), progress=False)


@pytest.fixture(scope="module")
def sweep4(gait):
    """RABBIT's 3^4 grid on [-5, 5] (stable and unstable points)."""
    return run_sweep(gait, grid_points(3, -5, 5, 4), progress=False)


def _stars(fig):
    """(x, y) of the best point's star in each panel that has one."""
    return [tuple(line.get_xydata()[0]) for ax in fig.axes for line in ax.get_lines()
            if line.get_gid() == "best"]


def _title(fig):
    return fig._suptitle.get_text()


def _replace(sweep, status, max_abs):
    return _result(sweep.points, np.asarray(status, "<U10"), np.asarray(max_abs, float),
                   sweep.eigenvalues, sweep.A, elapsed=0.0, chunk_size=sweep.chunk_size,
                   settings=sweep.settings)


def test_plane_of_two_components_marks_the_best(sweep2, gait3):
    assert sweep2.counts["stable"] > 0 and sweep2.counts["unstable"] > 0
    fig = grid_sweep_plot(sweep2, gait3)
    b = sweep2.best()
    assert _stars(fig) == [tuple(b.M1)]
    ax = fig.axes[0]
    assert ax.get_xlabel().startswith("$M_1(1)$") and ax.get_ylabel().startswith("$M_1(2)$")
    assert f"{b.max_abs:.3g}" in " ".join(t.get_text() for t in ax.texts)   # labelled
    title = _title(fig)
    assert "$5^{2}$ grid" in title and f"{sweep2.counts['stable']} of 25 points stable" in title
    assert "log scale" in fig.axes[-1].get_ylabel()                           # colour bar
    assert ax.collections                                 # cells and the |lambda| = 1 edges
    fig.canvas.draw()


def test_pairs_figure_of_four_components(sweep4, gait):
    fig = grid_sweep_plot(sweep4, gait)
    b = sweep4.best()
    stars = _stars(fig)
    assert sorted(stars) == sorted((b.M1[i], b.M1[j]) for i, j in combinations(range(4), 2))
    # each panel's cell holds the smallest max|lambda| over the other two components, and
    # the best point's cell holds the sweep's best
    P, mx = sweep4.points, sweep4.max_abs
    for i, j in combinations(range(4), 2):
        xv, yv, B, NS, per_cell, other = grid_cells(sweep4, i, j)
        assert per_cell == 9 and B.shape == (3, 3)
        a, c = np.searchsorted(xv, b.M1[i]), np.searchsorted(yv, b.M1[j])
        assert B[a, c] == b.max_abs
        for a, x in enumerate(xv):
            for c, y in enumerate(yv):
                cell = (P[:, i] == x) & (P[:, j] == y)
                ok = cell & np.isin(sweep4.point_status, ("stable", "unstable"))
                assert B[a, c] == (mx[ok].min() if ok.any() else np.inf)
                assert NS[a, c] == np.count_nonzero(cell & (sweep4.point_status == "stable"))
    assert "smallest max|λ|" in fig.axes[-1].get_ylabel()
    assert f"{sweep4.counts['stable']} of 81 points stable" in _title(fig)
    fig.canvas.draw()


def test_no_stable_point_and_no_value_still_draw(sweep2, sweep4):
    for s in (sweep2, sweep4):
        fin = np.isfinite(s.max_abs)
        unstable = _replace(s, np.where(s.point_status == "stable", "unstable",
                                        s.point_status),
                            np.where(fin, s.max_abs + 1.0, s.max_abs))
        fig = grid_sweep_plot(unstable)
        nu = s.points.shape[1]
        assert "NO STABLE POINT" in _title(fig)
        b = unstable.best()
        assert b.status == "unstable"
        assert sorted(_stars(fig)) == sorted((b.M1[i], b.M1[j])
                                             for i, j in combinations(range(nu), 2))
        fig.canvas.draw()
        singular = _replace(s, ["singular"] * s.n_points, np.full(s.n_points, np.inf))
        fig = grid_sweep_plot(singular)
        assert "every one of the" in _title(fig) and "singular" in _title(fig)
        assert _stars(fig) == []
        fig.canvas.draw()


def test_points_that_are_not_a_grid_are_refused(sweep4):
    line = sweep4.subset(np.arange(10))
    with pytest.raises(ValueError, match="not a full grid"):
        grid_sweep_plot(line)
    assert line_points(0, [0.0, 1.0]).shape == (2, 4)


@pytest.fixture(scope="module")
def gait_files(gait, gait3, tmp_path_factory):
    d = tmp_path_factory.mktemp("gaits")
    return gait.save(d / "rabbit.json"), gait3.save(d / "three_link.json")


def test_cli_grid_plot_writes_the_figure(gait_files, tmp_path, capsys):
    rabbit, three_link = gait_files
    out, figs = tmp_path / "sweep", tmp_path / "figs"
    # a stored sweep first, then the figure from the resumed folder
    assert biped_main(["sweep", "--gait", str(rabbit), "--grid", "3", "--range", "-5", "5",
                       "--out", str(out), "--json", "--no-progress"]) == 0
    assert "plots" not in json.loads(capsys.readouterr().out)
    assert biped_main(["sweep", "--gait", str(rabbit), "--grid", "3", "--range", "-5", "5",
                       "--out", str(out), "--plot", str(figs), "--json",
                       "--no-progress"]) == 0
    body = json.loads(capsys.readouterr().out)
    assert body["computed_points"] == 0
    assert body["plots"] == [str(figs / "m1_grid_3x3x3x3.png"),
                             str(figs / "m1_grid_3x3x3x3.pdf")]
    assert all(Path(p).stat().st_size > 0 for p in body["plots"])
    # the plane of the three-link biped, human output
    assert biped_main(["sweep", "--gait", str(three_link), "--grid", "5", "--plot",
                       str(figs), "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert f"figure: {figs / 'm1_grid_5x5.png'}" in text
    assert (figs / "m1_grid_5x5.pdf").is_file()
