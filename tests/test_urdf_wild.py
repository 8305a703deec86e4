"""URDFs as they are found in public biped repositories, each feature written here in a
small file of its own (tests/urdf_variants.py and the packaged rabbit.urdf):

- a xacro file (by its name, or saved as .urdf with its macros and ``${...}``), and a
  fragment that a xacro file includes (ros2_control tags, no link), are refused in one
  line that says to run xacro first; a URDF that only declares the xacro namespace
  imports;
- a leg whose spring, tarsus and toe joints are locked below the knee (the sagittal
  model of a Cassie-like leg): the foot is the lowest locked joint that turns in the
  plane (the ankle), not the first one below the knee; checked against Pinocchio's
  reduced model of the same file with its foot frame there;
- a shin with two fixed children named like a foot, a locked ankle's foot link and a
  contact frame: the contact frame is the foot (Pinocchio again);
- a pelvis whose centre of mass and geometry sit on the hip: its up direction is its
  frame's z, and the model equals Pinocchio's;
- a robot held by a rig (a pin, or a boom of prismatic joints, above the torso) is
  refused with what to do, and imports as the robot with ``torso=``;
- a torso turned under a world link so that gravity leaves the legs' plane (a y-up
  file) is refused; a massless link without joints beside the tree is ignored;
- legs that differ: the refusal names the largest difference and a tolerance that takes
  them all at once; camel-case sides name the links; ``<frame>`` elements mark a sole;
- materials that ``urdf_parser_py`` would refuse (iCub's ``<texture/>`` without a file
  name), appearance the model does not read, import as the robot without them, and a
  file in a default XML namespace (Drake's older files) as the file without it, and a
  file whose XML declaration follows its licence comment (NAO's) as the file;
- a last leg link without length, no foot, a ``<mimic>`` leg joint and a branching leg
  are refused in one line that says what to do.
"""
from __future__ import annotations

import re
from pathlib import Path

import pytest
from urdf_parser_py import urdf as parser
from urdf_variants import (biped3d_urdf, dynamics_error, energy_error, pinocchio_model,
                           pinocchio_reduced, random_states, torque_error)

from analysis.cli import main
from biped_casadi import BipedModel, robot
from biped_casadi.model.urdf import import_urdf

RABBIT_URDF = (Path(__file__).resolve().parents[1] / "biped_casadi" / "model" / "robots"
               / "rabbit.urdf").read_text()
SIDES = ("l", "r")
SAGITTAL = {f"{j}_{s}": 0.0 for s in SIDES
            for j in ("hip_yaw", "hip_roll", "ankle_pitch", "ankle_roll")}


def _write(tmp_path, text, name):
    p = tmp_path / name
    p.write_text(text)
    return p


def _cli_error(capsys, argv) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1, err
    return err


# ------------------------------------------------------------------ xacro
XACRO = RABBIT_URDF.replace(
    '<robot name="RABBIT">',
    '<robot name="RABBIT" xmlns:xacro="http://www.ros.org/wiki/xacro">\n'
    '  <xacro:property name="femur_mass" value="6.8"/>').replace(
    '<mass value="6.8"/>', '<mass value="${femur_mass}"/>')


@pytest.mark.parametrize("text,marker", [
    (XACRO, "<xacro:property>"),
    (re.sub(r"<xacro:property[^>]*>", "", XACRO), 'value="${femur_mass}"'),
    (XACRO.replace(' xmlns:xacro="http://www.ros.org/wiki/xacro"', ""), "<xacro:property>"),
], ids=["macro", "substitution", "no-namespace"])
def test_a_xacro_file_saved_as_urdf_is_refused_with_what_to_do(tmp_path, capsys, text, marker):
    path = _write(tmp_path, text, "robot_x.urdf")
    with pytest.raises(ValueError) as e:
        import_urdf(path)
    msg = str(e.value)
    assert "a xacro file, not a URDF" in msg and marker in msg
    assert "'xacro robot_x.urdf > robot.urdf'" in msg
    err = _cli_error(capsys, ["robot", "import", str(path), "--out", str(tmp_path / "r.toml")])
    assert "xacro robot_x.urdf > robot.urdf" in err
    assert not (tmp_path / "r.toml").exists()


