"""Per-joint torque limits: a robot whose hips and knees have different limits is held to
each joint's own limit wherever torques are checked or bounded (the description, the URDF
import, the gait's bounds, the simulator's check and saturation, the C export's clip,
MuJoCo's motors), not to the smallest for every joint."""
from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import casadi as ca
import numpy as np
import pytest

from biped_casadi import SimulationOptions, TimeVaryingController, robot, simulate
from biped_casadi.control import clip_torques
from biped_casadi.control.compiled import CompiledController, build_library, find_c_compiler
from biped_casadi.control.export import c_sources, exported_law
from biped_casadi.control.export_folder import write_export
from biped_casadi.model.description import (builtin_path, description_from_dict,
                                            description_toml, load_description)
from biped_casadi.model.urdf import import_urdf
from biped_casadi.simulation.full_order import Simulator
from biped_casadi.simulation.validity import Limits, node_violations
from gait_opt import optimize_gait
from gait_opt.transcription import build_problem

WALKER = Path(__file__).resolve().parents[1] / "docs" / "howto" / "walker" / "walker.urdf"
GAINS = [-10, 7.5, 10, -5]                      # the README's design


def _rabbit_with(tmp_path, limit: str, name: str = "rabbit_joints"):
    """RABBIT's file with another ``torque_limit`` line (``limit``: its TOML value)."""
    text = builtin_path("rabbit").read_text()
    text, n = re.subn(r"(?m)^torque_limit\s*=.*$", f"torque_limit = {limit}", text)
    assert n == 1
    path = tmp_path / f"{name}.toml"
    path.write_text(text.replace('name = "RABBIT"', f'name = "{name}"'))
    return robot(str(path))


@pytest.fixture(scope="module")
def knees(tmp_path_factory):
    """RABBIT with hips of 40 N m and knees of 20 N m: its gait's hip torques (about
    31 N m at the stance hip) are above the smallest limit, its knees' (about 13 N m)
    below the knees'."""
    m = _rabbit_with(tmp_path_factory.mktemp("robots"), "{ hip = 40.0, knee = 20.0 }")
    return m, optimize_gait(m, cache=True)


def test_a_table_gives_each_joint_its_limit_and_round_trips(tmp_path):
    m = _rabbit_with(tmp_path, "{ hip = 150.0, knee = 300.0 }")
    d = m.description
    assert d.torque_limit == 150.0 and d.leg_torque_limits == (150.0, 300.0)
    # u = (stance knee, stance hip, swing hip, swing knee)
    assert d.torque_limits == d.torque_bound == (300.0, 150.0, 150.0, 300.0)
    assert d.torque_limit_text == "hip 150, knee 300 N m"
    assert d.to_dict()["actuators"]["torque_limit"] == {"hip": 150.0, "knee": 300.0}
    back = tmp_path / "back.toml"
    back.write_text(description_toml(d))
    assert load_description(back) == d and load_description(back).cache_key == d.cache_key
    assert dataclasses.replace(d, leg_torque_limits=()) != d
    same = _rabbit_with(tmp_path, "{ hip = 150.0, knee = 150.0 }", "same").description
    assert same.leg_torque_limits == () and same.torque_bound == 150.0


@pytest.mark.parametrize("table, field", [
    ("{ hip = 150.0 }", "actuators.torque_limit.knee is missing"),
    ("{ hip = 150.0, knee = 300.0, ankle = 1.0 }", "actuators.torque_limit.ankle"),
    ("{ hip = 150.0, knee = -1.0 }", "actuators.torque_limit.knee must be positive"),
    ("{ hip = 150.0, knee = inf }", "actuators.torque_limit.knee must be finite"),
])
def test_a_bad_table_is_refused_naming_the_joint(tmp_path, table, field):
    with pytest.raises(ValueError, match=re.escape(field)):
        _rabbit_with(tmp_path, table)


def test_equal_limits_keep_rabbits_description_and_keys():
    d = robot("rabbit").description
    assert d.leg_torque_limits == () and d.torque_bound == 150.0
    assert d.to_dict()["actuators"]["torque_limit"] == 150.0
    assert not any("leg_torque_limits" in str(k) for k in d.cache_key)


