"""Planar point-foot bipeds (torso + two identical legs of k links, one degree of
underactuation): kinematics, Lagrangian dynamics and impact map as CasADi SX
expressions, exposed as named ``casadi.Function`` objects.

Coordinates follow docs: theory §1, generalised to k links per leg: absolute link angles
phi_i measured from the vertical (positive leaning to +x), the stance leg's links
pointing up from the stance foot, the torso up from the hip, the swing leg's links
pointing from the swing foot toward the hip; q1 = phi1 (the unactuated angle of the
stance leg's lowest link), q_i = phi_i - phi_{i-1} (relative angles up the stance leg,
the torso, then down the swing leg); stance foot at the origin.  RABBIT (k = 2) is
q = (stance tibia, stance knee, stance hip, swing hip, swing knee); the three-link
biped (k = 1) is q = (stance leg, torso rel. stance leg, swing leg rel. torso).
"""
from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from ..caching import cached
from .description import BUILTIN, RobotDescription, builtin_path, load_description
from .params import RABBIT, RobotParams, load_params
from .urdf import load_urdf, xacro_refusal

__all__ = ["BipedModel", "rabbit", "robot", "resolve_robot", "E_RELABEL", "B_INPUT",
           "absolute_angles", "relabelling", "RABBIT_DESCRIPTION"]

#: Relabelling of the legs at impact, q+ = E q- (docs: theory §1), for RABBIT; E @ E = I.
#: Every model has its own (:func:`relabelling`, ``model.E``).
E_RELABEL = np.array([[1, 1, 1, 1, 1],
                      [0, 0, 0, 0, -1],
                      [0, 0, 0, -1, 0],
                      [0, 0, -1, 0, 0],
                      [0, -1, 0, 0, 0]], dtype=float)

#: Input matrix of eq. (1) for RABBIT: torques act on q2..q5 (``model.B`` in general).
B_INPUT = np.vstack([np.zeros((1, 4)), np.eye(4)])

#: RABBIT's description (docs: theory §1, torque limit 150 N m): the same numbers as the
#: packaged ``rabbit.toml`` and the legacy :data:`~biped_casadi.model.params.RABBIT`.
RABBIT_DESCRIPTION = RABBIT.to_description()


def absolute_angles(q):
    """phi_1..phi_n from q (cumulative sums): phi_k = q1 + ... + qk.

    Parameters
    ----------
    q : sequence
        Coordinates (numbers or CasADi symbols).

    Returns
    -------
    list
        The absolute angles, in the order of q.
    """
    n = len(q)
    return [sum(q[i] for i in range(k + 1)) for k in range(n)]


def relabelling(nq: int) -> np.ndarray:
    """E of q+ = E q- (eq. 3) for n = ``nq`` joints.

    Exchanging the legs reverses the order of the absolute angles (the new stance
    leg's links are the old swing leg's, read from the foot up, the torso keeps its
    angle), so with S the difference matrix q = S phi, E = S J S^-1 with J the
    reversal.  E @ E = I.

    Parameters
    ----------
    nq : int
        Number of joints (odd: 2 k + 1).

    Returns
    -------
    numpy.ndarray
        (nq, nq), entries 0 and +-1; :data:`E_RELABEL` for RABBIT.
    """
    if isinstance(nq, bool) or not isinstance(nq, (int, np.integer)) or nq < 3 or nq % 2 == 0:
        raise ValueError(f"nq must be an odd integer >= 3 (the stance leg's angle and two "
                         f"legs of k joints each, with the torso: 1 + 2 k), got {nq!r}")
    S = np.eye(nq) - np.eye(nq, k=-1)
    J = np.eye(nq)[::-1]
    return S @ J @ np.linalg.inv(S)


def _up(phi):
    return ca.vertcat(ca.sin(phi), ca.cos(phi))


@dataclass
class _Kinematics:
    points: dict   # joint / foot positions, in drawing order
    coms: dict     # link centre-of-mass positions, in the order of phi
    masses: dict   # point-mass positions
    phi: list      # absolute angles


