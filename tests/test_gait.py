"""The reference gait (SPEC section 2): physical validity on a dense grid, dynamic
consistency checked by an independent integrator, the file format, the cache, the
optimiser's exact derivatives, failures, and ``biped gait``.

The default gait comes from the session fixture ``gait`` (on-disk cache); the 0.5 and
1.0 m/s gaits are solved here from the built-in initial guess, once per module.
"""
from __future__ import annotations

import hashlib
import json
import pathlib
import subprocess
import sys
from math import comb

import casadi as ca
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from biped_casadi import RobotParams, rabbit
from gait_opt import (ORBIT_TOL, Gait, GaitFileError, GaitOptimizationError, GaitOptions,
                      GaitSolveResult, OpenOrbitWarning, optimize_gait)
from gait_opt.transcription import build_problem, initial_guess
from gait_opt.urdf_angles import write_gait_csv

N_DENSE = 2001


@pytest.fixture(scope="module")
def gaits(model, gait):
    """Gaits at 0.5, 0.75 (cached default) and 1.0 m/s; the two others solved here from
    the built-in initial guess (no warm start)."""
    out = {0.75: gait}
    for v in (0.5, 1.0):
        out[v] = optimize_gait(model, speed=v)
    return out


SPEEDS = (0.5, 0.75, 1.0)


# ------------------------------------------------------------------ helpers
def bezier(alpha, s, T):
    """q_a^d and its first two time derivatives, evaluated here with numpy from the
    Bernstein form (independent of the toolkit's own evaluation)."""
    M = alpha.shape[1] - 1
    s = np.atleast_1d(s)

    def bern(m, k):
        return comb(m, k) * s**k * (1 - s)**(m - k)

    qa = sum(alpha[:, [k]] * bern(M, k) for k in range(M + 1))
    d1 = sum((alpha[:, [k + 1]] - alpha[:, [k]]) * bern(M - 1, k) for k in range(M)) * M / T
    d2 = sum((alpha[:, [k + 2]] - 2 * alpha[:, [k + 1]] + alpha[:, [k]]) * bern(M - 2, k)
             for k in range(M - 1)) * M * (M - 1) / T**2
    return qa, d1, d2


def dense_physics(m, g, n=N_DENSE):
    """Torques, contact force, swing foot on a dense grid, from the model directly."""
    t = np.linspace(0.0, g.T, n)
    q, dq, ddq = g.q(t), g.dq(t), g.ddq(t)
    D = np.array(m.D.map(n)(q)).reshape(5, 5, n, order="F")
    H = np.array(m.H.map(n)(q, dq))
    tau = np.einsum("ijn,jn->in", D, ddq) + H          # = B u with B = [0; I]
    Fx, Fz = (np.array(v).ravel() for v in m.ground_reaction_acc.map(n)(q, dq, ddq))
    xs, zs = (np.array(v).ravel() for v in m.swing_foot.map(n)(q))
    return dict(t=t, q=q, dq=dq, tau=tau, Fx=Fx, Fz=Fz, xs=xs, zs=zs)


# ------------------------------------------------------- the default problem
def test_default_gait_is_the_known_optimum(gait):
    # the optimum of SPEC section 2 (30 Legendre intervals of degree 3, Bezier degree 6)
    assert gait.T == pytest.approx(0.6903909221, rel=1e-6)
    assert gait.cost == pytest.approx(575.2778858, rel=1e-6)
    assert gait.speed == pytest.approx(0.75, abs=1e-10)
    assert 0.2 <= gait.step_length <= 0.8


@pytest.mark.parametrize("v", SPEEDS)
def test_converges_at_each_speed(gaits, v):
    g = gaits[v]
    assert g.solver_stats["status"] == "Solve_Succeeded"
    assert g.speed == pytest.approx(v, abs=1e-10)
    assert g.options.speed == v
    assert g.solver_stats["dense_grid_violations"] == []


# ------------------------------------------------ physical validity (dense)
@pytest.mark.parametrize("v", SPEEDS)
def test_dense_grid_physics(model, gaits, v):
    g = gaits[v]
    o = g.options
    d = dense_physics(model, g)
    # the unactuated joint gets no torque; the actuated torques respect the limit
    assert np.max(np.abs(d["tau"][0])) < 1e-8
    assert np.max(np.abs(d["tau"][1:])) <= o.torque_limit
    # unilateral contact and friction cone of the stance foot all along the step
    assert np.min(d["Fz"]) >= 0.0
    assert np.all(np.abs(d["Fx"]) <= o.mu * d["Fz"])
    # swing foot strictly above the ground inside the step, on it at T
    assert np.min(d["zs"][1:-1]) > 0.0
    assert abs(d["zs"][-1]) < 1e-10
    # no knee hyperextension
    assert np.max(d["q"][1]) <= 0.0 and np.min(d["q"][4]) >= 0.0


