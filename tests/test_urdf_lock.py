"""3-D bipeds read as their sagittal-plane models by locking joints (``lock=``,
``biped robot import --lock NAME[=RAD] --lock-off-axis``).

The robot (tests/urdf_variants.py, ``biped3d_urdf``) is a 3-D biped as CAD exporters
write one: hip yaw, roll and pitch, knee, ankle pitch and roll per leg, hips 0.18 m
apart across, link frames turned every which way, centres of mass off the links (across
too) and full inertia tensors with products of inertia, the right leg the mirror image
of the left; optionally two arms (shoulder and elbow).  Locked at zero or at other
angles, the import equals Pinocchio's reduced model of the same file
(``pinocchio.buildReducedModel`` with the same joints at the same angles): at random
states of the pinned model, for either stance leg, kinetic and potential energy, D and H
on the pinned motions and the joints' torques agree to 1e-10.  A lock at an angle equals
the file with that joint written as a fixed joint turned by the angle (hand-edited).
Legs that differ only across the plane import; legs that differ in it, a joint off the
axis left unlocked, bad locks are refused with one line naming the joint; the CLI exits
0, or 2 with one line.
"""
from __future__ import annotations

import json
import math
import re
import xml.etree.ElementTree as ET

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from urdf_variants import (biped3d_urdf, dynamics_error, energy_error, pinocchio_reduced,
                           random_states, torque_error)

from analysis.cli import main
from biped_casadi import BipedModel
from biped_casadi.model.description import load_description
from biped_casadi.model.urdf import import_urdf

SIDES = ("l", "r")
#: the joints a sagittal model of the 3-D biped locks (its point foot: ankle pitch too)
SAGITTAL = {f"{j}_{s}": 0.0 for s in SIDES
            for j in ("hip_yaw", "hip_roll", "ankle_pitch", "ankle_roll")}
ARMS = {"shoulder_l": 0.3, "shoulder_r": 0.3, "elbow_l": -0.6, "elbow_r": -0.6}

#: name -> (generator keywords, locks, foot frame name per side)
CASES = {
    "zero": (dict(), SAGITTAL, "sole"),
    "angles-arms": (dict(arms=True),
                    {**SAGITTAL, "ankle_pitch_l": 0.1, "ankle_pitch_r": 0.1,
                     "ankle_roll_l": 0.05, "ankle_roll_r": -0.05, "hip_yaw_l": 0.0, **ARMS},
                    "sole"),
    "ankle-foot-flipped-knee": (dict(sole=False, mirror=False, flip_right_knee=True),
                                {**SAGITTAL, "ankle_pitch_l": -0.2, "ankle_pitch_r": -0.2},
                                "ankle_link"),
}


def _write(tmp_path, text, name="biped3d.urdf"):
    p = tmp_path / name
    p.write_text(text)
    return p


@pytest.fixture(scope="module", params=sorted(CASES))
def case(request, tmp_path_factory):
    kw, locks, foot = CASES[request.param]
    text = biped3d_urdf(**kw)
    path = tmp_path_factory.mktemp("lock") / f"{request.param}.urdf"
    path.write_text(text)
    imp = import_urdf(path, lock=locks)
    m = pinocchio_reduced(text, imp.description.rotor_inertia, imp.urdf_map.names, locks)
    return dict(name=request.param, imp=imp, model=BipedModel(imp.description),
                pin=(m, m.createData()), foot=foot)


def _foot_of(case):
    umap = case["imp"].urdf_map
    return lambda leg: f"{case['foot']}_{umap.hips[leg - 1][-1]}"


def _check(case, what, states, tol):
    model, umap, (m, data) = case["model"], case["imp"].urdf_map, case["pin"]
    worst = what(model, umap, m, data, _foot_of(case), states)
    assert worst <= tol, (case["name"], worst)


def test_the_locked_import_is_the_planar_robot(case):
    imp = case["imp"]
    assert imp.urdf_map.axis == pytest.approx((0.0, 1.0, 0.0), abs=1e-15)
    assert imp.legs == (("hip_pitch_l", "knee_l"), ("hip_pitch_r", "knee_r"))
    assert set(imp.locked) == set(CASES[case["name"]][1])
    assert any(n.startswith("locked: hip_yaw_l at 0") for n in imp.notes)
    ankle_note = any("--foot X Y Z" in n for n in imp.notes)
    assert ankle_note == (case["foot"] == "ankle_link")
    if case["foot"] == "sole":
        assert imp.foot == "link 'sole_l' (below the locked joint 'ankle_pitch_l')"
    flipped = CASES[case["name"]][0].get("flip_right_knee", False)
    assert [j.sign for j in imp.urdf_map.joints if j.name == "knee_r"] == [-1.0 if flipped else 1.0]