def test_the_urdf_import_takes_each_joints_smaller_effort(tmp_path):
    """Efforts hip 150 / 140 (left / right) and knee 300 / 320: the hips' limit is 140,
    the knees' 300 (the legs swap roles every step), not 140 for every joint."""
    text = WALKER.read_text()
    for joint, effort in (("hip_left", 150), ("hip_right", 140), ("knee_left", 300),
                          ("knee_right", 320)):
        text, n = re.subn(rf'(<joint name="{joint}" type=")continuous(">)(.*?)(</joint>)',
                          rf'\1revolute\2\3<limit effort="{effort}" velocity="10" '
                          rf'lower="-6.2" upper="6.2"/>\4', text, flags=re.S)
        assert n == 1
    path = tmp_path / "walker.urdf"
    path.write_text(text)
    imp = import_urdf(path)
    d = imp.description
    assert d.torque_limit == 140.0 and d.leg_torque_limits == (140.0, 300.0)
    assert any("smaller of its two legs'" in n for n in imp.notes)
    assert description_from_dict(d.to_dict()) == d
    assert import_urdf(path, torque_limit=90.0).description.torque_bound == 90.0


def test_the_node_check_holds_each_torque_to_its_joints_limit(knees):
    """A torque of 30 N m is within a hip's 40 and beyond a knee's 20."""
    m, g = knees
    lim = Limits.of(SimulationOptions(), m, g)
    assert lim.torque_limit == (20.0, 40.0, 40.0, 20.0)
    u = np.array([[0.0, 30.0, 0.0, 0.0, -30.0],       # u1: stance knee
                  [30.0, 0.0, -39.0, 0.0, 0.0],        # u2: stance hip
                  [0.0, 0.0, 0.0, 41.0, 0.0],          # u3: swing hip
                  [0.0, 0.0, 0.0, 0.0, 0.0]])          # u4: swing knee
    n = u.shape[1]
    rows = dict(finite=np.ones(n, bool), den=np.ones(n), Fx=np.zeros(n), Fz=np.full(n, 100.0),
                xsw=np.full(n, -0.1), zsw=np.full(n, 0.1), hip=np.ones(n), torso=np.zeros(n),
                u=u)
    bad = node_violations(rows, lim, 1.0, 1.0)["torque_limit"]
    assert bad.tolist() == [False, True, False, True, True]
    sat = Simulator(TimeVaryingController(g, GAINS), SimulationOptions(steps=1, saturate=True))
    applied = np.array(sat.applied_torque(ca.DM([30.0, 30.0, -45.0, -10.0]))[0]).ravel()
    assert applied.tolist() == [20.0, 30.0, -40.0, -10.0]
    assert clip_torques(u, lim.torque_limit)[:, 4].tolist() == [-20.0, 0.0, 0.0, 0.0]


def test_the_gait_is_bounded_per_joint(knees):
    m, g = knees
    assert g.options.torque_limit == (20.0, 40.0, 40.0, 20.0)
    prob = build_problem(m, g.options)
    name, a, b = next(grp for grp in prob.groups if grp[0] == "torque limit")
    assert np.asarray(prob.ubg[a:b]).tolist()[:8] == [20.0, 40.0, 40.0, 20.0] * 2
    c = g.check()
    peaks = c["max_abs_torques"]
    assert max(peaks[1], peaks[2]) > 20.0                  # a hip beyond the smallest limit
    assert all(p <= u + 1e-6 for p, u in zip(peaks, g.options.torque_limit))
    assert g.violations() == []


def test_a_walk_is_held_to_each_joints_limit(knees, tmp_path):
    """The gait's hip torque (above 20 N m) walks on the robot of 40 N m hips; the same
    walk stops at its hip on a plant of 20 N m hips and 40 N m knees, and at its knee on
    one of 40 N m hips and 12 N m knees."""
    m, g = knees
    tv = TimeVaryingController(g, GAINS)
    ok = simulate(tv, options=SimulationOptions(steps=2))
    assert ok.status == "ok", ok.message
    assert ok.peak_torque > 20.0
    hips = simulate(tv, options=SimulationOptions(steps=2),
                    plant=_rabbit_with(tmp_path, "{ hip = 20.0, knee = 40.0 }", "hips20"))
    assert hips.status == "torque_limit", hips.message
    assert re.search(r"\|u[23]\| = \d+\.\d+ N m > its limit 20 N m", hips.message), hips.message
    knee = simulate(tv, options=SimulationOptions(steps=2),
                    plant=_rabbit_with(tmp_path, "{ hip = 40.0, knee = 12.0 }", "knees12"))
    assert knee.status == "torque_limit", knee.message
    assert re.search(r"\|u[14]\| = 1[23]\.\d+ N m > its limit 12 N m", knee.message), \
        knee.message


