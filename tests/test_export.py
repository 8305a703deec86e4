"""The controllers exported as C: the interpolant the C law shares with the gait, the
compiled library against the Python law (states, return codes, a full-order run it
drives), the files (C99 without warnings, no allocation, the README's build line, the
example), ``biped export`` and its bad inputs, and (slow) the robust design."""
from __future__ import annotations

import hashlib
import json
import re
import subprocess
from fractions import Fraction

import numpy as np
import pytest

import analysis.verify_export as export_check
from analysis import singular_m1_values
from analysis.cli import main as biped_main
from analysis.verify_export import (SIMULATION_TOL, TORQUE_RTOL, compare_simulations,
                                    compare_states, time_example, verify_export)
from biped_casadi import (Perturbation, SimulationOptions, TimeVaryingController,
                          VirtualConstraintController, simulate)
from biped_casadi.control.compiled import CompiledController, build_library, find_c_compiler
from biped_casadi.control.export import GENERATED, HEADER, WRAPPER, c_sources, exported_law
from biped_casadi.control.export_folder import staged_export, write_export
from biped_casadi.numerics import quintic_hermite_interval

CC = find_c_compiler()
needs_cc = pytest.mark.skipif(CC is None, reason="no C compiler (gcc, cc or $CC) on this machine")
M1 = (-10.0, 7.5, 10.0, -5.0)
M1_3 = (0.3, 1.7)
PAPER = (0.01, 0.1)


def export_and_build(ctrl, folder):
    write_export(c_sources(exported_law(ctrl), {"gait file": "test"}), folder)
    return CompiledController(build_library(folder, folder.parent / f"{folder.name}.so"), ctrl)


@pytest.fixture(scope="module")
def tv(model, gait, tmp_path_factory):
    ctrl = TimeVaryingController(gait, M1, rejoin=0.5)
    if CC is None:
        return ctrl, None
    return ctrl, export_and_build(ctrl, tmp_path_factory.mktemp("tv") / "export")


@pytest.fixture(scope="module")
def vc(model, gait, tmp_path_factory):
    ctrl = VirtualConstraintController(gait)
    if CC is None:
        return ctrl, None
    return ctrl, export_and_build(ctrl, tmp_path_factory.mktemp("vc") / "export")


# ----------------------------------------------------------------- the interpolant
def test_hermite_interval_is_the_exact_quintic(rng):
    """The interpolant in floats equals the same formula in exact rational arithmetic to
    round-off (the derivative too: a numerically inverted 6 x 6 system lost ~1e-11 there),
    meets its six end conditions, and its derivative is the finite difference of its
    value."""
    for _ in range(50):
        h = float(rng.uniform(1e-4, 1e-3))
        a, w, phi = rng.uniform(0.1, 1), rng.uniform(1, 20), rng.uniform(0, 6)
        f = [lambda t: a * np.sin(w * t + phi), lambda t: a * w * np.cos(w * t + phi),
             lambda t: -a * w**2 * np.sin(w * t + phi)]        # smooth data, as a gait's
        ends = np.array([g(0.0) for g in f] + [g(h) for g in f])
        th = float(rng.uniform(0, 1))
        y, dy, ddy = quintic_hermite_interval(th, h, *ends)
        ex = quintic_hermite_interval(Fraction(th), Fraction(h), *map(Fraction, ends))
        assert abs(y - float(ex[0])) <= 1e-15 * max(1, abs(y))
        assert abs(dy - float(ex[1])) <= 1e-14 * max(1, abs(dy))
        assert abs(y - f[0](th * h)) < 1e-12         # the interpolation error itself
        for s, k in ((0, 0), (1, 3)):
            v = quintic_hermite_interval(Fraction(s), Fraction(h), *map(Fraction, ends))
            assert [float(x) for x in v] == pytest.approx(list(ends[k:k + 3]), rel=1e-12)
        d = 1e-6
        fd = (quintic_hermite_interval(th + d, h, *ends)[0]
              - quintic_hermite_interval(th - d, h, *ends)[0]) / (2 * d * h)
        assert fd == pytest.approx(dy, rel=1e-6, abs=1e-6)


