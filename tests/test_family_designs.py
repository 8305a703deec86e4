"""Designs over a gait family: the M1 schedule (fit, evaluation, file), the command's
refusals, and (slow) the designs over a two-speed family end to end."""
from __future__ import annotations

import json

import numpy as np
import pytest

from analysis.cli import main
from analysis.design.designs_over_speed import smooth_schedule
from analysis.design.schedule import M1Schedule


def test_the_smooth_schedule_samples_its_polynomials(tmp_path):
    v = np.array([0.5, 0.6, 0.7, 0.8, 0.9])
    M = np.c_[1 + v, 2 - v ** 2, 0 * v + 3, v ** 3]        # three exact in degree 2
    s, coef, degree = smooth_schedule(v, M, rejoin=0.75, degree=2)
    assert degree == 2 and len(coef) == 4
    np.testing.assert_allclose(np.asarray(s.M1)[:, :3], M[:, :3], atol=1e-12)
    # the cubic component is the least-squares quadratic: close, not exact
    err = np.abs(np.asarray(s.M1)[:, 3] - M[:, 3])
    assert 0 < err.max() < 1e-2
    assert s.at(0.65)[1] == 0.75 and s.rejoin == (0.75,) * 5
    back = M1Schedule.load(s.save(tmp_path / "s.json"))
    np.testing.assert_allclose(back.at(0.65)[0], s.at(0.65)[0])
    assert smooth_schedule(v[:2], M[:2], rejoin=0.5)[2] == 1    # degree at most n - 1


def test_family_options_are_refused_elsewhere(capsys, tmp_path):
    # `m1 --robust --gait GAIT --out FILE` with a single gait writes the design's gait
    # (no longer refused: tests/test_codesign.py); --plot without --robust still is
    for argv, msg in ((["m1", "--plot", str(tmp_path)], "applies to --robust"),):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert msg in err and len(err.strip().splitlines()) == 1


@pytest.mark.slow
def test_designs_over_a_family(model, tmp_path, capsys):
    """Two speeds of the robust gait's family: the co-design at each, the schedule
    through them (so equal to them there), one M1 for all, virtual constraints, and the
    figure and schedule file of the command."""
    from analysis.design import ROBUST_GAIT
    from gait_opt import GaitOptions, gait_family
    fam = gait_family(model, [0.7, 0.8], GaitOptions(**ROBUST_GAIT))
    fam.save(tmp_path / "fam.json")
    out, figs = tmp_path / "schedule.json", tmp_path / "figs"
    assert main(["m1", "--robust", "--gait", str(tmp_path / "fam.json"), "--out", str(out),
                 "--plot", str(figs), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    assert [round(x, 9) for x in r["speeds"]] == [0.7, 0.8]
    for rec in r["records"]:
        d = rec["designs"]
        assert set(d) == {"co-design at each speed", "M1 scheduled over speed",
                          "one M1 for all speeds", "virtual constraints"}
        assert d["M1 scheduled over speed"]["s_star"] == d["co-design at each speed"]["s_star"]
        assert all(0 <= x["basin_fraction"] <= 1 and x["basin_area"] >= 0 for x in d.values())
    sched = M1Schedule.load(out)
    np.testing.assert_allclose([sched.at(rec["speed"])[0] for rec in r["records"]],
                               [rec["codesign"]["M1"] for rec in r["records"]], rtol=1e-9)
    assert (figs / "family_designs.png").stat().st_size > 10_000


def test_a_speed_without_a_deadbeat_m1_is_a_record(gait, monkeypatch):
    """At a family's fastest member the deadbeat NLP finds no non-singular start on group
    1 (RABBIT's default family at 1.2 m/s, whose torso leans past the fall bound), the
    co-design no start: that speed records why, the other speeds and the figure go on;
    other errors still stop."""
    from analysis.design import designs_over_speed as dos
    from analysis.reporting.plots import family_designs_plot
    from analysis.tasks import Engine, TaskError

    def refuse(g, group=None, n_random=0):
        raise ValueError(f"no non-singular start found on group {group}")
    monkeypatch.setattr(dos, "optimize_m1", refuse)
    with Engine("synchronous", cache=False) as eng:
        rec = dos._deadbeat(eng.submit(dos.deadbeat_m1, gait, 1))
    assert rec == dict(status="failed", message="no non-singular start found on group 1")

    from analysis.design.codesign import CodesignError

    def no_start(g, group=None, n_random=0):     # the co-design's refusal of a gait
        raise CodesignError("codesign: no start for the NLP")
    monkeypatch.setattr(dos, "optimize_m1", no_start)
    with Engine("synchronous", cache=False) as eng:
        err = dos._refused(eng.submit(dos.deadbeat_m1, gait, 1))
    assert isinstance(err, TaskError) and dos._failed(err) == dict(
        status="failed", message="codesign: no start for the NLP")

    def broken(g, group=None, n_random=0):
        raise RuntimeError("a bug")
    monkeypatch.setattr(dos, "optimize_m1", broken)
    with Engine("synchronous", cache=False) as eng, pytest.raises(TaskError, match="a bug"):
        dos._deadbeat(eng.submit(dos.deadbeat_m1, gait, 1))

    class Designs:               # two speeds, the second without a deadbeat M1
        records = [dict(speed=v, designs={"virtual constraints": dict(max_abs=0.5,
                                                                       s_star=0.6)},
                        deadbeat=d) for v, d in ((0.7, dict(M1=[0, 0, 0, 0], max_abs=1e-5)),
                                                 (1.2, rec))]
    fig = family_designs_plot(Designs())
    (line,) = [ln for ln in fig.axes[0].lines if ln.get_label().startswith("deadbeat")]
    assert list(line.get_xdata()) == [0.7]
