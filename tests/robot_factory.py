"""One factory for the robots of the tests: descriptions (built-in, random, broken) and
the independent Pinocchio twin of any description (in the style of crocoddyl's
unittest factory).

The Pinocchio chain follows SPEC section 1's coordinates for legs of k links: stance
leg from the foot up, torso, swing leg from the hip down, every joint a revolute joint
about +y, so a positive angle leans the link's +z axis toward +x; the stance leg's and
the torso's +z axes point away from the stance foot, the swing leg's toward the hip.
"""
from __future__ import annotations

import numpy as np
import pinocchio as pin

from biped_casadi import Link, RobotDescription


def random_description(rng, k: int, point_masses: bool = True, name: str = "random"):
    """A random but physical description with ``k`` links per leg."""
    def link(nm):
        length = rng.uniform(0.2, 0.6)
        return Link(nm, rng.uniform(0.5, 8.0), length, rng.uniform(0.0, length),
                    rng.uniform(0.0, 0.5))
    joints = ["hip", "foot"] + (["knee"] if k == 2 else [f"joint{j}" for j in range(1, k)])
    pm = tuple(sorted((j, float(rng.uniform(0.0, 5.0))) for j in joints)) if point_masses else ()
    return RobotDescription(name=name, torso=link("torso"),
                            leg=tuple(link(f"link{i + 1}") for i in range(k)),
                            point_masses=pm, rotor_inertia=float(rng.uniform(0.0, 1.0)),
                            gravity=9.81, torque_limit=100.0)


def pinocchio_chain(d: RobotDescription, planar_base: bool):
    """The Pinocchio model of a description and the frame id of its swing foot."""
    m = pin.Model()
    m.gravity = pin.Motion(np.array([0, 0, -d.gravity, 0, 0, 0]))
    parent = 0
    if planar_base:      # extended coordinates: stance-foot x and z
        parent = m.addJoint(parent, pin.JointModelPX(), pin.SE3.Identity(), "base_x")
        m.appendBodyToJoint(parent, pin.Inertia.Zero(), pin.SE3.Identity())
        parent = m.addJoint(parent, pin.JointModelPZ(), pin.SE3.Identity(), "base_z")
        m.appendBodyToJoint(parent, pin.Inertia.Zero(), pin.SE3.Identity())

    def body(mass, I, com_z):
        return pin.Inertia(mass, np.array([0, 0, com_z]), np.diag([I, I, I]))

    def point(mass, z):
        return pin.Inertia(mass, np.array([0, 0, z]), np.zeros((3, 3)))

    def at(z):
        return pin.SE3(np.eye(3), np.array([0, 0, z]))

    pm = dict(d.point_masses)
    inner = ["knee"] if d.k == 2 else [f"joint{j}" for j in range(1, d.k)]
    k = d.k
    place = 0.0
    ids = []
    for j in range(k):                              # stance leg, from the foot up
        link = d.leg[k - 1 - j]
        parent = m.addJoint(parent, pin.JointModelRY(), at(place), f"q{len(ids) + 1}")
        ids.append(parent)
        m.appendBodyToJoint(parent, body(link.mass, link.inertia, link.length - link.com),
                            pin.SE3.Identity())
        if j == 0 and "foot" in pm:
            m.appendBodyToJoint(parent, point(pm["foot"], 0.0), pin.SE3.Identity())
        if j > 0 and inner[k - 1 - j] in pm:        # the joint at this link's lower end
            m.appendBodyToJoint(parent, point(pm[inner[k - 1 - j]], 0.0), pin.SE3.Identity())
        place = link.length
    parent = m.addJoint(parent, pin.JointModelRY(), at(place), f"q{len(ids) + 1}")   # torso
    ids.append(parent)
    m.appendBodyToJoint(parent, body(d.torso.mass, d.torso.inertia, d.torso.com), pin.SE3.Identity())
    if "hip" in pm:
        m.appendBodyToJoint(parent, point(pm["hip"], 0.0), pin.SE3.Identity())
    place = 0.0
    for j in range(k):                              # swing leg, from the hip down
        link = d.leg[j]
        parent = m.addJoint(parent, pin.JointModelRY(), at(place), f"q{len(ids) + 1}")
        ids.append(parent)
        m.appendBodyToJoint(parent, body(link.mass, link.inertia, -link.com), pin.SE3.Identity())
        if j < k - 1 and inner[j] in pm:            # the joint at this link's lower end
            m.appendBodyToJoint(parent, point(pm[inner[j]], -link.length), pin.SE3.Identity())
        if j == k - 1 and "foot" in pm:
            m.appendBodyToJoint(parent, point(pm["foot"], -link.length), pin.SE3.Identity())
        place = -link.length
    foot = m.addFrame(pin.Frame("foot_sw", parent, 0, at(place), pin.FrameType.OP_FRAME))
    arm = np.zeros(m.nv)
    arm[m.nv - (2 * k):] = d.rotor_inertia        # reflected rotor inertia on q2..qn
    m.armature = arm
    return m, foot


