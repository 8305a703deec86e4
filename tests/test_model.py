"""Physics invariants of the CasADi model (not a re-derivation of its formulas)."""
from __future__ import annotations

import dataclasses
import json

import casadi as ca
import numpy as np
import pytest

from biped_casadi import RABBIT, BipedModel, E_RELABEL, RobotParams, load_params, rabbit


def random_states(rng, n):
    q = rng.uniform(-1.0, 1.0, size=(n, 5))
    dq = rng.uniform(-2.0, 2.0, size=(n, 5))
    return q, dq


def walking_pre_impact():
    """A symmetric double-support configuration of a normal step (both feet on ground)."""
    # absolute angles: stance leg leaning forward, swing leg mirrored ahead of the hip,
    # torso upright, knees slightly bent (q2 <= 0, q5 >= 0)
    q = np.array([0.25, -0.05, -0.2, -0.25, 0.05])
    # move q1 so that the swing foot is on the ground: solve z_sw = 0 along q1
    m = rabbit()
    from scipy.optimize import brentq
    q1 = brentq(lambda a: float(m.swing_foot(np.r_[a, q[1:]])[1]), 0.1, 0.4)
    q[0] = q1
    return q


def test_kinematics_upright(model):
    q0 = np.zeros(5)
    P = np.array(model.points(q0))
    np.testing.assert_allclose(P[:, 2], [0.0, 0.8], atol=1e-15)        # hip
    np.testing.assert_allclose(P[:, 5], [0.0, 0.0], atol=1e-15)        # swing foot
    np.testing.assert_allclose(P[:, 3], [0.0, 1.425], atol=1e-15)      # torso top
    x, z = model.swing_foot(q0)
    assert abs(float(x)) < 1e-15 and abs(float(z)) < 1e-15
    np.testing.assert_allclose(np.array(model.com(q0)).ravel(), [0.0, 0.71525], atol=1e-14)
    assert RABBIT.total_mass == pytest.approx(32.0)


def test_mass_matrix_symmetric_positive_definite(model, rng):
    q, _ = random_states(rng, 50)
    for qi in q:
        D = np.array(model.D(qi))
        np.testing.assert_allclose(D, D.T, atol=1e-13)
        assert np.linalg.eigvalsh(D).min() > 1e-3


def test_rotor_inertia_on_actuated_diagonal(model, rng):
    bare = BipedModel(dataclasses.replace(RABBIT, rotor_inertia=0.0))
    q, _ = random_states(rng, 5)
    for qi in q:
        diff = np.array(model.D(qi)) - np.array(bare.D(qi))
        np.testing.assert_allclose(diff, np.diag([0, 0.83, 0.83, 0.83, 0.83]), atol=1e-13)


def test_Ddot_minus_2C_skew(model, rng):
    q_s, dq_s = model.q_sym, model.dq_sym
    Ddot = ca.Function("Ddot", [q_s, dq_s], [ca.jtimes(model.D_expr, q_s, dq_s)])
    q, dq = random_states(rng, 30)
    for qi, dqi in zip(q, dq):
        N = np.array(Ddot(qi, dqi)) - 2 * np.array(model.C(qi, dqi))
        np.testing.assert_allclose(N + N.T, 0, atol=1e-12)


def test_gravity_is_gradient_of_potential(model, rng):
    q_s = model.q_sym
    V = model.energy(q_s, ca.SX.zeros(5))[1]
    gradV = ca.Function("gradV", [q_s], [ca.gradient(V, q_s)])
    q, _ = random_states(rng, 20)
    for qi in q:
        np.testing.assert_allclose(np.array(model.G(qi)), np.array(gradV(qi)), atol=1e-12)
        # and against a central finite difference of V
        h = 1e-6
        fd = [(float(model.energy(qi + h * e, 0)[1]) - float(model.energy(qi - h * e, 0)[1]))
              / (2 * h) for e in np.eye(5)]
        np.testing.assert_allclose(np.array(model.G(qi)).ravel(), fd, atol=1e-7)


def test_energy_conserved_passive(model):
    """u = 0 for 1 s with a tight-tolerance integrator: total energy constant."""
    x = ca.SX.sym("x", 10)
    ode = ca.vertcat(x[5:], model.forward_dynamics(x[:5], x[5:], ca.DM.zeros(4)))
    F = ca.integrator("F", "cvodes", {"x": x, "ode": ode}, 0.0, np.linspace(0, 1, 11),
                      {"abstol": 1e-13, "reltol": 1e-13, "max_num_steps": 200000})
    x0 = np.r_[0.1, -0.3, 0.2, 0.6, 0.4, -0.5, 0.8, -0.3, 0.4, 1.0]
    X = np.array(F(x0=x0)["xf"])
    E0 = float(model.energy(x0[:5], x0[5:])[2])
    E = np.array([float(model.energy(X[:5, k], X[5:, k])[2]) for k in range(X.shape[1])])
    K0 = float(model.energy(x0[:5], x0[5:])[0])
    assert np.max(np.abs(X[:5, -1] - x0[:5])) > 0.1           # it really moved
    assert np.max(np.abs(E - E0)) / abs(E0) <= 1e-9
    assert K0 > 1.0


def test_relabelling_involution():
    np.testing.assert_array_equal(E_RELABEL @ E_RELABEL, np.eye(5))


