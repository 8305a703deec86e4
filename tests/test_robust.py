"""Robust walking (issue 15): the zero-dynamics walkers against the full-order simulator,
s* replayed at and just above its value, basins, the robust gait's options, the CLI.

The walkers are exact reductions of the closed loop (the correction v_c zeroes the
output at every step start), so they must agree with the full-order simulator to its
integration accuracy; s* must be what the full-order simulator says at s* (every kept
direction walks and converges) and just above (the reported direction fails, for the
reported cause).
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from analysis import poincare_map
from analysis.cli import main as biped_main
from analysis.design import optimize_m1
from analysis.design import ROBUST_GAIT
from analysis.robustness import (Design, RobustnessSettings, basin, kept_directions,
                                 robustness)
from biped_casadi.simulation import start_states
from biped_casadi.simulation import VirtualConstraintWalker, ZeroDynamicsWalker
from biped_casadi import (Gains, SimulationOptions, TimeVaryingController,
                          VirtualConstraintController, directions, simulate)
from gait_opt import GaitOptions, optimize_gait


@pytest.fixture(scope="module")
def robust_gait(model):
    return optimize_gait(model, GaitOptions(**ROBUST_GAIT), cache=True)


@pytest.fixture(scope="module")
def deadbeat1(model, gait):
    """The group-1 deadbeat M1 of the NLP (paper §V-B) on the default gait."""
    return optimize_m1(gait, group=1, n_best=4, n_ipopt=1, n_random=0).M1


def _full_order(model, gait, design, d, s, steps=10, torque_limit=None):
    q0, dq0 = start_states(gait, d[None], s)
    ctrl = TimeVaryingController(gait, np.array(design.M1), rejoin=design.rejoin)
    return simulate(ctrl, q0[0], dq0[0], SimulationOptions(steps=steps,
                                                           torque_limit=torque_limit))


# ------------------------------------------------------------------ walkers
def test_walker_is_the_full_order_closed_loop(model, robust_gait):
    """From perturbed starts, the zero-dynamics walker and the full-order simulator give
    the same status, the same impacts and the same margins."""
    g = robust_gait
    M1 = np.array([-8.26, 2.54, 0.0034, 8.51])
    d = directions(4, model.nq, seed=5)
    q0, dq0 = start_states(g, d, np.full(4, 0.5))
    B = ZeroDynamicsWalker(model, g, rk4_steps=400).walk(q0, dq0, M1, 0.75, steps=4)
    ctrl = TimeVaryingController(g, M1, rejoin=0.75)
    for i in range(4):
        r = simulate(ctrl, q0[i], dq0[i], SimulationOptions(steps=4))
        assert r.status == B.status[i]
        n = len(r.steps)
        assert np.max(np.abs(r.dqu_error - B.dqu_error[i, :n]), initial=0) < 1e-6
        assert np.max(np.abs(r.qu_error - B.qu_error[i, :n]), initial=0) < 1e-7
        assert abs(r.min_normal_force - B.min_normal_force[i]) < 1e-3
        assert abs(r.peak_torque - B.peak_torque[i]) < 1e-2
        if n:
            assert abs(r.max_impulse_ratio - B.max_impulse_ratio[i]) < 1e-6


def test_output_gains_change_nothing(model, robust_gait):
    """With the correction v_c the output starts every step at zero, so the closed loop
    stays on its zero dynamics whatever the gains of eq. (13): two very different gain
    sets walk the same steps (the lever 'gains' buys nothing)."""
    g = robust_gait
    q0, dq0 = start_states(g, directions(1, model.nq)[:1], [0.5])
    runs = [simulate(TimeVaryingController(g, np.array([-8.26, 2.54, 0.0034, 8.51]),
                                           gains, rejoin=0.75), q0[0], dq0[0],
                     SimulationOptions(steps=4))
            for gains in (Gains(), Gains(Kp=4.0, Kd=4.0, eps=0.05))]
    assert runs[0].status == runs[1].status == "ok"
    assert np.max(np.abs(runs[0].dqu_error - runs[1].dqu_error)) < 1e-6
    assert np.max(np.abs(runs[0].qu_error - runs[1].qu_error)) < 1e-7


def test_walker_torque_limit_as_the_simulator(model, gait):
    """The walker stops at the torque limit exactly like the full-order simulator (one
    definition of validity): a limit below the reference's peak fails both in the first step."""
    opts = SimulationOptions(steps=1, torque_limit=20.0)
    B = ZeroDynamicsWalker(model, gait, opts).walk(gait.q(0.0)[None], gait.dq(0.0)[None],
                                                   np.zeros(4), 0.5, steps=1)
    r = simulate(TimeVaryingController(gait, np.zeros(4)), options=opts)
    assert r.status == B.status[0] == "torque_limit"


