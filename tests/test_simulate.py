"""Full-order hybrid closed-loop simulation (paper eq. 9, §V-C) checked against the
reference and the Poincaré analysis, and its refusal to continue past invalid states.

Tolerances (RK4 with the default 2000 steps per T, the gait's own scheme):
- unperturbed runs repeat the reference: impact times to 1e-9 s, pre-impact states to
  ~1e-9 in the first step; the time-varying closed loop amplifies round-off and
  truncation by its eigenvalues step to step (M1 = 0 is unstable, |lambda| ~ 12; the
  random M1 is drawn with |lambda| < 30), so the bound is 1e-9 * 30^k at step k;
- section errors of a 1e-6 perturbation follow delta x_{k+1} = A^z delta x_k to 1e-3
  relative (nonlinear terms ~ |delta x|, the map's own discretisation ~ 1e-10);
- the VC step-to-step ratio of dq_u errors converges to its eigenvalue: 2e-3 relative
  from a 1e-4 perturbation (nonlinear terms), 2 % for the paper's large perturbation.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from analysis.stability import vc_eigenvalue
from analysis.cli import main as biped_main
from biped_casadi.control import TimeVaryingController, VirtualConstraintController
from biped_casadi import Perturbation, directions
from biped_casadi.simulation.options import friction_of
from biped_casadi.simulation import (PAPER_SIZES, STATUSES, SimulationOptions, Simulator,
                                   perturbed_initial_state, simulate)


@pytest.fixture(scope="module")
def random_m1(gait, model):
    """A random output matrix M1 (components in [-3, 3]) not singular on the step and
    with max|lambda| < 30, so that round-off stays small over three steps (near-singular
    M1 give eigenvalues in the thousands)."""
    from analysis import poincare_eigenvalues
    rng = np.random.default_rng(7)
    for _ in range(100):
        M1 = rng.uniform(-3, 3, 4)
        if TimeVaryingController(gait, M1).singularity().singular:
            continue
        if poincare_eigenvalues(gait, M1).max_abs < 30:
            return M1
    raise AssertionError("no suitable random M1 found")


@pytest.fixture(scope="module")
def tv0(model, gait):
    return TimeVaryingController(gait, np.zeros(4))


@pytest.fixture(scope="module")
def tvr(model, gait, random_m1):
    return TimeVaryingController(gait, random_m1)


@pytest.fixture(scope="module")
def vc(model, gait):
    return VirtualConstraintController(gait)


@pytest.fixture(scope="module")
def stable_m1(model, gait):
    """The most stable M1 of a coarse 5^4 grid on [-10, 10]^4 (exact A^z)."""
    from analysis import PoincareMap
    v = np.linspace(-10, 10, 5)
    pts = np.array(np.meshgrid(v, v, v, v, indexing="ij")).reshape(4, -1).T
    jb = PoincareMap(model, gait).jacobian_batch(pts)
    status, max_abs = jb.status, jb.max_abs
    i = int(np.argmin(np.where(status == "stable", max_abs, np.inf)))
    assert status[i] == "stable"
    return pts[i]


# -------------------------------------------------- the reference is repeated
@pytest.mark.parametrize("which", ["tv_M1_zero", "tv_M1_random", "vc"])
def test_unperturbed_run_repeats_reference(gait, tv0, tvr, vc, which):
    ctrl = {"tv_M1_zero": tv0, "tv_M1_random": tvr, "vc": vc}[which]
    res = simulate(ctrl, options=SimulationOptions(steps=3))
    assert res.status == "ok" and len(res.steps) == 3
    qT, dqT = gait.q(gait.T), gait.dq(gait.T)
    q0, dq0 = gait.q(0.0), gait.dq(0.0)
    for k, s in enumerate(res.steps):
        tol = 1e-9 * 30.0**k                       # growth by |lambda| < 30 per step
        assert abs(s.duration - gait.T) < tol
        assert abs(s.t_impact - (k + 1) * gait.T) < 3 * tol
        np.testing.assert_allclose(s.q_minus, qT, atol=tol)
        np.testing.assert_allclose(s.dq_minus, dqT, atol=10 * tol)
        np.testing.assert_allclose(s.q_plus, q0, atol=tol)
        np.testing.assert_allclose(s.dq_plus, dq0, atol=10 * tol)
        assert abs(s.step_length - gait.step_length) < tol
    # along the first step the torques are the reference torques and the outputs vanish
    first = res.step == 0
    np.testing.assert_allclose(res.u[first], gait.u(res.tau[first]).T, atol=1e-6)
    assert np.max(np.abs(res.y[first])) < 1e-9
    assert np.all(np.diff(res.t) >= 0)


def test_impacts_are_on_the_guard(tvr):
    """Every impact is located on the SPEC §4 guard: z_sw = 0, x_sw > 0, moving down."""
    m = tvr.model
    res = simulate(tvr, *perturbed_initial_state(tvr.gait, 1e-5, 1e-4),
                   options=SimulationOptions(steps=2))
    assert res.status == "ok"
    assert max(abs(s.duration - tvr.gait.T) for s in res.steps) > 1e-7   # not on the grid
    for s in res.steps:
        x, z = (float(v) for v in m.swing_foot(s.q_minus))
        _, dz = (float(v) for v in m.swing_foot_velocity(s.q_minus, s.dq_minus))
        assert abs(z) < 1e-13 and x > 0 and dz < 0
        assert s.impulse[1] > 0 and abs(s.impulse[0]) <= 0.6 * s.impulse[1]


# ----------------------------------------------- against the Poincaré analysis
@pytest.mark.parametrize("which", ["zero", "stable"])
def test_tv_section_errors_follow_Az(model, gait, tv0, stable_m1, which):
    """Time-varying control: the (q_u, dq_u) error at tau = 0.75 T propagates step to
    step as delta x_{k+1} = A^z delta x_k, A^z the exact Jacobian of the restricted
    Poincaré map (analysis.poincare_eigenvalues); for a stable M1 it contracts."""
    from analysis import poincare_eigenvalues
    ctrl = tv0 if which == "zero" else TimeVaryingController(gait, stable_m1)
    M1 = ctrl.M1
    A = poincare_eigenvalues(gait, M1).A
    q0, dq0 = gait.q(0.0), gait.dq(0.0)
    q0[0] += 1e-6
    dq0[0] -= 2e-6
    res = simulate(ctrl, q0, dq0, SimulationOptions(steps=4 if which == "stable" else 3))
    assert res.status == "ok"
    E = res.section_errors
    assert np.all(np.isfinite(E))
    for k in range(len(E) - 1):
        pred = A @ E[k]
        assert np.linalg.norm(E[k + 1] - pred) <= 1e-3 * np.linalg.norm(pred) + 1e-10
    norms = np.linalg.norm(E, axis=1)
    if which == "stable":
        assert norms[-1] < norms[0]
    else:
        assert norms[-1] > 10 * norms[0]           # M1 = 0 is unstable for this gait


def test_vc_error_ratio_converges_to_eigenvalue(model, gait, vc):
    """Virtual constraints: the configuration at impact is the reference one and the
    step-to-step ratio of dq_u errors before impact tends to the 1-D map's eigenvalue."""
    lam = vc_eigenvalue(gait).eigenvalue
    q0, dq0 = perturbed_initial_state(gait, 0.0, 1e-4)
    res = simulate(vc, q0, dq0, SimulationOptions(steps=5))
    assert res.status == "ok"
    assert np.max(np.abs(res.qu_error)) < 1e-10
    ratios = res.dqu_error[1:] / res.dqu_error[:-1]
    assert abs(ratios[-1] - lam) < 2e-3 * lam