@pytest.mark.parametrize("v", SPEEDS)
def test_impact_is_a_valid_strike(model, gaits, v):
    g = gaits[v]
    qT, dqT = g.q(g.T), g.dq(g.T)
    _, dz = model.swing_foot_velocity(qT, dqT)
    assert float(dz) < -g.options.min_strike_speed + 1e-9          # strikes downward
    _, _, F, _, v_old = (np.array(x).ravel() for x in model.impact_full(qT, dqT))
    assert v_old[1] >= g.options.min_liftoff_speed - 1e-9          # old foot lifts upward
    assert F[1] > 0 and abs(F[0]) <= g.options.mu * F[1]           # impulse inside the cone
    # after the impact the new swing foot rises (it starts on the ground, moving up)
    t = np.linspace(0, 0.05 * g.T, 50)[1:]
    assert np.all(np.array(model.swing_foot.map(t.size)(g.q(t))[1]) > 0)


def test_active_limit_holds_between_nodes(model):
    """With an active torque limit the node constraints alone let |u| exceed it between
    nodes; optimize_gait tightens them until the dense grid is valid."""
    g = optimize_gait(model, torque_limit=20.0)
    d = dense_physics(model, g)
    assert np.max(np.abs(d["tau"][1:])) <= 20.0
    assert np.max(np.abs(d["tau"][1:])) > 19.99                   # and it is active
    first = g.solver_stats["refinements"][0]
    assert first["violations"][0][0] == "torque limit"
    assert g.solver_stats["dense_grid_violations"] == []


def test_clearance_holds_next_to_lift_off_and_strike(model):
    """On 8 intervals with a 0.25 m clearance the swing foot dips under the bound just
    after lift-off, before the first constrained point, where the bound and the foot both
    start at 0: a margin at the nodes only narrows that dip (1.3e-6 m were left after
    three re-solves); the foot's slope there is bounded instead."""
    g = optimize_gait(model, n_intervals=8, clearance=0.25)
    d = dense_physics(model, g, n=20001)
    s = d["t"] / g.T
    below = 0.25 * 4 * s * (1 - s) - d["zs"]
    assert np.max(below[1:-1]) <= 1e-7                  # the checks' tolerance
    first, second = g.solver_stats["refinements"][:2]
    assert first["violations"][0][0] == "swing-foot clearance"
    assert second["margins"] == {"swing-foot clearance at the ends": pytest.approx(
        2 * first["violations"][0][1], rel=1e-3)}
    assert g.solver_stats["dense_grid_violations"] == []


def test_dense_grid_figures_agree_with_check(model, gait):
    d = dense_physics(model, gait)
    c = gait.check(N_DENSE)
    assert c["max_abs_torque"] == pytest.approx(np.max(np.abs(d["tau"][1:])), rel=1e-10)
    assert c["min_normal_force"] == pytest.approx(np.min(d["Fz"]), rel=1e-10)
    assert gait.violations(c) == []


# ----------------------------------------------------- dynamic consistency
@pytest.mark.parametrize("v", SPEEDS)
def test_unactuated_row_reintegrated_independently(model, gaits, v):
    """q_u from scipy's DOP853 with q_a = q_a^d(t) imposed reproduces q_u^d(t)."""
    g = gaits[v]
    T = g.T

    def rhs(t, x):
        qa, dqa, ddqa = (a[:, 0] for a in bezier(g.alpha, t / T, T))
        q, dq = np.r_[x[0], qa], np.r_[x[1], dqa]
        D = np.array(model.D(q))
        H = np.array(model.H(q, dq)).ravel()
        return [x[1], -(D[0, 1:] @ ddqa + H[0]) / D[0, 0]]

    t = np.linspace(0.0, T, 1201)
    sol = solve_ivp(rhs, (0.0, T), g.q(0.0)[[0]].tolist() + g.dq(0.0)[[0]].tolist(),
                    method="DOP853", rtol=1e-13, atol=1e-13, t_eval=t)
    assert sol.success
    assert np.max(np.abs(sol.y[0] - g.q(t)[0])) <= 1e-8
    assert np.max(np.abs(sol.y[1] - g.dq(t)[0])) <= 1e-7
    # and the actuated joints are the Bezier polynomials, as evaluated independently
    qa, dqa, ddqa = bezier(g.alpha, t / T, T)
    assert np.max(np.abs(qa - g.q(t)[1:])) < 1e-12
    assert np.max(np.abs(ddqa - g.ddq(t)[1:])) < 1e-9


