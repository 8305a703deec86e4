"""URDF variants of a robot description, written as other tools write them, and the
independent Pinocchio twin of such a file for the tests.

:func:`variant_urdf` writes a description as a URDF whose zero pose, frames and axes are
chosen per joint: every leg link's frame at zero joint angles is turned by ``beta``
about y (absolute, from the torso frame; 0: the link hangs straight down) and optionally
rolled upside down (``roll``: its z axis then points up the link); each joint's axis is
written as +y or -y of the torso (``axis`` -1 flips it); the torso's centre of mass may
sit off the torso frame's z axis (``torso_tilt``: its up direction is then tilted);
``floating`` / ``planar`` add a world link and a root joint; ``frames`` hangs sensor
frames (a massless IMU, a sensor with mass and inertia, merged into its link);
``continuous`` writes continuous joints without <limit>; the legs may be listed in any
order (``right_first``).

:func:`pinocchio_state` places the Pinocchio model built from the same file (a free
flyer at the root) in the state of the pinned model: the base orientation from the
pitch, the joint angles, the base position and velocity such that the stance foot is at
the origin and at rest.
"""
from __future__ import annotations

import math

import numpy as np
import pinocchio as pin


def _ry(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def _rx(a):
    c, s = math.cos(a), math.sin(a)
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def _rpy(R) -> str:
    """URDF rpy of R = Rz(y) Ry(p) Rx(r)."""
    p = -math.asin(max(-1.0, min(1.0, R[2, 0])))
    r = math.atan2(R[2, 1], R[2, 2])
    y = math.atan2(R[1, 0], R[0, 0])
    return f"{r!r} {p!r} {y!r}"


def _vec(v) -> str:
    return " ".join(repr(float(x)) for x in v)


def _inertial(mass, com, I_plane, R_own, ixz=0.0):
    """<inertial> in a link frame whose rotation from the canonical frame is R_own."""
    Ic = np.array([[I_plane + 0.05, 0, ixz], [0, I_plane, 0], [ixz, 0, I_plane + 0.07]])
    Io = R_own.T @ Ic @ R_own
    Io[np.abs(Io) < 1e-15] = 0.0
    return (f'<inertial><origin xyz="{_vec(R_own.T @ com)}" rpy="0 0 0"/>'
            f'<mass value="{float(mass)!r}"/><inertia ixx="{float(Io[0, 0])!r}" '
            f'ixy="{float(Io[0, 1])!r}" ixz="{float(Io[0, 2])!r}" iyy="{float(Io[1, 1])!r}" '
            f'iyz="{float(Io[1, 2])!r}" izz="{float(Io[2, 2])!r}"/></inertial>')


def variant_urdf(d, beta=None, roll=None, axis=None, torso_tilt=0.0, floating=False,
                 planar=False, frames=False, continuous=False, right_first=False,
                 name=None) -> str:
    """A URDF of description ``d`` (module docstring).

    beta, roll, axis: dicts keyed by (side, i) -> value, side 'left'/'right', i the link
    from the hip (0-based); missing entries: 0, False, +1."""
    beta, roll, axis = beta or {}, roll or {}, axis or {}
    pm = dict(d.point_masses)
    inner = ["knee"] if d.k == 2 else [f"joint{j}" for j in range(1, d.k)]
    t = d.torso
    # the torso's centre of mass, tilted by torso_tilt from z (its up direction)
    tc = np.array([t.com * math.sin(torso_tilt), 0.0, t.com * math.cos(torso_tilt)])
    up_t = np.array([math.sin(torso_tilt), 0.0, math.cos(torso_tilt)])
    fw_t = np.array([math.cos(torso_tilt), 0.0, -math.sin(torso_tilt)])
    tc = tc + t.com_offset * fw_t
    top = (t.length / 2) * up_t
    out = [f'<robot name="{name or d.name}">']
    if floating or planar:
        kind = "floating" if floating else "planar"
        ax = '' if floating else '<axis xyz="0 1 0"/>'
        out.append(f'<link name="world"/><joint name="root" type="{kind}"><parent link="world"/>'
                   f'<child link="torso"/>{ax}</joint>')
    out.append(f'<link name="torso">{_inertial(t.mass, tc, t.inertia, np.eye(3), 0.02)}'
               f'<visual><origin xyz="{_vec(top)}" rpy="0 {torso_tilt!r} 0"/><geometry>'
               f'<box size="0.1 0.1 {t.length!r}"/></geometry></visual></link>')
    if frames:
        out.append('<joint name="imu_fix" type="fixed"><parent link="torso"/><child link="imu"/>'
                   '<origin xyz="0.05 0 0.3" rpy="0.3 0.2 0.1"/></joint><link name="imu"/>')
    if "hip" in pm:
        out.append(f'<joint name="hip_mass_fix" type="fixed"><parent link="torso"/>'
                   f'<child link="hip_mass"/></joint><link name="hip_mass"><inertial>'
                   f'<mass value="{pm["hip"]!r}"/><inertia ixx="0" ixy="0" ixz="0" iyy="0" '
                   f'iyz="0" izz="0"/></inertial></link>')
    sides = ("right", "left") if right_first else ("left", "right")
    for side in sides:
        y = 0.1 if side == "left" else -0.1
        parent, R_parent, b_parent = "torso", np.eye(3), 0.0
        for i, link in enumerate(d.leg):
            b = float(beta.get((side, i), 0.0))
            Rc = _ry(b)                                   # canonical: link along -z
            Rr = _rx(math.pi) if roll.get((side, i)) else np.eye(3)
            R = Rc @ Rr                                   # the link frame (torso frame)
            if i == 0:
                pos = np.array([0.0, y, 0.0])
            else:                                         # the previous link's distal end
                pos = R_parent.T @ (_ry(b_parent) @ np.array([0, 0, -d.leg[i - 1].length]))
            rel = R_parent.T @ R
            s = axis.get((side, i), 1)
            ax = R.T @ np.array([0.0, float(s), 0.0])
            ax[np.abs(ax) < 1e-15] = 0.0
            jname = f"{link.name}_{side}_joint"
            kind = "continuous" if continuous else "revolute"
            limit = "" if continuous else \
                f'<limit effort="{d.torque_limit!r}" velocity="20" lower="-6" upper="6"/>'
            out.append(f'<joint name="{jname}" type="{kind}"><parent link="{parent}"/>'
                       f'<child link="{link.name}_{side}"/><origin xyz="{_vec(pos)}" '
                       f'rpy="{_rpy(rel)}"/><axis xyz="{_vec(ax)}"/>{limit}</joint>')
            com_c = np.array([link.com_offset, 0.0, -link.com])      # canonical frame
            out.append(f'<link name="{link.name}_{side}">'
                       f'{_inertial(link.mass, com_c, link.inertia, Rr, 0.01)}</link>')
            if frames and i == 0:        # a sensor with mass and inertia: merged into the link
                out.append(f'<joint name="sensor_{side}_fix" type="fixed"><parent '
                           f'link="{link.name}_{side}"/><child link="sensor_{side}"/>'
                           f'<origin xyz="{_vec(Rr.T @ [0.01, 0.02, -0.05])}" '
                           f'rpy="{_rpy(Rr.T @ _ry(0.4))}"/></joint>'
                           f'<link name="sensor_{side}"><inertial><origin xyz="0.01 0 0.02"/>'
                           f'<mass value="0.5"/><inertia ixx="0.001" ixy="0" ixz="0" '
                           f'iyy="0.002" iyz="0" izz="0.001"/></inertial></link>')
            end = Rr.T @ np.array([0.0, 0.0, -link.length])          # distal end, own frame
            joint_mass = "foot" if i == d.k - 1 else inner[i]
            if joint_mass in pm:
                out.append(f'<joint name="{joint_mass}_{side}_mass_fix" type="fixed"><parent '
                           f'link="{link.name}_{side}"/><child link="{joint_mass}_{side}_mass"/>'
                           f'<origin xyz="{_vec(end)}"/></joint><link name="{joint_mass}_'
                           f'{side}_mass"><inertial><mass value="{pm[joint_mass]!r}"/><inertia '
                           f'ixx="0" ixy="0" ixz="0" iyy="0" iyz="0" izz="0"/></inertial></link>')
            out.append(f'<transmission name="{jname}_t"><type>transmission_interface/'
                       f'SimpleTransmission</type><joint name="{jname}"><hardwareInterface>'
                       f'EffortJointInterface</hardwareInterface></joint><actuator name='
                       f'"{jname}_m"><mechanicalReduction>{20.0 + i!r}</mechanicalReduction>'
                       f'<motorInertia>{d.rotor_inertia / (20.0 + i) ** 2!r}</motorInertia>'
                       f'</actuator></transmission>')
            parent, R_parent, b_parent = f"{link.name}_{side}", R, b
        if "foot" not in pm:
            end = R_parent.T @ (_ry(b_parent) @ np.array([0, 0, -d.leg[-1].length]))
            out.append(f'<joint name="foot_{side}_fix" type="fixed"><parent link="{parent}"/>'
                       f'<child link="foot_{side}"/><origin xyz="{_vec(end)}"/></joint>'
                       f'<link name="foot_{side}"/>')
    out.append("</robot>")
    return "\n".join(out)


def pinocchio_model(text: str, rotor: float, joint_names):
    """Pinocchio's model of a URDF text (free flyer at the root unless the file has a
    floating joint), the leg joints' armature set to the reflected rotor inertia."""
    if 'type="floating"' in text:
        m = pin.buildModelFromXML(text)
    else:
        text = text.replace('<link name="world"/><joint name="root" type="planar">'
                            '<parent link="world"/><child link="torso"/><axis xyz="0 1 0"/>'
                            '</joint>', "")
        m = pin.buildModelFromXML(text, pin.JointModelFreeFlyer())
    for n in joint_names:
        m.armature[m.joints[m.getJointId(n)].idx_v] = rotor
    return m


def pinocchio_state(m, data, names, x, dx, foot_frame: str):
    """(q, v) of the Pinocchio model for pitch + joint angles ``x`` and rates ``dx``
    (joints ``names``, URDF order), the stance foot (frame ``foot_frame``) pinned at the
    origin: base orientation Ry(pitch)."""
    q = pin.neutral(m)
    v = np.zeros(m.nv)
    R = _ry(x[0])
    q[3:7] = pin.Quaternion(R).coeffs()
    v[3:6] = R.T @ np.array([0.0, dx[0], 0.0])
    for n, a, da in zip(names, x[1:], dx[1:]):
        j = m.joints[m.getJointId(n)]
        if j.nq == 2:
            q[j.idx_q:j.idx_q + 2] = [math.cos(a), math.sin(a)]
        else:
            q[j.idx_q] = a
        v[j.idx_v] = da
    fid = m.getFrameId(foot_frame)
    pin.framesForwardKinematics(m, data, q)
    q[:3] = -data.oMf[fid].translation
    pin.forwardKinematics(m, data, q, v)
    vf = pin.getFrameVelocity(m, data, fid, pin.ReferenceFrame.LOCAL_WORLD_ALIGNED).linear
    v[:3] = R.T @ (-vf)
    return q, v


# ------------------------------------------------------------------ the comparisons
def rel_error(a, b) -> float:
    """Largest difference relative to max(1, |b|)."""
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b))) / max(1.0, np.max(np.abs(b))))


