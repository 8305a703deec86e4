"""``biped mujoco`` on a walk that fails: is the contact too stiff for the time step?  The
same walk is walked again at the same time step with softer contacts
(biped_casadi.mujoco.contact); the verdict names the ``--solref`` to use only when a
softer one walks every step, with what it costs, and that contact walks."""
from __future__ import annotations

import json

import numpy as np
import pytest

from analysis.cli import main as biped_main
from biped_casadi import Design
from biped_casadi.mujoco import FACTORS, ContactSettings, MujocoLoop, check_contact

pytest.importorskip("mujoco")

#: the three-link biped at a time step of 15 ms and a contact of two time steps, from a
#: start perturbed by (0.05 rad, 0.3 rad/s): an input of the tests, chosen as a walk that
#: fails (no built-in robot fails from its gait at the stiff settings) and walks with a
#: softer contact at the same time step
STIFF_FAILS = ["--timestep", "0.015", "--solref", "0.03", "--perturb", "0.05", "0.3"]


def _run(argv, capsys):
    rc = biped_main(argv)
    return rc, capsys.readouterr().out


def test_too_stiff_contact_is_named_with_its_cost_and_its_advice_walks(gait3, tmp_path,
                                                                       capsys):
    """A walk that fails at a contact of two time steps and walks at a softer one: the
    JSON says 'too_stiff' with the time constant that walked and what it costs (speed
    error, the feet's depth in the floor, beside the walk at the finer time step that the
    time step check found); the human output says it on the line after the time step's,
    with the --solref to try; a run with that contact walks and runs nothing more."""
    g = str(gait3.save(tmp_path / "gait3.json"))
    base = ["mujoco", "--gait", g, "--controller", "vc", "--steps", "10", "--no-eig"]
    rc, out = _run(base + STIFF_FAILS + ["--json"], capsys)
    r = json.loads(out)
    c, t = r["contact_check"], r["timestep_check"]
    assert rc == 1 and r["status"] != "walked", r["status"]
    assert c["status"] == "too_stiff" and c["timestep"] == 0.015 and c["solref"] == 0.03, c
    last = c["tried"][-1]
    assert last["status"] == "walked" and last["steps_walked"] == 10, c["tried"]
    assert all(x["status"] != "walked" for x in c["tried"][:-1]), c["tried"]
    # every softer contact at the walk's time step, at one of the factors, two steps or more
    assert all(x["timestep"] == 0.015 for x in c["tried"]), c["tried"]
    assert [x["solref"] for x in c["tried"]] == pytest.approx(
        [f * 0.03 for f in FACTORS[:len(c["tried"])]])
    assert all(x["contact_steps"] >= 2 for x in c["tried"]), c["tried"]
    soft = c["suggested_solref"]
    assert soft == last["solref"] > c["solref"], c
    # the cost: the speed error and the depth, a foot in the floor (at most the sphere's
    # centre below the surface plus a few radii, not a fall)
    assert np.isfinite(last["speed_error"]) and 0 < last["max_penetration"], last
    if t["suggested_timestep"] is not None:
        ref = c["reference"]
        assert ref["timestep"] == t["suggested_timestep"] and ref["solref"] == c["solref"]
        assert ref["max_penetration"] > 0, ref
    # the human output: the time step's line, then the contact's, with the --solref to try
    rc, out = _run(base + STIFF_FAILS, capsys)
    lines = out.splitlines()
    assert rc == 1 and "softer contact walks" in lines[2] and f"--solref {soft:g}" in lines[2], out
    assert f"{100 * last['speed_error']:+.2f} %" in lines[2], out
    # the advice walks, and a walk that walked tries nothing
    advice = list(STIFF_FAILS)
    advice[advice.index("--solref") + 1] = f"{soft:g}"
    rc, out = _run(base + advice + ["--json"], capsys)
    r = json.loads(out)
    assert rc == 0 and r["status"] == "walked", r["message"]
    assert r["contact_check"]["status"] == "not_needed" and r["contact_check"]["tried"] == []
    assert r["settings"]["solref"] == soft


