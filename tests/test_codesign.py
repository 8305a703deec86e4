"""The robust co-design NLP: its exact Jacobian against central differences, the walker
agreeing with the NLP's own rule, the command line's refusals, and (slow) a fixed-gait
co-design end to end against the issue's targets."""
from __future__ import annotations

import json

import numpy as np
import pytest

from analysis.cli import main
from analysis.design import RobustDesignSettings
from analysis.design.codesign import (CodesignError, CodesignSettings, IpoptLimits, Reduced,
                                      StartSampling, Transcription, TranscriptionSettings,
                                      TrustRegion, Verification)

#: a design of the good region (small M1) found by the co-design; any stable M1 would do
M1 = np.array([0.0385, 0.6158, 0.4359, -0.6560])


@pytest.fixture(scope="module")
def reduced(model, gait):
    """Two scenarios (the paper's direction and one sign pattern) of two steps each on the
    session's gait, the gait fixed."""
    dirs = np.array([np.ones(10), np.where(np.arange(10) % 3 == 0, -1.0, 1.0)])
    tr = Transcription(model, gait, dirs, steps=2, free_gait=False,
                       settings=TranscriptionSettings())
    red = Reduced(tr)
    red.tols[:] = 10.0
    red.steps[:] = 2
    return tr, red


def _design(tr, s=0.5):
    d = np.zeros(tr.n_design)
    d[tr.i_M1], d[tr.i_rejoin], d[tr.i_s] = M1, 0.75, s
    return d


def test_codesign_jacobian_matches_central_differences(reduced):
    """Every column but the rejoin (fixed per solve: v_c's jerk jumps at t_c) to 1e-6
    relative; the objective's gradient too."""
    tr, red = reduced
    d0 = _design(tr)
    f, grad, g, J, lo, hi = red.evaluate(d0)
    assert np.all(np.isfinite(g)) and J.shape == (g.size, tr.n_design)
    cols = [*tr.i_M1, int(tr.i_s)]
    for c in cols:
        h = 1e-6 * max(1.0, abs(d0[c]))
        dp, dm = d0.copy(), d0.copy()
        dp[c] += h
        dm[c] -= h
        fp, _, gp, *_ = red.evaluate(dp)
        fm, _, gm, *_ = red.evaluate(dm)
        fd = (gp - gm) / (2 * h)
        scale = np.max(np.abs(J[:, c])) + 1e-12
        assert np.max(np.abs(fd - J[:, c])) <= 1e-6 * max(scale, 1.0), (c, scale)
        assert abs((fp - fm) / (2 * h) - grad[c]) <= 1e-6 * max(abs(grad[c]), 1.0)


@pytest.fixture(scope="module")
def reduced_free(model):
    """The paper's direction and one sign pattern, two steps each, the gait free (its
    Bezier coefficients, T and unactuated start are variables), on the robust gait."""
    from analysis.design import ROBUST_GAIT
    from gait_opt import GaitOptions, optimize_gait
    g = optimize_gait(model, GaitOptions(**ROBUST_GAIT), cache=True)
    dirs = np.array([np.ones(10), np.where(np.arange(10) % 3 == 0, -1.0, 1.0)])
    tr = Transcription(model, g, dirs, steps=2, free_gait=True,
                       settings=TranscriptionSettings())
    red = Reduced(tr)
    red.tols[:] = 10.0
    red.steps[:] = 2
    return tr, red, g


