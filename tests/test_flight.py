"""The flight domain (biped_casadi.model.flight) against physics and against Pinocchio.

- Flight dynamics: De and He against an independent Pinocchio model with a planar
  floating base (prismatic x, prismatic z, then the chain, whose first revolute joint is
  the base's rotation) at random states.
- Invariants of flight: whatever the torques, the centre of mass falls at exactly -g and
  the angular momentum about it is constant (time derivatives by AD along the flight
  dynamics); the mechanical energy changes at the rate of the actuators' power, and a
  short integrated flight with u = 0 keeps it to the integrator's tolerance.
- Takeoff: the embedding reproduces the stance model's energy and mass matrix; with
  torques that zero the ground force the stance and flight accelerations agree.
- Landing: the landing foot stops, the impulse is the jump of linear momentum, the
  angular momentum about the landing point is kept, energy is lost, and with a zero base
  velocity the swing-foot landing is the walking impact.

RABBIT and the three-link biped (one-link legs: the same kinematics, no rotors); the
flight dynamics also for random bipeds of one to three links per leg.
"""
from __future__ import annotations

from pathlib import Path

import casadi as ca
import numpy as np
import pinocchio as pin
import pytest
from robot_factory import pinocchio_chain, random_description
from scipy.integrate import solve_ivp

from biped_casadi import BipedModel, robot
from biped_casadi.model import FlightModel, flight_model

ROBOTS = ["rabbit", "three_link"]


@pytest.fixture(scope="module", params=ROBOTS)
def case(request):
    model = robot(request.param)
    return model, flight_model(model)


def rel(a, b):
    return np.max(np.abs(np.asarray(a) - np.asarray(b))) / max(1.0, np.max(np.abs(b)))


def states(ne, n=12, seed=5):
    """Random extended states: angles, base position, rates and base velocity."""
    rng = np.random.default_rng(seed)
    return rng.uniform(-1.2, 1.2, (n, ne)), rng.uniform(-3, 3, (n, ne))


def arr(v):
    return np.array(v, dtype=float).squeeze()


# ------------------------------------------------------------------ flight dynamics
def test_mass_matrix_and_bias_against_pinocchio(case):
    model, fl = case
    n, ne = model.nq, fl.ne
    pm, _ = pinocchio_chain(model.description, planar_base=True)    # (x, z, q)
    data = pm.createData()
    idx = np.r_[np.arange(2, ne), 0, 1]          # ours (q, x, z) -> Pinocchio's index
    worst = [0.0, 0.0]
    for qe, dqe in zip(*states(ne)):
        qp, dqp = qe[np.r_[n, n + 1, :n]], dqe[np.r_[n, n + 1, :n]]
        D_pin = pin.crba(pm, data, qp)
        D_pin = np.triu(D_pin) + np.triu(D_pin, 1).T
        H_pin = pin.rnea(pm, data, qp, dqp, np.zeros(ne))
        worst[0] = max(worst[0], rel(arr(fl.De(qe)), D_pin[np.ix_(idx, idx)]))
        worst[1] = max(worst[1], rel(arr(fl.He(qe, dqe)), H_pin[idx]))
    assert worst[0] <= 1e-12 and worst[1] <= 1e-12, worst


@pytest.mark.parametrize("k", [1, 2, 3])
def test_random_bipeds_against_pinocchio(k):
    """Legs of one to three links, point masses at every joint, rotor inertia."""
    d = random_description(np.random.default_rng(200 + k), k, name=f"random_k{k}")
    model = BipedModel(d)
    fl, n = FlightModel(model), model.nq
    pm, _ = pinocchio_chain(d, planar_base=True)
    data = pm.createData()
    idx = np.r_[np.arange(2, fl.ne), 0, 1]
    for qe, dqe in zip(*states(fl.ne, 5, seed=k)):
        qp, dqp = qe[np.r_[n, n + 1, :n]], dqe[np.r_[n, n + 1, :n]]
        D_pin = pin.crba(pm, data, qp)
        D_pin = np.triu(D_pin) + np.triu(D_pin, 1).T
        assert rel(arr(fl.De(qe)), D_pin[np.ix_(idx, idx)]) <= 1e-12
        H_pin = pin.rnea(pm, data, qp, dqp, np.zeros(fl.ne))
        assert rel(arr(fl.He(qe, dqe)), H_pin[idx]) <= 1e-12