CC = find_c_compiler()


@pytest.mark.skipif(CC is None, reason="no C compiler (gcc, cc or $CC) on this machine")
def test_the_c_exports_clip_is_per_joint(knees, tmp_path):
    """At the gait's peak the stance hip's torque (above 20 N m) passes the export's clip
    unchanged; a knee's torque beyond 20 N m is clipped at 20."""
    m, g = knees
    tv = TimeVaryingController(g, GAINS)
    law = exported_law(tv, saturate=True)
    assert law.torque_limit == (20.0, 40.0, 40.0, 20.0)
    write_export(c_sources(law, {"gait file": "test"}), tmp_path / "c")
    lib = CompiledController(build_library(tmp_path / "c", tmp_path / "c.so"), tv)
    t = np.linspace(0.0, float(g.T), 41)
    q, dq = g.q(t[0]), g.dq(t[0])
    p = lib.step_start(q, dq).p
    seen = []
    for ti in t[:-1]:
        q, dq = g.q(ti), g.dq(ti)
        dq_off = np.array(dq).ravel() + np.array([0.0, 4.0, 0.0, 0.0, -4.0])
        rc, u = lib.torque(ti, q, dq_off, p)
        raw = np.array(tv.torque(q, dq_off, ti).u).ravel()
        assert rc == 0
        np.testing.assert_allclose(u, clip_torques(raw, law.torque_limit), rtol=1e-12,
                                   atol=1e-9)
        seen.append((raw, np.asarray(u)))
    assert any(abs(r[1]) > 20.0 and abs(c[1]) > 20.0 for r, c in seen)   # hip: not clipped
    assert any(abs(r[0]) > 20.0 and abs(c[0]) == 20.0 for r, c in seen)  # knee: clipped


def test_mujocos_motors_have_each_joints_range(knees):
    pytest.importorskip("mujoco")
    from biped_casadi.mujoco import mjcf
    m, _ = knees

    def ranges(text):
        return {n: [float(v) for v in r.split()] for n, r in
                re.findall(r'<motor name="(\w+)" joint="\w+" ctrlrange="([^"]+)"', text)}
    assert ranges(mjcf(m)) == {"hip_a": [-40.0, 40.0], "knee_a": [-20.0, 20.0],
                               "hip_b": [-40.0, 40.0], "knee_b": [-20.0, 20.0]}
    assert all(r == [-150.0, 150.0] for r in ranges(mjcf(robot("rabbit"))).values())


def test_a_mujoco_walk_counts_clipping_per_joint(knees):
    """The gait's hip torques (above 20 N m, within the hips' 40) are not clipped by the
    robot's own motors (the first step: nothing is; later steps clip torques beyond a
    joint's own limit, and apply more than 20 N m); with one limit of 20 N m for every
    motor they are."""
    pytest.importorskip("mujoco")
    from biped_casadi import Design
    from biped_casadi.mujoco import MujocoLoop
    m, g = knees
    loop = MujocoLoop(Design.vc(g))
    assert loop.torque_limit == (20.0, 40.0, 40.0, 20.0) and loop.driver == "python"
    own = loop.run(g.q(0.0), g.dq(0.0), 3)
    assert own.status == "walked", own.message
    first = own.steps[0]
    assert first.clipped_time == 0.0 and first.peak_applied == first.peak_commanded > 20.0
    assert all(20.0 < s.peak_applied <= 40.0 for s in own.steps)
    one = MujocoLoop(Design.vc(g), torque_limit=20.0).run(g.q(0.0), g.dq(0.0), 1)
    assert one.steps[0].clipped_time > 0.0 and one.steps[0].peak_applied == 20.0


