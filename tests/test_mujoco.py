"""RABBIT in MuJoCo (issue 45): the generated MJCF against the toolkit's model, the closed
loop of the exported C law against the same law in Python, the stride-map fit, bad input.
The walking figures of the issue are measured by benchmarks/bench_mujoco.py (the
robust design needs the co-design); virtual constraints' are checked here too."""
from __future__ import annotations

import dataclasses
import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest

from analysis.cli import main as biped_main
from biped_casadi import Design, Perturbation, robot
from biped_casadi.model.biped import builtin_path
from biped_casadi.mujoco import (MIN_INERTIA, MUJOCO_DEFAULT, STIFF, ContactSettings,
                                 MujocoLoop, fit_stride_map, floating_base_inertia, layout,
                                 mjcf, mujoco_module, walk)
from biped_casadi.mujoco.walk import start_of

mujoco = pytest.importorskip("mujoco")

#: a time-varying design that walks on the default gait (the M1 NLP's deadbeat point of
#: group 1, rounded): an input of the tests, not an expected value
DEADBEAT = [2.223419, -4.220774, 2.943679, 1.582508]


def _mass_matrix(m, d, qpos):
    d.qpos[:] = qpos
    mujoco.mj_forward(m, d)
    M = np.zeros((m.nv, m.nv))
    mujoco.mj_fullM(m, d, M)
    return M


WALKER = Path(__file__).resolve().parents[1] / "docs" / "howto" / "walker" / "walker.urdf"


@pytest.mark.parametrize("name", ["rabbit", "three_link", "rabbit.urdf", "walker.urdf"])
def test_mjcf_mass_matrix_is_the_toolkits(name, rng):
    """MuJoCo's floating-base inertia matrix of the generated MJCF equals J' De J, the
    impact map's extended-coordinate D in MuJoCo's coordinates, at random poses; the
    mass, the motors and the armature are the description's (the walker's URDF has no
    torque limit: the motors get one)."""
    src = {"rabbit.urdf": str(builtin_path("rabbit").with_suffix(".urdf")),
           "walker.urdf": str(WALKER)}.get(name, name)
    model = robot(src)
    limit = 40.0 if name == "walker.urdf" else None
    m = mujoco.MjModel.from_xml_string(mjcf(model, torque_limit=limit))
    d = mujoco.MjData(m)
    desc = model.description
    worst = 0.0
    for _ in range(20):
        qpos = rng.uniform(-1.2, 1.2, m.nq)
        qpos[:2] = rng.uniform(-2, 2, 2)
        M = _mass_matrix(m, d, qpos)
        T = floating_base_inertia(model, qpos)
        worst = max(worst, np.abs(M - T).max())
    # a link of zero inertia carries MIN_INERTIA in MuJoCo: a few 1e-14 at most
    assert worst < 1e-12, worst
    assert np.isclose(m.body_mass.sum(), desc.total_mass, rtol=0, atol=1e-12)
    U = limit or desc.torque_limit
    assert m.nu == model.nu and np.all(m.actuator_ctrlrange == [-U, U])
    assert np.allclose(m.dof_armature[3:], desc.rotor_inertia) and np.all(m.dof_armature[:3] == 0)


def test_mjcf_com_offset(rng):
    """Off-axis centres of mass (Link.com_offset) are the toolkit's: MuJoCo's mass matrix
    still equals the toolkit's."""
    desc = robot("rabbit").description
    leg = (dataclasses.replace(desc.leg[0], com_offset=0.02),
           dataclasses.replace(desc.leg[1], com_offset=-0.01))
    desc = dataclasses.replace(desc, leg=leg,
                               torso=dataclasses.replace(desc.torso, com_offset=0.03))
    m = mujoco.MjModel.from_xml_string(mjcf(desc))
    d = mujoco.MjData(m)
    qpos = rng.uniform(-1, 1, m.nq)
    assert np.abs(_mass_matrix(m, d, qpos) - floating_base_inertia(desc, qpos)).max() < 1e-12


