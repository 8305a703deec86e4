"""RABBIT-type planar five-link biped: kinematics, Lagrangian dynamics and impact map
as CasADi SX expressions, exposed as named ``casadi.Function`` objects.

Coordinates follow SPEC section 1: absolute link angles phi_i measured from the
vertical (positive leaning to +x); q1 = phi1 (the unactuated stance-tibia angle),
q2..q5 relative knee/hip angles; stance foot at the origin.
"""
from __future__ import annotations

from dataclasses import dataclass

import casadi as ca
import numpy as np

from .caching import cached
from .params import RABBIT, RobotParams

__all__ = ["BipedModel", "rabbit", "E_RELABEL", "B_INPUT", "absolute_angles"]

#: Relabelling of the legs at impact, q+ = E q- (SPEC section 1); E @ E = I.
E_RELABEL = np.array([[1, 1, 1, 1, 1],
                      [0, 0, 0, 0, -1],
                      [0, 0, 0, -1, 0],
                      [0, 0, -1, 0, 0],
                      [0, -1, 0, 0, 0]], dtype=float)

#: Input matrix of eq. (1): torques act on q2..q5.
B_INPUT = np.vstack([np.zeros((1, 4)), np.eye(4)])

LINKS = ("tibia_st", "femur_st", "torso", "femur_sw", "tibia_sw")


def absolute_angles(q):
    """phi1..phi5 from q (cumulative sums): phi_k = q1 + ... + qk."""
    return [sum(q[i] for i in range(k + 1)) for k in range(5)]


def _up(phi):
    return ca.vertcat(ca.sin(phi), ca.cos(phi))


@dataclass
class _Kinematics:
    points: dict   # joint / foot positions
    coms: dict     # link centre-of-mass positions
    phi: list      # absolute angles


def _kinematics(p: RobotParams, q, base=None) -> _Kinematics:
    phi = absolute_angles([q[i] for i in range(5)])
    e = [_up(a) for a in phi]
    foot_st = ca.SX.zeros(2) if base is None else base
    knee_st = foot_st + p.L_tibia * e[0]
    hip = knee_st + p.L_femur * e[1]
    torso_top = hip + p.L_torso * e[2]
    knee_sw = hip - p.L_femur * e[3]
    foot_sw = knee_sw - p.L_tibia * e[4]
    points = dict(foot_st=foot_st, knee_st=knee_st, hip=hip, torso_top=torso_top,
                  knee_sw=knee_sw, foot_sw=foot_sw)
    coms = dict(
        tibia_st=knee_st - p.c_tibia * e[0],
        femur_st=hip - p.c_femur * e[1],
        torso=hip + p.c_torso * e[2],
        femur_sw=hip - p.c_femur * e[3],
        tibia_sw=knee_sw - p.c_tibia * e[4],
    )
    return _Kinematics(points, coms, phi)


def _link_mass_inertia(p: RobotParams):
    return dict(tibia_st=(p.m_tibia, p.I_tibia), femur_st=(p.m_femur, p.I_femur),
                torso=(p.m_torso, p.I_torso), femur_sw=(p.m_femur, p.I_femur),
                tibia_sw=(p.m_tibia, p.I_tibia))


def _energies(p: RobotParams, kin: _Kinematics, coords, dcoords, rotor_rates):
    """Kinetic and potential energy for generalised coordinates ``coords``."""
    K = 0
    V = 0
    for i, name in enumerate(LINKS):
        m, I = _link_mass_inertia(p)[name]
        c = kin.coms[name]
        v = ca.jtimes(c, coords, dcoords)
        w = ca.jtimes(kin.phi[i], coords, dcoords)
        K += 0.5 * m * ca.dot(v, v) + 0.5 * I * w**2
        V += m * p.g * c[1]
    K += 0.5 * p.rotor_inertia * ca.sumsqr(rotor_rates)
    return K, V


def _fn(name, inputs, outputs, in_names, out_names):
    return ca.Function(name, inputs, outputs, in_names, out_names)