def _link_names(d: RobotDescription) -> list:
    """Link names in the order of phi: stance leg from the foot up, torso, swing leg
    from the hip down."""
    return ([f"{link.name}_st" for link in reversed(d.leg)] + ["torso"]
            + [f"{link.name}_sw" for link in d.leg])


def _inner_joint_names(d: RobotDescription) -> list:
    """Joints between leg links, from the hip down ('knee' when k = 2)."""
    return ["knee"] if d.k == 2 else [f"joint{j}" for j in range(1, d.k)]


def _kinematics(d: RobotDescription, q, base=None, units=None) -> _Kinematics:
    """Positions of every joint, foot, link centre of mass and point mass (SX).  With
    ``units`` (one 2-vector (s, c) per link, in the order of phi) the links point along
    them instead of (sin phi, cos phi), and their forward normals along (c, -s): every
    position is then linear in the units.

    A link's centre of mass is ``com`` along its line from its proximal joint and
    ``com_offset`` along its forward normal f = (cos phi, -sin phi) (the description's
    convention: forward when the robot stands upright)."""
    n, k = d.nq, d.k
    phi = absolute_angles([q[i] for i in range(n)])
    e = [_up(a) for a in phi] if units is None else list(units)
    f = [ca.vertcat(u[1], -u[0]) for u in e]             # forward normals

    def off(link, i):                  # the centre of mass off the line (none: no term)
        return link.com_offset * f[i] if link.com_offset != 0.0 else 0.0
    names = _link_names(d)
    inner = _inner_joint_names(d)
    foot_st = ca.SX.zeros(2) if base is None else base
    points = dict(foot_st=foot_st)
    coms = {}
    p = foot_st
    for j in range(k):                          # stance leg, from the foot up
        link = d.leg[k - 1 - j]
        top = p + link.length * e[j]
        coms[names[j]] = top - link.com * e[j] + off(link, j)
        if j < k - 1:
            points[f"{inner[k - 2 - j]}_st"] = top
        p = top
    hip = p
    points["hip"] = hip
    points["torso_top"] = hip + d.torso.length * e[k]
    coms["torso"] = hip + d.torso.com * e[k] + off(d.torso, k)
    p = hip
    for j in range(k):                          # swing leg, from the hip down
        link = d.leg[j]
        i = k + 1 + j
        bottom = p - link.length * e[i]
        coms[names[i]] = p - link.com * e[i] + off(link, i)
        if j < k - 1:
            points[f"{inner[j]}_sw"] = bottom
        p = bottom
    points["foot_sw"] = p
    masses = {}
    for joint, _ in d.point_masses:
        if joint == "hip":
            masses["hip"] = hip
        else:
            key = "foot" if joint == "foot" else joint
            masses[f"{joint}_st"] = points[f"{key}_st"]
            masses[f"{joint}_sw"] = points[f"{key}_sw"]
    return _Kinematics(points, coms, masses, phi)


def _link_mass_inertia(d: RobotDescription) -> dict:
    links = list(reversed(d.leg)) + [d.torso] + list(d.leg)
    return {name: (link.mass, link.inertia) for name, link in zip(_link_names(d), links)}


def _point_mass_values(d: RobotDescription) -> dict:
    out = {}
    for joint, m in d.point_masses:
        if joint == "hip":
            out["hip"] = m
        else:
            out[f"{joint}_st"] = m
            out[f"{joint}_sw"] = m
    return out


def _energies(d: RobotDescription, kin: _Kinematics, coords, dcoords, rotor_rates):
    """Kinetic and potential energy for generalised coordinates ``coords``."""
    K = 0
    V = 0
    for i, (name, (m, I)) in enumerate(_link_mass_inertia(d).items()):
        c = kin.coms[name]
        v = ca.jtimes(c, coords, dcoords)
        w = ca.jtimes(kin.phi[i], coords, dcoords)
        K += 0.5 * m * ca.dot(v, v) + 0.5 * I * w**2
        V += m * d.gravity * c[1]
    for name, m in _point_mass_values(d).items():
        c = kin.masses[name]
        v = ca.jtimes(c, coords, dcoords)
        K += 0.5 * m * ca.dot(v, v)
        V += m * d.gravity * c[1]
    K += 0.5 * d.rotor_inertia * ca.sumsqr(rotor_rates)
    return K, V