def test_paper_fig5_perturbation_vc(model, gait, vc):
    """Paper §V-C: from 0.01 rad on each joint and 0.1 rad/s on each velocity the
    virtual-constraint controller walks on, with the desired configuration at every
    impact and the velocity error shrinking by about its eigenvalue per step."""
    lam = vc_eigenvalue(gait).eigenvalue
    res = simulate(vc, *perturbed_initial_state(gait, *PAPER_SIZES),
                   options=SimulationOptions(steps=8))
    assert res.status == "ok", res.message
    assert np.max(np.abs(res.qu_error)) < 1e-9
    d = np.abs(res.dqu_error)
    assert np.all(np.diff(d) < 0)
    assert abs(res.dqu_error[-1] / res.dqu_error[-2] - lam) < 0.02 * lam


def test_paper_fig5_perturbation_tv_reports_status(model, gait, stable_m1):
    """The same perturbation with time-varying control ends in a definite status; when
    the run stops, the last logged state (or impact) is the invalid one and every
    earlier state satisfies all the checks: nothing continues silently."""
    ctrl = TimeVaryingController(gait, stable_m1)
    opts = SimulationOptions(steps=6)
    mu = friction_of(gait, opts.mu)                     # the gait's
    res = simulate(ctrl, *perturbed_initial_state(gait, *PAPER_SIZES), options=opts)
    assert res.status in STATUSES
    ok_nodes = slice(0, -1) if res.status != "ok" else slice(None)
    assert np.all(res.Fz[ok_nodes] >= 0)
    assert np.all(np.abs(res.Fx[ok_nodes]) <= mu * res.Fz[ok_nodes])
    if res.status == "ok":
        assert len(res.steps) == 6
    else:
        assert res.message and res.failure_time <= res.t[-1] + 1e-12
        if res.status == "slipped" and "impulse" in res.message:
            F = res.steps[-1].impulse
            assert abs(F[0]) > mu * F[1]


