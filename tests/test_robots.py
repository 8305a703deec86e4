"""Robots from description files: the schema and its errors, the built-in robots, the
physics of any description (energy, relabelling, momentum through the impact), and the
whole pipeline on the three-link biped of Grizzle, Abba & Plestan (2001): gait,
Poincaré map (AD against the finite-difference twin), a = b = 0, the M1 NLP, virtual
constraints, simulation and the command line."""
from __future__ import annotations

import dataclasses
import json

import casadi as ca
import numpy as np
import pytest
from robot_factory import random_description
from scipy_poincare import ScipyPoincare

from analysis import poincare_eigenvalues, poincare_map, vc_eigenvalue
from analysis.cli import main as biped_main
from analysis.design import (ab_solution_set, group_of, optimize_m1,
                                    swing_height_at_Td, taylor_ab, TaylorAB)
from biped_casadi import (RABBIT, BipedModel, SimulationOptions,
                          TimeVaryingController, VirtualConstraintController,
                          description_from_dict, load_description, rabbit, robot, simulate)
from biped_casadi.model.description import builtin_path
from gait_opt import Gait


# ------------------------------------------------------------ descriptions
def rabbit_dict():
    import tomllib
    return tomllib.loads(builtin_path("rabbit").read_text())


def test_builtin_rabbit_is_spec_section_1():
    """rabbit.toml holds SPEC §1's numbers (the builders' published values) and is the
    same robot as rabbit() and the legacy RobotParams default: the same D, H, impact."""
    d = robot("rabbit").description
    assert (d.torso.mass, d.torso.length, d.torso.inertia, d.torso.com) == (12.0, 0.625, 1.33, 0.24)
    femur, tibia = d.leg
    assert (femur.mass, femur.length, femur.inertia, femur.com) == (6.8, 0.4, 0.47, 0.11)
    assert (tibia.mass, tibia.length, tibia.inertia, tibia.com) == (3.2, 0.4, 0.20, 0.24)
    assert d.rotor_inertia == 3.32e-4 * 50.0**2 and d.gravity == 9.81
    assert d.torque_limit == 150.0 and d.total_mass == pytest.approx(32.0)
    assert d == RABBIT.to_description() == rabbit().description
    assert robot("rabbit") is rabbit() is rabbit(RABBIT)


def test_joint_names_are_distinct_when_a_link_is_named_like_a_joint():
    """The absolute angle is named after the lowest link; an imported robot whose lower
    link is called 'knee' (Cassie's URDF) would have had two 'stance knee' names."""
    assert robot("rabbit").joint_names[0] == "stance tibia (absolute)"
    d = rabbit_dict()
    d["leg"][1]["name"] = "knee"
    names = BipedModel(description_from_dict(d)).joint_names
    assert names[:2] == ("stance knee link (absolute)", "stance knee")
    assert len(set(names)) == len(names)


def test_builtin_three_link_is_grizzle_abba_plestan():
    """three_link.toml: legs r = 1 m with 5 kg at mid-leg, 15 kg at the hip, torso
    l = 0.5 m with 10 kg at its end (literature values of the 2001 paper)."""
    m = robot("three_link")
    d = m.description
    assert d.k == 1 and m.nq == 3 and m.nu == 2
    (leg,) = d.leg
    assert (leg.length, leg.mass, leg.com, leg.inertia) == (1.0, 5.0, 0.5, 0.0)
    assert (d.torso.length, d.torso.mass, d.torso.com, d.torso.inertia) == (0.5, 10.0, 0.5, 0.0)
    assert d.joint_masses == {"hip": 15.0} and d.gravity == 9.81
    assert d.total_mass == 35.0
    # upright: the hip at r, the torso's end at r + l, the centre of mass in between
    P = np.array(m.points(np.zeros(3)))
    np.testing.assert_allclose(P[:, m.hip_index], [0, 1.0], atol=1e-15)
    np.testing.assert_allclose(P[:, m.hip_index + 1], [0, 1.5], atol=1e-15)
    com = np.array(m.com(np.zeros(3))).ravel()
    np.testing.assert_allclose(com, [0, (2 * 5 * 0.5 + 15 * 1.0 + 10 * 1.5) / 35], atol=1e-15)


