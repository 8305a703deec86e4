"""The co-design from any gait (issue 47): the starts that fit the gait, the gait moved to
the robust gait constraints, the command line's one-line failures, and every subcommand
on gaits the toolkit and an import produced (small settings: no traceback, a JSON
object or one line and exit 2)."""
from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import numpy as np
import pytest

from analysis.cli import main
from analysis.design import ROBUST_GAIT
from analysis.design.codesign import (FIT, IpoptLimits, MoveSettings,
                                      NoDesign, StartSampling, Verification, continue_gait,
                                      gait_change, move_gait)
from analysis.design.codesign.functions import TranscriptionSettings
from analysis.design.codesign.gait_move import GaitProjection, optimal_options, own_values
from analysis.design.codesign.starts import BINDS, binds, gait_scale, vc_like_m1
from biped_casadi import robot
from gait_opt import import_gait


@pytest.fixture(scope="module")
def moved(gait):
    """The session's gait moved to the robust gait constraints."""
    return move_gait(gait, dict(ROBUST_GAIT), MoveSettings(), TranscriptionSettings())


def test_move_reaches_the_robust_constraints_near_the_gait(gait, moved):
    """The moved gait is an exact orbit at the same speed, meets the robust gait
    constraints on the dense grid, and the move says how far it went."""
    g = moved.gait
    assert moved.status == "moved", moved.message
    assert g.violations() == []
    assert g.orbit_residual()["worst"] < 1e-9
    own = own_values(g)
    assert own["impact_mu"] <= ROBUST_GAIT["impact_mu"] + 1e-7
    assert own["clearance"] >= ROBUST_GAIT["clearance"] - 1e-7
    assert own_values(gait)["impact_mu"] > 0.3              # the default gait's is not
    ch = moved.change
    assert ch == gait_change(gait, g)
    assert abs(ch["speed"][1] - gait.speed) < 1e-9
    assert 0 < ch["max_joint_change"] < 0.5
    assert g.options.continuation == ROBUST_GAIT["continuation"]


def test_move_of_a_gait_without_torque_limit():
    """A robot without a torque limit (a URDF without <limit effort>): the move keeps the
    limit infinite (it was inf + f x (inf - inf) = nan, and every move was refused)."""
    walker = Path(__file__).resolve().parents[1] / "docs" / "howto" / "walker"
    g = import_gait(robot(walker / "walker.urdf"), walker / "walker_step.csv",
                    angles="urdf", stance="hip_left").gait
    assert g.options.torque_limit == np.inf
    mv = move_gait(g, dict(ROBUST_GAIT), MoveSettings(), TranscriptionSettings())
    assert mv.status == "moved", mv.message
    assert [r["torque_limit"] for r in mv.steps] == [np.inf] * len(mv.steps)
    assert mv.gait.options.torque_limit == np.inf and mv.gait.violations() == []
    assert own_values(mv.gait)["impact_mu"] <= ROBUST_GAIT["impact_mu"] + 1e-7


def test_an_effort_out_of_iterations_is_not_tried_again(gait):
    """The effort term's straight solve runs out of iterations: the move is the nearest
    gait (its continuation), without a second effort solve from there."""
    mv = move_gait(gait, dict(ROBUST_GAIT), MoveSettings(effort=300.0, max_iter=30),
                   TranscriptionSettings())
    efforts = [(r["effort"], r["nlp_status"]) for r in mv.steps]
    assert efforts[0] == (300.0, "Maximum_Iterations_Exceeded")
    assert efforts[1:] == [(0.0, "Solve_Succeeded")] and mv.status == "moved"


def test_continue_gait_changes_speed_by_cadence(moved):
    """A gait continued to a higher speed keeps its options (the robust gait constraints)
    and its step length at most the neighbour's; to a lower speed the step is free; the
    result is an exact orbit valid on the dense grid."""
    g0 = moved.gait
    up = continue_gait(g0, g0.speed + 0.05)
    assert abs(up.speed - (g0.speed + 0.05)) < 1e-9
    assert up.step_length <= g0.step_length + 1e-7
    assert up.T < g0.T                                       # faster by cadence
    assert up.options.replace(speed=g0.options.speed,
                              step_length_bounds=g0.options.step_length_bounds) == g0.options
    assert up.violations() == [] and up.orbit_residual()["worst"] < 1e-9
    assert up.solver_stats["continued_from"] == g0.cache_key
    down = continue_gait(g0, g0.speed - 0.05)
    assert abs(down.speed - (g0.speed - 0.05)) < 1e-9
    assert down.options.step_length_bounds == g0.options.step_length_bounds
    for bad in (0.0, -1.0, float("nan"), "fast", True):
        with pytest.raises(ValueError, match="speed"):
            continue_gait(g0, bad)


