"""The CasADi model against an independent rigid-body library (Pinocchio): D, H,
swing-foot position and the impact map at random states, with the coordinates of
SPEC section 1 built as a serial chain of revolute joints about the y axis."""
from __future__ import annotations

import numpy as np
import pinocchio as pin
import pytest

from biped_casadi import RABBIT


def build_chain(p, planar_base: bool):
    """Stance tibia -> stance femur -> torso -> swing femur -> swing tibia; every joint
    turns about +y, so a positive angle leans the link's +z axis toward +x (SPEC)."""
    m = pin.Model()
    m.gravity = pin.Motion(np.array([0, 0, -p.g, 0, 0, 0]))
    parent = 0
    if planar_base:      # extended coordinates: stance-foot x and z
        parent = m.addJoint(parent, pin.JointModelPX(), pin.SE3.Identity(), "base_x")
        m.appendBodyToJoint(parent, pin.Inertia.Zero(), pin.SE3.Identity())
        parent = m.addJoint(parent, pin.JointModelPZ(), pin.SE3.Identity(), "base_z")
        m.appendBodyToJoint(parent, pin.Inertia.Zero(), pin.SE3.Identity())

    def body(mass, I, com_z):
        return pin.Inertia(mass, np.array([0, 0, com_z]), np.diag([I, I, I]))

    def at(z):
        return pin.SE3(np.eye(3), np.array([0, 0, z]))

    links = [  # (joint placement in parent, body inertia)
        (at(0.0), body(p.m_tibia, p.I_tibia, p.L_tibia - p.c_tibia)),
        (at(p.L_tibia), body(p.m_femur, p.I_femur, p.L_femur - p.c_femur)),
        (at(p.L_femur), body(p.m_torso, p.I_torso, p.c_torso)),
        (at(0.0), body(p.m_femur, p.I_femur, -p.c_femur)),
        (at(-p.L_femur), body(p.m_tibia, p.I_tibia, -p.c_tibia)),
    ]
    for k, (place, inertia) in enumerate(links):
        parent = m.addJoint(parent, pin.JointModelRY(), place, f"q{k + 1}")
        m.appendBodyToJoint(parent, inertia, pin.SE3.Identity())
    foot = m.addFrame(pin.Frame("foot_sw", parent, 0, at(-p.L_tibia), pin.FrameType.OP_FRAME))
    arm = np.zeros(m.nv)
    arm[-4:] = p.rotor_inertia          # reflected rotor inertia on q2..q5
    m.armature = arm
    return m, foot


@pytest.fixture(scope="module")
def chain():
    m, foot = build_chain(RABBIT, planar_base=False)
    return m, m.createData(), foot


@pytest.fixture(scope="module")
def chain_ext():
    m, foot = build_chain(RABBIT, planar_base=True)
    return m, m.createData(), foot


def states(n=20, seed=7):
    rng = np.random.default_rng(seed)
    return rng.uniform(-1.2, 1.2, (n, 5)), rng.uniform(-3, 3, (n, 5))


def rel(a, b):
    return np.max(np.abs(a - b)) / max(1.0, np.max(np.abs(b)))


def test_mass_matrix_and_H(model, chain):
    m, d, _ = chain
    for q, dq in zip(*states()):
        D_pin = pin.crba(m, d, q)
        D_pin = np.triu(D_pin) + np.triu(D_pin, 1).T
        assert rel(np.array(model.D(q)), D_pin) <= 1e-10
        H_pin = pin.rnea(m, d, q, dq, np.zeros(5))
        assert rel(np.array(model.H(q, dq)).ravel(), H_pin) <= 1e-10


def test_swing_foot(model, chain):
    m, d, foot = chain
    for q, _ in zip(*states()):
        pin.framesForwardKinematics(m, d, q)
        pos = d.oMf[foot].translation
        x, z = (float(v) for v in model.swing_foot(q))
        assert abs(x - pos[0]) <= 1e-12 and abs(z - pos[2]) <= 1e-12


def test_impact_map(model, chain_ext):
    m, d, foot = chain_ext
    E = model.E
    for q, dq in zip(*states(10, seed=3)):
        qe = np.r_[0.0, 0.0, q]
        De = pin.crba(m, d, qe)
        De = np.triu(De) + np.triu(De, 1).T
        pin.computeJointJacobians(m, d, qe)
        pin.framesForwardKinematics(m, d, qe)
        J = pin.getFrameJacobian(m, d, foot, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED)[[0, 2], :]
        K = np.block([[De, -J.T], [J, np.zeros((2, 2))]])
        sol = np.linalg.solve(K, np.r_[De @ np.r_[0, 0, dq], 0, 0])
        dq_after = sol[2:7]
        qp, dqp = (np.array(v).ravel() for v in model.impact(q, dq))
        assert rel(qp, E @ q) <= 1e-14
        assert rel(dqp, E @ dq_after) <= 1e-10
        F = np.array(model.impact_full(q, dq)[2]).ravel()
        assert rel(F, sol[7:]) <= 1e-10