def test_energies_equal_pinocchio_reduced(case):
    _check(case, energy_error, random_states(case["model"].nq, 5, 3), 1e-10)


def test_D_and_H_equal_pinocchio_reduced(case):
    _check(case, dynamics_error, random_states(case["model"].nq, 3, 5), 1e-10)


def test_torques_equal_pinocchio_reduced_joint_torques(case):
    model, umap, (m, data) = case["model"], case["imp"].urdf_map, case["pin"]
    assert torque_error(model, umap, m, data, _foot_of(case)) <= 1e-12


def _same(a, b, tol=1e-12):
    """Two descriptions equal to ``tol`` (links, point masses, the joint map)."""
    for x, y in zip((a.torso,) + a.leg, (b.torso,) + b.leg):
        for f in ("mass", "length", "com", "com_offset", "inertia"):
            assert getattr(x, f) == pytest.approx(getattr(y, f), rel=tol, abs=tol), (x.name, f)
    assert dict(a.point_masses) == pytest.approx(dict(b.point_masses), rel=tol)
    for i, j in zip(a.urdf.joints, b.urdf.joints):
        assert (i.name, i.sign) == (j.name, j.sign)
        assert i.offset == pytest.approx(j.offset, abs=tol)
    assert a.urdf.pitch_offset == pytest.approx(b.urdf.pitch_offset, abs=tol)


def test_a_lock_at_an_angle_is_the_hand_edited_fixed_joint(tmp_path):
    """Locking ankle pitch at 0.1 and the arms at their angles equals writing those
    joints as fixed joints turned by the angles (the rotation by scipy).  (Without sole
    frames: below a locked ankle the importer looks for one, below a fixed joint not.)"""
    locks = {**SAGITTAL, "ankle_pitch_l": 0.1, "ankle_pitch_r": 0.1, **ARMS}
    text = biped3d_urdf(arms=True, sole=False)
    edited = text
    for name, angle in locks.items():
        m = re.search(rf'<joint name="{name}" type="revolute">(.*?)</joint>', edited)
        xyz = re.search(r'<origin xyz="([^"]*)" rpy="([^"]*)"/>', m.group(1))
        axis = np.array(re.search(r'<axis xyz="([^"]*)"/>', m.group(1)).group(1).split(), float)
        R = Rotation.from_euler("xyz", np.array(xyz.group(2).split(), float)) \
            * Rotation.from_rotvec(angle * axis / np.linalg.norm(axis))
        rpy = " ".join(repr(float(v)) for v in R.as_euler("xyz"))
        parent_child = re.search(r'(<parent[^>]*/><child[^>]*/>)', m.group(1)).group(1)
        edited = edited.replace(m.group(0), f'<joint name="{name}" type="fixed">{parent_child}'
                                             f'<origin xyz="{xyz.group(1)}" rpy="{rpy}"/></joint>')
    locked = import_urdf(_write(tmp_path, text), lock=locks).description
    fixed = import_urdf(_write(tmp_path, edited, "edited.urdf")).description
    _same(locked, fixed)
    zero = import_urdf(_write(tmp_path, text, "zero.urdf"),
                       lock={**SAGITTAL, **dict.fromkeys(ARMS, 0.0)}).description
    assert abs(locked.urdf.pitch_offset - zero.urdf.pitch_offset) > 1e-3    # the arms moved


def test_arms_merge_into_the_torso(tmp_path):
    p = _write(tmp_path, biped3d_urdf(arms=True))
    with pytest.raises(ValueError, match=r"the torso 'torso' has 4 jointed children .* "
                                         r"\(lock the joints of the others, e\.g\. arms"):
        import_urdf(p, lock=SAGITTAL)
    # without locks the hips' yaw joints are children of the torso too: the refusal says
    # that --lock-off-axis locks them (the Unitree H1 and G1 meet this first)
    with pytest.raises(ValueError) as e:
        import_urdf(p)
    assert str(e.value).endswith("(lock the joints of the others, e.g. arms: 'biped robot "
                                 "import FILE --lock NAME', lock=); 'hip_yaw_l', 'hip_yaw_r' "
                                 "turn(s) out of the plane most joints turn in: a 3-D robot's "
                                 "sagittal model locks every such joint with 'biped robot "
                                 "import FILE --lock-off-axis' (lock_off_axis=True)")
    with pytest.raises(ValueError, match=r"lock=\)$"):     # the arms' only: no such hint
        import_urdf(p, lock_off_axis=True)       # (and the plane voted is the torso's y)
    imp = import_urdf(p, lock={**SAGITTAL, **ARMS})
    no_arms = import_urdf(_write(tmp_path, biped3d_urdf(), "no_arms.urdf"), lock=SAGITTAL)
    hips = 2 * (0.6 + 0.9)
    assert imp.description.torso.mass == pytest.approx(11.0 + hips + 2 * (1.3 + 0.9), abs=1e-12)
    assert no_arms.description.torso.mass == pytest.approx(14.0 + hips, abs=1e-12)
    assert imp.description.leg == no_arms.description.leg
    assert sum("merged into 'torso'" in n for n in imp.notes) == 8   # 2 hip links + 2 arm links per side