def test_own_orbit_says_why_the_gait_is_no_walk(gait):
    """Virtual constraints walk one step of the session's gait from its own orbit (''),
    and with a friction coefficient below its friction ratio the line says it slips."""
    from analysis.design.codesign.units import own_orbit
    from analysis.robustness.s_star import RobustnessSettings
    assert own_orbit(gait, RobustnessSettings()) == ""
    assert "slips" in own_orbit(gait, RobustnessSettings(mu=0.05))


def test_projection_gradient_matches_central_differences(gait):
    """The move's objective (distance and effort) and its constraint rows: exact
    derivatives against central differences in T and two Bezier coefficients."""
    opts = gait.options.replace(**ROBUST_GAIT)
    from gait_opt import Gait
    g = Gait(gait.model, opts, gait.alpha, gait.x0, gait.T)
    p = GaitProjection(g, np.r_[gait.alpha.ravel(order="F"), gait.T, gait.x0],
                       (0.05, 0.025, 0.25), effort=10.0)
    d0 = p.ref + 1e-3 * np.cos(np.arange(p.nd))
    f, grad, g0, J, lo, hi = p.evaluate(d0)
    for c in (0, 5, p.na):
        h = 1e-6
        dp, dm = d0.copy(), d0.copy()
        dp[c] += h
        dm[c] -= h
        fp, _, gp, *_ = p.evaluate(dp)
        fm, _, gm, *_ = p.evaluate(dm)
        assert abs((fp - fm) / (2 * h) - grad[c]) <= 1e-5 * max(1.0, abs(grad[c]))
        scale = max(np.max(np.abs(J[:, c])), 1.0)
        assert np.max(np.abs((gp - gm) / (2 * h) - J[:, c])) <= 1e-5 * scale


def test_optimal_gait_is_of_the_toolkits_degree(gait):
    """The infinite effort weight's gait: the given gait's options with the robust gait
    constraints, in the toolkit's Bezier degree whatever degree an import fitted."""
    from gait_opt import GaitOptions
    imported = dataclasses.make_dataclass("G", ["options"])(
        gait.options.replace(bezier_degree=12, clearance=0.03))
    opts = optimal_options(imported, dict(ROBUST_GAIT))
    assert opts.bezier_degree == GaitOptions().bezier_degree != 12
    assert opts.speed == gait.options.speed
    assert all(getattr(opts, k) == v for k, v in ROBUST_GAIT.items())
    assert optimal_options(gait, dict(ROBUST_GAIT)) == gait.options.replace(**ROBUST_GAIT)


def test_bezier_change_across_degrees():
    """The co-design's largest Bezier change between gaits of other degrees: the lower
    degree raised exactly (the same polynomials, so no change between them)."""
    from math import comb
    from analysis.design.codesign.method import _alpha_change, _elevated
    a = np.random.default_rng(0).normal(size=(4, 7))
    e = _elevated(a, 12)
    s = np.linspace(0.0, 1.0, 11)

    def bez(c):
        n = c.shape[1] - 1
        return sum(c[:, [i]] * comb(n, i) * s**i * (1 - s)**(n - i) for i in range(n + 1))
    assert e.shape == (4, 13)
    np.testing.assert_allclose(bez(e), bez(a), atol=1e-12)
    assert _alpha_change(a, e) < 1e-12 and _alpha_change(e, a) < 1e-12
    b = e.copy()
    b[2, 5] += 0.1
    assert abs(_alpha_change(a, b) - 0.1) < 1e-12


def test_starts_in_the_gaits_units(gait):
    """The sample box per component is the joint's range per radian of q_u; the virtual
    constraints' M1 is minus the slope of q_a^d against q_u^d."""
    c = gait_scale(gait)
    q, _, _ = gait.evaluate(np.linspace(0, gait.T, 201))
    np.testing.assert_allclose(c, np.maximum(np.ptp(q[1:], 1) / np.ptp(q[0]), 0.1))
    M = vc_like_m1(gait)
    assert M.shape == (2, gait.model.nu) and np.all(np.isfinite(M))
    # along the gait, v = q_a + M1 q_u changes less than q_a alone (first row: at 0.75 T)
    qs, dqs, _ = gait.evaluate(np.array([0.75 * gait.T]))
    assert np.allclose(dqs[1:, 0] + M[0] * dqs[0, 0], 0.0, atol=1e-9)


