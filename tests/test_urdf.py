"""Robots from URDF files: the packaged RABBIT and three-link URDFs give the models of
their TOML descriptions (D, H, the impact map, the swing foot to 1e-12), random bipeds
written as URDF (frames turned, point masses, the foot given as an argument) read back
to their own models, ``biped robot import`` round-trips, and every kind of file that is
not a planar biped is refused with one message naming what is wrong."""
from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from robot_factory import random_description, urdf_text

from analysis.cli import main
from biped_casadi import BipedModel, robot
from biped_casadi.model.description import builtin_path, load_description
from biped_casadi.model.urdf import import_urdf

ROBOTS = Path(builtin_path("rabbit")).parent


def functions_agree(a: BipedModel, b: BipedModel, seed=0, n=15):
    """max relative difference of D, H, the impact map and the swing foot at random states."""
    rng = np.random.default_rng(seed)
    worst = 0.0
    for _ in range(n):
        q, dq = rng.uniform(-1, 1, a.nq), rng.uniform(-2, 2, a.nq)
        pairs = [(a.D(q), b.D(q)), (a.H(q, dq), b.H(q, dq)),
                 (a.swing_foot(q)[0], b.swing_foot(q)[0]), (a.swing_foot(q)[1], b.swing_foot(q)[1])]
        pairs += list(zip(a.impact(q, dq), b.impact(q, dq)))
        for x, y in pairs:
            x, y = np.array(x), np.array(y)
            worst = max(worst, float(np.max(np.abs(x - y)) / max(1.0, np.max(np.abs(y)))))
    return worst


@pytest.mark.parametrize("name", ["rabbit", "three_link"])
def test_packaged_urdf_is_the_toml_robot(name):
    imp = import_urdf(ROBOTS / f"{name}.urdf")
    toml = load_description(builtin_path(name))
    assert imp.description == toml                    # every field, names included
    # the models built independently agree (not the memoised object twice)
    assert functions_agree(BipedModel(imp.description), BipedModel(toml)) <= 1e-12
    # the URDF's robot carries its joint map (part of the model's key, not of equality)
    m = robot(ROBOTS / f"{name}.urdf")
    assert m.description == robot(name).description and m.description.urdf is not None
    assert m is robot(ROBOTS / f"{name}.urdf")


def test_rabbit_urdf_reads_the_transmissions():
    d = import_urdf(ROBOTS / "rabbit.urdf").description
    assert d.rotor_inertia == 3.32e-4 * 50.0 ** 2          # motorInertia x reduction^2
    assert d.torque_limit == 150.0


@pytest.mark.parametrize("k, flipped, foot_arg", [(1, False, False), (2, True, True),
                                                  (3, True, False), (2, False, True)])
def test_random_biped_through_urdf(tmp_path, k, flipped, foot_arg):
    d = random_description(np.random.default_rng(40 + k), k, name=f"random{k}")
    path = tmp_path / "r.urdf"
    path.write_text(urdf_text(d, flipped=flipped, foot_link=not foot_arg))
    foot = (0.0, 0.0, (1 if flipped else -1) * d.leg[-1].length) if foot_arg else None
    if foot_arg and "foot" in dict(d.point_masses):
        foot = None                                  # the foot mass's link marks it
    got = import_urdf(path, foot=foot).description
    assert dict(got.point_masses).keys() == dict(d.point_masses).keys()
    assert functions_agree(BipedModel(got), BipedModel(d), seed=k) <= 1e-12


def test_foot_argument_when_no_foot_link(tmp_path):
    d = robot("rabbit").description
    path = tmp_path / "shin_only.urdf"
    path.write_text(urdf_text(d, foot_link=False))
    with pytest.raises(ValueError, match=r"no foot: the last leg link 'tibia_left'.*--foot"):
        import_urdf(path)
    m = robot(path, foot=(0.0, 0.0, -0.4))
    assert functions_agree(m, robot("rabbit")) <= 1e-12
    with pytest.raises(ValueError, match="foot: applies to a URDF file"):
        robot("rabbit", foot=(0, 0, -0.4))


