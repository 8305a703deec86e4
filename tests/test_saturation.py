"""Torque saturation keeps a NaN (biped_casadi.control.saturation): a law that produced
NaN is still seen to have failed through every saturating path, the running
controller's ``applied``, the walking simulator's ``applied_torque`` (its run stops,
'diverged') and both C exports with ``--saturate`` (their not-finite return code 3);
+-inf and torques beyond the limit become the limit."""
from __future__ import annotations

import copy

import casadi as ca
import numpy as np
import pytest

from biped_casadi import SimulationOptions, TimeVaryingController
from biped_casadi.control import clip_torques
from biped_casadi.control.compiled import CompiledController, build_library, find_c_compiler
from biped_casadi.control.compiled_running import CompiledRunningLaw
from biped_casadi.control.export import RETURN_CODES, c_sources, exported_law
from biped_casadi.control.export_folder import write_export
from biped_casadi.control.export_running import (RUNNING_RETURN_CODES, exported_running_law,
                                                 running_c_sources)
from biped_casadi.control.running import RunningController
from biped_casadi.simulation.full_order import Simulator

CC = find_c_compiler()
needs_cc = pytest.mark.skipif(CC is None, reason="no C compiler (gcc, cc or $CC) on this machine")
NAN, INF = float("nan"), float("inf")
#: what a failed law adds to its torques: NaN, nothing, -inf, +inf
FAILURE = (NAN, 0.0, -INF, INF)
LIMIT = 150.0
NOT_FINITE = 3
assert RETURN_CODES[NOT_FINITE] == RUNNING_RETURN_CODES[NOT_FINITE] == "not_finite"


def _same(a, b):
    """Equal, NaN where NaN."""
    return np.array_equal(np.asarray(a, float).ravel(), np.asarray(b, float).ravel(),
                          equal_nan=True)


def _expected(u):
    """``u`` plus FAILURE clipped by hand: NaN, u[1] within the limit, -limit, +limit."""
    u = np.asarray(u, float).ravel()
    return np.array([NAN, min(max(u[1], -LIMIT), LIMIT), -LIMIT, LIMIT])


def _failing(law, t_index, after):
    """``law`` (a Function whose first output is the torques) with FAILURE added to its
    torques once its input ``t_index`` (a time) exceeds ``after``."""
    xs = [ca.SX.sym(law.name_in(i), law.sparsity_in(i)) for i in range(law.n_in())]
    out = law(*xs)
    out = out if isinstance(out, (list, tuple)) else [out]
    u = ca.if_else(xs[t_index] > after, out[0] + ca.DM(FAILURE), out[0])
    return ca.Function(f"failing_{law.name()}", xs, [u, *out[1:]], law.name_in(),
                       law.name_out())


def test_clip_torques_keeps_nan_and_clips_infinities():
    u = [NAN, 1.0, -INF, INF, 200.0, -200.0, LIMIT]
    want = [NAN, 1.0, -LIMIT, LIMIT, LIMIT, -LIMIT, LIMIT]
    assert _same(clip_torques(np.array(u), LIMIT), want)
    assert isinstance(clip_torques(ca.DM(u), LIMIT), ca.DM)
    assert _same(clip_torques(ca.DM(u), LIMIT), want)
    for kind in (ca.SX, ca.MX):
        x = kind.sym("u", len(u))
        assert _same(ca.Function("f", [x], [clip_torques(x, LIMIT)])(u), want), kind
    assert _same(clip_torques(np.array(u[:4]), INF), u[:4])


def test_running_controller_applies_nan_as_nan(model, running_gait):
    c = RunningController(model, running_gait, saturate=True)
    assert _same(c.applied(ca.DM([NAN, 1.0, -INF, NAN])), [NAN, 1.0, -LIMIT, NAN])
    X = running_gait.x_stance
    q, dq = X[:model.nq, 3], X[model.nq:, 3]
    plain = c.stance_law
    c.stance_law = _failing(plain, 2, 0.05)
    assert _same(c.applied_law("stance")(q, dq, 0.01), c.applied(plain(q, dq, 0.01)))
    assert _same(c.applied_law("stance")(q, dq, 0.1), _expected(plain(q, dq, 0.1)))


def _failing_tv(gait):
    """The README's design, its law failing after half a step."""
    tv = TimeVaryingController(gait, [-10, 7.5, 10, -5], rejoin=0.5)
    bad = copy.copy(tv)
    bad.law = _failing(tv.law, 2, 0.5 * float(gait.T))
    return tv, bad


def test_a_saturating_walk_stops_where_its_law_gives_nan(gait):
    """The simulator's RK4 on the applied torques: a NaN law makes the state not
    finite, the run stops 'diverged' at half the step, saturating or not."""
    tv, bad = _failing_tv(gait)
    sim = Simulator(bad, SimulationOptions(steps=2, saturate=True))
    assert _same(sim.applied_torque(ca.DM([NAN, 1.0, -INF, 200.0]))[0],
                 [NAN, 1.0, -LIMIT, LIMIT])
    for saturate in (False, True):
        r = Simulator(bad, SimulationOptions(steps=2, saturate=saturate)).run(
            gait.q(0.0), gait.dq(0.0))
        assert r.status == "diverged" and "not finite" in r.message, (saturate, r.message)
        assert r.failure_time == pytest.approx(0.5 * float(gait.T), abs=2e-2)
    ok = Simulator(tv, SimulationOptions(steps=2, saturate=True)).run(gait.q(0.0), gait.dq(0.0))
    assert ok.status == "ok", ok.message


@needs_cc
def test_the_walking_c_export_returns_not_finite_for_a_nan_law(gait, tmp_path):
    tv, bad = _failing_tv(gait)
    folder = tmp_path / "walk"
    write_export(c_sources(exported_law(bad, saturate=True, torque_limit=LIMIT),
                           {"gait file": "test"}), folder)
    lib = CompiledController(build_library(folder, tmp_path / "walk.so"), bad)
    p = lib.step_start(gait.q(0.0), gait.dq(0.0)).p
    t0, t1 = 0.1 * float(gait.T), 0.7 * float(gait.T)
    rc, u = lib.torque(t0, gait.q(t0), gait.dq(t0), p)
    assert rc == 0 and np.all(np.isfinite(u))
    rc, u = lib.torque(t1, gait.q(t1), gait.dq(t1), p)
    assert rc == NOT_FINITE
    assert _same(u, _expected(tv.torque(gait.q(t1), gait.dq(t1), t1).u))


@needs_cc
def test_the_running_c_export_returns_not_finite_for_a_nan_law(model, running_gait, tmp_path):
    c = RunningController(model, running_gait, 400.0, 30.0, M1=(0.0, 0.95, 0.95, 0.0),
                          saturate=True)
    plain = c.stance_law
    c.stance_law = _failing(plain, 2, 0.05)
    folder = tmp_path / "run"
    write_export(running_c_sources(exported_running_law(c), {"gait file": "test"}), folder)
    lib = CompiledRunningLaw.build(folder, c, tmp_path / "run.so")
    X = running_gait.x_stance
    q, dq = X[:model.nq, 3], X[model.nq:, 3]
    rc, u = lib.torque(0, 0.01, q, dq)
    assert rc == 0 and np.all(np.isfinite(u))
    rc, u = lib.torque(0, 0.1, q, dq)
    assert rc == NOT_FINITE and _same(u, _expected(plain(q, dq, 0.1)))