def _pinned_kinetic(d: RobotDescription, q, dq):
    """Kinetic energy of the pinned robot (stance foot fixed) in relative angles.

    Every body's position is c = sum_i (A_i u_i + B_i f_i) with constants A_i, B_i,
    u_i = (sin phi_i, cos phi_i) and f_i = (cos phi_i, -sin phi_i) (B_i: the centres of
    mass off their links' lines), so |dc/dt|^2 = sum_ij dphi_i dphi_j [(A_i A_j +
    B_i B_j) cos(phi_i - phi_j) + (A_i B_j - B_i A_j) sin(phi_i - phi_j)]: K is a
    quadratic form in dphi whose entries depend on the differences phi_i - phi_j, sums
    of the relative coordinates q_2..q_n only.  The same energy as :func:`_energies`,
    without products of sines and cosines of absolute angles (D and H in a fraction of
    the operations, and exactly independent of q_1)."""
    n = d.nq
    S, C = ca.SX.sym("s", n), ca.SX.sym("c", n)
    kin = _kinematics(d, q, units=[ca.vertcat(S[i], C[i]) for i in range(n)])
    W = np.zeros((n, n))              # cos(phi_i - phi_j) coefficients
    V = np.zeros((n, n))              # sin(phi_i - phi_j) coefficients (antisymmetric)
    bodies = [(kin.coms[name], m) for name, (m, _) in _link_mass_inertia(d).items()]
    bodies += [(kin.masses[name], m) for name, m in _point_mass_values(d).items()]
    for pos, m in bodies:
        A = np.array(ca.evalf(ca.jacobian(pos[0], S))).ravel()
        B = np.array(ca.evalf(ca.jacobian(pos[0], C))).ravel()
        W += m * (np.outer(A, A) + np.outer(B, B))
        V += m * (np.outer(A, B) - np.outer(B, A))
    for i, (_, (_, inertia)) in enumerate(_link_mass_inertia(d).items()):
        W[i, i] += inertia
    dphi = absolute_angles([dq[i] for i in range(n)])
    K = 0
    for i in range(n):
        K += 0.5 * W[i, i] * dphi[i] ** 2
        for j in range(i):
            if W[i, j] == 0.0 and V[i, j] == 0.0:
                continue
            rel = sum(q[m] for m in range(j + 1, i + 1))       # phi_i - phi_j
            if V[i, j] == 0.0:
                K += W[i, j] * ca.cos(rel) * dphi[i] * dphi[j]
            elif W[i, j] == 0.0:
                K += V[i, j] * ca.sin(rel) * dphi[i] * dphi[j]
            else:
                K += (W[i, j] * ca.cos(rel) + V[i, j] * ca.sin(rel)) * dphi[i] * dphi[j]
    return K + 0.5 * d.rotor_inertia * ca.sumsqr(dq[1:])


def _fn(name, inputs, outputs, in_names, out_names):
    return ca.Function(name, inputs, outputs, in_names, out_names)