def test_binds_names_the_constraint():
    """A slip at an impact whose impulse left the cone is the impulse ratio; a slip in
    stance is friction."""
    run = dataclasses.make_dataclass("Run", ["status", "max_impulse_ratio"])
    assert binds(run("slipped", 0.61), 0.6) == BINDS["impulse"]
    assert binds(run("slipped", 0.3), 0.6) == BINDS["slipped"]
    assert binds(run("torque_limit", 0.3), 0.6) == BINDS["torque_limit"]
    assert binds(run("scuffed", 0.1), 0.6) == BINDS["scuffed"]


def test_no_design_is_one_json_object_and_one_line(monkeypatch, capsys, gait, tmp_path):
    """No design on the gait: with --json one object on stdout saying why, one line on
    stderr naming what binds, exit 2 (never an empty output)."""
    import analysis.cli.m1 as m1cli

    def none(*a, **k):
        raise NoDesign("no design on the gait as given: the start screen's best scale is "
                       "s* 0.312, stopped by the impact impulse ratio",
                       dict(vc_s_star=0.27))
    monkeypatch.setattr(m1cli, "codesign", none)
    path = gait.save(tmp_path / "g.json")
    assert main(["m1", "--robust", "--gait", str(path), "--json"]) == 2
    cap = capsys.readouterr()
    body = json.loads(cap.out)
    assert body["status"] == "no_design" and body["success"] is False
    assert "impulse ratio" in body["message"] and body["vc_s_star"] == 0.27
    lines = cap.err.strip().splitlines()
    assert len(lines) == 1 and "impulse ratio" in lines[0]


def test_a_failed_task_is_one_line(monkeypatch, capsys, gait, tmp_path):
    """A task failing anywhere (here the gait of `biped eig`) reaches the user as one
    line and exit 2, its own message without the engine's wrapping; an internal error
    says so."""
    import analysis.cli.eig as eigcli
    from analysis.tasks import TaskError
    path = str(gait.save(tmp_path / "g.json"))

    def failing(message):
        def f(*a, **k):
            raise TaskError("analysis.x.some_task", message, "Traceback ...")
        return f
    for message, expect in (("GaitOptimizationError: no feasible gait: IPOPT status "
                             "'Infeasible_Problem_Detected'", "no feasible gait"),
                            ("KeyError: 'x'", "internal error"),
                            # the engine's own line (a worker refusing the task): no bug
                            ("stale worker (tcp://h:1, pid 7): analysis/x.py differs",
                             "error: stale worker (tcp://h:1, pid 7): analysis/x.py differs\n")):
        monkeypatch.setattr(eigcli, "load_gait", failing(message))
        assert main(["eig", "--gait", path, "--m1", "0", "0", "0", "0"]) == 2
        err = capsys.readouterr().err
        assert len(err.strip().splitlines()) == 1 and expect in err
        assert "Traceback" not in err and "TaskError" not in err


# ------------------------------------------------------------ every subcommand
#: the co-design of `biped m1 --robust --gait` made small for the test (its logic, not
#: its figures)
SMALL = dataclasses.replace(
    FIT, starts=StartSampling(samples=300, kept=1, fit_gait=True, screened=6,
                              screen_rounds=3, deadbeat=False),
    verification=Verification(directions=3, walk_steps=4, hidden=False),
    screen=IpoptLimits(3, 4), gait_rounds=0, paper_steps=0,
    move=MoveSettings(max_iter=40, efforts=(0.0,)))


@pytest.fixture(scope="module")
def gait_files(gait, foreign, tmp_path_factory):
    """A gait of the toolkit and one imported from another tool's nodes."""
    d = tmp_path_factory.mktemp("gaits")
    csv = d / "foreign.csv"
    t, phi, dphi = foreign.t, foreign.q, foreign.dq
    np.savetxt(csv, np.c_[t, phi.T, dphi.T], delimiter=",", comments="",
               header="t," + ",".join(f"q{i + 1}" for i in range(5)) + ","
               + ",".join(f"dq{i + 1}" for i in range(5)))
    imported = d / "imported.json"
    assert main(["gait", "--import", str(csv), "--angles", "absolute", "--out",
                 str(imported)]) == 0
    return dict(toolkit=str(gait.save(d / "toolkit.json")), imported=str(imported))


@pytest.fixture(scope="module")
def foreign(model, gait):
    from foreign_gait import hermite_simpson_gait
    from gait_opt.nodes import Nodes
    t, phi, dphi = hermite_simpson_gait(model, gait, n_intervals=8, speed=0.6)
    return Nodes(t, phi, dphi, source="Hermite-Simpson, 8 intervals, absolute angles")


