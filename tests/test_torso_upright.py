"""A torso whose centre of mass hangs below the hip: the model's torso (its up direction
toward the centre of mass) points down when the robot stands upright, so its
description's ``torso_upright`` (pi or -pi) says where upright is, and every judgement of
the torso's posture (the simulators' fall checks, MuJoCo's walk in Python and in C, a
gait's lean, the gait problem's start) takes the lean wrap(phi - torso_upright).  The
field round-trips through TOML, is written only when not 0 (RABBIT's file and cache key
are unchanged), is validated, and the URDF import sets it."""
from __future__ import annotations

import dataclasses
import math
import tomllib
from pathlib import Path

import numpy as np
import pytest

from analysis.cli import main
from analysis.gait_metrics import torso_fall
from biped_casadi import Design, SimulationOptions, robot, simulate
from biped_casadi.model.description import (builtin_path, description_from_dict,
                                            description_toml, load_description, torso_lean)
from biped_casadi.model.urdf import import_urdf
from biped_casadi.simulation.validity import Limits, node_message, node_violations

ROBOTS = Path(builtin_path("rabbit")).parent


def _low_urdf(tmp_path) -> Path:
    """RABBIT's URDF with the torso's centre of mass 5 cm below the hip."""
    text = (ROBOTS / "rabbit.urdf").read_text().replace(
        '<origin xyz="0 0 0.24" rpy="0 0 0"/>', '<origin xyz="0 0 -0.05" rpy="0 0 0"/>', 1)
    p = tmp_path / "low.urdf"
    p.write_text(text)
    return p


@pytest.fixture(scope="module")
def low(tmp_path_factory):
    """The low-torso RABBIT, read from its URDF."""
    return robot(_low_urdf(tmp_path_factory.mktemp("low")))


def _tilted(q, lean):
    """q with the torso alone turned by ``lean`` (the stance hip q3 up, the swing hip
    q4 down: the legs keep their absolute angles)."""
    q = np.array(q, float)
    q[2] += lean
    q[3] -= lean
    return q


def test_urdf_import_sets_torso_upright(tmp_path, low):
    """A torso hanging below the hip stands upright at pitch 0, the model angle
    pitch_offset (-pi, wrapped as the joint map wraps it), said in the notes; RABBIT's own
    URDF (centre of mass above the hip) keeps 0 and no key in its file."""
    imp = import_urdf(_low_urdf(tmp_path))
    d = imp.description
    assert d.torso_upright == d.urdf.pitch_offset == -math.pi
    assert any("torso_upright" in n for n in imp.notes), imp.notes
    assert low.description.torso_upright == -math.pi
    rabbit_urdf = import_urdf(ROBOTS / "rabbit.urdf").description
    assert rabbit_urdf.torso_upright == 0.0 and "torso_upright" not in rabbit_urdf.to_dict()
    out = tmp_path / "low.toml"
    assert main(["robot", "import", str(_low_urdf(tmp_path)), "--out", str(out)]) == 0
    assert tomllib.loads(out.read_text())["torso_upright"] == -math.pi
    assert load_description(out).torso_upright == -math.pi


def test_torso_upright_round_trip_and_cache_key(tmp_path):
    """Written to TOML and gait records only when not 0: RABBIT's file, record and cache
    key are as before; a set value reads back exactly and joins the cache key (not the
    comparison: it changes no dynamics)."""
    rabbit = robot("rabbit").description
    assert rabbit.torso_upright == 0.0
    assert "torso_upright" not in description_toml(rabbit)
    assert "torso_upright" not in rabbit.to_dict()
    assert len(rabbit.cache_key) == 7
    flipped = dataclasses.replace(rabbit, torso_upright=math.pi)
    p = tmp_path / "flipped.toml"
    p.write_text(description_toml(flipped))
    back = load_description(p)
    assert back.torso_upright == math.pi and back == flipped
    assert back.cache_key == flipped.cache_key != rabbit.cache_key
    assert description_from_dict(flipped.to_dict()).torso_upright == math.pi
    assert flipped.scaled(mass=1.1).torso_upright == math.pi        # a plant keeps it