def urdf_text(d: RobotDescription, flipped: bool = False, foot_link: bool = True,
              transmissions: bool = True, gear: float = 50.0) -> str:
    """A URDF of a description: torso at the root, two legs of revolute joints about +y.

    ``flipped``: every leg link's frame turned upside down (roll pi: its z axis points
    down the leg, its joint axis written as -y) and every inertial turned about y, to
    exercise the frames.  ``foot_link``: a fixed child link marks each foot (else the
    importer needs ``foot=``: (0, 0, -L) in the last link's frame, (0, 0, L) flipped).
    The rotor inertia is written as motorInertia with ``gear`` (or no transmissions
    when ``transmissions`` is False, which needs a zero rotor inertia)."""
    pm = dict(d.point_masses)
    inner = ["knee"] if d.k == 2 else [f"joint{j}" for j in range(1, d.k)]

    def inertial(mass, I, z, tilt=0.0):
        Ia = I + 0.1                      # other axes: anything (they do not count)
        return (f'<inertial><origin xyz="0 0 {z!r}" rpy="0 {tilt!r} 0"/><mass value="{mass!r}"/>'
                f'<inertia ixx="{Ia!r}" ixy="0" ixz="0" iyy="{I!r}" iyz="0" izz="{Ia!r}"/>'
                f'</inertial>')

    def point(name, parent, z, mass):
        return (f'<joint name="{name}_fix" type="fixed"><parent link="{parent}"/>'
                f'<child link="{name}"/><origin xyz="0 0 {z!r}"/></joint>'
                f'<link name="{name}"><inertial><mass value="{mass!r}"/><inertia ixx="0" '
                f'ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial></link>')

    s = sgn = -1.0 if not flipped else 1.0       # z of "down the link" in its own frame
    out = [f'<robot name="{d.name}">',
           f'<link name="torso">{inertial(d.torso.mass, d.torso.inertia, d.torso.com)}'
           f'<visual><origin xyz="0 0 {d.torso.length / 2!r}"/><geometry><box size="0.1 0.1 '
           f'{d.torso.length!r}"/></geometry></visual></link>']
    if "hip" in pm:
        out.append(point("hip_mass", "torso", 0.0, pm["hip"]))
    for side, y in (("left", 0.1), ("right", -0.1)):
        parent = "torso"
        for i, link in enumerate(d.leg):
            name = f"{link.name}_{side}"
            if i == 0:
                origin = f'xyz="0 {y!r} 0" rpy="{np.pi if flipped else 0.0!r} 0 0"'
            else:
                origin = f'xyz="0 0 {sgn * d.leg[i - 1].length!r}"'
            axis = "0 -1 0" if flipped else "0 1 0"
            out.append(f'<joint name="j{i}_{side}" type="revolute"><parent link="{parent}"/>'
                       f'<child link="{name}"/><origin {origin}/><axis xyz="{axis}"/>'
                       f'<limit effort="{d.torque_limit!r}" velocity="10" lower="-3" upper="3"/>'
                       f'</joint>')
            out.append(f'<link name="{name}">{inertial(link.mass, link.inertia, s * link.com, 0.3)}'
                       f'</link>')
            if i < d.k - 1 and inner[i] in pm:
                out.append(point(f"{inner[i]}_mass_{side}", name, sgn * link.length, pm[inner[i]]))
            if transmissions:
                out.append(f'<transmission name="t{i}_{side}"><type>transmission_interface/'
                           f'SimpleTransmission</type><joint name="j{i}_{side}"><hardwareInterface>'
                           f'EffortJointInterface</hardwareInterface></joint><actuator name='
                           f'"m{i}_{side}"><mechanicalReduction>{gear!r}</mechanicalReduction>'
                           f'<motorInertia>{d.rotor_inertia / gear**2!r}</motorInertia></actuator>'
                           f'</transmission>')
            parent = name
        if "foot" in pm:
            out.append(point(f"foot_{side}", parent, sgn * d.leg[-1].length, pm["foot"]))
        elif foot_link:
            out.append(f'<joint name="foot_{side}_fix" type="fixed"><parent link="{parent}"/>'
                       f'<child link="foot_{side}"/><origin xyz="0 0 {sgn * d.leg[-1].length!r}"/>'
                       f'</joint><link name="foot_{side}"/>')
    out.append("</robot>")
    return "\n".join(out)