def test_impact_new_stance_foot_stops_old_one_lifts(model):
    q = walking_pre_impact()
    assert float(model.swing_foot(q)[0]) > 0.2
    # a forward walking velocity, swing foot moving down
    dq = np.array([1.0, 0.0, -1.0, -0.6, 0.3])   # stance leg rotating forward
    assert float(model.swing_foot_velocity(q, dq)[1]) < 0
    qp, dqp, F, dq_pre, v_old = model.impact_full(q, dq)
    # new stance foot (old swing foot) at rest after impact
    J = np.array(ca.Function("J", [model.q_sym], [ca.jacobian(
        ca.vertcat(*model.swing_foot(model.q_sym)), model.q_sym)])(q))
    # the velocity of the old swing foot = J dq_pre + velocity of the old stance foot
    v_new_stance = J @ np.array(dq_pre).ravel() + np.array(v_old).ravel()
    np.testing.assert_allclose(v_new_stance, 0, atol=1e-12)
    # in the new labels: new swing foot (old stance foot) moves up; new stance foot fixed
    assert np.array(v_old).ravel()[1] > 0
    np.testing.assert_allclose(np.array(qp).ravel(), E_RELABEL @ q, atol=1e-15)
    assert np.array(F).ravel()[1] > 0                 # ground pushes up on the foot
    # after relabelling the new swing foot (old stance foot) moves with v_old
    vs = np.array(model.swing_foot_velocity(qp, dqp)).ravel()
    np.testing.assert_allclose(vs, np.array(v_old).ravel(), atol=1e-12)


def test_angular_momentum_conserved_without_rotors(rng):
    bare = BipedModel(dataclasses.replace(RABBIT, rotor_inertia=0.0))
    for _ in range(5):
        q = walking_pre_impact() + np.r_[0, rng.normal(0, 0.05, 4)]
        xs = float(bare.swing_foot(q)[0]); zs = float(bare.swing_foot(q)[1])
        dq = rng.normal(0, 1.0, 5)
        qp, dqp, F, dq_pre, v_old = bare.impact_full(q, dq)
        # momentum about the impact point: before (stance foot fixed at origin) ...
        L_before = float(bare.angular_momentum(q, dq, [xs, zs]))
        # ... and after, in the old labels; the whole body also translates with v_old,
        # which adds m_total * (r_com x v_old) about the impact point
        com = np.array(bare.com(q)).ravel() - [xs, zs]
        M = RABBIT.total_mass
        vo = np.array(v_old).ravel()
        L_after = float(bare.angular_momentum(q, np.array(dq_pre).ravel(), [xs, zs])) \
            + M * (com[1] * vo[0] - com[0] * vo[1])
        assert abs(L_after - L_before) <= 1e-10 * max(1.0, abs(L_before))
        # and in the new labels, stance foot = impact point: the relabelled state alone
        L_new = float(bare.angular_momentum(np.array(qp).ravel(), np.array(dqp).ravel(), [0, 0]))
        assert abs(L_new - L_before) <= 1e-10 * max(1.0, abs(L_before))


def test_ground_reaction_static(model):
    """Standing upright, at rest, holding gravity torques: Fz = m g, Fx = 0."""
    q = np.zeros(5)
    u = np.array(model.G(q)).ravel()[1:]
    # with q1 unactuated the upright pose is an equilibrium (G1 = 0 at q = 0)
    Fx, Fz = model.ground_reaction(q, np.zeros(5), u)
    assert abs(float(Fx)) < 1e-12
    assert float(Fz) == pytest.approx(RABBIT.total_mass * RABBIT.g, rel=1e-12)


def test_params_validation(tmp_path):
    with pytest.raises(ValueError, match="m_femur"):
        RobotParams(m_femur=-1.0)
    with pytest.raises(ValueError, match="L_tibia"):
        RobotParams(L_tibia=0.0)
    d = RABBIT.to_dict()
    del d["I_torso"]
    f = tmp_path / "p.json"
    f.write_text(json.dumps(d))
    with pytest.raises(ValueError, match="I_torso"):
        load_params(f)
    f2 = tmp_path / "p.toml"
    f2.write_text("[robot]\n" + "\n".join(
        f"{k} = {v!r}" if not isinstance(v, str) else f'{k} = "{v}"' for k, v in RABBIT.to_dict().items()))
    assert load_params(f2) == RABBIT
    bad = tmp_path / "bad.toml"
    bad.write_text("m_torso = = 3")
    with pytest.raises(ValueError, match="cannot parse"):
        load_params(bad)
    with pytest.raises(ValueError, match="not found"):
        load_params(tmp_path / "nope.toml")


def test_model_cached():
    assert rabbit() is rabbit()


def test_relabelling_and_description_files_name_bad_arguments():
    """relabelling(4) returned a matrix: no planar biped of this kind has 4 joints."""
    from biped_casadi import load_description
    from biped_casadi.model import relabelling
    for bad in (0, 4, 6, "5", 5.0):
        with pytest.raises(ValueError, match="^nq must be an odd integer >= 3"):
            relabelling(bad)
    np.testing.assert_array_equal(relabelling(np.int64(5)), E_RELABEL)
    with pytest.raises(TypeError, match="^path must be a file name"):
        load_description(None)