@pytest.mark.parametrize("value, text", [
    ('"pi"', "torso_upright must be a number"),
    ("nan", "torso_upright must be finite"),
    ("inf", "torso_upright must be finite"),
    ("180.0", "torso_upright must be an angle in rad within [-2 pi, 2 pi]"),
])
def test_torso_upright_is_validated(tmp_path, capsys, value, text):
    """A hand-made description with a torso_upright that is not a finite angle in rad
    is refused in one line naming the file and the field (a command: exit 2)."""
    body = description_toml(robot("rabbit").description).replace(
        "gravity = 9.81\n", f"gravity = 9.81\ntorso_upright = {value}\n", 1)
    p = tmp_path / "bad.toml"
    p.write_text(body)
    with pytest.raises(ValueError, match=r"bad\.toml") as e:
        load_description(p)
    assert text in str(e.value) and "\n" not in str(e.value)
    assert main(["model", "--robot", str(p), "--json"]) == 2
    err = capsys.readouterr().err.strip()
    assert text in err and len(err.splitlines()) == 1


def test_lean_wraps_from_upright():
    """wrap(phi - upright) in [-pi, pi); phi itself (the same object) when upright is 0."""
    phi = np.array([-math.pi, math.pi, -math.pi + 0.2, math.pi - 0.2, 0.0, 1.6])
    lean = torso_lean(phi, -math.pi)
    assert np.allclose(lean, [0.0, 0.0, 0.2, -0.2, -math.pi, 1.6 - math.pi], atol=1e-15)
    assert torso_lean(phi, 0.0) is phi
    assert float(torso_lean(math.pi, 0.0)) == math.pi


def test_validity_judges_the_lean_from_upright(low):
    """The simulators' fall check on a torso hanging below the hip: standing upright
    (phi = -pi or, the same, +pi) and leaning 1.4 rad either way is not a fall; leaning
    1.7 rad, or the model's phi = 0 (the torso lying upside down), is.  The message gives
    the lean.  With upright 0 the judgement is the torso angle's, as before."""
    lim = Limits.of(SimulationOptions(), low)
    assert lim.torso_upright == -math.pi
    phi = np.array([-math.pi, math.pi, -math.pi + 1.4, math.pi - 1.4,
                    -math.pi + 1.7, math.pi - 1.7, 0.0])
    n = phi.size
    rows = dict(finite=np.ones(n, bool), den=np.full(n, 5.0), Fx=np.full(n, 10.0),
                Fz=np.full(n, 300.0), in_range=np.ones(n), xsw=np.full(n, 0.2),
                zsw=np.full(n, 0.05), hip=np.full(n, 0.78), torso=phi,
                u=np.full((4, n), 10.0))
    fell = node_violations(rows, lim, 5.0, 1.0)["fell"]
    assert fell.tolist() == [False, False, False, False, True, True, True]
    msg = node_message("fell", {k: v[..., 4] for k, v in rows.items()}, lim, 5.0)
    assert "lean 1.7000 rad from upright" in msg, msg
    upright0 = dataclasses.replace(lim, torso_upright=0.0)
    assert node_violations(rows, upright0, 5.0, 1.0)["fell"].tolist() == \
        [True, True, True, True, False, False, False]


@pytest.fixture(scope="module")
def low_gait(low):
    """The low-torso RABBIT's optimal gait at 0.3 m/s (its torso stays up; at 0.75 m/s
    the optimum lays it past horizontal, a fall the checks now name rightly)."""
    from gait_opt import optimize_gait
    return optimize_gait(low, speed=0.3, cache=True)


