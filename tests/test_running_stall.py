"""The running step's stall watch (gait_opt.running_solve): a search whose constraint
violation no longer falls is ended, and a failed solve says which constraints its last
iterate violates and which torques sit at their limit.  Small grids only (a few seconds);
the figures on the default grid (converging speeds unchanged, an unreachable speed
failing in about 30 s instead of minutes) are in the running how-to."""
from __future__ import annotations

from types import SimpleNamespace

import casadi as ca
import numpy as np
import pytest

import gait_opt.running as running
from biped_casadi.model import flight_model
from gait_opt.options import leg_scale
from gait_opt.running import (MIN_STEP_LENGTH, RunningOptions, hermite_simpson,
                              optimize_running, running_guess)
from gait_opt.running_solve import (FEASIBLE, STALL_FACTOR, STALL_WINDOW, TORQUE_LIMIT,
                                    stalled, torque_at_limit)

#: the groups a failed running step names, as its one line and the how-to quote them:
#: (label, unit)
LABELS = {
    ("stance duration bounds", "s"), ("flight duration bounds", "s"),
    ("collocation defects of stance (the dynamics)", ""),
    ("collocation defects of flight (the dynamics)", ""),
    ("torque rate bound", "N m"), ("torque limit |u| <= umax", "N m"),
    ("torso lean bound", "rad"), ("joint range (knees, hips)", "rad"),
    ("normal ground force Fz >= 0 in stance", "N"), ("Fz = 0 at takeoff", "N"),
    ("friction cone in stance", "N"), ("swing-foot clearance in stance", "m"),
    ("friction cone on the force's rate at takeoff", "N/s"),
    ("friction cone at the quarter points", "N"),
    ("stance foot above the ground in flight", "m"),
    ("swing foot above the ground in flight", "m"), ("touchdown of the swing foot", "m"),
    ("trailing-foot clearance at touchdown", "m"), ("swing foot's strike speed", "m/s"),
    ("takeoff state", ""), ("periodicity through the landing", ""),
    ("other foot's lift-off speed", "m/s"),
    ("landing impulse (upward, in the friction cone)", "N s"),
    ("torques continuous through takeoff", "N m"),
    ("step length = speed x (stance + flight)", "m"), ("minimum step length", "m")}


@pytest.mark.parametrize("history, window, expected", [
    ([5.0] * 10, 5, True),                        # no progress at all
    ([5.0] * 5, 5, False),                        # not more than a window yet
    ([5.0] * 10, None, False),                    # no watch
    ([8.0] * 5 + [4.1] + [9.0] * 4, 5, True),     # 4.1 > 0.5 * 8: not quite halved
    ([8.0] * 5 + [3.9] * 5, 5, False),            # halved within the window
    ([1e-3] * 5 + [2e-7] * 5, 5, False),          # feasible: never stalled
    ([1e-3] * 5 + [FEASIBLE * 2] + [1.0] * 4, 5, False),  # progress, though it rose again
    ([1.0, FEASIBLE / 2] + [1e-3] * 5, 5, False),  # feasible once: left for the cost
    ([1.0, FEASIBLE * 2] + [1e-3] * 5, 5, True),   # never feasible, then no progress
])
def test_stalled_on_made_up_histories(history, window, expected):
    assert stalled(history, window) is expected


def test_stalled_reads_the_window_only():
    """The smallest of the window is compared with the smallest before it."""
    h = [10.0, 1.0] + [0.6] * 3
    assert stalled(h, 3) and not stalled(h, 3, factor=0.7)
    assert STALL_FACTOR < 1 and STALL_WINDOW >= 1


def test_an_unreachable_speed_stops_on_a_stall(model):
    """6 m/s on a small grid: the watch ends the search before IPOPT's limit, and the
    last iterate is described in named groups."""
    from analysis.cli.running import failure
    o = RunningOptions(speed=6.0, n_stance=6, n_flight=4, stall_window=10,
                       ipopt={"max_iter": 300})
    s = optimize_running(model, o).solver_stats
    assert not s["success"] and s["return_status"] == "Stalled", s
    assert 10 <= s["iterations"] < 300 and s["stall_window"] == 10
    labels = {name for name, _ in LABELS}
    assert s["violated"] and all(d["name"] in labels and d["violation"] > FEASIBLE
                                 for d in s["violated"])
    joints = {d["joint"] for d in s["torque_at_limit"]}
    assert joints <= {"stance knee", "stance hip (torso)", "swing hip", "swing knee"}
    line = failure(6.0, s)
    assert "\n" not in line and "did not halve over 10 iterations" in line
    assert s["violated"][0]["name"] in line