def test_layout_maps_states_and_torques(model, rng):
    """The coordinate map: toolkit -> MuJoCo -> toolkit is the identity for either stance
    leg, the stance foot lands where it was put, and the torques do the same work."""
    lay = layout(model)
    for stance in (0, 1):
        q, dq, u = rng.normal(0, 0.5, 5), rng.normal(0, 1, 5), rng.normal(0, 50, 4)
        qpos, qvel = lay.from_toolkit(q, dq, stance, foot=(0.3, 0.005))
        q2, dq2 = lay.to_toolkit(qpos, qvel, stance)
        assert np.allclose(q2, q, atol=1e-14) and np.allclose(dq2, dq, atol=1e-14)
        assert np.allclose(lay.feet(qpos)[stance], [0.3, 0.005], atol=1e-14)
        ctrl = lay.G[stance] @ u
        assert math.isclose(float(ctrl @ qvel[3:]), float(u @ dq[1:]), rel_tol=1e-12)
    assert MIN_INERTIA < 1e-13


def test_c_law_in_the_loop_equals_the_python_law(gait):
    """The exported C law and the Python law driven by the same MuJoCo loop: the same
    touchdowns; the same torques at the same states to 1e-12 (relative to the peak).

    Virtual constraints: the two runs are bitwise equal.  Time-varying: the C law reads
    the reference state from its table, the Python law from the gait (round-off apart,
    1e-13 of the torque); the loop carries that to about 2e-12 of the peak torque
    (measured over 10 steps), so the runs are compared to 1e-11 and the laws to 1e-12."""
    for design in (Design.vc(gait), Design.tv(gait, DEADBEAT)):
        loops = [MujocoLoop(design, law=law) for law in ("c", "python")]
        c, py = (lp.run(gait.q(0.0), gait.dq(0.0), 3, log=True) for lp in loops)
        assert c.status == py.status == "walked", (c.message, py.message)
        assert [s.t_touchdown for s in c.steps] == [s.t_touchdown for s in py.steps]
        assert c.u.shape == py.u.shape
        peak = np.abs(py.u).max()
        assert np.abs(c.u - py.u).max() <= (1e-12 if design.M1 is None else 1e-11) * peak
        # the laws at the same states: the first step of the C run
        lay, (lc, lpy) = loops[0].layout, (lp.law for lp in loops)
        p_c = lc.step_start(gait.q(0.0), gait.dq(0.0)).p
        p_py = lpy.step_start(gait.q(0.0), gait.dq(0.0)).p
        for k in np.flatnonzero(c.t < c.steps[0].t_touchdown)[::5]:
            q, dq = lay.to_toolkit(c.qpos[k], c.qvel[k], 0)
            (rc1, u1), (rc2, u2) = (lc.torque(c.t[k], q, dq, p_c),
                                    lpy.torque(c.t[k], q, dq, p_py))
            assert rc1 == rc2 == 0 and np.abs(u1 - u2).max() <= 1e-12 * peak


def test_bound_law_is_the_law(gait, rng):
    """The loop's call of the law bound to its buffers (NumericLaw.bind) gives the law's
    own torques and return codes bit for bit, for the C law and the Python law, on
    states written into the buffers between calls (and out of range)."""
    from biped_casadi.mujoco.law import control_law
    for law_name in ("c", "python"):
        law = control_law(Design.tv(gait, DEADBEAT), law_name)
        q, dq, p = np.zeros(5), np.zeros(5), np.zeros(law.n_par)
        p[:] = law.step_start(gait.q(0.0), gait.dq(0.0)).p
        call = law.bind(q, dq, p)
        for tau in (0.05, 0.2, 0.4, 0.5, 10.0):
            q[:] = np.ravel(gait.q(tau if tau < gait.T else 0.1)) + rng.normal(0, 0.01, 5)
            dq[:] = np.ravel(gait.dq(tau if tau < gait.T else 0.1)) + rng.normal(0, 0.1, 5)
            rc, u = call(tau)
            rc0, u0 = law.torque(tau, q.copy(), dq.copy(), p.copy())
            assert rc == rc0 and (rc != 0 or u.tobytes() == u0.tobytes()), (law_name, tau)
        assert rc == 2                              # tau = 10 s: out of range
    with pytest.raises(ValueError, match="q must be"):
        control_law(Design.vc(gait), "c").bind(np.zeros(4), np.zeros(5), np.zeros(0))