def test_gait_state_is_the_interpolant_of_its_nodes(gait):
    """gait.state interpolates its nodes to round-off and its rate is the derivative of
    q_u^d."""
    t, y, dy, _ = gait.state_nodes()
    k = np.arange(1000, 1010)
    r = gait.states(t[k])
    assert np.max(np.abs(r[0] - y[k])) <= 1e-15 * np.abs(y).max()
    assert np.max(np.abs(r[1] - dy[k])) <= 1e-15 * np.abs(dy).max()
    tm = 0.37 * gait.T
    d = 1e-6
    fd = (gait.state(tm + d)[0] - gait.state(tm - d)[0]) / (2 * d)
    assert fd == pytest.approx(gait.state(tm)[1], rel=1e-8)


# ----------------------------------------------------------------- the compiled law
@needs_cc
@pytest.mark.parametrize("which", ["tv", "vc"])
def test_compiled_torques_equal_the_python_law(which, tv, vc):
    ctrl, lib = tv if which == "tv" else vc
    r = compare_states(lib, ctrl, n=2000, seed=1)
    assert r.success, r.message
    assert r.max_torque_rel <= TORQUE_RTOL and r.max_output_abs <= 1e-10
    assert r.max_den_rel <= 1e-12 and r.return_codes == {"0": 2000}


@needs_cc
def test_step_starts_both_laws_refuse_are_counted_not_evaluated(vc, monkeypatch):
    """Random step starts whose phase moves backwards (on a 0.1 m/s gait 14 of 1000 near
    the orbit's start) had the Python law called with its NaN step state: `biped export
    --verify` of that gait ended in "p must be finite" (exit 2).  Both laws refuse such a
    start; it is counted, not compared."""
    ctrl, lib = vc
    draw = export_check._random_states
    monkeypatch.setattr(export_check, "_random_states",
                        lambda c, n, rng: draw(c, n, rng, dq_err=2.0))
    r = compare_states(lib, ctrl, n=300, seed=1)
    assert r.success, r.message
    assert r.starts_refused > 0 and r.starts_disagree == 0
    assert sum(r.return_codes.values()) == 300 - r.starts_refused
    assert f"{r.starts_refused} step starts refused by both laws" in r.message


@needs_cc
def test_return_codes(tv, vc, model, gait):
    """tau outside the reference, a state where the denominator of eq. 24 is small, a
    non-finite state, the phase out of its range or moving backwards."""
    ctrl, lib = tv
    law = exported_law(ctrl)
    p = lib.step_start(gait.q(0.0), gait.dq(0.0)).p
    q, dq = gait.q(0.3), gait.dq(0.3)
    assert lib.torque(0.3, q, dq, p)[0] == 0
    for t in (-1e-3, gait.t_max + 1e-6):
        rc, u = lib.torque(t, q, dq, p)
        assert rc == 2 and np.all(np.isnan(u))
    assert lib.torque(gait.t_max, q, dq, p)[0] == 0
    assert lib.torque(0.3, np.r_[np.nan, q[1:]], dq, p)[0] == 3
    qbad, state = np.r_[np.inf, q[1:]], np.zeros(lib.n_par)
    assert lib._lib.biped_step_start(qbad.ctypes.data, dq.ctypes.data, state.ctypes.data) == 3
    with pytest.raises(ValueError, match="q must be finite"):
        lib.step_start(qbad, dq)
    # the law's own denominator decides 'singular': random configurations on both sides
    rng = np.random.default_rng(3)
    limit = law.singular_fraction * law.den_scale
    seen = set()
    for _ in range(400):
        qr = rng.uniform(-2.5, 2.5, model.nq)
        den = ctrl.torque(qr, dq, 0.3).denominator
        rc = lib.torque(0.3, qr, dq, p)[0]
        assert rc == (1 if den * law.den_sign <= limit else 0)
        seen.add(rc)
    assert seen == {0, 1}
    vctrl, vlib = vc
    pv = vlib.step_start(gait.q(0.0), gait.dq(0.0)).p
    lo, hi = vctrl.constraints.theta_range
    qo = gait.q(0.0) + np.r_[hi - lo, np.zeros(model.nq - 1)]
    assert vlib.torque(0.0, qo, gait.dq(0.0), pv)[0] == 2
    back = vlib.step_start(gait.q(0.0), -gait.dq(0.0))
    assert "cannot start" in back.problem and vctrl.step_start(gait.q(0.0), -gait.dq(0.0)).problem