def test_lock_off_axis_locks_yaw_and_roll(tmp_path):
    p = _write(tmp_path, biped3d_urdf(arms=True))
    for axis in (None, "y"):
        imp = import_urdf(p, lock={"ankle_pitch_l": 0.0, "ankle_pitch_r": 0.0, **ARMS},
                          lock_off_axis=True, axis=axis)
        assert set(imp.locked) == set(SAGITTAL) | set(ARMS)
        why = "--axis y" if axis else "the axis of 10 of the 16 joints"
        assert any(n.startswith(f"lock_off_axis: the plane's normal is [0.0, 1.0, 0.0] in the "
                                f"torso frame ({why})") for n in imp.notes), imp.notes
    ref = import_urdf(p, lock={**SAGITTAL, **ARMS}).description
    assert imp.description == ref
    # a joint named in lock keeps its angle; the others off the axis are locked at 0
    rolls = {"ankle_roll_l": 0.05, "ankle_roll_r": -0.05}
    imp = import_urdf(p, lock={"ankle_pitch_l": 0.0, "ankle_pitch_r": 0.0, **ARMS, **rolls},
                      lock_off_axis=True)
    assert imp.locked == {**import_urdf(p, lock={**SAGITTAL, **ARMS}).locked, **rolls}
    assert imp.description == import_urdf(p, lock={**SAGITTAL, **ARMS, **rolls}).description


def test_a_plane_voted_by_the_hands_is_named_in_the_refusals(tmp_path):
    # JVRC-1 (mc_rtc_data): its fingers, wrists and rolls turn about x, 22 of its 44
    # joints against 12 about y: --lock-off-axis takes x, and the refusal says so and
    # how to choose the plane
    fingers = "".join(
        f'<link name="finger{k}"><inertial><mass value="0.05"/><inertia ixx="1e-5" ixy="0" '
        f'ixz="0" iyy="1e-5" iyz="0" izz="1e-5"/></inertial></link><joint name="finger{k}" '
        f'type="revolute"><parent link="torso"/><child link="finger{k}"/><origin '
        f'xyz="0.1 0 {0.3 + 0.01 * k}"/><axis xyz="1 0 0"/><limit effort="1" velocity="1" '
        f'lower="-1" upper="1"/></joint>' for k in range(8))
    p = _write(tmp_path, biped3d_urdf(arms=True).replace("</robot>", fingers + "</robot>"))
    upper = {**ARMS, **{f"finger{k}": 0.0 for k in range(8)}}
    with pytest.raises(ValueError, match=r" \(--lock-off-axis took the plane's normal \[1\.0, "
                                         r"0\.0, 0\.0\] of the torso frame, the axis of 12 of "
                                         r"the 24 joints: --axis x\|y chooses it\)$"):
        import_urdf(p, lock=upper, lock_off_axis=True)
    imp = import_urdf(p, lock=upper, lock_off_axis=True, axis="y")
    off = {f"{j}_{s}": 0.0 for s in SIDES for j in ("hip_yaw", "hip_roll", "ankle_roll")}
    assert imp.description == import_urdf(p, lock={**upper, **off}).description


def _torso_turned(text: str, yaw: float) -> str:
    """The same robot with its torso's frame turned by ``yaw`` about its z: the torso's
    inertial, visual and the origins of the joints below it written in the turned frame."""
    R = Rotation.from_euler("z", yaw).as_matrix()
    root = ET.fromstring(text)

    def vec(el, key):
        return np.array(el.get(key, "0 0 0").split(), float)

    inertial = root.find("link[@name='torso']/inertial")
    origin, inertia = inertial.find("origin"), inertial.find("inertia")
    origin.set("xyz", " ".join(map(str, R.T @ vec(origin, "xyz"))))
    keys = ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")
    I = np.array([[float(inertia.get(f"i{a}{b}" if a <= b else f"i{b}{a}")) for b in "xyz"]
                  for a in "xyz"])
    I = R.T @ I @ R
    for k in keys:
        inertia.set(k, repr(float(I["xyz".index(k[1]), "xyz".index(k[2])])))
    frames = [j.find("origin") for j in root.findall("joint")
              if j.find("parent").get("link") == "torso"]
    for o in frames + root.findall("link[@name='torso']/visual/origin"):
        Rj = R.T @ Rotation.from_euler("xyz", vec(o, "rpy")).as_matrix()
        o.set("xyz", " ".join(map(str, R.T @ vec(o, "xyz"))))
        o.set("rpy", " ".join(map(str, Rotation.from_matrix(Rj).as_euler("xyz"))))
    return ET.tostring(root, encoding="unicode")