def test_a_walk_that_walks_runs_nothing_more(gait3, tmp_path, capsys, monkeypatch):
    """The checks cost nothing when the walk walks: one MuJoCo walk, both checks
    'not_needed' with nothing tried, and no check line in the human output."""
    runs = []
    real = MujocoLoop.run

    def counted(self, *a, **k):
        runs.append(self.settings)
        return real(self, *a, **k)

    monkeypatch.setattr(MujocoLoop, "run", counted)
    g = str(gait3.save(tmp_path / "gait3.json"))
    base = ["mujoco", "--gait", g, "--controller", "vc", "--steps", "3", "--no-eig"]
    rc, out = _run(base + ["--json"], capsys)
    r = json.loads(out)
    assert rc == 0 and r["status"] == "walked", r["message"]
    assert len(runs) == 1, runs
    for key in ("timestep_check", "contact_check"):
        assert r[key]["status"] == "not_needed" and r[key]["tried"] == [], r[key]
    runs.clear()
    rc, out = _run(base + ["--solref", "auto", "--timestep", "auto"], capsys)
    assert rc == 0 and len(runs) == 1, runs
    assert not any(s in out for s in ("softer", "stiffness", "likely cause", "not the time",
                                      "auto:")), out


def test_a_failure_elsewhere_is_not_blamed_on_the_contact(gait, tmp_path, capsys):
    """A torque limit far too low fails at every contact: the check says it is not the
    contact's stiffness, suggests none, and names the softer contacts it tried."""
    g = str(gait.save(tmp_path / "gait.json"))
    argv = ["mujoco", "--gait", g, "--controller", "vc", "--steps", "1", "--no-eig",
            "--torque-limit", "1"]
    rc, out = _run(argv + ["--json"], capsys)
    c = json.loads(out)["contact_check"]
    assert rc == 1 and c["status"] == "not_stiffness" and c["suggested_solref"] is None, c
    assert len(c["tried"]) == len(FACTORS) and all(t["status"] != "walked"
                                                   for t in c["tried"]), c
    assert all(t["solref"] > c["solref"] and t["timestep"] == c["timestep"]
               for t in c["tried"]), c
    rc, out = _run(argv, capsys)
    assert "not the contact's stiffness" in out.splitlines()[2], out


def test_auto_solref_walks_with_the_contact_that_walked(gait3, tmp_path, capsys,
                                                        monkeypatch):
    """``--solref auto``: from the default contact (here made the stiff one of
    STIFF_FAILS), a failed walk is replaced by the walk at the softer contact that walked;
    the JSON records both; with ``--timestep auto`` too, a finer time step that walks
    comes first (it keeps the contact asked for)."""
    import importlib
    mjcf_module = importlib.import_module("biped_casadi.mujoco.mjcf")
    g = str(gait3.save(tmp_path / "gait3.json"))
    dt, solref, perturb = STIFF_FAILS[1], STIFF_FAILS[3], STIFF_FAILS[4:]
    monkeypatch.setattr(mjcf_module, "STIFF", mjcf_module.ContactSettings(
        timestep=float(dt), solref=float(solref)))
    base = ["mujoco", "--gait", g, "--controller", "vc", "--steps", "10", "--no-eig",
            "--timestep", dt, *perturb, "--json"]
    rc, out = _run(base + ["--solref", "auto"], capsys)
    r = json.loads(out)
    c = r["contact_check"]
    assert c["status"] == "too_stiff" and c["auto_solref"] == c["suggested_solref"], c
    assert c["solref"] == float(solref) and r["timestep_check"]["auto_timestep"] is None
    assert rc == 0 and r["status"] == "walked" and r["steps_walked"] == 10, r["message"]
    assert r["settings"]["solref"] == c["auto_solref"] > float(solref)
    assert r["settings"]["timestep"] == float(dt)
    rc, out = _run(base[:-1] + ["--solref", "auto"], capsys)
    assert rc == 0 and out.startswith("--solref auto: with solref"), out
    # both auto: the time step first, when a finer one walks
    base[base.index("--timestep") + 1] = "auto"
    rc, out = _run(base + ["--solref", "auto"], capsys)
    r = json.loads(out)
    if r["timestep_check"]["status"] == "too_coarse":
        assert r["contact_check"]["auto_solref"] is None
        assert r["settings"]["solref"] == float(solref) and r["status"] == "walked"
        assert r["settings"]["timestep"] == r["timestep_check"]["auto_timestep"]


