"""The walking gait's bound on the torso's lean (GaitOptions.torso_lean_max, ``biped gait
--torso-lean-max``): validated, left out of files and cache keys when unset, imposed at
every point of the transcription (with exact structured derivatives), held on the dense
grid, and what makes RABBIT's 1.2 m/s optimum, which leans past the simulator's fall
bound unbounded, a gait that walks."""
from __future__ import annotations

import json
import math

import casadi as ca
import numpy as np
import pytest

from analysis.cli import main
from analysis.gait_metrics import torso_fall
from biped_casadi import SimulationOptions, VirtualConstraintController, simulate
from gait_opt import Gait, GaitOptions
from gait_opt.cache import cache_path
from gait_opt.continuation import SpeedNLP
from gait_opt.transcription import build_problem, initial_guess


@pytest.mark.parametrize("value", [0.0, -0.5, math.pi, 4.0, math.nan, math.inf, True, "1"])
def test_the_bound_must_be_an_angle_between_0_and_pi(value):
    with pytest.raises(ValueError, match="'torso_lean_max' must be None or a number of rad "
                                         "between 0 and pi"):
        GaitOptions(torso_lean_max=value)


@pytest.mark.parametrize("value", ["0", "-1", "nan", "inf", "3.2"])
def test_cli_refuses_a_bad_bound_in_one_line(value, capsys, tmp_path):
    assert main(["gait", "--torso-lean-max", value, "--out", str(tmp_path / "g.json")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--torso-lean-max must be a number of rad between 0 " \
                                    "and pi" in err
    assert not (tmp_path / "g.json").exists()


def test_unset_bound_leaves_records_and_cache_keys_as_before(model):
    """None is left out of to_dict (files, family records and cache keys), so those of
    every gait made before the option are unchanged; a set one is recorded and read back,
    and a record without it reads as None."""
    d = GaitOptions().to_dict()
    assert "torso_lean_max" not in d
    assert GaitOptions.from_dict(d).torso_lean_max is None
    bounded = GaitOptions(torso_lean_max=1.0)
    assert bounded.to_dict()["torso_lean_max"] == 1.0
    assert GaitOptions.from_dict(bounded.to_dict()) == bounded
    assert cache_path(model, GaitOptions()) != cache_path(model, bounded)
    assert cache_path(model, GaitOptions(torso_lean_max=None)) == cache_path(model)


def _q_at_points(model, prob, w):
    """Joint angles at every constrained point, from the decision vector's own variables
    (q_u of Xs and Xc, the lifted q_a last in w)."""
    _, _, Xs, Xc, _ = (np.array(v) for v in prob.unpack(w))
    npts = prob.s_all.size
    QA = np.asarray(w)[-3 * model.nu * npts:].reshape(3 * model.nu, npts, order="F")
    return np.vstack([np.hstack([Xs, Xc])[0], QA[:model.nu]])


def test_bound_is_a_constraint_row_at_every_point_with_exact_derivatives(model):
    """Absent without the option; with it, one row per point holding the torso's angle
    (q1 + q2 + q3 on RABBIT, summed independently) between -+bound, and the structured
    derivatives still equal CasADi's AD of the whole NLP."""
    plain = build_problem(model, GaitOptions(n_intervals=5))
    assert "torso lean" not in [n for n, _, _ in plain.groups]
    opts = GaitOptions(n_intervals=5, torso_lean_max=0.4)
    prob = build_problem(model, opts)
    (a, b), = [(a, b) for n, a, b in prob.groups if n == "torso lean"]
    assert b - a == prob.s_all.size
    assert np.all(prob.lbg[a:b] == -0.4) and np.all(prob.ubg[a:b] == 0.4)
    rng = np.random.default_rng(5)
    w = initial_guess(model, opts) + 0.01 * rng.standard_normal(prob.lbx.size)
    g = np.array(prob.jac_g(w, [])[0]).ravel()
    q = _q_at_points(model, prob, w)
    assert np.max(np.abs(g[a:b] - (q[0] + q[1] + q[2]))) <= 1e-12
    lam = rng.standard_normal(prob.lbg.size)
    x, f, gx = prob.nlp["x"], prob.nlp["f"], prob.nlp["g"]
    ref = ca.Function("ref", [x], [ca.jacobian(gx, x),
                                   ca.triu(ca.hessian(0.7 * f + ca.dot(ca.DM(lam), gx), x)[0])])
    J_ref, H_ref = (np.array(v.full()) for v in ref(w))
    assert np.max(np.abs(prob.jac_g(w, [])[1].full() - J_ref)) <= 1e-10 * np.max(np.abs(J_ref))
    H = prob.hess_lag(w, [], 0.7, lam).full()
    assert np.max(np.abs(H - H_ref)) <= 1e-10 * np.max(np.abs(H_ref))


def test_a_family_margin_tightens_both_sides_of_the_bound(model):
    nlp = SpeedNLP(model, GaitOptions(n_intervals=5, torso_lean_max=0.4))
    prob = nlp.problem({"torso lean": 0.01})
    (a, b), = [(a, b) for n, a, b in prob.groups if n == "torso lean"]
    assert np.allclose(prob.lbg[a:b], -0.39) and np.allclose(prob.ubg[a:b], 0.39)


def test_bounded_gait_at_1_2_m_s_keeps_the_torso_up_and_walks(model, capsys, tmp_path):
    """Unbounded, the 1.2 m/s optimum leans past the fall bound and the report points to
    --torso-lean-max; with --torso-lean-max 1.0 the bound is active and holds on the
    dense grid, the file records it, and a perturbed walk of the gait does not fall."""
    free, bounded = tmp_path / "free.json", tmp_path / "bounded.json"
    assert main(["gait", "--speed", "1.2", "--out", str(free)]) == 0
    text = capsys.readouterr().out
    assert "PAST the simulator's fall bound" in text and "--torso-lean-max RAD" in text
    assert main(["gait", "--speed", "1.2", "--torso-lean-max", "1.0", "--out",
                 str(bounded)]) == 0
    text = capsys.readouterr().out
    assert "PAST" not in text and "(bound 1 rad, --torso-lean-max)" in text
    assert json.loads(bounded.read_text())["options"]["torso_lean_max"] == 1.0
    assert "torso_lean_max" not in json.loads(free.read_text())["options"]
    g, g_free = Gait.load(bounded), Gait.load(free)
    assert g.options.torso_lean_max == 1.0 and g.violations() == []
    lean, past, _ = torso_fall(g)
    assert not past and 1.0 - 1e-4 < g.check()["max_torso_lean"] <= 1.0 + 1e-7
    assert torso_fall(g_free)[1] and g.cost > g_free.cost        # the bound costs torque
    q0 = g.q(0.0) + 0.005
    run = simulate(VirtualConstraintController(g), q0, g.dq(0.0) + 0.05,
                   SimulationOptions(steps=10))
    assert str(run.status) == "ok", run.status