def test_a_xacro_file_by_its_name_is_refused_with_what_to_do(tmp_path, capsys):
    path = _write(tmp_path, XACRO, "biped.urdf.xacro")
    err = _cli_error(capsys, ["robot", "import", str(path), "--out", str(tmp_path / "r.toml")])
    assert "biped.urdf.xacro is a xacro file" in err
    assert "'xacro biped.urdf.xacro > robot.urdf'" in err
    with pytest.raises(ValueError, match=r"xacro biped.urdf.xacro > robot.urdf"):
        robot(path)
    err = _cli_error(capsys, ["gait", "--robot", str(path), "--out", str(tmp_path / "g.json")])
    assert "is a xacro file" in err


def test_the_xacro_namespace_alone_is_a_urdf(tmp_path):
    text = RABBIT_URDF.replace('<robot name="RABBIT">',
                               '<robot name="RABBIT" xmlns:xacro="http://ros.org/wiki/xacro">')
    assert import_urdf(_write(tmp_path, text, "r.urdf")).description == robot("rabbit").description


def test_a_fragment_without_links_is_refused_with_what_to_do(tmp_path, capsys):
    text = ('<?xml version="1.0"?>\n<robot name="biped"><ros2_control name="sim" '
            'type="system"><joint name="hip_left"><command_interface name="effort"/>'
            '</joint></ros2_control></robot>')
    path = _write(tmp_path, text, "control.urdf")
    err = _cli_error(capsys, ["robot", "import", str(path), "--out", str(tmp_path / "r.toml")])
    assert "defines no <link>" in err and "xacro" in err
    assert "loop" not in err


# ------------------------------------------------------------------ feet
def _reduced_case(text, locks, foot, tmp_path):
    imp = import_urdf(_write(tmp_path, text, "leg.urdf"), lock=locks)
    m = pinocchio_reduced(text, imp.description.rotor_inertia, imp.urdf_map.names, locks)
    model, umap, data = BipedModel(imp.description), imp.urdf_map, m.createData()

    def foot_of(leg):
        return f"{foot}_{umap.hips[leg - 1][-1]}"

    for what, states in ((energy_error, random_states(model.nq, 4, 3)),
                         (dynamics_error, random_states(model.nq, 2, 5))):
        assert what(model, umap, m, data, foot_of, states) <= 1e-10
    assert torque_error(model, umap, m, data, foot_of) <= 1e-12
    return imp


def test_the_foot_below_a_chain_of_locked_joints_in_the_plane_is_the_lowest(tmp_path):
    # below the hip: the knee, the ankle pitch (both in the plane) and the ankle roll,
    # all locked; the foot is the ankle pitch's point (the last locked joint in the
    # plane), not the knee's (the first locked joint below the last leg link)
    locks = {**SAGITTAL, "knee_l": -0.3, "knee_r": -0.3, "ankle_pitch_l": 0.2,
             "ankle_pitch_r": 0.2}
    imp = _reduced_case(biped3d_urdf(sole=False), locks, "ankle_link", tmp_path)
    assert imp.legs == (("hip_pitch_l",), ("hip_pitch_r",))
    assert imp.foot == "link 'ankle_link_l' (the locked joint 'ankle_pitch_l')"
    assert any("'ankle_link_l' hangs from 'shin_l'" in n for n in imp.notes)


def _with_contact_frames(text: str) -> str:
    """A fixed contact frame on each shin beside the locked ankle's foot link."""
    frames = "".join(
        f'<joint name="foot_contact_{s}_fix" type="fixed"><parent link="shin_{s}"/>'
        f'<child link="foot_contact_{s}"/><origin xyz="0.01 0 -0.41"/></joint>'
        f'<link name="foot_contact_{s}"/>' for s in SIDES)
    return text.replace("</robot>", frames + "</robot>")