def test_the_margins_take_each_joints_limit():
    """The simulator's margins |u_i| <= U_i, numerically and symbolically, and its screen:
    a torque of 30 N m is 10 N m inside a hip's 40 and 10 N m beyond a knee's 20."""
    from biped_casadi.simulation.kernel import Diagnostics
    from biped_casadi.simulation.margins import MarginCheck
    lim = Limits(mu=0.6, min_normal_force=0.0, hip_floor=0.45, max_torso_angle=1.5,
                 ground_tolerance=1e-9, singular_tolerance=0.01,
                 torque_limit=(20.0, 40.0, 40.0, 20.0), min_liftoff_speed=0.0)
    check = MarginCheck(lim, Diagnostics(4))
    u = np.array([30.0, 30.0, -30.0, 0.0])
    got = check.values(u, 0.0, 100.0)[3:]
    assert got.tolist() == [-10.0, 10.0, 70.0, 20.0, 50.0, 70.0, 10.0, 20.0]
    us = ca.SX.sym("u", 4)
    sym = ca.Function("m", [us], [check.values(us, 0.0, 100.0, lib=ca)])
    assert np.array(sym(u)).ravel()[3:].tolist() == got.tolist()
    R = np.array([[30.0, 30.0, -30.0, 0.0, 0.0, 100.0]]).T[:, :, None].repeat(3, axis=2)
    hips = R.copy()
    hips[0] = 0.0                                        # the knee's 30 N m taken away
    assert check.near(R).tolist() == [True] and check.near(hips).tolist() == [False]


def _codesign_rows(m, g, settings):
    """The reduced co-design NLP's rows on ``g`` (free), two scenarios of two steps, at a
    small M1: (names, g, lo, hi, transcription)."""
    from analysis.design.codesign import Reduced, Transcription
    dirs = np.array([np.ones(2 * m.nq), np.where(np.arange(2 * m.nq) % 3 == 0, -1.0, 1.0)])
    tr = Transcription(m, g, dirs, steps=2, free_gait=True, settings=settings)
    red = Reduced(tr)
    red.tols[:] = 10.0
    red.steps[:] = 2
    d = np.zeros(tr.n_design)
    d[tr.i_G] = tr.gait_vector(g)
    d[tr.i_M1], d[tr.i_rejoin], d[tr.i_s] = [0.0385, 0.6158, 0.4359, -0.6560], 0.75, 0.01
    _, _, val, _, lo, hi = red.evaluate(d)
    return np.array(red.names), val, lo, hi, tr


def test_the_codesign_bounds_each_torque_by_its_joints_limit(knees):
    """The co-design's torque rows (the gait's and the walked scenarios') take each
    joint's limit: the gait's hip torques (above 20 N m) meet them, and the scenarios'
    do not with one limit of 20 N m (the smallest) for every joint."""
    from analysis.design.codesign import TranscriptionSettings
    m, g = knees
    names, val, lo, hi, tr = _codesign_rows(m, g, TranscriptionSettings())
    assert tr.st.torque_limit == (20.0, 40.0, 40.0, 20.0)
    assert tr.st.torque_margin == 0.02 * 20.0              # one margin: the smallest's
    gait = names == "gait torque limit"
    assert hi[gait].tolist()[:8] == [20.0, 40.0, 40.0, 20.0] * 2
    assert np.all((lo[gait] <= val[gait]) & (val[gait] <= hi[gait]))
    path = np.char.startswith(names.astype(str), "torque ")
    assert path.any() and np.all(val[path] <= hi[path])     # KS rows: <= 0
    names1, val1, _, hi1, _ = _codesign_rows(m, g, TranscriptionSettings(torque_limit=20.0))
    path1 = np.char.startswith(names1.astype(str), "torque ")
    assert np.any(val1[path1] > hi1[path1])


def test_the_codesign_takes_a_robot_whose_joints_limits_differ(knees, monkeypatch):
    """`codesign` runs such a robot (it refused it) and its method holds the NLP to each
    joint's limit, or to the verification's one limit where it gives one."""
    from analysis.design.codesign import CodesignSettings, Verification, api
    from analysis.design.codesign.method import Method
    m, g = knees

    class Started(Exception):
        pass

    def engine(*args, **kwargs):
        raise Started
    monkeypatch.setattr(api, "Engine", engine)
    with pytest.raises(Started):
        api.codesign(m, CodesignSettings())
    with pytest.raises(Started):
        api.codesign(g)
    assert Method(None, m, CodesignSettings()).tst.torque_limit == (20.0, 40.0, 40.0, 20.0)
    one = CodesignSettings(verification=Verification(torque_limit=30.0))
    assert Method(None, m, one).tst.torque_limit == 30.0