def test_codesign_free_gait_columns_match_central_differences(reduced_free):
    """The condensed Jacobian's gait columns (Bezier coefficients, T, the unactuated
    start), through the strike times and the gait's own rows, against central
    differences of the walked scenarios: every column to 1e-5 relative."""
    tr, red, g = reduced_free
    d0 = np.zeros(tr.n_design)
    d0[tr.i_G] = tr.gait_vector(g)
    d0[tr.i_M1], d0[tr.i_rejoin], d0[tr.i_s] = M1, 0.75, 0.5
    f, grad, g0, J, lo, hi = red.evaluate(d0)
    assert np.all(np.isfinite(g0)) and J.shape == (g0.size, tr.n_design)
    # every Bezier coefficient of one joint, T, and both components of the start
    cols = [int(c) for c in tr.i_G[:tr.degree + 1]] + [int(c) for c in tr.i_G[tr.na:]]
    worst = 0.0
    for c in cols:
        h = 1e-6 * max(1.0, abs(d0[c]))
        dp, dm = d0.copy(), d0.copy()
        dp[c] += h
        dm[c] -= h
        gp = red.evaluate(dp)[2]
        gm = red.evaluate(dm)[2]
        fd = (gp - gm) / (2 * h)
        scale = max(np.max(np.abs(J[:, c])), 1.0)
        err = np.max(np.abs(fd - J[:, c])) / scale
        worst = max(worst, err)
        assert err <= 1e-5, (c, err)
    assert np.max(np.abs(J[:, cols])) > 1e-3            # the columns are not empty


@pytest.mark.parametrize("which", ["reduced", "reduced_free"])
def test_codesign_node_kernel_equals_the_scalar_node(which, request):
    """The nodes walked by the four-lane kernel (one call per step) equal the compiled
    scalar node's (CHUNK nodes per call) to rounding: states, sensitivities, diagnostics
    and their sensitivities, for three scenarios over a whole step."""
    from analysis.design.codesign.functions import NodeFunctions, _node_functions, compiled
    from biped_casadi.simd import available
    tr = request.getfixturevalue(which)[0]
    # the kernel where the machine has one (AVX2, FMA, gcc), else the scalar node
    assert (tr.node.kernel is not None) == available()
    assert (tr.node.scalar is None) == available()
    w = np.zeros(tr.n_design)
    if tr.free:
        w[tr.i_G] = tr.gait_vector(tr.gait)
    tab = tr.table(w)
    rng = np.random.default_rng(3)
    L = np.c_[tr.gait.x0 + 0.01 * rng.standard_normal((3, 2)),
              0.01 * rng.standard_normal((3, 2 * tr.nu))]
    args = (tab, L, int(tr.N * 1.2), M1, 0.75, tr.gait.T)
    if not available():                 # nothing to compare the scalar node with here
        pytest.skip("no four-lane kernel on this machine (AVX2, FMA, gcc)")
    fast = tr.nodes(*args)
    kernel = tr.node
    f = kernel.kernel.f
    try:
        tr.node = NodeFunctions(None, compiled(f))
        slow = tr.nodes(*args)
    finally:
        tr.node = kernel
    assert _node_functions(tr.model, tr.nG) is kernel
    for a, b in zip(fast, slow):
        assert a.shape == b.shape
        assert np.all(np.isfinite(a))
        assert np.max(np.abs(a - b)) <= 1e-11 * max(1.0, np.max(np.abs(b)))


def test_codesign_solve_records_what_walked_its_nodes(reduced):
    """A solve's record names what walked its nodes: the kernel rounds differently from
    the scalar node, so a process that could not build it gives another design (to about
    1e-11) and its solves say so."""
    from analysis.design.codesign.functions import NodeFunctions
    from analysis.design.codesign.problem import _record
    from analysis.design.codesign.reduced import NLPSolve
    from biped_casadi.simd import available
    tr = reduced[0]
    res = NLPSolve(d=np.zeros(tr.n_design), lam_g=np.zeros(0), status="Solve_Succeeded",
                   success=True, iterations=3, time=0.5, evaluations=4)
    assert _record(res, tr)["node"] == ("kernel" if available() else "scalar")
    kernel = tr.node
    try:
        tr.node = NodeFunctions(None, object())
        assert _record(res, tr) == dict(status="Solve_Succeeded", iterations=3,
                                        evaluations=4, time=0.5, node="scalar")
    finally:
        tr.node = kernel


def test_codesign_rule_is_the_walkers(model, gait, reduced):
    """Each step's end error and duration in the NLP (100 RK4 nodes per T) equal the
    walker's at 400 per T to 1e-6: the same closed loop, the same strike."""
    from biped_casadi.simulation import start_states, zero_dynamics_walker
    from biped_casadi.simulation.options import SimulationOptions
    tr, red = reduced
    red.evaluate(_design(tr))
    w = zero_dynamics_walker(gait, SimulationOptions(), 400, jit=False)
    q0, dq0 = start_states(gait, tr.dirs, 0.5)
    B = w.walk(q0, dq0, np.repeat(M1[None], len(q0), 0), 0.75, steps=2)
    assert len(red.info) == 4
    for i in red.info:
        k, j = i["k"], i["j"]
        assert abs(i["err"][0] - B.qu_error[k, j]) < 1e-6
        assert abs(i["err"][1] - B.dqu_error[k, j]) < 1e-6
        assert abs(i["te"] - B.duration[k, j]) < 1e-6