def random_states(nq: int, n: int, seed: int, span: float = 1.0):
    """``n`` (q, dq): angles within +-span rad, rates within +-3 rad/s."""
    rng = np.random.default_rng(seed)
    return zip(rng.uniform(-span, span, (n, nq)), rng.uniform(-3, 3, (n, nq)))


def mass_matrix(m, data, qp) -> np.ndarray:
    """Pinocchio's joint-space mass matrix, both triangles."""
    M = pin.crba(m, data, qp)
    return np.triu(M) + np.triu(M, 1).T


def pinned(m, data, umap, q, dq, leg: int, foot: str) -> tuple:
    """Pinocchio's (q, v, G) for the model's state, stance leg ``leg`` on frame ``foot``
    pinned at the origin: G maps dq to Pinocchio's v."""
    x, dx = umap.from_model(q, dq, leg)
    qp, vp = pinocchio_state(m, data, umap.names, x, dx, foot)
    G = np.column_stack([pinocchio_state(m, data, umap.names, x,
                                         umap.from_model(q, e, leg)[1], foot)[1]
                         for e in np.eye(len(q))])
    return qp, vp, G


def energy_error(model, umap, m, data, foot_of, states) -> float:
    """The largest relative difference of kinetic and potential energy, the model
    against Pinocchio, over ``states`` on either stance leg (``foot_of(leg)``: its
    foot frame)."""
    worst = 0.0
    for q, dq in states:
        for leg in (1, 2):
            qp, vp, _ = pinned(m, data, umap, q, dq, leg, foot_of(leg))
            K, V, _ = (float(v) for v in model.energy(q, dq))
            worst = max(worst, rel_error(K, 0.5 * vp @ mass_matrix(m, data, qp) @ vp),
                        rel_error(V, pin.computePotentialEnergy(m, data, qp)))
    return worst