def test_low_torso_gait_walks_in_the_simulator_and_mujoco(low, low_gait):
    """End to end on the low-torso RABBIT: the gait problem starts the torso upright and
    finds a gait whose torso stays within 0.5 rad of upright (not a fall); the full-order
    simulator and MuJoCo (its steps driven in C and in Python, bit for bit the same) walk
    it; the same start with the torso turned 1.7 rad from upright is a fall at once in
    both."""
    pytest.importorskip("mujoco")
    from biped_casadi.mujoco import MujocoLoop
    from biped_casadi.mujoco.cloop import walk_differences
    g = low_gait
    lean, past, bound = torso_fall(g)
    assert lean < 0.5 and not past, lean
    phi = np.array([float(low.torso_angle(g.q(t))) for t in np.linspace(0, g.T, 21)])
    assert np.all(np.abs(np.abs(phi) - math.pi) < 0.5), phi
    design = Design.vc(g)
    q0, dq0 = np.asarray(g.q(0.0)).ravel(), np.asarray(g.dq(0.0)).ravel()
    assert simulate(design, options=SimulationOptions(steps=3)).status == "ok"
    falls = simulate(design, _tilted(q0, 1.7), dq0, SimulationOptions(steps=3))
    assert falls.status == "fell" and falls.failure_time == 0.0 and "from upright" in \
        falls.message, falls.message
    loops = [MujocoLoop(design, driver=d) for d in ("c", "python")]
    assert [lp.driver for lp in loops] == ["c", "python"]
    walks = [lp.run(q0, dq0, 3) for lp in loops]
    assert walks[0].status == "walked" and len(walks[0].steps) == 3, walks[0].message
    assert walk_differences(*walks) == []
    tipped = [lp.run(_tilted(q0, 1.7), dq0, 3) for lp in loops]
    assert tipped[0].status == "fell" and "from upright" in tipped[0].message, \
        tipped[0].message
    assert walk_differences(*tipped) == []


def test_low_torso_hips_are_taken_about_upright(tmp_path, low, low_gait):
    """The hips of a hanging torso sit near +-pi (the upright pose q = (0, 0, -pi, pi, 0)):
    the gait problem bounds them within pi of it, not of 0 (which held the torso on one
    side of the stance leg); URDF angles convert to q within pi of it, so a step written in
    URDF angles reads back as the same orbit (not 2 pi off at the impact), and the law
    exported in URDF angles sees the same q as the toolkit's."""
    from biped_casadi.control.export_urdf import UrdfAngleLaw
    from gait_opt import GaitOptions
    from gait_opt.transcription import _layout, _variable_bounds
    from gait_opt import import_gait
    from gait_opt.urdf_angles import write_gait_csv
    up = low.description.upright_q
    assert up == (0.0, 0.0, -math.pi, math.pi, 0.0)
    assert robot("rabbit").description.upright_q == (0.0,) * 5
    opts = GaitOptions(speed=0.3)
    lbx, ubx = _variable_bounds(low, opts, _layout(opts, low.nu))
    lay = _layout(opts, low.nu)
    a_lb = lbx[lay.off_a:lay.off_a + lay.na].reshape(low.nu, -1, order="F")
    a_ub = ubx[lay.off_a:lay.off_a + lay.na].reshape(low.nu, -1, order="F")
    assert np.allclose(a_lb[1:3, 0], [-2 * math.pi, 0.0]) and \
        np.allclose(a_ub[1:3, 0], [0.0, 2 * math.pi])
    csv = write_gait_csv(low_gait, tmp_path / "step.csv", angles="urdf", stance="hip_left")
    back = import_gait(low, csv, angles="urdf", stance="hip_left").gait
    t = np.linspace(0, low_gait.T, 7)
    assert np.max(np.abs(back.q(t) - low_gait.q(t))) < 1e-6
    x, dx = low.description.urdf.from_model(low_gait.q(0.0), low_gait.dq(0.0), "hip_left")
    law = UrdfAngleLaw(Design.vc(low_gait).controller_for(), low.description.urdf)
    q, _ = low.description.urdf.to_model(x, dx, "hip_left", centre=law.centre)
    assert np.allclose(q, low_gait.q(0.0), atol=1e-12)