COMMANDS = [
    ["eig", "--gait", "{g}", "--m1", "0", "0", "0", "0", "--json"],
    ["eig", "--gait", "{g}", "--controller", "vc", "--json"],
    ["robust", "--gait", "{g}", "--controller", "vc", "--directions", "2", "--json"],
    ["simulate", "--gait", "{g}", "--controller", "tv", "--m1", "0.1", "0.5", "0.4", "-0.6",
     "--steps", "2", "--json"],
    ["simulate", "--gait", "{g}", "--controller", "vc", "--steps", "2", "--json"],
    ["sweep", "--gait", "{g}", "--grid", "2", "--out", "{tmp}/sweep", "--no-progress"],
    ["terrain", "--gait", "{g}", "--controller", "vc", "--runs", "2", "--max-steps", "3",
     "--sigma", "0.002", "--json"],
    ["export", "--gait", "{g}", "--controller", "vc", "--out", "{tmp}/export"],
    ["mujoco", "--gait", "{g}", "--controller", "vc", "--steps", "2", "--json"],
    ["m1", "--robust", "--gait", "{g}", "--json"],
    ["m1", "--robust", "--gait", "{g}", "--fixed-gait", "--json"],
    ["m1", "--robust", "--gait", "{g}", "--free-gait"],
]


@pytest.mark.parametrize("which", ["toolkit", "imported"])
def test_every_command_on_any_gait_ends_cleanly(which, gait_files, tmp_path, monkeypatch,
                                                capsys):
    """Every subcommand that takes a gait, on a gait of the toolkit and on an imported
    one: exit 0 with one JSON object (with --json), or exit 2 with one line on stderr;
    never a traceback."""
    import analysis.cli.m1 as m1cli
    monkeypatch.setattr(m1cli, "FIT", SMALL)
    for args in COMMANDS:
        argv = [a.format(g=gait_files[which], tmp=tmp_path) for a in args]
        rc = main(argv)
        cap = capsys.readouterr()
        assert "Traceback" not in cap.err, (argv, cap.err)
        assert rc in (0, 2), (argv, rc, cap.err)
        if rc == 2:
            lines = cap.err.strip().splitlines()
            assert len(lines) == 1 and lines[0].startswith("biped"), (argv, cap.err)
        if "--json" in argv and (rc == 0 or argv[:2] == ["m1", "--robust"]):
            assert cap.out.strip(), (argv, rc, cap.err)  # never empty
            body = json.loads(cap.out)                 # one object
            assert isinstance(body, dict), argv


def test_replay_names_the_gait_the_design_runs_on(gait, gait3, tmp_path):
    """With a given gait the co-design moved (gait free), the replay arguments and
    ``gait_file`` name the moved gait, saved beside the cache, not the given file (whose
    gait the design's M1 was not made for); a design on the gait as given keeps it."""
    from types import SimpleNamespace

    from analysis.design.codesign.api import _with_gait_file
    from gait_opt import Gait

    given = tmp_path / "given.json"
    gait.save(given)

    def result(on):
        return SimpleNamespace(design=SimpleNamespace(M1=[0.5, -0.5], rejoin=0.75, gait=on),
                               gait=on, settings={"verification": dict(
                                   mu=0.6, walk_steps=10, torque_limit=None)})

    moved = _with_gait_file(result(gait3), gait, given, tmp_path / "cache", "k" * 40)
    assert moved.gait_file != str(given)
    assert Gait.load(moved.gait_file).cache_key == gait3.cache_key
    assert moved.simulate_args[:2] == ["--gait", moved.gait_file]
    kept = _with_gait_file(result(gait), gait, given, tmp_path / "cache", "j" * 40)
    assert kept.gait_file == str(given) and kept.simulate_args[:2] == ["--gait", str(given)]


def test_no_design_either_way_says_which_gait_each_reason_is_for(monkeypatch):
    """'auto' with no design on the gait as given nor on the gait moved from it: the one
    line says which reason is which (they read alike, with different figures)."""
    from types import SimpleNamespace

    from analysis.design.codesign import api

    calls = []

    def designed(method, settings):
        calls.append(method)
        raise NoDesign(f"codesign: no walk (torso {len(calls)} rad)", {})

    monkeypatch.setattr(api, "Method", lambda *a, **k: len(calls))
    monkeypatch.setattr(api, "_designed", designed)
    with pytest.raises(NoDesign) as e:
        api._auto(SimpleNamespace(say=lambda *a: None), None, None, object())
    msg = str(e.value)
    assert msg.startswith("codesign: on the gait as given: no walk (torso 3 rad); "), msg
    assert msg.endswith("on the gait moved from it: no walk (torso 2 rad)"), msg
    assert msg.count("codesign:") == 1 and "\n" not in msg