def _broken(tmp_path, edit):
    text = (ROBOTS / "rabbit.urdf").read_text()
    new = edit(text)
    assert new != text
    p = tmp_path / "bad.urdf"
    p.write_text(new)
    return p


BAD = {
    "non-planar joint": (lambda s: s.replace('<axis xyz="0 1 0"/>', '<axis xyz="1 0 0"/>', 1),
                         r"joint 'hip_left' turns about .* not a planar robot"),
    "prismatic joint": (lambda s: s.replace('name="knee_right" type="revolute"',
                                            'name="knee_right" type="prismatic"'),
                        r"joint 'knee_right' is prismatic"),
    "legs differ": (lambda s: s.replace('<mass value="3.2"/>', '<mass value="3.3"/>', 1),
                    r"legs differ: link 'tibia_left' has mass 3.3"),
    "unactuated joint": (lambda s: re.sub(r'<transmission name="knee_left_transmission">.*?'
                                          r'</transmission>', "", s, flags=re.S),
                         r"joint 'knee_left' has no actuator .* more than one unactuated joint"),
    "missing inertial": (lambda s: re.sub(r'(<link name="femur_right">\s*)<inertial>.*?</inertial>',
                                          r"\1", s, flags=re.S),
                         r"link 'femur_right' has no <inertial>"),
    "one leg's centre of mass off": (lambda s: s.replace('<origin xyz="0 0 -0.11"',
                                                         '<origin xyz="0.02 0 -0.11"', 1),
                                     r"legs differ: link 'femur_left' has com_offset 0.02, "
                                     r"link 'femur_right' 0"),
    "no foot": (lambda s: re.sub(r'<joint name="foot_left_fixed".*?<link name="foot_left"/>',
                                 "", s, flags=re.S), r"no foot: the last leg link 'tibia_left'"),
    "one leg": (lambda s: re.sub(r'<joint name="hip_right".*(?=</robot>)', "", s, flags=re.S),
                r"the torso 'torso' has 1 jointed children \('hip_left'\); a biped has two legs"),
    "hips apart": (lambda s: s.replace('<origin xyz="0 -0.1 0" rpy="0 0 0"/>',
                                       '<origin xyz="0.05 -0.1 0" rpy="0 0 0"/>', 1),
                   r"hip joints 'hip_left' and 'hip_right' are 0.05 m apart in the plane"),
    "not XML": (lambda s: s[:200], r"cannot parse the URDF"),
    "rotors differ": (lambda s: s.replace("<motorInertia>3.32e-4</motorInertia>",
                                          "<motorInertia>1e-4</motorInertia>", 1),
                      r"reflected rotor inertias differ"),
    "legs differ in the 9th digit": (lambda s: s.replace('<mass value="6.8"/>',
                                                         '<mass value="6.80000002"/>', 1),
                                     r"legs differ: link 'femur_left' has mass 6.80000002, "
                                     r"link 'femur_right' 6.8 \(apart by 2e-08, 2e-09 of "
                                     r"the leg's mass\); match_tol 1e-09 allows less: "
                                     r"--match-tol 2e-09 \(match_tol=\) takes their mean"),
    "rotors differ in the 8th digit": (lambda s: s.replace(
        "<motorInertia>3.32e-4</motorInertia>", "<motorInertia>3.3200001e-4</motorInertia>", 1),
        r"reflected rotor inertias differ: joint 'knee_left' 0.83, joint 'hip_left' "
        r"0.830000025 kg m\^2 \(apart by 2.5e-08;"),
    "link defined twice": (lambda s: s.replace('<link name="tibia_right">',
                                               '<link name="tibia_left">', 1),
                           r"link 'tibia_left' is defined twice"),
    "joint defined twice": (lambda s: s.replace('<joint name="knee_right" type',
                                                '<joint name="knee_left" type', 1),
                            r"joint 'knee_left' is defined twice"),
    "parent not defined": (lambda s: s.replace('<parent link="femur_right"/>',
                                               '<parent link="femur_rigth"/>', 1),
                           r"joint 'knee_right' names parent link 'femur_rigth', which the "
                           r"file does not define"),
    "child not defined": (lambda s: s.replace('<child link="tibia_right"/>',
                                              '<child link="tibia_rigth"/>', 1),
                          r"joint 'knee_right' names child link 'tibia_rigth', which the "
                          r"file does not define"),
    "a loop of joints": (lambda s: s.replace('</robot>', '<joint name="loop" type="fixed">'
                                             '<parent link="foot_left"/><child link="torso"/>'
                                             '</joint></robot>'),
                         r"no root link: the joints make a loop"),
    "a loop beside the root": (lambda s: s.replace('<robot name="RABBIT">',
                                                   '<robot name="RABBIT"><link name="world"/>', 1)
                               .replace('</robot>', '<joint name="loop" type="fixed"><parent '
                                        'link="foot_left"/><child link="torso"/></joint>'
                                        '</robot>'),
                               r"link\(s\) 'torso', .* not connected to the root link 'world': "
                               r"the joints make a loop"),
    "a negative mass beside a heavier fixed child": (
        lambda s: s.replace('<mass value="6.8"/>', '<mass value="-1"/>', 1).replace(
            '<link name="femur_left">', '<joint name="pad_fixed" type="fixed"><parent '
            'link="femur_left"/><child link="pad"/></joint><link name="pad"><inertial><origin '
            'xyz="0 0 -0.2"/><mass value="7.8"/><inertia ixx="0.1" ixy="0" ixz="0" iyy="0.1" '
            'iyz="0" izz="0.1"/></inertial></link><link name="femur_left">', 1),
        r"link 'femur_left' has a negative mass \(-1 kg\)"),
    "lengths in mm": (lambda s: s.replace('xyz="0 0 -0.4"', 'xyz="0 0 -400"'),
                      r"the leg of 'hip_left' is 800 m long: URDF lengths are in metres \(a "
                      r"file in millimetres\?\)"),
    "a nan inertia": (lambda s: s.replace('iyy="0.47"', 'iyy="nan"', 1),
                      r"link 'femur_left': <inertia> has a value that is not finite \(nan\)"),
    "a nan origin": (lambda s: s.replace('<origin xyz="0 0 -0.4" rpy="0 0 0"/>',
                                         '<origin xyz="0 0 nan" rpy="0 0 0"/>', 1),
                     r"joint 'knee_left': <origin> has a value that is not finite \(nan\)"),
    "an infinite axis": (lambda s: s.replace('<axis xyz="0 1 0"/>', '<axis xyz="0 inf 0"/>', 1),
                         r"joint 'hip_left': <axis> has a value that is not finite \(inf\)"),
    "a nan motor inertia": (lambda s: s.replace("<motorInertia>3.32e-4</motorInertia>",
                                                "<motorInertia>nan</motorInertia>", 1),
                            r"the transmission of joint 'hip_left' has motorInertia nan"),
    "mimic joint": (lambda s: s.replace('<joint name="knee_right" type="revolute">',
                                        '<joint name="knee_right" type="revolute"><mimic '
                                        'joint="knee_left" multiplier="1" offset="0"/>'),
                    r"joint 'knee_right' mimics joint 'knee_left'"),
    "some efforts 0": (lambda s: s.replace('<limit effort="150"', '<limit effort="0"', 1),
                       r"joint 'hip_left' has no actuator"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_not_a_planar_biped_is_refused(tmp_path, case):
    edit, message = BAD[case]
    p = _broken(tmp_path, edit)
    with pytest.raises(ValueError, match=message) as e:
        robot(p)
    assert str(p) in str(e.value) and "\n" not in str(e.value)
    out = tmp_path / "robot.toml"
    assert main(["robot", "import", str(p), "--out", str(out)]) == 2
    assert not out.exists()


def test_cli_import_round_trip(tmp_path, capsys):
    out = tmp_path / "rabbit.toml"
    assert main(["robot", "import", str(ROBOTS / "rabbit.urdf"), "--out", str(out),
                 "--json"]) == 0
    body = json.loads(capsys.readouterr().out)
    assert body["legs"] == [["hip_left", "knee_left"], ["hip_right", "knee_right"]]
    assert load_description(out) == robot("rabbit").description
    # every command's --robot takes the URDF too
    assert main(["model", "--robot", str(ROBOTS / "three_link.urdf"), "--json"]) == 0
    D_urdf = json.loads(capsys.readouterr().out)["D"]
    assert main(["model", "--robot", "three_link", "--json"]) == 0
    assert D_urdf == json.loads(capsys.readouterr().out)["D"]


def test_cli_import_bad_arguments(tmp_path, capsys):
    out = tmp_path / "r.toml"
    for argv, text in [([str(tmp_path / "missing.urdf")], "URDF file not found"),
                       ([str(ROBOTS / "rabbit.toml")], "a URDF file (.urdf) is expected"),
                       ([str(ROBOTS / "rabbit.urdf"), "--foot", "0", "0", "nan"],
                        "--foot takes 3 finite numbers")]:
        assert main(["robot", "import", *argv, "--out", str(out)]) == 2
        err = capsys.readouterr().err.strip()
        assert text in err and len(err.splitlines()) == 1
        assert not out.exists()


def test_floating_base_and_unknown_tags_are_fine(tmp_path):
    text = (ROBOTS / "rabbit.urdf").read_text().replace(
        '<robot name="RABBIT">',
        '<robot name="RABBIT"><link name="world"/><joint name="base" type="floating">'
        '<parent link="world"/><child link="torso"/></joint><gazebo><plugin/></gazebo>')
    p = tmp_path / "floating.urdf"
    p.write_text(text)
    imp = import_urdf(p)
    assert imp.description == robot("rabbit").description
    assert any("floating joint 'base'" in n for n in imp.notes)


def test_torso_inertial_in_a_fixed_child_of_a_massless_root(tmp_path):
    """ROS's habit (KDL refuses a root link with inertia): a massless root link carries
    the legs and a fixed child link carries the torso's inertial; the two are one body."""
    text = (ROBOTS / "rabbit.urdf").read_text()
    inertial = re.search(r'<link name="torso">\s*(<inertial>.*?</inertial>)', text, re.S).group(1)
    text = text.replace(inertial, "", 1).replace(
        '<link name="torso">', '<joint name="torso_inertia_fixed" type="fixed"><parent '
        'link="torso"/><child link="torso_inertia"/></joint><link name="torso_inertia">'
        f'{inertial}</link><link name="torso">', 1)
    p = tmp_path / "kdl.urdf"
    p.write_text(text)
    imp = import_urdf(p)
    assert imp.description == robot("rabbit").description
    assert any("'torso_inertia' merged into 'torso'" in n for n in imp.notes)


def test_efforts_all_zero_are_no_limit(tmp_path, capsys):
    """Exporters write effort="0" (and velocity="0") on every joint when they know no
    limit: no torque limit, as without <limit effort>, and --torque-limit sets one."""
    text = (ROBOTS / "rabbit.urdf").read_text().replace('effort="150"', 'effort="0"')
    p = tmp_path / "zero_efforts.urdf"
    p.write_text(text)
    imp = import_urdf(p)
    assert imp.description.torque_limit == float("inf")
    assert any('effort="0"' in n and "no torque limit" in n for n in imp.notes)
    out = tmp_path / "r.toml"
    assert main(["robot", "import", str(p), "--torque-limit", "150", "--out", str(out)]) == 0
    assert load_description(out) == robot("rabbit").description


def test_efforts_far_beyond_the_robots_weight_are_said_to_look_like_a_placeholder(tmp_path):
    """ODRI's Bolt (1.25 kg, legs of 0.4 m) gives effort="1000" on every joint: imported
    as a 1000 N m limit without a word.  A limit of at least PLACEHOLDER_RATIO times
    m g L is now a note; RABBIT's 150 N m (0.6 times its m g L) is not."""
    from biped_casadi.model.torque_limits import PLACEHOLDER_RATIO
    text = (ROBOTS / "rabbit.urdf").read_text()
    d = robot("rabbit").description
    weight = d.total_mass * d.gravity * d.leg_length
    assert not any("placeholder" in n for n in import_urdf(ROBOTS / "rabbit.urdf").notes)
    for effort, said in ((PLACEHOLDER_RATIO * weight * 1.01, True),
                         (PLACEHOLDER_RATIO * weight * 0.99, False)):
        p = tmp_path / "big_efforts.urdf"
        p.write_text(text.replace('effort="150"', f'effort="{effort!r}"'))
        imp = import_urdf(p)
        assert imp.description.torque_limit == pytest.approx(effort)
        notes = [n for n in imp.notes if "placeholder" in n]
        assert len(notes) == int(said), imp.notes
        assert not said or f"are {effort / weight:.0f} times" in notes[0], notes
        assert not any("placeholder" in n for n in import_urdf(p, torque_limit=150.0).notes)


def test_joint_damping_and_friction_are_said_to_be_ignored(tmp_path):
    """<dynamics damping friction> is physics the model has not (rigid, frictionless
    joints): the import says it leaves it out instead of dropping it silently."""
    text = (ROBOTS / "rabbit.urdf").read_text().replace(
        '<axis xyz="0 1 0"/>', '<axis xyz="0 1 0"/><dynamics damping="0.5" friction="1.2"/>')
    p = tmp_path / "damped.urdf"
    p.write_text(text)
    imp = import_urdf(p)
    assert imp.description == robot("rabbit").description
    said = [n for n in imp.notes if "<dynamics>" in n]
    assert len(said) == 1 and "hip_left" in said[0] and "damping 0.5" in said[0], imp.notes


def test_joint_ranges_are_said_to_be_not_held_to(tmp_path):
    """A revolute joint's <limit lower upper> narrower than a turn is not a constraint of
    the gaits or walks: the import says so (RABBIT's +-3.14 is no range and says nothing)."""
    src = (ROBOTS / "rabbit.urdf").read_text()
    assert not [n for n in import_urdf(ROBOTS / "rabbit.urdf").notes if "ranges" in n]
    knee = src.index('name="knee_left"')
    at = src.index('lower="-3.14" upper="3.14"', knee)
    p = tmp_path / "ranged.urdf"
    p.write_text(src[:at] + 'lower="-0.1" upper="2.5"' + src[at + 26:])
    imp = import_urdf(p)
    assert imp.description == robot("rabbit").description
    said = [n for n in imp.notes if "ranges" in n]
    assert len(said) == 1 and "knee_left [-0.1, 2.5]" in said[0] and "hip" not in said[0], said


def test_torso_geometry_below_the_hip_is_not_called_missing(tmp_path):
    """A torso whose centre of mass hangs below the hip (its up direction points down)
    and whose box stands above it: the note on its drawn length says where the geometry
    is, not that there is none."""
    text = (ROBOTS / "rabbit.urdf").read_text().replace(
        '<origin xyz="0 0 0.24" rpy="0 0 0"/>', '<origin xyz="0 0 -0.05" rpy="0 0 0"/>', 1)
    p = tmp_path / "low.urdf"
    p.write_text(text)
    notes = import_urdf(p).notes
    assert not any("no box, cylinder or sphere" in n for n in notes), notes
    assert any("geometry does not reach above the hip" in n for n in notes), notes


def test_all_axes_flipped_print_no_negative_zeros(tmp_path, capsys):
    """Every joint about -y: the plane's normal is +y, written [0, 1, 0] (it printed
    [-0, 1, -0] and kept -0.0 in the description's map)."""
    p = tmp_path / "flipped.urdf"
    p.write_text((ROBOTS / "rabbit.urdf").read_text().replace('<axis xyz="0 1 0"/>',
                                                              '<axis xyz="0 -1 0"/>'))
    axis = import_urdf(p).urdf_map.axis
    assert axis == (0.0, 1.0, 0.0) and all(math.copysign(1.0, v) > 0 for v in axis), axis
    assert main(["robot", "import", str(p), "--out", str(tmp_path / "r.toml")]) == 0
    assert "-0" not in capsys.readouterr().out.split("pitch:")[1].split("\n")[0]
