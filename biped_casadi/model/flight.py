"""The flight phase of a planar point-foot biped and its two edges with single support:
the model of a second domain, for running gaits.

In flight no foot touches the ground and the robot has n + 2 degrees of freedom.  Its
coordinates are the extended coordinates in which :class:`~biped_casadi.model.biped.BipedModel`
already solves the walking impact: qe = (q, x_st, z_st), the stance coordinates q of
docs: theory §1 (q1 the absolute angle of the lowest link of the leg that last stood,
the other entries relative angles) and the position (x_st, z_st) of that leg's foot,
the floating base.  Kinetic and potential energies come from the same kinematics and
energy helpers as the stance model, so the two domains describe one robot:

- flight dynamics De(q) ddqe + He(q, dqe) = Be u with Be = [B; 0] (the torques act on
  the same joints; nothing acts on the base) (:attr:`FlightModel.flight_dynamics`);
- takeoff, stance -> flight: the stance state embedded with the base at the stance foot
  and its velocity zero (:attr:`FlightModel.takeoff`), when the normal ground force of
  ``ground_reaction`` reaches zero (:attr:`FlightModel.takeoff_guard`);
- landing, flight -> stance: the rigid impact of one foot from any extended velocity,
  with the assumptions of the walking impact (instantaneous, no slip, no rebound, the
  other foot leaves the ground without interaction, no impulsive torque), followed by the
  relabelling E when the landing foot is the former swing foot
  (:attr:`FlightModel.landing_swing`, :attr:`FlightModel.landing_stance`).  The walking
  impact ``BipedModel.impact`` is ``landing_swing`` with a zero base velocity.

Every Function takes the extended state even where only q matters (De and He do not
depend on the base's position): a domain's functions take that domain's state.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from ..caching import cached
from .biped import (BipedModel, _energies, _fn, _kinematics, _link_mass_inertia,
                    _point_mass_values)

__all__ = ["FlightModel", "flight_model"]


class FlightModel:
    """The flight domain of a biped and its takeoff and landing edges.

    Named ``casadi.Function`` objects, built from a
    :class:`~biped_casadi.model.biped.BipedModel` (its description, its B and E).  With
    ``n`` = ``model.nq`` and ``ne`` = n + 2, extended coordinates qe = (q, x_st, z_st)
    (module docstring).  Every Function takes numpy arrays or lists and returns
    ``casadi.DM``:

    ``De(qe)`` mass matrix (ne x ne; equal to ``model.D_extended(q)``);
    ``He(qe, dqe)`` = Ce(q, dqe) dqe + Ge (ne x 1); ``flight_dynamics(qe, dqe, u)`` ->
    ddqe, the solution of De ddqe + He = Be u; ``feet(qe)`` (2 x 2: the stance foot,
    i.e. the base, then the swing foot, as columns (x, z)); ``feet_velocity(qe, dqe)``
    (2 x 2, the same columns); ``com(qe)``; ``com_velocity(qe, dqe)``;
    ``energy(qe, dqe)`` -> (K, V, E); ``angular_momentum(qe, dqe, p)`` about a point p
    (links and point masses, rotors excluded, as ``model.angular_momentum``);
    ``points(qe)`` (2 x npts, the order of ``model.point_names``);

    ``sliding_dynamics(qe, dqe, u, mu_s)`` -> (ddqe, Fz): the stance foot held at
    z_st = 0 and sliding under the ground force (mu_s Fz, Fz), the solution of
    De ddqe + He = Be u + e_x mu_s Fz + e_z Fz, ddz_st = 0 (e_x, e_z the base's
    coordinates); with mu_s the ratio Fx / Fz of ``takeoff_guard`` at a state with the
    foot at rest it gives the pinned foot's ``forward_dynamics`` and ddx_st = 0;

    ``takeoff(q, dq)`` -> (qe, dqe): a stance state in extended coordinates (base at
    the stance foot, at the origin of the stance frame, with zero velocity);
    ``takeoff_guard(q, dq, u)`` -> (Fz, Fx): the ground force on the stance foot
    (``model.ground_reaction``); the foot lifts off when Fz reaches 0 from above;

    ``landing_swing(qe, dqe)`` and ``landing_stance(qe, dqe)`` -> (q_plus, dq_plus, F,
    dqe_post, v_other, p_foot): the rigid impact of the swing foot (then relabelled with
    E) or of the stance foot (no relabelling): the stance state after landing, the
    impulse F (2,) of the ground on the landing foot, the extended velocity just after
    impact, the velocity of the other foot just after impact (it must move up for the
    landing to be valid) and where the landing foot is (the origin of the new stance
    frame, in the flight frame).

    Parameters
    ----------
    model : BipedModel
        The robot in single support.  Prefer :func:`flight_model`, which builds each
        flight model once.

    Attributes
    ----------
    model : BipedModel
        The stance model it extends.
    nq, ne, nu : int
        Joints, extended coordinates (nq + 2) and torques.
    Be : numpy.ndarray
        (ne, nu) input matrix, [B; 0].
    qe_sym, dqe_sym, u_sym : casadi.SX
        The symbols the flight Functions are built from.
    """

    def __init__(self, model: BipedModel):
        if not isinstance(model, BipedModel):
            raise ValueError(f"model must be a BipedModel, got {type(model).__name__}")
        self.model = model
        self.nq, self.nu = model.nq, model.nu
        self.ne = self.nq + 2
        self.Be = np.vstack([model.B, np.zeros((2, self.nu))])
        self._build_dynamics()
        self._build_takeoff()
        for foot in ("swing", "stance"):
            self._build_landing(foot)

    @property
    def cache_key(self):
        """What the Functions depend on: the stance model's description."""
        return self.model.cache_key

    def __repr__(self):
        return f"FlightModel({self.model.description.name}, {self.ne} coordinates)"

    # ---------------------------------------------------------------- flight
    def _build_dynamics(self):
        """De, He, flight_dynamics and the flight kinematics (Lagrange, as eq. (1) with
        the base free)."""
        d, n = self.model.description, self.nq
        q, base = ca.SX.sym("q", n), ca.SX.sym("base", 2)
        dq, dbase = ca.SX.sym("dq", n), ca.SX.sym("dbase", 2)
        u = ca.SX.sym("u", self.nu)
        qe, dqe = ca.vertcat(q, base), ca.vertcat(dq, dbase)
        self.qe_sym, self.dqe_sym, self.u_sym = qe, dqe, u
        kin = _kinematics(d, q, base)
        self._kin = kin
        K, V = _energies(d, kin, qe, dqe, dq[1:])
        De = ca.hessian(K, dqe)[0]
        De = 0.5 * (De + De.T)
        Ge = ca.gradient(V, qe)
        K_dq = 0.5 * ca.dot(dqe, ca.mtimes(De, dqe))
        He = ca.jtimes(ca.mtimes(De, dqe), qe, dqe) - ca.gradient(K_dq, qe) + Ge
        ddqe = ca.solve(De, ca.mtimes(ca.DM(self.Be), u) - He)
        self._De = De
        self.De = _fn("De", [qe], [De], ["qe"], ["De"])
        self.He = _fn("He", [qe, dqe], [He], ["qe", "dqe"], ["He"])
        self.flight_dynamics = _fn("flight_dynamics", [qe, dqe, u], [ddqe],
                                   ["qe", "dqe", "u"], ["ddqe"])
        feet = ca.horzcat(kin.points["foot_st"], kin.points["foot_sw"])
        self.feet = _fn("feet", [qe], [feet], ["qe"], ["P"])
        self.feet_velocity = _fn("feet_velocity", [qe, dqe], [ca.jtimes(feet, qe, dqe)],
                                 ["qe", "dqe"], ["V"])
        self.energy = _fn("energy", [qe, dqe], [K, V, K + V], ["qe", "dqe"], ["K", "V", "E"])
        self.points = _fn("points", [qe], [ca.horzcat(*kin.points.values())], ["qe"], ["P"])
        self._build_momentum(qe, dqe)
        self._build_sliding(qe, dqe, u, He)

    def _build_sliding(self, qe, dqe, u, He):
        """The stance foot sliding on the ground: held on it vertically (z_st = 0, one
        holonomic constraint), the tangential force Coulomb's, Fx = mu_s Fz."""
        n = self.nq
        mu_s = ca.SX.sym("mu_s")
        ex, ez = ca.DM.zeros(self.ne), ca.DM.zeros(self.ne)
        ex[n], ez[n + 1] = 1, 1
        # [De  -(ez + mu_s ex); ez' 0] [ddqe; Fz] = [Be u - He; 0]  (dJ = 0: J is constant)
        A = ca.blockcat([[self._De, -(ez + mu_s * ex)], [ez.T, ca.SX.zeros(1, 1)]])
        sol = ca.solve(A, ca.vertcat(ca.mtimes(ca.DM(self.Be), u) - He, 0))
        self.sliding_dynamics = _fn("sliding_dynamics", [qe, dqe, u, mu_s],
                                    [sol[:self.ne], sol[self.ne]],
                                    ["qe", "dqe", "u", "mu_s"], ["ddqe", "Fz"])

    def _build_momentum(self, qe, dqe):
        """Centre of mass, its velocity and the angular momentum about a point."""
        d = self.model.description
        kin = self._kin
        pt = ca.SX.sym("p", 2)
        bodies = [(kin.coms[name], m, I, kin.phi[i])
                  for i, (name, (m, I)) in enumerate(_link_mass_inertia(d).items())]
        bodies += [(kin.masses[name], m, 0.0, None) for name, m in _point_mass_values(d).items()]
        com = sum(m * c for c, m, _, _ in bodies) / d.total_mass
        L = 0
        for c, m, I, phi in bodies:
            v = ca.jtimes(c, qe, dqe)
            r = c - pt
            L += m * (r[1] * v[0] - r[0] * v[1])       # about +y (x forward, z up)
            if phi is not None:
                L += I * ca.jtimes(phi, qe, dqe)
        self.com = _fn("com", [qe], [com], ["qe"], ["com"])
        self.com_velocity = _fn("com_velocity", [qe, dqe], [ca.jtimes(com, qe, dqe)],
                                ["qe", "dqe"], ["dcom"])
        self.angular_momentum = _fn("angular_momentum", [qe, dqe, pt], [L],
                                    ["qe", "dqe", "p"], ["L"])

    # ---------------------------------------------------------------- edges
    def _build_takeoff(self):
        """Stance -> flight: the embedding and the lift-off guard."""
        m, n = self.model, self.nq
        q, dq, u = ca.SX.sym("q", n), ca.SX.sym("dq", n), ca.SX.sym("u", self.nu)
        zero = ca.SX.zeros(2)
        self.takeoff = _fn("takeoff", [q, dq], [ca.vertcat(q, zero), ca.vertcat(dq, zero)],
                           ["q", "dq"], ["qe", "dqe"])
        Fx, Fz = m.ground_reaction(q, dq, u)
        self.takeoff_guard = _fn("takeoff_guard", [q, dq, u], [Fz, Fx],
                                 ["q", "dq", "u"], ["Fz", "Fx"])

    def _build_landing(self, foot: str):
        """Flight -> stance: the rigid impact of one foot (the walking impact's
        equations, paper eq. 2, with any pre-impact base velocity), then the relabelling
        E when the swing foot lands."""
        n = self.nq
        qe, dqe = self.qe_sym, self.dqe_sym
        landing = self._kin.points["foot_sw" if foot == "swing" else "foot_st"]
        other = self._kin.points["foot_st" if foot == "swing" else "foot_sw"]
        J = ca.jacobian(landing, qe)                             # 2 x ne
        # [De -J'; J 0] [dqe+; F] = [De dqe-; 0]
        A = ca.blockcat([[self._De, -J.T], [J, ca.SX.zeros(2, 2)]])
        sol = ca.solve(A, ca.vertcat(ca.mtimes(self._De, dqe), ca.SX.zeros(2)))
        dqe_post, F = sol[:self.ne], sol[self.ne:]
        v_other = ca.mtimes(ca.jacobian(other, qe), dqe_post)
        q, dq_post = qe[:n], dqe_post[:n]
        if foot == "swing":
            Em = ca.DM(self.model.E)
            q, dq_post = ca.mtimes(Em, q), ca.mtimes(Em, dq_post)
        name = f"landing_{foot}"
        setattr(self, name, _fn(name, [qe, dqe], [q, dq_post, F, dqe_post, v_other, landing],
                                ["qe", "dqe"],
                                ["q_plus", "dq_plus", "F", "dqe_post", "v_other", "p_foot"]))


def flight_model(model: BipedModel) -> FlightModel:
    """The flight domain of a model, built once per robot description.

    Parameters
    ----------
    model : BipedModel
        The robot in single support (:func:`~biped_casadi.model.biped.robot`,
        :func:`~biped_casadi.model.biped.rabbit`).

    Returns
    -------
    FlightModel
        Its flight dynamics, takeoff and landing Functions (memoised by the model's
        description).

    Raises
    ------
    ValueError
        ``model`` is not a BipedModel.
    """
    if not isinstance(model, BipedModel):
        raise ValueError(f"model must be a BipedModel, got {type(model).__name__}")
    return _flight(model)


@cached(maxsize=8)
def _flight(model: BipedModel) -> FlightModel:
    return FlightModel(model)