def test_flight_dynamics_solves_the_equation(case):
    model, fl = case
    rng = np.random.default_rng(2)
    for qe, dqe in zip(*states(fl.ne, 5)):
        u = rng.uniform(-50, 50, model.nu)
        ddqe = arr(fl.flight_dynamics(qe, dqe, u))
        He, Bu = arr(fl.He(qe, dqe)), fl.Be @ u
        res = arr(fl.De(qe)) @ ddqe + He - Bu
        assert np.max(np.abs(res)) <= 1e-11 * max(1.0, np.abs(He).max(), np.abs(Bu).max())


def test_the_mass_matrix_is_the_walking_impacts(case):
    model, fl = case
    for qe, _ in zip(*states(fl.ne, 5)):
        assert np.array_equal(arr(fl.De(qe)), arr(model.D_extended(qe[:model.nq])))


def _rates(fl, fn):
    """d/dt of fn(qe, dqe) along the flight dynamics (by AD), as a Function of
    (qe, dqe, u)."""
    qe, dqe, u = fl.qe_sym, fl.dqe_sym, fl.u_sym
    value = fn(qe, dqe)
    ddqe = fl.flight_dynamics(qe, dqe, u)
    rate = ca.jtimes(value, qe, dqe) + ca.jtimes(value, dqe, ddqe)
    return ca.Function("rate", [qe, dqe, u], [rate])


@pytest.mark.parametrize("torques", ["zero", "random"])
def test_com_falls_at_g_and_angular_momentum_is_kept(case, torques):
    model, fl = case
    g = model.description.gravity
    com_acc = _rates(fl, fl.com_velocity)
    dL = _rates(fl, lambda qe, dqe: fl.angular_momentum(qe, dqe, fl.com(qe)))
    rng = np.random.default_rng(4)
    worst = [0.0, 0.0]
    for qe, dqe in zip(*states(fl.ne)):
        u = np.zeros(model.nu) if torques == "zero" else rng.uniform(-100, 100, model.nu)
        worst[0] = max(worst[0], np.max(np.abs(arr(com_acc(qe, dqe, u)) - [0.0, -g])))
        L = abs(float(fl.angular_momentum(qe, dqe, fl.com(qe))))
        # relative to the generalised forces that cancel in it (N m), or to L
        scale = max(1.0, L, np.abs(arr(fl.He(qe, dqe))).max(), np.abs(u).max())
        worst[1] = max(worst[1], abs(float(dL(qe, dqe, u))) / scale)
    assert worst[0] <= 1e-12 * g and worst[1] <= 1e-12, worst


def test_energy_rate_is_the_actuators_power(case):
    model, fl = case
    dE = _rates(fl, lambda qe, dqe: fl.energy(qe, dqe)[2])
    rng = np.random.default_rng(6)
    for qe, dqe in zip(*states(fl.ne, 6)):
        u = rng.uniform(-100, 100, model.nu)
        power = float(dqe @ fl.Be @ u)
        assert abs(float(dE(qe, dqe, u)) - power) <= 1e-10 * max(1.0, abs(power))


def test_an_unactuated_flight_keeps_its_energy(case):
    model, fl = case
    q = np.linspace(-0.4, 0.4, model.nq)
    qe, dqe = arr(fl.takeoff(q, np.zeros(model.nq))[0]), 0.5 * np.ones(fl.ne)
    ne, zero = fl.ne, np.zeros(model.nu)

    def rhs(_, x):
        return np.r_[x[ne:], arr(fl.flight_dynamics(x[:ne], x[ne:], zero))]
    sol = solve_ivp(rhs, (0.0, 0.3), np.r_[qe, dqe], method="DOP853", rtol=1e-11, atol=1e-12)
    assert sol.success
    E = np.array([float(fl.energy(x[:ne], x[ne:])[2]) for x in sol.y.T])
    K0 = float(fl.energy(qe, dqe)[0])
    assert np.max(np.abs(E - E[0])) <= 1e-8 * max(1.0, K0)
    com0 = arr(fl.com(qe)) + 0.3 * arr(fl.com_velocity(qe, dqe))     # ballistic
    com0[1] -= 0.5 * model.description.gravity * 0.3**2
    assert np.max(np.abs(arr(fl.com(sol.y[:ne, -1])) - com0)) <= 1e-8


