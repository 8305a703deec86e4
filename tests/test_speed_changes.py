"""Speed changes: a profile of one design per step walked in full order (the gait
switched at the impacts), on the walkers, the schedule of designs over a gait family,
the study's functions, the figures and ``biped simulate --speeds``.

Fast tests use a family of three gaits (0.7, 0.75, 0.8 m/s) on the robust co-design's
gait options; the slow ones make the study's family (0.45 to 1.05 m/s) and walk the ramp
of issue 33 (0.5 -> 1.0 -> 0.5 m/s by 0.05 per step)."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from analysis.cli import main as biped_main
from analysis.design import ROBUST_GAIT
from analysis.design.schedule import (M1Schedule, check_profile, profile_designs,
                                      profile_gaits, ramp_speeds)
from analysis.reporting.plots import speed_jumps_plot, speed_profile_plot
from analysis.robustness.speed import (schedule_eigenvalues, speed_change, speed_jumps,
                                       speed_ramp)
from biped_casadi import Design, SimulationOptions, simulate
from biped_casadi.simulation import simulate_profile, walk_profile
from biped_casadi.simulation.options import friction_of
from gait_opt import GaitFamily, GaitOptions, gait_family, speed_range

SPEEDS = (0.7, 0.75, 0.8)
#: the robust co-design's M1 on its own 0.75 m/s gait (stable on these three gaits)
M1 = (0.32978, -0.07573, 0.63068, -0.39785)
OPTS = SimulationOptions(mu=0.6, torque_limit=150.0)


@pytest.fixture(scope="module")
def family_path(model, tmp_path_factory):
    path = tmp_path_factory.mktemp("speed") / "family.json"
    gait_family(model, SPEEDS, GaitOptions(**ROBUST_GAIT), path=path)
    return path


@pytest.fixture(scope="module")
def family(family_path, model):
    return GaitFamily.load(family_path, model)


def _tv(family, v):
    return Design.tv(family.gait(v), M1, 0.75)


# ------------------------------------------------------------- the full-order profile
@pytest.mark.parametrize("kind", ["tv", "vc"])
def test_constant_profile_is_the_simulators_run(family, kind):
    g = family.gait(0.75)
    d = _tv(family, 0.75) if kind == "tv" else Design.vc(g)
    q0, dq0 = g.q(0.0) + 0.01, g.dq(0.0) + 0.1
    one = simulate(d, q0, dq0, SimulationOptions(steps=5))
    prof = simulate_profile([d] * 5, q0, dq0)
    assert prof.status == one.status == "ok"
    for name in ("qu_error", "dqu_error", "duration"):
        np.testing.assert_allclose(getattr(prof, name), getattr(one, name), rtol=0, atol=1e-13)
    for name in ("peak_torque", "min_normal_force", "max_friction_ratio", "max_impulse_ratio"):
        assert getattr(prof, name) == pytest.approx(getattr(one, name), abs=1e-12)
    assert len(prof.segments) == 1 and prof.segments[0].n_steps == 5


@pytest.mark.parametrize("kind", ["tv", "vc"])
def test_the_step_after_a_switch_runs_on_the_new_gait(model, family, kind):
    """Each step's reference is its own gait: its outputs start at zero (v_c from y_i,
    dy_i against the new gait; virtual constraints' phase correction), its errors are
    against the new orbit, and it starts where the last impact left the robot."""
    sp = (0.7, 0.75, 0.8, 0.75)
    ds = [(_tv(family, v) if kind == "tv" else Design.vc(family.gait(v))) for v in sp]
    r = simulate_profile(ds, options=OPTS)
    assert r.ok and r.speeds == pytest.approx(sp, abs=1e-9)
    for k, (run, step) in enumerate(zip(r.runs, r.steps)):
        g = family.gait(sp[k])
        assert run.reference["T"] == g.T and step.speed == pytest.approx(sp[k], abs=1e-9)
        assert np.max(np.abs(run.y[0])) < 1e-9 and np.max(np.abs(run.dy[0])) < 1e-8
        rec = run.steps[0]
        assert step.qu_error == pytest.approx(rec.q_minus[0] - g.q(g.T)[0], abs=1e-14)
        assert step.dqu_error == pytest.approx(rec.dq_minus[0] - g.dq(g.T)[0], abs=1e-13)
        qp, dqp = (np.array(v).ravel() for v in model.impact(rec.q_minus, rec.dq_minus))
        np.testing.assert_allclose(step.q_plus, qp, atol=1e-12)
        np.testing.assert_allclose(step.dq_plus, dqp, atol=1e-12)
        if k:
            np.testing.assert_array_equal(run.q[0], r.steps[k - 1].q_plus)
            np.testing.assert_array_equal(run.dq[0], r.steps[k - 1].dq_plus)
    assert r.errors()[0] < 1e-8 and r.errors()[1] > 1e-3     # on the orbit, then switched
    assert r.peak_torque == max(s.peak_torque for s in r.steps)
    assert r.friction_margin == pytest.approx(
        0.6 - max(max(s.max_friction_ratio, s.max_impulse_ratio) for s in r.steps))


def test_a_profile_stops_at_its_first_invalid_state(family):
    sp = (0.7, 0.8, 0.8, 0.8)
    ds = [_tv(family, v) for v in sp]
    free = simulate_profile(ds, options=OPTS)
    assert free.ok
    limit = 0.5 * (free.steps[0].peak_torque + free.steps[1].peak_torque)
    assert free.steps[1].peak_torque > free.steps[0].peak_torque   # the switch costs torque
    r = simulate_profile(ds, options=SimulationOptions(torque_limit=limit))
    assert r.status == "torque_limit" and r.fail_step == 1 and len(r.steps) == 2
    assert r.steps[0].status == "ok" and r.steps[1].status == "torque_limit"
    assert r.message.startswith("step 2:") and np.all(np.isnan(r.qu_error[1:]))  # 1-based
    assert r.steps[1].peak_torque > limit and r.steps[1].q_plus is None
    assert math.isnan(r.segments[1].steps_to_converge) and r.segments[1].walked == 0


def test_segments_count_the_steps_to_converge(family):
    ds = [_tv(family, 0.7)] + [_tv(family, 0.75)] * 9
    r = simulate_profile(ds, options=OPTS, tol=1e-2)
    assert r.ok and [s.n_steps for s in r.segments] == [1, 9]
    e = r.errors()[1:]
    k = next(i for i in range(e.size) if np.all(e[i:] < 1e-2)) + 1
    assert r.segments[1].steps_to_converge == k and 1 < k < 9
    assert math.isnan(simulate_profile(ds, options=OPTS, tol=1e-9).segments[1]
                      .steps_to_converge)
    assert r.segments[1].first_error == e[0] and r.segments[1].final_error == e[-1]


def test_profile_input_errors(family, gait):
    with pytest.raises(ValueError, match="designs: the profile is empty"):
        simulate_profile([])
    with pytest.raises(ValueError, match=r"designs\[1\]: expected a Design"):
        simulate_profile([_tv(family, 0.7), "x"])
    with pytest.raises(ValueError, match="designs: expected a sequence"):
        simulate_profile(_tv(family, 0.7))
    with pytest.raises(ValueError, match="tol"):
        simulate_profile([_tv(family, 0.7)], tol=0)


# ------------------------------------------------------------------------- walkers
def test_walkers_walk_the_profile_as_the_full_order_simulator(family):
    sp = (0.75, 0.8, 0.7, 0.7)
    for ds, tol in (([_tv(family, v) for v in sp], 1e-7),
                    ([Design.vc(family.gait(v)) for v in sp], 1e-6)):
        g = ds[0].gait
        q0 = np.vstack([g.q(0.0), g.q(0.0) + 0.005])
        dq0 = np.vstack([g.dq(0.0), g.dq(0.0) + 0.05])
        b = walk_profile(ds, q0, dq0, OPTS)
        for i in range(2):
            full = simulate_profile(ds, q0[i], dq0[i], OPTS)
            assert b.status[i] == full.status == "ok"
            np.testing.assert_allclose(b.qu_error[i], full.qu_error, atol=tol)
            np.testing.assert_allclose(b.dqu_error[i], full.dqu_error, atol=10 * tol)
            assert b.peak_torque[i] == pytest.approx(full.peak_torque, abs=1e-3)


def test_walkers_stop_where_the_full_order_does(family):
    ds = [_tv(family, v) for v in (0.7, 0.8, 0.8)]
    free = simulate_profile(ds, options=OPTS)
    opts = SimulationOptions(torque_limit=0.5 * (free.steps[0].peak_torque
                                                 + free.steps[1].peak_torque))
    b = walk_profile(ds, options=opts)
    assert b.status[0] == "torque_limit" and b.fail_step[0] == 1
    assert np.isfinite(b.qu_error[0, 0]) and np.all(np.isnan(b.qu_error[0, 1:]))


# ------------------------------------------------------------------ speeds, schedules
def test_ramp_and_profile_speeds():
    np.testing.assert_allclose(ramp_speeds(0.5, 0.6, 0.05, hold=2),
                               [0.5, 0.55, 0.6, 0.55, 0.5, 0.5, 0.5])
    assert ramp_speeds(0.5, 1.0, 0.05).size == 21
    for args, words in (((0.6, 0.5, 0.05), "reversed"), ((0.5, 0.5, 0.05), "empty"),
                        ((0.5, math.nan, 0.05), "finite"), ((0.5, 0.6, 0.07), "whole")):
        with pytest.raises(ValueError, match=words):
            ramp_speeds(*args)
    np.testing.assert_allclose(check_profile([0.7, 0.8], hold=1), [0.7, 0.8, 0.8])
    for bad, words in (([], "empty"), ([0.7, math.inf], "finite"), ([0.7, -0.1], "positive")):
        with pytest.raises(ValueError, match=words):
            check_profile(bad)


def test_profile_gaits_from_the_family(family):
    gaits, src = profile_gaits(family, [0.7, 0.725, 0.7, 0.8])
    assert gaits[0] is family.gait(0.7) and gaits[2] is gaits[0]
    assert gaits[3] is family.gait(0.8)
    assert gaits[1].speed == pytest.approx(0.725, abs=1e-9)
    assert gaits[1].orbit_residual()["worst"] < 1e-8
    assert [s.source for s in src] == ["member", "interpolated", "member"]
    assert src[1].interpolant_residual > src[1].orbit_residual
    with pytest.raises(ValueError, match="speeds: 0.85 m/s is outside the family"):
        profile_gaits(family, [0.7, 0.85])


def test_schedule_interpolates_linearly_in_speed(tmp_path):
    s = M1Schedule((0.5, 1.0), ((0.0, 1.0, 2.0, 3.0), (1.0, 3.0, 2.0, -1.0)), (0.5, 0.75))
    M, r = s.at(0.625)
    np.testing.assert_allclose(M, [0.25, 1.5, 2.0, 2.0])
    assert r == pytest.approx(0.5625)
    np.testing.assert_allclose(s.at(1.0)[0], s.M1[1])
    with pytest.raises(ValueError, match="speed: 1.1 m/s is outside the schedule"):
        s.at(1.1)
    c = M1Schedule.constant(M1, 0.75)
    np.testing.assert_allclose(c.at(0.3)[0], M1) and c.at(2.0)[1] == 0.75
    path = s.save(tmp_path / "s.json")
    assert M1Schedule.load(path) == s
    (tmp_path / "b.json").write_text(json.dumps({"rejoin": 0.6, "points": [
        {"speed": 0.8, "M1": [1, 2, 3, 4]}, {"speed": 0.6, "M1": [0, 0, 0, 0],
                                             "rejoin": 0.4}]}))
    b = M1Schedule.load(tmp_path / "b.json")
    assert b.speeds == (0.6, 0.8) and b.rejoin == (0.4, 0.6)


@pytest.mark.parametrize("body, words", [
    ("[1, 2]", "expected a JSON object"),
    ('{"points": []}', "non-empty list"),
    ('{"points": [{"speed": 0.5}]}', "'M1'"),
    ('{"points": [{"speed": 0.5, "M1": [1, 2]}, {"speed": 0.5, "M1": [1, 2]}]}',
     "strictly increasing"),
    ('{"points": [{"speed": 0.5, "M1": [1, 2]}, {"speed": 0.6, "M1": [1]}]}', "one length"),
    ('{"points": [{"speed": 0.5, "M1": [1, 2], "rejoin": 0.9}]}', "rejoin"),
    ('{"format": "other", "points": []}', "format"),
    ("not json", "not valid JSON"),
])
def test_bad_schedule_files(tmp_path, body, words):
    (tmp_path / "s.json").write_text(body)
    with pytest.raises(ValueError, match=words):
        M1Schedule.load(tmp_path / "s.json")


def test_profile_designs(family):
    gaits, _ = profile_gaits(family, [0.7, 0.75, 0.75])
    s = M1Schedule((0.7, 0.8), (M1, tuple(2 * np.array(M1))), (0.75, 0.75))
    ds = profile_designs(gaits, "tv", s, speeds=[0.7, 0.75, 0.75])
    assert ds[1] is ds[2] and ds[0].gait is gaits[0]
    np.testing.assert_allclose(ds[1].M1, 1.5 * np.array(M1))
    assert all(d.controller == "vc" for d in profile_designs(gaits, "vc"))
    with pytest.raises(ValueError, match="schedule"):
        profile_designs(gaits, "tv")
    with pytest.raises(ValueError, match="controller"):
        profile_designs(gaits, "xx", s)


# --------------------------------------------------------------------- the study
def test_speed_change_is_deterministic_and_survives_a_neighbour(family):
    a = speed_change(_tv(family, 0.7), _tv(family, 0.75), OPTS)
    b = speed_change(_tv(family, 0.7), _tv(family, 0.75), OPTS)
    assert a == b
    assert a.success and a.valid and a.dv == pytest.approx(0.05, abs=1e-9)
    assert len(a.errors) == 12 and a.switch_error == a.errors[1] > 1e-3
    assert a.final_error == a.errors[-1] < 1e-3
    assert 1 < a.steps_to_converge <= 11 and a.fail_step == -1
    tight = speed_change(_tv(family, 0.7), _tv(family, 0.8), OPTS.__class__(
        torque_limit=a.peak_torque * 0.6))
    assert not tight.success and tight.status == "torque_limit" and not tight.valid


def test_speed_jumps_bracket_the_largest_change(family):
    j = speed_jumps(family, "vc", None, OPTS, v1s=[0.75], refine=1)
    assert j.v1 == [0.75] and len(j.changes[0]) >= 2
    for dv, failed in ((j.up[0], j.up_failed[0]), (j.down[0], j.down_failed[0])):
        assert failed is None or abs(failed) > abs(dv)
    assert j.up[0] >= 0 >= j.down[0]
    survived = {round(c.dv, 9): c.success for c in j.changes[0]}
    if j.up[0] > 0:
        assert survived[round(j.up[0], 9)]
    if j.up_failed[0] is not None:
        assert not survived[round(j.up_failed[0], 9)]
    assert j.largest()[0] == max(j.up[0], -j.down[0])
    assert j.valid[0][0] >= j.up[0] and j.valid[0][1] <= j.down[0]   # survived => valid


def test_schedule_eigenvalues(family):
    rows = schedule_eigenvalues(family.gaits, M1Schedule.constant(M1, 0.75))
    assert [r["speed"] for r in rows] == pytest.approx(SPEEDS)
    assert all(r["status"] == "stable" and 0 < r["max_abs"] < 1 for r in rows)
    assert all(0 < r["vc_eigenvalue"] < 1 for r in rows)


def test_speed_figures(family, tmp_path):
    sp = (0.7, 0.75, 0.8)
    runs = {"tv": simulate_profile([_tv(family, v) for v in sp], options=OPTS),
            "vc": simulate_profile([Design.vc(family.gait(v)) for v in sp], options=OPTS)}
    fig = speed_profile_plot(runs)
    ax_v, ax_e = fig.axes[:2]
    assert "speed" in ax_v.get_ylabel() and ax_e.get_xlabel() == "step"
    assert ax_e.get_yscale() == "log"
    j = speed_jumps(family, "vc", None, OPTS, v1s=[0.75], refine=0)
    fig = speed_jumps_plot({"vc": j}, (0.7, 0.8))
    assert "v1" in fig.axes[0].get_xlabel() and "|dv|" in fig.axes[1].get_ylabel()


# ------------------------------------------------------------------ command line
def _run(capsys, *argv):
    rc = biped_main(["simulate", *argv])
    out, err = capsys.readouterr()
    return rc, out, err


def test_cli_speed_profile_figure_names_the_robot(capsys, tmp_path, family_path, monkeypatch):
    """The command's figure said neither the robot nor how many steps it walked."""
    from analysis.cli import simulate_profile as cli
    made, real = [], cli.speed_profile_plot
    monkeypatch.setattr(cli, "speed_profile_plot",
                        lambda *a, **kw: made.append(real(*a, **kw)) or made[-1])
    rc, _, err = _run(capsys, "--gait", str(family_path), "--speeds", "0.7", "0.75",
                      "--controller", "vc", "--plot", str(tmp_path / "figs"))
    assert rc == 0 and err == ""
    (title,) = [t.get_text() for t in made[0].texts]
    assert title.startswith("RABBIT: speed profile of 2 steps"), title


