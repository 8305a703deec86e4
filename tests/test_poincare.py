"""The restricted Poincaré map: exact AD Jacobian against finite differences of an
independent SciPy implementation, the fixed point for any M1, the batched variational
Jacobian, and the singular outputs of eq. (24)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy_poincare import ScipyPoincare

from analysis import poincare_eigenvalues, poincare_map, singular_m1_values


@pytest.fixture(scope="module")
def pm(model, gait):
    return poincare_map(gait)


def random_nonsingular(pm, rng, n):
    out = []
    while len(out) < n:
        M1 = rng.uniform(-3, 3, 4)
        if not pm.is_singular(M1):
            out.append(M1)
    return np.array(out)


def test_spec_surface(model, gait):
    r = poincare_eigenvalues(gait, [0.0, 0.0, 0.0, 0.0])
    assert r.A.shape == (2, 2)
    assert r.eigenvalues.shape == (2,)
    assert r.max_abs == pytest.approx(np.max(np.abs(np.linalg.eigvals(r.A))), rel=1e-12)
    assert r.status in ("stable", "unstable")
    with pytest.raises(ValueError, match="M1"):
        poincare_eigenvalues(gait, [1.0, 2.0])
    with pytest.raises(ValueError, match="finite"):
        poincare_eigenvalues(gait, [np.nan, 0, 0, 0])


def test_ad_jacobian_matches_scipy_finite_differences(model, gait, pm, rng):
    sp = ScipyPoincare(model, gait)
    for M1 in [np.zeros(4), random_nonsingular(pm, rng, 1)[0]]:
        A_ad = pm.analyse(M1, method="ad").A
        A_fd = sp.jacobian(M1, h=1e-4)
        rel = np.max(np.abs(A_ad - A_fd)) / np.max(np.abs(A_fd))
        assert rel <= 1e-6, (M1, A_ad, A_fd)


def test_fixed_point_for_random_M1(pm, rng):
    for M1 in random_nonsingular(pm, rng, 4):
        step = pm.evaluate(pm.x_star, M1)
        x1, tau_i = step.x_next, step.tau_impact
        assert np.max(np.abs(x1 - pm.x_star)) <= 1e-8
        assert tau_i == pytest.approx(pm.T, abs=1e-8)


def test_map_moves_off_the_fixed_point(pm):
    """A perturbation is mapped to first order by A^z (second-order remainder)."""
    M1 = np.zeros(4)
    A = pm.analyse(M1, method="ad").A
    for d in (1e-3, 5e-4):
        dx = np.array([d, -2 * d])
        x1 = pm.evaluate(pm.x_star + dx, M1).x_next
        err = np.linalg.norm(x1 - pm.x_star - A @ dx)
        assert err < 50 * np.linalg.norm(dx) ** 2
        assert np.linalg.norm(x1 - pm.x_star) > 0.1 * np.linalg.norm(dx)


def test_variational_batch_matches_full_ad(pm, rng):
    M1s = np.vstack([np.zeros(4), random_nonsingular(pm, rng, 3)])
    jb = pm.jacobian_batch(M1s)
    status, A, max_abs = jb.status, jb.A, jb.max_abs
    for i, M1 in enumerate(M1s):
        r = pm.analyse(M1, method="ad")
        assert status[i] == r.status
        assert np.max(np.abs(A[i] - r.A)) <= 1e-6 * np.max(np.abs(r.A))
        assert max_abs[i] == pytest.approx(r.max_abs, rel=1e-6)


def test_variational_kernels_match_the_symbolic_jacobian(pm, rng):
    """The batch's compiled RK4 kernels (both segments) and numpy impact give A_fn's A^z
    to round-off, for points not a multiple of the four lanes; the fallback (A_fn mapped)
    is what the batch returns without kernels."""
    from analysis.stability import variational as va
    var = pm.variational
    M1s = random_nonsingular(pm, rng, 13)
    want = np.array([var.jacobian(M) for M in M1s])
    got = var.jacobians(M1s, threads=2)
    scale = np.max(np.abs(want), axis=(1, 2))[:, None, None]
    assert np.max(np.abs(got - want) / scale) < 1e-11
    if va._step_kernels(pm.nu) is not None:
        A = np.array(var._mapped(len(M1s), 1)(M1s.T)).reshape(2, len(M1s), 2).transpose(1, 0, 2)
        assert np.max(np.abs(A - want) / scale) < 1e-14


def test_eigenvalues_depend_on_M1(pm):
    a = pm.analyse(np.zeros(4)).max_abs
    b = pm.analyse(np.array([1.1 * singular_m1_values(pm.gait)[0], 0, 0, 0])).max_abs
    assert max(a, b) > 2 * min(a, b)


def test_singular_values_eq24(model, gait, pm):
    sv = singular_m1_values(gait)
    D = np.array(model.D(gait.q(gait.T)))
    np.testing.assert_allclose(sv * D[0, 1:], D[0, 0], rtol=1e-12)
    for j in range(4):
        M1 = np.zeros(4)
        M1[j] = sv[j]
        assert pm.analyse(M1).status == "singular"
    # for the first two components the singular set starts exactly at the eq. (24)
    # value; approaching it from below, max|lambda| blows up (Fig. 2's jump)
    for j in (0, 1):
        vals = sv[j] * np.array([0.5, 0.99, 0.9999])
        M1s = np.zeros((3, 4))
        M1s[:, j] = vals
        jb = pm.jacobian_batch(M1s)
        status, mx = jb.status, jb.max_abs
        assert list(status) == ["unstable"] * 3 or "stable" in status[:1]
        assert mx[2] > 1e3 * mx[0]
        assert mx[2] > mx[1] > mx[0] or mx[0] < 1


def test_rejoin_is_checked_by_name(gait):
    for bad in ("x", None, 0.9):
        with pytest.raises(ValueError, match="^rejoin must"):
            poincare_eigenvalues(gait, [0.0] * 4, rejoin=bad)


@pytest.mark.parametrize("option, value, message", [
    ("n_pre", 0, "^n_pre must be an integer >= 1"),
    ("n_post", 2.5, "^n_post must be an integer >= 1"),
    ("n_scan", -1, "^n_scan must be an integer >= 1"),
    ("threads", -1, "^threads must be an integer >= 1"),
    ("horizon", -1.0, "^horizon must exceed 0.75 \\(the section\\)"),
    ("horizon", float("nan"), "^horizon must be finite")])
def test_map_options_are_checked_by_name(gait, option, value, message):
    """n_pre = 0 was CasADi's 'mapaccum: N must be positive'; a negative horizon was
    taken."""
    with pytest.raises(ValueError, match=message):
        poincare_map(gait, **{option: value})


def test_a_path_for_the_gait_is_named(gait):
    with pytest.raises(TypeError, match="^gait: a gait is needed"):
        poincare_map("gait.json")


def test_result_repr_is_one_line_of_python_numbers(gait):
    import json
    r = poincare_eigenvalues(gait, [-10, 7.5, 10, -5])
    text = repr(r)
    assert "\n" not in text and len(text) < 500 and "array(" not in text and "np." not in text
    assert f"max_abs={r.max_abs!r}" in text and f"status={r.status!r}" in text
    assert "A=[[" in text and "eigenvalues=[(" in text      # 2x2 and complex, 6 digits
    json.dumps(r.to_dict(), allow_nan=False)


def test_other_robot_refused(gait):
    import dataclasses

    from analysis import PoincareMap
    from biped_casadi import RABBIT, BipedModel
    other = BipedModel(dataclasses.replace(RABBIT, m_torso=13.0))
    with pytest.raises(ValueError, match="robot parameters"):
        PoincareMap(other, gait)


def test_the_specification_form_is_the_same_call(model, gait):
    """poincare_eigenvalues(model, gait, M1) (the specification's form) equals the
    gait-first form; a model that is not the gait's is refused."""
    from analysis import poincare_eigenvalues
    from biped_casadi import Design, robot
    M1 = np.array([-10.0, 7.5, 10.0, -5.0])
    new = poincare_eigenvalues(gait, M1)
    old = poincare_eigenvalues(model, gait, M1)
    np.testing.assert_array_equal(old.A, new.A)
    d = poincare_eigenvalues(gait, Design.tv(gait, M1, rejoin=0.75))
    np.testing.assert_array_equal(d.A, poincare_eigenvalues(gait, M1, rejoin=0.75).A)
    assert np.max(np.abs(d.A - new.A)) > 1e-6          # the rejoin time matters
    with pytest.raises(ValueError, match="other robot"):
        poincare_eigenvalues(robot("three_link"), gait, M1)


def test_the_specification_form_takes_the_method_too(model, gait):
    """poincare_eigenvalues(model, gait, M1, method=...) (and the method as the fourth
    argument) is the gait-first call with that method; it raised TypeError ('multiple
    values for argument method')."""
    from analysis import poincare_eigenvalues
    M1 = np.array([-10.0, 7.5, 10.0, -5.0])
    ref = poincare_eigenvalues(gait, M1, method="ad")
    for r in (poincare_eigenvalues(model, gait, M1, method="ad"),
              poincare_eigenvalues(model, gait, M1, "ad"), poincare_eigenvalues(gait, M1, "ad")):
        assert r.method == "ad"
        np.testing.assert_array_equal(r.A, ref.A)
    with pytest.raises(TypeError, match="method"):
        poincare_eigenvalues(gait, M1, "ad", method="ad")
    with pytest.raises(ValueError, match="M1"):
        poincare_eigenvalues(model, gait)


def test_something_else_than_a_gait_is_named(model):
    """The model without its gait (or a file name, or None) where the gait goes: a
    TypeError that says what is needed, not "'BipedModel' object has no attribute
    'model'"."""
    from analysis import poincare_eigenvalues
    for wrong in (model, "gait.json", None):
        with pytest.raises(TypeError, match="a gait is needed"):
            poincare_eigenvalues(wrong, [0.0, 0.0, 0.0, 0.0])


def test_variational_jacobian_checks_its_arguments(gait):
    """n_pre = 0 was a ZeroDivisionError, a section time outside the step the gait's
    message about t, a path for the gait an AttributeError."""
    from analysis.stability import variational_jacobian
    tau_s = 0.75 * gait.T
    with pytest.raises(TypeError, match="^gait: a gait is needed"):
        variational_jacobian("gait.json", tau_s, 80, 240)
    for bad in (0, 2.5):
        with pytest.raises(ValueError, match="^n_pre must be an integer >= 1"):
            variational_jacobian(gait, tau_s, bad, 240)
    for bad in (-1.0, 0.0, gait.T, float("nan")):
        with pytest.raises(ValueError, match="^tau_s"):
            variational_jacobian(gait, bad, 80, 240)
    with pytest.raises(ValueError, match="^rejoin must be in"):
        variational_jacobian(gait, tau_s, 80, 240, rejoin=0.9)
