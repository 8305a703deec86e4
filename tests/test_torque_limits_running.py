"""Per-joint torque limits in running: the running step's bounds, its controller's clip,
its C export, MuJoCo's motors and the closed loop's constraints take each joint's limit,
not the smallest for every joint.

The robot is RABBIT with hips of 60 N m and knees of 150 N m: its 1.5 m/s running step
pushes with about 106 N m at the stance knee (above the smallest limit, within the
knees') and, unbounded, about 68 N m at the hips (held to 60 here)."""
from __future__ import annotations

import json
import re

import numpy as np
import pytest

from analysis.cli import main
from biped_casadi import robot
from biped_casadi.control.running import RunningController
from biped_casadi.model.description import builtin_path
from gait_opt.running import RunningOptions, optimize_running
from gait_opt.running_checks import check_running
from gait_opt.running_solve import MAX_TIGHTENINGS, TORQUE_TOL, torque_peaks

LIMITS = (150.0, 60.0, 60.0, 150.0)                 # u1 .. u4: knee, hip, hip, knee
STABLE_M1 = (0.0, 0.95, 0.95, 0.0)


@pytest.fixture(scope="module")
def hips60(tmp_path_factory):
    """(robot file, model, its 1.5 m/s running step)."""
    text = builtin_path("rabbit").read_text()
    text, n = re.subn(r"(?m)^torque_limit\s*=.*$", "torque_limit = { hip = 60.0, knee = 150.0 }",
                      text)
    assert n == 1
    path = tmp_path_factory.mktemp("robots") / "hips60.toml"
    path.write_text(text.replace('name = "RABBIT"', 'name = "hips60"'))
    m = robot(str(path))
    return path, m, optimize_running(m, RunningOptions(), cache=True)


def test_the_running_step_is_bounded_per_joint(hips60):
    """Its knee pushes beyond the smallest limit (60 N m), its hips stay within theirs
    between the points too (the quadratic through the points and quarter points peaked
    0.07 N m above 60 N m at a hip before the bound was lowered by that and the step
    solved again), and the dense check measures each torque against its own limit."""
    _, m, g = hips60
    assert g.success and RunningOptions().limit(m) == LIMITS
    r = check_running(m, g)
    peaks = r.torque_max_dense_each
    assert len(peaks) == 4 and max(peaks) == r.torque_max_dense
    assert peaks[0] > 100.0                                     # the stance knee
    assert all(p <= u + TORQUE_TOL for p, u in zip(peaks, LIMITS))
    exact = np.maximum(torque_peaks(g.u_stance), torque_peaks(g.u_flight))
    assert np.all(exact <= np.array(LIMITS) + TORQUE_TOL) and np.all(exact >= peaks)
    assert max(peaks[1], peaks[2]) > 59.9                       # the hips' bound is active
    assert r.violations(LIMITS) == []
    passes = g.solver_stats["tightenings"]
    assert 1 <= len(passes) <= MAX_TIGHTENINGS and "failed" not in passes[-1]
    first = passes[0]
    assert max(first["excess"][1:3]) > 1e-3 and max(first["excess"][0], first["excess"][3]) < 0
    assert first["bound"][0] == first["bound"][3] == 150.0 and max(first["bound"][1:3]) < 60.0
    assert dict(r.violations(60.0))["torque limit"] == pytest.approx(peaks[0] - 60.0)
    assert RunningOptions(torque_limit=90.0).limit(m) == 90.0


def test_the_running_controller_clips_each_torque_at_its_limit(hips60):
    """The controller's (and so its C export's) clip is per torque: a knee torque of
    100 N m passes, a hip torque of 100 N m is clipped at 60."""
    from biped_casadi.control.export_running import (RUNNING_HEADER, exported_running_law,
                                                     running_c_sources)
    _, m, g = hips60
    c = RunningController(m, g, 400.0, 30.0, M1=STABLE_M1, saturate=True)
    assert c.torque_limit == c.clipped_at == LIMITS
    u = np.array([100.0, 100.0, -100.0, -160.0])
    assert np.asarray(c.applied(u)).tolist() == [100.0, 60.0, -60.0, -150.0]
    law = c.applied_law("stance")
    n = m.nq
    X = np.asarray(g.x_stance, float)
    q, dq = X[:n, 3] + 0.3, X[n:, 3] + 3.0
    raw = np.array(c.stance_law(q, dq, 0.1)).ravel()
    got = np.array(law(q, dq, 0.1)).ravel()
    assert np.array_equal(got, np.clip(raw, -np.array(LIMITS), np.array(LIMITS)))
    assert np.abs(raw).max() > 60.0
    exp = exported_running_law(c)
    assert exp.controller["torque_limit"] == LIMITS
    header = running_c_sources(exp)[RUNNING_HEADER]
    assert "torques clipped at +-(150.0, 60.0, 60.0, 150.0) (u1 .. u4, each joint's) N m" \
        in header
    with pytest.raises(ValueError, match="torque_limit must be one number or 4, one per "):
        RunningController(m, g, torque_limit=(60.0, 150.0))
    with pytest.raises(ValueError, match="torque_limit must be a positive number"):
        RunningController(m, g, torque_limit=(60.0, 150.0, -1.0, 60.0))


