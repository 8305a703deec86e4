"""``biped mujoco`` on a walk that fails: is MuJoCo's time step the cause?  The same walk
is walked again at finer time steps (biped_casadi.mujoco.timestep); the verdict names the
time step to use only when a finer one walks every step, and that time step walks."""
from __future__ import annotations

import json

import numpy as np
import pytest

from analysis.cli import main as biped_main
from biped_casadi import Design
from biped_casadi.mujoco import (BOUNCE_TOLERANCE, ContactSettings, MujocoLoop,
                                 check_timestep, strike_velocity)

pytest.importorskip("mujoco")

#: the three-link biped at a time step of 30 ms (its contact time constant 60 ms, two time
#: steps, kept at the finer ones): an input of the tests, chosen as a walk that fails
COARSE = ["--timestep", "0.03", "--solref", "0.06"]


def _run(argv, capsys):
    rc = biped_main(argv)
    return rc, capsys.readouterr().out


def test_too_coarse_time_step_is_named_and_its_advice_walks(gait3, tmp_path, capsys):
    """A walk that fails at a coarse time step and walks at a finer one: the JSON says
    'too_coarse' with the time step that walked, the human output says it in one line
    with the --timestep to try, and a run at that time step walks."""
    g = str(gait3.save(tmp_path / "gait3.json"))
    base = ["mujoco", "--gait", g, "--controller", "vc", "--steps", "10", "--no-eig"]
    rc, out = _run(base + COARSE + ["--json"], capsys)
    r = json.loads(out)
    c = r["timestep_check"]
    assert rc == 1 and r["status"] != "walked", r["status"]
    assert c["status"] == "too_coarse" and c["timestep"] == 0.03, c
    assert c["contact_steps"] == pytest.approx(float(COARSE[3]) / float(COARSE[1])), c
    last = c["tried"][-1]
    assert last["status"] == "walked" and last["steps_walked"] == 10, c["tried"]
    # those before it failed, or walked with landings beyond the tolerance
    assert all(t["status"] != "walked" or t["landing_travel"] > c["bounce_limit"]
               for t in c["tried"][:-1]), c["tried"]
    fine = c["suggested_timestep"]
    assert fine == last["timestep"] < c["timestep"], c
    # the human output: the likely cause in one line, right under the status line
    rc, out = _run(base + COARSE, capsys)
    lines = out.splitlines()
    assert rc == 1 and "too coarse" in lines[1] and f"--timestep {fine:g}" in lines[1], out
    # the advice walks, and a walk that walked tries nothing
    rc, out = _run(base + ["--timestep", f"{fine:g}", "--solref", "0.06", "--json"], capsys)
    r = json.loads(out)
    assert rc == 0 and r["status"] == "walked", r["message"]
    t = r["timestep_check"]
    lands = t["walk"]["landing_travel"] <= t["bounce_limit"]
    assert t["status"] == ("not_needed" if lands else "bounces") and t["tried"] == [], t


def test_a_failure_elsewhere_is_not_blamed_on_the_time_step(gait, tmp_path, capsys):
    """A torque limit far too low fails at every time step: the check says it is not the
    time step, suggests none, and names the finer time steps it tried."""
    g = str(gait.save(tmp_path / "gait.json"))
    argv = ["mujoco", "--gait", g, "--controller", "vc", "--steps", "1", "--no-eig",
            "--torque-limit", "1"]
    rc, out = _run(argv + ["--json"], capsys)
    c = json.loads(out)["timestep_check"]
    assert rc == 1 and c["status"] == "not_timestep" and c["suggested_timestep"] is None, c
    assert len(c["tried"]) == 2 and all(t["status"] != "walked" for t in c["tried"]), c
    assert [t["timestep"] for t in c["tried"]] == sorted((t["timestep"] for t in c["tried"]),
                                                         reverse=True)
    assert all(t["timestep"] < c["timestep"] for t in c["tried"])
    rc, out = _run(argv, capsys)
    assert "not the time step" in out.splitlines()[1], out