def test_a_contact_frame_beside_a_locked_ankle_is_the_foot(tmp_path):
    imp = _reduced_case(_with_contact_frames(biped3d_urdf(sole=False)), SAGITTAL,
                        "foot_contact", tmp_path)
    assert imp.foot == "link 'foot_contact_l'"
    assert not any("--foot X Y Z" in n for n in imp.notes)


# ------------------------------------------------------------------ the torso
def test_a_pelvis_with_its_mass_on_the_hip_points_up_its_frame(tmp_path):
    text = RABBIT_URDF.replace('<origin xyz="0 0 0.24" rpy="0 0 0"/>',
                               '<origin xyz="0 0 0" rpy="0 0 0"/>', 1)
    text = re.sub(r"<visual>.*?</visual>", "", text, count=1, flags=re.S)
    imp = import_urdf(_write(tmp_path, text, "pelvis.urdf"))
    d = imp.description
    assert d.torso.com == 0.0 and d.torso.com_offset == 0.0
    assert imp.urdf_map.pitch_offset == 0.0
    assert any("its up direction is z of 'torso'" in n for n in imp.notes)
    model, umap = BipedModel(d), imp.urdf_map
    m = pinocchio_model(text, d.rotor_inertia, umap.names)
    data = m.createData()

    def foot_of(leg):
        return "foot_" + umap.hips[leg - 1].split("_")[1]

    assert energy_error(model, umap, m, data, foot_of, random_states(model.nq, 4, 7)) <= 1e-10
    assert dynamics_error(model, umap, m, data, foot_of, random_states(model.nq, 2, 9)) <= 1e-10


# ------------------------------------------------------------------ refusals that say what to do
def test_a_last_link_without_length_says_lock_it_or_give_the_foot(tmp_path, capsys):
    # the feet at the knees: the tibiae have no length
    text, k = re.subn(r'(<child link="foot_(left|right)"/>\s*<origin xyz=)"0 0 -0.4"',
                      r'\1"0 0 0"', RABBIT_URDF)
    assert k == 2
    path = _write(tmp_path, text, "r.urdf")
    err = _cli_error(capsys, ["robot", "import", str(path), "--out", str(tmp_path / "r.toml")])
    assert "link 'tibia_left' has no length in the plane of motion" in err
    assert "--lock knee_left" in err and "--foot X Y Z in the frame of 'tibia_left'" in err


PIN = ('<link name="stand"><inertial><mass value="2.0"/><inertia ixx="0.1" ixy="0" ixz="0" '
       'iyy="0.1" iyz="0" izz="0.1"/></inertial></link>'
       '<joint name="pin" type="continuous"><parent link="stand"/><child link="torso"/>'
       '<origin xyz="0 0 1.0"/><axis xyz="0 1 0"/></joint>')
BOOM = ('<link name="stand"/>'
        '<joint name="boom_x" type="prismatic"><parent link="stand"/><child link="slider"/>'
        '<axis xyz="1 0 0"/><limit effort="0" velocity="5" lower="-10" upper="10"/></joint>'
        '<link name="slider"><inertial><mass value="1.5"/><inertia ixx="0.01" ixy="0" '
        'ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>'
        '<joint name="boom_z" type="prismatic"><parent link="slider"/><child link="carriage"/>'
        '<axis xyz="0 0 1"/><limit effort="0" velocity="5" lower="0" upper="2"/></joint>'
        '<link name="carriage"/>'
        '<joint name="boom_pitch" type="continuous"><parent link="carriage"/>'
        '<child link="torso"/><axis xyz="0 1 0"/></joint>')