def test_walk_records_and_outcome(gait):
    """A short walk: its records are consistent (periods add up, speed = length /
    period), the touchdown errors are those of its pre-impact states, and the contact
    start refuses what it cannot start (virtual constraints at MuJoCo's soft default)."""
    w = walk(Design.vc(gait), steps=3)
    assert w.success and w.steps_walked == 3 and w.mujoco_steps > 0
    s = w.steps
    assert np.isclose(s[-1].t_touchdown, sum(r.period for r in s))
    assert all(np.isclose(r.speed, r.step_length / r.period) for r in s)
    assert all(np.isclose(r.qu_error, r.q_minus[0] - float(gait.q(gait.T)[0])) for r in s)
    assert all(r.section is not None and abs(r.slip) < 0.005 for r in s)
    d = w.to_dict()
    assert d["status"] == "walked" and len(d["steps"]) == 3 and "qpos" not in d
    from analysis.reporting.plots import mujoco_steps_plot
    ax = mujoco_steps_plot([w]).axes[3]
    ax.figure.canvas.draw()
    lo, hi = ax.get_xlim()
    ticks = [t for t in ax.get_xticks() if lo <= t <= hi]
    assert ticks and all(float(t).is_integer() for t in ticks)     # whole steps
    soft = walk(Design.vc(gait), steps=3, settings=MUJOCO_DEFAULT, step_start="contact")
    assert soft.status == "out_of_range" and "cannot start" in soft.message


def test_a_higher_friction_only_makes_slipping_harder(gait):
    """Above mu = 1 the stance foot slides less the higher mu is, and sinks about as far
    as at mu = 1 (MuJoCo's pyramidal cone softened the contact's normal as mu^4: at mu 2
    the foot slid 2.4 times as far as at mu 1 and sank 1.8 mm, at mu 10 RABBIT's virtual
    constraints scuffed in step 1 with the foot 89 mm deep); at mu <= 1 the MJCF is
    MuJoCo's own cone."""
    assert "impratio" not in mjcf(gait.model, dataclasses.replace(STIFF, mu=1.0))
    d = Design.vc(gait)
    base = walk(d, steps=2, settings=dataclasses.replace(STIFF, mu=1.0))
    assert base.success
    slip = base.max_slip
    for mu in (2.0, 10.0, 1e6):
        w = walk(d, steps=2, settings=dataclasses.replace(STIFF, mu=mu))
        assert w.success, (mu, w.message)
        assert w.max_penetration < 1.5 * base.max_penetration, mu
        assert w.max_slip <= slip, mu
        slip = w.max_slip


def test_stride_map_fit_is_exact_on_a_linear_map(rng):
    """The least-squares fit recovers an affine map exactly from noiseless pairs."""
    A = np.array([[0.3, -0.2], [0.5, 0.1]])
    c = np.array([0.1, -0.4])
    X0 = rng.normal(size=(12, 2))
    Lam, c2, res = fit_stride_map(X0, X0 @ A.T + c)
    assert np.allclose(Lam, A, atol=1e-12) and np.allclose(c2, c, atol=1e-12)
    assert np.all(res < 1e-12)


def test_c_driven_loop_is_the_python_loop_bit_for_bit(gait, gait3):
    """The MuJoCo steps driven by the C function (driver 'c') and by the Python loop
    give the same walk, every field and array bit for bit (the wall time apart): RABBIT's
    virtual constraints and deadbeat design and the three-link biped's virtual
    constraints, both contacts, both touchdowns and step starts, with and without the
    log, from the gait and from perturbed starts that walk, fall, scuff, slip, run out of
    the law's range or time.  (benchmarks/check_mujoco_drivers.py: 1216 cases.)"""
    from biped_casadi.mujoco.cloop import walk_differences
    paper = Perturbation.paper(5)
    runs = [(Design.vc(gait), [None, paper.scaled(3.0), (0.15, 1.5)]),
            (Design.tv(gait, DEADBEAT), [None, paper.scaled(1.0), (0.3, 3.0)]),
            (Design.vc(gait3), [None, (0.05, 0.5), (0.2, 2.0)])]
    n, outcomes = 0, set()
    for (design, starts), contact, step_start, touchdown in itertools.product(
            runs, ("stiff", "default"), ("impact", "contact"), ("grid", "interpolated")):
        slip = 0.0005 if touchdown == "interpolated" else 0.05
        kw = dict(settings=ContactSettings.of(contact), step_start=step_start,
                  touchdown=touchdown, max_slip=slip, horizon=0.9 if contact == "stiff"
                  else 2.0)
        c, py = (MujocoLoop(design, driver=d, **kw) for d in ("c", "python"))
        assert (c.driver, py.driver) == ("c", "python")
        for k, start in enumerate(starts):
            q0, dq0 = start_of(design.gait, start)
            log = bool((n + k) % 2)
            a, b = c.run(q0, dq0, 5, log=log), py.run(q0, dq0, 5, log=log)
            assert walk_differences(a, b) == [], (kw, start, log)
            outcomes.add(b.status)
        n += len(starts)
    assert n == 72 and {"walked", "fell", "scuffed", "slipped", "no_impact",
                        "out_of_range"} <= outcomes, outcomes
    assert MujocoLoop(Design.vc(gait), law="python").driver == "python"
    with pytest.raises(ValueError, match="driver"):
        MujocoLoop(Design.vc(gait), law="python", driver="c")
    with pytest.raises(ValueError, match="driver"):
        MujocoLoop(Design.vc(gait), driver="fortran")