def test_cli_speeds_and_ramp(capsys, tmp_path, family_path):
    rc, out, err = _run(capsys, "--gait", str(family_path), "--speeds", "0.7", "0.75", "0.8",
                        "--m1", *map(str, M1), "--rejoin", "0.75", "--json",
                        "--plot", str(tmp_path / "figs"))
    assert rc == 0 and err == ""
    d = json.loads(out)
    assert d["status"] == "ok" and d["n_steps"] == 3
    assert [s["speed"] for s in d["steps"]] == pytest.approx(SPEEDS)
    assert all("qu_error" in s and "dqu_error" in s for s in d["steps"])
    assert d["figures"]["speed_profile"].endswith("speed_profile.png")
    assert (tmp_path / "figs" / "speed_profile.png").is_file()
    sched = tmp_path / "s.json"
    M1Schedule((0.7, 0.8), (M1, M1), (0.75, 0.75)).save(sched)
    rc, out, err = _run(capsys, "--gait", str(family_path), "--ramp", "0.7", "0.8", "0.05",
                        "--hold", "2", "--schedule", str(sched), "--compare", "--json")
    d = json.loads(out)
    assert rc == 0 and d["n_steps"] == 7 and d["compare"]["status"] == "ok"
    assert [s["speed"] for s in d["steps"]] == pytest.approx([.7, .75, .8, .75, .7, .7, .7])
    assert d["gaits"][0]["source"] == "member"
    rc, out, err = _run(capsys, "--gait", str(family_path), "--speeds", "0.7", "0.725",
                        "--controller", "vc")
    assert rc == 0 and "interpolated" in out and "vc: status ok" in out