@pytest.mark.parametrize("rig,joints", [
    (PIN, "'pin' (continuous)"),
    (BOOM, "'boom_x' (prismatic), 'boom_z' (prismatic), 'boom_pitch' (continuous)"),
], ids=["pin", "boom"])
def test_a_robot_held_by_a_rig_says_make_the_torso_the_root(tmp_path, capsys, rig, joints):
    text = RABBIT_URDF.replace('<robot name="RABBIT">', '<robot name="RABBIT">' + rig)
    path = _write(tmp_path, text, "rig.urdf")
    err = _cli_error(capsys, ["robot", "import", str(path), "--out", str(tmp_path / "r.toml")])
    assert f"the legs hang from link 'torso', held by the joint(s) {joints}" in err
    assert "--torso torso" in err and "make 'torso' the file's root link" in err
    # named, the torso is the robot: the rig's joints and links are left out
    imp = import_urdf(path, torso="torso")
    assert imp.description == robot("rabbit").description
    assert any(n.startswith(f"torso 'torso' (torso=): the joint(s) {joints} from the root "
                            f"'stand' hold it") for n in imp.notes)
    out = tmp_path / "r.toml"
    assert main(["robot", "import", str(path), "--torso", "torso", "--out", str(out)]) == 0
    assert out.is_file()
    capsys.readouterr()
    err = _cli_error(capsys, ["robot", "import", str(path), "--torso", "pelvis",
                              "--out", str(tmp_path / "p.toml")])
    assert "torso: the file has no link 'pelvis'" in err


def test_no_foot_names_the_legs_joints(tmp_path, capsys):
    # the leg's joints show which plane and chain were found (a file whose joints are
    # mislabelled reads as another plane's legs)
    text = re.sub(r'<joint name="foot_(left|right)_fixed".*?<link name="foot_(left|right)"/>',
                  "", RABBIT_URDF, flags=re.S)
    path = _write(tmp_path, text, "r.urdf")
    err = _cli_error(capsys, ["robot", "import", str(path), "--out", str(tmp_path / "r.toml")])
    assert ("no foot: the last leg link 'tibia_left' (the leg's joints: hip_left -> "
            "knee_left)") in err
    assert "--foot X Y Z" in err and "--lock NAME" in err


def test_a_massless_link_without_joints_is_not_a_second_root(tmp_path, capsys):
    text = RABBIT_URDF.replace('<robot name="RABBIT">', '<robot name="RABBIT"><link name="world"/>')
    imp = import_urdf(_write(tmp_path, text, "r.urdf"))
    assert imp.description == robot("rabbit").description
    assert any("ignored: link(s) 'world' without mass and joints" in n for n in imp.notes)
    heavy = RABBIT_URDF.replace(
        '<robot name="RABBIT">', '<robot name="RABBIT"><link name="table"><inertial><mass '
        'value="5"/><inertia ixx="1" ixy="0" ixz="0" iyy="1" iyz="0" izz="1"/></inertial></link>')
    err = _cli_error(capsys, ["robot", "import", str(_write(tmp_path, heavy, "t.urdf")),
                              "--out", str(tmp_path / "r.toml")])
    assert "found roots ['table', 'torso']: join them by joints" in err


def _on_a_world(rpy: str) -> str:
    return RABBIT_URDF.replace(
        '<robot name="RABBIT">', '<robot name="RABBIT"><link name="world"/><joint '
        'name="world_fix" type="fixed"><parent link="world"/><child link="torso"/>'
        f'<origin xyz="0 0 1" rpy="{rpy}"/></joint>')


def test_a_torso_turned_so_gravity_leaves_the_legs_plane_is_refused(tmp_path, capsys):
    # the world link's z (the vertical) is the legs' axis in the torso's frame: the robot
    # lies on its side in the file (a y-up file, as animation and RL humanoids are
    # written); read with the torso frame's z as vertical it would be another robot
    path = _write(tmp_path, _on_a_world("1.5707963267948966 0 0"), "side.urdf")
    err = _cli_error(capsys, ["robot", "import", str(path), "--out", str(tmp_path / "r.toml")])
    assert ("the world's vertical (z of the root link 'world') is [0.0, 1.0, 0.0] in the "
            "torso's frame, turned by the origin of 'world_fix'") in err
    assert "gravity would act across it" in err
    # turned about the legs' axis (pitched): the same robot (pitch is a coordinate)
    pitched = import_urdf(_write(tmp_path, _on_a_world("0 0.3 0"), "pitched.urdf"))
    assert pitched.description == robot("rabbit").description