def test_c_driven_loop_raises_mujocos_fatal_error(gait):
    """A MuJoCo error inside the steps driven in C is the ``mujoco.FatalError`` the
    Python loop's ``mj_step`` raises, with the same message (MuJoCo would otherwise end
    the process): a model with too little memory for its contacts."""
    messages = []
    for driver in ("c", "python"):
        lp = MujocoLoop(Design.vc(gait), driver=driver)
        xml = mjcf(gait.model, lp.settings, lp.torque_limit).replace(
            "<compiler ", '<size memory="4K"/><compiler ', 1)
        lp.m = mujoco.MjModel.from_xml_string(xml)
        lp.d = mujoco.MjData(lp.m)
        with pytest.raises(mujoco.FatalError, match="mj_stackAlloc") as e:
            lp.run(gait.q(0.0), gait.dq(0.0), 2)
        messages.append(str(e.value))
    assert messages[0] == messages[1]


def test_contact_names_what_it_is():
    """The contact's name says which it is: MuJoCo's own, the stiff one, or another
    solref (``--contact default --solref 0.01`` was called 'stiff')."""
    assert MUJOCO_DEFAULT.contact == "default" and STIFF.contact == "stiff"
    assert ContactSettings.of("default", solref=0.01).contact == "custom"
    assert ContactSettings.of("stiff", solref=0.006).to_dict()["contact"] == "custom"
    assert ContactSettings.of("default", solref=STIFF.solref).contact == "stiff"


def test_settings_and_torque_limit_refused():
    """Settings MuJoCo would reject or silently change, and a robot without a finite
    torque limit, are a ValueError naming the argument."""
    with pytest.raises(ValueError, match="timestep"):
        ContactSettings(timestep=0.0)
    with pytest.raises(ValueError, match="solref"):
        ContactSettings(timestep=0.002, solref=0.003)
    with pytest.raises(ValueError, match="foot_radius"):
        ContactSettings.of("stiff", foot_radius=-1.0)
    with pytest.raises(ValueError, match="mu must be at most"):      # MuJoCo's NaN state
        ContactSettings.of("stiff", mu=1e300)
    with pytest.raises(ValueError, match=r"foot_radius must be smaller than the leg's last "
                                         r"link \(0\.4 m"):
        mjcf(robot("rabbit"), ContactSettings.of("stiff", foot_radius=0.4))
    inf = dataclasses.replace(robot("rabbit").description, torque_limit=math.inf)
    with pytest.raises(ValueError, match="torque_limit"):
        mjcf(inf)
    assert 'ctrlrange="-80.0 80.0"' in mjcf(inf, STIFF, torque_limit=80.0)
    assert mujoco_module() is mujoco


@pytest.mark.parametrize("argv, words", [
    (["mujoco", "--timestep", "-1", "--no-eig"], "--timestep"),
    (["mujoco", "--solref", "0.001", "--no-eig"], "--solref"),
    (["mujoco", "--timestep", "0.5", "--no-eig"], "--timestep"),
    (["mujoco", "--timestep", "1e-9", "--no-eig"], "--timestep must be at least 1e-05 s"),
    (["mujoco", "--controller", "vc", "--m1", "1", "2", "3", "4"], "--m1"),
    (["mujoco", "--robot", "three_link", "--gait", "{gait}"], "gait"),
    (["mujoco", "--perturb-q", "1", "2", "--no-eig"], "--perturb-q"),
    (["mujoco", "--max-slip", "0", "--no-eig"], "--max-slip"),
    (["robot", "mjcf", "--out", "{tmp}/robot.txt"], "--out"),
    (["robot", "mjcf", "--robot", "nosuch", "--out", "{tmp}/robot.xml"], "nosuch"),
    (["robot", "mjcf", "--robot", str(WALKER), "--out", "{tmp}/robot.xml"], "--torque-limit"),
])
def test_bad_input_is_one_line_and_exit_2(argv, words, gait, tmp_path, capsys):
    g = gait.save(tmp_path / "gait.json")
    argv = [a.format(gait=g, tmp=tmp_path) for a in argv]
    assert biped_main(argv) == 2
    out, err = capsys.readouterr()
    assert out == "" and len(err.strip().splitlines()) == 1 and words in err, err
    assert not (tmp_path / "robot.xml").exists()


