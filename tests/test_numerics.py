"""biped_casadi.numerics: the buffer calls of CasADi Functions, and several Functions
compiled into one library."""
from __future__ import annotations

import threading

import casadi as ca
import numpy as np
import pytest

from biped_casadi.numerics import FastCall, compiled


def _function():
    x, p, m = ca.SX.sym("x", 3), ca.SX.sym("p"), ca.SX.sym("m", 2, 3)
    e = ca.SX.sym("e", 0)
    return ca.Function("f", [x, p, m, e], [ca.sin(x) * p, ca.mtimes(m, x), ca.sumsqr(m)])


def test_fast_call_equals_the_plain_call():
    f = _function()
    g = FastCall(f)
    rng = np.random.default_rng(0)
    for _ in range(3):
        x, p, m = rng.normal(size=3), rng.normal(), rng.normal(size=(2, 3))
        got = g(x, p, m, np.zeros(0))
        want = [np.array(v) for v in f(x, p, m, np.zeros(0))]
        for a, b in zip(got, want):
            assert a.shape == b.shape
            np.testing.assert_array_equal(a, b)
    # results are fresh arrays: a later call does not overwrite an earlier result
    first = g(np.ones(3), 1.0, np.ones((2, 3)), np.zeros(0))[0].copy()
    keep = g(np.ones(3), 1.0, np.ones((2, 3)), np.zeros(0))[0]
    g(np.zeros(3), 2.0, np.ones((2, 3)), np.zeros(0))
    np.testing.assert_array_equal(keep, first)


def test_fast_call_threads_and_sparse_outputs():
    f = _function()
    g = FastCall(f)
    out = {}

    def work(k):
        out[k] = [g(np.full(3, k), float(k), np.eye(2, 3), np.zeros(0))[1] for _ in range(200)]
    ts = [threading.Thread(target=work, args=(k,)) for k in range(4)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    for k, rs in out.items():
        for r in rs:
            np.testing.assert_array_equal(r, np.eye(2, 3) @ np.full((3, 1), k))
    x = ca.SX.sym("x", 2)
    sparse = ca.Function("s", [x], [ca.diag(x)])            # a sparse output: plain call
    h = FastCall(sparse)
    assert not h.dense
    np.testing.assert_array_equal(h([1.0, 2.0])[0], np.diag([1.0, 2.0]))


def test_several_functions_in_one_library():
    x = ca.SX.sym("x", 2)
    fs = [ca.Function("lib_a", [x], [x * 2]), ca.Function("lib_b", [x], [ca.dot(x, x)])]
    a, b = compiled(fs, "-O1")
    assert float(b([3.0, 4.0])) == 25.0
    np.testing.assert_array_equal(np.array(a([1.0, 2.0])).ravel(), [2.0, 4.0])


def test_as_count_takes_integers_only():
    from biped_casadi.numerics import as_count
    assert as_count(3, "n") == 3 and type(as_count(np.int64(3), "n")) is int
    assert as_count(0, "seed", low=0) == 0
    for bad in (0, -1, 2.5, 3.0, True, "3", None):
        with pytest.raises(ValueError, match=r"^n must be an integer >= 1, got "):
            as_count(bad, "n")


def test_as_rows_refuses_columns_and_words():
    from biped_casadi.numerics import as_rows
    assert as_rows([1, 2], 2, "x").shape == (1, 2) and as_rows(np.ones((3, 2)), 2, "x").shape == (3, 2)
    for bad, message in ((np.ones((2, 1)), r"got shape \(2, 1\)"), ([], r"got shape \(0,\)"),
                         ("ab", "must be numbers"), ([np.inf, 0], "must be finite")):
        with pytest.raises(ValueError, match="^x " + message if "must" in message else message):
            as_rows(bad, 2, "x")


@pytest.mark.parametrize("solve", [
    "x = ca.SX.sym('x'); s = ipopt_solver('t', {'x': x, 'f': (x - 1) ** 2}, "
    "{'ipopt': {'print_level': 0, 'sb': 'yes'}, 'print_time': False}); x = s(x0=0)['x']",
    "o = ca.Opti(); x = o.variable(); o.minimize((x - 1) ** 2); ipopt_on_one_thread(); "
    "o.solver('ipopt', {'print_time': False}, {'print_level': 0, 'sb': 'yes'}); "
    "x = o.solve().value(x)"])
def test_ipopt_factorises_on_one_blas_thread(solve):
    """MUMPS's BLAS on more threads moved the co-design's optimum by 1e-4 (a Dask
    worker's nanny pins one): every solver of the toolkit pins one in its process (an
    nlpsol, or an Opti as the running step's)."""
    import os
    import subprocess
    import sys
    code = ("import ctypes, casadi as ca; from biped_casadi.numerics import ipopt_solver, "
            f"ipopt_on_one_thread; {solve}; b = ctypes.CDLL('libcasadi-tp-openblas.so.0');"
            "print(float(x), b.openblas_get_num_threads())")
    env = dict(os.environ, OPENBLAS_NUM_THREADS="2", OMP_NUM_THREADS="2")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, timeout=120)
    if "OSError" in out.stderr:
        pytest.skip("CasADi's build has no OpenBLAS of its own")
    x, n = out.stdout.split()
    assert abs(float(x) - 1) < 1e-8 and n == "1", out.stderr