@needs_cc
def test_simulation_driven_by_the_library(vc, tv, gait):
    """Virtual constraints (no reference state): the runs agree to round-off over 10 steps
    from the paper's perturbation.  Time-varying: the compiled run repeats the Python
    law's in the same numeric loop to round-off, and differs from biped simulate's by the
    discretisation of the reference state only (integrated with the robot there, read
    from the gait's interpolant by the C law), an O(h^4) difference: about 16 times
    smaller at half the RK4 step."""
    q0, dq0 = Perturbation.uniform(5, *PAPER).initial_state(gait)
    ctrl, lib = vc
    r = compare_simulations(lib, ctrl, q0, dq0, SimulationOptions(steps=10))
    assert r.status == "equal" and r.python_status == "ok" and r.steps == 10, r.message
    assert max(r.max_impact_time, r.max_state, r.twin_max_state) < 1e-11
    ctrl, lib = tv
    q0, dq0 = Perturbation.uniform(5, 0.001, 0.01).initial_state(gait)
    d = {}
    for n in (2000, 4000):
        r = compare_simulations(lib, ctrl, q0, dq0, SimulationOptions(steps=1, rk4_steps=n))
        assert r.success and r.compiled_status == r.python_status == "ok", r.message
        assert r.steps == 1 and r.twin_max_impact_time < 1e-12 and r.twin_max_state < 1e-11
        d[n] = r.max_state
    assert 10 < d[2000] / d[4000] < 25 and d[4000] <= SIMULATION_TOL


@needs_cc
def test_a_virtual_constraint_run_apart_from_biped_simulates_is_said_to_be_round_off(
        vc, gait, monkeypatch):
    """The virtual-constraint law reads no reference state: where its run differs from
    biped simulate's while the Python law's in the library's loop repeats the library's
    (on ODRI's Bolt by 2.8e-9 over 10 steps; here the limit is lowered below RABBIT's
    7.6e-13), the difference is round-off, not the reference state's integration."""
    import analysis.verify_export as ve
    monkeypatch.setattr(ve, "SIMULATION_TOL", 1e-15)
    q0, dq0 = Perturbation.uniform(5, *PAPER).initial_state(gait)
    ctrl, lib = vc
    r = compare_simulations(lib, ctrl, q0, dq0, SimulationOptions(steps=3))
    assert r.status == "discretisation" and r.twin_max_state == 0.0, r.message
    assert "round-off" in r.message and "reference state" not in r.message
    assert "reference state" in ve.apart_reason(4)


@needs_cc
def test_a_margin_dipping_between_two_nodes_stops_the_compiled_run_as_the_python_one(
        vc, gait, monkeypatch):
    """The closed loop driven by the library, with one more margin, (F_z - F*)^2 - d:
    F* the stance force 30 % of the way between two nodes in the middle of the nominal
    step, d a quarter of the square of that 30 %; above 0 at every node, below 0 between
    those two.  No derivatives through the library: the margins are sampled inside the
    flagged steps and the minimum located from their values.  The run stops as the
    Python law's (minimum located by its AD rate) does: status, message ("between two
    RK4 nodes"), time to 1e-8 of the RK4 step, the margin there to round-off.  With the
    margins at the nodes only (as before) it walks."""
    from biped_casadi.simulation import Simulator
    from biped_casadi.simulation.margins import MarginCheck
    ctrl, lib = vc
    q0, dq0 = gait.q(0.0), gait.dq(0.0)
    opts = SimulationOptions(steps=1)
    nominal = Simulator(ctrl, opts).run(q0, dq0)
    i = len(nominal.t) // 2
    F_star = 0.7 * nominal.Fz[i] + 0.3 * nominal.Fz[i + 1]
    depth = 0.25 * (0.3 * (nominal.Fz[i + 1] - nominal.Fz[i])) ** 2
    base = MarginCheck.values

    def values(self, u, Fx, Fz, lib=np):
        extra = (Fz - F_star) ** 2 - depth
        return lib.vertcat(base(self, u, Fx, Fz, lib), extra) if lib is not np else \
            np.vstack([base(self, u, Fx, Fz), np.atleast_1d(extra)[None, :]])

    monkeypatch.setattr(MarginCheck, "values", values)
    sims = [Simulator(c, opts) for c in (ctrl, lib)]
    for sim in sims:
        sim.margin.status.append("negative_normal_force")       # the extra margin's name
    py, cc = (sim.run(q0, dq0) for sim in sims)
    assert py.status == cc.status == "negative_normal_force", cc.message
    assert cc.message == py.message and cc.message.endswith(", between two RK4 nodes")
    assert nominal.t[i] < cc.failure_time < nominal.t[i + 1]
    assert abs(cc.failure_time - py.failure_time) <= 1e-8 * sims[1].h
    assert (cc.Fz[-1] - F_star) ** 2 - depth == pytest.approx((py.Fz[-1] - F_star) ** 2 - depth,
                                                              rel=1e-9)
    monkeypatch.setattr(MarginCheck, "first_dip", lambda *args: None)   # nodes only
    assert sims[1].run(q0, dq0).status == "ok"


