"""Controllers of paper §III (time-varying outputs, eq. 12-13, 17) and §V-C (virtual
constraints / hybrid zero dynamics): what they do to the robot, not their formulas.

- on the reference both controllers command exactly the reference torques u^d(t);
- off the reference the plant driven by their torque has the output dynamics of eq. (13);
- the singularity of eq. (23-24) is found where D11 - D12 M1 vanishes;
- the virtual constraints reproduce the orbit and are impact invariant (a state on the
  constraint surface at the impact lands on it again, for any speed);
- the VC eigenvalue is the same for two different output choices on the same orbit
  (and equals the closed-form delta_zero^2), while the time-varying controller's
  eigenvalues depend on M1.
"""
from __future__ import annotations

import numpy as np
import pytest

from analysis.stability import VirtualConstraintMap, vc_eigenvalue
from biped_casadi.control import (HIP_PHASE, Gains, TimeVaryingController,
                                      VirtualConstraintController, fit_virtual_constraints)
from biped_casadi.control.output_law import correction


@pytest.fixture(scope="module")
def random_m1(gait, model):
    """A random output matrix M1 (components in [-3, 3]) that is not singular on the step."""
    rng = np.random.default_rng(2024)
    for _ in range(100):
        M1 = rng.uniform(-3, 3, 4)
        if not TimeVaryingController(gait, M1).singularity().singular:
            return M1
    raise AssertionError("no non-singular random M1 found")


@pytest.fixture(scope="module")
def vc_ctrl(model, gait):
    return VirtualConstraintController(gait)


# ----------------------------------------------------------- time-varying
@pytest.mark.parametrize("which", ["zero", "random"])
def test_tv_reference_torque(model, gait, random_m1, which):
    """On the reference (y_i = dy_i = 0) the torque of eq. (12) is u^d(t), for any M1."""
    M1 = np.zeros(4) if which == "zero" else random_m1
    ctrl = TimeVaryingController(gait, M1)
    for t in np.linspace(0, gait.T, 7):
        out = ctrl.torque(gait.q(t), gait.dq(t), t)
        np.testing.assert_allclose(out.u, gait.u(t), rtol=1e-9, atol=1e-8)
        assert np.max(np.abs(out.y)) < 1e-12 and np.max(np.abs(out.dy)) < 1e-10


def test_tv_output_dynamics(model, gait, random_m1, rng):
    """Off the reference, the plant under the torque of eq. (12) has
    ddy_c = -Kd/eps dy_c - Kp/eps^2 y_c (eq. 13 with the output of eq. 17)."""
    gains = Gains(Kp=1.3, Kd=2.1, eps=0.05)
    ctrl = TimeVaryingController(gait, random_m1, gains)
    M = ctrl.M
    for tau in (0.1 * gait.T, 0.4 * gait.T, 0.8 * gait.T):
        q = gait.q(tau) + rng.normal(0, 0.02, 5)
        dq = gait.dq(tau) + rng.normal(0, 0.1, 5)
        yi, dyi = rng.normal(0, 0.02, 4), rng.normal(0, 0.1, 4)
        out = ctrl.torque(q, dq, tau, yi, dyi)
        ddq = np.array(model.forward_dynamics(q, dq, out.u)).ravel()
        _, _, ddvc = correction(tau, yi, dyi, gait.T / 2)
        ddy = M @ ddq - M @ gait.ddq(tau) - ddvc
        expected = -gains.Kd / gains.eps * out.dy - gains.Kp / gains.eps**2 * out.y
        np.testing.assert_allclose(ddy, expected, rtol=1e-7, atol=1e-7)
        assert np.max(np.abs(out.y)) > 1e-3          # genuinely off the reference


def test_tv_singularity_eq24(model, gait):
    """D11 - D12 M1 = 0 somewhere on the step for M1 = (D11 / D12[0], 0, 0, 0) taken at
    mid-step (eq. 24): reported singular, and the law's denominator is D11 - D12 M1."""
    t = 0.5 * gait.T
    D = np.array(model.D(gait.q(t)))
    m = D[0, 0] / D[0, 1]
    sing = TimeVaryingController(gait, [m, 0, 0, 0])
    rep = sing.singularity()
    assert rep.singular and rep.min_abs < 0.05 * abs(D[0, 0])
    assert not TimeVaryingController(gait, np.zeros(4)).singularity().singular
    out = sing.torque(gait.q(t), gait.dq(t), t)
    assert abs(out.denominator - (D[0, 0] - D[0, 1] * m)) < 1e-9


def test_tv_step_start_makes_output_zero(model, gait, random_m1, rng):
    """With y_i, dy_i of the step start, y_c = dy_c = 0 at tau = 0 (eq. 17-18)."""
    ctrl = TimeVaryingController(gait, random_m1)
    q = gait.q(0.0) + rng.normal(0, 0.01, 5)
    dq = gait.dq(0.0) + rng.normal(0, 0.1, 5)
    st = ctrl.step_start(q, dq)
    out = ctrl.evaluate(q, dq, 0.0, st.r, st.p)
    # zero up to rounding of the terms that cancel: |M| |dq| (M = [M1, I]) sets their size
    # (CI's processor rounds differently from a workstation's: 1e-12 seen, 1e-13 here)
    scale = (1.0 + np.sum(np.abs(random_m1))) * np.max(np.abs(dq))
    assert np.max(np.abs(out.y)) < 1e-14
    assert np.max(np.abs(out.dy)) < 1e3 * np.finfo(float).eps * scale
    np.testing.assert_allclose(st.r, gait.x0)