def dynamics_error(model, umap, m, data, foot_of, states) -> float:
    """The largest relative difference of D and H against Pinocchio's mass matrix and
    bias forces projected on the pinned motions (D = G' M G, H = G' rnea(q, v, a) with
    the base's acceleration a that keeps the stance foot at rest at ddq = 0)."""
    worst = 0.0
    for q, dq in states:
        for leg in (1, 2):
            qp, vp, G = pinned(m, data, umap, q, dq, leg, foot_of(leg))
            worst = max(worst, rel_error(model.D(q), G.T @ mass_matrix(m, data, qp) @ G))
            a = np.zeros(m.nv)
            pin.forwardKinematics(m, data, qp, vp, a)
            af = pin.getFrameClassicalAcceleration(m, data, m.getFrameId(foot_of(leg)),
                                                   pin.ReferenceFrame.LOCAL_WORLD_ALIGNED).linear
            a[:3] = pin.Quaternion(qp[3:7]).matrix().T @ (-af)
            H = G.T @ pin.rnea(m, data, qp, vp, a)
            worst = max(worst, rel_error(np.array(model.H(q, dq)).ravel(), H))
    return worst


def torque_error(model, umap, m, data, foot_of, seed: int = 11) -> float:
    """The URDF joints' torques of the map against the model's generalised forces: with
    Pinocchio's joint torques tau (zero on the base), G' tau = B u."""
    rng, worst = np.random.default_rng(seed), 0.0
    for leg in (1, 2):
        q, dq = rng.uniform(-1, 1, model.nq), rng.uniform(-2, 2, model.nq)
        _, _, G = pinned(m, data, umap, q, dq, leg, foot_of(leg))
        u = rng.uniform(-50, 50, model.nu)
        f = np.zeros(m.nv)
        for name, t in zip(umap.names, umap.torques(u, leg)):
            f[m.joints[m.getJointId(name)].idx_v] = t
        worst = max(worst, rel_error(G.T @ f, model.B @ u))
    return worst