def three_link_check(model3, gait3, folder, steps):
    q0, dq0 = Perturbation.uniform(3, *PAPER).initial_state(gait3)
    for ctrl in (TimeVaryingController(gait3, M1_3),
                 VirtualConstraintController(gait3)):
        lib = export_and_build(ctrl, folder / ctrl.name)
        assert (lib.nq, lib.nu) == (3, 2)
        s = compare_states(lib, ctrl, n=1000)
        assert s.success and s.max_torque_rel <= TORQUE_RTOL, s.message
        r = compare_simulations(lib, ctrl, q0, dq0, SimulationOptions(steps=steps))
        assert r.status == "equal" and r.python_status == "ok" and r.steps == steps, r.message


@needs_cc
def test_three_link_exports_and_verifies(model3, gait3, tmp_path):
    """Both controllers of the three-link biped (M1 = (0.3, 1.7)), 3 steps from the
    paper's perturbation (10 in the slow test)."""
    three_link_check(model3, gait3, tmp_path, 3)


@needs_cc
def test_verify_compares_impacts_when_the_perturbed_start_fails_in_its_first_step(
        gait3, tmp_path):
    """A torque limit the orbit keeps and a large perturbation does not (a heavy robot's
    case): the runs from the perturbed start end in their first step and compare no
    impact, so the verification compares the runs from the orbit's start too, and says
    so."""
    ctrl = VirtualConstraintController(gait3)
    q0, dq0 = Perturbation.uniform(3, 0.05, 0.5).initial_state(gait3)
    orbit = simulate(ctrl, *Perturbation.uniform(3, 0.0, 0.0).initial_state(gait3),
                     SimulationOptions(steps=2))
    hit = simulate(ctrl, q0, dq0, SimulationOptions(steps=2))
    assert orbit.status == "ok" and hit.peak_torque > 1.2 * orbit.peak_torque
    limit = (orbit.peak_torque + hit.peak_torque) / 2
    folder = tmp_path / "vc"
    write_export(c_sources(exported_law(ctrl), {"gait file": "test"}), folder)
    opts = SimulationOptions(steps=2, torque_limit=limit)
    v = verify_export(folder, ctrl, q0, dq0, opts, n_states=100, calls=1000)
    sim = v.simulation
    assert v.status == "verified", v.message
    assert sim.start == "orbit" and sim.steps == 2 and sim.compiled_status == "ok", sim.message
    assert "from the given start the runs ended before an impact (" in sim.message
    assert sim.max_state <= SIMULATION_TOL
    # a start that walks is compared from where it was given
    v = verify_export(folder, ctrl, *Perturbation.uniform(3, 0.001, 0.01).initial_state(gait3),
                      opts, n_states=100, calls=1000)
    assert v.simulation.start == "given" and v.simulation.steps == 2, v.message


@pytest.mark.slow
@needs_cc
def test_three_link_ten_steps(model3, gait3, tmp_path):
    three_link_check(model3, gait3, tmp_path, 10)