def test_strike_velocity_is_the_impact_of_the_gait(gait):
    """The recorded strike: the swing foot moving down into the floor at the gait's impact
    (SPEC §2), equal to a finite difference of the swing foot's position, and its
    travel in one time step |v_z| dt; a walk that walked is not walked again."""
    v = strike_velocity(gait)
    T, h = float(gait.T), 1e-6
    a = np.array(gait.model.swing_foot(gait.q(T)), float).ravel()
    b = np.array(gait.model.swing_foot(gait.q(T - h)), float).ravel()
    assert v[1] < 0 and np.allclose(v, (a - b) / h, rtol=1e-4, atol=1e-4), (v, (a - b) / h)
    settings = ContactSettings(timestep=0.002)
    loop = MujocoLoop(Design.vc(gait), settings)
    q0, dq0 = gait.q(0.0), gait.dq(0.0)
    w = loop.run(q0, dq0, 1)
    c = check_timestep(loop, q0, dq0, 1, w)
    assert w.status == "walked" and c.success and c.tried == [], c
    assert c.strike_travel == pytest.approx(abs(v[1]) * settings.timestep, rel=1e-12)


def test_auto_time_step_walks_at_the_time_step_that_walked(gait3, tmp_path, capsys,
                                                           monkeypatch):
    """``--timestep auto``: from the default time step (here made the coarse one of
    COARSE, as no built-in robot fails at 2 ms), a failed walk is replaced by the walk at
    the time step that walked; the JSON records both; where the default walks, auto is the
    default, bit for bit."""
    import importlib
    mjcf_module = importlib.import_module("biped_casadi.mujoco.mjcf")
    g = str(gait3.save(tmp_path / "gait3.json"))
    base = ["mujoco", "--gait", g, "--controller", "vc", "--steps", "10", "--no-eig", "--json"]
    rc, out = _run(base, capsys)
    plain = json.loads(out)
    rc_auto, out = _run(base + ["--timestep", "auto"], capsys)
    auto = json.loads(out)
    assert rc == rc_auto == 0 and auto["timestep_check"]["auto_timestep"] is None
    assert auto["steps"] == plain["steps"] and auto["settings"] == plain["settings"]

    coarse = mjcf_module.ContactSettings(timestep=float(COARSE[1]), solref=float(COARSE[3]))
    monkeypatch.setattr(mjcf_module, "STIFF", coarse)
    rc, out = _run(base + ["--solref", COARSE[3], "--timestep", "auto"], capsys)
    r = json.loads(out)
    c = r["timestep_check"]
    assert c["status"] == "too_coarse" and c["walk"]["status"] != "walked", c
    assert c["timestep"] == coarse.timestep and c["auto_timestep"] == c["suggested_timestep"]
    assert rc == 0 and r["status"] == "walked" and r["steps_walked"] == 10, r["message"]
    assert r["settings"]["timestep"] == c["auto_timestep"] < coarse.timestep
    rc, out = _run(base[:-1] + ["--solref", COARSE[3], "--timestep", "auto"], capsys)
    assert rc == 0 and out.startswith("--timestep auto: at"), out


#: the robust design's worst landing at 2 ms (biped mujoco on the simulate_args of 'biped m1
#: --robust', 30 steps from the gait, 2026-12-07): the new stance foot thrown 16.1 mm
#: forward, an input of the test below
ROBUST_LANDING_2MS = 0.0161