def test_auto_solref_starts_at_two_time_steps_of_a_coarse_timestep(gait3, tmp_path, capsys):
    """``--solref auto`` with a ``--timestep`` whose two steps exceed the stiff contact's
    4 ms: the walk starts from a contact of two time steps (the stiffest MuJoCo takes as
    given) instead of refusing the default it was not asked for; the same contact given
    as a number is still refused."""
    g = str(gait3.save(tmp_path / "gait3.json"))
    base = ["mujoco", "--gait", g, "--controller", "vc", "--steps", "2", "--no-eig",
            "--timestep", "0.01"]
    rc, out = _run(base + ["--solref", "auto", "--json"], capsys)
    r = json.loads(out)
    assert r["contact_check"]["solref"] == 0.02, r["contact_check"]
    assert rc in (0, 1) and r["settings"]["timestep"] == 0.01
    assert biped_main(base + ["--solref", "0.004"]) == 2
    assert "at least two time steps" in capsys.readouterr().err


def test_max_penetration_is_the_feet_depth_in_the_floor(gait):
    """The walk's depth: the sphere's radius less the lowest height of either foot's
    centre over the states it went through (MuJoCo's own geometry of the logged states),
    the same bit for bit with the steps driven in C and in Python; deeper at a softer
    contact."""
    import mujoco
    q0, dq0 = gait.q(0.0), gait.dq(0.0)
    depth = []
    for solref in (0.004, 0.008):
        settings = ContactSettings(timestep=0.002, solref=solref)
        loop = MujocoLoop(Design.vc(gait), settings)
        w = loop.run(q0, dq0, 2, log=True)
        py = MujocoLoop(Design.vc(gait), settings, driver="python").run(q0, dq0, 2)
        assert py.max_penetration == w.max_penetration, (py.max_penetration, loop.driver)
        d = mujoco.MjData(loop.m)
        lowest = np.inf
        for qpos in w.qpos:
            d.qpos[:] = qpos
            mujoco.mj_kinematics(loop.m, d)
            lowest = min(lowest, float(d.geom_xpos[list(loop.feet), 2].min()))
        p = w.max_penetration
        assert p == pytest.approx(loop.settings.foot_radius - lowest, abs=1e-12), (p, lowest)
        depth.append(p)
        assert check_contact(loop, q0, dq0, 2, w).tried == []
    assert 0 < depth[0] < depth[1], depth


def test_a_friction_below_the_gaits_is_said_up_front(gait, tmp_path, capsys):
    """A ``--mu`` below the friction ratio the gait needs (its largest |F_x| / F_z in the
    stance, its impact impulse's) is said before the walk in one line on stderr naming
    both (and in the JSON); the walk still runs (MuJoCo's friction is soft: between the
    two ratios RABBIT's gait walks).  At the gait's own mu nothing is said."""
    c = gait.check()
    stance, impact = c["max_friction_ratio"], c["impact_friction_ratio"]
    assert stance < impact, (stance, impact)
    g = str(gait.save(tmp_path / "gait.json"))
    base = ["mujoco", "--gait", g, "--controller", "vc", "--steps", "1", "--no-eig"]
    for mu, words in ((0.9 * stance, "friction the gait needs"),
                      ((stance + impact) / 2, "friction the gait's rigid impact needs")):
        rc = biped_main(base + ["--mu", f"{mu:.6g}", "--json"])
        out, err = capsys.readouterr()
        r = json.loads(out)
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("biped mujoco: warning: --mu"), err
        assert words in lines[0] and f"{stance:.3g}" in lines[0] and f"{impact:.3g}" in lines[0]
        f = r["friction_needed"]
        assert f["stance"] == stance and f["impact"] == impact and f["mu"] == float(f"{mu:.6g}")
        assert f["warning"] == lines[0].split("warning: ", 1)[1] and "steps" in r, f
    rc = biped_main(base + ["--json"])
    out, err = capsys.readouterr()
    assert rc == 0 and err == "" and json.loads(out)["friction_needed"]["warning"] == ""