def test_cli_profile_names_the_mu_of_each_gait(capsys, family, family_path):
    """A profile's output named no friction coefficient (a single gait's says 'mu 0.6,
    the gait's'): the table names it at each gait switch, the JSON at every step."""
    own = friction_of(family)                       # the family's gaits' own
    for extra, mu, source in (([], own, "the gait's"), (["--mu", "0.9"], 0.9, "--mu")):
        rc, out, err = _run(capsys, "--gait", str(family_path), "--speeds", "0.7", "0.75",
                            "0.75", "--controller", "vc", *extra)
        assert rc == 0 and err == "", err
        head, *rows = [ln for ln in out.splitlines() if ln.startswith("  ")][:4]
        assert head.endswith("mu (at a gait switch)"), head
        assert [r.endswith(f"  {mu:g}, {source}") for r in rows] == [True, True, False], rows
        rc, out, _ = _run(capsys, "--gait", str(family_path), "--speeds", "0.7", "0.75",
                          "--controller", "vc", "--json", *extra)
        steps = json.loads(out)["steps"]
        assert [s["mu"] for s in steps] == [mu, mu]
        assert all(s["mu"] - s["friction_margin"] == pytest.approx(
            max(s["max_friction_ratio"], s["max_impulse_ratio"])) for s in steps)