def test_description_file_round_trip(tmp_path):
    """A description written as TOML reads back to an equal description; the record in
    a gait file reads back too."""
    d = robot("three_link").description
    assert description_from_dict(d.to_dict()) == d
    f = tmp_path / "mine.toml"
    f.write_text(builtin_path("three_link").read_text().replace('"three_link"', '"mine"'))
    mine = robot(f)
    assert mine.description.name == "mine" and mine.description.torso == d.torso


def write_toml(tmp_path, data, name="bad.toml"):
    def value(v):
        return f'"{v}"' if isinstance(v, str) else repr(v)
    lines = []
    for k, v in data.items():
        if not isinstance(v, (dict, list)):
            lines.append(f"{k} = {value(v)}")
    for k, v in data.items():
        if isinstance(v, dict):
            lines += [f"[{k}]"] + [f"{a} = {value(b)}" for a, b in v.items()]
        elif isinstance(v, list):
            for item in v:
                lines += [f"[[{k}]]"] + [f"{a} = {value(b)}" for a, b in item.items()]
    p = tmp_path / name
    p.write_text("\n".join(lines).replace('leg = "EMPTY"', "leg = []") + "\n")
    return p


def broken(change):
    d = rabbit_dict()
    change(d)
    return d


BAD = [
    ("negative link mass", lambda d: d["leg"][0].update(mass=-1.0), "leg[1].mass must be positive"),
    ("zero length", lambda d: d["torso"].update(length=0.0), "torso.length must be positive"),
    ("negative inertia", lambda d: d["leg"][1].update(inertia=-0.1), "leg[2].inertia must be non-negative"),
    ("com not a number", lambda d: d["leg"][1].update(com="0.5"), "leg[2].com must be a number"),
    ("com_offset not finite", lambda d: d["torso"].update(com_offset=float("inf")),
     "torso.com_offset must be finite"),
    ("urdf map of another k", lambda d: d.update(urdf={"joints": []}), "urdf.joints has 0 entries"),
    ("missing field", lambda d: d["torso"].pop("inertia"), "torso.inertia is missing"),
    ("missing table", lambda d: d.pop("actuators"), "actuators is missing"),
    ("unknown key", lambda d: d["leg"][0].update(colour="red"), "leg[1].colour is not a known key"),
    ("unknown top-level key", lambda d: d.update(wheels=2), "wheels is not a known key"),
    ("no leg link (k = 0)", lambda d: d.update(leg=[]), "at least one link"),
    ("leg = [] (k = 0)", lambda d: d.update(leg="EMPTY"), "at least one link"),
    ("not a number", lambda d: d.update(gravity="9.81"), "gravity must be a number"),
    ("negative gravity", lambda d: d.update(gravity=-9.81), "gravity must be positive"),
    ("negative point mass", lambda d: d.update(point_masses={"hip": -2.0}), "point_masses.hip must be non-negative"),
    ("point mass at no joint", lambda d: d.update(point_masses={"elbow": 1.0}), "point_masses.elbow is not a known key"),
    ("zero torque limit", lambda d: d["actuators"].update(torque_limit=0), "actuators.torque_limit must be positive"),
    ("negative rotor", lambda d: d["actuators"].update(rotor_inertia=-1e-4), "actuators.rotor_inertia must be non-negative"),
    ("same link names", lambda d: d["leg"][1].update(name="femur"), "link names must differ"),
    # a leg 1e300 m long made D overflow to inf: `biped model` printed it with exit 0
    ("huge length", lambda d: d["leg"][0].update(length=1e300), "leg[1].length must be at most 1e+06"),
    ("huge com", lambda d: d["torso"].update(com=-1e300), "torso.com must be at most 1e+06"),
    ("huge mass", lambda d: d["torso"].update(mass=1e200), "torso.mass must be at most 1e+06"),
    ("huge point mass", lambda d: d.update(point_masses={"hip": 1e300}), "point_masses.hip must be at most"),
]