def test_robot_mjcf_command(tmp_path, capsys):
    """``biped robot mjcf`` writes a model MuJoCo reads, with the settings asked for."""
    out = tmp_path / "rabbit.xml"
    assert biped_main(["robot", "mjcf", "--out", str(out), "--contact", "default",
                       "--foot-radius", "0.01", "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    m = mujoco.MjModel.from_xml_path(str(out))
    assert r["settings"]["solref"] is None and r["nq"] == m.nq == 7
    foot = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_GEOM, "foot_a")
    assert m.geom_size[foot, 0] == 0.01 and np.allclose(m.geom_solref[foot], [0.02, 1])


def test_mujoco_floor_has_the_gaits_friction(gait, tmp_path, capsys):
    """Without --mu the floor has the friction coefficient the gait was optimised for
    (as the simulators judge it), and says so; --mu overrides."""
    from gait_opt import Gait
    own = Gait(gait.model, gait.options.replace(mu=0.9), gait.alpha, gait.x0, gait.T)
    g = own.save(tmp_path / "gait.json")
    args = ["mujoco", "--gait", str(g), "--controller", "vc", "--steps", "1", "--json"]
    for extra, mu in (([], 0.9), (["--mu", "0.7"], 0.7)):
        assert biped_main(args + extra) == 0
        assert json.loads(capsys.readouterr().out)["settings"]["mu"] == mu


def test_mujoco_command_json(gait, tmp_path, capsys):
    """``biped mujoco --json``: the walk, its records and MuJoCo's eigenvalues beside the
    exact ones; --plot writes the figure and the animation."""
    g = gait.save(tmp_path / "gait.json")
    rc = biped_main(["mujoco", "--gait", str(g), "--controller", "vc", "--steps", "2",
                     "--plot", str(tmp_path / "fig"), "--json"])
    r = json.loads(capsys.readouterr().out)
    assert rc == 0 and r["status"] == "walked" and r["steps_walked"] == 2
    assert {"speed_error", "period_error", "steps", "eigenvalues"} <= set(r)
    e = r["eigenvalues"]
    assert e["status"] == "ok" and e["reason"] == ""
    assert len(e["mujoco"]) == 2 and abs(e["exact_max_abs"] - abs(complex(*e["exact"][0]))) < 1e-12
    assert (tmp_path / "fig" / "mujoco_steps.png").is_file()
    assert (tmp_path / "fig" / "mujoco_walk.gif").is_file()


def test_animation_shows_the_first_steps_of_a_long_walk(gait, tmp_path, capsys, monkeypatch):
    """A long walk's GIF animates its first ANIMATED_STEPS steps (1000 steps drew 14,000
    frames, 25 MB in two minutes, of axes 300 m wide where the robot was a dot), and its
    title says so."""
    from PIL import Image

    import analysis.cli.mujoco as cli
    monkeypatch.setattr(cli, "ANIMATED_STEPS", 2)
    g = gait.save(tmp_path / "gait.json")
    assert biped_main(["mujoco", "--gait", str(g), "--controller", "vc", "--steps", "4",
                       "--no-eig", "--plot", str(tmp_path / "fig"), "--json"]) == 0
    r = json.loads(capsys.readouterr().out)
    with Image.open(tmp_path / "fig" / "mujoco_walk.gif") as im:
        frames = im.n_frames
    two = r["steps"][1]["t_touchdown"]                  # the second step's end, s
    assert frames <= 25 * two + 2 < 25 * r["steps"][3]["t_touchdown"], (frames, two)


def test_steps_figure_of_a_walk_that_took_no_step():
    """A walk that ends in its first step: the figure's step axis shows step 1 and says
    no step was completed (it showed steps -0.04 to 0.04 over empty panels)."""
    from analysis.reporting.plots import mujoco_steps_plot
    w = dict(law="c", settings=dict(contact="stiff"), status="scuffed",
             gait=dict(speed=0.6, T=0.54), speeds=[], periods=[], qu_errors=[], dqu_errors=[])
    fig = mujoco_steps_plot([w])
    ax = fig.axes[3]
    ticks = [t for t in ax.get_xticks() if ax.get_xlim()[0] <= t <= ax.get_xlim()[1]]
    assert ticks and all(t >= 1 and float(t).is_integer() for t in ticks), ticks
    assert any("no step" in t.get_text() for t in fig.axes[0].texts)


def test_no_cycle_prints_no_eigenvalues(gait, tmp_path, capsys):
    """A design that cannot walk in MuJoCo has no cycle to fit: the stride-map line says
    so (it printed 'eigenvalues [] (fit residual nan of the deviations)')."""
    g = gait.save(tmp_path / "gait.json")
    assert biped_main(["mujoco", "--gait", str(g), "--controller", "vc", "--steps", "1",
                       "--torque-limit", "1"]) == 1
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if x.startswith("MuJoCo's stride map"))
    assert "nan" not in line and "[]" not in line and "no cycle" in line, line