def test_locked_joints_vote_for_the_plane_of_a_turned_torso_frame(tmp_path):
    # ddlyRabbit/biped_lower's robot.urdf: its torso frame's x is lateral; with the ankle
    # pitch locked by name, the legs' pitch joints (with it, 6 of 12) outvote the rolls
    # (4): without the locked joints' votes they would tie, and the tie go to the rolls
    text = _torso_turned(biped3d_urdf(), math.pi / 2)
    p = _write(tmp_path, text, "turned.urdf")
    ankles = {"ankle_pitch_l": 0.0, "ankle_pitch_r": 0.0}
    imp = import_urdf(p, lock=ankles, lock_off_axis=True)
    assert any(n.startswith("lock_off_axis: the plane's normal is [1.0, 0.0, 0.0] in the torso "
                            "frame (the axis of 6 of the 12 joints)") for n in imp.notes)
    assert imp.description == import_urdf(p, lock=SAGITTAL).description
    _same(imp.description, import_urdf(_write(tmp_path, biped3d_urdf()), lock=SAGITTAL)
          .description)                       # the same robot as the file not turned


def test_mirror_images_and_differences_across_the_plane_are_the_same_legs(tmp_path):
    ref = import_urdf(_write(tmp_path, biped3d_urdf()), lock=SAGITTAL).description
    for kw in (dict(mirror=False), dict(differ="across")):
        d = import_urdf(_write(tmp_path, biped3d_urdf(**kw), "v.urdf"), lock=SAGITTAL).description
        _same(d, ref)
    with pytest.raises(ValueError, match=r"legs differ: link 'thigh_l' has inertia .* link "
                                         r"'thigh_r' .*apart by"):
        import_urdf(_write(tmp_path, biped3d_urdf(differ="plane"), "p.urdf"), lock=SAGITTAL)


BAD = {
    "no lock": (None, r"joint 'hip_yaw_l' turns about \[0\.0, 0\.0, 1\.0\], not about the other "
                      r"joints' axis \[0\.0, 1\.0, 0\.0\] \(torso frame\): not a planar robot; "
                      r"for its sagittal model lock it \('biped robot import FILE --lock "
                      r"hip_yaw_l', lock=\{'hip_yaw_l': 0\}\) or every joint off that axis "
                      r"\(--lock-off-axis\)"),
    "a roll turns the pitch axes": ({**SAGITTAL, "hip_roll_l": 0.05, "hip_roll_r": -0.05},
                                    r"joint 'hip_pitch_r' turns about \[-?0\.0, 0\.99875, "
                                    r"-0\.049979\] \(turned by the locked joints' angles\), "
                                    r"not about the other joints' axis \[-?0\.0, 0\.99875, "
                                    r"0\.049979\]"),
    "unknown": ({"hip_yaw": 0.0}, r"lock: the file has no joint 'hip_yaw'"),
    "fixed": ({"sole_l_fix": 0.0}, r"lock: joint 'sole_l_fix' is fixed: only revolute and "
                                   r"continuous joints can be locked"),
    "not finite": ({"knee_l": math.nan}, r"lock: joint 'knee_l' needs a finite angle in rad"),
    "twice": ([("knee_l", 0.0), "knee_l"], r"lock: joint 'knee_l' is locked twice"),
    "not a name": ([3], r"lock: give joint names, \(name, angle\) pairs or a mapping"),
    "empty name": ({"": 0.1}, r"lock: joint names must be non-empty strings, got ''"),
}


@pytest.mark.parametrize("which", sorted(BAD))
def test_bad_locks_are_refused_naming_the_joint(tmp_path, which):
    lock, message = BAD[which]
    p = _write(tmp_path, biped3d_urdf())
    with pytest.raises(ValueError, match=message) as e:
        import_urdf(p, lock=lock)
    assert "\n" not in str(e.value)


