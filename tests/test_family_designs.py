"""Designs over a gait family: the M1 schedule (fit, evaluation, file), the command's
refusals, and (slow) the designs over a two-speed family end to end."""
from __future__ import annotations

import json

import numpy as np
import pytest

from analysis.cli import main
from analysis.design.family import SCHEDULE_FORMAT, M1Schedule


def test_schedule_fits_and_evaluates_its_polynomials(tmp_path):
    v = np.array([0.5, 0.6, 0.7, 0.8, 0.9])
    M = np.c_[1 + v, 2 - v ** 2, 0 * v + 3, v ** 3]        # two exact in degree 2
    s = M1Schedule.fit(v, M, rejoin=0.75, degree=2)
    assert s.degree == 2 and len(s.coefficients) == 4
    np.testing.assert_allclose(s.M1(0.65)[:3], [1.65, 2 - 0.65 ** 2, 3.0], atol=1e-12)
    # the cubic component is the least-squares quadratic: close, not exact
    assert 0 < abs(s.M1(0.65)[3] - 0.65 ** 3) < 1e-2
    with pytest.raises(ValueError, match="outside the schedule"):
        s.M1(1.2)
    body = json.loads(s.save(tmp_path / "s.json").read_text())
    assert body["format"] == SCHEDULE_FORMAT and body["rejoin"] == 0.75
    np.testing.assert_allclose(body["M1"], [s.M1(x) for x in v])
    two = M1Schedule.fit(v[:2], M[:2], rejoin=0.5)           # degree at most n - 1
    assert two.degree == 1


def test_family_options_are_refused_elsewhere(capsys, tmp_path, gait):
    path = gait.save(tmp_path / "g.json")
    for argv, msg in ((["m1", "--robust", "--gait", str(path), "--out", "s.json"],
                       "gait family"),
                      (["m1", "--plot", str(tmp_path)], "applies to --robust")):
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
    sched = json.loads(out.read_text())
    np.testing.assert_allclose(sched["M1"], [rec["codesign"]["M1"] for rec in r["records"]],
                               rtol=1e-9)
    assert (figs / "family_designs.png").stat().st_size > 10_000