# ----------------------------------------------------------------- the files
@needs_cc
def test_files_are_plain_c99_and_the_readme_build_works(tv, gait, tmp_path):
    ctrl, _ = tv
    folder = tmp_path / "export"
    write_export(c_sources(exported_law(ctrl), {"gait file": "x"}), folder)
    assert sorted(p.name for p in folder.glob("*.c")) == sorted([WRAPPER, GENERATED])
    assert len(list(folder.glob("*.h"))) == 1
    header = (folder / HEADER).read_text()
    declared = re.findall(r"^int (\w+)\(", header, re.M)
    assert declared == ["biped_sizes", "biped_step_start", "biped_torque", "biped_outputs"]
    for f in (WRAPPER, GENERATED):
        src = (folder / f).read_text()
        assert not re.search(r"\b(malloc|calloc|realloc|free|printf|fopen)\s*\(", src)
        assert set(re.findall(r"#include\s*[<\"]([^>\"]+)", src)) <= {"math.h", "stddef.h",
                                                                     HEADER}
        extra = ["-Wextra"] if f == WRAPPER else []     # CasADi's code has unused arguments
        r = subprocess.run([*CC, "-std=c99", "-pedantic", "-Wall", *extra, "-Werror",
                            "-O2", "-c", str(folder / f), "-o", str(tmp_path / f"{f}.o")],
                           capture_output=True, text=True)
        assert r.returncode == 0, r.stderr[:2000]
    lib = tmp_path / "libbiped_controller.so"
    cmd = f"{' '.join(CC)} -O2 -shared -fPIC -o {lib} {folder}/*.c -lm"
    assert subprocess.run(cmd, shell=True).returncode == 0 and lib.is_file()
    us, line = time_example(folder, CC, calls=20000)
    assert 0 < us < 100 and "0 non-zero returns" in line


def test_staged_export_is_all_or_nothing(tmp_path):
    out = tmp_path / "out"
    with pytest.raises(RuntimeError):
        with staged_export({"a.c": "int a;\n"}, out):
            raise RuntimeError("interrupted")
    assert not out.exists() and list(tmp_path.iterdir()) == []
    with staged_export({"a.c": "int a;\n"}, out) as stage:
        stage.discard()
    assert not out.exists() and list(tmp_path.iterdir()) == []


# ----------------------------------------------------------------- command line
def run(capsys, *args):
    rc = biped_main([str(a) for a in args])
    out = capsys.readouterr()
    return rc, out


@needs_cc
def test_cli_export_verify(gait, tmp_path, capsys):
    g = gait.save(tmp_path / "gait.json")
    out = tmp_path / "vc"
    rc, o = run(capsys, "export", "--gait", g, "--controller", "vc", "--out", out, "--verify",
                "--states", 300, "--steps", 3, "--json")
    d = json.loads(o.out)
    assert rc == 0 and d["status"] == "verified", o.err
    v = d["verification"]
    assert v["states"]["max_torque_rel"] <= TORQUE_RTOL
    assert v["simulation"]["max_state"] <= SIMULATION_TOL and v["c_us"] > 0
    assert d["gait_sha256"] == hashlib.sha256(g.read_bytes()).hexdigest()
    assert (out / "gait.json").read_bytes() == g.read_bytes()
    header = (out / HEADER).read_text()
    assert d["gait_sha256"] in header and "RABBIT" in header and "eps = 0.02" in header
    assert "us per `biped_torque` call" in (out / "README.md").read_text()
    # again over the earlier export, a time-varying design this time: replaced
    rc, o = run(capsys, "export", "--gait", g, "--m1", *M1, "--rejoin", 0.75, "--gains",
                1, 2, 0.03, "--out", out)
    assert rc == 0, o.err
    header = (out / HEADER).read_text()
    assert "M1 = [-10.0, 7.5, 10.0, -5.0]" in header and "rejoin = 0.75 T" in header
    assert "eps = 0.03" in header and "virtual constraints" not in header
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gait.json", "vc"]