def test_a_guess_is_described_in_named_groups(model, monkeypatch):
    """No iteration: the built-in guess violates the dynamics and more (here a stance
    of at least 0.5 s, the guess's being shorter); every violated row is traced to its
    constraint with its unit, the phases told apart."""
    import gait_opt.running_solve as rs
    every = []

    def all_groups(opti, g, groups, **kw):
        every.extend(original(opti, g, groups, most=None))
        return every[:3]
    original = rs.violated
    monkeypatch.setattr(rs, "violated", all_groups)
    o = RunningOptions(n_stance=4, n_flight=3, stall_window=None, ipopt={"max_iter": 0},
                       stance_time_bounds=(0.5, 0.8))
    s = optimize_running(model, o).solver_stats
    assert s["return_status"] == "Maximum_Iterations_Exceeded" and len(every) > 3
    names = {d["name"] for d in every}
    assert {"collocation defects of stance (the dynamics)", "stance duration bounds"} <= names
    assert "flight duration bounds" not in names
    assert all((d["name"], d["unit"]) in LABELS for d in every), every


def _flat(a):
    """A casadi or numpy value as a flat float array, column after column."""
    return np.array(a, dtype=float).ravel(order="F")


class _Built(Exception):
    """The running step's problem, built and not solved (its LabelledConstraints)."""


def _built(model, monkeypatch, opts, guess):
    def stop(con, *args):
        raise _Built(con)
    monkeypatch.setattr(running, "solve_running", stop)
    with pytest.raises(_Built) as built:
        optimize_running(model, opts, guess)
    return built.value.args[0]