@pytest.mark.parametrize("what, change, message", BAD, ids=[b[0] for b in BAD])
def test_bad_descriptions_are_one_clear_value_error(tmp_path, what, change, message):
    path = write_toml(tmp_path, broken(change))
    with pytest.raises(ValueError) as e:
        load_description(path)
    text = str(e.value)
    assert message in text and str(path) in text and "\n" not in text
    with pytest.raises(ValueError, match=message.split(" ")[0].replace("[", r"\[").replace("]", r"\]")):
        robot(path)


def test_bad_robot_names_and_files(tmp_path):
    with pytest.raises(ValueError, match="neither a built-in robot"):
        robot("quadruped")
    with pytest.raises(ValueError, match="not found"):
        robot(tmp_path / "none.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("name = = 1")
    with pytest.raises(ValueError, match="cannot parse"):
        robot(bad)


def test_legacy_parameter_files_and_objects_still_load(tmp_path):
    """Flat RobotParams files (.toml/.json) and objects give the same model as before."""
    other = dataclasses.replace(RABBIT, m_torso=13.0)
    f = tmp_path / "old.json"
    f.write_text(json.dumps(other.to_dict()))
    assert robot(f).description == other.to_description() == rabbit(other).description
    assert float(robot(f).D(np.zeros(5))[0, 0]) != float(rabbit().D(np.zeros(5))[0, 0])


def test_gait_files_written_before_descriptions_still_load(gait, tmp_path):
    """A gait file whose robot record is the older flat parameter set (no torque limit,
    RABBIT's fields) loads onto RABBIT's model, and is refused by another robot."""
    from biped_casadi.caching import digest
    body = gait.to_dict()
    flat = RABBIT.to_dict()
    flat.pop("torque_limit")
    body["robot"] = flat
    body["sha256"] = digest(body)
    path = tmp_path / "old_gait.json"
    path.write_text(json.dumps(body))
    old = Gait.load(path)
    assert old.model is rabbit() and old.T == gait.T
    np.testing.assert_array_equal(old.q(0.3 * gait.T), gait.q(0.3 * gait.T))
    with pytest.raises(ValueError, match="other robot parameters"):
        Gait.load(path, model=robot("three_link"))


# ----------------------------------------------------------------- physics
MODELS = ["three_link", "random_k1", "random_k3", "rabbit_com_offsets"]


def make_model(name):
    if name == "rabbit_com_offsets":        # centres of mass off the links' lines
        d = robot("rabbit").description
        off = [0.04, -0.03]
        return BipedModel(dataclasses.replace(
            d, torso=dataclasses.replace(d.torso, com_offset=0.05),
            leg=tuple(dataclasses.replace(link, com_offset=o) for link, o in zip(d.leg, off))))
    if name.startswith("random_k"):
        k = int(name[-1])
        return BipedModel(random_description(np.random.default_rng(7 + k), k))
    return robot(name)


@pytest.mark.parametrize("name", MODELS)
def test_energy_conserved_passive(name):
    """u = 0 for 1 s, tight-tolerance integrator: K + V constant (point masses too)."""
    m = make_model(name)
    n = m.nq
    x = ca.SX.sym("x", 2 * n)
    ode = ca.vertcat(x[n:], m.forward_dynamics(x[:n], x[n:], ca.DM.zeros(m.nu)))
    F = ca.integrator("F", "cvodes", {"x": x, "ode": ode}, 0.0, np.linspace(0, 1, 11),
                      {"abstol": 1e-13, "reltol": 1e-13, "max_num_steps": 200000})
    rng = np.random.default_rng(1)
    x0 = np.r_[rng.uniform(-0.4, 0.4, n), rng.uniform(-1, 1, n)]
    X = np.array(F(x0=x0)["xf"])
    E0 = float(m.energy(x0[:n], x0[n:])[2])
    E = np.array([float(m.energy(X[:n, k], X[n:, k])[2]) for k in range(X.shape[1])])
    assert np.max(np.abs(X[:n, -1] - x0[:n])) > 0.1                # it really moved
    assert np.max(np.abs(E - E0)) / max(abs(E0), 1.0) <= 1e-9


@pytest.mark.parametrize("name", MODELS + ["rabbit"])
def test_relabelling_exchanges_the_legs(name):
    """E @ E = I, and E maps a configuration to the one with the legs' roles exchanged:
    in the new labels the old swing foot is the stance foot, at the same distance."""
    m = make_model(name)
    np.testing.assert_array_equal(m.E @ m.E, np.eye(m.nq))
    rng = np.random.default_rng(3)
    for _ in range(5):
        q = rng.uniform(-0.6, 0.6, m.nq)
        P, P2 = np.array(m.points(q)), np.array(m.points(m.E @ q))
        foot = P[:, -1]
        # the relabelled picture is the old one seen from the old swing foot: the old
        # stance foot is the new swing foot, hip and torso top stay where they were
        np.testing.assert_allclose(P2[:, -1], P[:, 0] - foot, atol=1e-12)     # old stance foot
        np.testing.assert_allclose(P2[:, m.hip_index], P[:, m.hip_index] - foot, atol=1e-12)
        np.testing.assert_allclose(P2[:, m.hip_index + 1], P[:, m.hip_index + 1] - foot,
                                   atol=1e-12)                                 # torso top
        # the new stance leg is the old swing leg, joint by joint, and vice versa
        st, sw = list(m.stance_chain), list(m.swing_chain)
        np.testing.assert_allclose(P2[:, st], P[:, sw[::-1]] - foot[:, None], atol=1e-12)
        np.testing.assert_allclose(P2[:, sw], P[:, st[::-1]] - foot[:, None], atol=1e-12)


@pytest.mark.parametrize("name", MODELS)
def test_impact_keeps_angular_momentum_about_the_strike(name):
    """Without rotors, the angular momentum about the impact point is the same before
    the impact and after it in the new labels (the new stance foot at the origin)."""
    base = make_model(name).description
    bare = BipedModel(dataclasses.replace(base, rotor_inertia=0.0))
    rng = np.random.default_rng(5)
    for _ in range(4):
        q = rng.uniform(-0.5, 0.5, bare.nq)
        dq = rng.normal(0, 1.0, bare.nq)
        xs, zs = (float(v) for v in bare.swing_foot(q))
        qp, dqp = (np.array(v).ravel() for v in bare.impact(q, dq))
        L_before = float(bare.angular_momentum(q, dq, [xs, zs]))
        L_after = float(bare.angular_momentum(qp, dqp, [0.0, 0.0]))
        assert abs(L_after - L_before) <= 1e-10 * max(1.0, abs(L_before))


# ------------------------------------------------- the three-link pipeline
def test_three_link_gait_is_consistent(gait3):
    """The default problem on the three-link biped: a cyclic gait as exact as RABBIT's."""
    s = gait3.summary()
    assert s["dense_grid_violations"] == []
    assert s["periodicity_q"] < 1e-10 and s["periodicity_dq"] < 1e-10
    assert abs(s["swing_height_at_T"]) < 1e-10
    assert s["unactuated_row_residual"] < 1e-10 and s["reintegration_error"] < 1e-10
    assert s["speed"] == pytest.approx(0.75, abs=1e-9)
    assert s["max_stance_knee"] is None and s["min_swing_knee"] is None     # no knees
    assert s["peak_torque"] <= gait3.model.description.torque_limit
    # no knees: the swing foot grazes the ground passing the stance leg, but is above
    # it beyond the scuff zone in front of the stance foot
    m = gait3.model
    t = np.linspace(0, gait3.T, 2001)[1:-1]
    x, z = np.array(m.swing_foot.map(t.size)(gait3.q(t))).reshape(2, -1)
    assert np.all(z[x > m.scuff_zone] > 0)


def test_three_link_gait_file_round_trip_and_other_robot(gait3, tmp_path):
    path = gait3.save(tmp_path / "g3.json")
    g = Gait.load(path)
    assert g.model is gait3.model and g.cache_key == gait3.cache_key
    with pytest.raises(ValueError, match="other robot parameters"):
        Gait.load(path, model=rabbit())


def test_three_link_poincare_ad_matches_finite_differences(model3, gait3):
    """A^z by AD through the discrete map against central differences of the SciPy
    twin (solve_ivp with events), and the variational path against the full AD."""
    pm = poincare_map(gait3)
    sp = ScipyPoincare(model3, gait3)
    for M1 in (np.zeros(2), np.array([0.3, 1.7]), np.array([-2.0, 3.0])):
        r = pm.analyse(M1, method="ad")
        A_fd = sp.jacobian(M1, h=1e-4)
        assert np.max(np.abs(r.A - A_fd)) <= 1e-6 * np.max(np.abs(A_fd)), (M1, r.A, A_fd)
        assert r.fixed_point_residual < 1e-9
        A_var = pm.analyse(M1).A
        assert np.max(np.abs(A_var - r.A)) <= 1e-6 * np.max(np.abs(r.A))


def test_three_link_ab_is_a_line(model3, gait3):
    """a = b = 0 for the three-link biped: the swing foot's height ignores the torso,
    so a and b depend on M1(1) + M1(2) only; on the line a = 0 both legs stay symmetric
    at the impact and Z_sw(q^d(T) + M_T dq_u) vanishes to every order."""
    tay = taylor_ab(gait3)
    ab = ab_solution_set(tay)
    assert ab.kind == "line" and len(ab.points) == 0
    P = ab.sample(7, -10, 10)
    np.testing.assert_allclose(tay.a(P), 0, atol=1e-12)
    np.testing.assert_allclose(tay.b(P), 0, atol=1e-12)
    for dq in (1e-1, 1e-2):
        assert np.max(np.abs(swing_height_at_Td(gait3, P, dq))) < 1e-12
    off = P[0] + np.array([0.5, 0.0])
    assert abs(swing_height_at_Td(gait3, off[None], 1e-2)[0]) > 1e-4
    assert group_of(tay, P[3]) == 1 and group_of(tay, off) is None


def test_ab_solution_set_finds_isolated_points():
    """On a synthetic Z_sw (gradient and Hessian given) the solutions are the real roots
    of b on the line a = 0: two, one, or none, each satisfying a = b = 0."""
    g = np.array([0.3, -0.7, 0.4])
    for H, expected in ((np.diag([1.0, -2.0, 0.5]), 2), (np.diag([1.0, 2.0, 0.5]), 0)):
        tay = TaylorAB(g, H, 0.0)
        s = ab_solution_set(tay)
        assert len(s.points) == expected and s.kind == ("points" if expected else "none")
        for p in s.points:
            assert abs(tay.a(p)[0]) < 1e-12 and abs(tay.b(p)[0]) < 1e-12
            assert group_of(tay, p) in (1, 2)


def test_three_link_m1_nlp_and_vc(model3, gait3):
    """The M1 NLP with both components free reaches max|lambda| far below the best point
    of the (M1(1), M1(2)) grid (verified by the full AD map), and the virtual-constraint
    eigenvalue equals delta_zero^2 of the orbit's impact."""
    r = optimize_m1(gait3, group=None, n_best=4, n_ipopt=2, n_random=0)
    check = poincare_eigenvalues(gait3, r.M1, method="ad")
    assert check.max_abs == pytest.approx(r.max_abs, rel=1e-9, abs=1e-12)
    pm = poincare_map(gait3)
    v = np.linspace(-10, 10, 41)
    grid = np.stack(np.meshgrid(v, v, indexing="ij"), -1).reshape(-1, 2)
    jb = pm.jacobian_batch(grid)
    st, mx = jb.status, jb.max_abs
    assert r.status == "stable" and r.max_abs <= np.min(mx[st == "stable"])
    line = optimize_m1(gait3, group=1, n_best=4, n_ipopt=2, n_random=0)
    assert line.group == 1 and abs(line.a) < 1e-9 and abs(line.b) < 1e-9
    vc = vc_eigenvalue(gait3)
    assert vc.status == "stable" and abs(vc.eigenvalue - vc.delta_zero_squared) < 1e-8
    assert vc.orbit_mismatch < 1e-8


def test_three_link_simulation(model3, gait3):
    """Unperturbed, both controllers repeat the reference; perturbed, the time-varying
    controller's section errors follow A^z step to step."""
    tv = TimeVaryingController(gait3, [0.3, 1.7])
    for ctrl in (tv, VirtualConstraintController(gait3)):
        res = simulate(ctrl, options=SimulationOptions(steps=2))
        assert res.status == "ok", res.message
        assert max(abs(s.duration - gait3.T) for s in res.steps) < 1e-8
        assert np.max(np.abs(res.qu_error)) < 1e-8
    A = poincare_eigenvalues(gait3, tv.M1).A
    q0, dq0 = gait3.q(0.0), gait3.dq(0.0)
    q0[0] += 1e-6
    res = simulate(tv, q0, dq0, SimulationOptions(steps=4))
    assert res.status == "ok"
    E = res.section_errors
    for k in range(len(E) - 1):
        pred = A @ E[k]
        assert np.linalg.norm(E[k + 1] - pred) <= 1e-3 * np.linalg.norm(pred) + 1e-10


# ------------------------------------------------------------ command line
def run(capsys, *args):
    rc = biped_main(list(args))
    return rc, capsys.readouterr()


def test_cli_three_link(gait3, tmp_path, capsys):
    g3 = str(gait3.save(tmp_path / "g3.json"))
    rc, out = run(capsys, "eig", "--gait", g3, "--m1", "0.3", "1.7", "--json")
    assert rc == 0, out.err
    body = json.loads(out.out)
    ref = poincare_eigenvalues(gait3, [0.3, 1.7])
    np.testing.assert_allclose(body["A"], ref.A, rtol=1e-12)
    rc, out = run(capsys, "eig", "--gait", g3, "--controller", "vc", "--json")
    assert rc == 0 and json.loads(out.out)["status"] == "stable"
    rc, out = run(capsys, "simulate", "--gait", g3, "--m1", "0.3", "1.7", "--steps", "2",
                  "--perturb-q", "0.001", "0", "0", "--json")
    assert rc == 0, out.err
    assert json.loads(out.out)["status"] == "ok"
    rc, out = run(capsys, "model", "--robot", "three_link", "--json")
    assert rc == 0 and np.array(json.loads(out.out)["D"]).shape == (3, 3)


@pytest.mark.parametrize("args, message", [
    (["eig", "--gait", "{g3}", "--m1", "1", "2", "3", "4"], "--m1 takes 2 numbers"),
    (["eig", "--gait", "{g3}", "--robot", "rabbit", "--m1", "0", "0"], "other robot"),
    (["model", "--robot", "quadruped"], "neither a built-in robot"),
    (["model", "--robot", "three_link", "--q", "0", "0"], "--q takes 3 numbers"),
    (["gait", "--robot", "{bad}"], "leg[1].mass must be positive"),
    (["m1", "--gait", "{g3}", "--group", "2"], "one line"),
])
def test_cli_robot_errors_are_one_line_exit_2(gait3, tmp_path, capsys, args, message):
    d = rabbit_dict()
    d["leg"][0]["mass"] = -1.0
    subs = dict(g3=str(gait3.save(tmp_path / "g3.json")), bad=str(write_toml(tmp_path, d)))
    rc, out = run(capsys, *[a.format(**subs) for a in args])
    lines = out.err.strip().splitlines()
    assert rc == 2 and out.out == "" and len(lines) == 1 and message in lines[0], out.err


@pytest.mark.slow
def test_robust_codesign_of_another_robot_without_a_gait_says_why(gait3, capsys):
    """``biped m1 --robust --robot three_link``: the starts drawn for RABBIT's default
    flow give none on this robot; the one line says so and names the form that works
    (``--gait``), not 'IPOPT (not run) found no verified design from 0 start(s)'."""
    from analysis.cli import main
    rc = main(["m1", "--robust", "--robot", "three_link", "--workers", "1"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2 and len(err) == 1, err
    assert "no start" in err[0] and "--gait" in err[0] and "not run" not in err[0], err[0]


def test_three_link_m1_nlp_free_with_the_commands_starts(gait3):
    """``biped m1 --free`` on the three-link gait (the default starts): a Newton run
    from one start went to M1 ~ 4e8, beyond the outputs' valid range, and the
    verification's range check ended the command with "M1: components must lie within
    +-1e+06" as if the user had given it; points beyond the range are not candidates."""
    from biped_casadi.control.output_law import M1_LIMIT
    r = optimize_m1(gait3, group=None)
    assert np.max(np.abs(r.M1)) <= M1_LIMIT and r.status == "stable"