@pytest.mark.parametrize("argv, words", [
    (["--speeds", "0.6", "0.7"], "--speeds: 0.6 m/s is outside the family"),
    (["--speeds", "0.7", "nan"], "--speeds: speeds must be finite"),
    (["--ramp", "0.8", "0.7", "0.05"], "--ramp: the range 0.8:0.7 is reversed"),
    (["--ramp", "0.7", "0.7", "0.05"], "empty"),
    # a step longer than the ramp walked one step at 0.7 and exited 0
    (["--ramp", "0.7", "0.8", "1e300"], "--ramp: the step 1e+300 is longer than the range"),
    (["--ramp", "0.7", "0.8", "0.16"], "--ramp: the step 0.16 is longer than the range"),
    (["--ramp", "0.7", "0.9", "0.05"], "--ramp: 0.85 m/s is outside the family"),
    (["--speeds", "0.7", "--steps", "3"], "--steps does not apply"),
    (["--speeds", "0.7", "--ramp", "0.7", "0.8", "0.05"], "exclude"),
    (["--speeds", "0.7", "--schedule", "missing.json"], "not found"),
    (["--speeds", "0.7", "--controller", "vc", "--m1", "1", "2", "3", "4"], "--m1 applies"),
    (["--hold", "2"], "--hold applies"),
    (["--speeds", "0.7", "--plot", "nofolder/x/y"], "--plot"),
])
def test_cli_bad_profiles(argv, words, capsys, tmp_path, monkeypatch, family_path):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "nofolder").write_text("a file")
    gait = [] if "--hold" in argv else ["--gait", str(family_path)]
    before = sorted(p.name for p in tmp_path.iterdir())
    rc, out, err = _run(capsys, *gait, *argv)
    assert rc == 2 and out == "" and words in err and len(err.strip().splitlines()) == 1
    assert sorted(p.name for p in tmp_path.iterdir()) == before