def test_vc_walker_is_the_full_order_closed_loop(model, gait):
    """Virtual constraints from states on their constraint surface: the phase walker and
    the full-order simulator agree."""
    V = VirtualConstraintWalker(model, gait)
    xs = gait.state_at(0.75 * gait.T)
    X = xs + np.array([[0.0, 0.0], [0.01, -0.2], [-0.02, 0.3]])
    B = V.walk_from_section(X, steps=3)
    th, w = V.section_states(X)
    for i in range(len(X)):
        q, Q1, _ = (np.array(v).ravel() for v in V.vmap.curve(th[i]))
        r = simulate(VirtualConstraintController(gait), q, Q1 * w[i],
                     SimulationOptions(steps=3))
        assert r.status == B.status[i] == "ok"
        assert np.max(np.abs(r.dqu_error - B.dqu_error[i])) < 1e-8
        assert abs(r.peak_torque - B.peak_torque[i]) < 1e-2



@pytest.mark.parametrize("scale, index", [(0.9, 32), (1.5, 25), (1.5, 50), (1.0, 0),
                                          (1.0, 3), (0.5, 32)])
def test_vc_walker_verdicts_from_perturbed_starts(model, gait, scale, index):
    """From perturbed step starts (the s* protocol's), the phase walker passes exactly the
    runs the full-order simulator passes, with the same unactuated errors: among them a
    step that stalls (the phase rate turns back before the strike: the simulator rolls
    back and scuffs) and steps slower than the horizon (2 T: no impact in time), which the
    walker once passed."""
    d = directions(60, model.nq, seed=RobustnessSettings().seed)[index]
    q0, dq0 = start_states(gait, d[None], scale)
    opts = SimulationOptions(steps=10, mu=0.6)
    B = VirtualConstraintWalker(model, gait, opts).walk_from_states(q0, dq0, steps=10)
    r = simulate(VirtualConstraintController(gait), q0[0], dq0[0], opts)
    assert (B.verdict(1e-3)[0] == "ok") == (r.verdict(1e-3) == "ok")
    assert B.fail_step[0] == r.fail_step
    if r.status == "ok":
        assert np.max(np.abs(r.qu_error - B.qu_error[0])) < 1e-8
        assert abs(r.min_normal_force - B.min_normal_force[0]) < 1e-3
    else:       # the same cause, or no impact where the step stalls or runs late
        assert B.status[0] in (r.status, "no_impact")

# ------------------------------------------------------------------------ s*
def test_s_star_replayed_at_and_above(model, gait, deadbeat1):
    """A design replayed in the full-order simulator at its reported s*: every kept
    direction walks and converges; just above: the reported direction fails, for the
    reported cause."""
    st = RobustnessSettings(directions=4, rounds=7)
    kept = kept_directions(gait, st)
    design = Design(tuple(deadbeat1))
    r = robustness(Design.of(design, gait), st, kept=kept)
    assert 0 < r.s_star < r.s_fail < 2 and r.failure
    for d in kept.directions:
        run = _full_order(model, gait, design, d, r.s_star)
        assert run.verdict(1e-3) == "ok"
    f = r.failure
    run = _full_order(model, gait, design, kept.directions[f["direction"]], r.s_fail)
    assert run.status == f["status"] and run.fail_step == f["step"]
    # the paper's deadbeat recommendation does not survive the paper's perturbation
    assert r.s_star < 1 and r.paper["status"] != "ok"