def test_a_stride_map_fit_not_determined_is_not_called_mujocos(tmp_path, capsys):
    """The walker (RABBIT from its URDF, on its own imported step) with the default gait's
    deadbeat M1: MuJoCo's walk settles on a cycle (repeating to 1e-6, approached by a
    factor 0.77 a step), but the rollouts
    from the gait's start at the default perturbation leave the map's linear range (one
    grows 2.5 times in 3 steps) and the fit's max|lambda| is 1.04 beside an exact 7e-4;
    ``biped mujoco --steps 5`` printed those as MuJoCo's eigenvalues.  Now the line and
    the JSON (eigenvalues.status, .reason) say the fit is not determined."""
    toml, g = tmp_path / "walker.toml", tmp_path / "wg.json"
    assert biped_main(["robot", "import", str(WALKER), "--torque-limit", "150",
                       "--out", str(toml)]) == 0
    assert biped_main(["gait", "--import", str(WALKER.with_name("walker_step.csv")),
                       "--robot", str(toml), "--angles", "urdf", "--stance", "hip_left",
                       "--out", str(g)]) == 0
    capsys.readouterr()
    args = ["mujoco", "--gait", str(g), "--robot", str(toml), "--steps", "2", "--m1"]
    assert biped_main(args + [str(v) for v in DEADBEAT] + ["--json"]) == 0
    e = json.loads(capsys.readouterr().out)["eigenvalues"]
    assert e["mujoco"] == [] and e["mujoco_max_abs"] is None, e["mujoco"]
    assert e["status"] == e["stride_map"]["status"] == "undetermined", e["status"]
    assert e["stride_map"]["max_abs"] >= 1 and "max|lambda|" in e["reason"], e["reason"]
    c = e["stride_map"]["cycle"]                # the walk's own approach: it attracts
    assert c["status"] == "ok" and 0 < c["approach"] < 1 and len(c["approach_steps"]) == 2
    assert biped_main(args + [str(v) for v in DEADBEAT]) == 0
    out = capsys.readouterr().out
    line = next(x for x in out.splitlines() if x.startswith("MuJoCo's stride map"))
    assert "not determined by its rollouts (max|lambda|" in line and "eigenvalues" not in line
    assert f"approached its cycle by a factor {c['approach']:.3g} a step" in out, out


def test_undetermined_reason():
    """Each reason a fit is not MuJoCo's map, and none for a contracting fit with a
    perturbation above the jitter (whatever its residual: the paper's strongly
    contracting designs leave 0.94-0.99 and still bracket the exact eigenvalue)."""
    from biped_casadi.mujoco.stride import LimitCycle, undetermined_reason
    nan2 = [math.nan, math.nan]
    cyc = LimitCycle(status="ok", message="", steps=60, section=[0.2, 0.8],
                     jitter=[0.001, 0.01], section_distance=nan2, pre_impact_distance=nan2,
                     speed_error=0.0, period_error=0.0)
    assert undetermined_reason(0.5, cyc, [0.002, 0.02]) == ""
    assert "jitter" in undetermined_reason(0.5, cyc, [0.001, 0.01])
    assert ">= 1" in undetermined_reason(1.0, cyc, [0.002, 0.02])
    assert undetermined_reason(math.nan, cyc, [0.002, 0.02]) != ""


