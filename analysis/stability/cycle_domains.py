"""The domains of a walking and a running biped, for the stride map over a cycle of
domains (:mod:`analysis.stability.hybrid_cycle`).

Walking (:func:`walking_domain`, :func:`walking_cycle`) is the cycle of one domain,
single support under a controller with the law interface, ended by the swing foot's
strike and reset by the impact with the relabelling: its stride map is
:class:`~analysis.stability.step_map.StepMap`'s S (no push; flat ground, or the ground
height h of the strike), built from the same simulator.  :func:`stance_flight_cycle`
builds stance -> flight -> stance of a robot under a PD law on the joints
(:mod:`biped_casadi.model.flight`): takeoff where the stance normal force reaches zero,
landing of the swing foot.
"""
from __future__ import annotations

import casadi as ca
import numpy as np

from biped_casadi.model import flight_model
from biped_casadi.simulation import SimulationOptions, simulator

from .hybrid_cycle import Domain, HybridCycle

__all__ = ["walking_domain", "walking_cycle", "stance_flight_cycle"]


# -------------------------------------------------------------------- walking
def walking_domain(controller, options: SimulationOptions | None = None, plant=None,
                   ground: float = 0.0, name: str = "single support") -> Domain:
    """Single support of the walking closed loop as a domain.

    Built from the simulator's plant and controller
    (:class:`~biped_casadi.simulation.Simulator`, as
    :class:`~analysis.stability.step_map.StepMap` uses them):
    x = (q, dq); X = (q, dq, r) and p the controller's step constants, set by its
    ``start`` at entry; the vector field is the simulator's (the law's torques, clipped
    when the options saturate, on the plant's eq. 1); the guard is the swing foot's
    height above the ground ``ground``, armed in front of ``plant.scuff_zone``; the
    reset the impact with the relabelling; the constraint the stance normal force >= 0;
    the time limit the simulator's horizon.

    Parameters
    ----------
    controller : Design, TimeVaryingController or VirtualConstraintController
        The control law.
    options : SimulationOptions, optional
        Its ``rk4_steps`` (per reference step T) and ``horizon`` (in T).
    plant : BipedModel, optional
        The robot that moves (default the controller's model).
    ground : float
        Height of the ground the swing foot strikes, m (StepMap's h).
    name : str
        The domain's name.

    Returns
    -------
    Domain
    """
    sim = simulator(controller, options, plant)
    c, m = sim.controller, sim.plant
    nq = m.nq
    X, t, p = ca.SX.sym("X", 2 * nq + c.n_ref), ca.SX.sym("t"), ca.SX.sym("p", c.n_par)
    q, dq, r = X[:nq], X[nq:2 * nq], X[2 * nq:]
    u, _, _, _, dr, _ = c.law(q, dq, t, r, p)
    ua = sim.applied_torque(u)[0]
    f = ca.Function("walking_vector_field", [X, t, p],
                    [ca.vertcat(dq, m.forward_dynamics(q, dq, ua), dr)])
    xs, zs = m.swing_foot(q)
    guard = ca.Function("swing_foot_height", [X, t, p], [zs - ground])
    arming = ca.Function("in_front", [X, t, p], [xs - m.scuff_zone])
    _, Fz = m.ground_reaction(q, dq, ua)
    cons = ca.Function("normal_force", [X, t, p], [Fz])
    qs, dqs = ca.SX.sym("q", nq), ca.SX.sym("dq", nq)
    r0, p0 = c.start(qs, dqs)
    x = ca.vertcat(qs, dqs)
    start = ca.Function("walking_start", [x], [ca.vertcat(qs, dqs, r0), p0])
    reset = ca.Function("walking_impact", [x], [ca.vertcat(*m.impact(qs, dqs))])
    return Domain(name, 2 * nq, f, guard, reset, sim.h,
                  sim.options.horizon * sim.T, start=start, arming=arming,
                  constraints=cons, constraint_names=("stance normal force",),
                  guard_name="swing foot height")


def walking_cycle(controller, options: SimulationOptions | None = None, plant=None,
                  ground: float = 0.0) -> HybridCycle:
    """Walking as the cycle of one domain (:func:`walking_domain`).

    Its stride map is the step-to-step map S of
    :class:`~analysis.stability.step_map.StepMap` at the ground height ``ground`` with no
    push.

    Parameters
    ----------
    controller, options, plant, ground
        As :func:`walking_domain`.

    Returns
    -------
    HybridCycle
    """
    return HybridCycle([walking_domain(controller, options, plant, ground)])