def _expected_violations(model, o, guess):
    """{label: violation of every row, in the order added}, computed here from the model's
    Functions at the point ``guess`` (a violation is max(low - value, value - high),
    negative inside the bounds: the same whichever side Opti moves a term to)."""
    fl, n, nu, mu = flight_model(model), model.nq, model.nu, o.mu - o.mu_margin
    Ts, Tf, Xs, Us, Xf, Uf = (np.asarray(guess[k], float) for k in (
        "T_stance", "T_flight", "x_stance", "u_stance", "x_flight", "u_flight"))
    out = {}

    def add(label, lo, value, hi):
        value = _flat(value)
        out.setdefault(label, []).extend(np.maximum(lo - value, value - hi))

    rhs = ({"x": Xs, "u": Us, "T": Ts, "n": o.n_stance, "m": n, "f": lambda x, u: np.r_[
                x[n:], _flat(model.forward_dynamics(x[:n], x[n:], u))]},
           {"x": Xf, "u": Uf, "T": Tf, "n": o.n_flight, "m": fl.ne, "f": lambda x, u: np.r_[
                x[fl.ne:], _flat(fl.flight_dynamics(x[:fl.ne], x[fl.ne:], u))]})
    for ph, name, bounds in zip(rhs, ("stance", "flight"),
                                (o.stance_time_bounds, o.flight_time_bounds)):
        X, U, h = ph["x"], ph["u"], ph["T"] / ph["n"]
        ph["F"] = F = np.column_stack([ph["f"](X[:, k], U[:, k]) for k in range(X.shape[1])])
        add(f"{name} duration bounds", bounds[0], ph["T"], bounds[1])
        x0, xm, x1, f0, fm, f1 = (A[:, s] for A in (X, F) for s in (
            slice(0, -1, 2), slice(1, None, 2), slice(2, None, 2)))
        add(f"collocation defects of {name} (the dynamics)", 0,
            np.abs(np.r_[_flat(xm - (x0 + x1) / 2 - h / 8 * (f0 - f1)),
                         _flat(x1 - x0 - h / 6 * (f0 + 4 * fm + f1))]), 0)
    for ph in rhs:
        U, umax = ph["u"], o.limit(model)
        u0, um, u1 = U[:, 0:-1:2], U[:, 1::2], U[:, 2::2]
        for u in (U, .375 * u0 + .75 * um - .125 * u1, -.125 * u0 + .75 * um + .375 * u1):
            add(TORQUE_LIMIT, -umax, u, umax)
        step = o.torque_rate_max * ph["T"] / (2 * ph["n"])
        add("torque rate bound", -np.inf, U[:, 1:] - U[:, :-1], step)
        add("torque rate bound", -step, U[:, 1:] - U[:, :-1], np.inf)
    Fz, Fx = (_flat(a) for a in fl.takeoff_guard.map(Xs.shape[1])(Xs[:n], Xs[n:], Us))
    add("normal ground force Fz >= 0 in stance", 0, Fz[:-1], np.inf)
    add("Fz = 0 at takeoff", 0, Fz[-1], 0)
    add("friction cone in stance", 0, np.r_[mu * Fz - Fx, mu * Fz + Fx], np.inf)
    x, u = ca.SX.sym("x", 2 * n), ca.SX.sym("u", nu)
    J = ca.Function("J", [x, u], [ca.jacobian(ca.vertcat(*fl.takeoff_guard(x[:n], x[n:], u)),
                                              ca.vertcat(x, u))])
    du = (Us[:, -3] - 4 * Us[:, -2] + 3 * Us[:, -1]) / (Ts / o.n_stance)
    dF = np.array(J(Xs[:, -1], Us[:, -1])) @ np.r_[rhs[0]["F"][:, -1], du]
    add("friction cone on the force's rate at takeoff", -np.inf,
        [mu * dF[0] + dF[1], mu * dF[0] - dF[1]], 0)
    t = np.linspace(0, Ts, Xs.shape[1])
    tq = np.r_[t[:-1:2] + (t[2] - t[0]) / 4, t[:-1:2] + 3 * (t[2] - t[0]) / 4]
    xq, uq = hermite_simpson(t, Xs, rhs[0]["F"], Us, tq)
    Fzq, Fxq = (_flat(a) for a in fl.takeoff_guard.map(tq.size)(xq[:n], xq[n:], uq))
    add("friction cone at the quarter points", 0, np.r_[mu * Fzq - Fxq, mu * Fzq + Fxq],
        np.inf)
    zsw = _flat(model.swing_foot.map(Xs.shape[1])(Xs[:n])[1])
    s = np.linspace(0, 1, Xs.shape[1])
    add("swing-foot clearance in stance", o.clearance * 4 * s * (1 - s), zsw, np.inf)
    feet = [np.array(fl.feet(Xf[:fl.ne, k])) for k in range(Xf.shape[1])]
    z_st, z_sw = np.array([p[1, 0] for p in feet]), np.array([p[1, 1] for p in feet])
    add("stance foot above the ground in flight", 0, z_st[1:], np.inf)
    add("swing foot above the ground in flight", 0, z_sw[:-1], np.inf)
    add("touchdown of the swing foot", 0, z_sw[-1], 0)
    add("trailing-foot clearance at touchdown", o.trailing_clearance, z_st[-1], np.inf)
    v_end = np.array(fl.feet_velocity(Xf[:fl.ne, -1], Xf[fl.ne:, -1]))
    add("swing foot's strike speed", -np.inf, v_end[1, 1], -o.min_strike_speed)
    up = model.description.upright_q
    for Q in (Xs[:n], Xf[:n]):
        lean = _flat(model.torso_angle.map(Q.shape[1])(Q)) - model.description.torso_upright
        add("torso lean bound", -o.torso_lean_max, lean, o.torso_lean_max)
        for i in range(1, n):
            lo, hi = ((-o.knee_flexion_max, o.stance_knee_max) if i in model.stance_knees
                      else (o.swing_knee_min, o.knee_flexion_max) if i in model.swing_knees
                      else (up[i] - np.pi, up[i] + np.pi))
            add("joint range (knees, hips)", lo, Q[i], hi)
    e0 = np.r_[tuple(_flat(a) for a in fl.takeoff(Xs[:n, -1], Xs[n:, -1]))]
    add("takeoff state", 0, np.abs(Xf[:, 0] - e0), 0)
    q_plus, dq_plus, F, _, v_other, p = (_flat(a) for a in fl.landing_swing(
        Xf[:fl.ne, -1], Xf[fl.ne:, -1]))
    add("periodicity through the landing", 0, np.abs(np.r_[q_plus, dq_plus] - Xs[:, 0]), 0)
    add("landing impulse (upward, in the friction cone)", 0,
        [F[1], mu * F[1] - F[0], mu * F[1] + F[0]], np.inf)
    add("other foot's lift-off speed", o.min_liftoff_speed, v_other[1], np.inf)
    add("torques continuous through takeoff", 0, np.abs(Uf[:, 0] - Us[:, -1]), 0)
    add("step length = speed x (stance + flight)", 0, abs(p[0] - o.speed * (Ts + Tf)), 0)
    add("minimum step length", MIN_STEP_LENGTH * leg_scale(model), p[0], np.inf)
    return out