def test_the_suggested_match_tol_takes_every_difference_at_once(tmp_path):
    # a CAD export's legs: the hips 1e-6 m apart, the right femur's centre of mass
    # 1e-5 m off (first in the file), the right tibia 1 % heavier (later): the refusal
    # names the largest and its tolerance takes all three in one step
    text = RABBIT_URDF.replace('<origin xyz="0 -0.1 0" rpy="0 0 0"/>',
                               '<origin xyz="0.000001 -0.1 0" rpy="0 0 0"/>', 1)
    femur_r = text.index('<link name="femur_right">')
    text = text[:femur_r] + text[femur_r:].replace('<origin xyz="0 0 -0.11"',
                                                   '<origin xyz="0.00001 0 -0.11"', 1)
    tibia_r = text.index('<link name="tibia_right">')
    text = text[:tibia_r] + text[tibia_r:].replace('<mass value="3.2"/>',
                                                   '<mass value="3.232"/>', 1)
    path = _write(tmp_path, text, "cad.urdf")
    with pytest.raises(ValueError) as e:
        import_urdf(path)
    msg = str(e.value)
    assert "legs differ: link 'tibia_left' has mass 3.2, link 'tibia_right' 3.232" in msg
    tol = float(re.search(r"--match-tol (\S+) \(match_tol=\)", msg).group(1))
    imp = import_urdf(path, match_tol=tol)
    assert any("the hips are 1e-06 m apart" in n for n in imp.notes)


def test_a_mimic_leg_joint_says_lock_it(tmp_path, capsys):
    # a linkage joint (a foot kept level by a parallelogram) written as <mimic>: held
    # fixed, the robot imports as its model with that joint locked
    text = RABBIT_URDF
    for side in ("left", "right"):
        text = text.replace(
            f'<link name="foot_{side}"/>',
            f'<link name="foot_{side}"/><joint name="toe_{side}" type="revolute"><parent '
            f'link="foot_{side}"/><child link="toe_{side}"/><axis xyz="0 1 0"/><mimic '
            f'joint="knee_{side}" multiplier="-1"/><limit effort="1" velocity="1" lower="-1" '
            f'upper="1"/></joint><link name="toe_{side}"><inertial><mass value="0.1"/><inertia '
            f'ixx="1e-4" ixy="0" ixz="0" iyy="1e-4" iyz="0" izz="1e-4"/></inertial></link>')
    path = _write(tmp_path, text, "mimic.urdf")
    err = _cli_error(capsys, ["robot", "import", str(path), "--out", str(tmp_path / "r.toml")])
    assert "joint 'toe_left' mimics joint 'knee_left'" in err
    assert "--lock toe_left[=RAD]" in err
    imp = import_urdf(path, lock={"toe_left": 0, "toe_right": 0})
    assert imp.legs == (("hip_left", "knee_left"), ("hip_right", "knee_right"))


