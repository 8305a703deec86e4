"""The four-lane batch kernels (biped_casadi.simd) against CasADi's own evaluation."""
from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from biped_casadi import simd
from biped_casadi.simulation import SimulationOptions
from biped_casadi.simulation.tv_walker import ZeroDynamicsWalker
from gait_opt import GaitOptions, optimize_gait

pytestmark = pytest.mark.skipif(not simd.available(), reason="needs AVX2, FMA and gcc")


def _casadi_columns(f, cols):
    """f on every column of the inputs, by CasADi's own (scalar) evaluation."""
    n = cols[0].shape[1]
    return [np.array(v) for v in f.map(n).call(list(cols))]


def test_every_operation_matches_casadi_lane_by_lane():
    x = ca.SX.sym("x", 3)
    a, b, c = x[0], x[1], x[2]
    outs = [a + b, a - b, a * b, a / b, -a, a**2, 2 * a, 1 / b, ca.sin(a), ca.cos(a),
            ca.sin(a) * ca.cos(a), ca.sin(a + b), ca.cos(a - b), ca.sin(2 * a),
            ca.cos(-a), ca.exp(c / 10), ca.log(ca.fabs(b) + 1), ca.sqrt(ca.fabs(a)),
            ca.fabs(a), ca.tan(c / 4), ca.atan2(a, b), ca.fmin(a, b), ca.fmax(a, b),
            ca.if_else(a < b, c, 2 * c), a <= b, a == b, a != b, ca.logic_not(a > 0),
            ca.logic_and(a > 0, b > 0), ca.logic_or(a > 0, b > 0), ca.sign(a),
            ca.floor(c), ca.ceil(c), ca.power(ca.fabs(a) + 1, b), ca.asin(ca.sin(a)),
            ca.acos(ca.cos(b) / 2), ca.atan(c), ca.tanh(a), ca.sqrt(a)]
    f = ca.Function("every_op", [x], [ca.vertcat(*outs)])
    rng = np.random.default_rng(0)
    X = rng.normal(scale=3.0, size=(3, 103))              # not a multiple of four lanes
    X[:, 7] = [np.nan, 1.0, 2.0]                           # NaN propagates
    X[:, 8] = [2e5, -3e6, 1.0]                             # beyond the fast sine's range
    X[:, 9] = [1.0, 1.0, 0.5]                              # equal operands, ties
    k = simd.kernels({"f": (f, 0, ["sample"])}, "test_every_op")["f"]
    got = k(X)[0][:, :, 0]
    want = _casadi_columns(f, [X])[0]
    assert np.array_equal(np.isnan(got), np.isnan(want))
    ok = ~np.isnan(want)
    err = np.abs(got[ok] - want[ok]) / (1 + np.abs(want[ok]))
    assert err.max() < 1e-13


def test_sine_and_cosine_to_a_few_ulp():
    x = ca.SX.sym("x")
    f = ca.Function("sincos", [x], [ca.sin(x), ca.cos(x)])
    t = np.concatenate([np.linspace(-60, 60, 400_003), np.geomspace(1e-300, 1e5, 3_001),
                        -np.geomspace(1e-300, 1e5, 3_001), [0.0, -0.0, np.pi / 4, np.pi / 2]])
    k = simd.kernels({"f": (f, 0, ["sample"])}, "test_sincos")["f"]
    s, c = (o[0, :, 0] for o in k(t[None, :]))
    ulp = np.spacing(1.0) / 2
    assert np.max(np.abs(s - np.sin(t))) <= 2 * ulp
    assert np.max(np.abs(c - np.cos(t))) <= 2 * ulp
    tiny = np.abs(t) < 1e-8                                 # relative accuracy near zero
    assert np.all(np.abs(s[tiny] - t[tiny]) <= np.abs(t[tiny]) * 2 * ulp)
    assert np.array_equal(np.isnan(k(np.array([[np.inf, -np.inf, np.nan]]))[0]),
                          np.ones((1, 3, 1), bool))