def test_tv_bad_input(model, gait):
    with pytest.raises(ValueError, match="M1"):
        TimeVaryingController(gait, [0, 0, 0])
    with pytest.raises(ValueError, match="M1"):
        TimeVaryingController(gait, [0, np.nan, 0, 0])
    with pytest.raises(ValueError, match="eps"):
        Gains(eps=0.0)
    with pytest.raises(ValueError, match="'eps' = 1e\\+300 s is too large"):   # OverflowError
        Gains(eps=1e300)
    ctrl = TimeVaryingController(gait)
    with pytest.raises(ValueError, match="q"):
        ctrl.torque(np.zeros(4), np.zeros(5), 0.1)
    with pytest.raises(ValueError, match="tau"):
        ctrl.torque(gait.q(0.0), gait.dq(0.0), 5 * gait.T)


@pytest.mark.parametrize("not_a_gait", [None, "gait.json", "model"])
def test_a_model_or_path_for_the_gait_is_one_type_error(model, gait, not_a_gait):
    """What a user passes for the gait by mistake (its file, the model) is a TypeError
    naming the gait, not an AttributeError from inside."""
    bad = model if not_a_gait == "model" else not_a_gait
    from biped_casadi import Design
    calls = [lambda: TimeVaryingController(bad, [0.0] * 4),
             lambda: VirtualConstraintController(bad),
             lambda: fit_virtual_constraints(bad)]
    if bad is not None:                     # Design(gait=None) is a design without a gait
        calls += [lambda: Design.tv(bad, [0.0] * 4), lambda: Design.vc(bad)]
    for call in calls:
        with pytest.raises(TypeError, match=r"^(gait|reference): a gait is needed") as e:
            call()
        assert "\n" not in str(e.value)


def test_design_inputs(gait):
    from biped_casadi import Design
    M1 = [-10, 7.5, 10, -5]
    with pytest.raises(ValueError, match="M1: .*Design.vc"):
        Design.tv(gait, None)                       # not virtual constraints in disguise
    with pytest.raises(ValueError, match="^M1 must be numbers"):
        Design.tv(gait, "abcd")
    for bad in ((1.0, 2.0), 5, "1 2 0.02"):
        with pytest.raises(ValueError, match="^gains must be a Gains or the three numbers"):
            Design.tv(gait, M1, gains=bad)
    with pytest.raises(ValueError, match="^gains: unknown gain 'kp'"):
        Design.tv(gait, M1, gains={"kp": 2.0})
    d = Design.tv(gait, M1, gains={"Kp": 2.0})     # some gains by name, the others default
    assert d.gains == Gains(Kp=2.0) and d.gains != Gains()
    assert Design.tv(gait, M1, gains=(2.0, 3.0, 0.01)).gains == Gains(2.0, 3.0, 0.01)


# ------------------------------------------------------ virtual constraints
def test_vc_fit_reproduces_orbit(gait):
    """h_d(c q^d(t)) = q_a^d(t) all along the step (between the knots too) and the
    derivative along the orbit matches: the constraints hold the whole reference."""
    vc = fit_virtual_constraints(gait)
    assert vc.fit_residual < 1e-10 and vc.invariance_residual < 1e-9
    t = np.linspace(0, gait.T, 977)[1:-1] + 1e-5 * gait.T
    q, dq = gait.q(t), gait.dq(t)
    h, dh, _ = (np.array(v) for v in vc.h.map(t.size)((vc.c @ q)[None, :]))
    assert np.max(np.abs(q[1:] - h)) < 1e-10
    assert np.max(np.abs(dq[1:] - dh * (vc.c @ dq))) < 1e-8


def test_vc_reference_torque(gait, vc_ctrl):
    """On the reference the virtual-constraint controller commands u^d(t) too."""
    for t in np.linspace(0.05, 0.95, 5) * gait.T:
        out = vc_ctrl.torque(gait.q(t), gait.dq(t))
        np.testing.assert_allclose(out.u, gait.u(t), rtol=1e-7, atol=1e-6)
        assert np.max(np.abs(out.y)) < 1e-10


def test_vc_output_dynamics(model, gait, vc_ctrl, rng):
    """Off the constraint surface, y = q_a - h_d(theta) obeys the PD of eq. (13):
    checked by finite differences of y along the closed-loop motion."""
    k = vc_ctrl.gains
    vc = vc_ctrl.constraints
    q = gait.q(0.3 * gait.T) + rng.normal(0, 0.01, 5)
    dq = gait.dq(0.3 * gait.T) + rng.normal(0, 0.1, 5)
    out = vc_ctrl.torque(q, dq)
    ddq = np.array(model.forward_dynamics(q, dq, out.u)).ravel()

    def y_of(s):
        qs = q + s * dq + 0.5 * s**2 * ddq
        return qs[1:] - np.array(vc.h(vc.c @ qs)[0]).ravel()
    e = 1e-4
    ddy = (y_of(e) - 2 * y_of(0.0) + y_of(-e)) / e**2
    expected = -k.Kd / k.eps * out.dy - k.Kp / k.eps**2 * out.y
    np.testing.assert_allclose(ddy, expected, rtol=1e-4, atol=1e-3)