@pytest.mark.parametrize("v", SPEEDS)
def test_periodic_through_impact(model, gaits, v):
    g = gaits[v]
    qT, dqT = g.q(g.T), g.dq(g.T)
    assert abs(float(model.swing_foot(qT)[1])) <= 1e-10
    qp, dqp = (np.array(x).ravel() for x in model.impact(qT, dqT))
    assert np.max(np.abs(qp - g.q(0.0))) <= 1e-8
    assert np.max(np.abs(dqp - g.dq(0.0))) <= 1e-8
    assert g.reintegration_error() <= 1e-8


# ------------------------------------------------------------ evaluation
def test_shapes_and_past_T(gait):
    T = gait.T
    for f in (gait.q, gait.dq, gait.ddq):
        assert f(0.3 * T).shape == (5,)
        assert f(np.linspace(0, T, 7)).shape == (5, 7)
    assert gait.u(0.3 * T).shape == (4,)
    assert gait.u(np.linspace(0, T, 7)).shape == (4, 7)
    assert np.allclose(gait.q(np.array([0.3 * T]))[:, 0], gait.q(0.3 * T), atol=0)
    # defined past T (SPEC section 3) and C^2 across it
    eps = 1e-7
    for f in (gait.q, gait.dq, gait.ddq):
        assert np.max(np.abs(f(T + eps) - f(T - eps))) < 1e-4
    assert np.all(np.isfinite(gait.q(np.linspace(T, 1.5 * T, 20))))
    # and before 0, down to -T/2 (the unactuated row integrated backwards): the VC fit
    # uses it; C^2 across 0
    assert gait.t_min == pytest.approx(-0.5 * T)
    for f in (gait.q, gait.dq, gait.ddq):
        assert np.max(np.abs(f(eps) - f(-eps))) < 1e-4
    with pytest.raises(ValueError, match="t must lie"):
        gait.q(-0.6 * T)
    with pytest.raises(ValueError, match="t must lie"):
        gait.q(2.1 * T)


def test_ddq_is_the_derivative_of_dq(gait):
    t = np.linspace(0.02, gait.T - 0.02, 300)
    h = 1e-5
    fd = (gait.dq(t + h) - gait.dq(t - h)) / (2 * h)
    scale = np.max(np.abs(gait.ddq(t)))
    assert np.max(np.abs(fd - gait.ddq(t))) < 1e-6 * scale
    fd_q = (gait.q(t + h) - gait.q(t - h)) / (2 * h)
    assert np.max(np.abs(fd_q - gait.dq(t))) < 1e-6 * np.max(np.abs(gait.dq(t)))


# ------------------------------------------------------------- the file
def test_save_load_round_trip(gait, tmp_path):
    path = gait.save(tmp_path / "g.json")
    g2 = Gait.load(path, model=gait.model)
    assert g2.T == gait.T and g2.options == gait.options
    t = np.linspace(0, gait.T, 101)
    assert np.array_equal(g2.alpha, gait.alpha)
    assert np.max(np.abs(g2.q(t) - gait.q(t))) == 0.0
    body = json.loads(path.read_text())
    assert body["format"] == "biped-casadi-gait" and body["robot"]["name"] == "RABBIT"