def test_robustness_refuses_a_singular_design(gait):
    """A singular M1 (eq. 24) is refused by the Python API as by 'biped robust', before
    any run, instead of an s* of 0."""
    st = RobustnessSettings(directions=1, rounds=1)
    with pytest.raises(ValueError, match=r"^M1 = \[1\.0, 2\.0, 3\.0, 4\.0\] makes the "
                                         r"controller singular on the reference step"):
        robustness(Design.tv(gait, [1, 2, 3, 4]), st)


def test_virtual_constraints_walk_every_kept_direction(model, gait):
    """Virtual constraints walk 10 valid steps from the paper's full perturbation and
    every kept direction (by construction of the kept set; checked here) and converge
    at their eigenvalue's rate (0.54 on the default gait: 1.2e-3 left after 10 steps, so
    their convergence-based s* is below 1: see the report)."""
    st = RobustnessSettings(directions=4)
    kept = kept_directions(gait, st)
    dirs, tried, rejected = kept.directions, kept.tried, kept.rejected
    assert np.all(dirs[0] == 1) and tried == len(dirs) + sum(rejected.values())
    assert set(rejected) <= {"scuffed"}           # rejected: the swing foot starts in the ground
    runs = [simulate(VirtualConstraintController(gait), *(a[0] for a in
                     start_states(gait, d[None], 1.0))) for d in dirs]
    assert all(r.ok and len(r.steps) == 10 for r in runs)
    errs = [max(abs(r.qu_error[-1]), abs(r.dqu_error[-1])) for r in runs]
    assert max(errs) < 2e-3


def test_ad_and_variational_agree_on_a_continued_reference(model, robust_gait):
    """With the reference continued past T by an acceleration ramp, the full-AD map and
    the variational equation give the same A^z (the impact time lands on T to round-off:
    both sides see the polynomial)."""
    pm = poincare_map(robust_gait, rejoin=0.75)
    for M1 in ([-5.79, 2.91, 0.545, 5.69], [0.3, -0.2, 0.1, 0.4]):
        a = pm.analyse(np.array(M1))
        b = pm.analyse(np.array(M1), method="ad")
        assert np.max(np.abs(a.A - b.A)) < 1e-7 * np.max(np.abs(b.A))


def test_continuation_keeps_contact_past_T(model, gait, robust_gait):
    """Past T the Bezier reference loses ground contact within ~0.15 T on the default gait;
    the continued reference keeps it (the reason for the option)."""
    def fz(g, frac):
        t = g.T * np.asarray(frac)
        return np.array(model.ground_reaction_acc.map(t.size)(g.q(t), g.dq(t), g.ddq(t))[1]).ravel()
    assert fz(gait, [1.15]).min() < 0
    assert fz(robust_gait, np.linspace(1.0, 1.2, 9)).min() > 0


def test_smooth_continuation_is_C3_at_T_and_changes_nothing_before(model, robust_gait):
    """The 'smooth' continuation matches the reference up to its jerk at T (the ramp's
    jerk jumps there), is the same gait on [0, T], and the actuated joints' acceleration
    decays (their velocity tends to a constant)."""
    from gait_opt import Gait
    g = robust_gait
    gs = Gait(model, g.options.replace(continuation_shape="smooth"), g.alpha, g.x0, g.T)
    T = g.T
    t = np.linspace(0, T, 7)
    for a, b in zip(g.evaluate(t), gs.evaluate(t)):
        assert np.max(np.abs(a - b)) < 1e-12
    assert gs.orbit_residual()["worst"] < 1e-8

    def jerk_jump(gait, h):
        dd = gait.ddq
        return np.max(np.abs((dd(T + h) - dd(T)) / h - (dd(T) - dd(T - h)) / h))
    # the jump shrinks with h for the smooth one (finite differences of a C^3 join), not
    # for the ramp (a jerk discontinuity)
    assert jerk_jump(gs, 1e-5) < 0.02 * jerk_jump(g, 1e-5)
    assert jerk_jump(gs, 1e-6) < 0.2 * jerk_jump(gs, 1e-5)
    late = gs.ddq(np.array([1.6 * T, 1.9 * T]))[1:]          # the actuated joints
    assert np.max(np.abs(late)) < 1e-3 * np.max(np.abs(gs.ddq(T)[1:]))


