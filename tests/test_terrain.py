"""Uneven ground, model error and saturation, the exact step map and gait sensitivity
norm, the mean first-passage time by Monte Carlo (issue 22).

The walkers are exact reductions of the closed loop on uneven ground too (v_c, and the
virtual constraints' phase correction, start from the outputs at each step start), so
they must agree with the full-order simulator to its integration accuracy; the step
map's AD Jacobians must agree with central differences of the simulator; the GSN must
predict the Monte Carlo's step-time RMS at small sigma; the MFPT estimator must cover a
known failure probability.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from analysis import poincare_map, vc_eigenvalue
from analysis.cli import main as biped_main
from analysis.design import ROBUST_GAIT
from analysis.stability import StepMap
from analysis.terrain import (MonteCarloSettings, WalkerSpec, gait_sensitivity,
                              gsn_of, mfpt_estimate, monte_carlo, predicted_rms)
from analysis.terrain.gsn import StepLinearisation
from biped_casadi import (Gains, SimulationOptions, TimeVaryingController,
                          VirtualConstraintController, robot, simulate)
from biped_casadi.simulation import (Terrain, TerrainFileError, VirtualConstraintWalker,
                                     ZeroDynamicsWalker, directions, random_heights,
                                     start_states, step_heights, torso_push)
from biped_casadi.simulation.terrain import ground_levels
from gait_opt import GaitOptions, optimize_gait

#: the robust design of the reproduction (README); any design that walks would do
M1R, REJOIN = np.array([-8.2618, 2.5374, 0.0034, 8.5090]), 0.75


@pytest.fixture(scope="module")
def robust_gait(model):
    return optimize_gait(model, GaitOptions(**ROBUST_GAIT), cache=True)


@pytest.fixture(scope="module")
def tv(model, robust_gait):
    return TimeVaryingController(robust_gait, M1R, rejoin=REJOIN)


# ------------------------------------------------------------------ terrain
def test_terrain_files_and_streams(tmp_path):
    (tmp_path / "a.json").write_text(json.dumps({"heights": [0.01, -0.02]}))
    (tmp_path / "b.txt").write_text("# a profile\n0.01, -0.02\n 0.005 # step 3\n")
    assert Terrain.load(tmp_path / "a.json").heights == (0.01, -0.02)
    assert Terrain.load(tmp_path / "b.txt").heights == (0.01, -0.02, 0.005)
    t = Terrain((0.01, -0.02))
    assert t.height(1) == -0.02 and t.height(5) == 0.0
    assert t.behind(0) == 0.0 and t.behind(1) == -0.01 and t.behind(2) == 0.0
    t.save(tmp_path / "c.json")
    assert Terrain.load(tmp_path / "c.json") == t
    for text, word in (("0.01 abc", "not a number"), ("[1, ", "malformed"), ("", "no height"),
                       ('["a"]', "list of numbers"), ("0.5", "at most")):
        (tmp_path / "bad.txt").write_text(text)
        with pytest.raises(TerrainFileError, match=word):
            Terrain.load(tmp_path / "bad.txt")
    with pytest.raises(TerrainFileError, match="not found"):
        Terrain.load(tmp_path / "missing.txt")
    # run i's heights depend on the seed and i only, not on the other runs drawn
    H = random_heights(0.01, 7, 3, range(10))
    assert np.array_equal(H[4:6], random_heights(0.01, 7, 3, [4, 5]))
    assert not np.array_equal(H[0], random_heights(0.01, 7, 4, [0])[0])
    assert abs(np.std(random_heights(0.01, 200, 0, range(50))) - 0.01) < 5e-4
    assert np.all(random_heights(0.0, 5, 0, range(3)) == 0)
    assert step_heights(Terrain((0.01,)), 2, 3).tolist() == [[0.01, 0, 0]] * 2
    ahead, behind = ground_levels(np.array([[0.01, -0.02, 0.03]]), 2)
    assert ahead[0] == 0.03 and behind[0] == 0.0
    with pytest.raises(ValueError, match="sigma"):
        random_heights(-1.0, 3, 0, [0])


def test_flat_terrain_changes_nothing_and_steps_change_the_step_time(tv, robust_gait):
    o = SimulationOptions(steps=3)
    a = simulate(tv, options=o)
    b = simulate(tv, options=o, terrain=Terrain.flat())
    assert np.array_equal(a.qu_error, b.qu_error) and np.array_equal(a.duration, b.duration)
    up = simulate(tv, options=o, terrain=Terrain((0.005,)))
    down = simulate(tv, options=o, terrain=Terrain((-0.005,)))
    T = robust_gait.T
    # a step up is struck sooner, a step down later; the foot strikes at the height
    assert up.duration[0] < T - 1e-3 < T + 1e-3 < down.duration[0]
    for r, h in ((up, 0.005), (down, -0.005)):
        assert r.steps[0].ground_height == h
        z = float(tv.model.swing_foot(r.steps[0].q_minus)[1])
        assert abs(z - h) < 1e-12


def test_walkers_are_the_closed_loop_on_uneven_ground(model, robust_gait, tv):
    """Random terrain, perturbed starts: the zero-dynamics walker and the virtual-
    constraint walker against the full-order simulator."""
    g = robust_gait
    H = random_heights(0.003, 5, 11, range(3))
    _, dq0 = start_states(g, directions(3, model.nq, seed=2), np.full(3, 0.3))
    q0 = np.tile(g.q(0.0), (3, 1))          # the swing foot on the ground, the rates off
    B = ZeroDynamicsWalker(model, g, rk4_steps=400).walk(q0, dq0, M1R, REJOIN, steps=5,
                                                          terrain=H)
    vc = VirtualConstraintController(g)
    V = VirtualConstraintWalker(model, g, nodes=800).walk_from_states(q0, dq0, steps=5,
                                                                      terrain=H)
    o = SimulationOptions(steps=5, jit=True)
    for i in range(3):
        r = simulate(tv, q0[i], dq0[i], o, terrain=H[i])
        assert r.status == B.status[i] and r.completed_steps == B.completed_steps[i]
        k = r.completed_steps
        assert k >= 2
        assert np.max(np.abs(r.dqu_error[:k] - B.dqu_error[i, :k])) < 1e-7
        assert np.max(np.abs(r.duration[:k] - B.duration[i, :k])) < 1e-7
        rv = simulate(vc, q0[i], dq0[i], o, terrain=H[i])
        assert rv.status == V.status[i] and rv.completed_steps == V.completed_steps[i]
        k = rv.completed_steps
        # the full-order simulator's own integration error (2000 RK4 steps per T) is a
        # few 1e-6 rad/s after 5 perturbed steps
        assert np.max(np.abs(rv.dqu_error[:k] - V.dqu_error[i, :k])) < 1e-5
        assert np.max(np.abs(rv.duration[:k] - V.duration[i, :k])) < 1e-5


# --------------------------------------------------------- model error, saturation
def test_model_error_makes_the_gains_matter(model, robust_gait, tv):
    """With the plant's torso 20 % heavier the closed loop leaves its zero dynamics and
    the output gains change the motion; with a perfect plant they do not."""
    plant = robot(model.description.scaled(torso_mass=1.2))
    assert abs(plant.description.torso.mass - 1.2 * model.description.torso.mass) < 1e-12
    o = SimulationOptions(steps=3, jit=True)
    same = simulate(tv, options=o, plant=model)
    assert np.array_equal(same.dqu_error, simulate(tv, options=o).dqu_error)
    runs = {}
    for eps in (0.02, 0.08):
        for p in (None, plant):
            c = TimeVaryingController(robust_gait, M1R, Gains(eps=eps), rejoin=REJOIN)
            runs[eps, p is None] = simulate(c, options=o, plant=p)
    perfect = np.max(np.abs(runs[0.02, True].dqu_error - runs[0.08, True].dqu_error))
    wrong = np.max(np.abs(runs[0.02, False].dqu_error - runs[0.08, False].dqu_error))
    assert perfect < 1e-6 < 1e-3 < wrong
    with pytest.raises(ValueError, match="plant"):
        simulate(tv, options=o, plant=robot("three_link"))


def test_gains_too_stiff_for_rk4_are_said_not_walked(robust_gait, capsys):
    """Output gains too stiff for the RK4 step make the closed loop diverge (it ended as
    'out_of_range', the GSN as 'does not strike'): they are refused in one line naming
    them, by the simulator, by 'biped terrain' before any full-order run (exit 2), and
    as the reason the GSN has no value when the runs do not need them."""
    c = TimeVaryingController(robust_gait, M1R, Gains(Kp=1e9), rejoin=REJOIN)
    with pytest.raises(ValueError, match=r"^the output gains \(Kp, Kd, eps\) = \(1e\+09, 2, "
                                         r"0.02\) make the closed loop too stiff .* RK4 would "
                                         r"diverge"):
        simulate(c, options=SimulationOptions(steps=1))
    args = ["terrain", "--controller", "vc", "--gains", "1e9", "1", "0.02", "--runs", "1",
            "--max-steps", "1", "--scheduler", "inline"]
    assert biped_main([*args, "--mass-scale", "1.05"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("biped terrain: error: --gains: (Kp, Kd, eps) = (1e+09, 1, 0.02) "
                          "make the closed loop too stiff") and "\n" not in err
    assert biped_main([*args, "--json"]) == 0         # exact walkers: gains do not matter
    d = json.loads(capsys.readouterr().out)
    assert d["gsn"] is None and "too stiff" in d["gsn_message"], d["gsn_message"]


def test_saturation_keeps_walking_and_reports_the_time(tv):
    low = SimulationOptions(steps=2, torque_limit=40.0, jit=True)
    stop = simulate(tv, options=low, terrain=Terrain((0.01,)))
    assert stop.status == "torque_limit" and stop.saturated_time == 0
    sat = simulate(tv, options=SimulationOptions(steps=2, torque_limit=40.0, saturate=True,
                                                 jit=True), terrain=Terrain((0.01,)))
    assert sat.status != "torque_limit"
    assert sat.saturated_time > 0 and sat.peak_torque <= 40.0 + 1e-9
    assert simulate(tv, options=SimulationOptions(steps=2)).saturated_time == 0
    with pytest.raises(ValueError, match="saturate"):
        ZeroDynamicsWalker(tv.model, tv.reference, SimulationOptions(saturate=True))


# ------------------------------------------------------------- the step map
def _fd_jacobian(sm, s, h, d, push=0.0):
    cols = []
    for i in range(s.size + 2):
        e = np.zeros(s.size + 2)
        e[i] = d
        a = sm.step(s + e[:-2], h + e[-2], push + e[-1])
        b = sm.step(s - e[:-2], h - e[-2], push - e[-1])
        cols.append(np.r_[a.next_state - b.next_state, a.step_time - b.step_time,
                          a.step_length - b.step_length] / (2 * d))
    return np.array(cols).T


@pytest.mark.parametrize("kind", ["tv", "vc"])
def test_step_map_jacobians_against_central_differences(model, gait, kind):
    """A, B, C, D by AD against central differences of the map, and the map against
    the simulator it is made of (default gait, away from the flat orbit's RK4 node)."""
    c = TimeVaryingController(gait, np.array([-10, 7.5, 10, -5.0])) if kind == "tv" \
        else VirtualConstraintController(gait)
    o = SimulationOptions(steps=1, rk4_steps=400, ground_tolerance=1e-4)
    sm = StepMap(c, o)
    s = np.r_[gait.q(0.0), gait.dq(0.0)] + 1e-4 * directions(1, model.nq, seed=3)[0]
    lin = sm.linearise(s, h=0.002, push=0.5)
    J = np.vstack([np.hstack([lin.A, lin.B]), np.hstack([lin.C, lin.D])])
    fd = _fd_jacobian(sm, s, 0.002, 1e-6, push=0.5)
    assert np.max(np.abs(fd - J)) < 1e-6 * np.max(np.abs(J))
    v = sm.step(s, 0.002, 0.5)
    q, dq = s[:model.nq], np.array(torso_push(model)(s[:model.nq], s[model.nq:], 0.5)).ravel()
    r = simulate(c, q, dq, o, terrain=Terrain((0.002,)))
    assert np.max(np.abs(v.next_state - np.r_[r.steps[0].q_plus, r.steps[0].dq_plus])) < 1e-12
    assert abs(v.step_time - r.steps[0].duration) < 1e-12


@pytest.mark.parametrize("kind", ["tv", "vc"])
def test_gait_sensitivity_eigenvalues_are_the_restricted_maps(gait, robust_gait, tv, kind):
    """At the periodic walk the full state's step map has rank 2 for the time-varying
    controller, its non-zero eigenvalues those of A^z (eq. 20), and rank 1 for virtual
    constraints, its eigenvalue the 1-D map's: the spectral radius of the GSN is the
    restricted analysis's max|lambda| to the discretisations' accuracy (measured 1e-9;
    linearised 10 um above the walk instead, 1e-4 apart)."""
    if kind == "tv":
        g = gait_sensitivity(tv)
        ref = poincare_map(robust_gait, rejoin=REJOIN, n_pre=320, n_post=960).analyse(M1R)
        ref = ref.eigenvalues
    else:
        g = gait_sensitivity(VirtualConstraintController(gait))
        ref = np.array([vc_eigenvalue(gait).eigenvalue])
    ev = g.linearisation.eigenvalues
    n = ref.size
    assert np.max(np.abs(np.sort_complex(ev[:n]) - np.sort_complex(ref))) < 1e-8, (ev[:n], ref)
    assert abs(g.spectral_radius - np.max(np.abs(ref))) < 1e-8
    assert np.all(np.abs(ev[n:]) < 1e-8) and g.fixed_point_residual < 1e-9


@pytest.mark.parametrize("kind", ["tv", "vc"])
def test_gsn_matches_central_differences_of_the_simulator(model, gait, kind):
    """The GSN from the exact Jacobians and from central differences of the simulator
    agree to 1e-5 relative, for the time-varying controller and for virtual constraints,
    10 um above the periodic walk (at the walk its strike is on an RK4 node, where the
    map's second derivative jumps: differences across it are accurate to the step
    only)."""
    c = TimeVaryingController(gait, np.array([-10, 7.5, 10, -5.0])) if kind == "tv" \
        else VirtualConstraintController(gait)
    o = SimulationOptions(rk4_steps=800, ground_tolerance=1e-4)
    g = gait_sensitivity(c, o)
    sm = StepMap(c, o)
    s = g.linearisation.state
    lin = sm.linearise(s, h=1e-5)
    fd = _fd_jacobian(sm, s, 1e-5, 1e-6)
    n = s.size
    lin_fd = StepLinearisation(state=s, A=fd[:n, :n], B=fd[:n, n:], C=fd[n:, :n], D=fd[n:, n:],
                               step_time=0.0, step_length=0.0, residual=0.0,
                               eigenvalues=np.linalg.eigvals(fd[:n, :n]))
    ad, num = gsn_of(lin), gsn_of(lin_fd)
    for dist in ad:
        for ind, v in ad[dist].items():
            # (an indicator the disturbance does not move, such as virtual constraints'
            # step length under a push, is ~6e-9 and compared to the differences' noise,
            # which moves it by up to ~2e-9 with a step of 1e-6)
            assert abs(num[dist][ind] - v) <= 1e-5 * abs(v) + 4e-9, (dist, ind, v,
                                                                    num[dist][ind])
    assert g.status == "stable" and g.fixed_point_residual < 1e-9


@pytest.mark.parametrize("kind", ["tv", "vc"])
def test_gsn_predicts_the_monte_carlo_step_time_rms(model, robust_gait, kind):
    """At sigma = 0.5 mm the Monte Carlo's RMS step-time deviation is the GSN's within
    10 % (measured 0.4 % and 0.8 % with 200 runs of 30 steps)."""
    spec = WalkerSpec("tv", tuple(M1R), REJOIN) if kind == "tv" else WalkerSpec("vc")
    st = MonteCarloSettings(sigma=5e-4, runs=80, max_steps=25, chunk=80)
    mc = monte_carlo(robust_gait, spec, st, scheduler="inline")
    assert mc.estimate.failures == 0
    g = gait_sensitivity(spec.controller_for(robust_gait), SimulationOptions(rk4_steps=400))
    pred = predicted_rms(g.linearisation, st.sigma, st.max_steps, st.transient)
    assert abs(pred - st.sigma * g.gsn["ground_height"]["step_time"]) < 0.02 * pred
    assert abs(mc.step_time_rms - pred) < 0.1 * pred


# -------------------------------------------------------------- Monte Carlo
def test_mfpt_estimate_covers_a_known_failure_probability():
    rng = np.random.default_rng(1)
    p, K, n = 0.04, 60, 3000
    fail_at = rng.geometric(p, n) - 1                 # steps walked before the failure
    walked = np.minimum(fail_at, K)
    failed = fail_at < K
    e = mfpt_estimate(walked, failed, K)
    lo, hi = e.failure_probability_ci
    assert lo < p < hi and abs(e.failure_probability - p) < 0.15 * p
    assert e.mfpt_ci[0] < (1 - p) / p < e.mfpt_ci[1]
    assert all(type(x) is float for x in e.failure_probability_ci + e.mfpt_ci)   # repr
    assert e.mean_steps_walked < e.mfpt                # censoring biases the plain mean
    assert e.survival[0] == 1.0 and np.all(np.diff(e.survival) <= 0)
    none = mfpt_estimate(np.full(50, K), np.zeros(50, bool), K)
    assert none.mfpt == math.inf and 0 < none.mfpt_ci[0] < math.inf
    assert none.failure_probability == 0 and none.failure_probability_ci[1] < 3.7 / (50 * K)
    from scipy.stats import chi2                       # the exact (Garwood) interval
    E = int(walked.sum() + failed.sum())
    F = int(failed.sum())
    assert (lo, hi) == (chi2.ppf(0.025, 2 * F) / (2 * E), chi2.ppf(0.975, 2 * F + 2) / (2 * E))


def test_flat_ground_every_run_walks_and_chunks_change_nothing(robust_gait):
    st = MonteCarloSettings(sigma=0.0, runs=6, max_steps=12, chunk=4)
    for spec in (WalkerSpec("tv", tuple(M1R), REJOIN), WalkerSpec("vc")):
        r = monte_carlo(robust_gait, spec, st, scheduler="inline")
        assert r.estimate.failures == 0 and np.all(r.walked == 12)
    spec = WalkerSpec("tv", tuple(M1R), REJOIN)
    a = monte_carlo(robust_gait, spec, MonteCarloSettings(sigma=0.01, runs=12, max_steps=15,
                                                          chunk=5), scheduler="inline")
    b = monte_carlo(robust_gait, spec, MonteCarloSettings(sigma=0.01, runs=12, max_steps=15,
                                                          chunk=12), scheduler="inline")
    # the same runs whatever the chunks (round-off aside: numpy sums over other shapes)
    assert np.array_equal(a.walked, b.walked)
    assert np.allclose(a.duration, b.duration, rtol=0, atol=1e-12, equal_nan=True)
    assert a.estimate.failures > 0                     # 1 cm steps: the design trips


def test_monte_carlo_resumes_with_the_same_numbers(robust_gait, tmp_path):
    spec = WalkerSpec("tv", tuple(M1R), REJOIN)
    st = MonteCarloSettings(sigma=0.008, runs=9, max_steps=10, chunk=3)
    out = tmp_path / "mc"
    a = monte_carlo(robust_gait, spec, st, out_dir=out, scheduler="inline")
    files = sorted((out / "chunks").glob("part-*.parquet"))
    assert len(files) == 3 and a.chunks_computed == 3
    files[0].unlink()                                                   # lost
    files[1].write_bytes(files[1].read_bytes()[:-20] + b"\0" * 20)      # damaged
    b = monte_carlo(robust_gait, spec, st, out_dir=out, scheduler="inline")
    assert b.chunks_reused == 1 and b.chunks_computed == 2
    assert np.array_equal(a.walked, b.walked)
    assert np.array_equal(a.duration, b.duration, equal_nan=True)
    assert a.estimate.to_dict() == b.estimate.to_dict()
    with pytest.raises(ValueError, match="other settings"):
        monte_carlo(robust_gait, spec, MonteCarloSettings(sigma=0.009, runs=9, max_steps=10,
                                                          chunk=3), out_dir=out,
                    scheduler="inline")


def test_model_error_monte_carlo_differs_between_gains(model, robust_gait):
    """With the torso 20 % heavier the two gain sets give different outcomes (the
    full-order simulator runs; the gains do nothing without a model error)."""
    plant = model.description.scaled(torso_mass=1.2).to_dict()
    st = MonteCarloSettings(sigma=0.006, runs=4, max_steps=6, chunk=4, full_rk4_steps=400)
    r = [monte_carlo(robust_gait, WalkerSpec("tv", tuple(M1R), REJOIN, gains, plant), st,
                     scheduler="inline") for gains in ((1, 2, 0.02), (1, 2, 0.1))]
    assert r[0].spec["engine"] == "full_order"
    assert not np.allclose(r[0].duration, r[1].duration, equal_nan=True)


def test_settings_refuse_bad_values():
    for kw, word in ((dict(sigma=-1.0), "sigma"), (dict(sigma=math.nan), "sigma"),
                     (dict(sigma=math.inf), "sigma"), (dict(runs=0), "runs"),
                     (dict(runs=10**9), "runs"), (dict(max_steps=0), "max_steps"),
                     (dict(profile=(0.01,), sigma=0.01), "exclude")):
        with pytest.raises(ValueError, match=word):
            MonteCarloSettings(**kw)
    with pytest.raises(ValueError, match="scale"):
        robot("rabbit").description.scaled(torso_mass=0.0)


# --------------------------------------------------------------------- CLI
def test_cli_terrain_json(tmp_path, capsys):
    rc = biped_main(["terrain", "--m1", *map(str, [-10, 7.5, 10, -5]), "--sigma", "0.004",
                     "--runs", "6", "--max-steps", "8", "--scheduler", "inline", "--json",
                     "--plot", str(tmp_path / "figs")])
    assert rc == 0
    d = json.loads(capsys.readouterr().out)
    assert any("mfpt" in k for k in d) and any("gsn" in k for k in d)
    assert d["gsn"]["ground_height"]["step_time"] > 0
    assert len(d["survival"]) == 9 and d["settings"]["runs"] == 6
    assert (tmp_path / "figs" / "survival.png").is_file()
    prof = tmp_path / "profile.txt"
    prof.write_text("0.002 -0.002 0.001\n")
    rc = biped_main(["terrain", "--controller", "vc", "--terrain", str(prof), "--runs", "3",
                     "--max-steps", "4", "--scheduler", "inline", "--json"])
    assert rc == 0
    d = json.loads(capsys.readouterr().out)
    assert d["settings"]["profile"] == [0.002, -0.002, 0.001]
    assert "not independent draws" in d["message"], d["message"]   # what the interval is
    rc = biped_main(["simulate", "--m1", *map(str, [-10, 7.5, 10, -5]), "--terrain", "0.004",
                     "-0.004", "--steps", "2", "--json"])
    assert rc == 0
    d = json.loads(capsys.readouterr().out)
    assert [s["ground_height"] for s in d["steps"]] == [0.004, -0.004]


def test_mfpt_estimate_refuses_bad_counts():
    with pytest.raises(ValueError, match="^walked must be whole numbers"):
        mfpt_estimate([-1, 3], [False, True], 10)
    with pytest.raises(ValueError, match="^walked must be whole numbers"):
        mfpt_estimate([11, 3], [False, True], 10)      # beyond max_steps
    with pytest.raises(ValueError, match="^walked must be whole numbers"):
        mfpt_estimate([2.5, 3], [False, True], 10)
    with pytest.raises(ValueError, match="^failed must have one entry per run"):
        mfpt_estimate([10, 3], [True], 10)
    for bad in (0, -1, 2.0, None):
        with pytest.raises(ValueError, match="^max_steps must be a positive integer"):
            mfpt_estimate([5], [True], bad)
    for bad in (0, 1, 95, float("nan"), "0.95"):
        with pytest.raises(ValueError, match="^confidence must be a number in"):
            mfpt_estimate([5], [True], 10, confidence=bad)
    e = mfpt_estimate(np.array([10, 3]), [False, True], np.int64(10))
    assert e.failures == 1 and e.censored == 1


def test_monte_carlo_names_a_missing_design_or_bad_settings(gait):
    from biped_casadi import Design
    for bad in (None, [-10, 7.5, 10, -5], "gait.json"):
        with pytest.raises(TypeError, match="^design: a Design on its gait"):
            monte_carlo(bad)
    with pytest.raises(ValueError, match="^design: a Design on its gait is needed"):
        monte_carlo(Design([-10, 7.5, 10, -5]))     # a design without its gait
    with pytest.raises(ValueError, match="^settings must be a MonteCarloSettings, got dict$"):
        monte_carlo(Design.tv(gait, [-10, 7.5, 10, -5]), settings={"runs": 2})