def test_corrupted_file_is_refused(gait, tmp_path):
    path = gait.save(tmp_path / "g.json")
    text = path.read_text()
    i = text.index('"T": ') + len('"T": ') + 4           # a digit of T
    flipped = text[:i] + str((int(text[i]) + 1) % 10) + text[i + 1:]
    path.write_text(flipped)
    with pytest.raises(GaitFileError, match="corrupted"):
        Gait.load(path)
    path.write_text(text[: len(text) // 2])
    with pytest.raises(GaitFileError, match="not valid JSON"):
        Gait.load(path)
    with pytest.raises(GaitFileError, match="not found"):
        Gait.load(tmp_path / "missing.json")


def test_other_format_version_is_refused(gait, tmp_path):
    path = gait.save(tmp_path / "g.json")
    body = json.loads(path.read_text())
    body["version"] = 99
    path.write_text(json.dumps(body))
    with pytest.raises(GaitFileError, match="format version 99"):
        Gait.load(path)


def test_other_robot_is_refused(gait, tmp_path):
    path = gait.save(tmp_path / "g.json")
    other = rabbit(RobotParams(m_torso=13.0))
    with pytest.raises(GaitFileError, match="other robot parameters.*torso.mass"):
        Gait.load(path, model=other)


def _resigned(path, edit):
    """Edit a gait file's body and give it a valid checksum again (a file edited by a
    program: only the schema and the orbit checks can catch it)."""
    body = json.loads(path.read_text())
    body.pop("sha256")
    edit(body)
    body["sha256"] = hashlib.sha256(json.dumps(body, sort_keys=True).encode()).hexdigest()
    path.write_text(json.dumps(body))
    return path


@pytest.mark.parametrize("edit, message", [
    (lambda b: b["solution"].pop("alpha"), "'solution' lacks alpha"),
    (lambda b: b.update(solution=[0.69, [], []]), "'solution' must be an object"),
    (lambda b: b.update(solution="0.69"), "'solution' must be an object"),
    (lambda b: b.pop("options"), "missing key(s): options"),
    (lambda b: b.update(robot="RABBIT"), "'robot'"),
    (lambda b: b.update(options=[]), "'options' must be an object"),
    (lambda b: b["options"].update(bezier_degree="6"), "bezier_degree"),
    (lambda b: b["options"].update(polish_steps=10**9), "polish_steps"),
    # beyond these a command that solves the file's problem (gait --family --resolve,
    # m1 --robust) exhausted the memory (n_intervals) or failed inside CasADi (degree)
    (lambda b: b["options"].update(n_intervals=10**7), "'n_intervals' must be at most"),
    (lambda b: b["options"].update(degree=10), "'degree' must be at most 9"),
    (lambda b: b["options"].update(expand="yes"), "'expand' must be true or false"),
    (lambda b: b["options"].update(speed=True), "'speed' must be a positive number"),
    (lambda b: b["solution"].update(T=None), "solution.T"),
    (lambda b: b["solution"].update(T=True), "solution.T"),
    (lambda b: b["solution"].update(T=float("nan")), "solution.T"),
    (lambda b: b["solution"].update(T=10**400), "solution.T"),
    (lambda b: b["solution"].update(x0=[0.1]), "solution.x0"),
    (lambda b: b["solution"].update(x0=[0.1, float("inf")]), "non-finite"),
    (lambda b: b["solution"].update(x0=[[0.1], [0.2]]), "only numbers"),
    (lambda b: b["solution"]["alpha"][3].append(0.0), "solution.alpha"),
    (lambda b: b["solution"]["alpha"].pop(), "solution.alpha"),
    (lambda b: b["solution"]["alpha"][0].__setitem__(2, float("nan")), "non-finite"),
    (lambda b: b["solution"]["alpha"][1].__setitem__(2, None), "only numbers"),
    (lambda b: b["solution"].update(alpha={"q2": []}), "solution.alpha"),
    (lambda b: b.update(solver_stats=[]), "solver_stats"),
    (lambda b: b.update(note="hand-edited"), "unknown key(s): note"),
])
def test_malformed_solution_is_a_gait_file_error(gait, tmp_path, edit, message):
    """Issue 12: a valid checksum over a malformed body gave KeyError / TypeError
    tracebacks or plain ValueErrors; every case is a GaitFileError naming the file."""
    path = _resigned(gait.save(tmp_path / "g.json"), edit)
    with pytest.raises(GaitFileError) as e:
        Gait.load(path)
    assert message in str(e.value) and str(path) in str(e.value)
    assert "\n" not in str(e.value)


@pytest.mark.parametrize("edit", [
    lambda b: b["solution"].update(T=b["solution"]["T"] * 1.01),        # period edited
    lambda b: b["solution"].update(T=b["solution"]["T"] * (1 + 1e-7)),
    lambda b: b["solution"]["x0"].__setitem__(1, b["solution"]["x0"][1] + 1e-6),
    lambda b: b["solution"]["alpha"][0].__setitem__(3, b["solution"]["alpha"][0][3] + 1e-3),
    lambda b: b["solution"].update(T=1e3),                              # cannot even reach T
])
def test_a_gait_that_is_not_a_periodic_orbit_is_refused(gait, tmp_path, edit):
    """Issue 12: with T edited, `biped eig` analysed a non-periodic gait with exit 0
    (fixed-point residual 0.19 instead of 4e-10)."""
    path = _resigned(gait.save(tmp_path / "g.json"), edit)
    with pytest.raises(GaitFileError, match="not a periodic orbit of its robot"):
        Gait.load(path)


@pytest.mark.parametrize("edit", [
    lambda b: b["solution"].update(T=1e300),
    lambda b: b["solution"].update(T=1e-300),      # an IndexError, also without the flag
    lambda b: b["solution"]["alpha"][0].__setitem__(0, 1e300),
])
def test_a_gait_that_cannot_be_evaluated_is_refused_even_as_an_open_orbit(gait, tmp_path,
                                                                          edit):
    """allow_open_orbit let it through with a warning, and every command then failed on
    an IndexError or OverflowError ('internal error')."""
    path = _resigned(gait.save(tmp_path / "g.json"), edit)
    for allow in (False, True):
        with pytest.raises(GaitFileError, match="its motion cannot be evaluated up to T"):
            Gait.load(path, allow_open_orbit=allow)


def test_open_orbit_can_be_loaded_with_a_warning(gait, tmp_path):
    path = _resigned(gait.save(tmp_path / "g.json"),
                     lambda b: b["solution"].update(T=b["solution"]["T"] * 1.01))
    with pytest.warns(OpenOrbitWarning, match=r"misses the start by 0\.00\d+ rad"):
        g = Gait.load(path, allow_open_orbit=True)
    assert g.orbit_residual()["worst"] > 1e-3
    assert gait.orbit_residual()["worst"] < ORBIT_TOL / 100          # the real one closes
    # the tolerance is stated and adjustable
    with pytest.warns(OpenOrbitWarning):
        Gait.load(gait.save(tmp_path / "g2.json"), orbit_tol=1e-20, allow_open_orbit=True)


def test_not_a_file(gait, tmp_path):
    with pytest.raises(GaitFileError, match="is a folder, not a file"):
        Gait.load(tmp_path)
    with pytest.raises(GaitFileError, match="not a regular file"):
        Gait.load("/dev/null")
    (tmp_path / "bin.json").write_bytes(bytes(range(256)))
    with pytest.raises(GaitFileError, match="not a text"):
        Gait.load(tmp_path / "bin.json")


def test_another_input_as_a_gait_file_says_what_to_do(gait, tmp_path):
    """A sampled step (the exported CSV, an NPZ, a JSON of nodes) or a robot description
    given as a gait file: 'not valid JSON (truncated or corrupted?)' or 'not a text
    file' before; now what it is and how it becomes a gait."""
    write_gait_csv(gait, tmp_path / "step.csv")
    np.savez(tmp_path / "step.npz", t=np.zeros(5), q=np.zeros((5, 5)), dq=np.zeros((5, 5)))
    (tmp_path / "step.json").write_text(json.dumps({"t": [0.0], "q": [[0.0] * 5],
                                                    "dq": [[0.0] * 5]}))
    for name in ("step.csv", "step.npz", "step.json"):
        with pytest.raises(GaitFileError, match=r"is a sampled step, not a gait file: make "
                                                r"a gait of it with gait_opt.import_gait"):
            Gait.load(tmp_path / name)
    toml = tmp_path / "robot.toml"
    toml.write_text((pathlib.Path(__file__).parent.parent / "biped_casadi" / "model" / "robots"
                     / "rabbit.toml").read_text())
    with pytest.raises(GaitFileError, match="is a robot description, not a gait file"):
        Gait.load(toml)
    (tmp_path / "missing.csv").unlink(missing_ok=True)
    with pytest.raises(GaitFileError, match="not found"):     # still the reader's own line
        Gait.load(tmp_path / "missing.csv")


def test_save_leaves_nothing_behind_on_failure(gait, tmp_path, monkeypatch):
    """Issue 12: `biped gait --out EXISTING_DIR` crashed after the solve and left a stray
    *.tmp file.  A failed save leaves no temporary file and no damaged earlier file."""
    (tmp_path / "adir").mkdir()
    with pytest.raises(IsADirectoryError):
        gait.save(tmp_path / "adir")
    path = gait.save(tmp_path / "g.json")
    before = path.read_bytes()

    def disk_full(self, text, *a, **k):            # half a file, then the disk is full
        with open(self, "w") as f:
            f.write(text[: len(text) // 2])
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(type(path), "write_text", disk_full)
    with pytest.raises(OSError, match="No space"):
        gait.save(path)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["adir", "g.json"]


# ------------------------------------------------------------- the cache
def test_cache_reuses_and_recomputes(model, gait, tmp_path, monkeypatch):
    calls = []

    def fake_solve(m, options, **kw):
        calls.append(options)
        return GaitSolveResult("Solve_Succeeded", "", 0, 0.0,
                               gait=Gait(m, options, gait.alpha, gait.x0, gait.T))

    import gait_opt.cache as cache
    import gait_opt.optimize as optimize
    monkeypatch.setattr(optimize, "_solve", fake_solve)
    g1 = optimize_gait(model, cache_dir=tmp_path, cache=True)
    assert len(calls) == 1 and g1.solver_stats["cache"].startswith("computed")
    files = list(tmp_path.glob("tasks/*/*.gait.json"))
    assert len(files) == 1
    g2 = optimize_gait(model, cache_dir=tmp_path, cache=True)
    assert len(calls) == 1 and g2.solver_stats["cache"] == "hit" and g2.T == gait.T
    # a corrupted cache file is recomputed, not trusted
    text = files[0].read_text()
    files[0].write_text(text.replace('"T": 0.69', '"T": 0.68', 1))
    g3 = optimize_gait(model, cache_dir=tmp_path, cache=True)
    assert len(calls) == 2 and "corrupted" in g3.solver_stats["cache"]
    assert Gait.load(files[0]).T == gait.T            # and the file is repaired
    # other options or another robot: another key
    monkeypatch.setenv("BIPED_CACHE_DIR", str(tmp_path))
    assert cache.cache_path(model, GaitOptions(speed=0.5)) != files[0]
    assert cache.cache_path(rabbit(RobotParams(m_torso=13.0))) != files[0]
    assert cache.cache_path(model) == files[0]


# ------------------------------------------------------------- failures
def test_unreachable_speed_fails_clearly(model):
    with pytest.raises(GaitOptimizationError, match=r"speed 5 m/s is out of reach") as e:
        optimize_gait(model, speed=5.0)
    assert e.value.status == "not_run" and e.value.violations[0][0] == "speed"


def test_infeasible_request_names_ipopt_status_and_families(model):
    # 2 N m cannot carry the robot; a short iteration budget keeps the test fast
    with pytest.raises(GaitOptimizationError) as e:
        optimize_gait(model, torque_limit=2.0, ipopt={"max_iter": 15})
    msg = str(e.value)
    assert "IPOPT status 'Maximum_Iterations_Exceeded'" in msg
    assert "torque limit (off by" in msg
    assert e.value.violations and all(v > 0 for _, v in e.value.violations)


def test_bad_options_are_value_errors(model):
    with pytest.raises(ValueError, match="'mu'"):
        optimize_gait(model, mu=-1.0)
    with pytest.raises(ValueError, match="'derivatives'"):
        GaitOptions(derivatives="numeric")
    with pytest.raises(ValueError, match="'n_intervals' must be at most"):
        optimize_gait(model, n_intervals=10**7)         # refused before any memory is used
    with pytest.raises(ValueError, match="'degree' must be at most 9"):
        GaitOptions(degree=10)
    with pytest.raises(ValueError, match="^gait option 'step_length_bounds' must be \\(low, high\\)"):
        GaitOptions(step_length_bounds=0.5)
    assert GaitOptions(step_time_bounds=[0.3, 1]).step_time_bounds == (0.3, 1.0)


def test_warm_start_and_save_name_what_is_wrong(model, gait):
    with pytest.raises(TypeError, match="^warm_start: a Gait is needed, got str$"):
        optimize_gait(model, warm_start="gait.json")
    with pytest.raises(TypeError, match="^path must be a file name"):
        gait.save(None)


#: a light shin under a heavy torso (round numbers): Newton's residual on the orbit
#: wanders at round-off between 1e-11 and 1e-9 instead of falling below 1e-10
LIGHT_SHIN = """name = "light_shin"
gravity = 9.81
[actuators]
torque_limit = 20.0
rotor_inertia = 0.0
gear_ratio = 1.0
[torso]
name = "torso"
mass = 5.6
length = 0.21
com = 0.105
inertia = 0.067
[[leg]]
name = "thigh"
mass = 0.88
length = 0.234
com = 0.054
inertia = 0.008
[[leg]]
name = "shin"
mass = 0.1
length = 0.303
com = 0.163
inertia = 0.00124
"""


def test_polish_wandering_at_round_off_keeps_its_best_orbit(tmp_path):
    """The polish used to refuse such a robot ('residual 5.4e-10 after 20 iterations');
    it keeps its best iterate when within ORBIT_TOL, and that is a fixed point of the
    restricted Poincare map for any M1 (SPEC section 2)."""
    from analysis.stability.poincare import poincare_map
    from biped_casadi import robot
    from gait_opt import polish

    path = tmp_path / "light_shin.toml"
    path.write_text(LIGHT_SHIN)
    hist = []
    real = polish.polish

    def recorded(*a, **k):
        out = real(*a, **k)
        hist.append(out[3])
        return out

    import gait_opt.optimize as optimize
    try:
        optimize.polish = recorded
        g = optimize_gait(robot(str(path)), speed=0.5)
    finally:
        optimize.polish = real
    h = hist[-1]
    assert h[-1] == min(h) and 1e-12 < h[-1] <= ORBIT_TOL     # kept the best, at round-off
    assert g.orbit_residual()["worst"] <= ORBIT_TOL
    pm = poincare_map(g)
    for M1 in (np.zeros(4), np.array([0.5, -0.3, 0.2, 0.1])):
        step = pm.evaluate(pm.x_star, M1)
        assert np.max(np.abs(step.x_next - pm.x_star)) <= 1e-8


# ------------------------------------------------ the optimiser's derivatives
@pytest.fixture(scope="module")
def small_problem(model):
    opts = GaitOptions(n_intervals=5)
    prob = build_problem(model, opts)
    rng = np.random.default_rng(7)
    w = initial_guess(model, opts) + 0.01 * rng.standard_normal(prob.lbx.size)
    lam = rng.standard_normal(prob.lbg.size)
    return prob, w, lam


def test_structured_derivatives_match_casadi_ad(small_problem):
    prob, w, lam = small_problem
    x, f, g = prob.nlp["x"], prob.nlp["f"], prob.nlp["g"]
    lf = 0.7
    ref = ca.Function("ref", [x], [ca.jacobian(g, x), ca.gradient(f, x),
                                   ca.triu(ca.hessian(lf * f + ca.dot(ca.DM(lam), g), x)[0])])
    J_ref, gf_ref, H_ref = (np.array(v.full()) for v in ref(w))
    _, J = prob.jac_g(w, [])
    _, gf = prob.grad_f(w, [])
    H = prob.hess_lag(w, [], lf, lam)
    assert np.max(np.abs(J.full() - J_ref)) <= 1e-10 * np.max(np.abs(J_ref))
    assert np.max(np.abs(gf.full() - gf_ref)) <= 1e-12 * max(1, np.max(np.abs(gf_ref)))
    assert np.max(np.abs(H.full() - H_ref)) <= 1e-10 * np.max(np.abs(H_ref))
    assert H.sparsity().is_triu()


def test_structured_derivatives_match_finite_differences(small_problem):
    prob, w, lam = small_problem
    rng = np.random.default_rng(3)
    d = rng.standard_normal(w.size)
    h = 1e-6
    lf = 0.7

    def g_of(x):
        return np.array(prob.jac_g(x, [])[0]).ravel()

    def grad_lag(x):
        _, J = prob.jac_g(x, [])
        _, gf = prob.grad_f(x, [])
        return lf * np.array(gf).ravel() + np.array(J.T @ lam).ravel()

    J = prob.jac_g(w, [])[1]
    fd = (g_of(w + h * d) - g_of(w - h * d)) / (2 * h)
    Jd = np.array(J @ d).ravel()
    assert np.max(np.abs(fd - Jd)) <= 1e-6 * np.max(np.abs(Jd))
    Hu = prob.hess_lag(w, [], lf, lam)
    Hfull = Hu + Hu.T - ca.diag(ca.diag(Hu))
    Hd = np.array(Hfull @ d).ravel()
    fd = (grad_lag(w + h * d) - grad_lag(w - h * d)) / (2 * h)
    assert np.max(np.abs(fd - Hd)) <= 1e-5 * np.max(np.abs(Hd))


# ------------------------------------------------------------- the CLI
def run(*args, cwd=None):
    return subprocess.run([sys.executable, "-m", "analysis.cli", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=300)


def test_cli_gait_json(tmp_path):
    out = tmp_path / "g.json"
    r = run("gait", "--json", "--out", str(out), "--plot", str(tmp_path / "plots"))
    assert r.returncode == 0, r.stderr
    s = json.loads(r.stdout)
    assert s["T"] == pytest.approx(0.6903909221, rel=1e-6)
    assert s["speed"] == pytest.approx(0.75)
    assert s["peak_torque"] <= 150 and s["min_normal_force"] >= 0
    assert s["max_friction_ratio"] <= 0.6 and s["dense_grid_violations"] == []
    assert max(s["periodicity_q"], s["periodicity_dq"]) <= 1e-8
    assert abs(s["swing_height_at_T"]) <= 1e-10 and s["reintegration_error"] <= 1e-8
    assert s["ipopt_iterations"] > 0 and s["solve_time"] > 0
    assert 0.0 < s["max_torso_lean"] < 1.5707963
    assert Gait.load(out).T == s["T"]
    for name in ("gait_stick.png", "gait_profiles.png"):
        png = tmp_path / "plots" / name
        assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 10_000


def test_cli_gait_errors(tmp_path):
    r = run("gait", "--speed", "5", "--out", str(tmp_path / "g.json"))
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert r.stderr.count("\n") == 1 and "speed 5 m/s is out of reach" in r.stderr
    r = run("gait", "--mu", "0")
    assert r.returncode == 2 and "--mu must be a positive number" in r.stderr
    r = run("gait", "--torque-limit", "2", "--max-iter", "5", "--out", str(tmp_path / "g.json"))
    assert r.returncode == 2 and "IPOPT status" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "g.json").exists()


def test_torso_lean_reported_and_tied_to_the_simulators_fall(model, gait):
    """`biped gait` reports the torso's largest lean: on the default gait (an independent
    sum of the stance leg's and the torso's relative angles) well inside the simulator's
    fall bound; at 1.2 m/s the optimum leans past it, and a walk from its own orbit is a
    fall, as the line says."""
    import math

    from analysis.gait_metrics import torso_fall
    from biped_casadi import SimulationOptions, VirtualConstraintController, simulate

    lean, past, bound = torso_fall(gait)
    t = np.linspace(0.0, gait.T, 201)
    q = np.atleast_2d(gait.q(t))
    q = q if q.shape[0] == 5 else q.T
    assert lean == pytest.approx(np.max(np.abs(q[0] + q[1] + q[2])), abs=1e-12)
    assert bound == pytest.approx(math.pi / 2) and not past and lean < 0.5
    fast = optimize_gait(model, GaitOptions(speed=1.2))
    lean12, past12, _ = torso_fall(fast)
    assert past12 and lean12 > bound
    run = simulate(VirtualConstraintController(fast), fast.q(0.0), fast.dq(0.0),
                   SimulationOptions(steps=1))
    assert str(run.status) == "fell"


def test_no_times_give_empty_arrays(gait):
    """An empty array of times gives (nq, 0) arrays (CasADi's 'Degenerate map
    operation' before), as N = 0 of the (nq, N) rule."""
    for f in (gait.q, gait.dq, gait.ddq):
        assert f(np.array([])).shape == (5, 0)
        assert f([]).shape == (5, 0)
    assert all(r.shape == (5, 0) for r in gait.evaluate(np.zeros(0)))
    assert gait.u(np.array([])).shape == (4, 0)


def test_optimize_gait_names_a_model_that_is_not_one():
    """A robot's name (or anything else) where the model goes: a TypeError that says
    what to pass, not "'str' object has no attribute 'description'"."""
    for wrong in ("rabbit", 3):
        with pytest.raises(TypeError, match=r"robot\("):
            optimize_gait(wrong)


def test_bounds_hit_names_a_step_length_bound_the_optimum_lies_beyond(model3, gait3, tmp_path,
                                                                       capsys):
    """The three-link gait's step length is inside the default bounds; with an upper bound
    below it the optimiser stops on that bound, and the gait (and ``biped gait``'s
    report of it) says so."""
    from analysis.cli.gait import _print_gait
    assert gait3.bounds_hit() == []
    L = gait3.step_length
    hi = round(0.9 * L, 3)
    g = optimize_gait(model3, gait3.options.replace(step_length_bounds=(0.1, hi)))
    assert g.step_length == pytest.approx(hi, rel=1e-6)
    assert g.bounds_hit() == [["step_length_bounds", "upper", hi]]
    s = g.summary()
    assert s["bounds_hit"] == g.bounds_hit()
    _print_gait(dict(s, max_torso_lean=0.0), g, model3, tmp_path / "g.json", 0.6, False, 1.0)
    line = next(x for x in capsys.readouterr().out.splitlines() if "step length" in x)
    assert f"on its upper bound {hi:g} m, GaitOptions.step_length_bounds" in line
def test_orbit_tools_name_bad_arguments(gait):
    """max_iter = 0 and n = 0 were IndexErrors; a path for the gait an AttributeError."""
    from gait_opt import close_orbit, fit_bezier_constraints, gait_family
    from gait_opt.urdf_angles import write_gait_csv
    with pytest.raises(TypeError, match="^gait: a Gait is needed"):
        close_orbit("gait.json")
    for bad in (0, -1, float("nan"), "1e-12"):
        with pytest.raises(ValueError, match="^tol must be a positive number"):
            close_orbit(gait, tol=bad)
    for bad in (0, 2.5):
        with pytest.raises(ValueError, match="^max_iter must be a positive integer"):
            close_orbit(gait, max_iter=bad)
    with pytest.raises(TypeError, match="^gait: a gait is needed"):
        fit_bezier_constraints("gait.json")
    for bad in (0, 10, 2.5):
        with pytest.raises(ValueError, match=r"^n \(samples of the fit\) must be an integer"):
            fit_bezier_constraints(gait, degree=10, n=bad)
    with pytest.raises(ValueError, match=r"^phase must have 5 components"):
        fit_bezier_constraints(gait, phase=[1.0, 0.5])
    assert fit_bezier_constraints(gait, degree=6, n=11).alpha.shape[1] == 7
    with pytest.raises(TypeError, match="^path must be a file name"):
        write_gait_csv(gait, None)
    with pytest.raises(TypeError, match="^model: a robot model is needed"):
        gait_family("rabbit", [0.7, 0.8])


def test_times_are_numbers_not_words(gait):
    """q('0.1') was parsed as 0.1; None is named as a missing time, not as NaN."""
    for bad in ("0.1", ["0.1", "0.2"], None):
        for f in (gait.q, gait.dq, gait.ddq, gait.states):
            with pytest.raises(ValueError, match="^gait: t must be a number or an array of numbers"):
                f(bad)
    np.testing.assert_array_equal(gait.q(np.float32(0.25)), gait.q(float(np.float32(0.25))))
    assert gait.q([0.1, 0.2]).shape == (5, 2)