def test_the_closed_loops_constraints_take_each_joints_limit(hips60):
    import casadi as ca
    from analysis.stability.running_domains import _phase_constraints
    _, m, g = hips60
    c = RunningController(m, g, 400.0, 30.0, M1=STABLE_M1)
    u = ca.SX.sym("u", 4)
    cons, names = _phase_constraints(c, u, ca.SX.zeros(0, 1), ())
    values = np.array(ca.Function("c", [u], [cons])([100.0, 50.0, -70.0, 0.0])).ravel()
    assert values.tolist() == [50.0, 10.0, 130.0, 150.0, 250.0, 110.0, -10.0, 150.0]
    assert names[:2] == ("torque u1 <= 150 N m", "torque u2 <= 60 N m")


def test_mujocos_running_motors_have_each_joints_limit(hips60):
    """The robot's own motors let the stance knee push beyond 60 N m, and the run goes
    on; with one limit of 60 N m for every motor the first stride fails."""
    pytest.importorskip("mujoco")
    from biped_casadi.mujoco import ContactSettings
    from biped_casadi.mujoco.running import RunningLoop
    _, m, g = hips60
    c = RunningController(m, g, 400.0, 30.0, M1=STABLE_M1)
    fine = ContactSettings(timestep=0.001)
    loop = RunningLoop(c, fine)
    assert loop.torque_limit == LIMITS
    own = loop.run(None, 3)
    assert own.status == "ran", own.message
    assert all(s.peak_torque > 100.0 for s in own.strides)
    one = RunningLoop(c, fine, torque_limit=60.0).run(None, 3)
    assert one.status != "ran" and len(one.strides) < 3, one.message
    stopped = RunningLoop(c, fine, stop_on_saturation=True).run(None, 3)
    assert stopped.status == "saturated"
    assert re.search(r"\|u[1-4]\| = \d+\.\d N m commanded \(its limit (60|150)\)",
                     stopped.message), stopped.message


def test_the_running_command_says_each_joints_limit(hips60, capsys, tmp_path):
    path, _, _ = hips60
    out = str(tmp_path / "step.json")
    assert main(["running", "--robot", str(path), "--json", "--out", out]) == 0
    s = json.loads(capsys.readouterr().out)
    assert len(s["checks"]["torque_max_dense_each"]) == 4
    assert main(["running", "--robot", str(path), "--out", out]) == 0
    assert "limit 150/60/60/150)" in capsys.readouterr().out


def test_torques_at_their_limits_are_told_with_each_joints(hips60, monkeypatch):
    """The step's rows |u_i| <= U_i hold each torque to its joint's limit, point after
    point: torques held at 150, 60, 30, 10 N m put the stance knee (150) and the stance
    hip (60) at their limits, the others at none; a failure says each one's limit."""
    from analysis.cli.running import failure
    from gait_opt import running
    from gait_opt.running import running_guess
    from gait_opt.running_solve import torque_at_limit
    _, m, _ = hips60
    o = RunningOptions(n_stance=4, n_flight=3).for_model(m)
    guess = running_guess(m, o)
    u = np.array([[150.0], [60.0], [30.0], [10.0]])
    for phase in ("stance", "flight"):
        guess[f"u_{phase}"] = np.repeat(u, guess[f"u_{phase}"].shape[1], axis=1)

    class Built(Exception):
        pass

    def stop(con, *args):
        raise Built(con)
    monkeypatch.setattr(running, "solve_running", stop)
    with pytest.raises(Built) as built:
        optimize_running(m, o, guess)
    con = built.value.args[0]
    g = np.array(con.opti.debug.value(con.opti.g, con.opti.initial()), float).ravel(order="F")
    joints = ["knee", "hip", "hip b", "knee b"]
    points = 4 * o.n_stance + 1 + 4 * o.n_flight + 1
    got = torque_at_limit(con.opti, g, con.groups, joints)
    assert got == [dict(joint="knee", count=points, limit=150.0),
                   dict(joint="hip", count=points, limit=60.0)]
    said = failure(1.5, dict(return_status="Maximum_Iterations_Exceeded", iterations=3,
                             torque_at_limit=got))
    assert f"torques at their limits (knee at {points} points of its 150 N m, hip at " \
           f"{points} points of its 60 N m)" in said