def test_accumulated_map_is_mapaccum():
    """A damped pendulum by RK4: the kernel's K nodes equal mapaccum's, every kind of
    input used."""
    x, h, tab, p = ca.SX.sym("x", 2), ca.SX.sym("h"), ca.SX.sym("r"), ca.SX.sym("p", 2)

    def rhs(v):
        return ca.vertcat(v[1], -p[0] * ca.sin(v[0]) - p[1] * v[1] + tab)

    k1 = rhs(x)
    k2 = rhs(x + h / 2 * k1)
    k3 = rhs(x + h / 2 * k2)
    k4 = rhs(x + h * k3)
    xn = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    f = ca.Function("pendulum", [x, h, tab, p], [xn, ca.cos(xn[0])])
    K, n = 37, 21
    rng = np.random.default_rng(1)
    X0, P, R = rng.normal(size=(2, n)), rng.uniform(0.5, 2, size=(2, n)), rng.normal(size=(1, K))
    k = simd.kernels({"f": (f, 1, ["const", "node", "sample"])}, "test_pendulum")["f"]
    got = k(X0, [0.01], R, P, K=K, threads=2)
    acc = f.mapaccum("acc", K, [0], [0])
    for j in range(n):
        want = [np.array(v) for v in acc(X0[:, j], 0.01, R, P[:, j])]
        for g_, w_ in zip(got, want):
            np.testing.assert_allclose(g_[:, j, :], w_, rtol=1e-13, atol=1e-13)
    # built with last=True: only the last node's outputs, the same numbers
    f2 = ca.Function("pendulum_last", [x, h, tab, p], [xn, ca.cos(xn[0])])
    k_last = simd.kernels({"f": (f2, 1, ["const", "node", "sample"], True)},
                          "test_pendulum_last")["f"]
    last = k_last(X0, [0.01], R, P, K=K, threads=2)
    for g_, l_ in zip(got, last):
        assert l_.shape == (g_.shape[0], n, 1)
        np.testing.assert_array_equal(l_[:, :, 0], g_[:, :, -1])


def test_calls_run_casadis_code_lane_by_lane():
    """A call of another Function (here a B-spline and its derivative, as the virtual
    constraints' surface has) inside an SX Function."""
    t = ca.MX.sym("t")
    knots = [0.0] * 4 + [0.3, 0.5, 0.8] + [1.0] * 4
    spline = ca.Function.bspline("sp", [knots], list(np.linspace(-1, 2, 7) ** 2), [3], 1, {})
    inner = ca.Function("inner", [t], [spline(t), ca.jacobian(spline(t), t)],
                        {"never_inline": True})
    y = ca.SX.sym("y", 2)
    h, dh = inner(y[0])
    f = ca.Function("outer", [y], [ca.vertcat(h * y[1] + ca.sin(h), dh, ca.cos(h + y[1]))])
    X = np.vstack([np.linspace(0, 1, 41), np.linspace(-2, 2, 41)])
    k = simd.kernels({"f": (f, 0, ["sample"])}, "test_call")["f"]
    np.testing.assert_allclose(k(X)[0][:, :, 0], _casadi_columns(f, [X])[0], rtol=1e-14,
                               atol=1e-14)


def test_unknown_operations_fall_back():
    y = ca.SX.sym("y")
    assert simd.kernels({"f": (ca.Function("g", [y], [ca.erf(y)]), 0, ["sample"])},
                        "test_erf") is None
    with pytest.raises(ValueError, match="inputs"):
        simd.kernels({"f": (ca.Function("g", [y], [y]), 0, ["sample", "sample"])}, "t")


def test_a_library_in_the_cache_is_loaded_without_translating(tmp_path, monkeypatch):
    """The second process (here: an emptied table of loaded libraries) finds the library
    by its index and does not translate the Function again; a library removed from the
    cache folder is made again; another Function gets a library of its own."""
    monkeypatch.setenv("BIPED_CACHE_DIR", str(tmp_path))
    monkeypatch.setattr(simd, "_LOADED", {})
    x = ca.SX.sym("x", 2)
    f = ca.Function("index_f", [x], [ca.sin(x[0]) * x[1]])
    X = np.array([[0.1, 0.2, 0.3, 0.4, 0.5], [1.0, 2.0, 3.0, 4.0, 5.0]])
    want = simd.kernels({"f": (f, 0, ["sample"])}, "test_index")["f"](X)[0]
    translated = []
    body = simd._body
    monkeypatch.setattr(simd, "_body", lambda g: translated.append(g.name()) or body(g))
    monkeypatch.setattr(simd, "_LOADED", {})
    got = simd.kernels({"f": (f, 0, ["sample"])}, "test_index")["f"](X)[0]
    assert translated == [] and np.array_equal(got, want)
    (so,) = (tmp_path / "compiled").glob("test_index_simd_*.so")
    so.unlink()
    monkeypatch.setattr(simd, "_LOADED", {})
    got = simd.kernels({"f": (f, 0, ["sample"])}, "test_index")["f"](X)[0]
    assert translated == ["index_f"] and so.is_file() and np.array_equal(got, want)
    g = ca.Function("index_f", [x], [ca.cos(x[0]) * x[1]])
    other = simd.kernels({"f": (g, 0, ["sample"])}, "test_index")["f"](X)[0]
    assert translated == ["index_f"] * 2
    np.testing.assert_allclose(other[0, :, 0], np.cos(X[0]) * X[1], rtol=1e-14)