def test_short_walk_says_how_to_see_the_settled_errors(gait, tmp_path, capsys):
    """A walk of at most SETTLE steps has no settled worst error: the line says how many
    steps it takes (it said "none (no step after it)" on every default run)."""
    from biped_casadi.mujoco import SETTLE
    g = gait.save(tmp_path / "gait.json")
    assert biped_main(["mujoco", "--gait", str(g), "--controller", "vc", "--steps", "2",
                       "--no-eig"]) == 0
    out = capsys.readouterr().out
    assert f"needs more than {SETTLE} steps (--steps {2 * SETTLE + 10})" in out, out
    # a walk that ended early gets no such advice, and an unstable design says so
    assert biped_main(["mujoco", "--gait", str(g), "--steps", "12"]) == 1
    out = capsys.readouterr().out
    assert "none (the walk ended first)" in out and "--steps 30" not in out, out
    assert "the design is unstable (exact max|lambda|" in out and "biped m1" in out, out


def test_done_when_walks_at_stiff_settings(gait):
    """Virtual constraints at the stiff settings: 100 steps from the gait, 30 from the
    paper's perturbation at scale 2, speed and period within 3 %, errors after step 10
    within 0.1 rad and 0.3 rad/s (the robust design is measured by the benchmark)."""
    loop = MujocoLoop(Design.vc(gait), STIFF)
    w = loop.run(gait.q(0.0), gait.dq(0.0), 100)
    q0, dq0 = Perturbation.paper(5).scaled(2.0).initial_state(gait)
    wp = loop.run(q0, dq0, 30)
    for r in (w, wp):
        assert r.status == "walked", r.message
        assert abs(r.speed_error) < 0.03 and abs(r.period_error) < 0.03
        assert r.worst_qu_error < 0.1 and r.worst_dqu_error < 0.3


def test_reproduce_section_from_a_check(gait):
    """The reproduction's stage task on a small budget: its row, the report's section
    (table and the sentence on A^z) and the figure."""
    from analysis.pipeline.mujoco import _row, check_in_mujoco
    from analysis.reporting.in_mujoco import mujoco_lines
    from analysis.reporting.plots import mujoco_eigen_plot
    budget = dict(steps=12, scale_steps=4, scales=(1, 2), directions=4)
    (r,) = check_in_mujoco(Design.vc(gait), ("stiff",), "virtual constraints", budget)
    assert r.success and r.largest_scale == 2.0 and r.stride.status == "ok"
    assert abs(r.exact_max_abs - abs(r.exact[0])) < 1e-15 and r.exact[1] == 0
    row = _row("virtual constraints", "stiff", r)
    json.dumps(row, allow_nan=False)
    lines = mujoco_lines({"mujoco": {"rows": [row], "budget": budget,
                                     "settings": {"stiff": STIFF.to_dict()}}})
    text = "\n".join(lines)
    assert "## In MuJoCo" in text and "| virtual constraints | stiff | walked 12/12 |" in text
    assert "the exact A^z is within" in text or "unresolved" in text
    assert len(mujoco_eigen_plot([row]).axes) == 2


def test_interpolated_touchdown(gait):
    """The interpolated touchdown lies within one time step before MuJoCo's first state
    in contact, and its state between the two states around it."""
    grid = walk(Design.vc(gait), steps=2, log=True)
    interp = walk(Design.vc(gait), steps=2, log=True, touchdown="interpolated")
    dt = STIFF.timestep
    a, b = grid.steps[0], interp.steps[0]
    assert a.t_touchdown - dt <= b.t_touchdown <= a.t_touchdown
    k = int(round(a.t_touchdown / dt))
    lay = layout(gait.model)
    q_before = lay.to_toolkit(grid.qpos[k - 1], grid.qvel[k - 1], 0)[0]
    lo, hi = np.minimum(q_before, a.q_minus), np.maximum(q_before, a.q_minus)
    assert np.all(lo - 1e-12 <= b.q_minus) and np.all(np.array(b.q_minus) <= hi + 1e-12)