# ------------------------------------------------------------- statuses
def test_status_slipped_when_reference_leaves_cone(gait, vc):
    """mu = 0.3 is below the reference's friction demand: the run stops as 'slipped' at
    the first time |F_x| > 0.3 F_z on the reference (within one RK4 step)."""
    m = gait.model
    opts = SimulationOptions(steps=1, mu=0.3)
    res = simulate(vc, options=opts)
    t = np.linspace(0, gait.T, 20001)
    Fx, Fz = (np.array(v).ravel() for v in m.ground_reaction_acc.map(t.size)(
        gait.q(t), gait.dq(t), gait.ddq(t)))
    t_first = t[np.argmax(np.abs(Fx) > 0.3 * Fz)]
    assert res.status == "slipped"
    assert abs(res.failure_time - t_first) <= gait.T / opts.rk4_steps + 1e-4
    assert abs(res.Fx[-1]) > 0.3 * res.Fz[-1]
    assert np.all(np.abs(res.Fx[:-1]) <= 0.3 * res.Fz[:-1])


def test_status_negative_normal_force(gait, tv0):
    """A normal-force floor above the reference's minimum stops the run where F_z^d(t)
    first drops below it."""
    m = gait.model
    t = np.linspace(0, gait.T, 20001)
    _, Fz = (np.array(v).ravel() for v in m.ground_reaction_acc.map(t.size)(
        gait.q(t), gait.dq(t), gait.ddq(t)))
    floor = Fz.min() + 0.3 * (Fz[0] - Fz.min())
    res = simulate(tv0, options=SimulationOptions(steps=1, min_normal_force=float(floor)))
    assert res.status == "negative_normal_force"
    t_first = t[np.argmax(Fz < floor)]
    assert abs(res.failure_time - t_first) <= gait.T / 2000 + 1e-4
    assert res.Fz[-1] < floor and np.all(res.Fz[:-1] >= floor)


def test_status_scuffed_foot_starts_in_ground(gait, vc):
    """-0.01 rad on every joint puts the swing foot below the ground behind the stance
    foot at t = 0: scuffed immediately."""
    q0, dq0 = perturbed_initial_state(gait, -0.01, 0.0)
    assert float(gait.model.swing_foot(q0)[1]) < 0
    res = simulate(vc, q0, dq0, SimulationOptions(steps=2))
    assert res.status == "scuffed" and res.failure_time == 0.0 and not res.steps


def test_a_scuff_between_two_nodes_stops_the_run(gait, vc, monkeypatch):
    """At the step's start (the swing foot on the ground behind the stance foot) the swing
    knee turned so that the foot moves down at 2 mm/s: the law lifts it again within
    the first RK4 step, the foot below the ground between the first two nodes (found
    here by sampling the step at 64 lengths) and above it at both.  The run stops there,
    scuffed, at the time the samples say; checked at the nodes only it goes on."""
    q0, dq0 = perturbed_initial_state(gait, 0.0, 0.0)
    model = gait.model

    def foot_speed(dq):
        return float(model.swing_foot_velocity(q0, dq)[1])

    knee = np.eye(model.nq)[-1]                     # z_sw's rate is linear in dq
    dq = dq0 + (-2e-3 - foot_speed(dq0)) / (foot_speed(dq0 + knee) - foot_speed(dq0)) * knee
    sim = Simulator(vc, SimulationOptions(steps=1))
    start = vc.step_start(q0, dq)
    X = np.r_[q0, dq, start.r]
    etas = np.linspace(0, sim.h, 65)
    z = np.array([float(np.ravel(sim.event(X, 0.0, eta, start.p)[0])[0]) for eta in etas])
    tol = sim.limits.ground_tolerance
    assert z[0] >= -tol and z[-1] > 0 and z.min() < -10 * tol
    res = sim.run(q0, dq)
    assert res.status == "scuffed" and "between two RK4 nodes" in res.message
    assert abs(res.failure_time - etas[np.argmin(z)]) <= etas[1]
    assert float(model.swing_foot(res.q[-1])[1]) == pytest.approx(z.min(), rel=1e-2)
    monkeypatch.setattr(Simulator, "_dip", lambda *args: None)      # the nodes only
    at_nodes = Simulator(vc, SimulationOptions(steps=1)).run(q0, dq)
    assert not at_nodes.failure_time <= sim.h


