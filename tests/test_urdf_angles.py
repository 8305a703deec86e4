"""The robot's own URDF joint angles end to end.

- The walker of docs/howto/walker (RABBIT written with continuous joints, no limits, the
  legs along +z of the torso frame at zero, a floating base, meshes, an IMU frame)
  imports to RABBIT: with a torque limit of 150 N m its description equals RABBIT's to
  1e-12, and its joint map puts the hips at -pi.
- Its step in its own joint angles (walker_step.csv) imports and polishes to an orbit
  whose eigenvalues (time-varying and virtual-constraint maps) equal those of the same
  nodes converted by hand to the toolkit's coordinates.
- A gait written in URDF angles (``biped gait --export-csv --angles urdf``, the other
  leg in stance; and for a URDF with turned zero pose and flipped axes) imports back to
  the same orbit: residual <= 1e-10, eigenvalues to 1e-8.
- The exported law in URDF angles equals the toolkit's law to 1e-12 at 10,000 random
  states with random stance legs (and finds the stance leg at every step start), and
  the closed loop it drives equals ``biped simulate``'s.
- Bad input: one line, exit 2, nothing written.
"""
from __future__ import annotations

import json
import math
import shutil
from pathlib import Path

import numpy as np
import pytest
from urdf_variants import variant_urdf

from analysis import poincare_eigenvalues, vc_eigenvalue
from analysis.cli import main
from analysis import verify_export
from analysis.verify_export import compare_simulations, compare_urdf_states
from biped_casadi import (SimulationOptions, TimeVaryingController,
                          VirtualConstraintController, robot)
from biped_casadi.control.compiled import CompiledUrdfController, build_library
from biped_casadi.control.export import c_sources, exported_law
from biped_casadi.control.export_folder import write_export
from biped_casadi.model.description import builtin_path, load_description
from biped_casadi.model.urdf import import_urdf
from gait_opt import Gait, Nodes, import_gait
from gait_opt.urdf_angles import write_gait_csv
from gait_opt.nodes import check_units

WALKER = Path(__file__).resolve().parents[1] / "docs" / "howto" / "walker"
URDF, CSV = WALKER / "walker.urdf", WALKER / "walker_step.csv"
M1 = np.array([0.2, -0.3, 0.1, 0.0])


@pytest.fixture(scope="module")
def walker():
    return robot(URDF)


@pytest.fixture(scope="module")
def walker_gait(walker):
    r = import_gait(walker, CSV, angles="urdf", stance="hip_left")
    assert r.orbit_residual_after <= 1e-10
    return r.gait


def eigenvalues(g):
    tv, vc = poincare_eigenvalues(g, M1), vc_eigenvalue(g)
    assert tv.fixed_point_residual <= 1e-8
    return np.sort_complex(tv.eigenvalues), vc.eigenvalue