def test_cli_profile_needs_a_family(capsys, tmp_path, family, family_path):
    family.gait(0.75).save(tmp_path / "one.json")
    rc, out, err = _run(capsys, "--gait", str(tmp_path / "one.json"), "--speeds", "0.7")
    assert rc == 2 and "--gait:" in err and "gait family" in err
    rc, out, err = _run(capsys, "--speeds", "0.7")
    assert rc == 2 and "need --gait FAMILY.json" in err


# ------------------------------------------------------------ the study (slow)
@pytest.fixture(scope="module")
def study_family(model, tmp_path_factory):
    path = tmp_path_factory.mktemp("study") / "family.json"
    return gait_family(model, speed_range(0.45, 1.05, 0.05), GaitOptions(**ROBUST_GAIT),
                       path=path)


@pytest.mark.slow
def test_the_ramp_walks_with_virtual_constraints_and_converges(study_family):
    r = speed_ramp(study_family, "vc", None, OPTS, 0.5, 1.0, 0.05, hold=10)
    assert r.ok and r.n_steps == 31 and r.peak_torque <= 150
    assert r.errors()[-1] < 1e-3 and r.friction_margin > 0
    assert np.isfinite(r.segments[-1].steps_to_converge)


@pytest.mark.slow
def test_one_m1_for_all_speeds_fails_the_ramp_below_its_stable_range(study_family):
    """The co-design's M1 is unstable on the slow gaits (max|lambda| > 1 below 0.6 m/s)
    and the ramp fails on its way up."""
    s = M1Schedule.constant(M1, 0.75)
    eig = {round(e["speed"], 2): e for e in schedule_eigenvalues(study_family.gaits, s)}
    assert eig[0.5]["max_abs"] > 1 and eig[0.75]["max_abs"] < 1
    r = speed_ramp(study_family, "tv", s, OPTS, 0.5, 1.0, 0.05, hold=10)
    assert not r.ok and r.fail_step < 10


@pytest.mark.slow
def test_the_ramp_walks_with_an_m1_schedule_of_gait_fixed_codesigns(study_family):
    """Three co-designs (the how-to's schedule has seven; three walk too and cost 50 s
    instead of 120 s)."""
    from analysis.design.codesign import QUICK, codesign
    pts = (0.45, 0.75, 1.05)
    res = [codesign(study_family.gait(v), QUICK, workers=1) for v in pts]
    s = M1Schedule(pts, tuple(tuple(r.design.M1) for r in res),
                   tuple(r.design.rejoin for r in res))
    eig = schedule_eigenvalues(study_family.gaits, s)
    assert all(e["max_abs"] < 1 for e in eig)
    r = speed_ramp(study_family, "tv", s, OPTS, 0.5, 1.0, 0.05, hold=10)
    assert r.ok and r.peak_torque <= 150 and r.errors()[-1] < 1e-3