@pytest.mark.parametrize("z0, x_sw, scuff_zone, ignored, kind", [
    (1e-7, 0.3, 0.0, False, "strike"), (1e-7, -0.3, 0.0, False, "scuffed"),
    (1e-7, -0.3, 0.1, True, None), (1e-7, 0.05, 0.1, True, None),
    (1e-7, 0.3, 0.1, True, "strike"), (3e-7, -0.3, 0.0, False, None)])
def test_a_dip_between_two_nodes_is_a_strike_in_front_and_a_scuff_behind(
        z0, x_sw, scuff_zone, ignored, kind):
    """The swing foot on z = z0 - 2e-3 eta + 5 eta^2 along a step of 1 ms (its rate -2 mm/s
    at the first node, +8 mm/s at the last), lowest at eta = 0.2 ms, z0 - 2e-7 m: below
    the ground, in front of the stance foot (beyond the scuff zone) it is a strike, behind
    it a scuff, ignored where the robot's scuffing is; above the ground, nothing."""
    from types import SimpleNamespace

    def dip(X, tau, eta, p):
        return (np.array([[z0 - 2e-3 * eta + 5 * eta ** 2]]), np.array([[-2e-3 + 10 * eta]]),
                np.array([[10.0]]), np.array([[x_sw]]), np.zeros((1, 1)))

    sim = SimpleNamespace(dip=dip, h=1e-3, plant=SimpleNamespace(scuff_zone=scuff_zone),
                          limits=SimpleNamespace(scuffing_ignored=ignored,
                                                 ground_tolerance=1e-9))
    got = Simulator._dip(sim, np.zeros(1), 0.0, None, np.zeros((1, 1)), np.array([1e-3]),
                         np.array([z0]), np.array([-2e-3]), np.array([8e-3]), None, 1)
    if kind is None:
        assert got is None
        return
    j, what, info, eta, _ = got
    assert (j, what) == (0, kind) and eta == pytest.approx(2e-4, rel=1e-12)
    if kind == "strike":
        assert info == pytest.approx(z0 - 2e-7, rel=1e-9)      # z at the minimum
    else:
        assert info.endswith("x_sw = -0.3000 m, z_sw = -1e-07 m, between two RK4 nodes")


def test_status_fell(gait, vc):
    """'fell' when the hip is lower than min_hip_height or the torso leans more than
    max_torso_angle: thresholds beyond the reference's extremes let it walk; a hip
    level above its lowest point (at t = 0 on this gait: checked) stops the run at once;
    a lean threshold inside its range stops it where the reference first exceeds it."""
    m = gait.model
    t = np.linspace(0, gait.T, 20001)
    q = gait.q(t)
    hip = np.array(m.points.map(t.size)(q)).reshape(2, 6, t.size, order="F")[1, 2]
    lean = np.abs(q[0] + q[1] + q[2])
    assert hip[0] <= hip.min() + 1e-9 and lean.max() > lean[0] + 1e-3
    ok = simulate(vc, options=SimulationOptions(steps=1, min_hip_height=hip.min() - 1e-3,
                                                max_torso_angle=lean.max() + 1e-3))
    assert ok.status == "ok"
    low = simulate(vc, options=SimulationOptions(steps=1, min_hip_height=hip.min() + 1e-3))
    assert low.status == "fell" and "hip" in low.message and low.failure_time == 0.0
    level = float(0.5 * (lean[0] + lean.max()))
    bent = simulate(vc, options=SimulationOptions(steps=1, max_torso_angle=level))
    assert bent.status == "fell" and "torso" in bent.message and not bent.steps
    assert abs(bent.failure_time - t[np.argmax(lean > level)]) <= gait.T / 2000 + 1e-4