def test_a_gait_moved_for_the_codesign_keeps_each_joint_within_its_fraction(knees):
    """The co-design's move of a given gait takes each joint's torque to within 0.8 of
    its own limit (16 N m at the knees, 32 at the hips; the gait's hip torque is above
    16), and says so per torque."""
    from analysis.design import ROBUST_GAIT
    from analysis.design.codesign import MoveSettings, TranscriptionSettings, move_gait
    from analysis.design.codesign.gait_move import own_values
    m, g = knees
    mv = move_gait(g, dict(ROBUST_GAIT), MoveSettings(), TranscriptionSettings())
    assert mv.status == "moved", mv.message
    assert mv.targets["torque_limit"] == (16.0, 32.0, 32.0, 16.0)
    peaks = own_values(mv.gait)["torque_limit"]
    assert max(peaks[1], peaks[2]) > 16.0
    assert all(p <= u for p, u in zip(peaks, mv.targets["torque_limit"]))
    assert mv.gait.violations() == []
    assert "torques <= 16/32/32/16 N m" in mv.message


def test_no_torque_limit_is_said_in_words_not_as_inf():
    """A robot without a torque limit (an infinite one) is 'no torque limit' where a limit
    is printed, not 'inf N m': the bound's text, the gait optimiser's words, and the
    co-design's gait move ('torques <= inf N m (given 30.72)' before)."""
    import math
    from analysis.design.codesign.gait_move import _Move
    from biped_casadi.model.torque_limits import torque_bound_text, torque_limit_words
    assert torque_bound_text(math.inf) == "none"
    assert torque_bound_text((math.inf, 150.0)) == "none/150"
    assert torque_bound_text(np.float64(150.0)) == "150"
    assert torque_limit_words(math.inf) == "no torque limit"
    assert torque_limit_words((math.inf,) * 4) == "no torque limit"
    assert torque_limit_words((20.0, 40.0, 40.0, 20.0)) == "torque limit 20/40/40/20 N m"
    mv = _Move.__new__(_Move)                       # the message of a move, no solve
    mv.own = dict(impact_mu=0.5, clearance=0.01, mu=0.5, torque_limit=30.72)
    mv.start = dict(impact_mu=0.5, clearance=0.01, mu=0.5, torque_limit=math.inf)
    mv.tgt = dict(impact_mu=0.4, clearance=0.02, mu=0.4, torque_limit=math.inf)
    mv.records = [{}]
    change = dict(T=(0.4, 0.41), step_length=(0.3, 0.31), max_joint_change=0.01)
    said = mv.message(1.0, change)
    assert "no torque limit (largest 30.72 N m)" in said and "inf" not in said, said
    mv.start["torque_limit"], mv.tgt["torque_limit"] = 40.0, 24.0
    assert "torques <= 24 N m (given 30.72)" in mv.message(1.0, change)


def test_a_speed_profiles_torque_margin_takes_each_joints_limit(knees):
    """A speed profile's per-step ``torque_margin`` on a robot whose joints' limits differ
    is the smallest over the torques of (U_i - the step's largest |u_i|) (NaN before): a
    hip at 30.7 N m of 40 and knees at about 13 N m of 20 leave a positive margin, where
    the smallest limit against the largest torque would be negative; with one limit it
    is the limit minus the step's peak torque, exactly."""
    from biped_casadi.simulation import simulate_profile
    m, g = knees
    c = TimeVaryingController(g, GAINS)
    prof = simulate_profile([c] * 2)
    U = np.array(m.description.torque_bound, float)
    assert len(set(U)) == 2
    for step, run in zip(prof.steps, prof.runs):
        assert step.status == "ok"
        peaks = np.max(np.abs(run.u), axis=0)
        assert np.max(peaks) == step.peak_torque
        assert step.torque_margin == np.min(U - peaks)
        assert 0 < step.torque_margin < np.min(U) and np.min(U) - step.peak_torque < 0
    one = simulate_profile([TimeVaryingController(g, GAINS)],
                           options=SimulationOptions(torque_limit=50.0))
    assert one.steps[0].torque_margin == 50.0 - one.steps[0].peak_torque