@needs_cc
def test_cli_verification_difference_writes_nothing(gait, tmp_path, capsys, monkeypatch):
    import analysis.verify_export as ve
    monkeypatch.setattr(ve, "TORQUE_RTOL", -1.0)      # every difference is too large
    g = gait.save(tmp_path / "gait.json")
    out = tmp_path / "out"
    rc, o = run(capsys, "export", "--gait", g, "--controller", "vc", "--out", out, "--verify",
                "--states", 20, "--steps", 1)
    assert rc == 1 and "nothing written" in o.out and not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["gait.json"]


@needs_cc
def test_cli_verification_that_compared_no_impact_is_not_verified(gait, tmp_path, capsys):
    """A torque limit the orbit does not keep (1 N m): the runs from the perturbation and
    from the orbit's start all end at once (torque_limit), no impact compared; --verify
    said 'verified', wrote the export and exited 0.  Now 'unverified', exit 1, nothing
    written."""
    g = gait.save(tmp_path / "gait.json")
    out = tmp_path / "out"
    args = ["export", "--gait", g, "--out", out, "--verify", "--states", 20, "--steps", 2,
            "--torque-limit", 1]
    rc, o = run(capsys, *args, "--json")
    d = json.loads(o.out)
    sim = d["verification"]["simulation"]
    assert (rc, d["status"], sim["status"], sim["steps"]) == (1, "unverified",
                                                             "nothing_compared", 0), o.out
    assert sim["start"] == "orbit" and sim["compiled_status"] == "torque_limit"
    rc, o = run(capsys, *args)
    assert rc == 1 and "no impact to compare, nothing verified" in o.out, o.out
    assert "wrote" not in o.out and not out.exists()


@needs_cc
def test_a_saturating_export_clips_its_torques_in_c(tv, gait, tmp_path, capsys):
    """``biped export --saturate`` (as ``export-running --saturate``): the C law clips
    its torques at the limit; compared with the Python law clipped the same way, it is
    equal, and unclipped it is not (the clip is active at these states)."""
    ctrl, plain = tv
    ref = ctrl.reference
    tau = np.linspace(0.0, ref.T, 9)
    p = ctrl.step_start(ref.q(0.0), ref.dq(0.0)).p
    peak = max(np.max(np.abs(plain.torque(float(t), ref.q(t), ref.dq(t), p)[1])) for t in tau)
    limit = 0.5 * float(peak)                   # below what the law asks on its own orbit
    law = exported_law(ctrl, saturate=True, torque_limit=limit)
    assert law.torque_limit == limit and exported_law(ctrl).torque_limit is None
    folder = tmp_path / "sat"
    write_export(c_sources(law, {"gait file": "test"}), folder)
    lib = CompiledController(build_library(folder, tmp_path / "sat.so"), ctrl)
    pc = lib.step_start(ref.q(0.0), ref.dq(0.0)).p
    u = np.array([lib.torque(float(t), ref.q(t), ref.dq(t), pc)[1] for t in tau])
    assert np.max(np.abs(u)) == limit and np.any(np.abs(u) < limit)
    assert compare_states(lib, ctrl, n=300, seed=2, torque_limit=limit).success
    assert not compare_states(lib, ctrl, n=300, seed=2).success
    assert f"torques clipped at +-{limit!r} N m" in (folder / HEADER).read_text()
    with pytest.raises(ValueError, match="saturate: the robot RABBIT has no torque limit"):
        exported_law(ctrl, saturate=True, torque_limit=float("inf"))
    g = gait.save(tmp_path / "gait.json")
    rc, o = run(capsys, "export", "--gait", g, "--m1", *M1, "--out", tmp_path / "cli",
                "--saturate", "--torque-limit", limit, "--verify", "--states", 300,
                "--steps", 2, "--json")
    d = json.loads(o.out)
    assert rc == 0 and d["status"] == "verified", o.err
    assert d["saturate"] is True and d["clipped_at"] == limit
    assert d["verification"]["states"]["max_torque_rel"] <= TORQUE_RTOL
    rc, o = run(capsys, "export", "--gait", g, "--m1", *M1, "--out", tmp_path / "cli",
                "--saturate", "--torque-limit", limit)
    assert rc == 0 and f"torques clipped at {limit:g} N m" in o.out, o.err