# ------------------------------------------------------------------ takeoff
def test_takeoff_embeds_the_stance_state(case):
    model, fl = case
    n = model.nq
    for qe, dqe in zip(*states(fl.ne, 5)):
        q, dq = qe[:n], dqe[:n]
        xe, dxe = (arr(v) for v in fl.takeoff(q, dq))
        assert np.array_equal(xe, np.r_[q, 0, 0]) and np.array_equal(dxe, np.r_[dq, 0, 0])
        assert np.allclose(arr(fl.feet(xe))[:, 0], 0.0, atol=0)
        assert np.allclose(arr(fl.feet_velocity(xe, dxe))[:, 0], 0.0, atol=0)
        assert rel(arr(fl.feet(xe))[:, 1], arr(model.swing_foot(q))) <= 1e-14
        assert rel(arr(fl.De(xe))[:n, :n], arr(model.D(q))) <= 1e-12
        for a, b in zip(fl.energy(xe, dxe), model.energy(q, dq)):
            assert rel(float(a), float(b)) <= 1e-12
        assert rel(arr(fl.angular_momentum(xe, dxe, [0.3, 0.1])),
                   arr(model.angular_momentum(q, dq, [0.3, 0.1]))) <= 1e-12


def test_takeoff_guard_is_the_normal_ground_force(case):
    model, fl = case
    rng = np.random.default_rng(8)
    for qe, dqe in zip(*states(fl.ne, 5)):
        q, dq, u = qe[:model.nq], dqe[:model.nq], rng.uniform(-50, 50, model.nu)
        Fz, Fx = (float(v) for v in fl.takeoff_guard(q, dq, u))
        Fx_ref, Fz_ref = (float(v) for v in model.ground_reaction(q, dq, u))
        assert (Fz, Fx) == (Fz_ref, Fx_ref)


def test_stance_and_flight_agree_where_the_ground_force_vanishes(case):
    """Lift-off with zero ground force (Fz = 0, so Fx = 0 in a friction cone) is smooth:
    the stance accelerations are the flight accelerations, the foot's is zero."""
    model, fl = case
    n = model.nq
    for qe, dqe in zip(*states(fl.ne, 5, seed=9)):
        q, dq = qe[:n], dqe[:n]
        F0 = np.r_[arr(model.ground_reaction(q, dq, np.zeros(model.nu)))]
        A = np.column_stack([arr(model.ground_reaction(q, dq, e)) - F0 for e in np.eye(model.nu)])
        u = np.linalg.lstsq(A, -F0, rcond=None)[0]         # ground force affine in u
        residual = np.max(np.abs(arr(model.ground_reaction(q, dq, u))))
        assert residual <= 1e-9 * max(1.0, np.abs(F0).max())
        xe, dxe = (arr(v) for v in fl.takeoff(q, dq))
        ddqe = arr(fl.flight_dynamics(xe, dxe, u))
        ddq = arr(model.forward_dynamics(q, dq, u))
        assert rel(ddqe, np.r_[ddq, 0.0, 0.0]) <= 1e-9


