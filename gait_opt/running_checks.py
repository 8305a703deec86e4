"""Measured checks of a running gait (:mod:`gait_opt.running`), independent of the NLP.

- Dense grid: the Hermite-Simpson interpolant of each phase (states cubic, torques
  quadratic per interval) between the collocation points, with the ground force from
  the model's exact dynamics under the interpolated torques (not the collocation's).
- ODE integration: each phase integrated by scipy's DOP853 (tight tolerances) from its
  collocated initial state under the interpolated torques; the deviation from the
  collocated end state measures the transcription's error (open loop: the error grows
  with the phase's instability, so it is an upper estimate at the end of the phase).
- The step map through the exact edges: from the collocated end states through
  ``takeoff`` and ``landing_swing``, and from the integrated phases composed with the
  same edges (stance from the gait's start, the takeoff, flight to the swing foot's
  touchdown found as an event, the landing): both residuals against the start state.
- Physics of flight along the collocated and the integrated trajectory: the centre of
  mass on the parabola of its takeoff position and velocity, the angular momentum about
  it constant.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np

from biped_casadi.control.running import phase_derivatives
from biped_casadi.model import flight_model

from .running import RunningGait, hermite_simpson

__all__ = ["RunningReport", "check_running", "phase_rhs", "dense", "integrate_phase"]

DENSE = 20          # dense samples per Hermite-Simpson interval


@dataclass
class RunningReport:
    """What :func:`check_running` measured (SI units; forces N, lengths m, speeds m/s).

    Parameters
    ----------
    fz_takeoff : float
        Fz at the last stance point (the takeoff guard), N.
    fz_min_nodes, fz_min_dense : float
        Smallest Fz over the stance points and over the dense grid, N.
    friction_ratio_max : float
        Largest ``|Fx|`` / Fz on the dense grid where Fz > 1 % of the weight.
    friction_excess_nodes, friction_excess_dense : float
        Largest ``|Fx|`` - mu Fz over the stance points and over the dense grid, N (<= 0:
        inside the cone; the ratio alone exaggerates a small excess where Fz is small,
        near takeoff).
    torque_max_dense : float
        Largest ``|u|`` on the dense grid of both phases, N m.
    torque_max_dense_each : tuple of float
        Largest ``|u_i|`` of each torque u1 .. u_nu there, N m (their largest is
        ``torque_max_dense``).
    swing_min_stance : float
        Smallest swing-foot height in stance (dense grid), m.
    feet_min_flight : float
        Smallest height of either foot in flight, its ends excluded (dense grid), m.
    flight_duration : float
        s.
    takeoff_torque_jump : float
        max ``|u_flight(0) - u_stance(Ts)|``, N m (0: the accelerations agree at takeoff).
    takeoff_foot_acceleration : float
        The pushing-off foot's vertical acceleration at the start of flight, m/s^2 (with
        Fz = 0 and continuous torques, 0; negative would push it into the ground).
    strike_velocity : float
        The swing foot's vertical velocity at touchdown, m/s (< 0: moving down).
    other_foot_velocity : float
        The other foot's vertical velocity just after the landing impact, m/s (> 0).
    impulse_ratio : float
        ``|Fx|`` / Fz of the landing impulse.
    periodicity_collocated : float
        The larger of max ``|landing(end of flight) - start of stance|`` and max
        ``|takeoff(end of stance) - start of flight|``, the collocated states through
        the exact edges.
    stance_end_error, flight_end_error : float
        max ``|x_integrated(T) - x_collocated(T)|`` of each phase integrated from its own
        collocated start (rad, rad/s, m, m/s mixed: the largest entry).
    interval_error : float
        The same over one collocation interval, each integrated from its own collocated
        start, the largest of both phases: the grid's own error (O(h^4) per interval),
        which the phases' errors above also hold grown by the open loop.
    step_map_residual : float
        max ``|P(x0) - x0|`` of the step map composed of the integrated phases (flight to
        the touchdown event) and the exact edges, open loop under the gait's torques.
    touchdown_time_error : float
        Integrated touchdown time minus the collocated flight duration, s.
    com_ballistic_collocated, com_ballistic_integrated : float
        Largest distance of the centre of mass from its ballistic parabola in flight, m.
    momentum_drift_collocated, momentum_drift_integrated : float
        Largest change of the angular momentum about the centre of mass in flight, kg
        m^2/s.
    momentum_scale : float
        Largest ``|angular momentum about the centre of mass|`` in flight, kg m^2/s (the
        drifts' scale).
    """

    fz_takeoff: float
    fz_min_nodes: float
    fz_min_dense: float
    friction_ratio_max: float
    friction_excess_nodes: float
    friction_excess_dense: float
    torque_max_dense: float
    swing_min_stance: float
    feet_min_flight: float
    flight_duration: float
    takeoff_torque_jump: float
    takeoff_foot_acceleration: float
    strike_velocity: float
    other_foot_velocity: float
    impulse_ratio: float
    periodicity_collocated: float
    stance_end_error: float
    flight_end_error: float
    interval_error: float
    step_map_residual: float
    touchdown_time_error: float
    com_ballistic_collocated: float
    com_ballistic_integrated: float
    momentum_drift_collocated: float
    momentum_drift_integrated: float
    momentum_scale: float
    torque_max_dense_each: tuple = ()

    def as_dict(self) -> dict:
        """The figures as a plain dict.

        Returns
        -------
        dict
        """
        return asdict(self)

    def violations(self, torque_limit, tol: float = 1e-7) -> list:
        """The path constraints violated between the collocation points (dense grid).

        As :meth:`gait_opt.Gait.violations` says of a walking gait.

        Parameters
        ----------
        torque_limit : float or tuple of float
            The torque limit the step was made for, N m (friction: the step's own mu):
            one number, or one per torque u1 .. u_nu
            (:meth:`gait_opt.running.RunningOptions.limit`).
        tol : float
            Amounts up to this count as satisfied (round-off where Fz and Fx vanish).

        Returns
        -------
        list of (str, float)
            (constraint, worst amount), worst first, in N m, N and m; empty when all hold.
        """
        over = self.torque_max_dense - torque_limit if np.ndim(torque_limit) == 0 else \
            max(u - U for u, U in zip(self.torque_max_dense_each, torque_limit))
        amounts = {"torque limit": over,
                   "normal force in stance": -self.fz_min_dense,
                   "friction cone in stance (|Fx| - mu Fz)": self.friction_excess_dense,
                   "swing foot above the ground in stance": -self.swing_min_stance,
                   "feet above the ground in flight": -self.feet_min_flight}
        bad = [(k, float(v)) for k, v in amounts.items() if v > tol]
        return sorted(bad, key=lambda kv: -kv[1])


def phase_rhs(model, phase: str):
    """x' = f(x, u) of one phase as a numpy function.

    Parameters
    ----------
    model : BipedModel
        The robot.
    phase : str
        'stance' (x = (q, dq)) or 'flight' (x = (qe, dqe)).

    Returns
    -------
    callable
        f(x, u) -> numpy array of x's size (vectorised over columns).
    """
    if phase not in ("stance", "flight"):
        raise ValueError(f"phase must be 'stance' or 'flight', got {phase!r}")
    n = model.nq if phase == "stance" else flight_model(model).ne

    def f(x, u):
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float).reshape(model.nu, -1)
        return phase_derivatives(model, phase, x.reshape(2 * n, -1), u).reshape(x.shape)
    return f


def _phase_data(model, gait: RunningGait, phase: str):
    """(t nodes, X, F, U, f) of one phase."""
    f = phase_rhs(model, phase)
    t, X, U = ((gait.t_stance, gait.x_stance, gait.u_stance) if phase == "stance" else
               (gait.t_flight, gait.x_flight, gait.u_flight))
    return t, X, f(X, U), U, f


def dense(model, gait: RunningGait, phase: str, per_interval: int = DENSE):
    """One phase on a dense grid: the Hermite-Simpson interpolant.

    Parameters
    ----------
    model : BipedModel
        The robot.
    gait : RunningGait
        The gait.
    phase : str
        'stance' or 'flight'.
    per_interval : int
        Samples per Hermite-Simpson interval.

    Returns
    -------
    tuple of numpy.ndarray
        (t, x, u): times from the phase's start (s), states and torques as columns.
    """
    tn, X, F, U, _ = _phase_data(model, gait, phase)
    t = np.linspace(tn[0], tn[-1], per_interval * (tn.size - 1) // 2 + 1)
    x, u = hermite_simpson(tn, X, F, U, t)
    return t, x, u


def integrate_phase(model, gait: RunningGait, phase: str, x0=None, t_end=None,
                    events=None):
    """One phase integrated by scipy's DOP853 under the gait's interpolated torques.

    rtol = atol = 1e-11; past the phase's end the torques are held at their end values.

    Parameters
    ----------
    model : BipedModel
        The robot.
    gait : RunningGait
        The gait.
    phase : str
        'stance' or 'flight'.
    x0 : array_like, optional
        The initial state; default the collocated one.
    t_end : float, optional
        The final time from the phase's start, s; default the phase's duration.
    events : callable, optional
        ``solve_ivp`` events (e.g. the swing foot's touchdown).

    Returns
    -------
    scipy.integrate._ivp.ivp.OdeResult
        ``solve_ivp``'s result, with dense output.
    """
    from scipy.integrate import solve_ivp        # (its import: 0.4 s of every command's)
    tn, X, F, U, f = _phase_data(model, gait, phase)
    x0 = X[:, 0] if x0 is None else np.asarray(x0, dtype=float)
    t_end = tn[-1] if t_end is None else t_end

    def rhs(t, x):
        _, u = hermite_simpson(tn, X, F, U, [min(max(t, tn[0]), tn[-1])])
        return f(x, u[:, 0])
    return solve_ivp(rhs, (0.0, t_end), x0, method="DOP853", rtol=1e-11, atol=1e-11,
                     dense_output=True, events=events)


def _interval_error(model, gait: RunningGait) -> float:
    """The largest error of one collocation interval integrated (DOP853, as
    :func:`integrate_phase`) from its collocated start, over both phases."""
    from scipy.integrate import solve_ivp
    worst = 0.0
    for phase in ("stance", "flight"):
        tn, X, F, U, f = _phase_data(model, gait, phase)

        def rhs(t, x):
            _, u = hermite_simpson(tn, X, F, U, [t])
            return f(x, u[:, 0])
        for k in range(0, tn.size - 2, 2):
            r = solve_ivp(rhs, (tn[k], tn[k + 2]), X[:, k], method="DOP853", rtol=1e-11,
                          atol=1e-11)
            worst = max(worst, float(np.max(np.abs(r.y[:, -1] - X[:, k + 2]))))
    return worst


def _flight_physics(fl, xs, ts):
    """(largest CoM distance from its parabola, largest change of the angular momentum
    about the CoM, largest |momentum|) along flight states xs (columns) at times ts."""
    ne = fl.ne
    g = fl.model.description.gravity
    c = np.array(fl.com.map(xs.shape[1])(xs[:ne]))
    dc = np.array(fl.com_velocity(xs[:ne, 0], xs[ne:, 0])).ravel()
    para = c[:, :1] + dc[:, None] * ts[None, :] + np.vstack([0 * ts, -0.5 * g * ts ** 2])
    L = np.array([float(fl.angular_momentum(xs[:ne, k], xs[ne:, k], c[:, k]))
                  for k in range(xs.shape[1])])
    return (float(np.max(np.linalg.norm(c - para, axis=0))), float(np.max(np.abs(L - L[0]))),
            float(np.max(np.abs(L))))


def _edges(model, fl, gait: RunningGait):
    """Figures of the two edges from the collocated end states."""
    n, ne = model.nq, fl.ne
    xs, xf = gait.x_stance, gait.x_flight
    qe0, dqe0 = fl.takeoff(xs[:n, -1], xs[n:, -1])
    r_take = np.max(np.abs(np.r_[np.array(qe0).ravel(), np.array(dqe0).ravel()] - xf[:, 0]))
    q_p, dq_p, F, _, v_other, _ = fl.landing_swing(xf[:ne, -1], xf[ne:, -1])
    r_land = np.max(np.abs(np.r_[np.array(q_p).ravel(), np.array(dq_p).ravel()] - xs[:, 0]))
    F = np.array(F).ravel()
    u0 = gait.u_flight[:, 0]
    acc = np.array(fl.flight_dynamics(xf[:ne, 0], xf[ne:, 0], u0)).ravel()
    # foot_st of the flight frame is the base: its acceleration is the base's
    v_sw = np.array(fl.feet_velocity(xf[:ne, -1], xf[ne:, -1]))[1, 1]
    return dict(periodicity_collocated=float(max(r_take, r_land)),
                takeoff_torque_jump=float(np.max(np.abs(u0 - gait.u_stance[:, -1]))),
                takeoff_foot_acceleration=float(acc[n + 1]),
                strike_velocity=float(v_sw), other_foot_velocity=float(np.array(v_other)[1, 0]),
                impulse_ratio=float(abs(F[0]) / F[1]) if F[1] > 0 else float("inf"))


def _stance_figures(model, fl, gait: RunningGait):
    n = model.nq
    xs, us = gait.x_stance, gait.u_stance
    Fz_n, Fx_n = (np.array(v).ravel()
                  for v in fl.takeoff_guard.map(xs.shape[1])(xs[:n], xs[n:], us))
    mu = gait.options.mu
    t, x, u = dense(model, gait, "stance")
    Fz, Fx = (np.array(v).ravel() for v in fl.takeoff_guard.map(t.size)(x[:n], x[n:], u))
    weight = model.description.total_mass * model.description.gravity
    loaded = Fz > 0.01 * weight
    _, zsw = model.swing_foot.map(t.size)(x[:n])
    return dict(fz_takeoff=float(Fz_n[-1]), fz_min_nodes=float(Fz_n.min()),
                fz_min_dense=float(Fz.min()),
                friction_ratio_max=float(np.max(np.abs(Fx[loaded]) / Fz[loaded], initial=0.0)),
                friction_excess_nodes=float(np.max(np.abs(Fx_n) - mu * Fz_n)),
                friction_excess_dense=float(np.max(np.abs(Fx) - mu * Fz)),
                swing_min_stance=float(np.array(zsw).min())), np.abs(u).max(axis=1)


def _step_map(model, fl, gait: RunningGait):
    """Integrated stance, takeoff, integrated flight to touchdown, landing."""
    n, ne = model.nq, fl.ne
    st = integrate_phase(model, gait, "stance")
    x_take = st.y[:, -1]
    qe0, dqe0 = fl.takeoff(x_take[:n], x_take[n:])
    x_fl0 = np.r_[np.array(qe0).ravel(), np.array(dqe0).ravel()]

    def touchdown(t, x):
        return float(np.array(fl.feet(x[:ne]))[1, 1]) if t > 0.5 * gait.T_flight else 1.0
    touchdown.terminal, touchdown.direction = True, -1
    fl_run = integrate_phase(model, gait, "flight", x_fl0, 1.5 * gait.T_flight, touchdown)
    if fl_run.t_events[0].size:
        t_td, x_td = fl_run.t_events[0][0], fl_run.y_events[0][0]
    else:
        t_td, x_td = np.nan, fl_run.y[:, -1]
    q_p, dq_p, *_ = fl.landing_swing(x_td[:ne], x_td[ne:])
    x_next = np.r_[np.array(q_p).ravel(), np.array(dq_p).ravel()]
    return dict(stance_end_error=float(np.max(np.abs(x_take - gait.x_stance[:, -1]))),
                step_map_residual=float(np.max(np.abs(x_next - gait.x_stance[:, 0]))),
                touchdown_time_error=float(t_td - gait.T_flight))


def check_running(model, gait: RunningGait) -> RunningReport:
    """Measure a running gait outside the NLP.

    Dense path constraints, integrated phases, the step map through the exact edges,
    the physics of flight (module docstring).

    Parameters
    ----------
    model : BipedModel
        The robot the gait was optimised for.
    gait : RunningGait
        The gait.

    Returns
    -------
    RunningReport
    """
    fl = flight_model(model)
    ne = fl.ne
    stance, u_max_s = _stance_figures(model, fl, gait)
    t, x, u = dense(model, gait, "flight")
    feet = np.array(fl.feet.map(t.size)(x[:ne]))
    inner = slice(1, t.size - 1)
    fl_int = integrate_phase(model, gait, "flight")
    tf = np.linspace(0, gait.T_flight, 101)
    xi = fl_int.sol(tf)
    coll = _flight_physics(fl, x, t)
    integ = _flight_physics(fl, xi, tf)
    return RunningReport(
        **stance, torque_max_dense=float(max(u_max_s.max(), np.abs(u).max())),
        torque_max_dense_each=tuple(float(v) for v in np.maximum(u_max_s,
                                                                 np.abs(u).max(axis=1))),
        feet_min_flight=float(min(feet[1, 0::2][inner].min(), feet[1, 1::2][inner].min())),
        flight_duration=gait.T_flight, **_edges(model, fl, gait),
        flight_end_error=float(np.max(np.abs(fl_int.y[:, -1] - gait.x_flight[:, -1]))),
        **_step_map(model, fl, gait), interval_error=_interval_error(model, gait),
        com_ballistic_collocated=coll[0], com_ballistic_integrated=integ[0],
        momentum_drift_collocated=coll[1], momentum_drift_integrated=integ[1],
        momentum_scale=max(coll[2], integ[2]))