class BipedModel:
    """Symbolic model of one planar point-foot biped with numeric CasADi Functions.

    Built from a :class:`~biped_casadi.model.description.RobotDescription` (or a legacy
    :class:`~biped_casadi.model.params.RobotParams`); ``nq`` = 2 k + 1 joints, ``nu`` = 2 k
    torques for legs of k links.  Every Function takes numpy arrays or lists and
    returns ``casadi.DM``:

    ``D(q)`` mass matrix (nq x nq); ``H(q, dq)`` = C(q, dq) dq + G(q) (nq x 1);
    ``C(q, dq)`` Coriolis matrix with dD/dt - 2C skew; ``G(q)``;
    ``swing_foot(q)`` -> (x, z); ``swing_foot_velocity(q, dq)``;
    ``impact(q, dq)`` -> (q+, dq+) after impact and relabelling (docs: theory §1);
    ``impact_full(q, dq)`` -> (q+, dq+, F, dq_pre, v_old_stance): also the impulse on
    the new stance foot, the post-impact velocity before relabelling and the velocity
    of the old stance foot after impact;
    ``forward_dynamics(q, dq, u)`` -> ddq; ``inverse_dynamics(q, dq, ddq)`` -> u (rows
    2..n of D ddq + H, eq. (1) with B = [0; I]); ``ground_reaction(q, dq, u)`` -> (Fx, Fz)
    on the stance foot (Newton's law for the centre of mass); ``ground_reaction_acc(q,
    dq, ddq)`` the same from the accelerations;
    ``energy(q, dq)`` -> (K, V, E); ``com(q)``; ``link_coms(q)`` (2 x nq: every link's
    centre of mass, in the order of phi: stance leg from the foot up, torso, swing leg
    from the hip down); ``points(q)`` (2 x (2k + 2): stance
    foot, the stance leg's inner joints upward, hip, torso top, the swing leg's inner
    joints downward, swing foot; :attr:`point_names`); ``angular_momentum(q, dq, p)``
    about a point p (links and point masses, rotors excluded).

    Implements eqs. (1)-(4): the single-support dynamics D(q) ddq + H(q, dq) = B u of
    eq. (1) (``D``, ``H``, ``B``; ``forward_dynamics`` is f(x) + g(x) u of eq. (4)), the
    rigid impact dq+ = I(q-) dq- of eq. (2) solved in extended coordinates (q, x_st,
    z_st) with the impulse at the swing foot, the relabelling q+ = E q- of eq. (3)
    (``E``), so that ``impact`` is the map Delta of eq. (4), and the switching surface
    S = {z_sw(q) = 0, x_sw(q) > 0} of eq. (4) through ``swing_foot``.

    Parameters
    ----------
    params : RobotDescription or RobotParams
        The robot (legacy parameters are converted with
        :meth:`RobotParams.to_description`); default RABBIT.  Prefer :func:`robot` or
        :func:`rabbit`, which build each model once.

    Attributes
    ----------
    description : RobotDescription
        What the model was built from; ``params`` is the same object (the name older
        code uses).
    nq, nu : int
        Joints (2 k + 1) and torques (2 k).
    q_sym, dq_sym, u_sym : casadi.SX
        The symbols the Functions are built from (for symbolic work on the model).
    E, B : numpy.ndarray
        Relabelling (eq. 3) and input matrix (eq. 1).
    joint_names : tuple of str
        One per coordinate.
    stance_knees, swing_knees : tuple of int
        Indices (0-based) of the leg joints between links; empty without knees.
    hip_phase : numpy.ndarray
        theta = hip_phase . q, a linear stand-in for the angle of the line stance foot
        -> hip from the vertical (exact for straight legs, and for two links of equal
        length): the default phase variable of the virtual-constraint controller.
    scuffing_ignored : bool
        True for legs without knees (k = 1), which cannot lift the swing foot: as it
        passes the stance leg mid-step it must touch the ground.  Like Grizzle, Abba &
        Plestan (2001) the toolkit then ignores the swing foot being below the ground
        during the step (the simulator does not call it a scuff); a strike (the end of
        a step) is a downward crossing of the ground beyond ``scuff_zone`` in front of
        the stance foot, and the reference gait keeps the foot above the ground beyond
        that zone (``gait_opt`` clearance).
    scuff_zone : float
        m: 0.1 leg length when ``scuffing_ignored``, else 0 (a strike anywhere in front
        of the stance foot, and no passing below the ground).
    """

    def __init__(self, params: RobotDescription | RobotParams = RABBIT):
        if isinstance(params, RobotParams):
            params = params.to_description()
        if not isinstance(params, RobotDescription):
            raise ValueError(f"params must be a RobotDescription (or RobotParams), got "
                             f"{type(params).__name__}")
        self.description = self.params = params
        d = params
        self.k = d.k
        self.nq, self.nu = d.nq, d.nu
        self.E = relabelling(self.nq)
        self.B = np.vstack([np.zeros((1, self.nu)), np.eye(self.nu)])
        self.stance_knees = tuple(range(1, d.k))
        self.swing_knees = tuple(range(d.k + 2, d.nq))
        self.scuffing_ignored = d.k == 1
        self.scuff_zone = 0.1 * d.leg_length if self.scuffing_ignored else 0.0
        w = [link.length / d.leg_length for link in reversed(d.leg)]   # foot upward
        self.hip_phase = np.array([sum(w[m:]) for m in range(d.k)] + [0.0] * (d.k + 1))
        self.joint_names = self._joint_names()
        self._build()
        self.point_names = tuple(self._kin.points)
        #: index of the hip and of the torso top in ``points`` and drawing chains
        self.hip_index = self.point_names.index("hip")
        self.stance_chain = tuple(range(0, self.hip_index + 1))
        self.torso_chain = (self.hip_index, self.hip_index + 1)
        self.swing_chain = (self.hip_index,) + tuple(range(self.hip_index + 2,
                                                           len(self.point_names)))

    def _joint_names(self) -> tuple:
        d, k = self.description, self.k
        inner = _inner_joint_names(d)
        st = [f"stance {n}" for n in reversed(inner)]
        sw = [f"swing {n}" for n in inner]
        low = d.leg[-1].name
        # a link named like a joint (an imported Cassie's lower link 'knee') says 'link'
        lowest = "stance leg" if k == 1 else f"stance {low}" + (" link" if low in inner else "")
        return tuple([f"{lowest} (absolute)"] + st + ["stance hip (torso)", "swing hip"] + sw)

    # ------------------------------------------------------------------ build
    def _build(self):
        d, n, nu = self.description, self.nq, self.nu
        q = ca.SX.sym("q", n)
        dq = ca.SX.sym("dq", n)
        u = ca.SX.sym("u", nu)
        self.q_sym, self.dq_sym, self.u_sym = q, dq, u

        kin = _kinematics(d, q)
        self._kin = kin
        K0, V = _energies(d, kin, q, dq, dq[1:])
        K = _pinned_kinetic(d, q, dq)           # = K0, in relative angles
        self._K_absolute = K0
        D = ca.hessian(K, dq)[0]
        D = 0.5 * (D + D.T)
        G = ca.gradient(V, q)
        # Christoffel symbols: C[k, j] = sum_i c_ijk dq_i
        dD = [ca.jacobian(D[:, j], q) for j in range(n)]  # dD[j][k, i] = dD_kj/dq_i
        C = ca.SX.zeros(n, n)
        for k in range(n):
            for j in range(n):
                C[k, j] = sum(0.5 * (dD[j][k, i] + dD[i][k, j] - dD[j][i, k]) * dq[i]
                              for i in range(n))
        # H = C dq + G, with C dq = d/dt(dK/ddq) - dK/dq - D ddq; the same vector as
        # mtimes(C, dq) from the Christoffel symbols, in a third of the operations
        K_dq = 0.5 * ca.dot(dq, ca.mtimes(D, dq))
        H = ca.jtimes(ca.mtimes(D, dq), q, dq) - ca.gradient(K_dq, q) + G
        Bm = ca.DM(self.B)
        ddq = ca.solve(D, ca.mtimes(Bm, u) - H)
        acc = ca.SX.sym("ddq", n)

        self.D_expr, self.H_expr, self.G_expr = D, H, G
        foot = kin.points["foot_sw"]
        dfoot = ca.jtimes(foot, q, dq)
        M = d.total_mass
        com = sum(m_i * kin.coms[name] for name, (m_i, _) in _link_mass_inertia(d).items())
        for name, m_i in _point_mass_values(d).items():
            com = com + m_i * kin.masses[name]
        com = com / M
        dcom = ca.jtimes(com, q, dq)
        ddcom = ca.jtimes(dcom, q, dq) + ca.jtimes(com, q, ddq)
        grf = M * (ddcom + ca.vertcat(0, d.gravity))
        grf_acc = M * (ca.jtimes(dcom, q, dq) + ca.jtimes(com, q, acc) + ca.vertcat(0, d.gravity))

        self.D = _fn("D", [q], [D], ["q"], ["D"])
        self.H = _fn("H", [q, dq], [H], ["q", "dq"], ["H"])
        self.C = _fn("C", [q, dq], [C], ["q", "dq"], ["C"])
        self.G = _fn("G", [q], [G], ["q"], ["G"])
        self.swing_foot = _fn("swing_foot", [q], [foot[0], foot[1]], ["q"], ["x", "z"])
        self.swing_foot_velocity = _fn("swing_foot_velocity", [q, dq], [dfoot[0], dfoot[1]],
                                       ["q", "dq"], ["dx", "dz"])
        self.forward_dynamics = _fn("forward_dynamics", [q, dq, u], [ddq],
                                    ["q", "dq", "u"], ["ddq"])
        self.inverse_dynamics = _fn("inverse_dynamics", [q, dq, acc], [(ca.mtimes(D, acc) + H)[1:]],
                                    ["q", "dq", "ddq"], ["u"])
        self.ground_reaction = _fn("ground_reaction", [q, dq, u], [grf[0], grf[1]],
                                   ["q", "dq", "u"], ["Fx", "Fz"])
        self.ground_reaction_acc = _fn("ground_reaction_acc", [q, dq, acc],
                                       [grf_acc[0], grf_acc[1]], ["q", "dq", "ddq"], ["Fx", "Fz"])
        self.energy = _fn("energy", [q, dq], [K, V, K + V], ["q", "dq"], ["K", "V", "E"])
        self.com = _fn("com", [q], [com], ["q"], ["com"])
        self.com_velocity = _fn("com_velocity", [q, dq], [dcom], ["q", "dq"], ["dcom"])
        self.torso_angle = _fn("torso_angle", [q], [kin.phi[d.k]], ["q"], ["phi_torso"])
        self.link_coms = _fn("link_coms", [q], [ca.horzcat(*kin.coms.values())], ["q"],
                             ["C"])
        pts = kin.points
        self.points = _fn("points", [q], [ca.horzcat(*pts.values())], ["q"], ["P"])
        self._build_impact(q, dq)
        self._build_momentum(q, dq)

    def _build_impact(self, q, dq):
        """Rigid impact (paper eq. 2-3) in extended coordinates (q, x_st, z_st)."""
        d, n = self.description, self.nq
        base = ca.SX.sym("base", 2)
        dbase = ca.SX.sym("dbase", 2)
        qe = ca.vertcat(q, base)
        dqe = ca.vertcat(dq, dbase)
        kin = _kinematics(d, q, base)
        K, _ = _energies(d, kin, qe, dqe, dq[1:])
        De = ca.hessian(K, dqe)[0]
        De = 0.5 * (De + De.T)
        E2 = ca.jacobian(kin.points["foot_sw"], qe)          # 2 x (n + 2)
        # [De -E2'; E2 0] [dqe+; F] = [De dqe-; 0], dqe- = (dq-, 0, 0)
        A = ca.blockcat([[De, -E2.T], [E2, ca.SX.zeros(2, 2)]])
        rhs = ca.vertcat(ca.mtimes(De, ca.vertcat(dq, 0, 0)), ca.SX.zeros(2))
        sol = ca.solve(A, rhs)
        sol = ca.substitute(sol, ca.vertcat(base, dbase), ca.SX.zeros(4))
        dqe_plus = sol[:n + 2]
        F = sol[n + 2:]
        dq_pre = dqe_plus[:n]
        v_old_stance = dqe_plus[n:n + 2]
        Em = ca.DM(self.E)
        q_plus = ca.mtimes(Em, q)
        dq_plus = ca.mtimes(Em, dq_pre)
        self.impact = _fn("impact", [q, dq], [q_plus, dq_plus], ["q", "dq"], ["q_plus", "dq_plus"])
        self.impact_full = _fn("impact_full", [q, dq],
                               [q_plus, dq_plus, F, dq_pre, v_old_stance],
                               ["q", "dq"], ["q_plus", "dq_plus", "F", "dq_pre", "v_old_stance"])
        De0 = ca.substitute(De, base, ca.SX.zeros(2))
        self.D_extended = _fn("D_extended", [q], [De0], ["q"], ["De"])

    def _build_momentum(self, q, dq):
        """Whole-body angular momentum about a point (links and point masses, rotors
        excluded)."""
        d = self.description
        pt = ca.SX.sym("p", 2)
        kin = self._kin
        L = 0
        for i, (name, (m, I)) in enumerate(_link_mass_inertia(d).items()):
            c = kin.coms[name]
            v = ca.jtimes(c, q, dq)
            r = c - pt
            # planar angular momentum, positive about +y (x forward, z up): z*vx - x*vz
            L += m * (r[1] * v[0] - r[0] * v[1]) + I * ca.jtimes(kin.phi[i], q, dq)
        for name, m in _point_mass_values(d).items():
            c = kin.masses[name]
            v = ca.jtimes(c, q, dq)
            r = c - pt
            L += m * (r[1] * v[0] - r[0] * v[1])
        self.angular_momentum = _fn("angular_momentum", [q, dq, pt], [L], ["q", "dq", "p"], ["L"])

    # ---------------------------------------------------------------- helpers
    def __reduce__(self):
        # pickled as its description: unpickling builds the model once per process
        return (_model, (self.description,))

    @property
    def cache_key(self):
        """What the model's Functions depend on: its description."""
        return self.description.cache_key

    @property
    def has_knees(self) -> bool:
        """Whether the legs have joints between links (k >= 2)."""
        return self.k >= 2

    def describe(self, q=None) -> dict:
        """The robot and its mass matrix at one configuration, as a JSON-ready dict.

        Parameters
        ----------
        q : array_like, optional
            Configuration (nq,), rad; default upright (zeros).

        Returns
        -------
        dict
            ``params`` (the description's ``to_dict()``), ``total_mass`` (kg),
            ``joints`` (names), ``q``, ``D`` (nq x nq, D(q)) and ``H`` (H(q, 0): gravity
            only).
        """
        q = np.zeros(self.nq) if q is None else np.asarray(q, dtype=float)
        return dict(params=self.params.to_dict(), total_mass=self.params.total_mass,
                    joints=list(self.joint_names),
                    q=q.tolist(), D=np.array(self.D(q)).tolist(),
                    H=np.array(self.H(q, np.zeros(self.nq))).ravel().tolist())

    def __repr__(self):
        return (f"BipedModel({self.params.name}, {self.nq} joints, total mass "
                f"{self.params.total_mass:g} kg)")