def test_a_failure_at_a_touchdown_is_the_step_it_ends(gait):
    """A walk that fails at a touchdown (the stance foot slid more than ``max_slip`` in
    step 1, measured when step 1 ends) has ``fail_step`` 0, the step the touchdown ends,
    as the Python simulator counts a failure at an impact; its message names it as step
    1 (``failure_text``'s rule); the C-driven and the Python loops agree.  A step that
    cannot start after a touchdown is the next one."""
    from biped_casadi.mujoco.cloop import walk_differences
    from biped_casadi.simulation.outcome import failure_text
    q0, dq0 = start_of(gait)
    a, b = (MujocoLoop(Design.vc(gait), max_slip=2e-4, driver=d).run(q0, dq0, 3)
            for d in ("c", "python"))
    assert walk_differences(a, b) == []
    assert (a.status, a.fail_step, a.steps_walked, a.steps[-1].index) == ("slipped", 0, 1, 0)
    assert a.message.startswith("step 1: ") and failure_text(a.status, a.fail_step) == \
        "slipped in step 1"
    soft = walk(Design.vc(gait), steps=3, settings=MUJOCO_DEFAULT, step_start="contact")
    assert soft.status == "out_of_range" and soft.fail_step == soft.steps_walked
    assert soft.message.startswith(f"step {soft.fail_step + 1} cannot start")


def test_start_of_names_a_missing_gait():
    for bad in (None, "gait.json"):
        with pytest.raises(TypeError, match="^gait: a gait is needed"):
            start_of(bad)


def _normal_regulariser(gait, settings):
    """MuJoCo's regulariser R of the stance foot's contact normal at the gait's start: the
    elliptic cone's first row, a quarter of the pyramid's common edge R (its four edges
    share the normal force equally)."""
    loop = MujocoLoop(Design.vc(gait), settings)
    m, d = loop.m, loop.d
    mujoco.mj_resetData(m, d)
    d.qpos[:], d.qvel[:] = loop.initial_state(gait.q(0.0), gait.dq(0.0))
    d.qpos[1] -= 1e-4                                      # the foot 0.1 mm into the floor
    mujoco.mj_forward(m, d)
    c = next(c for c in d.contact[:d.ncon] if loop.feet[0] in c.geom)
    i = int(c.efc_address)
    return d.efc_R[i] if settings.cone == "elliptic" else d.efc_R[i] / 4


def test_the_elliptic_cone_keeps_the_contact_independent_of_mu(gait, tmp_path):
    """With cone='elliptic' MuJoCo regularises the contact's normal by its solref alone,
    the pyramid's at mu = 1, at every mu from 0.3 to 1e6 (the pyramidal cone's normal is
    mu^2 (1 + mu^2) / 2 of it at mu <= 1); a walk then sinks and slips the same at mu 0.6
    and 1e6, where the pyramidal cone's slip differs tenfold."""
    el = dataclasses.replace(STIFF, cone="elliptic")
    ref = _normal_regulariser(gait, dataclasses.replace(STIFF, mu=1.0))
    for mu in (0.3, 0.6, 1.0, 10.0, 1e6):
        assert 'cone="elliptic"' in mjcf(gait.model, dataclasses.replace(el, mu=mu))
        r = _normal_regulariser(gait, dataclasses.replace(el, mu=mu))
        assert r == pytest.approx(ref, rel=1e-12), mu
        pyr = _normal_regulariser(gait, dataclasses.replace(STIFF, mu=mu))
        assert pyr == pytest.approx(ref * min(1.0, mu * mu * (1 + mu * mu) / 2), rel=1e-12)
    d = Design.vc(gait)
    w = {(c, mu): walk(d, steps=3, settings=dataclasses.replace(STIFF, cone=c, mu=mu))
         for c in ("elliptic", "pyramidal") for mu in (0.6, 1e6)}
    assert all(x.success for x in w.values())
    a, b = w["elliptic", 0.6], w["elliptic", 1e6]
    assert b.max_slip == pytest.approx(a.max_slip, rel=0.05)
    assert b.max_penetration == pytest.approx(a.max_penetration, rel=0.2)
    assert w["pyramidal", 0.6].max_slip > 10 * w["pyramidal", 1e6].max_slip
    with pytest.raises(ValueError, match="cone must be one of"):
        ContactSettings(cone="conical")
    out = tmp_path / "m.xml"
    assert biped_main(["robot", "mjcf", "--cone", "elliptic", "--out", str(out)]) == 0
    assert 'cone="elliptic"' in out.read_text()