def test_vc_impact_invariance(model, gait, vc_ctrl):
    """Hybrid zero dynamics: a state on the constraint surface at the impact
    configuration, moving at any speed along it, lands on the surface after the impact
    (y = dy = 0 to round-off), so the zero dynamics is invariant through the impact."""
    vmap = VirtualConstraintMap(model, gait, vc_ctrl.constraints, n_steps=200)
    q_m, Q1, _ = (np.array(v).ravel() for v in vmap.curve(vmap.theta_minus))
    assert abs(float(model.swing_foot(q_m)[1])) < 1e-12
    for w in (0.5, 1.0, 1.7):
        q_p, dq_p = (np.array(v).ravel() for v in model.impact(q_m, Q1 * w))
        out = vc_ctrl.torque(q_p, dq_p)
        assert np.max(np.abs(out.y)) < 1e-9 and np.max(np.abs(out.dy)) < 1e-8


def test_vc_bad_input(gait):
    with pytest.raises(ValueError, match="monotonic"):
        fit_virtual_constraints(gait, c=[0.1, 0, 0, 0, 1.0])      # mostly the swing knee
    with pytest.raises(ValueError, match="invertible"):
        fit_virtual_constraints(gait, c=[0, 1.0, 0, 0, 0])        # q2 is an output too
    with pytest.raises(ValueError, match="H0"):
        fit_virtual_constraints(gait, H0=np.eye(4))
    with pytest.raises(ValueError, match="c"):
        fit_virtual_constraints(gait, c=[1, 0.5, 0, 0])
    with pytest.raises(TypeError, match=r"^gait: a gait is needed"):
        vc_eigenvalue(None)                 # an AttributeError on None.model before


# --------------------------------------------------------------- eigenvalues
def test_vc_eigenvalue_independent_of_outputs(model, gait):
    """Paper §V-C: for the same orbit the VC eigenvalue does not depend on the outputs.
    Choice 1: q_a - h_d(q1 + q2/2) (hip angle); choice 2: [M1, I] q - h_d(q1) with
    another phase variable (stance tibia angle) and mixed outputs.  Both fitted to the
    same gait: same eigenvalue to 1e-8, equal to delta_zero^2 of the orbit's impact."""
    H0 = np.hstack([np.array([[0.5], [-1.0], [0.3], [0.2]]), np.eye(4)])
    a = vc_eigenvalue(gait, phase=HIP_PHASE)
    b = vc_eigenvalue(gait, phase=(1.0, 0, 0, 0, 0), H0=H0)
    assert a.status == b.status == "stable"
    assert abs(a.eigenvalue - b.eigenvalue) < 1e-8
    assert abs(a.eigenvalue - a.delta_zero_squared) < 1e-8
    # both maps have the reference orbit as their fixed point
    assert a.orbit_mismatch < 1e-8 and b.orbit_mismatch < 1e-8
    assert a.fixed_point_residual < 1e-12
    assert 0 < a.eigenvalue < 1


def test_vc_eigenvalue_matches_finite_difference(model, gait):
    """The AD derivative of the 1-D map against a central difference of the map."""
    vmap = VirtualConstraintMap(model, gait, fit_virtual_constraints(gait), n_steps=400)
    r = vmap.analyse()
    e = 1e-6
    fd = (vmap.evaluate(r.w_star + e) - vmap.evaluate(r.w_star - e)) / (2 * e)
    assert abs(vmap.derivative(r.w_star) - fd) < 1e-7
    assert abs(r.eigenvalue - fd) < 1e-7


def test_tv_eigenvalues_depend_on_m1(model, gait, random_m1):
    """Unlike VC, the time-varying controller's A^z changes with the outputs M1."""
    from analysis import poincare_eigenvalues
    r0 = poincare_eigenvalues(gait, np.zeros(4))
    r1 = poincare_eigenvalues(gait, random_m1)
    assert r0.status in ("stable", "unstable") and r1.status in ("stable", "unstable")
    assert abs(r0.max_abs - r1.max_abs) > 1e-3 * max(r0.max_abs, r1.max_abs)
    assert np.max(np.abs(r0.A - r1.A)) > 1e-3


def test_vc_phase_is_named(gait):
    """A phase of the wrong length was reported as 'c' (the fit's own name for it)."""
    from analysis.stability import vc_map
    for call in (lambda: vc_eigenvalue(gait, phase=[1.0, 0.5]),
                 lambda: vc_map(gait, phase=[1.0, 0.5])):
        with pytest.raises(ValueError, match=r"^phase must have 5 components, got shape \(2,\)"):
            call()
    with pytest.raises(TypeError, match="^gait: a gait is needed"):
        vc_eigenvalue("gait.json")