# ------------------------------------------------------------------ a 3-D biped
#: per side: (joint, parent, child, joint position (torso frame, left side), axis
#: (torso frame), link mass, centre of mass from the joint, principal inertias, the
#: link frame's rotation from the torso's (exporters' frames: turned), effort)
_LEG3D = (
    ("hip_yaw", None, "hip_yaw_link", (0.0, 0.09, -0.06), "z", 0.6, (-0.01, 0.005, -0.03),
     (0.0012, 0.0010, 0.0008), (0.0, 0.0, 0.0), 60.0),
    ("hip_roll", "hip_yaw_link", "hip_roll_link", (0.0, 0.10, -0.11), "x", 0.9,
     (0.005, 0.012, -0.02), (0.0020, 0.0018, 0.0011), (0.0, 0.0, 0.4), 60.0),
    ("hip_pitch", "hip_roll_link", "thigh", (0.0, 0.11, -0.14), "y", 4.2,
     (0.015, 0.01, -0.16), (0.065, 0.060, 0.012), (0.0, 0.0, math.pi / 2), 120.0),
    ("knee", "thigh", "shin", (0.0, 0.10, -0.54), "y", 2.6, (0.005, 0.005, -0.17),
     (0.035, 0.033, 0.005), (0.3, 0.2, 0.0), 120.0),
    ("ankle_pitch", "shin", "ankle_link", (0.0, 0.10, -0.92), "y", 0.25, (0.0, 0.0, -0.01),
     (0.0002, 0.0002, 0.0002), (0.0, 0.0, 0.0), 80.0),
    ("ankle_roll", "ankle_link", "foot", (0.0, 0.10, -0.935), "x", 0.9, (0.04, 0.005, -0.035),
     (0.0012, 0.0040, 0.0045), (math.pi / 2, 0.0, -0.5), 60.0),
)
#: the arms: shoulder pitch and elbow, as the legs' rows
_ARM3D = (
    ("shoulder", None, "upper_arm", (0.0, 0.20, 0.42), "y", 1.3, (0.0, 0.02, -0.12),
     (0.008, 0.0082, 0.0012), (0.0, 0.0, 0.0), 40.0),
    ("elbow", "upper_arm", "forearm", (0.0, 0.22, 0.16), "y", 0.9, (0.01, 0.0, -0.12),
     (0.005, 0.0052, 0.0008), (0.0, -0.7, 0.0), 40.0),
)
_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