def test_codesign_path_rows_of_an_early_strike(reduced):
    """A step that strikes before 0.1 T (no node in the lift-off or mid-step windows)
    still gives the same rows as any step (the NLP's row count is fixed), finite, and
    its mid-step clearance row violated: the swing foot is at the ground."""
    from analysis.design.codesign.reduced import _Dense
    tr, red = reduced
    red.evaluate(_design(tr))
    c = red._constants(tr.table(_design(tr)))
    counts = {}
    for n in (0, 3, 60):
        p = n + 2
        diag = np.zeros((tr.nu + 5, p))
        diag[tr.nu + 1] = 300.0                       # normal force
        diag[tr.nu + 4] = tr.den_sign * tr.den_scale  # a denominator far from zero
        rows = _Dense(red.nd)
        red._path_rows(rows, diag, np.zeros((tr.nu + 5, red.nd, p)), n, "k0 j0", c)
        g = np.concatenate(rows.g)
        assert np.all(np.isfinite(g)) and np.all(np.isfinite(np.vstack(rows.J)))
        counts[n] = g.size
        mid = [v for v, name in zip(g, rows.names) if name.endswith("mid-step")]
        assert len(mid) == 1 and mid[0] > 0           # zsw = 0 < the clearance asked
    assert len(set(counts.values())) == 1, counts


def test_codesign_clearance_rows_scale_with_the_legs(model, gait, reduced):
    """The lift-off and mid-step clearance rows and the strike-front bound use the
    settings' lengths: with every length doubled (the doubled robot's defaults) and the
    swing foot twice as high, the clearance rows are the same to rounding, and the
    strike-front row's bound is twice RABBIT's."""
    import dataclasses
    from analysis.design.codesign.reduced import _Dense
    from biped_casadi import BipedModel
    tr, red = reduced
    doubled = BipedModel(model.description.scaled(length=2))
    lengths = ("strike_front_min", "clearance_mid", "lift_scale", "clearance_scale")
    big = TranscriptionSettings().for_model(doubled)
    st2 = dataclasses.replace(tr.st, **{n: getattr(big, n) for n in lengths})
    tr2 = Transcription(model, gait, tr.dirs, steps=2, free_gait=False, settings=st2)
    assert tr2.st == st2 and st2.lift_scale == 2 * tr.st.lift_scale
    red2 = Reduced(tr2)
    red2.tols[:], red2.steps[:] = red.tols, red.steps
    c = red._constants(tr.table(_design(tr)))
    n = 60
    tn = np.arange(n + 2) / tr.N
    diag = np.zeros((tr.nu + 5, n + 2))
    diag[tr.nu + 1] = 300.0
    diag[tr.nu + 4] = tr.den_sign * tr.den_scale
    diag[tr.nu + 3] = 0.004 * np.sin(np.pi * tn) - 0.0005     # touches 0 near the ends
    out = {}
    for r, z in ((red, 1.0), (red2, 2.0)):
        d = diag.copy()
        d[tr.nu + 3] *= z
        rows = _Dense(r.nd)
        r._path_rows(rows, d, np.zeros((tr.nu + 5, r.nd, n + 2)), n, "k0 j0", c)
        out[z] = {name: v for v, name in zip(np.concatenate(rows.g), rows.names)
                  if name.startswith("clearance")}
    assert set(out[1.0]) == set(out[2.0]) and len(out[1.0]) == 2
    for name, v in out[1.0].items():
        assert out[2.0][name] == pytest.approx(v, rel=1e-12, abs=1e-14), name
    # the strike-front bound (the strike rows of a walked design)
    lo = {}
    for r in (red, red2):
        r.evaluate(_design(r.tr))
        lo[r is red2] = {r._lo[i] for i, name in enumerate(r.names)
                         if name.startswith("strike_front")}
    assert lo[False] == {tr.st.strike_front_min}
    assert lo[True] == {2 * tr.st.strike_front_min}