# ------------------------------------------------------------------ landing
@pytest.mark.parametrize("foot", ["swing", "stance"])
def test_landing_stops_the_foot_and_balances_momentum(case, foot):
    model, fl = case
    n, M = model.nq, model.description.total_mass
    land = fl.landing_swing if foot == "swing" else fl.landing_stance
    col = 1 if foot == "swing" else 0
    for qe, dqe in zip(*states(fl.ne, 8, seed=11)):
        q_plus, dq_plus, F, dqe_post, v_other, p_foot = (arr(v) for v in land(qe, dqe))
        v_scale = max(1.0, np.abs(dqe).max())
        assert np.max(np.abs(arr(fl.feet_velocity(qe, dqe_post))[:, col])) <= 1e-11 * v_scale
        assert rel(v_other, arr(fl.feet_velocity(qe, dqe_post))[:, 1 - col]) <= 1e-14
        assert rel(p_foot, arr(fl.feet(qe))[:, col]) <= 1e-15
        jump = M * (arr(fl.com_velocity(qe, dqe_post)) - arr(fl.com_velocity(qe, dqe)))
        assert rel(jump, F) <= 1e-11
        L_pre = float(fl.angular_momentum(qe, dqe, p_foot))
        L_post = float(fl.angular_momentum(qe, dqe_post, p_foot))
        assert abs(L_post - L_pre) <= 1e-11 * max(1.0, abs(L_pre))
        assert float(fl.energy(qe, dqe_post)[0]) <= float(fl.energy(qe, dqe)[0]) * (1 + 1e-14)
        E = model.E if foot == "swing" else np.eye(n)
        assert rel(q_plus, E @ qe[:n]) <= 1e-15
        assert rel(dq_plus, E @ dqe_post[:n]) <= 1e-15


def test_landing_against_pinocchio(case):
    model, fl = case
    n, ne = model.nq, fl.ne
    pm, foot = pinocchio_chain(model.description, planar_base=True)
    data = pm.createData()
    idx = np.r_[np.arange(2, ne), 0, 1]
    for qe, dqe in zip(*states(ne, 6, seed=13)):
        qp = qe[np.r_[n, n + 1, :n]]
        De = pin.crba(pm, data, qp)
        De = (np.triu(De) + np.triu(De, 1).T)[np.ix_(idx, idx)]
        pin.computeJointJacobians(pm, data, qp)
        pin.framesForwardKinematics(pm, data, qp)
        J = pin.getFrameJacobian(pm, data, foot, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)
        J = J[[0, 2], :][:, idx]
        sol = np.linalg.solve(np.block([[De, -J.T], [J, np.zeros((2, 2))]]),
                              np.r_[De @ dqe, 0, 0])
        _, dq_plus, F, dqe_post, _, p_foot = (arr(v) for v in fl.landing_swing(qe, dqe))
        assert rel(dqe_post, sol[:ne]) <= 1e-10 and rel(F, sol[ne:]) <= 1e-10
        assert rel(p_foot, data.oMf[foot].translation[[0, 2]]) <= 1e-12


def test_walking_impact_is_landing_with_the_base_at_rest(case):
    model, fl = case
    n = model.nq
    for qe, dqe in zip(*states(fl.ne, 8, seed=17)):
        q, dq = qe[:n], dqe[:n]
        xe, dxe = (arr(v) for v in fl.takeoff(q, dq))
        q_plus, dq_plus, F, dqe_post, v_other, _ = (arr(v) for v in fl.landing_swing(xe, dxe))
        ref = [arr(v) for v in model.impact_full(q, dq)]      # q+, dq+, F, dq_pre, v_old
        assert rel(q_plus, ref[0]) <= 1e-15 and rel(dq_plus, ref[1]) <= 1e-12
        assert rel(F, ref[2]) <= 1e-12 and rel(dqe_post[:n], ref[3]) <= 1e-12
        assert rel(v_other, ref[4]) <= 1e-12
        assert rel(dq_plus, arr(model.impact(q, dq)[1])) <= 1e-12


def test_flight_model_is_built_once_and_checks_its_argument(case):
    model, fl = case
    assert flight_model(model) is fl and fl.model is model
    assert fl.ne == model.nq + 2 and fl.Be.shape == (model.nq + 2, model.nu)
    with pytest.raises(ValueError, match="model"):
        flight_model("rabbit")
    with pytest.raises(ValueError, match="model"):
        FlightModel(None)


def test_the_how_to_example_runs():
    """The example of docs/howto/running.md, as written there (its assert included)."""
    page = Path(__file__).resolve().parents[1] / "docs" / "howto" / "running.md"
    block = page.read_text().split("```python\n", 1)[1].split("```", 1)[0]
    exec(compile(block, str(page), "exec"), {})