def test_a_prismatic_joint_is_not_locked(tmp_path):
    text = biped3d_urdf().replace('<joint name="hip_yaw_l" type="revolute">',
                                  '<joint name="hip_yaw_l" type="prismatic">')
    with pytest.raises(ValueError, match=r"lock: joint 'hip_yaw_l' is prismatic"):
        import_urdf(_write(tmp_path, text), lock=SAGITTAL)


def test_axis_needs_lock_off_axis(tmp_path):
    p = _write(tmp_path, biped3d_urdf())
    with pytest.raises(ValueError, match="axis chooses the plane's normal for lock_off_axis"):
        import_urdf(p, axis="y")
    with pytest.raises(ValueError, match="axis must be 'x' or 'y'"):
        import_urdf(p, lock_off_axis=True, axis="z")


def test_cli_import_with_locks(tmp_path, capsys):
    p = _write(tmp_path, biped3d_urdf(arms=True))
    out = tmp_path / "robot.toml"
    argv = ["robot", "import", str(p), "--lock-off-axis", "--lock", "ankle_pitch_l",
            "ankle_pitch_r=0", "--lock", "shoulder_l=0.3", "shoulder_r=0.3", "elbow_l=-0.6",
            "--lock", "elbow_r=-0.6", "--out", str(out)]
    assert main(argv) == 0
    text = capsys.readouterr().out
    assert "note: locked: hip_yaw_l at 0, hip_roll_l at 0, ankle_pitch_l at 0" in text
    assert load_description(out) == import_urdf(p, lock={**SAGITTAL, **ARMS}).description
    assert "shoulder_l = 0.3" in out.read_text().splitlines()[1]
    assert main(argv + ["--json"]) == 0
    body = json.loads(capsys.readouterr().out)
    assert body["locked"] == import_urdf(p, lock={**SAGITTAL, **ARMS}).locked
    assert body["legs"] == [["hip_pitch_l", "knee_l"], ["hip_pitch_r", "knee_r"]]


@pytest.mark.parametrize("extra, text", [
    (["--axis", "y"], "--axis chooses the plane's normal for --lock-off-axis"),
    (["--lock", "knee_l=abc"], "--lock knee_l=abc: the angle after '=' must be a number"),
    (["--lock", "knee_l", "--lock", "knee_l=0.1"], "--lock: joint 'knee_l' is locked twice"),
    (["--lock", "knee_l=nan"], "--lock: joint 'knee_l' needs a finite angle"),
    (["--lock", "hip_yaw"], "lock: the file has no joint 'hip_yaw'"),
    (["--lock-off-axis", "--axis", "z"], "invalid choice: 'z'"),
    ([], "for its sagittal model lock it ('biped robot import FILE --lock hip_yaw_l'"),
])
def test_cli_bad_locks_exit_2_with_one_line(tmp_path, capsys, extra, text):
    p = _write(tmp_path, biped3d_urdf())
    out = tmp_path / "r.toml"
    assert main(["robot", "import", str(p), *extra, "--out", str(out)]) == 2
    err = capsys.readouterr().err.strip()
    assert text in err and len(err.splitlines()) == 1, err
    assert not out.exists()


@pytest.mark.slow
def test_the_sagittal_model_walks(tmp_path, capsys):
    """End to end: the 3-D biped (arms held at their angles) imported with its joints
    locked, a reference gait at 0.5 m/s, the virtual-constraint controller's
    eigenvalue: a walking, stable robot."""
    p = _write(tmp_path, biped3d_urdf(arms=True))
    toml, gait = tmp_path / "biped3d.toml", tmp_path / "g.json"
    locks = [f"{k}={v!r}" for k, v in ARMS.items()]
    assert main(["robot", "import", str(p), "--lock-off-axis", "--lock", "ankle_pitch_l",
                 "ankle_pitch_r", *locks, "--out", str(toml)]) == 0
    assert main(["gait", "--robot", str(toml), "--speed", "0.5", "--out", str(gait)]) == 0
    capsys.readouterr()
    assert main(["eig", "--gait", str(gait), "--controller", "vc", "--json"]) == 0
    body = json.loads(capsys.readouterr().out)
    assert body["success"] and body["status"] == "stable", body


def test_a_3d_robot_given_to_another_command_is_told_where_locks_are(tmp_path, capsys):
    """--robot FILE.urdf on a command without --lock (biped model, eig, ...): the refusal
    names the command that locks joints (it said '--lock NAME' and '--lock-off-axis',
    options 'biped model' does not have)."""
    p = _write(tmp_path, biped3d_urdf(arms=True))
    assert main(["model", "--robot", str(p)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    assert "'biped robot import FILE --lock NAME'" in err, err
    assert "'biped robot import FILE --lock-off-axis'" in err, err