# -------------------------------------------------------------------- running
def stance_flight_cycle(model, target, flight_target=None, Kp: float = 300.0,
                        Kd: float = 20.0, h: float = 1e-3,
                        t_max: tuple = (1.0, 1.0)) -> HybridCycle:
    """Stance -> flight -> stance of a robot under a PD law on its actuated joints.

    u = -Kp (q_a - target) - Kd dq_a in stance and the same law about ``flight_target``
    in flight (q_a the relative joint angles, the same coordinates in flight:
    :mod:`biped_casadi.model.flight`).  Not a running controller: an example of a
    cycle whose resets change the state's dimension.  Nothing keeps the tangential
    force inside a friction cone as the normal force reaches zero; the stance foot's
    height in flight is checked instead.

    - stance: x = (q, dq) (2 nq); guard the stance normal force Fz (``takeoff_guard``);
      constraint the swing foot above the ground; reset ``takeoff`` into (qe, dqe);
    - flight: x = (qe, dqe) (2 nq + 4); guard the swing foot's height; constraint the
      stance foot above the ground; exit constraints the normal landing impulse >= 0 and
      the other foot moving up after it; reset ``landing_swing`` (relabelled) into the
      stance state.

    Parameters
    ----------
    model : BipedModel
        The robot.
    target : array_like
        (nu,) the joints' set point in stance, rad.
    flight_target : array_like, optional
        (nu,) the set point in flight (default ``target``), rad.
    Kp, Kd : float
        PD gains, N m/rad and N m s/rad.
    h : float
        RK4 step of both domains, s.
    t_max : (float, float)
        Time limits of stance and flight, s.

    Returns
    -------
    HybridCycle
    """
    fl = flight_model(model)
    nq, nu, ne = model.nq, model.nu, fl.ne
    targets = []
    for name, v in (("target", target), ("flight_target", flight_target)):
        v = np.asarray(target if v is None else v, float).ravel()
        if v.size != nu:
            raise ValueError(f"{name} must have {nu} numbers, got {v.size}")
        targets.append(ca.DM(v))
    B = np.asarray(model.B)
    t, p = ca.SX.sym("t"), ca.SX.sym("p", 0)

    def pd(qv, dqv, set_point):
        qa, dqa = ca.mtimes(B.T, qv), ca.mtimes(B.T, dqv)
        return -Kp * (qa - set_point) - Kd * dqa

    X = ca.SX.sym("X", 2 * nq)
    q, dq = X[:nq], X[nq:]
    u = pd(q, dq, targets[0])
    f_st = ca.Function("stance_vector_field", [X, t, p],
                       [ca.vertcat(dq, model.forward_dynamics(q, dq, u))])
    Fz, _ = fl.takeoff_guard(q, dq, u)
    g_st = ca.Function("normal_force", [X, t, p], [Fz])
    c_st = ca.Function("swing_clearance", [X, t, p], [model.swing_foot(q)[1]])
    x = ca.SX.sym("x", 2 * nq)
    qe0, dqe0 = fl.takeoff(x[:nq], x[nq:])
    r_st = ca.Function("takeoff", [x], [ca.vertcat(qe0, dqe0)])
    stance = Domain("stance", 2 * nq, f_st, g_st, r_st, h, t_max[0],
                    constraints=c_st, constraint_names=("swing foot height",),
                    guard_name="stance normal force", dense_constraints=("swing foot height",))

    Y = ca.SX.sym("Y", 2 * ne)
    qe, dqe = Y[:ne], Y[ne:]
    uf = pd(qe[:nq], dqe[:nq], targets[1])
    f_fl = ca.Function("flight_vector_field", [Y, t, p],
                       [ca.vertcat(dqe, fl.flight_dynamics(qe, dqe, uf))])
    feet = fl.feet(qe)
    g_fl = ca.Function("swing_foot_height", [Y, t, p], [feet[1, 1]])
    c_fl = ca.Function("stance_foot_height", [Y, t, p], [feet[1, 0]])
    y = ca.SX.sym("y", 2 * ne)
    qp, dqp, F, _, v_other, _ = fl.landing_swing(y[:ne], y[ne:])
    r_fl = ca.Function("landing", [y], [ca.vertcat(qp, dqp)])
    e_fl = ca.Function("landing_checks", [y], [ca.vertcat(F[1], v_other[1])])
    flight = Domain("flight", 2 * ne, f_fl, g_fl, r_fl, h, t_max[1],
                    constraints=c_fl, constraint_names=("stance foot height",),
                    exit_constraints=e_fl,
                    exit_constraint_names=("landing normal impulse",
                                           "other foot's lift-off velocity"),
                    guard_name="swing foot height",
                    dense_constraints=("stance foot height",), dense_guard=True)
    return HybridCycle([stance, flight])