def test_a_branching_leg_says_a_cut_linkage_is_not_a_leg(tmp_path, capsys):
    # a four-bar leg as FROST-style files write it: the loop cut open, two branches
    strut = ('<joint name="strut_{s}" type="revolute"><parent link="femur_{s}"/><child '
             'link="strut_{s}"/><origin xyz="0 0 -0.1"/><axis xyz="0 1 0"/><limit effort="150" '
             'velocity="20" lower="-3" upper="3"/></joint><link name="strut_{s}"><inertial>'
             '<mass value="0.5"/><inertia ixx="1e-3" ixy="0" ixz="0" iyy="1e-3" iyz="0" '
             'izz="1e-3"/></inertial></link>')
    text = RABBIT_URDF.replace("</robot>", "".join(strut.format(s=s) for s in ("left", "right"))
                               + "</robot>")
    err = _cli_error(capsys, ["robot", "import", str(_write(tmp_path, text, "b.urdf")),
                              "--out", str(tmp_path / "r.toml")])
    assert "link 'femur_left' has 2 jointed children ('knee_left', 'strut_left')" in err
    assert "a four-bar leg, is not one" in err


@pytest.mark.parametrize("left,right,name", [
    ("LeftThigh", "RightThigh", "Thigh"), ("thighLeft", "thighRight", "thigh"),
    ("femur_left", "femur_right", "femur"), ("l_uleg", "r_uleg", "uleg")])
def test_camel_case_sides_give_the_links_name(tmp_path, left, right, name):
    text = RABBIT_URDF.replace('"femur_left"', f'"{left}"').replace('"femur_right"', f'"{right}"')
    assert import_urdf(_write(tmp_path, text, "r.urdf")).description.leg[0].name == name


@pytest.mark.parametrize("left,right,names", [
    (("FL_UPPER_LEG", "FL_LOWER_LEG"), ("FR_UPPER_LEG", "FR_LOWER_LEG"),
     ("UPPER_LEG", "LOWER_LEG")),                      # ODRI's Bolt: a quadruped's names
    (("leg1_thigh", "leg1_shin"), ("leg2_a", "leg2_b"), ("link1", "link2"))])
def test_side_tokens_of_any_spelling_give_distinct_link_names(tmp_path, left, right, names):
    # the side is the one token in which the two names differ; names that still coincide
    # (a prefix shared by both links) become the links' positions
    text = RABBIT_URDF
    for old, new in zip(("femur_left", "tibia_left", "femur_right", "tibia_right"),
                        left + right):
        text = text.replace(f'"{old}"', f'"{new}"')
    d = import_urdf(_write(tmp_path, text, "r.urdf")).description
    assert tuple(link.name for link in d.leg) == names


def test_a_leg_welded_to_the_torso_says_the_legs_differ_first(tmp_path, capsys):
    # Drake's kneed compass gait: one thigh welded to the hip, no foot links; the refusal
    # is the legs' joints, not the shorter chain's foot or the longer one's lengths
    text = re.sub(r'<joint name="hip_left" type="revolute">', '<joint name="hip_left" '
                  'type="fixed">', RABBIT_URDF)
    text = re.sub(r'<joint name="foot_(left|right)_fixed".*?</joint>\s*<link name="foot_\1"/>',
                  "", text, flags=re.S)
    assert "foot_left" not in text and "foot_right" not in text
    err = _cli_error(capsys, ["robot", "import", str(_write(tmp_path, text, "c.urdf")),
                              "--out", str(tmp_path / "c.toml")])
    assert ("legs differ: 1 joint(s) (knee_left) and 2 joint(s) (hip_right -> knee_right)"
            in err), err
    assert err.endswith("('knee_left' hangs from link 'femur_left', fixed to the torso "
                        "'torso': if that is a thigh welded to the hip, as in a compass-gait "
                        "walker with one joint between its thighs, the robot has no torso "
                        "apart from its legs, which the model needs to carry both legs by "
                        "their hip joints)"), err


def test_a_tag_unknown_to_urdf_on_every_link_is_one_note(tmp_path):
    # Bolt's file (PyBullet's <contact> on each of its 9 links): one line per tag, not
    # one per link
    text = re.sub(r'(<link name="[^"]+">)', r'\1<contact><lateral_friction value="1"/></contact>',
                  RABBIT_URDF)
    notes = [n for n in import_urdf(_write(tmp_path, text, "r.urdf")).notes
             if n.startswith("ignored: Unknown tag")]
    n_links = len(re.findall(r'<link name="[^"]+">', RABBIT_URDF))
    assert notes == [f"ignored: Unknown tag \"contact\" in {n_links} places "
                     f"(/robot[@name='RABBIT']/link[@name='torso'], ...)"], notes