def _rot_rpy(r, p, y):
    cr, sr, cp, sp, cy, sy = (math.cos(r), math.sin(r), math.cos(p), math.sin(p),
                              math.cos(y), math.sin(y))
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _tensor(principal, seed):
    """A full inertia tensor (products of inertia) of the principal moments, turned by a
    rotation fixed by ``seed``."""
    a, b, c = 0.3 + 0.1 * seed, -0.2 + 0.05 * seed, 0.15 * seed
    Q = _rot_rpy(a, b, c)
    return Q @ np.diag(principal) @ Q.T


def _mirror(v, side):
    return np.array([v[0], side * v[1], v[2]])


def _link3d(name, mass, com, I, R, p, visual=""):
    """A link whose frame is at p, turned by R (torso frame), its inertial given in the
    torso frame."""
    Io = R.T @ I @ R
    c = R.T @ (np.asarray(com, float) - p)
    return (f'<link name="{name}"><inertial><origin xyz="{_vec(c)}" rpy="0 0 0"/>'
            f'<mass value="{float(mass)!r}"/><inertia ixx="{float(Io[0, 0])!r}" ixy="{float(Io[0, 1])!r}" '
            f'ixz="{float(Io[0, 2])!r}" iyy="{float(Io[1, 1])!r}" iyz="{float(Io[1, 2])!r}" '
            f'izz="{float(Io[2, 2])!r}"/>'
            f'</inertial>{visual}</link>')