def test_torque_peaks_are_the_quadratics_exact_peaks():
    """Each interval's quadratic peaks at an end or its vertex: the exact peak bounds a
    fine sampling of the interpolant (within its round-off) and equals it where the
    samples hit the vertex; a torque that does not overshoot peaks at a point."""
    from gait_opt.running import hermite_simpson
    rng = np.random.default_rng(3)
    U = rng.uniform(-60.0, 60.0, (4, 9))
    U[3] = [0.0, 10.0, 40.0, 45.0, 50.0, 55.0, 58.0, 59.0, 60.0]      # monotone, no vertex
    tn = np.linspace(0.0, 1.0, 9)
    t = np.linspace(0.0, 1.0, 4 * 20000 + 1)
    _, u = hermite_simpson(tn, np.zeros((1, 9)), np.zeros((1, 9)), U, t)
    sampled, exact = np.abs(u).max(axis=1), torque_peaks(U)
    assert np.all(exact >= sampled - 1e-12) and np.allclose(exact, sampled, rtol=0, atol=1e-6)
    assert exact[3] == 60.0 and np.any(exact[:3] > np.abs(U[:3]).max(axis=1))
    a = np.array([[0.0, 1.0, 0.0]])                  # a hump: 4 s (1 - s), vertex at s = 1/2
    assert torque_peaks(a)[0] == 1.0 and torque_peaks(-a)[0] == 1.0


class _Step:
    def __init__(self, peak, success=True, iterations=10):
        self.u_stance = np.array([[0.0, peak, 0.0]])     # peaks at exactly ``peak``
        self.u_flight = np.zeros((1, 3))
        self.success = success
        self.solver_stats = dict(iterations=iterations, wall_s=1.0, success=success,
                                 return_status="Solve_Succeeded" if success else "Failed")


def test_a_step_within_its_limits_is_solved_once():
    """The step whose limits hold between the points is the first solve's, the same
    object: nothing re-solved, nothing added to its statistics."""
    from gait_opt.running_solve import within_path_limits
    calls, first = [], _Step(59.0)

    def solve(guess, umax, points):
        calls.append((guess, umax, points))
        return first
    got = within_path_limits(solve, 60.0, lambda gait: [])
    assert got is first and calls == [(None, 60.0, ())]
    assert "tightenings" not in got.solver_stats


def test_a_torque_above_its_limit_lowers_its_bound_and_solves_again():
    """A peak above the limit lowers the bound by its excess, the step solved again from
    the one found; at most MAX_TIGHTENINGS times; a failed re-solve keeps the step
    before it, and says so."""
    from gait_opt.running_solve import within_path_limits
    calls = []

    def solve(guess, umax, points):   # overshoots the bound by 0.05 more at every solve
        calls.append((guess, umax))
        return _Step(float(np.max(umax)) + 0.05 * len(calls))
    got = within_path_limits(solve, 60.0)
    passes = got.solver_stats["tightenings"]
    assert len(calls) == 1 + MAX_TIGHTENINGS and len(passes) == MAX_TIGHTENINGS
    assert [p["excess"][0] for p in passes] == pytest.approx([0.05] * 3)
    assert [p["bound"][0] for p in passes] == pytest.approx([59.95, 59.9, 59.85])
    assert [c[0] is not None for c in calls] == [False, True, True, True]
    assert got.solver_stats["iterations"] == 40 and got.solver_stats["wall_s"] == 4.0

    def converging(guess, umax, points):      # the re-solve lands on the limit
        return _Step(60.05 if guess is None else 60.0)
    assert len(within_path_limits(converging, 60.0).solver_stats["tightenings"]) == 1
    first = _Step(60.05)

    def failing(guess, umax, points):
        return first if guess is None else _Step(59.0, success=False)
    got = within_path_limits(failing, 60.0)
    assert got is first and got.solver_stats["tightenings"][0]["failed"] == "Failed"