def test_basin_outcomes(model, gait):
    b = basin(Design.vc(gait), n=5, q_span=0.01, dq_span=0.1, steps=3)
    assert b.outcome.shape == (5, 5) and b.outcome[2, 2] in ("converged", "walked")
    assert set(b.counts) <= {"converged", "walked", "slipped", "scuffed", "no_impact",
                             "negative_normal_force", "torque_limit", "fell"}
    t = basin(Design.tv(gait, (-2.5, 5.0, -2.5, 5.0)), n=5, q_span=0.01, dq_span=0.1,
              steps=3)
    assert t.outcome[2, 2] in ("converged", "walked")       # the fixed point walks
    assert 0 < t.converged_fraction + np.mean(t.outcome == "walked") <= 1
    with pytest.raises(ValueError, match="n"):
        basin(Design.vc(gait), n=1)


def test_basin_adaptive_grid_draws_the_full_grid(model, gait):
    """The adaptive grid (every 4th row and column, then the boundary cell by cell) walks
    fewer cells and gives the full grid's outcome on all but a few of them; where it
    walked a cell, the outcome and the final error are the full grid's exactly."""
    d = Design((-2.5, 5.0, -2.5, 5.0))
    full = basin(Design.of(d, gait), n=21, steps=4)
    ad = basin(Design.of(d, gait), n=21, steps=4, refine=4)
    assert full.walked_cells == 21 * 21 and ad.walked_cells < 21 * 21
    differ = np.sum(full.outcome != ad.outcome)
    assert differ <= 0.02 * 21 * 21, differ
    w = np.isfinite(ad.final_error) | (ad.final_error == np.inf)
    np.testing.assert_array_equal(ad.final_error[w], full.final_error[w])
    assert set(np.unique(full.outcome[w] == ad.outcome[w])) == {True}
    with pytest.raises(ValueError, match="refine"):
        basin(Design.of(d, gait), n=21, refine=3)


