"""The one zero dynamics and what is built on it: its linearisation against AD of the
zero dynamics itself, the derivative of A^z in M1 against finite differences (the M1 NLP
follows it), and the one stepping kernel's strike test and refinement."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from analysis.stability import poincare_map
from biped_casadi.control.zero_dynamics import denominator_samples, zero_dynamics
from biped_casadi.simulation.kernel import Diagnostics, locate_strike, strike


@pytest.fixture(scope="module")
def zd(model):
    return zero_dynamics(model)


def test_one_instance_per_robot(model, zd):
    assert zero_dynamics(model) is zd


def test_zero_dynamics_on_the_reference_is_the_reference(model, gait, zd):
    """On the orbit (v_c = 0, q_u = q_u^d) the zero dynamics returns q^d and ddq_u^d for
    every M1: the outputs pin q_a, the unactuated row gives the reference's own ddq_u."""
    rng = np.random.default_rng(3)
    for t in (0.1 * gait.T, 0.5 * gait.T, 0.9 * gait.T):
        q, dq, ddq = gait.evaluate(t)
        R = np.r_[q, dq, ddq]
        for M1 in rng.uniform(-3, 3, (3, 4)):
            P = zd.params(M1, 0.5 * gait.T, np.zeros(4), np.zeros(4))
            dx = np.array(zd.rhs([q[0], dq[0]], t, R, P)).ravel()
            qz, dqz, ddqz = (np.array(v).ravel() for v in zd.state([q[0], dq[0]], t, R, P))
            assert np.max(np.abs(qz - q)) < 1e-12 and np.max(np.abs(dqz - dq)) < 1e-12
            assert abs(dx[0] - dq[0]) < 1e-12 and abs(dx[1] - ddq[0]) < 1e-9
            assert np.max(np.abs(ddqz - ddq)) < 1e-9


def test_linearisation_matches_ad_of_the_zero_dynamics(model, gait, zd):
    """The M1-independent factors of the variational equation give the same derivatives
    of ddq_u as AD of the zero dynamics' right-hand side about the reference, for random
    M1: in (q_u, dq_u), and in the correction's (y_i, dy_i) through its basis."""
    t = np.array([0.2, 0.45, 0.7]) * gait.T
    qd, dqd, ddqd = gait.evaluate(t)
    lin = zd.linearisation(qd, dqd, ddqd)
    tc = 10 * gait.T                          # v_c still active at every t of the test
    a, b = zd.correction_basis(t, tc)
    x, R, P = ca.SX.sym("x", 2), ca.SX.sym("R", 15), ca.SX.sym("P", zd.n_par)
    tau = ca.SX.sym("tau")
    _, _, yi, dyi = zd.split(P)
    jac = ca.Function("j", [x, tau, R, P], [ca.jacobian(zd.rhs(x, tau, R, P)[1],
                                                        ca.vertcat(x, yi, dyi))])
    rng = np.random.default_rng(5)
    for M1 in rng.uniform(-4, 4, (4, 4)):
        Jq, Jdq, den = (np.array(v).ravel() for v in lin.coefficients(M1))
        Fy, Fdy = lin.forcing(*a) / den, lin.forcing(*b) / den
        for k in range(t.size):
            P0 = zd.params(M1, tc, np.zeros(4), np.zeros(4))
            R0 = np.r_[qd[:, k], dqd[:, k], ddqd[:, k]]
            J = np.array(jac([qd[0, k], dqd[0, k]], t[k], R0, P0)).ravel()
            np.testing.assert_allclose(J[:2], [Jq[k], Jdq[k]], rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(J[2:6], Fy[:, k], rtol=1e-8, atol=1e-9)
            np.testing.assert_allclose(J[6:10], Fdy[:, k], rtol=1e-8, atol=1e-9)


def test_dAz_dM1_matches_finite_differences(model, gait):
    """The derivative of A^z in M1 (AD of the variational Jacobian, what the M1 NLP's
    exact derivatives are) against central differences of A^z itself."""
    var = poincare_map(gait).variational
    M1 = ca.SX.sym("M1", 4)
    dA = ca.Function("dA", [M1], [ca.jacobian(ca.vec(var.A_fn(M1)), M1)])
    rng = np.random.default_rng(11)
    pts = [np.zeros(4), np.array([-10, 7.5, 10, -5.0]), *rng.uniform(-3, 3, (2, 4))]
    for p in pts:
        exact = np.array(dA(p))
        h = 1e-5
        fd = np.column_stack([(np.array(var.A_fn(p + h * e)).ravel(order="F")
                               - np.array(var.A_fn(p - h * e)).ravel(order="F")) / (2 * h)
                              for e in np.eye(4)])
        scale = max(1.0, np.max(np.abs(exact)))
        assert np.max(np.abs(exact - fd)) / scale < 1e-6, (p, np.max(np.abs(exact - fd)))


def test_denominator_samples_are_shared(model, gait):
    D11, D12 = denominator_samples(gait)
    assert denominator_samples(gait)[0] is D11
    assert D11.shape == (1001,) and D12.shape == (4, 1001)
    pm = poincare_map(gait)
    assert pm.D11_table is D11


# ------------------------------------------------------------------ the kernel
def test_strike_is_a_downward_crossing_in_front():
    z_prev = np.array([0.01, 0.0, 0.01, -0.01, 0.01, np.nan])
    z = np.array([-0.01, -0.01, 0.02, -0.02, -0.01, -0.01])
    x = np.array([0.3, 0.3, 0.3, 0.3, -0.1, 0.3])
    assert strike(z, z_prev, x, 0.0).tolist() == [True, True, False, False, False, False]
    # beyond the scuff zone only
    assert strike(z[:1], z_prev[:1], x[:1], 0.4).tolist() == [False]


def test_locate_strike_finds_the_root_vectorised():
    """The refinement finds eta with z(eta) = 0 for several scenarios at once, each
    stopping on its own, and handles a root at the end of the step."""
    roots = np.array([0.2e-3, 0.7e-3, 1.0e-3])
    h = 1e-3
    calls = []

    def event(eta):
        calls.append(eta.copy())
        z = (roots - eta) * (1 + 50 * (roots - eta))        # decreasing through the root
        return z, -(1 + 100 * (roots - eta))

    eta = locate_strike(event, h, roots * (1 + 50 * roots), (roots - h) * (1 + 50 * (roots - h)))
    assert np.max(np.abs(eta - roots)) < 1e-15
    assert len(calls) < 15


def test_diagnostics_schema_by_name(model):
    with_outputs, without = Diagnostics(4, outputs=True), Diagnostics(4, outputs=False)
    assert with_outputs.size == 3 * 4 + len(Diagnostics.SCALARS) + 2      # + in_range, saturated
    assert without.size == 4 + len(Diagnostics.SCALARS)
    full = with_outputs.rows(np.ones((with_outputs.size, 1)))
    assert "in_range" in full and "saturated" in full
    D = np.arange(without.size, dtype=float)[:, None] * np.ones((1, 3))
    rows = without.rows(D)
    assert rows["u"].shape == (4, 3) and rows["zsw"][0] == without.index["zsw"]
    assert rows["finite"].all()
