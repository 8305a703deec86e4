"""The choice of M1 for a running gait (analysis.design.running_m1, biped running
--choose-m1).

RABBIT's 1.5 m/s running gait is solved once per session (kept on disk after the first
solve), its stride map built once; the search is capped at a few dozen evaluations
(about 0.5 s each).  Every figure is checked against another computation: the chosen
radius against a fresh analysis at the chosen M1 and against the evaluations' record,
the AD Jacobian there against central differences, the perturbed run's contraction
against the radius, the command line's numbers against the library's.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from analysis.cli.running import MAX_EVALUATIONS
from analysis.design.running_m1 import INFEASIBLE, choose_running_m1
from analysis.stability.running_cycle import (finite_difference_jacobian, running_stability,
                                              simulate_running)

HAND = (0.0, 0.95, 0.95, 0.0)        # the hand-picked design of docs/howto/running.md
CAP = 15


@pytest.fixture(scope="session")
def m1_gait(running_gait):
    return running_gait


@pytest.fixture(scope="session")
def m1_cycle(running_cycle15):
    np.testing.assert_array_equal(running_cycle15.controller.M1, HAND)
    return running_cycle15


@pytest.fixture(scope="session")
def choice(m1_cycle):
    return choose_running_m1(m1_cycle, max_evaluations=CAP)


@pytest.fixture(scope="session")
def m1_gait_file(m1_gait, tmp_path_factory):
    return str(m1_gait.save(tmp_path_factory.mktemp("runm1") / "run15.json"))


def test_the_choice_lowers_the_radius_below_one(m1_cycle, choice):
    start = running_stability(m1_cycle)                      # the hand-picked design
    assert choice.status == "stable" and choice.success
    assert choice.start_radius == pytest.approx(start.spectral_radius, rel=1e-12)
    assert choice.spectral_radius <= choice.start_radius
    assert choice.spectral_radius < 1
    np.testing.assert_array_equal(choice.start_M1, HAND)
    assert 1 <= choice.n_evaluations == len(choice.evaluations) <= CAP


def test_the_reported_radius_is_a_fresh_analysis_at_the_choice(m1_cycle, choice):
    fresh = running_stability(m1_cycle.retuned(M1=choice.M1))
    assert fresh.status == "stable"
    assert choice.spectral_radius == pytest.approx(fresh.spectral_radius, rel=1e-10)
    np.testing.assert_allclose(np.abs(choice.stability.eigenvalues),
                               np.abs(fresh.eigenvalues), rtol=1e-9, atol=1e-14)
    # the best feasible evaluation of the record is the choice
    feasible = [e for e in choice.evaluations if e.status != "infeasible"]
    best = min(feasible, key=lambda e: e.spectral_radius)
    np.testing.assert_array_equal(best.M1, choice.M1)
    assert best.spectral_radius == pytest.approx(choice.spectral_radius, rel=1e-10)
    assert choice.n_infeasible == len(choice.evaluations) - len(feasible)


def test_the_choice_holds_in_a_perturbed_run_and_by_central_differences(model, m1_cycle,
                                                                       choice):
    cyc = m1_cycle.retuned(M1=choice.M1)
    r = choice.stability
    J = finite_difference_jacobian(cyc, r.fixed_point, 1e-5)
    assert np.abs(J - r.A).max() / np.abs(r.A).max() < 1e-6
    x = r.fixed_point.copy()
    x[model.nq:] += 1e-2
    run = simulate_running(cyc, r.fixed_point, x, strides=16)
    assert run.status == "ok", run.message
    d = run.deviations
    assert d[-1] < 1e-3 * d[0]
    mean = (d[-1] / d[1]) ** (1 / (d.size - 2))      # after the first stride
    assert mean == pytest.approx(choice.spectral_radius, rel=0.3)


def test_infeasible_points_are_recorded_with_their_reason(m1_cycle):
    # no fixed point is within 1e-9 of the collocation: every point infeasible
    ch = choose_running_m1(m1_cycle, max_evaluations=3, max_distance=1e-9)
    assert ch.status == "failed" and not ch.success
    assert ch.n_infeasible == ch.n_evaluations == 3
    assert all(e.status == "infeasible" and "another orbit" in e.message
               and np.isnan(e.spectral_radius) for e in ch.evaluations)
    assert "no feasible design" in ch.message
    assert INFEASIBLE > 100


@pytest.mark.parametrize("kw, word", [
    (dict(method="bfgs"), "method"), (dict(max_evaluations=0), "max_evaluations"),
    (dict(start=(1.0, 2.0)), "start"), (dict(initial_step=-1.0), "initial_step"),
    (dict(max_distance=float("nan")), "max_distance"),
    # a TypeError of math.isfinite ('must be real number, not str') named nothing
    (dict(initial_step="a"), "initial_step"), (dict(max_distance=None), "max_distance"),
    (dict(start="abc"), "start"), (dict(start=(0.0, 0.0, 1e300, 0.0)), "start: components")])
def test_bad_options_are_refused(m1_cycle, kw, word):
    with pytest.raises(ValueError, match=word):
        choose_running_m1(m1_cycle, **kw)


def test_bad_cycle_and_progress_are_refused(m1_cycle):
    with pytest.raises(TypeError, match="cycle must be a running cycle"):
        choose_running_m1(None)
    with pytest.raises(TypeError, match="progress must be a function"):
        choose_running_m1(m1_cycle, progress=5)


def test_command_line_choose_m1(m1_gait_file, m1_cycle, capsys):
    from analysis.cli import main
    assert main(["running", "--gait", m1_gait_file, "--choose-m1", "--max-evaluations", "8",
                 "--steps", "3", "--json"]) == 0
    s = json.loads(capsys.readouterr().out)["stability"]
    ch = s["choice"]
    assert ch["n_evaluations"] <= 8 and ch["start_M1"] == list(HAND)
    assert s["M1"] == ch["M1"]                          # the analysis is at the choice
    assert s["spectral_radius"] == pytest.approx(ch["spectral_radius"], rel=1e-10)
    assert ch["spectral_radius"] <= ch["start_radius"]
    fresh = running_stability(m1_cycle.retuned(M1=s["M1"]))
    assert s["spectral_radius"] == pytest.approx(fresh.spectral_radius, rel=1e-10)
    assert s["simulation"]["status"] == "ok" and len(s["simulation"]["contraction"]) == 3
    from analysis.cli.running import _print_stability
    _print_stability(s)
    line = next(ln for ln in capsys.readouterr().out.splitlines()
                if ln.startswith("  chosen               M1 "))
    printed, radius = line.split("M1 ", 1)[1].split(", spectral radius ")
    M1 = [float(v) for v in printed.split()]
    assert M1 == ch["M1"]                               # the printed M1 is the one analysed
    again = running_stability(m1_cycle.retuned(M1=M1)).spectral_radius
    assert f"{again:.4f}" == radius == f"{ch['spectral_radius']:.4f}"
    # every digit, also where 5 significant digits would round (the radius at a chosen
    # M1 of 150 evaluations moves in the 4th decimal with them)
    fine = [v + np.pi * 1e-7 for v in ch["M1"]]
    _print_stability(dict(s, M1=fine, choice=dict(ch, M1=fine)))
    out = capsys.readouterr().out
    for head in ("  chosen               M1 ", "closed loop (pd, Kp 400, Kd 30, M1 "):
        line = next(ln for ln in out.splitlines() if ln.startswith(head))
        assert [float(v) for v in line[len(head):].split(",")[0].split(")")[0].split()] == fine


@pytest.mark.parametrize("args, words", [
    (["--max-evaluations", "5"], "--choose-m1"), (["--tune-gains"], "--choose-m1"),
    (["--choose-m1", "--max-evaluations", "0"], "--max-evaluations"),
    (["--choose-m1", "--max-evaluations", "100000"], "--max-evaluations must be between 1 "
                                                     f"and {MAX_EVALUATIONS}, got 100000"),
    (["--choose-m1", "--tune-gains", "--kd", "0"], "--tune-gains"),
    (["--max-distance", "0.1"], "--choose-m1"),
    (["--choose-m1", "--max-distance", "-1"], "--max-distance must be a positive"),
    (["--choose-m1", "--max-distance", "nan"], "--max-distance must be a positive")])
def test_command_line_refuses_bad_combinations(m1_gait_file, capsys, args, words):
    from analysis.cli import main
    assert main(["running", "--gait", m1_gait_file, *args]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and words in err


def test_the_gains_can_be_searched_too(m1_cycle):
    ch = choose_running_m1(m1_cycle, tune_gains=True, max_evaluations=6, gain_step=0.3)
    assert ch.tune_gains and ch.n_evaluations == 6
    # Nelder-Mead's first simplex: the start, then a step on each M1 component and log Kp
    assert ch.evaluations[5].Kp == pytest.approx(400.0 * np.exp(0.3), rel=1e-12)
    assert ch.evaluations[5].Kd == pytest.approx(30.0, rel=1e-12)
    assert ch.spectral_radius <= ch.start_radius
    fresh = running_stability(m1_cycle.retuned(Kp=ch.Kp, Kd=ch.Kd, M1=ch.M1))
    assert ch.spectral_radius == pytest.approx(fresh.spectral_radius, rel=1e-10)


def test_command_line_choice_without_a_feasible_design_is_one_line(m1_gait_file, capsys):
    """Every fixed point farther than --max-distance from the gait: the choice fails as a
    solver that did not converge (one line naming why and what to change, exit 2), not a
    report that exits 0."""
    from analysis.cli import main
    assert main(["running", "--gait", m1_gait_file, "--choose-m1", "--max-evaluations", "2",
                 "--max-distance", "1e-9"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no feasible design among 2 evaluations" in err
    assert "larger --max-distance than 1e-09" in err, err