def test_status_torque_limit(gait, vc):
    """A torque limit below the reference's peak |u^d| stops the run ('torque_limit') at
    the first node where some |u_i| exceeds it; the robot's own limit (150 N m) lets it
    walk."""
    t = np.linspace(0, gait.T, 20001)
    peak = np.abs(gait.u(t)).max(axis=0)
    limit = float(0.8 * peak.max())
    assert simulate(vc, options=SimulationOptions(steps=1)).status == "ok"
    res = simulate(vc, options=SimulationOptions(steps=1, torque_limit=limit))
    assert res.status == "torque_limit" and "torque limit" in res.message
    assert np.abs(res.u[-1]).max() > limit and np.all(np.abs(res.u[:-1]) <= limit)
    assert abs(res.failure_time - t[np.argmax(peak > limit)]) <= gait.T / 2000 + 1e-4
    assert res.peak_torque > limit


def test_status_impulse_outside_cone(gait, vc):
    """mu between the reference's single-support friction demand and its impact-impulse
    ratio: the step itself is valid, the impact is not ('slipped', impulse)."""
    c = gait.check()
    mu = 0.5 * (c["max_friction_ratio"] + c["impact_friction_ratio"])
    res = simulate(vc, options=SimulationOptions(steps=2, mu=mu))
    assert res.status == "slipped" and "impulse" in res.message
    assert len(res.steps) == 1 and res.max_impulse_ratio > mu > res.max_friction_ratio
    F = res.steps[0].impulse
    assert abs(F[0]) > mu * F[1]


def test_status_no_liftoff(gait, vc):
    """The old stance foot must leave the ground after the impact: a lift-off speed floor
    above the reference's stops the run at the first impact ('scuffed')."""
    v = gait.check()["liftoff_velocity"]
    assert simulate(vc, options=SimulationOptions(steps=1, min_liftoff_speed=0.5 * v)).status == "ok"
    res = simulate(vc, options=SimulationOptions(steps=2, min_liftoff_speed=1.5 * v))
    assert res.status == "scuffed" and "lift off" in res.message and len(res.steps) == 1


def test_perturbation_type(gait):
    p = Perturbation.paper()
    q0, dq0 = p.initial_state(gait)
    np.testing.assert_allclose(q0 - gait.q(0.0), 0.01)
    np.testing.assert_allclose(dq0 - gait.dq(0.0), 0.1)
    d = directions(16, 5, seed=3)
    assert d.shape == (16, 10) and np.all(d[0] == 1)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), np.sqrt(10))
    assert np.array_equal(d, directions(16, 5, seed=3))          # reproducible
    half = Perturbation.from_direction(d[1], scale=0.5)
    np.testing.assert_allclose(half.q, 0.005 * d[1, :5])
    np.testing.assert_allclose(half.dq, 0.05 * d[1, 5:])
    with pytest.raises(ValueError, match="dq"):
        Perturbation((0.0,) * 5, (0.0,) * 4)
    with pytest.raises(ValueError, match="joints"):
        Perturbation.uniform(4, 0.1, 0.1).initial_state(gait)


def test_status_no_impact_and_singular(model, gait, tv0):
    res = simulate(tv0, options=SimulationOptions(steps=1, horizon=0.9))
    assert res.status == "no_impact" and res.failure_time == pytest.approx(0.9 * gait.T)
    # eq. (24): D11 - D12 M1 crosses zero during the step
    D = np.array(model.D(gait.q(0.5 * gait.T)))
    sing = TimeVaryingController(gait, [D[0, 0] / D[0, 1], 0, 0, 0])
    res = simulate(sing, options=SimulationOptions(steps=1))
    assert res.status == "singular"
    rep = sing.singularity()
    assert rep.singular
    scale = max(abs(rep.min_value), abs(rep.max_value))
    den = res.denominator
    assert abs(den[-1]) < 0.01 * scale and np.all(np.abs(den[:-1]) >= 0.01 * scale)
    assert 0 < res.failure_time < gait.T


def test_bad_input(gait, vc):
    with pytest.raises(ValueError, match="q0"):
        simulate(vc, np.zeros(4), np.zeros(5))
    with pytest.raises(ValueError, match="dq0"):
        simulate(vc, np.zeros(5), np.full(5, np.nan))
    with pytest.raises(ValueError, match="rk4_steps"):
        SimulationOptions(rk4_steps=1001)
    with pytest.raises(ValueError, match="mu"):
        SimulationOptions(mu=-1.0)
    with pytest.raises(ValueError, match="q_error"):
        perturbed_initial_state(gait, [0.1, 0.2], 0.0)
    with pytest.raises(ValueError, match="options"):
        Simulator(vc, options={"steps": 2})