@cached(maxsize=8)
def _model(description: RobotDescription) -> BipedModel:
    return BipedModel(description)


def resolve_robot(robot, foot=None, torque_limit=None) -> RobotDescription:
    """The description named by ``robot``.

    Parameters
    ----------
    robot : str, Path, RobotDescription or RobotParams
        A built-in name (``'rabbit'``, ``'three_link'``, case-insensitive), a
        description file (``.toml``), a URDF file (``.urdf``, read by
        :func:`biped_casadi.model.urdf.import_urdf`), a legacy flat parameter file
        (``.toml`` or ``.json`` with the fields of :class:`RobotParams`), or an object.
    foot : sequence of 3 floats, optional
        For a URDF file only: the foot point in the last leg link's frame, m.
    torque_limit : float, optional
        For a URDF file only: the torque limit, N m, instead of the file's efforts.

    Returns
    -------
    RobotDescription
        Validated.

    Raises
    ------
    ValueError
        Unknown name, missing file or an invalid description (the message names the
        field).
    """
    is_urdf = isinstance(robot, (str, Path)) and str(robot).lower().endswith(".urdf")
    if isinstance(robot, (str, Path)) and str(robot).lower().endswith(".xacro"):
        raise ValueError(f"robot: {Path(robot).name} is a xacro file, not a URDF: "
                         f"{xacro_refusal(Path(robot).name)}")
    for name, value in (("foot", foot), ("torque_limit", torque_limit)):
        if value is not None and not is_urdf:
            raise ValueError(f"{name}: applies to a URDF file (.urdf) only, not to {robot!r}")
    if is_urdf:
        if not Path(robot).is_file():
            raise ValueError(f"robot URDF file not found: {robot}")
        return load_urdf(robot, foot, torque_limit)
    if isinstance(robot, RobotDescription):
        return robot
    if isinstance(robot, RobotParams):
        return robot.to_description()
    if not isinstance(robot, (str, Path)) or not str(robot).strip():
        raise ValueError(f"robot must be a built-in name ({', '.join(BUILTIN)}) or a "
                         f"description file, got {robot!r}")
    text = str(robot)
    key = text.strip().lower().replace("-", "_")
    path = Path(text)
    if key in BUILTIN and not path.is_file():
        return load_description(builtin_path(key))
    if not path.exists() and not path.is_symlink():
        if path.suffix.lower() in (".toml", ".json") or "/" in text:
            raise ValueError(f"robot description file not found: {path}")
        raise ValueError(f"robot: {text!r} is neither a built-in robot "
                         f"({', '.join(BUILTIN)}) nor a description file")
    # it exists: a folder, a device or an unreadable file is reported by the reader
    if path.suffix.lower() == ".json" or _legacy_file(path):
        return load_params(path).to_description()
    return load_description(path)