def test_walker_kernels_keep_the_verdicts(model):
    """The walker on the SIMD kernels and on CasADi's compiled Functions: the same status
    and failing step for every run, states to round-off."""
    from analysis.design import ROBUST_GAIT
    gait = optimize_gait(model, GaitOptions(**ROBUST_GAIT), cache=True)        # on-disk cache
    M1 = [-8.2618, 2.5374, 0.0034, 8.5090]                         # its robust design
    rng = np.random.default_rng(2)
    n = 150
    q0, dq0 = gait.evaluate(0.0)[:2]
    Q = np.repeat(q0[None], n, 0)
    DQ = dq0[None] * (1 + 0.05 * rng.normal(size=(n, 5)))
    H = 0.01 * rng.normal(size=(n, 6))
    fast = ZeroDynamicsWalker(model, gait, SimulationOptions(), rk4_steps=128, jit=True)
    assert fast._simd is not None
    ref = ZeroDynamicsWalker(model, gait, SimulationOptions(), rk4_steps=128, jit=True)
    ref._simd = None                 # CasADi's Functions (interpreted: the reference)
    a = fast.walk(Q, DQ, M1, 0.75, steps=6, terrain=H)
    b = ref.walk(Q, DQ, M1, 0.75, steps=6, terrain=H)
    assert np.array_equal(a.status, b.status) and np.array_equal(a.fail_step, b.fail_step)
    assert len(set(a.status)) > 2                          # walks and several failures
    ok = np.isfinite(b.qu_error)
    np.testing.assert_allclose(a.qu_error[ok], b.qu_error[ok], atol=1e-10)
    np.testing.assert_allclose(a.duration[ok], b.duration[ok], atol=1e-10)


def test_vc_walker_kernel_is_shared_by_gaits_and_keeps_the_verdicts(model, gait):
    """The virtual-constraint walker's node holds no number of its gait (one machine code
    for every gait of a robot), and on the kernels it walks as on CasADi's Functions."""
    from analysis.design import ROBUST_GAIT
    from biped_casadi.simulation import virtual_constraint_walker
    other = optimize_gait(model, GaitOptions(**ROBUST_GAIT), cache=True)     # on-disk cache
    assert abs(other.T - gait.T) > 1e-3
    walkers = [virtual_constraint_walker(g, None, 200, jit=True) for g in (gait, other)]
    assert all(w._simd is not None for w in walkers)
    sources = [w._simd["chunk"]._source() for w in walkers]
    assert sources[0][0] == sources[1][0]                       # the node's C: the same
    assert set(sources[0][1]) == set(sources[1][1]) == {"h_d"}  # the gait: its spline only
    for g, fast in zip((gait, other), walkers):
        ref = virtual_constraint_walker(g, None, 200, jit=True)
        assert ref is fast                                       # memoised: copy the kernels
        simd_kernels, fast._simd = fast._simd, None              # CasADi's Functions
        q0, dq0 = g.evaluate(0.75 * g.T)[:2]                   # on the section
        x = np.array([[q0[0], dq0[0]]]) * (1 + np.linspace(-1, 1, 60)[:, None] * [0.0, 2.0])
        try:
            b = fast.walk_from_section(x, steps=5)
        finally:
            fast._simd = simd_kernels
        a = fast.walk_from_section(x, steps=5)
        assert np.array_equal(a.status, b.status) and np.array_equal(a.fail_step, b.fail_step)
        assert len(set(a.status)) >= 3                 # walks and failures of several kinds
        ok = np.isfinite(b.qu_error)
        assert ok.any()
        np.testing.assert_allclose(a.qu_error[ok], b.qu_error[ok], atol=1e-10)
        np.testing.assert_allclose(a.duration[ok], b.duration[ok], atol=1e-10)