def biped3d_urdf(arms=False, sole=True, mirror=True, flip_right_knee=False, differ=None,
                 rotor=0.4, name="biped3d") -> str:
    """A 3-D biped as CAD exporters write one: per leg hip yaw (z), hip roll (x), hip
    pitch (y), knee (y), ankle pitch (y) and ankle roll (x), the hips 0.18 m apart
    across, link frames turned every which way, centres of mass off the links (also
    across) and full inertia tensors with products of inertia; the right leg the mirror
    image of the left (``mirror``; else the left's tensors as they are), optionally its
    knee's axis flipped; a sole frame under each foot (``sole``); ``arms``: a shoulder
    and an elbow (both about y) per side.  ``differ``: 'plane' gives the right thigh 1 %
    more inertia about y, 'across' changes only what the plane does not see (its
    moments about x and z, its products with x, its centre of mass across).  Every
    joint has a transmission (reflected rotor inertia ``rotor``) and an effort limit."""
    torso_I = np.array([[0.45, 0.004, 0.03], [0.004, 0.40, -0.006], [0.03, -0.006, 0.12]])
    out = [f'<robot name="{name}">',
           _link3d("torso", 11.0 if arms else 14.0, (0.02, 0.004, 0.22), torso_I, np.eye(3),
                   np.zeros(3), '<visual><origin xyz="0 0 0.25"/><geometry><box size="0.2 '
                   '0.3 0.5"/></geometry></visual>')]
    rows = [(r, "leg") for r in _LEG3D] + ([(r, "arm") for r in _ARM3D] if arms else [])
    for side, s in (("l", 1.0), ("r", -1.0)):
        frames = {"torso": (np.eye(3), np.zeros(3))}
        for k, ((jn, parent, child, pos, ax, mass, com, pr, rpy, effort), _) in enumerate(rows):
            parent = f"{parent}_{side}" if parent else "torso"
            p = _mirror(pos, s)
            R = _rot_rpy(*rpy) if s > 0 else _rot_rpy(-rpy[0], rpy[1], -rpy[2])
            I = _tensor(pr, k)
            if s < 0 and mirror:
                M = np.diag([1.0, -1.0, 1.0])
                I = M @ I @ M
            c = p + _mirror(com, s)
            if s < 0 and differ == "plane" and child == "thigh":
                I = I + np.diag([0.0, 0.01 * I[1, 1], 0.0])
            if s < 0 and differ == "across" and child == "thigh":
                I = I + np.array([[0.004, 0.0, 0.002], [0.0, 0.0, 0.0], [0.002, 0.0, 0.003]])
                c = c + np.array([0.0, 0.02, 0.0])
            Rp, pp = frames[parent]
            a = np.array(_AXES[ax]) * (-1.0 if flip_right_knee and s < 0 and jn == "knee" else 1.0)
            a = R.T @ a
            a[np.abs(a) < 1e-15] = 0.0
            out.append(f'<joint name="{jn}_{side}" type="revolute"><parent link="{parent}"/>'
                       f'<child link="{child}_{side}"/><origin xyz="{_vec(Rp.T @ (p - pp))}" '
                       f'rpy="{_rpy(Rp.T @ R)}"/><axis xyz="{_vec(a)}"/><limit effort='
                       f'"{effort!r}" velocity="10" lower="-2.5" upper="2.5"/></joint>')
            visual = ('<visual><origin xyz="0.03 0 -0.05"/><geometry><box size="0.22 0.1 '
                      '0.03"/></geometry></visual>') if child == "foot" else ""
            out.append(_link3d(f"{child}_{side}", mass, c, I, R, p, visual))
            red = 50.0 + k
            out.append(f'<transmission name="{jn}_{side}_t"><type>transmission_interface/'
                       f'SimpleTransmission</type><joint name="{jn}_{side}"><hardwareInterface>'
                       f'EffortJointInterface</hardwareInterface></joint><actuator name='
                       f'"{jn}_{side}_m"><mechanicalReduction>{red!r}</mechanicalReduction>'
                       f'<motorInertia>{rotor / red ** 2!r}</motorInertia></actuator>'
                       f'</transmission>')
            frames[f"{child}_{side}"] = (R, p)
        if sole:
            R, p = frames[f"foot_{side}"]
            out.append(f'<joint name="sole_{side}_fix" type="fixed"><parent link="foot_{side}"/>'
                       f'<child link="sole_{side}"/><origin xyz="{_vec(R.T @ np.array([0.01, 0.0, -0.055]))}"'
                       f'/></joint><link name="sole_{side}"/>')
    out.append("</robot>")
    return "\n".join(out)


def pinocchio_reduced(text: str, rotor: float, joint_names, locked: dict):
    """Pinocchio's model of a URDF text (free flyer at the root) with the joints of
    ``locked`` (name -> angle) locked at their angles by ``pinocchio.buildReducedModel``,
    the remaining leg joints' armature the reflected rotor inertia."""
    full = pin.buildModelFromXML(text, pin.JointModelFreeFlyer())
    q_ref = pin.neutral(full)
    for n, a in locked.items():
        q_ref[full.joints[full.getJointId(n)].idx_q] = a
    m = pin.buildReducedModel(full, [full.getJointId(n) for n in locked], q_ref)
    for n in joint_names:
        m.armature[m.joints[m.getJointId(n)].idx_v] = rotor
    return m