def _bad(capsys, tmp_path, *args, env=None, monkeypatch=None):
    before = sorted(p.name for p in tmp_path.iterdir())
    rc, o = run(capsys, "export", *args)
    assert rc == 2 and o.out == "" and len(o.err.strip().splitlines()) == 1, o.err
    assert sorted(p.name for p in tmp_path.iterdir()) == before
    return o.err


def test_cli_bad_inputs(gait, model, tmp_path, capsys, monkeypatch):
    g = gait.save(tmp_path / "gait.json")
    G = ["--gait", g]
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "todo.txt").write_text("mine\n")
    assert "--out" in _bad(capsys, tmp_path, *G, "--out", g / "sub")
    assert "cannot write" in _bad(capsys, tmp_path, *G, "--out", "/proc/biped-export")
    assert "other than an export" in _bad(capsys, tmp_path, *G, "--out", tmp_path / "notes")
    s = singular_m1_values(gait)
    err = _bad(capsys, tmp_path, *G, "--m1", s[0], 0, 0, 0, "--out", tmp_path / "o")
    assert "singular" in err and "eq. 24" in err
    monkeypatch.setenv("CC", str(tmp_path / "no-such-compiler"))
    err = _bad(capsys, tmp_path, *G, "--controller", "vc", "--out", tmp_path / "o", "--verify")
    assert "no C compiler" in err
    monkeypatch.delenv("CC")
    assert "--m1" in _bad(capsys, tmp_path, *G, "--controller", "vc", "--m1", 0, 0, 0, 0,
                          "--out", tmp_path / "o")
    assert "--gains" in _bad(capsys, tmp_path, *G, "--gains", 1, 2, 0.02, "--eps", 0.03,
                             "--out", tmp_path / "o")
    assert "--gains EPS" in _bad(capsys, tmp_path, *G, "--gains", 1, 2, 0, "--out",
                                 tmp_path / "o")
    assert "--m1" in _bad(capsys, tmp_path, *G, "--m1", 1, 2, "--out", tmp_path / "o")
    assert "--rejoin" in _bad(capsys, tmp_path, *G, "--rejoin", 0.9, "--out", tmp_path / "o")


def test_exported_law_refuses(model, gait):
    s = singular_m1_values(gait)
    with pytest.raises(ValueError, match="singular along its own gait"):
        exported_law(TimeVaryingController(gait, [s[0], 0, 0, 0]))
    with pytest.raises(ValueError, match="controller"):
        exported_law(object())


# ----------------------------------------------------------------- the robust design
@pytest.mark.slow
@needs_cc
def test_robust_design_exports_and_verifies(tmp_path, capsys):
    """`biped m1 --robust` (under a minute, then cached) replayed into `biped export
    --verify`: 10,000 states to 1e-12, the 10-step run from the paper's perturbation to
    1e-9, and at most 5 microseconds per call in C."""
    rc, o = run(capsys, "m1", "--robust", "--json")
    assert rc == 0, o.err
    args = json.loads(o.out)["simulate_args"]
    rc, o = run(capsys, "export", *args, "--out", tmp_path / "robust", "--verify", "--json")
    d = json.loads(o.out)
    assert rc == 0 and d["status"] == "verified", o.err
    v = d["verification"]
    assert v["states"]["n"] == 10_000 and v["states"]["max_torque_rel"] <= 1e-12
    assert v["simulation"]["steps"] == 10 and v["simulation"]["python_status"] == "ok"
    assert v["simulation"]["max_impact_time"] <= 1e-9 and v["simulation"]["max_state"] <= 1e-9
    assert v["c_us"] <= 5.0


def test_export_destination_must_be_a_folder_name(tmp_path):
    from biped_casadi.control.export_folder import check_destination
    for bad in (None, 5):
        with pytest.raises(TypeError, match="^out must be a file name"):
            check_destination(bad)
        with pytest.raises(TypeError, match="^out must be a file name"):
            write_export({"a.c": "int a;\n"}, bad)
    assert check_destination(str(tmp_path / "new")) == tmp_path / "new"


def test_c_sources_names_a_missing_law():
    with pytest.raises(TypeError, match=r"^law: an ExportedLaw is needed \(exported_law"):
        c_sources(None)