@pytest.mark.parametrize("argv, msg", [
    (["m1", "--robust", "--method", "search", "--gait", "g.json"], "--gait with --robust"),
    (["m1", "--robust", "--scheduler", "tcp://127.0.0.1:1", "--workers", "2"], "--workers"),
    (["m1", "--method", "nlp"], "--method applies to --robust"),
    (["m1", "--samples", "0"], "--samples applies to --robust"),
    (["m1", "--starts", "0"], "--starts applies to --robust"),
    (["m1", "--seed", "0"], "--seed applies to --robust"),
    (["m1", "--robust", "--free"], "excludes --free"),
    (["m1", "--robust", "--samples", "5"], "--samples must be"),
    (["m1", "--robust", "--mu", "nan"], "--mu"),
])
def test_robust_cli_refuses_conflicts(argv, msg, capsys):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert msg in err and len(err.strip().splitlines()) == 1


def test_robust_cli_reports_ipopt_failure_in_one_line(monkeypatch, capsys, gait, tmp_path):
    """IPOPT failing on every start: one line naming the solver and what to try, exit 2."""
    import analysis.cli.m1 as m1cli

    def fail(*a, **k):
        raise CodesignError("codesign: IPOPT (Maximum_Iterations_Exceeded) found no verified "
                            "design from 5 start(s); try other starts, more samples")
    monkeypatch.setattr(m1cli, "codesign", fail)
    path = gait.save(tmp_path / "g.json")
    assert main(["m1", "--robust", "--gait", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert "IPOPT" in err and "try" in err and len(err.splitlines()) == 1


def test_robust_cli_verifies_at_the_gaits_friction(gait, monkeypatch, capsys, tmp_path):
    """`biped m1 --robust --gait FILE` verifies the designs at the friction coefficient the
    gait was optimised for unless --mu is given; a name without .json for --out is
    refused before any work."""
    import analysis.cli.m1 as m1cli
    from gait_opt import Gait
    own = Gait(gait.model, gait.options.replace(mu=0.9), gait.alpha, gait.x0, gait.T)
    g = str(own.save(tmp_path / "own.json"))
    seen = []

    def codesign(target, st, **kw):
        seen.append(st.verification.mu)
        raise CodesignError("stop here")

    monkeypatch.setattr(m1cli, "codesign", codesign)
    assert main(["m1", "--robust", "--gait", g]) == 2
    assert main(["m1", "--robust", "--gait", g, "--mu", "0.7"]) == 2
    assert seen == [0.9, 0.7] and "stop here" in capsys.readouterr().err
    assert main(["m1", "--robust", "--gait", g, "--out", str(tmp_path / "design")]) == 2
    assert "--out: the file name must end in .json" in capsys.readouterr().err
    assert seen == [0.9, 0.7]


@pytest.mark.parametrize("method", ["nlp", "search"])
def test_robust_cli_out_writes_the_design_gait(method, monkeypatch, capsys, tmp_path):
    """`biped m1 --robust --out FILE` (the co-design NLP or the sampling search): the
    design's gait is copied there from the cache folder, and the replay line reads it;
    an --out that cannot be written is refused before any work."""
    import types

    import analysis.cli.m1 as m1cli
    kept = tmp_path / "cache" / "codesign-abc.gait.json"
    kept.parent.mkdir()
    kept.write_text('{"a gait": 1}')
    design = types.SimpleNamespace(
        gait_file=str(kept), simulate_args=["--gait", str(kept), "--controller", "tv"],
        message="a design", cached=False, design=dict(M1=[0.0] * 4, rejoin=0.75),
        gait_options={}, verified={})
    calls = []
    monkeypatch.setattr(m1cli, "codesign" if method == "nlp" else "robust_design",
                        lambda *a, **k: calls.append(1) or design)
    monkeypatch.setattr(m1cli, "_print_design", lambda r, st: print(
        "replay: biped simulate " + " ".join(r.simulate_args)))
    out = tmp_path / "mine.json"
    assert main(["m1", "--robust", "--method", method, "--out", str(out)]) == 0
    assert out.read_text() == '{"a gait": 1}' and design.gait_file == str(out)
    assert f"--gait {out} --controller tv" in capsys.readouterr().out
    assert main(["m1", "--robust", "--method", method, "--out",
                 str(out / "x.json")]) == 2                 # under a file, not a folder
    assert "is a file, not a folder" in capsys.readouterr().err and calls == [1]


@pytest.mark.slow
def test_codesign_gait_fixed_meets_the_targets(tmp_path, capsys):
    """`biped m1 --robust --gait FILE` on the robust gait: the targets of a given gait,
    measured by the protocol (not by the NLP): s* >= 1, the paper's perturbation below
    1e-3 by step 5, max|lambda| at most the virtual constraints', the gait as given
    (the target is met without moving it), and the replay arguments walk."""
    from analysis.design import ROBUST_GAIT
    from biped_casadi import RABBIT, BipedModel
    from gait_opt import GaitOptions, optimize_gait
    g = optimize_gait(BipedModel(RABBIT), GaitOptions(**ROBUST_GAIT), cache=True)
    path = g.save(tmp_path / "robust.json")
    out = tmp_path / "design_gait.json"
    assert main(["m1", "--robust", "--gait", str(path), "--json", "--out", str(out)]) == 0
    r = json.loads(capsys.readouterr().out)
    assert r["gait_file"] == str(out) and out.read_bytes() == path.read_bytes()
    assert r["simulate_args"][r["simulate_args"].index("--gait") + 1] == str(out)
    assert r["status"] == "target_met", r["message"]
    assert r["s_star"] >= 1.0 and r["steps_to_converge"] <= 5
    assert r["max_abs"] <= r["vc_eigenvalue"]
    assert r["given_gait"] == "fixed" and not r["gait_free"]
    assert r["ipopt"]["iterations"] > 0
    assert main(["simulate", *r["simulate_args"], "--json"]) == 0
    run = json.loads(capsys.readouterr().out)
    assert run["status"] == "ok", run.get("message")
    errs = [max(abs(s["qu_error"]), abs(s["dqu_error"])) for s in run["steps"]]
    np.testing.assert_allclose(errs, r["paper_errors"], rtol=1e-6, atol=1e-9)
    assert max(errs[4:]) < 1e-3                       # below 1e-3 from step 5 on
    # hidden sign patterns: every valid one walks at scale 1 and ends below 1e-3
    hp = r["hidden"]
    assert hp["patterns"] > 0 and hp["by_scale"]["1.0"]["passed"] == hp["patterns"], hp
    assert hp["full_order"]["passed"] == hp["patterns"], hp




def test_robust_cli_prints_a_design_that_never_converges(capsys):
    """A design whose paper's perturbation never converges (it slips) is printed as such,
    not as "below 0.001 from step None"; a fixed gait prints no "moved from" line; an
    IPOPT status at its iteration cap says the design counts by the checks."""
    import types

    from analysis.cli.m1 import _print_design
    from analysis.design.codesign import FIT
    from analysis.design.verification import DesignCheck
    ns = types.SimpleNamespace
    r = ns(message="co-design (gait fixed)", cached=False,
           design=ns(M1=[3.39, -3.23], rejoin=0.75), gait_free=False, gait_file="g.json",
           gait_change=dict(T_start=0.48, T=0.48, max_alpha_change=0.0,
                            from_given=dict(speed=(0.75, 0.75), step_length=(0.36, 0.36),
                                            T=(0.48, 0.48), max_joint_change=0.0)),
           gait_move=None, s_star=0.066, directions_kept=16, vc_s_star=0.016, max_abs=0.12,
           vc_eigenvalue=0.86, steps_to_converge=None,
           check=DesignCheck(s_star=0.066, s_fail=0.07, failure="", verified={}, max_abs=0.12,
                             vc_eigenvalue=0.86, steps_to_converge=None, paper_errors=[],
                             paper_status="slipped", peak_torque=58.5),
           peak_torque=58.5, alternative=None, verified={}, hidden=None,
           active_constraints=[], elapsed=10.4, simulate_args=["--gait", "g.json"],
           ipopt=dict(solves=[1], iterations=30, evaluations=30,
                      status="Maximum_Iterations_Exceeded"))
    _print_design(r, FIT)
    out = capsys.readouterr().out
    assert "step None" not in out and "paper's perturbation: slipped" in out
    assert "moved from the given gait" not in out
    assert "the design counts by the checks above" in out
    # virtual constraints' s* is over the design's 10 steps, too few for their rate
    assert "(virtual constraints 0.016 over the same 10 steps)" in out
    assert "--controller vc instead of --m1 and --rejoin" in out


@pytest.mark.parametrize("make, message", [
    (lambda: CodesignSettings(rejoin=2.0), "^rejoin must be in"),
    (lambda: CodesignSettings(rejoin_choices=(0.5, 0.9)), "^rejoin_choices must be in"),
    (lambda: CodesignSettings(steps=0), r"^steps must be an integer >= 1"),
    (lambda: CodesignSettings(gait={"sped": 1.0}), "^gait: 'sped' is not a GaitOptions field"),
    (lambda: CodesignSettings(gait={"speed": -1.0}), "^gait option 'speed' must be"),
    (lambda: CodesignSettings(verification={"directions": 4}), "^verification must be a Verification"),
    (lambda: Verification(directions=0), r"^directions must be an integer >= 1"),
    (lambda: Verification(tol=float("nan")), "^tol must be finite"),
    (lambda: IpoptLimits(max_iter=0), r"^max_iter must be an integer >= 1"),
    (lambda: TrustRegion(alpha=-0.05), "^alpha must be positive"),
    (lambda: StartSampling(samples=0), r"^samples must be an integer >= 1"),
    (lambda: StartSampling(box=-1.0), "^box must be positive"),
    (lambda: StartSampling(refine_rounds=-1), r"^refine_rounds must be an integer >= 0"),
    (lambda: RobustDesignSettings(samples=0), r"^samples must be an integer >= 1"),
    (lambda: RobustDesignSettings(rejoin=0), "^rejoin must be positive"),
    (lambda: RobustDesignSettings(eigen_bound="x"), r"^eigen_bound \(a number, or 'vc'\) must be a number"),
    (lambda: RobustDesignSettings(seed=-1), r"^seed must be an integer >= 0"),
    (lambda: RobustDesignSettings(search_rk4_steps=4), r"^search_rk4_steps must be an integer >= 8")])
def test_design_settings_refuse_bad_values(make, message):
    """All of these were taken; steps = 0 ran a co-design of no steps, the others failed
    inside a task or not at all."""
    with pytest.raises(ValueError, match=message) as e:
        make()
    assert "\n" not in str(e.value)


def test_design_settings_defaults_unchanged():
    """The checks keep the defaults (the cache keys of cached designs are made of them)."""
    assert RobustDesignSettings(samples=np.int64(40000), box=12) == RobustDesignSettings()
    assert type(RobustDesignSettings(samples=np.int64(5)).samples) is int
    assert RobustDesignSettings(eigen_bound=0.9).eigen_bound == 0.9
    assert CodesignSettings(rejoin_choices=[0.5, 0.75]).rejoin_choices == (0.5, 0.75)


@pytest.mark.parametrize("fields, words", [
    ({"bogus": 1}, ["no field 'bogus'", "strike_front_min"]),
    ({"torque_limit": 40.0}, ["torque_limit is the verification's"]),
    ({"mu": 0.4}, ["mu is the verification's"]),
])
def test_transcription_fields_the_codesign_cannot_take_are_named(fields, words):
    """A ``transcription`` field TranscriptionSettings does not have, or one the
    verification sets (its friction and torque limit), is refused when the settings are
    made (it used to reach the co-design as a duplicate keyword); a known field passes."""
    from analysis.design.codesign.settings import CodesignSettings
    with pytest.raises(ValueError) as e:
        CodesignSettings(transcription=fields)
    assert all(w in str(e.value) for w in words), str(e.value)
    assert CodesignSettings(transcription={"strike_front_min": 0.01}).transcription == {
        "strike_front_min": 0.01}