def _with_frames(text: str) -> str:
    """RABBIT's file with its foot links written as <frame> elements, two per leg."""
    text = re.sub(r'<joint name="foot_(left|right)_fixed".*?<link name="foot_(left|right)"/>',
                  "", text, flags=re.S)
    text = text.replace("</robot>", "".join(
        f'<frame link="tibia_{s}" name="{s}_sole" xyz="0 0 -0.4" rpy="0 0 0"/>'
        f'<frame link="tibia_{s}" name="{s}_toe" xyz="0.1 0 -0.4" rpy="0 0 0"/>'
        for s in ("left", "right")) + "</robot>")
    return text


@pytest.mark.parametrize("namespace", ["", ' xmlns="http://drake.mit.edu"'])
def test_frame_elements_mark_the_foot(tmp_path, namespace):
    # Drake's and FROST's <frame name link xyz rpy/> (Atlas's soles and toes in FROST's
    # file): read as massless links fixed to their links, a sole among them is the foot;
    # Drake's older files (the kneed compass gait) put every element in a default
    # namespace, where urdf_parser_py alone would find no link
    text = _with_frames(RABBIT_URDF).replace('<robot name="RABBIT">',
                                             f'<robot name="RABBIT"{namespace}>')
    assert namespace in text
    imp = import_urdf(_write(tmp_path, text, "frames.urdf"))
    assert imp.description == robot("rabbit").description
    assert imp.foot == "link 'left_sole'"
    assert any(n.startswith("read the <frame> elements 'left_sole' on 'tibia_left'")
               for n in imp.notes)


def test_a_passive_leg_joint_says_lock_it(tmp_path, capsys):
    # Cassie's shin spring: a leg joint with effort 0 among actuated ones
    text = RABBIT_URDF.replace('<limit effort="150" velocity="20" lower="-3.14" upper="3.14"/>\n'
                               '  </joint>\n  <link name="tibia_left">',
                               '<limit effort="0" velocity="20" lower="-3.14" upper="3.14"/>\n'
                               '  </joint>\n  <link name="tibia_left">')
    assert text != RABBIT_URDF
    err = _cli_error(capsys, ["robot", "import", str(_write(tmp_path, text, "p.urdf")),
                              "--out", str(tmp_path / "r.toml")])
    assert "joint 'knee_left' has no actuator" in err and "--lock knee_left[=RAD]" in err


def test_a_texture_without_a_file_name_is_appearance_the_model_does_not_read(tmp_path):
    # the iCub of example-robot-data: <material name=...><texture/></material> in its
    # visuals, which urdf_parser_py refuses (filename required) and ROS's parser passes over
    text = RABBIT_URDF.replace(
        "</visual>", '<material name="metal"><texture/><color rgba="0 0 0 1"/></material>'
        "</visual>").replace("<link ", '<material name="grey"><texture/></material><link ', 1)
    assert text.count("<texture/>") >= 2
    with pytest.raises(Exception, match="filename"):     # the parser alone refuses it
        parser.URDF.from_xml_string(text.encode())
    assert import_urdf(_write(tmp_path, text, "t.urdf")).description == robot("rabbit").description


def test_an_xml_declaration_after_a_comment_is_read_as_ros_reads_it(tmp_path):
    # ijnek/nao_description's nao.urdf: a licence comment, then <?xml version="1.0" ?>,
    # which an XML parser refuses ("XML or text declaration not at start of entity")
    assert RABBIT_URDF.startswith('<?xml version="1.0"?>')
    text = "<!-- licence -->\n\n" + RABBIT_URDF
    imp = import_urdf(_write(tmp_path, text, "late.urdf"))
    assert imp.description == robot("rabbit").description
