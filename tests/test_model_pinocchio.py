"""The CasADi model of any description against an independent rigid-body library
(Pinocchio) built from the same description: D, H, swing-foot position and the impact
map at random states.  RABBIT, the three-link biped and random bipeds with one to three
links per leg and point masses at every joint."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest
from robot_factory import pinocchio_chain, random_description

from biped_casadi import BipedModel, robot

ROBOTS = ["rabbit", "three_link", "random_k1", "random_k2", "random_k3"]


def description(name):
    if name.startswith("random_k"):
        k = int(name[-1])
        return random_description(np.random.default_rng(100 + k), k, name=name)
    return robot(name).description


@pytest.fixture(scope="module", params=ROBOTS)
def case(request):
    d = description(request.param)
    model = BipedModel(d)
    m, foot = pinocchio_chain(d, planar_base=False)
    me, foot_e = pinocchio_chain(d, planar_base=True)
    return model, (m, m.createData(), foot), (me, me.createData(), foot_e)


def states(nq, n=20, seed=7):
    rng = np.random.default_rng(seed)
    return rng.uniform(-1.2, 1.2, (n, nq)), rng.uniform(-3, 3, (n, nq))


def rel(a, b):
    return np.max(np.abs(a - b)) / max(1.0, np.max(np.abs(b)))


def test_mass_matrix_and_H(case):
    model, (m, d, _), _ = case
    for q, dq in zip(*states(model.nq)):
        D_pin = pin.crba(m, d, q)
        D_pin = np.triu(D_pin) + np.triu(D_pin, 1).T
        assert rel(np.array(model.D(q)), D_pin) <= 1e-10
        H_pin = pin.rnea(m, d, q, dq, np.zeros(model.nq))
        assert rel(np.array(model.H(q, dq)).ravel(), H_pin) <= 1e-10


def test_swing_foot(case):
    model, (m, d, foot), _ = case
    for q, _ in zip(*states(model.nq)):
        pin.framesForwardKinematics(m, d, q)
        pos = d.oMf[foot].translation
        x, z = (float(v) for v in model.swing_foot(q))
        assert abs(x - pos[0]) <= 1e-12 and abs(z - pos[2]) <= 1e-12


def test_impact_map(case):
    model, _, (m, d, foot) = case
    E, n = model.E, model.nq
    for q, dq in zip(*states(n, 10, seed=3)):
        qe = np.r_[0.0, 0.0, q]
        De = pin.crba(m, d, qe)
        De = np.triu(De) + np.triu(De, 1).T
        pin.computeJointJacobians(m, d, qe)
        pin.framesForwardKinematics(m, d, qe)
        J = pin.getFrameJacobian(m, d, foot, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[[0, 2], :]
        K = np.block([[De, -J.T], [J, np.zeros((2, 2))]])
        sol = np.linalg.solve(K, np.r_[De @ np.r_[0, 0, dq], 0, 0])
        dq_after = sol[2:2 + n]
        qp, dqp = (np.array(v).ravel() for v in model.impact(q, dq))
        assert rel(qp, E @ q) <= 1e-14
        assert rel(dqp, E @ dq_after) <= 1e-10
        F = np.array(model.impact_full(q, dq)[2]).ravel()
        assert rel(F, sol[2 + n:]) <= 1e-10