class BipedModel:
    """Symbolic model of one planar five-link biped with numeric CasADi Functions.

    Every Function takes numpy arrays or lists and returns ``casadi.DM``:

    ``D(q)`` mass matrix (5x5); ``H(q, dq)`` = C(q, dq) dq + G(q) (5x1);
    ``C(q, dq)`` Coriolis matrix with dD/dt - 2C skew; ``G(q)``;
    ``swing_foot(q)`` -> (x, z); ``swing_foot_velocity(q, dq)``;
    ``impact(q, dq)`` -> (q+, dq+) after impact and relabelling (SPEC section 1);
    ``impact_full(q, dq)`` -> (q+, dq+, F, dq_pre, v_old_stance): also the impulse on
    the new stance foot, the post-impact velocity before relabelling and the velocity
    of the old stance foot after impact;
    ``forward_dynamics(q, dq, u)`` -> ddq; ``inverse_dynamics(q, dq, ddq)`` -> u (rows
    2..5 of D ddq + H, eq. (1) with B = [0; I]); ``ground_reaction(q, dq, u)`` -> (Fx, Fz) on
    the stance foot (Newton's law for the centre of mass); ``ground_reaction_acc(q, dq,
    ddq)`` the same from the accelerations;
    ``energy(q, dq)`` -> (K, V, E); ``com(q)``; ``points(q)`` (2x6: stance foot, stance
    knee, hip, torso top, swing knee, swing foot); ``angular_momentum(q, dq, p)`` about
    a point p.
    """

    nq = 5
    nu = 4
    E = E_RELABEL
    B = B_INPUT

    def __init__(self, params: RobotParams = RABBIT):
        if not isinstance(params, RobotParams):
            raise ValueError(f"params must be a RobotParams, got {type(params).__name__}")
        self.params = params
        self._build()

    # ------------------------------------------------------------------ build
    def _build(self):
        p = self.params
        q = ca.SX.sym("q", 5)
        dq = ca.SX.sym("dq", 5)
        u = ca.SX.sym("u", 4)
        self.q_sym, self.dq_sym, self.u_sym = q, dq, u

        kin = _kinematics(p, q)
        self._kin = kin
        K, V = _energies(p, kin, q, dq, dq[1:])
        D = ca.hessian(K, dq)[0]
        D = 0.5 * (D + D.T)
        G = ca.gradient(V, q)
        # Christoffel symbols: C[k, j] = sum_i c_ijk dq_i
        dD = [ca.jacobian(D[:, j], q) for j in range(5)]  # dD[j][k, i] = dD_kj/dq_i
        C = ca.SX.zeros(5, 5)
        for k in range(5):
            for j in range(5):
                C[k, j] = sum(0.5 * (dD[j][k, i] + dD[i][k, j] - dD[j][i, k]) * dq[i]
                              for i in range(5))
        # H = C dq + G, with C dq = d/dt(dK/ddq) - dK/dq - D ddq; the same vector as
        # mtimes(C, dq) from the Christoffel symbols, in a third of the operations
        K_dq = 0.5 * ca.dot(dq, ca.mtimes(D, dq))
        H = ca.jtimes(ca.mtimes(D, dq), q, dq) - ca.gradient(K_dq, q) + G
        Bm = ca.DM(B_INPUT)
        ddq = ca.solve(D, ca.mtimes(Bm, u) - H)
        acc = ca.SX.sym("ddq", 5)

        self.D_expr, self.H_expr, self.G_expr = D, H, G
        foot = kin.points["foot_sw"]
        dfoot = ca.jtimes(foot, q, dq)
        M = p.total_mass
        com = sum(m_i * kin.coms[n] for n, (m_i, _) in _link_mass_inertia(p).items()) / M
        dcom = ca.jtimes(com, q, dq)
        ddcom = ca.jtimes(dcom, q, dq) + ca.jtimes(com, q, ddq)
        grf = M * (ddcom + ca.vertcat(0, p.g))
        grf_acc = M * (ca.jtimes(dcom, q, dq) + ca.jtimes(com, q, acc) + ca.vertcat(0, p.g))

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
        self.torso_angle = _fn("torso_angle", [q], [kin.phi[2]], ["q"], ["phi_torso"])
        pts = kin.points
        self.points = _fn("points", [q], [ca.horzcat(*[pts[k] for k in (
            "foot_st", "knee_st", "hip", "torso_top", "knee_sw", "foot_sw")])],
            ["q"], ["P"])
        self._build_impact(q, dq)
        self._build_momentum(q, dq)

    def _build_impact(self, q, dq):
        """Rigid impact (paper eq. 2-3) in extended coordinates (q, x_st, z_st)."""
        p = self.params
        base = ca.SX.sym("base", 2)
        dbase = ca.SX.sym("dbase", 2)
        qe = ca.vertcat(q, base)
        dqe = ca.vertcat(dq, dbase)
        kin = _kinematics(p, q, base)
        K, _ = _energies(p, kin, qe, dqe, dq[1:])
        De = ca.hessian(K, dqe)[0]
        De = 0.5 * (De + De.T)
        E2 = ca.jacobian(kin.points["foot_sw"], qe)          # 2x7
        # [De -E2'; E2 0] [dqe+; F] = [De dqe-; 0], dqe- = (dq-, 0, 0)
        A = ca.blockcat([[De, -E2.T], [E2, ca.SX.zeros(2, 2)]])
        rhs = ca.vertcat(ca.mtimes(De, ca.vertcat(dq, 0, 0)), ca.SX.zeros(2))
        sol = ca.solve(A, rhs)
        sol = ca.substitute(sol, ca.vertcat(base, dbase), ca.SX.zeros(4))
        dqe_plus = sol[:7]
        F = sol[7:]
        dq_pre = dqe_plus[:5]
        v_old_stance = dqe_plus[5:7]
        Em = ca.DM(E_RELABEL)
        q_plus = ca.mtimes(Em, q)
        dq_plus = ca.mtimes(Em, dq_pre)
        self.impact = _fn("impact", [q, dq], [q_plus, dq_plus], ["q", "dq"], ["q_plus", "dq_plus"])
        self.impact_full = _fn("impact_full", [q, dq],
                               [q_plus, dq_plus, F, dq_pre, v_old_stance],
                               ["q", "dq"], ["q_plus", "dq_plus", "F", "dq_pre", "v_old_stance"])
        De0 = ca.substitute(De, base, ca.SX.zeros(2))
        self.D_extended = _fn("D_extended", [q], [De0], ["q"], ["De"])

    def _build_momentum(self, q, dq):
        """Whole-body angular momentum about a point (links only, rotors excluded)."""
        p = self.params
        pt = ca.SX.sym("p", 2)
        kin = self._kin
        L = 0
        for i, name in enumerate(LINKS):
            m, I = _link_mass_inertia(p)[name]
            c = kin.coms[name]
            v = ca.jtimes(c, q, dq)
            r = c - pt
            # planar angular momentum, positive about +y (x forward, z up): z*vx - x*vz
            L += m * (r[1] * v[0] - r[0] * v[1]) + I * ca.jtimes(kin.phi[i], q, dq)
        self.angular_momentum = _fn("angular_momentum", [q, dq, pt], [L], ["q", "dq", "p"], ["L"])

    # ---------------------------------------------------------------- helpers
    @property
    def cache_key(self):
        """What the model's Functions depend on: its parameters."""
        return self.params

    def describe(self, q=None) -> dict:
        """Parameters, total mass, D(q) and H(q, 0) at ``q`` (default upright), as a dict."""
        q = np.zeros(5) if q is None else np.asarray(q, dtype=float)
        return dict(params=self.params.to_dict(), total_mass=self.params.total_mass,
                    q=q.tolist(), D=np.array(self.D(q)).tolist(),
                    H=np.array(self.H(q, np.zeros(5))).ravel().tolist())

    def __repr__(self):
        return f"BipedModel({self.params.name}, total mass {self.params.total_mass:g} kg)"


@cached(maxsize=8)
def _model(params: RobotParams) -> BipedModel:
    return BipedModel(params)


def rabbit(params: RobotParams | None = None) -> BipedModel:
    """The RABBIT model of SPEC section 1, or another parameter set.

    Parameters
    ----------
    params : RobotParams, optional
        Default: :data:`~biped_casadi.params.RABBIT`.

    Returns
    -------
    BipedModel
        Built once per parameter set (memoised).
    """
    return _model(RABBIT if params is None else params)