def test_the_walker_is_rabbit(tmp_path, capsys):
    rabbit = robot("rabbit").description
    imp = import_urdf(URDF)
    assert imp.description.torque_limit == math.inf
    assert any("no torque limit" in n for n in imp.notes)
    d = import_urdf(URDF, torque_limit=150.0).description
    a, b = d.to_dict(), rabbit.to_dict()
    a.pop("urdf")
    flat = lambda t: {k: v for k, v in t.items() if isinstance(v, float)}  # noqa: E731
    for key in ("actuators", "torso"):
        assert flat(a[key]) == pytest.approx(flat(b[key]), abs=1e-12)
    for x, y in zip(a["leg"], b["leg"]):
        assert flat(x) == pytest.approx(flat(y), abs=1e-12)
    assert d == rabbit                        # names and every number
    offsets = {j.name: (j.sign, j.offset) for j in d.urdf.joints}
    assert offsets == {"hip_left": (1.0, -math.pi), "knee_left": (1.0, 0.0),
                       "hip_right": (1.0, -math.pi), "knee_right": (1.0, 0.0)}
    # the command prints the map and writes it; the file reads back to the same robot
    out = tmp_path / "walker.toml"
    assert main(["robot", "import", str(URDF), "--torque-limit", "150", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "hip_left: leg 1 hip, model angle = theta - 3.14159265359 rad" in text
    back = load_description(out)
    assert back == rabbit and back.urdf == d.urdf
    # without a limit the file says inf, and reads back the same
    assert main(["robot", "import", str(URDF), "--out", str(out)]) == 0
    assert "torque_limit = inf" in out.read_text()
    assert load_description(out).torque_limit == math.inf


def test_the_walkers_step_is_the_same_gait_in_toolkit_coordinates(walker_gait, model):
    """The CSV's nodes converted by hand (the walker's hip is the model's plus pi, the
    model reads the stance leg from the foot up) import to the same eigenvalues."""
    a = np.genfromtxt(CSV, delimiter=",", names=True)
    q3, q2 = np.pi - a["hip_left"], -a["knee_left"]
    q = np.vstack([a["pitch"] - q2 - q3, q2, q3, a["hip_right"] - np.pi, a["knee_right"]])
    dq3, dq2 = -a["dhip_left"], -a["dknee_left"]
    dq = np.vstack([a["dpitch"] - dq2 - dq3, dq2, dq3, a["dhip_right"], a["dknee_right"]])
    toolkit = import_gait(model, Nodes(a["t"], q, dq)).gait
    (ev_w, vc_w), (ev_t, vc_t) = eigenvalues(walker_gait), eigenvalues(toolkit)
    assert np.max(np.abs(ev_w - ev_t)) <= 1e-8 and abs(vc_w - vc_t) <= 1e-8
    assert walker_gait.T == pytest.approx(toolkit.T, abs=1e-12)


def test_cli_export_csv_and_import_back(walker_gait, tmp_path, capsys):
    g = tmp_path / "walker_gait.json"
    assert main(["gait", "--import", str(CSV), "--robot", str(URDF), "--angles", "urdf",
                 "--stance", "hip_left", "--out", str(g)]) == 0
    back = tmp_path / "back.csv"
    assert main(["gait", "--export-csv", str(back), "--gait", str(g), "--angles", "urdf",
                 "--stance", "hip_right", "--nodes", "61"]) == 0
    head = back.read_text().splitlines()[0].split(",")
    assert head[:6] == ["t", "pitch", "hip_left", "knee_left", "hip_right", "knee_right"]
    assert head[-4:] == ["x", "z", "dx", "dz"]
    g2 = tmp_path / "again.json"
    assert main(["gait", "--import", str(back), "--angles", "urdf", "--stance", "hip_right",
                 "--robot", str(URDF), "--out", str(g2), "--json"]) == 0
    capsys.readouterr()
    a, b = Gait.load(g), Gait.load(g2)
    assert b.orbit_residual()["worst"] <= 1e-10
    (ev_a, vc_a), (ev_b, vc_b) = eigenvalues(a), eigenvalues(b)
    assert np.max(np.abs(ev_a - ev_b)) <= 1e-8 and abs(vc_a - vc_b) <= 1e-8
    assert b.model.description.urdf == a.model.description.urdf


def test_round_trip_through_a_turned_and_flipped_urdf(gait, tmp_path):
    """RABBIT's default gait, read for a URDF whose zero pose is turned per joint and
    whose right leg turns about -y, written in its angles and imported back."""
    d = robot("rabbit").description
    path = tmp_path / "turned.urdf"
    path.write_text(variant_urdf(d, beta={("left", 0): 2.0, ("left", 1): -0.7,
                                          ("right", 0): -math.pi / 2 + 0.1},
                                 roll={("right", 1): True}, torso_tilt=0.4,
                                 axis={("right", 0): -1, ("right", 1): -1}))
    turned = robot(path)
    saved = gait.save(tmp_path / "default.json")
    g = Gait.load(saved, model=turned)
    csv = write_gait_csv(g, tmp_path / "turned.csv", "urdf", stance="femur_right_joint")
    r = import_gait(turned, csv, angles="urdf", stance="femur_right_joint")
    assert r.info["stance_foot_spread"] <= 1e-12
    assert r.orbit_residual_after <= 1e-10
    (ev_a, vc_a), (ev_b, vc_b) = eigenvalues(gait), eigenvalues(r.gait)
    assert np.max(np.abs(ev_a - ev_b)) <= 1e-8 and abs(vc_a - vc_b) <= 1e-8


@pytest.fixture(scope="module")
def urdf_library(walker_gait, tmp_path_factory):
    """The walker's virtual-constraint law exported in URDF angles (motor side), built."""
    ctrl = VirtualConstraintController(walker_gait)
    law = exported_law(ctrl, angles="urdf", motor_side=True)
    folder = tmp_path_factory.mktemp("urdf_export") / "ctrl"
    write_export(c_sources(law, {"gait file": "walker"}), folder)
    return ctrl, law, folder, CompiledUrdfController(build_library(folder), ctrl, law.urdf,
                                                      True)


def test_urdf_law_equals_the_toolkits_law(urdf_library):
    ctrl, law, folder, lib = urdf_library
    r = compare_urdf_states(lib, ctrl, n=10_000, seed=4)
    assert r.success, r.message
    assert r.max_torque_rel <= 1e-12 and r.stance_found == 10_000
    header = (folder / "biped_controller.h").read_text()
    words = " ".join(w for w in header.split() if w != "*")       # the comment's text
    assert "q[1] hip_left, q[2] knee_left, q[3] hip_right, q[4] knee_right" in words
    assert "int biped_step_start_leg(int stance" in header
    assert "knee_right 50" in (folder / "README.md").read_text()       # the reductions


def test_urdf_step_starts_both_laws_refuse_are_counted(urdf_library, monkeypatch):
    """The URDF comparison called the Python law with the NaN state of a start whose
    phase moves backwards (ValueError: p must be finite); both laws refuse it."""
    ctrl, law, folder, lib = urdf_library
    draw = verify_export._random_states
    monkeypatch.setattr(verify_export, "_random_states",
                        lambda c, n, rng: draw(c, n, rng, dq_err=2.0))
    r = compare_urdf_states(lib, ctrl, n=300, seed=4)
    assert r.success, r.message
    assert r.starts_refused > 0 and r.starts_disagree == 0
    assert r.stance_found == 300 - r.starts_refused


def test_closed_loop_driven_by_the_urdf_law_is_biped_simulate(urdf_library, walker_gait):
    ctrl, _, _, lib = urdf_library
    q0, dq0 = walker_gait.q(0.0) + 0.01, walker_gait.dq(0.0) + 0.1     # the paper's size
    r = compare_simulations(lib, ctrl, q0, dq0, SimulationOptions(steps=6))
    assert r.success and r.steps == 6, r.message
    assert r.max_state <= 1e-9 and r.twin_max_state <= 1e-9


def test_the_python_law_in_urdf_angles_repeats_the_librarys_run(urdf_library, walker_gait):
    """The twin of an export in URDF angles takes the library's path (the conversions
    inside the law): its run repeats the library's to round-off, while the toolkit's law
    at the model's state, without the conversions' round-off, parts from it by what the
    closed loop grows that to (above 1e-9 on a small robot, ODRI's Bolt)."""
    ctrl, law, _, lib = urdf_library
    q0, dq0 = walker_gait.q(0.0) + 0.01, walker_gait.dq(0.0) + 0.1
    opts = SimulationOptions(steps=6)
    r = compare_simulations(lib, ctrl, q0, dq0, opts, law)
    assert r.success and r.steps == 6, r.message
    assert r.twin_max_state <= 1e-13 and r.twin_max_impact_time <= 1e-13, r.message
    toolkit = compare_simulations(lib, ctrl, q0, dq0, opts)
    assert toolkit.twin_max_state > 100 * max(r.twin_max_state, 1e-16), toolkit.message


def test_tv_law_in_urdf_angles(walker_gait, tmp_path):
    ctrl = TimeVaryingController(walker_gait, M1)
    law = exported_law(ctrl, angles="urdf")
    write_export(c_sources(law), tmp_path / "tv")
    lib = CompiledUrdfController(build_library(tmp_path / "tv"), ctrl, law.urdf)
    r = compare_urdf_states(lib, ctrl, n=500, seed=1)
    assert r.success and r.max_torque_rel <= 1e-12, r.message
    q0, dq0 = walker_gait.q(0.0) + 0.01, walker_gait.dq(0.0) + 0.1
    s = compare_simulations(lib, ctrl, q0, dq0, SimulationOptions(steps=3), law)
    assert s.steps >= 1 and s.twin_max_state <= 1e-13, s.message   # the reference's table


def test_a_saturating_law_in_urdf_angles_clips_the_joints_torques(walker_gait, tmp_path):
    """``--saturate`` with ``--angles urdf --motor-side``: the model's torques are clipped
    before the mapping (the motor side divides them by the reductions after), in C as in
    the Python law; unclipped, the comparison fails (the clip is active)."""
    ctrl = TimeVaryingController(walker_gait, M1)
    ref = ctrl.reference
    p = ctrl.step_start(ref.q(0.0), ref.dq(0.0)).p
    peak = max(np.max(np.abs(ctrl.torque(ref.q(t), ref.dq(t), t, p[:ctrl.model.nu],
                                         p[ctrl.model.nu:]).u)) for t in (0.2, 0.5, 0.8))
    limit = 0.5 * float(peak)
    law = exported_law(ctrl, angles="urdf", motor_side=True, saturate=True,
                       torque_limit=limit)
    write_export(c_sources(law), tmp_path / "sat")
    lib = CompiledUrdfController(build_library(tmp_path / "sat"), ctrl, law.urdf, True)
    r = compare_urdf_states(lib, ctrl, n=500, seed=1, torque_limit=limit)
    assert r.success and r.max_torque_rel <= 1e-12, r.message
    assert not compare_urdf_states(lib, ctrl, n=500, seed=1).success


# ------------------------------------------------------------------ bad input
def _bad_csv(tmp_path, edit):
    text = CSV.read_text()
    p = tmp_path / "bad.csv"
    p.write_text(edit(text))
    return p


@pytest.mark.parametrize("case", ["no header", "unknown stance", "knee as stance", "no stance",
                                  "missing column", "other stance", "legs-down convention",
                                  "knees the other way", "no map", "stance without urdf"])
def test_bad_import_is_one_line_exit_2(case, tmp_path, capsys):
    src, robot_arg, extra = CSV, str(URDF), ["--angles", "urdf", "--stance", "hip_left"]
    message = {"no header": "no header line: line 1 holds numbers, not the column names "
                            "(t, pitch, the joints hip_left, knee_left, hip_right, knee_right",
               "unknown stance": "--stance: the URDF has no leg joint 'hip_middle'",
               "knee as stance": "--stance: 'knee_left' is not a hip joint",
               "no stance": "--angles urdf needs --stance HIP_JOINT",
               "missing column": "missing column(s) dknee_right",
               "other stance": "say the stance foot (leg of hip_right) moves by",
               "legs-down convention": "angles in another convention",
               "knees the other way": "not an orbit of RABBIT: the fitted gait misses",
               "no map": "--angles urdf: the robot RABBIT has no URDF joint map",
               "stance without urdf": "--stance names the stance leg of --angles urdf"}[case]
    if case == "no header":
        src = _bad_csv(tmp_path, lambda s: s.split("\n", 1)[1])
    elif case == "unknown stance":
        extra[-1] = "hip_middle"
    elif case == "knee as stance":
        extra[-1] = "knee_left"
    elif case == "no stance":
        extra = extra[:2]
    elif case == "missing column":
        src = _bad_csv(tmp_path, lambda s: "\n".join(",".join(r.split(",")[:10])
                                                     for r in s.splitlines()))
    elif case == "other stance":
        extra[-1] = "hip_right"
    elif case == "legs-down convention":    # the walker's angles read as RABBIT's zero pose
        src = _bad_csv(tmp_path, lambda s: "\n".join(",".join(r.split(",")[:11])
                                                     for r in s.splitlines()))
        robot_arg = str(builtin_path("rabbit").with_suffix(".urdf"))
    elif case == "knees the other way":     # a knee axis read as -y: no base columns
        def flip(text):
            rows = [r.split(",")[:11] for r in text.splitlines()]
            knees = [i for i, h in enumerate(rows[0]) if "knee" in h]
            for r in rows[1:]:
                for i in knees:
                    r[i] = repr(-float(r[i]))
            return "\n".join(",".join(r) for r in rows)
        src = _bad_csv(tmp_path, flip)
    elif case == "no map":
        robot_arg = "rabbit"
    elif case == "stance without urdf":
        extra = ["--stance", "hip_left"]
    out = tmp_path / "gait.json"
    assert main(["gait", "--import", str(src), "--robot", robot_arg, *extra,
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1, err
    assert not out.exists()


def test_bad_export_is_one_line_exit_2(gait, walker_gait, tmp_path, capsys):
    g = walker_gait.save(tmp_path / "walker.json")
    plain = gait.save(tmp_path / "plain.json")
    cases = [
        (["gait", "--export-csv", str(tmp_path / "x.csv"), "--gait", str(plain), "--angles",
          "urdf"], "--angles urdf: the robot RABBIT has no URDF joint map", "x.csv"),
        (["gait", "--export-csv", str(tmp_path / "x.csv"), "--gait", str(g), "--angles",
          "urdf", "--stance", "tibia"], "--stance: the URDF has no leg joint 'tibia'", "x.csv"),
        (["export", "--gait", str(plain), "--controller", "vc", "--angles", "urdf", "--out",
          str(tmp_path / "ctrl")], "--angles urdf: the robot RABBIT has no URDF joint map",
         "ctrl"),
        (["export", "--gait", str(g), "--controller", "vc", "--motor-side", "--out",
          str(tmp_path / "ctrl")], "--motor-side divides", "ctrl"),
    ]
    for argv, message, written in cases:
        assert main(argv) == 2
        err = capsys.readouterr().err.strip()
        assert message in err and len(err.splitlines()) == 1, err
        assert not (tmp_path / written).exists()
    # the export in URDF angles of a gait with a map works from the command line
    out = tmp_path / "ok"
    assert main(["export", "--gait", str(g), "--controller", "vc", "--angles", "urdf",
                 "--out", str(out), "--json"]) == 0
    body = json.loads(capsys.readouterr().out)
    assert body["inputs"] == ["pitch", "hip_left", "knee_left", "hip_right", "knee_right"]
    shutil.rmtree(out)


def test_a_urdf_without_torque_limits_takes_the_commands_limit_for_its_default_gait(capsys):
    """The walker URDF has no effort limits: a command's --torque-limit also bounds the
    default gait it solves; without it, one line says what to give (--torque-limit, or a
    gait file for a command without the option)."""
    assert main(["simulate", "--robot", str(URDF), "--torque-limit", "150",
                 "--controller", "vc", "--steps", "2"]) == 0
    capsys.readouterr()
    assert main(["simulate", "--robot", str(URDF), "--controller", "vc", "--steps", "2"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.rstrip().endswith("give --torque-limit N")
    assert main(["eig", "--robot", str(URDF), "--controller", "vc"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--gait FILE, made by 'biped gait --robot" in err


def test_mujoco_motors_take_the_limit_the_gait_was_made_for(tmp_path, capsys):
    """The walker URDF has no effort limits: MuJoCo's motors default to the limit its gait
    was optimised for (150 N m here), not to a refusal."""
    pytest.importorskip("mujoco")
    gait = tmp_path / "walker_gait.json"
    assert main(["gait", "--robot", str(URDF), "--torque-limit", "150", "--out",
                 str(gait)]) == 0
    capsys.readouterr()
    assert main(["mujoco", "--gait", str(gait), "--controller", "vc", "--steps", "2",
                 "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["torque_limit"] == 150.0


# ------------------------------------------------------------------ files as tools write them
def test_files_with_a_byte_order_mark_read_as_without(tmp_path, capsys):
    """Excel's 'CSV UTF-8' (and Notepad) start a file with a byte order mark: the step,
    a description file and a gait file read as the same text without it."""
    bom = "\ufeff"
    src = tmp_path / "step.csv"
    src.write_text(bom + CSV.read_text(), encoding="utf-8")
    out = tmp_path / "gait.json"
    assert main(["gait", "--import", str(src), "--robot", str(URDF), "--angles", "urdf",
                 "--stance", "hip_left", "--out", str(out)]) == 0, capsys.readouterr().err
    toml = tmp_path / "rabbit.toml"
    toml.write_text(bom + builtin_path("rabbit").read_text(), encoding="utf-8")
    assert load_description(toml) == robot("rabbit").description
    again = tmp_path / "again.json"
    again.write_text(bom + out.read_text(), encoding="utf-8")
    assert Gait.load(again).T == Gait.load(out).T


def test_a_step_saved_as_utf16_reads_and_latin1_is_named(tmp_path, capsys):
    """Excel's "Unicode text" is UTF-16 with a byte order mark: it reads as the same step.
    Text in another 8-bit encoding is named as such (it was 'not a text file')."""
    src = tmp_path / "step.csv"
    src.write_text(CSV.read_text(), encoding="utf-16")
    out = tmp_path / "gait.json"
    argv = ["gait", "--import", str(src), "--robot", str(URDF), "--angles", "urdf",
            "--stance", "hip_left", "--out", str(out)]
    assert main(argv) == 0, capsys.readouterr().err
    out.unlink()
    src.write_text("# Schritt \u00fcber Hindernisse\n" + CSV.read_text(), encoding="latin-1")
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "not UTF-8" in err and len(err.splitlines()) == 1, err
    assert not out.exists()


def _import_refused(src, rows, angles, tmp_path, capsys) -> str:
    """Write ``rows`` to ``src``, import it (exit 2, one line, no gait written): the line."""
    src.write_text("\n".join(",".join(r) for r in rows) + "\n")
    out = tmp_path / "gait.json"
    extra = ["--angles", "urdf", "--stance", "hip_left"] if angles == "urdf" else []
    assert main(["gait", "--import", str(src), "--robot", str(URDF), *extra,
                 "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and not out.exists(), err
    return err


@pytest.mark.parametrize("angles", ["urdf", "relative"])
def test_a_step_in_degrees_is_named(angles, walker_gait, tmp_path, capsys):
    """Angles in degrees (and rates in deg/s): one line saying so, exit 2, nothing written
    (not a message about the stance foot or the coordinate convention)."""
    src = tmp_path / "step.csv"
    write_gait_csv(walker_gait, src, angles=angles, n_nodes=21)
    rows = [r.split(",") for r in src.read_text().splitlines()]
    deg = [i for i, h in enumerate(rows[0]) if h not in ("t", "x", "z", "dx", "dz")]
    for r in rows[1:]:
        for i in deg:
            r[i] = repr(math.degrees(float(r[i])))
    err = _import_refused(src, rows, angles, tmp_path, capsys)
    assert "degrees?" in err and "rad" in err, err


def test_one_angle_in_degrees_beside_radians_is_named(walker_gait, tmp_path, capsys):
    """One angle and its rate logged in degrees beside the others in radians (an IMU's
    pitch beside the encoders): it turns by less than a full turn and its rate agrees with
    it, so it passed the unit checks and was refused later for another cause; one line
    names the column and says to convert it."""
    src = tmp_path / "step.csv"
    write_gait_csv(walker_gait, src, angles="urdf", n_nodes=21)
    rows = [r.split(",") for r in src.read_text().splitlines()]
    for i in (rows[0].index("pitch"), rows[0].index("dpitch")):
        for r in rows[1:]:
            r[i] = repr(math.degrees(float(r[i])))
    err = _import_refused(src, rows, "urdf", tmp_path, capsys)
    assert ": pitch goes from " in err and "in degrees? (convert it and its rate to " \
        "radians, x pi/180" in err, err


def test_degrees_check_spares_half_turn_joints_and_finds_small_degrees():
    """A URDF whose zero pose folds the hips by a half turn (the how-to's walker: 2.3 to
    3.15 rad) is not taken for degrees; a pitch of 4.5 to 5.5 degrees beside angles within
    a half turn is."""
    t = np.linspace(0.0, 1.0, 11)
    hips = np.vstack([2.3 + 0.85 * t, 3.15 - 0.85 * t])
    q = np.vstack([0.3 + 0.01 * t, hips, 0.4 * t])
    check_units(t, q, np.gradient(q, t, axis=1), ["pitch", "a", "b", "c"])
    with pytest.raises(ValueError, match=r"^nodes: pitch goes from 4\.5 to 5\.5, beyond a "
                                         r"half turn where the other angles stay within 3\.15"):
        q = np.vstack([4.5 + t, hips, 0.4 * t])
        check_units(t, q, np.gradient(q, t, axis=1), ["pitch", "a", "b", "c"])


@pytest.mark.parametrize("robot_file, stance, says, not_says", [
    ("rabbit", "hip_left", "with --stance hip_right it moves by 0.204 m too: angles in "
     "another convention", "(--stance hip_right?)"),
    ("walker", "hip_right", "another stance leg (--stance hip_left?)", " too:")])
def test_a_moving_stance_foot_suggests_the_other_leg_only_when_it_stays(
        robot_file, stance, says, not_says, tmp_path, capsys):
    """The walker's step with its base columns, read for the legs-down rabbit.urdf: its
    stance foot moves with either leg in stance, and the line says so (it suggested the
    other leg, which fails too); read with the other leg for the walker, it still
    suggests the leg that keeps the foot put."""
    urdf = URDF if robot_file == "walker" else builtin_path("rabbit").with_suffix(".urdf")
    out = tmp_path / "gait.json"
    assert main(["gait", "--import", str(CSV), "--robot", str(urdf), "--angles", "urdf",
                 "--stance", stance, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert says in err and not_says not in err and len(err.splitlines()) == 1, err
    assert not out.exists()


def test_joint_names_with_commas_round_trip_through_the_csv(walker_gait, tmp_path):
    """URDF names may hold commas and quotes: the CSV a gait is written to quotes them
    (it wrote them bare, and read its own file back as 17 columns over rows of 15)."""
    text = URDF.read_text().replace("knee_right", "R,knee").replace("hip_left", "L &quot;hip")
    p = tmp_path / "names.urdf"
    p.write_text(text)
    m = robot(p, torque_limit=150)
    assert 'L "hip' in m.description.urdf.names
    g = Gait(m, walker_gait.options, walker_gait.alpha, walker_gait.x0, walker_gait.T)
    src = write_gait_csv(g, tmp_path / "step.csv", angles="urdf", stance='L "hip',
                         n_nodes=21)
    r = import_gait(m, src, angles="urdf", stance='L "hip')
    assert r.orbit_residual_after <= 1e-10


def test_joint_names_that_close_a_c_comment_build(walker_gait, tmp_path):
    """A URDF name (or a gait path) holding '*/' ends no comment of the exported header:
    the law builds and is the toolkit's (gcc stopped at the header)."""
    text = URDF.read_text().replace("knee_right", "knee */ right").replace("RABBIT", "R */ B")
    p = tmp_path / "names.urdf"
    p.write_text(text)
    m = robot(p, torque_limit=150)
    g = Gait(m, walker_gait.options, walker_gait.alpha, walker_gait.x0, walker_gait.T)
    ctrl = TimeVaryingController(g, M1)
    law = exported_law(ctrl, angles="urdf")
    write_export(c_sources(law, {"gait file": "a*/b.json"}), tmp_path / "tv")
    lib = CompiledUrdfController(build_library(tmp_path / "tv"), ctrl, law.urdf)
    r = compare_urdf_states(lib, ctrl, n=50, seed=2)
    assert r.success and r.max_torque_rel <= 1e-12, r.message


@pytest.mark.parametrize("angles, unit", [("urdf", "ms"), ("relative", "ms"),
                                          ("relative", "deg/s"), ("urdf", "dpitch deg/s")])
def test_times_in_ms_or_rates_in_degrees_are_named(angles, unit, walker_gait, tmp_path,
                                                    capsys):
    """t in ms (or rates in deg/s beside angles in rad): the rates do not integrate to
    the angles; one line saying so (it said the Bezier fit misses the nodes by 470 rad)."""
    src = tmp_path / "step.csv"
    write_gait_csv(walker_gait, src, angles=angles, n_nodes=21)
    rows = [r.split(",") for r in src.read_text().splitlines()]
    rates = [i for i, h in enumerate(rows[0]) if h.startswith("d") and not h.startswith("dd")
             and h not in ("dx", "dz")]
    for r in rows[1:]:
        if unit == "ms":
            r[0] = repr(1e3 * float(r[0]))
        elif unit == "dpitch deg/s":           # an IMU's rate beside the encoders'
            i = rows[0].index("dpitch")
            r[i] = repr(math.degrees(float(r[i])))
        else:
            for i in rates:
                r[i] = repr(math.degrees(float(r[i])))
    err = _import_refused(src, rows, angles, tmp_path, capsys)
    assert "t in ms" in err and "integrate" in err, err


def test_a_trailing_separator_on_every_line_is_no_column(tmp_path, capsys):
    """Spreadsheets often end every line with a separator: the empty last column is none
    (it said 'line 2 has a value that is not a number')."""
    src = tmp_path / "step.csv"
    src.write_text("\n".join(r + "," for r in CSV.read_text().splitlines()) + "\n")
    out = tmp_path / "gait.json"
    assert main(["gait", "--import", str(src), "--robot", str(URDF), "--angles", "urdf",
                 "--stance", "hip_left", "--out", str(out)]) == 0, capsys.readouterr().err


def test_five_nodes_in_urdf_angles(walker, walker_gait, tmp_path):
    """As many nodes as coordinates in URDF angles: the same orbit."""
    src = write_gait_csv(walker_gait, tmp_path / "five.csv", angles="urdf", n_nodes=5)
    r = import_gait(walker, src, angles="urdf", stance="hip_left")
    assert r.orbit_residual_after <= 1e-10 and abs(r.gait.T - walker_gait.T) < 1e-12


def _walker_columns():
    """t, q (pitch and the four joints) and their rates, from the walker's step file."""
    with open(CSV) as f:
        head = f.readline().strip().split(",")
    a = np.loadtxt(CSV, delimiter=",", skiprows=1)
    names = head[1:6]
    return a[:, 0], a[:, 1:6].T, a[:, 6:11].T, names


def test_a_time_column_scaled_alone_is_named_as_such(tmp_path, capsys):
    """The walker's step with t doubled and the rates unchanged: every coordinate changes
    0.5 times what its rate integrates to (within the factor 3 of the rate check), and
    the import says the time scales disagree by a factor 2, instead of blaming the fit.
    The file as given, and noised resamplings of it at 8 to 20 nodes, pass."""
    t, q, dq, names = _walker_columns()
    check_units(t, q, dq, names)
    with pytest.raises(ValueError, match=r"^nodes: every coordinate changes 0\.5 times what "
                                         r"its rate integrates to over t .*different time "
                                         r"scales, by a factor 2 "):
        check_units(2 * t, q, dq, names)
    with pytest.raises(ValueError, match=r"by a factor 0\.66\d "):
        check_units(t / 1.5, q, dq, names)
    rng = np.random.default_rng(0)
    for n in (8, 12, 20):
        for _ in range(5):
            ts = np.linspace(t[0], t[-1], n)
            qs = np.array([np.interp(ts, t, r) for r in q]) + rng.normal(0, 1e-4, (5, n))
            dqs = np.array([np.interp(ts, t, r) for r in dq]) + rng.normal(0, 2e-3, (5, n))
            check_units(ts, qs, dqs, names)
    src = tmp_path / "step_t2.csv"
    lines = CSV.read_text().splitlines()
    src.write_text("\n".join([lines[0]] + [",".join([repr(2 * float(r.split(",")[0]))]
                                                    + r.split(",")[1:]) for r in lines[1:]]))
    rc = main(["gait", "--import", str(src), "--robot", str(URDF), "--angles", "urdf",
               "--stance", "hip_left", "--out", str(tmp_path / "g.json")])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and "\n" not in err and "by a factor 2 " in err, err


@pytest.mark.parametrize("column", ["x", "dx", "knee_left", "dhip_right", "pitch"])
def test_a_nan_in_a_column_names_the_line_and_column(column, tmp_path, capsys):
    """A NaN or infinity in the root's position or velocity, a joint's or the pitch's
    column: one line naming the file's line and the column (a joint's said 'q has a NaN
    or infinite value', and the file has no column q; the root's said the stance foot
    moves by nan m (x), or was taken silently (dx))."""
    rows = [r.split(",") for r in CSV.read_text().splitlines()]
    rows[5][rows[0].index(column)] = "-inf" if column == "pitch" else "nan"
    src = tmp_path / "step.csv"
    src.write_text("\n".join(",".join(r) for r in rows) + "\n")
    out = tmp_path / "gait.json"
    assert main(["gait", "--import", str(src), "--robot", str(URDF), "--angles", "urdf",
                 "--stance", "hip_left", "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert f"line 6: column {column} has a NaN or infinite value" in err, err
    assert len(err.splitlines()) == 1 and " q has" not in err and " dq has" not in err, err
    assert not out.exists()
    assert not out.exists()


def test_an_imported_gaits_violations_are_of_the_given_constraints(tmp_path, capsys):
    """The constraints an imported gait is checked against are --mu, --torque-limit, ...:
    a note names the one it violates and the amount in its unit (it said 'the default
    gait constraint' for a limit the user gave, and gave no unit)."""
    out = tmp_path / "gait.json"
    args = ["gait", "--import", str(CSV), "--robot", str(URDF), "--angles", "urdf",
            "--stance", "hip_left", "--torque-limit", "10", "--out", str(out)]
    assert main(args + ["--json"]) == 0
    peak = json.loads(capsys.readouterr().out)["peak_torque"]
    assert peak > 10
    assert main(args) == 0
    text = capsys.readouterr().out
    assert (f"note: violates the gait constraint 'torque limit' by {peak - 10:.3g} N m "
            "(reported, not enforced)") in text, text
    assert "default" not in text, text


def test_motor_side_without_reductions_is_said(walker_gait, tmp_path, capsys):
    """``--motor-side`` on a URDF without transmission reductions (the Unitree H1's)
    divided every torque by 1 without a word: the 'motors' torques' were the joints'.
    The walker with its reductions moved into the motors' inertia (the same robot, the
    same gait) is warned about in one line; the walker itself (50:1) is not."""
    flat = URDF.read_text().replace("<mechanicalReduction>50</mechanicalReduction>",
                                    "<mechanicalReduction>1</mechanicalReduction>")
    flat = flat.replace("<motorInertia>3.32e-4</motorInertia>", "<motorInertia>0.83</motorInertia>")
    (tmp_path / "flat.urdf").write_text(flat)
    g = import_gait(robot(tmp_path / "flat.urdf"), CSV, angles="urdf", stance="hip_left").gait
    for gait, warned in ((g, True), (walker_gait, False)):
        path = gait.save(tmp_path / f"g{warned}.json")
        out = tmp_path / f"ctrl{warned}"
        assert main(["export", "--gait", str(path), "--controller", "vc", "--angles", "urdf",
                     "--motor-side", "--out", str(out), "--json"]) == 0
        err = [line for line in capsys.readouterr().err.splitlines() if "warning" in line]
        assert len(err) == int(warned), err
        assert not warned or "every reduction is 1" in err[0]