def test_a_walk_whose_landings_bounce_is_named_and_refined(gait):
    """A walk that walks but whose landings move the new stance foot beyond the tolerance
    (here RABBIT's walk at 2 ms with the robust design's recorded landing put into its
    record): without ``refine`` it is named ('bounces') and nothing is run again; with it,
    the walk is walked again at the finer time steps and the first whose landings stay
    within the tolerance is suggested; where none does, the finest that walked is, and
    the message says so.  The walk as it was (its landings within) is left alone."""
    loop = MujocoLoop(Design.vc(gait), ContactSettings(timestep=0.002))
    q0, dq0 = gait.q(0.0), gait.dq(0.0)
    w = loop.run(q0, dq0, 3)
    limit = BOUNCE_TOLERANCE * float(gait.step_length)
    assert w.status == "walked" and w.landing_travel <= limit, w.landing_travel
    c = check_timestep(loop, q0, dq0, 3, w, refine=True)
    assert c.status == "not_needed" and c.tried == [] and c.bounce_limit == limit, c
    w.steps[1].impact_travel = -ROBUST_LANDING_2MS           # thrown back or forward alike
    assert w.landing_travel == ROBUST_LANDING_2MS > limit
    c = check_timestep(loop, q0, dq0, 3, w)
    assert c.status == "bounces" and c.tried == [] and c.suggested_timestep is None, c
    assert "16.1 mm" in c.message and "--timestep auto" in c.message, c.message
    c = check_timestep(loop, q0, dq0, 3, w, refine=True)
    assert c.status == "too_coarse" and c.walk["landing_travel"] == ROBUST_LANDING_2MS, c
    assert [t["timestep"] for t in c.tried] == [0.001], c.tried
    assert c.tried[0]["status"] == "walked" and c.tried[0]["landing_travel"] <= limit
    assert c.suggested_timestep == 0.001 and "try --timestep 0.001" in c.message, c
    # a tolerance no finer time step meets: the finest that walked, and said so
    c = check_timestep(loop, q0, dq0, 3, w, refine=True, tolerance=1e-6)
    assert [t["timestep"] for t in c.tried] == [0.001, 0.0005], c.tried
    assert all(t["status"] == "walked" and t["landing_travel"] > c.bounce_limit
               for t in c.tried), c.tried
    assert c.status == "too_coarse" and c.suggested_timestep == 0.0005, c
    assert "finest time step tried" in c.message, c.message


def test_auto_time_step_refines_a_walk_whose_landings_move_too_far(gait, tmp_path, capsys):
    """``--timestep auto`` on a walk that walks at 2 ms but whose landings move the new
    stance foot more than the tolerance (RABBIT's gait on a floor of mu 0.42, below its
    impact impulse's friction ratio: the landing foot slides): the walk reported is the
    one at the first finer time step whose landings stay within it; without auto, one
    line names the landings and nothing is walked again."""
    g = str(gait.save(tmp_path / "gait.json"))
    base = ["mujoco", "--gait", g, "--controller", "vc", "--steps", "5", "--no-eig",
            "--mu", "0.42"]
    rc, out = _run(base + ["--json"], capsys)
    c = json.loads(out)["timestep_check"]
    assert rc == 0 and c["status"] == "bounces" and c["tried"] == [], c
    assert c["walk"]["landing_travel"] > c["bounce_limit"], c
    rc, out = _run(base, capsys)
    assert "the landings move the new stance foot" in out.splitlines()[1], out
    rc, out = _run(base + ["--timestep", "auto", "--json"], capsys)
    r = json.loads(out)
    c = r["timestep_check"]
    assert rc == 0 and c["status"] == "too_coarse" and c["auto_timestep"], c
    chosen = next(t for t in c["tried"] if t["timestep"] == c["auto_timestep"])
    assert chosen["landing_travel"] <= c["bounce_limit"], c["tried"]
    assert all(t["landing_travel"] > c["bounce_limit"] for t in c["tried"] if t is not chosen)
    assert r["settings"]["timestep"] == c["auto_timestep"] and r["status"] == "walked"
    assert max(abs(s["impact_travel"]) for s in r["steps"][1:]) == chosen["landing_travel"]
    rc, out = _run(base + ["--timestep", "auto"], capsys)
    assert out.startswith("--timestep auto: at 0.002 s the walk walked but its landings"), out