def test_every_row_is_what_its_label_says(model, monkeypatch):
    """Every row of the running step's constraints, at a point that violates most of
    them, has the violation of the quantity its label names, computed here from the
    model's Functions; the groups cover the rows in order, each label with its unit."""
    o = RunningOptions(n_stance=4, n_flight=3, cone_quarter_points=True).for_model(model)
    guess = running_guess(model, o)
    steps = np.linspace(-1, 1, guess["u_stance"].shape[1])
    guess["u_stance"] = 40 * np.arange(1, model.nu + 1)[:, None] * steps    # reaching
    guess["u_flight"] = guess["u_flight"] - 20.0                             # the limit
    guess["T_flight"] += 0.01                       # not the speed, the swing foot not
    guess["x_flight"][flight_model(model).ne - 1, -1] += 0.01    # on the ground at the end
    con = _built(model, monkeypatch, o, guess)
    opti = con.opti
    g = _flat(opti.debug.value(opti.g, opti.initial()))
    lbg, ubg = (_flat(ca.evalf(b)) for b in (opti.lbg, opti.ubg))
    v = np.maximum(lbg - g, g - ubg)
    assert [a for _, _, a, _ in con.groups] == [0] + [b for _, _, _, b in con.groups[:-1]]
    assert con.groups[-1][3] == opti.ng == g.size
    assert {(label, unit) for label, unit, _, _ in con.groups} == LABELS
    expected = _expected_violations(model, o, guess)
    assert set(expected) == {label for label, _ in LABELS}
    for label, want in expected.items():
        rows = np.concatenate([np.arange(a, b) for k, _, a, b in con.groups if k == label])
        assert v[rows] == pytest.approx(want, rel=1e-9, abs=1e-9), label
    same = [(k, j) for k, _, a, b in con.groups for j, _, c, d in con.groups    # a swap of
            if k < j and b - a == d - c and np.allclose(v[a:b], v[c:d])]       # two is seen
    assert not same, same


def test_torques_at_the_limit_are_told_by_joint(model, monkeypatch):
    """The rows |u| <= umax of both phases, at the points and the quarter points, map to
    their joints: torques held at 10, 20, 30, 40 N m (flight 1 N m more) under a 30 N m
    limit put the last two joints at the limit at every point, the first two at none."""
    o = RunningOptions(n_stance=4, n_flight=3, torque_limit=30.0).for_model(model)
    guess = running_guess(model, o)
    u = 10.0 * np.arange(1, model.nu + 1)[:, None]
    guess["u_stance"] = np.repeat(u, guess["u_stance"].shape[1], axis=1)
    guess["u_flight"] = np.repeat(u + 1, guess["u_flight"].shape[1], axis=1)
    con = _built(model, monkeypatch, o, guess)
    g = _flat(con.opti.debug.value(con.opti.g, con.opti.initial()))
    joints = [f"joint {j}" for j in range(model.nu)]
    points = 4 * o.n_stance + 1 + 4 * o.n_flight + 1    # 2n + 1 points, 2n quarter points
    assert torque_at_limit(con.opti, g, con.groups, joints) == [
        dict(joint=j, count=points, limit=30.0) for j in joints[2:]]


@pytest.mark.parametrize("args, window", [([], STALL_WINDOW), (["--max-iter", "50"], None)])
def test_command_line_max_iter_is_the_long_search(tmp_path, monkeypatch, capsys, args, window):
    """--max-iter turns the watch off; a failure is one line saying what the last
    iterate showed, nothing written."""
    from analysis.cli import main, running as cli
    seen = []
    stats = {"success": False, "return_status": "Stalled", "iterations": 180,
             "stall_window": STALL_WINDOW,
             "violated": [{"name": "Fz = 0 at takeoff", "unit": "N", "violation": 0.0124,
                           "count": 1}],
             "torque_at_limit": [{"joint": "stance knee", "count": 33, "limit": 150.0}]}

    def solve(model, opts, **kw):
        seen.append(opts)
        return SimpleNamespace(success=False, solver_stats=stats)
    monkeypatch.setattr(cli, "optimize_running", solve)
    monkeypatch.chdir(tmp_path)
    assert main(["running", "--speed", "4", *args]) == 2
    assert [o.stall_window for o in seen] == [window]
    assert seen[0].ipopt == ({"max_iter": 50} if args else {})
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "did not converge at 4 m/s" in err
    assert "stance knee at 33 points" in err and "Fz = 0 at takeoff violated by 0.012 N" in err
    assert list(tmp_path.iterdir()) == []