# ------------------------------------------------------------------------ CLI
def test_cli_robust(gait, tmp_path, capsys):
    path = str(gait.save(tmp_path / "gait.json"))
    rc = biped_main(["robust", "--gait", path, "--controller", "vc", "--directions", "2",
                     "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["controller"] == "vc" and out["directions_kept"] == 2
    assert out["s_star"] > 0 and out["success"]
    rc = biped_main(["robust", "--gait", path, "--m1", "-2.5", "5", "-2.5", "5",
                     "--directions", "2", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["design"]["M1"] == [-2.5, 5.0, -2.5, 5.0]
    assert out["design"]["rejoin"] == 0.5


@pytest.mark.parametrize("args, message", [
    (["--controller", "vc", "--m1", "0", "0", "0", "0"], "--m1"),
    (["--m1", "0", "0", "0", "0", "--rejoin", "0.9"], "--rejoin"),
    (["--m1", "0", "0", "0"], "--m1"),
    (["--m1", "0", "0", "0", "0", "--directions", "0"], "--directions"),
    (["--m1", "0", "0", "0", "0", "--mu", "-1"], "--mu"),
])
def test_cli_robust_bad_inputs(gait, tmp_path, capsys, args, message):
    path = str(gait.save(tmp_path / "gait.json"))
    rc = biped_main(["robust", "--gait", path] + args)
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1 and message in err[0]


def test_cli_simulate_rejoin(gait, tmp_path, capsys):
    path = str(gait.save(tmp_path / "gait.json"))
    rc = biped_main(["simulate", "--gait", path, "--m1", "-2.5", "5", "-2.5", "5",
                     "--rejoin", "0.75", "--steps", "1", "--perturb", "0.001", "0.01",
                     "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["controller"]["rejoin"] == 0.75
    assert biped_main(["simulate", "--gait", path, "--rejoin", "0.8"]) == 2
    assert "--rejoin" in capsys.readouterr().err


@pytest.mark.slow
def test_m1_robust_replays(tmp_path, capsys):
    """`biped m1 --robust --method search` (a small search): its simulate_args replay the
    design from the paper's perturbation as reported, and a second call is read from the
    cache."""
    args = ["m1", "--robust", "--method", "search", "--samples", "20000", "--starts", "1",
            "--json"]
    rc = biped_main(args)
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["s_star"] > 0.5 and out["max_abs"] <= out["vc_eigenvalue"]
    assert out["verified"]["at_s_star"]["passed"] == out["directions_kept"]
    rc = biped_main(["simulate"] + out["simulate_args"] + ["--json"])
    run = json.loads(capsys.readouterr().out)
    assert rc == 0
    conv = out["steps_to_converge"]
    assert run["status"] == "ok" if conv else True
    errs = [max(abs(s["qu_error"]), abs(s["dqu_error"])) for s in run["steps"]]
    np.testing.assert_allclose(errs, out["paper_errors"], rtol=1e-6, atol=1e-9)
    rc = biped_main(args)
    again = json.loads(capsys.readouterr().out)
    assert rc == 0 and again["cached"] and again["design"] == out["design"]


def test_s_star_batch_on_a_dask_cluster(model, gait):
    """The bisection of several designs on a real Dask LocalCluster (two worker
    processes, each building the walker once) gives exactly the in-process results."""
    distributed = pytest.importorskip("dask.distributed")
    from analysis.robustness import s_star_batch
    from biped_casadi.simulation import zero_dynamics_walker
    st = RobustnessSettings(directions=2, rounds=4, rk4_steps=200)
    dirs = kept_directions(gait, st).directions
    designs = [Design((-2.5, 5.0, -2.5, 5.0)), Design((-10.0, 7.5, 10.0, -5.0))]
    walker = zero_dynamics_walker(gait, st.simulation_options(), 200, jit=True)
    local = s_star_batch(walker, gait, designs, dirs, st, chunk=1)
    with distributed.LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                                  dashboard_address=None, host="127.0.0.1") as cluster:
        remote = s_star_batch(walker, gait, designs, dirs, st, chunk=1,
                              scheduler=cluster.scheduler_address)
    np.testing.assert_array_equal(local.s_star, remote.s_star)
    assert local.cause == remote.cause and local.scenario_steps == remote.scenario_steps


def test_cli_robust_paper_run_without_impact_prints_no_nan(gait3, tmp_path, capsys):
    """The paper's perturbation failing before any impact (three-link, deadbeat M1):
    its impact ratio reads 'n/a' as in ``biped simulate``, not 'nan'."""
    path = str(gait3.save(tmp_path / "g3.json"))
    rc = biped_main(["robust", "--gait", path, "--m1", "3.39", "-3.23", "--directions", "2"])
    out = capsys.readouterr().out
    assert rc == 0 and "slipped in step 1" in out, out       # the first step, counted from 1
    assert "nan" not in out and "max impulse ratio n/a" in out, out


@pytest.mark.parametrize("seed", [-1, 1.5, True])
def test_a_seed_that_is_not_one_is_named(seed):
    """numpy's generators said only 'expected non-negative integer' (that was the whole
    error line of 'biped robust --seed -1')."""
    from analysis.design import RobustDesignSettings
    for settings in (RobustnessSettings, RobustDesignSettings):
        with pytest.raises(ValueError, match=r"^seed must be an integer >= 0, got "):
            settings(seed=seed)
@pytest.mark.parametrize("field, value", [("directions", 0), ("directions", -2),
                                          ("directions", 2.5), ("steps", 0), ("rounds", 0),
                                          ("seed", -1), ("max_candidates", 0),
                                          ("rk4_steps", 100), ("tol", float("nan")),
                                          ("s_max", 0), ("mu", -0.6), ("torque_limit", 0)])
def test_robustness_settings_refuse_bad_values(field, value):
    with pytest.raises(ValueError, match=f"^{field} must") as e:
        RobustnessSettings(**{field: value})
    assert "\n" not in str(e.value)


def test_robustness_settings_take_numpy_integers():
    st = RobustnessSettings(directions=np.int64(4), rounds=np.int32(6))
    assert st == RobustnessSettings(directions=4, rounds=6)
    assert type(st.directions) is int and type(st.rounds) is int


def test_robustness_arguments_of_the_wrong_type_are_named(gait):
    d = Design.tv(gait, [-10, 7.5, 10, -5])
    with pytest.raises(ValueError, match="^settings must be a RobustnessSettings, got dict$"):
        robustness(d, {"directions": 2})
    with pytest.raises(ValueError, match="^settings must be a RobustnessSettings, got dict$"):
        kept_directions(gait, {})                   # an empty dict was the defaults
    with pytest.raises(ValueError, match="^kept must be the KeptDirections"):
        robustness(d, kept="kept.json")
    with pytest.raises(TypeError, match="^gait: a gait is needed"):
        kept_directions("gait.json")
    with pytest.raises(ValueError, match="^options must be a SimulationOptions, got dict$"):
        basin(d, n=3, options={"steps": 2})


def test_walker_inputs_are_named(gait):
    """A column M1 was reported as 'shape (1,)', a short q0 was CasADi's dimension error,
    a NaN start walked (status 'diverged') and a rejoin past the section was taken."""
    from biped_casadi.simulation import virtual_constraint_walker, zero_dynamics_walker
    w = zero_dynamics_walker(gait)
    q0, dq0, M1 = gait.q(0.0), gait.dq(0.0), [-10.0, 7.5, 10.0, -5.0]
    cases = [((q0, dq0, np.array(M1)[:, None], 0.5), r"^M1s must be \(4,\) or \(n, 4\), got shape \(4, 1\)$"),
             ((q0[:4], dq0, M1, 0.5), r"^q0 must be \(5,\) or \(n, 5\), got shape \(4,\)$"),
             ((q0 * np.nan, dq0, M1, 0.5), "^q0 must be finite$"),
             ((q0, dq0, M1, 2.0), r"^rejoin must be a number or \(n,\) numbers in \(0, 0.75\]"),
             ((q0, dq0, np.tile(M1, (3, 1)), [0.5, 0.5]), r"^scenarios: every argument has 1 or n rows"),
             ((np.tile(q0, (2, 1)), dq0, np.tile(M1, (3, 1)), 0.5), "^scenarios: every argument")]
    for args, message in cases:
        with pytest.raises(ValueError, match=message):
            w.walk(*args, steps=1)
    with pytest.raises(ValueError, match=r"^x must be \(2,\) or \(n, 2\)"):
        w.walk_from_section([0.1, 0.2, 0.3], M1, 0.5, steps=1)
    assert w.walk(np.tile(q0, (2, 1)), dq0, M1, [0.5, 0.75], steps=1).status.tolist() == \
        ["ok", "ok"]
    with pytest.raises(TypeError, match="^gait: a gait is needed"):
        zero_dynamics_walker("gait.json")
    with pytest.raises(ValueError, match=r"^nodes must be an integer >= 1, got 0$"):
        virtual_constraint_walker(gait, nodes=0)