def test_bad_input_from_a_notebook(gait, vc):
    """What a user gets wrong: no controller, a path for the gait, words for heights;
    each one line naming the argument.  numpy integers count as integers."""
    for call in (lambda: simulate(None), lambda: Simulator("tv")):
        with pytest.raises(TypeError, match="^controller: .* is needed, got (NoneType|str)$"):
            call()
    for bad in (None, "gait.json"):
        with pytest.raises(TypeError, match="^gait: a gait is needed"):
            perturbed_initial_state(bad, 0.01, 0.1)
    with pytest.raises(ValueError, match="^terrain must be numbers"):
        simulate(vc, steps=2, terrain=[0.0, "x"])
    assert SimulationOptions(steps=np.int64(3), rk4_steps=np.int32(400)) == \
        SimulationOptions(steps=3, rk4_steps=400)
    assert type(SimulationOptions(steps=np.int64(3)).steps) is int
    with pytest.raises(ValueError, match="steps"):
        SimulationOptions(steps=np.float64(3.0))
    run = simulate(vc, steps=np.int64(1))
    assert run.n_steps == 1


# ---------------------------------------------------------------- CLI
def test_cli_simulate_json(gait, tmp_path, capsys):
    path = gait.save(tmp_path / "gait.json")
    rc = biped_main(["simulate", "--gait", str(path), "--controller", "vc", "--steps", "2",
                     "--perturb", "0.001", "0.01", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["status"] == "ok" and len(out["steps"]) == 2
    for s in out["steps"]:
        assert {"t_impact", "qu_error", "dqu_error"} <= set(s)
        assert abs(s["qu_error"]) < 1e-9           # VC: configuration at impact is exact
    assert out["steps"][1]["t_impact"] > out["steps"][0]["t_impact"] > 0


def test_cli_simulate_figures(gait, tmp_path, capsys):
    from PIL import Image
    path = gait.save(tmp_path / "gait.json")
    rc = biped_main(["simulate", "--gait", str(path), "--controller", "tv", "--steps", "2",
                     "--compare", "--plot", str(tmp_path / "fig"),
                     "--animate", str(tmp_path / "walk.gif")])
    text = capsys.readouterr().out
    assert rc == 0 and "tv: status ok" in text and "vc: status ok" in text
    for name in ("fig5_qu_error.png", "fig6_swing_torques.png"):
        with Image.open(tmp_path / "fig" / name) as im:
            assert im.size[0] > 300 and im.size[1] > 300
    with Image.open(tmp_path / "walk.gif") as im:
        assert im.n_frames >= 25 * 2 * gait.T - 1      # 25 frames per simulated second


def test_cli_simulate_per_joint_perturbation(gait, tmp_path, capsys):
    """--perturb-q/--perturb-dq give any per-joint error; JSON has the validity margins."""
    path = gait.save(tmp_path / "gait.json")
    rc = biped_main(["simulate", "--gait", str(path), "--controller", "vc", "--steps", "1",
                     "--perturb-q", "0.002", "0", "0", "0", "0.001", "--perturb-dq", "0.05",
                     "0", "0", "0", "0", "--json"])
    out = json.loads(capsys.readouterr().out)
    assert rc == 0 and out["status"] == "ok" and out["success"]
    assert out["perturbation"]["q"] == [0.002, 0, 0, 0, 0.001]
    for k in ("peak_torque", "min_normal_force", "max_friction_ratio", "max_impulse_ratio"):
        assert out[k] > 0
    rc = biped_main(["simulate", "--gait", str(path), "--controller", "vc", "--steps", "1",
                     "--torque-limit", "20", "--json"])
    out = json.loads(capsys.readouterr().out)
    # success: the run was simulated; its verdict is the status, and the exit code 1
    assert rc == 1 and out["status"] == "torque_limit" and out["success"]


def test_cli_simulate_bad_input(gait, tmp_path, capsys):
    path = gait.save(tmp_path / "gait.json")
    assert biped_main(["simulate", "--gait", str(path), "--m1", "1", "2", "3"]) == 2
    assert "--m1" in capsys.readouterr().err
    assert biped_main(["simulate", "--gait", str(path), "--animate", "x.mp4"]) == 2
    assert ".gif" in capsys.readouterr().err
    assert biped_main(["simulate", "--gait", str(tmp_path / "missing.json")]) == 2
    capsys.readouterr()
    assert biped_main(["simulate", "--gait", str(path), "--perturb-q", "0.1", "0.1"]) == 2
    assert "--perturb-q takes 5" in capsys.readouterr().err
    assert biped_main(["simulate", "--gait", str(path), "--perturb", "0", "0",
                       "--perturb-dq", "0", "0", "0", "0", "0"]) == 2
    assert "excludes" in capsys.readouterr().err
    assert biped_main(["simulate", "--gait", str(path), "--torque-limit", "-3"]) == 2
    assert "--torque-limit" in capsys.readouterr().err


def test_messages_count_steps_from_one(gait, vc, tmp_path, capsys):
    """A message names a step counted from 1 (step 1: from the start state to the first
    impact), the row of ``biped simulate``'s table and Fig. 5's axis for the same step;
    ``fail_step`` stays the 0-based index (a field scripts read)."""
    from biped_casadi.simulation import NOT_CONVERGED, failure_text
    # an 8 cm step up at the third foothold: the third step cannot strike, two rows
    r = simulate(vc, steps=4, terrain=[0.0, 0.0, 0.08])
    assert r.status == "scuffed" and r.message.startswith("step 3: "), r.message
    assert r.fail_step == 2 and [s.index + 1 for s in r.steps] == [1, 2]
    # a 3 cm step up at the second foothold: the second impact's impulse leaves the cone;
    # its row (2) is in the table, and the message names step 2
    path = gait.save(tmp_path / "gait.json")
    args = ["simulate", "--gait", str(path), "--controller", "vc", "--steps", "4",
            "--terrain", "0", "0.03", "0.03"]
    biped_main(args + ["--json"])
    out = json.loads(capsys.readouterr().out)
    assert out["status"] == "slipped" and out["message"].startswith("step 2: impact impulse")
    assert out["fail_step"] == 1 and len(out["steps"]) == 2
    biped_main(args)
    text = capsys.readouterr().out.splitlines()
    assert text[0].startswith("vc: status slipped - step 2: impact impulse"), text
    rows = [line.split()[0] for line in text[2:] if line.split()[0].isdigit()]
    assert rows == ["1", "2"], text
    # the same rule in the robustness texts
    assert failure_text("slipped", 0) == "slipped in step 1"
    assert failure_text(NOT_CONVERGED, 10) == "not_converged after step 10"


def test_cli_simulate_says_whether_the_error_settled(gait, stable_m1, tmp_path, capsys):
    """A valid run is not a converged one: the text says from which step the error stays
    below 1e-3, or that it did not settle and which way it went (with the default M1 = 0,
    unstable on RABBIT's gait, that it is not a design); the JSON carries the verdict and
    the step, as the library computes them."""
    path = str(gait.save(tmp_path / "gait.json"))
    args = ["simulate", "--gait", path, "--controller", "tv", "--steps", "2",
            "--perturb", "0.0001", "0.001"]
    assert biped_main(args) == 0
    text = capsys.readouterr().out
    assert "tv: status ok" in text and "at step 2 (growing, x" in text
    assert "a step); not converged (not below 0.001" in text
    assert "M1 = 0 (the default) is not a stable design" in text
    assert biped_main(args + ["--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["status"] == "ok" and out["verdict"] == "not_converged"
    assert out["steps_to_converge"] is None and out["converged_below"] == 1e-3
    m1 = [str(v) for v in stable_m1]
    stable = ["simulate", "--gait", path, "--controller", "tv", "--m1", *m1, "--steps", "10",
              "--perturb", "0.001", "0.01"]
    assert biped_main(stable + ["--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    r = simulate(TimeVaryingController(gait, stable_m1), *Perturbation.uniform(
        gait.model.nq, 0.001, 0.01).initial_state(gait), SimulationOptions(steps=10))
    assert out["verdict"] == r.verdict(1e-3) == "ok"
    assert out["steps_to_converge"] == int(r.steps_to_converge(1e-3))
    assert biped_main(stable) == 0
    text = capsys.readouterr().out
    assert f"below 0.001 from step {out['steps_to_converge']}" in text
    assert "(falling, x0." in text and "not converged" not in text and "M1 = 0" not in text


def test_result_repr_reads_in_a_notebook(gait, vc):
    """The repr of a run is one short line of Python numbers: the logs (20 000 samples
    of every signal) and the per-step records are summarised, not printed."""
    run = simulate(vc, steps=3)
    text = repr(run)
    assert text.startswith("SimulationResult(status='ok', ")
    assert "\n" not in text and len(text) < 800
    assert "np." not in text and "array(" not in text
    assert "steps=<list of 3>" in text and "qu_error=[" in text   # 3 numbers: shown
    assert "dq=" not in text                                    # a log: left out
    json.dumps(run.to_dict(), allow_nan=False)


def test_directions_need_joints():
    with pytest.raises(ValueError, match=r"^nq \(joints\) must be a positive integer"):
        directions(3, nq=0)                            # was an empty (3, 0) array
    assert directions(3, nq=np.int64(3)).shape == (3, 6)


def test_start_states_name_the_directions(gait):
    """Directions of the wrong width were numpy's 'operands could not be broadcast'."""
    from biped_casadi.simulation import start_states
    with pytest.raises(ValueError, match=r"^dirs must be \(10,\) or \(n, 10\), got shape \(2, 3\)$"):
        start_states(gait, np.ones((2, 3)), 1.0)
    with pytest.raises(TypeError, match="^gait: a gait is needed"):
        start_states("gait.json", directions(2), 1.0)
    q0, dq0 = start_states(gait, directions(2), 0.0)
    np.testing.assert_array_equal(q0, np.tile(gait.q(0.0), (2, 1)))


def test_a_design_runs_wherever_its_controller_does(gait):
    """Simulator and step_map (hence gait_sensitivity) take a Design as simulate does
    (Simulator(design) was an AttributeError, then a TypeError naming the Design)."""
    from analysis.stability import step_map
    from biped_casadi import Design
    d = Design.tv(gait, [-10, 7.5, 10, -5])
    a = Simulator(d, SimulationOptions(steps=1)).run(gait.q(0.0), gait.dq(0.0))
    b = simulate(d.controller_for(), steps=1)
    assert a.status == b.status == "ok"
    np.testing.assert_array_equal(a.qu_error, b.qu_error)
    assert isinstance(step_map(d).controller, TimeVaryingController)


def test_friction_defaults_to_the_gaits(gait, tmp_path, capsys):
    """A gait that records a friction coefficient is judged at it when none is given (in
    Python and by ``biped simulate``), and the output says which; ``--mu`` overrides.
    The gait's orbit with mu between its single-support ratio and its impact-impulse
    ratio recorded: only the impact leaves that cone."""
    from gait_opt import Gait
    c = gait.check()
    mu = 0.5 * (c["max_friction_ratio"] + c["impact_friction_ratio"])
    own = Gait(gait.model, gait.options.replace(mu=mu), gait.alpha, gait.x0, gait.T)
    res = simulate(VirtualConstraintController(own), options=SimulationOptions(steps=2))
    assert res.status == "slipped" and "impulse" in res.message
    path = own.save(tmp_path / "own.json")
    args = ["simulate", "--gait", str(path), "--controller", "vc", "--steps", "2"]
    assert biped_main(args + ["--json"]) == 1                  # the walk stopped
    out = json.loads(capsys.readouterr().out)
    assert out["status"] == "slipped" and out["mu"] == pytest.approx(mu)
    assert biped_main(args) == 1
    text = capsys.readouterr().out
    assert text.startswith("vc: status slipped") and f"(mu {mu:g}, the gait's)" in text
    assert biped_main(args + ["--mu", "0.6", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["status"] == "ok" and out["mu"] == 0.6


def test_cli_simulate_growth_factor_counts_from_above_round_off(gait, model, tmp_path,
                                                                capsys):
    """An unperturbed run of the unstable M1 = 0 starts at round-off (below 1e-8, the
    floor of the factor) and grows by the dominant eigenvalue a step: the factor the text
    prints is measured from the first step above round-off, so it is that eigenvalue, not
    the floor's smaller mean over all steps."""
    from analysis import poincare_eigenvalues
    import re
    path = str(gait.save(tmp_path / "gait.json"))
    assert biped_main(["simulate", "--gait", path, "--controller", "tv", "--steps", "6"]) == 0
    text = capsys.readouterr().out
    rate = float(re.search(r"growing, x(\S+) a step", text).group(1))
    lam = poincare_eigenvalues(model, gait, np.zeros(4)).max_abs
    assert lam > 1.05 and abs(rate / lam - 1) < 0.1, (rate, lam, text)