def _legacy_file(path: Path) -> bool:
    """A flat parameter file (RobotParams fields at top level or under [robot])."""
    if not path.is_file() or path.stat().st_size > 1_000_000:
        return False                      # let load_description say what is wrong
    try:
        data = tomllib.loads(path.read_text())
    except Exception:          # noqa: BLE001 - let load_description report it
        return False
    if isinstance(data.get("robot"), dict):
        data = data["robot"]
    return RobotParams.is_legacy_record(data)


def robot(name_or_path="rabbit", foot=None, torque_limit=None) -> BipedModel:
    """The model of a built-in robot, of a description file or of a URDF file.

    Parameters
    ----------
    name_or_path : str, Path or RobotDescription
        ``'rabbit'`` (default), ``'three_link'``, a description file (see
        :mod:`biped_casadi.model.description` for the schema; legacy flat parameter files
        load too) or a URDF file (``.urdf``: :mod:`biped_casadi.model.urdf`).
    foot : sequence of 3 floats, optional
        For a URDF file whose last leg link has no foot link or frame: the foot point
        in that link's frame, m.
    torque_limit : float, optional
        For a URDF file: the torque limit, N m (needed when the file gives no effort
        limits and a command needs one).

    Returns
    -------
    BipedModel
        Built once per description (memoised); the same methods as :func:`rabbit`.
    """
    return _model(resolve_robot(name_or_path, foot, torque_limit))


def rabbit(params: RobotParams | RobotDescription | None = None) -> BipedModel:
    """The RABBIT model of docs: theory §1, or another parameter set.

    Parameters
    ----------
    params : RobotParams or RobotDescription, optional
        Default: RABBIT (:data:`RABBIT_DESCRIPTION`, the numbers of docs: theory §1 and
        of the packaged ``rabbit.toml``).

    Returns
    -------
    BipedModel
        Built once per parameter set (memoised).
    """
    if params is None:
        return _model(RABBIT_DESCRIPTION)
    return _model(resolve_robot(params))
